"""A cheap test of a pair before it is matched: rectified, in order, and inside the range searched?

Every matcher assumes a rectified pair, LEFT the reference, and a search range that holds
the scene's disparities. When one of these fails, the matchers still return a map that
looks plausible (a pair shifted 6 px vertically keeps most pixels "valid") but is wrong.
:func:`check_pair` tests the three assumptions on sparse feature matches, before matching:

1. both bands are downscaled by :func:`check_factor` (area averaging, width kept at least
   :data:`CHECK_WIDTH` px), turned into colour-agnostic gradient images
   (:func:`gradient_band`: bands from different filters match, contrast inversions
   included), and described by upright ORB features (:func:`describe_band`: FAST corners
   ranked by Harris response, :func:`feature_count` of them, one per
   :data:`AREA_PER_FEATURE` px of the pair, so that the work follows the image area as the
   matchers' does; the binary pattern is not steered by each corner's orientation, which
   between spectral bands is unstable); features within :func:`max_horizontal` columns and
   :data:`MAX_VERTICAL_SHARE` rows of each other compete (:func:`match_features`), and the
   row of each match is refined to a fraction of a pixel (:func:`subpixel_row_shift`, on
   the same gradient images);
2. the row difference of the matches is fitted as a vertical offset plus a rotation about
   the image centre: the line (offset, rotation) that most matches lie on is found by a
   vote over rotations of up to :data:`MAX_ROTATION_DEG` (:func:`dominant_line`: cross-band
   matches hold many wrong ones, spread over every row difference), then refined on the
   matches near it by the rig self-check's robust fit
   (:func:`cade_cli.rigs.self_check.fit_vertical_misalignment`); the matches it keeps are
   the pair's trusted matches;
3. their horizontal offsets ``x_left - x_right`` are disparities (px): mostly negative
   with a non-negative range means LEFT and RIGHT are swapped; mostly outside the range
   searched means the range misses the scene, and a range that holds them is suggested.

The check only reads the pair: it never changes a disparity, and its result does not depend
on the thread count (with two OpenCV threads or more the two bands are described side by
side). Its cost follows the image area: about 5 ms for a small pair such as ArtL, 347 x 277,
about 8-9 ms for a Q-size Middlebury pair, 4-6 % of the fastest matcher's (sgbm) time on
those but about 20 % on ArtL (``benchmarks/pair_check.py``, docs/pair-check.md, which also
counts its false alarms on every rectified Middlebury, KITTI and FlyingThings3D pair of the
data folder). A pair with too little texture shared by the bands gives too few matches to
judge: the check is then inconclusive and finds no problem.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.rigs.self_check import fit_vertical_misalignment
from cade_cli.scale.range import range_margin

CHECK_WIDTH = 320
"""The pair is downscaled by powers of two while it stays at least this wide (px)."""
FEATURES = 600
"""The most features detected per band."""
MIN_FEATURES = 100
"""The fewest features detected per band."""
AREA_PER_FEATURE = 320
"""One feature per this many px of the pair's full-size area (between :data:`MIN_FEATURES` and
:data:`FEATURES`): the check's work follows the image area, as the matchers' does."""
FAST_THRESHOLD = 40
"""FAST threshold of the detector (grey levels of :func:`gradient_band`, edges about 64)."""
PATCH_SIZE = 31
"""Descriptor patch size (px of the downscaled band)."""
MAX_VERTICAL_SHARE = 0.05
"""Matches whose rows differ by more than this share of the width (at least
:data:`MIN_MAX_VERTICAL_PX`) are not considered: room for a 2 degree rotation plus an offset."""
MIN_MAX_VERTICAL_PX = 16.0
MIN_MATCHES = 20
"""Fewer trusted matches than this: the check is inconclusive (repetitive texture can put a
handful of wrong matches on one wrong row)."""
MIN_ROLL_MATCHES = 20
"""The rotation is fitted from at least this many matches (below: the offset only)."""
LINE_BAND_PX = 1.0
"""Matches within this many px of the line voted for are refined; the fit keeps those within
3 robust standard deviations of its line, at least half of this."""
MAX_ROTATION_DEG = 3.0
ROTATION_STEP_DEG = 0.2
"""Rotations voted for: -3..3 degrees in steps of 0.2 (1.25 px at the edge of a 718 px wide image)."""
VERTICAL_TOLERANCE_PX = 1.5
"""A vertical misalignment reaching this many px somewhere across the width is reported.
Matchers search along rows: beyond about a pixel their error grows quickly."""
ROTATION_PRECISION_DEG = 0.4
"""The check's rotations are this precise (spurious rotations of up to 0.32 degrees on the
rectified benchmark pairs, docs/pair-check.md): the misalignment judged is that of the
rotation shrunk towards 0 by this much."""
SWAPPED_SHARE = 0.5
"""More than this share of the trusted matches with a negative disparity, while the range
searched is non-negative: LEFT and RIGHT are swapped."""
RANGE_MISS_SHARE = 0.5
"""More than this share of the trusted matches outside the range searched: the range misses the scene."""
DISPARITY_TOLERANCE_PX = 2.0
"""Slack (px of the check's scale) on the range bounds: the matches' positions are that coarse."""
RANGE_PERCENTILES = (2.0, 98.0)
"""Percentiles (%) of the trusted matches' disparities taken as the scene's range before the margin."""
PROBLEMS = ("swapped", "vertical", "range")
"""What :attr:`PairCheck.problems` may name, in the order they are reported."""


@dataclass(frozen=True)
class PairCheck:
    """What :func:`check_pair` found.

    Attributes:
        matches: trusted matches (consistent with the vertical fit); fewer than the fit
            needs: the check is inconclusive (:attr:`conclusive`) and finds no problem.
        vertical_offset: right-image row minus left-image row of one scene point at the
            image centre, px (> 0: RIGHT shows things lower); None when inconclusive.
        rotation: rotation of RIGHT against LEFT about the image centre, degrees; None
            when inconclusive.
        vertical_worst: the largest |row difference| across the width, px: the offset
            plus, at the far edge, the rotation less :data:`ROTATION_PRECISION_DEG`; None
            when inconclusive.
        disparity: (low, high) robust percentiles (:data:`RANGE_PERCENTILES`) of the
            trusted matches' disparities ``x_left - x_right``, px; None when inconclusive.
        negative_share: share of the trusted matches with a disparity below
            ``-tolerance``, in [0, 1].
        outside_share: share of the trusted matches outside ``searched`` widened by the
            tolerance, in [0, 1].
        searched: the inclusive range checked against, px.
        suggested: a range holding the trusted matches, px (their percentiles widened by
            :func:`cade_cli.scale.range.range_margin`); None when inconclusive.
        factor: the downscale the pair was matched at (1, 2, 4, ...).
        problems: what is wrong, a subset of :data:`PROBLEMS` in that order; empty: nothing found.
    """

    matches: int
    vertical_offset: float | None
    rotation: float | None
    vertical_worst: float | None
    disparity: tuple[float, float] | None
    negative_share: float
    outside_share: float
    searched: tuple[int, int]
    suggested: tuple[int, int] | None
    factor: int
    problems: tuple[str, ...]

    @property
    def conclusive(self) -> bool:
        """Whether there were enough matches to judge the pair."""
        return self.vertical_offset is not None

    def describe(self) -> str:
        """One line for the user: what is wrong, the numbers measured, and the fix; "" when nothing is."""
        findings = []
        if "swapped" in self.problems:
            findings.append(f"{100 * self.negative_share:.0f}% of the {self.matches} feature matches have a negative "
                            f"disparity ({self.disparity[0]:+.1f}..{self.disparity[1]:+.1f} px): LEFT and RIGHT look "
                            "swapped; give the reference (left) image first")
        if "vertical" in self.problems:
            findings.append(f"the pair is not rectified: vertical offset {self.vertical_offset:+.2f} px, rotation "
                            f"{self.rotation:+.2f} deg (up to {self.vertical_worst:.1f} px across the width, "
                            f"{VERTICAL_TOLERANCE_PX} px tolerated); rectify it (cade rectify, or --rig RIG.json "
                            "--fix-vertical)")
        if "range" in self.problems:
            low, high = self.suggested
            findings.append(f"{100 * self.outside_share:.0f}% of the {self.matches} feature matches lie outside the "
                            f"searched range [{self.searched[0]}, {self.searched[1]}] px (they span "
                            f"{self.disparity[0]:.1f}..{self.disparity[1]:.1f} px); search --min-disp {low} "
                            f"--max-disp {high}, or --max-disp auto")
        return "pair check: " + "; ".join(findings) if findings else ""

    def summary(self) -> str:
        """A few words for a summary line: the vertical offset measured."""
        if not self.conclusive:
            return f"vertical offset unmeasured ({self.matches} feature matches)"
        return f"vertical offset {self.vertical_offset:+.2f} px"

    def record(self) -> dict:
        """JSON-ready fields for a record (px and degrees, shares in [0, 1])."""
        return {"vertical_offset_px": self.vertical_offset, "rotation_deg": self.rotation,
                "vertical_worst_px": self.vertical_worst, "matches": self.matches,
                "disparity_px": None if self.disparity is None else list(self.disparity),
                "negative_share": self.negative_share, "outside_share": self.outside_share,
                "problems": list(self.problems)}


MAX_HORIZONTAL_SHARE = 0.3
"""Features whose columns differ by more than this share of the width (or than the range
searched, widened by a quarter) are not matched: a scene's disparities stay well within it."""


def max_horizontal(width: int, min_disp: int, max_disp: int) -> float:
    """The largest |x_left - x_right| (px) a match may have: :data:`MAX_HORIZONTAL_SHARE` of
    ``width``, or the range searched widened by a quarter when that reaches further."""
    reach = max(abs(min_disp), abs(max_disp))
    return max(MAX_HORIZONTAL_SHARE * width, 1.25 * reach)


def check_factor(width: int, *, check_width: int = CHECK_WIDTH) -> int:
    """The largest power of two that keeps ``width`` (px) divided by it at least ``check_width``."""
    factor = 1
    while width / (2 * factor) >= check_width:
        factor *= 2
    return factor


def feature_count(width: int, height: int) -> int:
    """Features detected per band for a ``width`` x ``height`` pair: one per
    :data:`AREA_PER_FEATURE` px, between :data:`MIN_FEATURES` and :data:`FEATURES`."""
    return int(min(max(round(width * height / AREA_PER_FEATURE), MIN_FEATURES), FEATURES))


def gradient_band(band: np.ndarray) -> np.ndarray:
    """(H, W) uint8 colour-agnostic gradient image of a float32 band: the gradient magnitude
    (Gaussian sigma 1, Sobel) over its local mean (31 x 31 box), times 64; the same for a band
    and its inverse, and similar across spectral bands. The cheap form (cv2 only, no float64
    or NumPy temporaries) of :func:`cade_cli.matching.sparse.gradient_image`."""
    smooth = cv2.GaussianBlur(band, (0, 0), 1.0)
    magnitude = cv2.magnitude(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3),
                              cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3))
    local = cv2.blur(magnitude, (31, 31))
    local += 1e-3 * float(magnitude.max() + 1e-12)
    return cv2.divide(magnitude, local, scale=64, dtype=cv2.CV_8U)


def describe_band(band: np.ndarray, features: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Upright features of one band: ((N, 2) float64 (x, y) px, (N, 32) uint8 ORB descriptors or
    None, its :func:`gradient_band`).

    The :data:`features` FAST corners (threshold :data:`FAST_THRESHOLD`) with the strongest
    Harris response on the gradient image, each described by ORB's binary test pattern at
    angle 0: a rectified pair's views are not rotated against each other, so steering the
    pattern by each corner's own orientation (ORB's default) only adds wrong matches, the
    more so between spectral bands where the orientation of a corner is unstable."""
    gradient = gradient_band(band)
    finder = cv2.ORB_create(nfeatures=features, nlevels=1, fastThreshold=FAST_THRESHOLD, edgeThreshold=PATCH_SIZE,
                            patchSize=PATCH_SIZE)
    keys = finder.detect(gradient, None)
    for key in keys:
        key.angle = 0.0
    keys, descriptors = finder.compute(gradient, keys)
    if descriptors is None or len(keys) < 2:
        return np.zeros((0, 2)), None, gradient
    return cv2.KeyPoint_convert(keys).astype(np.float64), descriptors, gradient


_POOL: ThreadPoolExecutor | None = None


def band_features(left: np.ndarray, right: np.ndarray, *, features: int):
    """:func:`describe_band` of both bands: ((points, descriptors) left, (...) right, (gradient
    images)). With OpenCV allowed two threads or more (``cv2.getNumThreads``, as the matchers
    are), the two bands are processed side by side."""
    global _POOL
    if cv2.getNumThreads() >= 2:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="cade-pair-check")
        pending = _POOL.submit(describe_band, right, features)
        found_left, found_right = describe_band(left, features), pending.result()
    else:
        found_left, found_right = describe_band(left, features), describe_band(right, features)
    return found_left[:2], found_right[:2], (found_left[2], found_right[2])


MATCH_RATIO = 0.8
"""Lowe's ratio test: the best candidate's Hamming distance below this share of the second's."""


def match_features(points_left: np.ndarray, desc_left: np.ndarray | None, points_right: np.ndarray,
                   desc_right: np.ndarray | None, *, max_vertical: float,
                   max_horizontal: float) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours by Hamming distance that pass the ratio test, among the
    features whose rows differ by at most ``max_vertical`` px and columns by at most
    ``max_horizontal`` px (only those distances are computed: ``cv2.batchDistance`` with a
    mask). Returns (points_left, points_right), (N, 2) each."""
    if desc_left is None or desc_right is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    left32, right32 = points_left.astype(np.float32), points_right.astype(np.float32)
    allowed = ((np.abs(left32[:, 1:2] - right32[:, 1]) <= max_vertical)
               & (np.abs(left32[:, 0:1] - right32[:, 0]) <= max_horizontal)).view(np.uint8)
    distance, nearest = cv2.batchDistance(desc_left, desc_right, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2,
                                          mask=allowed)
    _, back = cv2.batchDistance(desc_right, desc_left, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=1,
                                mask=np.ascontiguousarray(allowed.T))
    best, back = nearest[:, 0], back[:, 0]
    keep = (nearest[:, 1] >= 0) & (best >= 0) & (distance[:, 0] < MATCH_RATIO * distance[:, 1])
    keep[keep] = back[best[keep]] == np.flatnonzero(keep)
    return points_left[keep], points_right[best[keep]]


def check_pair(left: np.ndarray, right: np.ndarray, *, min_disp: int = 0, max_disp: int) -> PairCheck:
    """Test a pair before matching it: vertical alignment, order, and the range searched.

    Args:
        left, right: (H, W) float bands of the pair as they will be matched, any range;
            they may come from different spectral filters.
        min_disp, max_disp: the inclusive range that will be searched, px.

    Returns:
        :class:`PairCheck`. Its ``problems`` name what was found; an inconclusive check
        (too few matches) finds nothing.

    Raises:
        CadeError: bands of different shapes, or not (H, W).
    """
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    if left.ndim != 2 or left.shape != right.shape:
        raise CadeError(f"the pair check needs two (H, W) bands of one size, got {left.shape} and {right.shape}")
    height, width = left.shape
    factor = check_factor(width)
    if factor > 1:
        size = (max(8, round(width / factor)), max(8, round(height / factor)))
        left, right = (cv2.resize(band, size, interpolation=cv2.INTER_AREA) for band in (left, right))
    scale_x, scale_y = width / left.shape[1], height / left.shape[0]
    max_vertical = max(MAX_VERTICAL_SHARE * width, MIN_MAX_VERTICAL_PX)
    features = feature_count(width, height)
    (points_left, desc_left), (points_right, desc_right), (gradient_left, gradient_right) = band_features(
        left, right, features=features)
    points_left, points_right = match_features(points_left, desc_left, points_right, desc_right,
                                               max_vertical=max_vertical / scale_y,
                                               max_horizontal=max_horizontal(width, min_disp, max_disp) / scale_x)
    row_shift = subpixel_row_shift(gradient_left, gradient_right, points_left, points_right)
    points_left, points_right = points_left * (scale_x, scale_y), points_right * (scale_x, scale_y)
    dy = points_right[:, 1] + row_shift * scale_y - points_left[:, 1]
    disparities = points_left[:, 0] - points_right[:, 0]
    searched = (int(min_disp), int(max_disp))
    near = dominant_line(points_left[:, 0], dy, width=width, band=LINE_BAND_PX)
    try:
        found, inliers = fit_vertical_misalignment(points_left[near, 0], dy[near], size=(width, height),
                                                   min_band=LINE_BAND_PX / 2, min_roll_matches=MIN_ROLL_MATCHES)
        if found.matches < MIN_MATCHES:
            raise CadeError("too few matches")
    except CadeError:  # too few matches: nothing to judge
        return PairCheck(int(near.sum()), None, None, None, None, 0.0, 0.0, searched, None, factor, ())
    trusted = disparities[near][inliers]
    tolerance = DISPARITY_TOLERANCE_PX * scale_x
    negative_share = float(np.mean(trusted < -tolerance))
    outside_share = float(np.mean((trusted < min_disp - tolerance) | (trusted > max_disp + tolerance)))
    low, high = (float(v) for v in np.percentile(trusted, RANGE_PERCENTILES))
    margin = range_margin(low, high, factor)
    suggested = (max(0, math.floor(low - margin)) if low >= 0 else math.floor(low - margin),
                 max(1, math.ceil(high + margin)))
    rotation = math.degrees(found.roll)
    beyond_precision = math.copysign(max(abs(rotation) - ROTATION_PRECISION_DEG, 0.0), rotation)
    worst = max(abs(found.offset + math.tan(math.radians(beyond_precision)) * dx) for dx in (-width / 2, width / 2))
    swapped = min_disp >= 0 and negative_share > SWAPPED_SHARE
    problems = tuple(name for name, found_it in (("swapped", swapped), ("vertical", worst >= VERTICAL_TOLERANCE_PX),
                                                 ("range", not swapped and outside_share > RANGE_MISS_SHARE))
                     if found_it)
    return PairCheck(matches=found.matches, vertical_offset=found.offset, rotation=rotation,
                     vertical_worst=worst, disparity=(low, high), negative_share=negative_share,
                     outside_share=outside_share, searched=searched, suggested=suggested, factor=factor,
                     problems=problems)


def dominant_line(x: np.ndarray, dy: np.ndarray, *, width: int, band: float = 1.0) -> np.ndarray:
    """The matches on the line ``dy = offset + tan(rotation) (x - cx)`` that most matches lie near.

    Every rotation from -:data:`MAX_ROTATION_DEG` to +:data:`MAX_ROTATION_DEG` degrees in
    steps of :data:`ROTATION_STEP_DEG` is tried; for each, the offsets are binned (1 px)
    and the most populated window of three bins wins. A pair's true matches lie on one
    line, its wrong matches spread over every row difference.

    Args:
        x: (N,) column of each match in the left image, px.
        dy: (N,) right row minus left row of each match, px.
        width: image width, px (the rotation turns about its centre column).
        band: half-width of the window kept around the winning line, px.

    Returns:
        (N,) bool, True for the matches within ``band`` px of the winning line.
    """
    x, dy = np.asarray(x, np.float64), np.asarray(dy, np.float64)
    if not len(dy):
        return np.zeros(0, bool)
    angles = np.arange(-MAX_ROTATION_DEG, MAX_ROTATION_DEG + 1e-9, ROTATION_STEP_DEG)
    angles = angles[np.argsort(np.abs(angles), kind="stable")]  # ties go to the smaller rotation
    residuals = dy[None, :] - np.tan(np.radians(angles))[:, None] * (x - (width - 1) / 2)[None, :]  # (A, N)
    bins = np.floor(residuals).astype(np.int64)
    lowest = int(bins.min()) - 1
    span = int(bins.max()) - lowest + 2
    counts = np.bincount((bins - lowest + span * np.arange(len(angles))[:, None]).ravel(),
                         minlength=span * len(angles)).reshape(len(angles), span)
    windows = counts.copy()
    windows[:, 1:] += counts[:, :-1]
    windows[:, :-1] += counts[:, 1:]
    windows[counts == 0] = -1  # a window is centred on a bin that holds matches
    best, peak = np.unravel_index(int(np.argmax(windows)), windows.shape)  # the first: smallest rotation, then offset
    return np.abs(residuals[best] - (peak + lowest + 0.5)) <= band


SUBPIXEL_HALF_WINDOW = 4
"""Half-size of the patches :func:`subpixel_row_shift` compares: 9 x 9 px."""


def subpixel_row_shift(left: np.ndarray, right: np.ndarray, points_left: np.ndarray,
                       points_right: np.ndarray) -> np.ndarray:
    """Sub-pixel correction of the right rows of matches: the normalised cross-correlation
    of the left patch with right patches from two rows above to two rows below the match,
    and the vertex of a parabola through its peak (within one row of the match) and the
    rows either side.

    Args:
        left, right: (H, W) images the points were found on (e.g. :func:`gradient_band`).
        points_left, points_right: (N, 2) (x, y) px of the matches, whole pixels.

    Returns:
        (N,) float64 in [-1.5, 1.5] px, to add to the right rows; 0 where a patch leaves the
        image or the correlation has no peak near the match.
    """
    half, reach = SUBPIXEL_HALF_WINDOW, 2
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    shift = np.zeros(len(points_left))
    if not len(points_left):
        return shift
    (xl, yl), (xr, yr) = (np.rint(points.T).astype(np.int64) for points in (points_left, points_right))
    height, width = left.shape
    inside = ((np.minimum(xl, xr) >= half) & (np.maximum(xl, xr) < width - half)
              & (np.minimum(yl, yr) >= half + reach) & (np.maximum(yl, yr) < height - half - reach))
    if not inside.any():
        return shift
    offsets = np.arange(-half, half + 1)
    rows, cols = offsets[None, :, None], offsets[None, None, :]

    def patches(image, x, y):
        values = image[y[:, None, None] + rows, x[:, None, None] + cols].reshape(len(x), -1)
        values = values - values.mean(axis=1, keepdims=True)
        return values / (np.linalg.norm(values, axis=1, keepdims=True) + 1e-6)

    reference = patches(left, xl[inside], yl[inside])
    scores = np.stack([np.sum(reference * patches(right, xr[inside], yr[inside] + step), axis=1)
                       for step in range(-reach, reach + 1)], axis=1)  # (M, 5): rows -2..2
    peak = 1 + np.argmax(scores[:, 1:4], axis=1)  # column of the best of rows -1, 0, 1
    index = np.arange(len(peak))
    below, centre, above = scores[index, peak - 1], scores[index, peak], scores[index, peak + 1]
    curvature = below - 2 * centre + above
    peaked = (centre >= below) & (centre >= above) & (curvature < 0)
    vertex = np.where(peaked, 0.5 * (below - above) / np.where(peaked, curvature, -1.0), 0.0)
    shift[inside] = np.where(peaked, peak - reach + np.clip(vertex, -0.5, 0.5), 0.0)
    return shift
