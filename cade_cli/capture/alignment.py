"""How well a registered band lines up with its reference band, with no ground truth: the
shift left between the two in windows on a grid, found by normalised cross-correlation of
their gradient images (which edges the two bands share does not depend on their contrast),
summarised as its median, 90th percentile and share above 1 px, with the coverage kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.capture.homography import gradient_magnitude
from cade_cli.errors import CadeError

WINDOW = 64
"""Side, px, of the reference windows a shift is measured in."""
SEARCH = 32
"""How far (px, each axis) a window's match is searched for in the registered band."""
MIN_TEXTURE = 0.15
"""A window is scored only where the mean gradient of both bands in it is at least this share
of that band's typical textured window (the 90th percentile of the windows' means)."""
MIN_PEAK = 0.45
"""A window is scored only where the normalised cross-correlation peak reaches this (the best
of the ~37,000 places a 96 px search tries between unrelated smooth textures stayed below 0.4;
the raw bands of a bench capture peak at 0.47-0.96, 10th to 90th percentile)."""
MAX_AMBIGUITY = 0.9
"""... and where no other peak (beyond :data:`PEAK_RADIUS`) reaches this share of it
(repeated structure, e.g. rows of a crop, gives no single answer)."""
PEAK_RADIUS = 4
"""Half side, px, of the neighbourhood of the best peak excluded when looking for a second."""
OVER = 1.0
"""The residual shift, px, above which a window counts as misregistered."""


@dataclass(frozen=True)
class WindowShifts:
    """The residual shift of every window on the grid.

    ``centres``: (N, 2) float, the windows' centres (row, column) in reference pixels.
    ``shifts``: (N, 2) float, (dx, dy) px: the registered band's content of a window lies at
    ``reference position + shift``; NaN where the window was not scored.
    ``peaks``: (N,) float, the correlation peak (NaN where not computed).
    ``beyond``: (N,) bool, the match lies at the edge of the search: the shift is at least that
    large (a lower bound, kept in the summary at its value).
    """

    centres: np.ndarray
    shifts: np.ndarray
    peaks: np.ndarray
    beyond: np.ndarray

    @property
    def magnitudes(self) -> np.ndarray:
        """(N,) shift length, px; NaN where not scored."""
        return np.hypot(self.shifts[:, 0], self.shifts[:, 1])


@dataclass(frozen=True)
class Alignment:
    """A registered band's alignment with the reference.

    ``median``, ``p90``: of the scored windows' residual-shift lengths, px (NaN when no window
    was scored); ``share_over_1px``: the share of them above :data:`OVER`, in [0, 1];
    ``coverage``: the share of the reference's valid pixels the band has a value at;
    ``windows``: how many windows were scored; ``beyond``: how many of those matched at the
    edge of the search (their shift a lower bound).
    """

    median: float
    p90: float
    share_over_1px: float
    coverage: float
    windows: int
    beyond: int


def _window_means(gradient: np.ndarray, tops: np.ndarray, lefts: np.ndarray, window: int) -> np.ndarray:
    integral = cv2.integral(gradient.astype(np.float64))
    bottom, right = tops + window, lefts + window
    sums = (integral[bottom[:, None], right[None, :]] - integral[tops[:, None], right[None, :]]
            - integral[bottom[:, None], lefts[None, :]] + integral[tops[:, None], lefts[None, :]])
    return sums / window ** 2


def _textured(gradient: np.ndarray, tops: np.ndarray, lefts: np.ndarray, window: int,
              min_texture: float) -> np.ndarray:
    means = _window_means(gradient, tops, lefts, window)
    typical = float(np.percentile(means, 90))
    return means >= min_texture * typical if typical > 0 else np.zeros_like(means, bool)


def _parabola(minus: float, centre: float, plus: float) -> float:
    """Sub-pixel offset of a peak from three samples around it."""
    curvature = minus - 2.0 * centre + plus
    return 0.0 if curvature >= 0 else float(np.clip(0.5 * (minus - plus) / curvature, -0.5, 0.5))


def _match(template: np.ndarray, area: np.ndarray, *, max_ambiguity: float
           ) -> tuple[float, float, float, tuple[bool, bool, bool, bool]]:
    """Where ``template`` best matches in ``area``: (x, y) of its top-left corner, sub-pixel,
    the peak (NaN when not unique), and whether the peak lies on the area's top, bottom, left,
    right edge."""
    scores = cv2.matchTemplate(area, template, cv2.TM_CCOEFF_NORMED)
    height, width = template.shape
    sums = cv2.integral(area.astype(np.float64))
    patch_sums = sums[height:, width:] - sums[:-height, width:] - sums[height:, :-width] + sums[:-height, :-width]
    scores[patch_sums <= 0] = -1.0  # no gradient at all (the frame around the band): OpenCV's NCC there is 1
    y, x = np.unravel_index(int(np.argmax(scores)), scores.shape)
    peak = float(scores[y, x])
    sides = (y == 0, y == scores.shape[0] - 1, x == 0, x == scores.shape[1] - 1)
    others = scores.copy()
    others[max(y - PEAK_RADIUS, 0):y + PEAK_RADIUS + 1, max(x - PEAK_RADIUS, 0):x + PEAK_RADIUS + 1] = -1.0
    if float(others.max()) > max_ambiguity * peak:
        return float(x), float(y), float("nan"), sides
    dx = 0.0 if sides[2] or sides[3] else _parabola(scores[y, x - 1], peak, scores[y, x + 1])
    dy = 0.0 if sides[0] or sides[1] else _parabola(scores[y - 1, x], peak, scores[y + 1, x])
    return x + dx, y + dy, peak, sides


REFINE_MARGIN = 4
"""Margin, px, around the correlation peak that the sub-pixel refinement may move within."""


def _refine(template: np.ndarray, band_gradient: np.ndarray, dy: float, dx: float, top: int, left: int
            ) -> tuple[float, float]:
    """The shift (dx, dy) of ``template`` (the reference window at ``top``, ``left``) refined to
    sub-pixel by ECC (a translation, on the gradient images) from the correlation peak's
    (``dx``, ``dy``); that peak where ECC fails or leaves its neighbourhood."""
    window = template.shape[0]
    rows = (max(int(np.floor(top + dy)) - REFINE_MARGIN, 0), min(int(np.ceil(top + dy)) + window + REFINE_MARGIN,
                                                                 band_gradient.shape[0]))
    cols = (max(int(np.floor(left + dx)) - REFINE_MARGIN, 0), min(int(np.ceil(left + dx)) + window + REFINE_MARGIN,
                                                                  band_gradient.shape[1]))
    start = np.float32([[1, 0, left + dx - cols[0]], [0, 1, top + dy - rows[0]]])
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    try:
        _, warp = cv2.findTransformECC(template, band_gradient[rows[0]:rows[1], cols[0]:cols[1]], start,
                                       cv2.MOTION_TRANSLATION, criteria, None, 1)
    except cv2.error:
        return dx, dy
    refined = (float(warp[0, 2]) + cols[0] - left, float(warp[1, 2]) + rows[0] - top)
    return refined if max(abs(refined[0] - dx), abs(refined[1] - dy)) <= 1.0 else (dx, dy)


def window_shifts(reference: np.ndarray, registered: np.ndarray, *, window: int = WINDOW, step: int | None = None,
                  search: int = SEARCH, min_texture: float = MIN_TEXTURE, min_peak: float = MIN_PEAK,
                  max_ambiguity: float = MAX_AMBIGUITY) -> WindowShifts:
    """The residual shift of ``registered`` against ``reference`` in every ``window`` x
    ``window`` window on a grid of ``step`` px (default: ``window``, no overlap) over the image.

    Each reference window's gradient image (:func:`gradient_magnitude`) is searched for in the
    registered band's, up to ``search`` px away, by normalised cross-correlation; the integer
    peak is refined to sub-pixel by ECC (a translation). A window is not scored (NaN) where
    the reference window holds a NaN, where either band has too little texture there
    (``min_texture``), where the peak is below ``min_peak`` or not unique (``max_ambiguity``),
    or where the match holds a pixel the registered band did not see (NaN, or outside its
    frame). A match on the edge of the search is kept at that shift, marked ``beyond``: a
    lower bound.

    Args:
        reference, registered: (H, W) real arrays of one size, NaN where not seen.

    Raises:
        CadeError: shapes differ or the bands are smaller than a window.
    """
    reference, registered = np.asarray(reference, np.float32), np.asarray(registered, np.float32)
    if reference.shape != registered.shape or reference.ndim != 2:
        raise CadeError(f"reference {reference.shape} and registered band {registered.shape} must be two (H, W) "
                        "images of one size")
    height, width = reference.shape
    step = step or window
    if window < 16 or min(height, width) < window or step < 1 or search < 1:
        raise CadeError(f"a {window} px window (step {step}, search {search}) does not fit a {width}x{height} band")
    gradients = [gradient_magnitude(reference), gradient_magnitude(registered)]
    tops, lefts = np.arange(0, height - window + 1, step), np.arange(0, width - window + 1, step)
    textured = np.logical_and(*[_textured(g, tops, lefts, window, min_texture) for g in gradients])
    unseen = cv2.integral((~np.isfinite(reference)).astype(np.uint8))
    # the registered band framed by `search` px of nothing: a match there is not scored
    framed = cv2.copyMakeBorder(gradients[1], search, search, search, search, cv2.BORDER_CONSTANT, value=0.0)
    framed_unseen = cv2.integral(cv2.copyMakeBorder((~np.isfinite(registered)).astype(np.uint8), search, search,
                                                    search, search, cv2.BORDER_CONSTANT, value=1))
    count = len(tops) * len(lefts)
    centres = np.stack(np.meshgrid(tops + (window - 1) / 2.0, lefts + (window - 1) / 2.0, indexing="ij"), -1)
    shifts, peaks, beyond = np.full((count, 2), np.nan), np.full(count, np.nan), np.zeros(count, bool)
    for k, (i, j) in enumerate(np.ndindex(len(tops), len(lefts))):
        top, left = int(tops[i]), int(lefts[j])
        if textured[i, j] and not _holes(unseen, (top, top + window), (left, left + window)):
            template = gradients[0][top:top + window, left:left + window]
            shifts[k], peaks[k], beyond[k] = _score_window(template, framed, framed_unseen, top, left, search=search,
                                                           min_peak=min_peak, max_ambiguity=max_ambiguity)
    return WindowShifts(centres.reshape(-1, 2), shifts, peaks, beyond)


def _score_window(template: np.ndarray, framed: np.ndarray, framed_unseen: np.ndarray, top: int, left: int, *,
                  search: int, min_peak: float, max_ambiguity: float) -> tuple[tuple[float, float], float, bool]:
    """((dx, dy) or NaN, peak, beyond) of the reference window ``template`` at (``top``,
    ``left``), searched for in the registered band's gradient ``framed`` by ``search`` px of
    nothing (``framed_unseen``: the integral of its unseen pixels)."""
    window = template.shape[0]
    area = framed[top:top + window + 2 * search, left:left + window + 2 * search]
    x, y, peak, sides = _match(template, area, max_ambiguity=max_ambiguity)
    nothing = (float("nan"), float("nan"))
    if not peak >= min_peak:
        return nothing, peak, False
    dx, dy = x - search, y - search
    match_top, match_left = top + search + int(round(dy)), left + search + int(round(dx))
    if _holes(framed_unseen, (match_top, match_top + window), (match_left, match_left + window)):
        return nothing, peak, False  # the match holds pixels the band did not see (or outside its frame)
    if any(sides):
        return (dx, dy), peak, True
    return _refine(template, framed, dy, dx, top + search, left + search), peak, False


def _holes(integral: np.ndarray, rows: tuple[int, int], cols: tuple[int, int]) -> bool:
    return bool(integral[rows[1], cols[1]] - integral[rows[0], cols[1]] - integral[rows[1], cols[0]]
                + integral[rows[0], cols[0]] > 0)


def summarise(shifts: WindowShifts, coverage: float) -> Alignment:
    """:class:`Alignment` of the scored windows of ``shifts``."""
    scored = np.isfinite(shifts.shifts).all(axis=1)
    magnitudes = shifts.magnitudes[scored]
    if magnitudes.size == 0:
        return Alignment(float("nan"), float("nan"), float("nan"), coverage, 0, 0)
    return Alignment(float(np.median(magnitudes)), float(np.percentile(magnitudes, 90)),
                     float((magnitudes > OVER).mean()), coverage, int(magnitudes.size),
                     int(shifts.beyond[scored].sum()))


def coverage(reference: np.ndarray, registered: np.ndarray) -> float:
    """Share of the reference's valid (finite) pixels where the registered band has a value."""
    seen = np.isfinite(np.asarray(reference, np.float32))
    if not seen.any():
        raise CadeError("the reference band has no valid pixel")
    return float((seen & np.isfinite(np.asarray(registered, np.float32))).sum() / seen.sum())


def alignment(reference: np.ndarray, registered: np.ndarray, **options) -> Alignment:
    """The alignment of ``registered`` with ``reference``: :func:`window_shifts` (``options``
    are its keywords) summarised, with the :func:`coverage`."""
    return summarise(window_shifts(reference, registered, **options), coverage(reference, registered))
