"""What is left between a band and the reference once both are in the common pinhole frame
(undistorted, lens rotation applied): robust cross-spectral sparse matches, the plane
homography they fit (``--plane-only``, and the start of the parallax step), and the direction
and range of the parallax the homography leaves (the lens translations are not in the files).

After the rotation, a scene point at depth Z is displaced between two lenses a few cm apart by
``f·t/Z``: along one direction (the baseline, the epipole at infinity), by an amount that
depends on depth. After the plane homography the displacement is still along that direction,
signed (before or behind the plane). :func:`measure_parallax` finds it from the matches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from cade_cli.pair_features import describe_band, gradient_band, match_features

MIN_MATCHES = 12
"""Fewer matches than this: no plane is fitted (the rotation alone stays)."""
PLANE_THRESHOLD = 1.5
"""RANSAC reprojection threshold of the plane homography, px."""
LINE_TOLERANCE = 0.5
"""A match lies on a parallax direction when its residual is within this many px of the line
(the refined matches are good to about a tenth of a pixel)."""
MIN_OFF_PLANE = 1.0
"""Matches whose residual from the plane is longer than this (px) show the parallax's direction."""
DIRECTION_STEP_DEG = 0.5
CHEAP_PARALLAX = 0.3
"""Below this parallax (px, each way from the plane, beyond the matches' noise: :func:`off_plane`)
the band is registered by the plane homography alone: a high flight."""


MATCH_SCALE = 0.5
"""Features are found on the bands downscaled by this (area averaging): matching cost, and the
gradient features of the blurrier bands agree better."""
FEATURES = 2500
"""The most features per band."""
MATCH_REACH = 64
"""Two features are candidates only when their rows and their columns differ by at most this
many px of the downscaled bands (:data:`MATCH_SCALE`): the lens rotation is compensated, what
is left is the parallax (tens of px at close range) and the plane's residual."""


Features = tuple[np.ndarray, np.ndarray | None]


def band_features(band: np.ndarray) -> Features:
    """Upright ORB features on the gradient image of ``band`` (H, W) at :data:`MATCH_SCALE`
    (:func:`~cade_cli.pair_features.describe_band`): ((N, 2) (x, y) px of the full-size band,
    descriptors)."""
    values = np.nan_to_num(np.asarray(band, np.float32))
    small = cv2.resize(values, None, fx=MATCH_SCALE, fy=MATCH_SCALE, interpolation=cv2.INTER_AREA)
    points, descriptors, _ = describe_band(small, FEATURES)
    return (points + 0.5) / MATCH_SCALE - 0.5, descriptors


def cross_spectral_matches(reference: np.ndarray | Features, band: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mutual matches of :func:`band_features` (Hamming distance, ratio test, within
    :data:`MATCH_REACH`: :func:`~cade_cli.pair_features.match_features`) between two bands in
    one frame. ``reference`` may be its :func:`band_features` already. Returns ((N, 2), (N, 2))
    (x, y) px of the reference and the band."""
    found_reference = band_features(reference) if isinstance(reference, np.ndarray) else reference
    found_band = band_features(band)
    reach = MATCH_REACH / MATCH_SCALE
    return match_features(*found_reference, *found_band, max_vertical=reach, max_horizontal=reach)


REFINE_HALF = 7
"""Half-size of the patches :func:`refine_matches` correlates: 15 x 15 px."""
REFINE_REACH = 3
"""How far (px) :func:`refine_matches` searches around a match, each way."""
MIN_CORRELATION = 0.6
"""A refined match whose patches correlate less than this is dropped."""


def refine_matches(reference: np.ndarray, band: np.ndarray, points_reference: np.ndarray,
                   points_band: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Matches brought to sub-pixel on the full-size gradient images: the reference patch
    (:data:`REFINE_HALF`) correlated (normalised) with the band within :data:`REFINE_REACH` px of
    the match, and a parabola through the peak and its neighbours in x and in y. Matches whose
    peak is weak (:data:`MIN_CORRELATION`), at the edge of the search or whose patches leave
    an image are dropped. Returns the kept (reference, band) points, (M, 2) each."""
    left = gradient_band(np.nan_to_num(np.asarray(reference, np.float32))).astype(np.float32)
    right = gradient_band(np.nan_to_num(np.asarray(band, np.float32))).astype(np.float32)
    half, reach = REFINE_HALF, REFINE_REACH
    height, width = left.shape
    kept_reference, kept_band = [], []
    for (xl, yl), (xr, yr) in zip(np.rint(points_reference).astype(int), np.rint(points_band).astype(int)):
        if not (half <= xl < width - half and half <= yl < height - half
                and half + reach <= xr < width - half - reach and half + reach <= yr < height - half - reach):
            continue
        template = left[yl - half:yl + half + 1, xl - half:xl + half + 1]
        window = right[yr - half - reach:yr + half + reach + 1, xr - half - reach:xr + half + reach + 1]
        if template.std() < 1e-3:
            continue
        scores = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
        row, column = np.unravel_index(int(np.argmax(scores)), scores.shape)
        if scores[row, column] < MIN_CORRELATION or not (0 < row < 2 * reach and 0 < column < 2 * reach):
            continue
        dx = _vertex(scores[row, column - 1:column + 2])
        dy = _vertex(scores[row - 1:row + 2, column])
        kept_reference.append((xl, yl))
        kept_band.append((xr + column - reach + dx, yr + row - reach + dy))
    if not kept_reference:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.float64(kept_reference), np.float64(kept_band)


def _vertex(values: np.ndarray) -> float:
    """Offset in [-0.5, 0.5] of the peak of a parabola through three samples."""
    curvature = values[0] - 2 * values[1] + values[2]
    return float(np.clip(0.5 * (values[0] - values[2]) / curvature, -0.5, 0.5)) if curvature < 0 else 0.0


def plane_from_matches(points_reference: np.ndarray, points_band: np.ndarray, *,
                       init: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The homography (3, 3) reference px -> band px that most matches agree with (RANSAC,
    :data:`PLANE_THRESHOLD`), and its (N,) bool inliers; ``init`` (identity when None) when
    the matches are too few to fit one."""
    fallback = np.eye(3) if init is None else np.asarray(init, np.float64)
    if len(points_reference) < MIN_MATCHES:
        return fallback, np.zeros(len(points_reference), bool)
    homography, inliers = cv2.findHomography(points_reference, points_band, cv2.RANSAC, PLANE_THRESHOLD,
                                             maxIters=4000, confidence=0.999)
    if homography is None or inliers.sum() < MIN_MATCHES:
        return fallback, np.zeros(len(points_reference), bool)
    return homography / homography[2, 2], inliers.ravel().astype(bool)


def plane_homography(reference: np.ndarray, band: np.ndarray, *, init: np.ndarray | None = None) -> np.ndarray:
    """The one homography per band (the anchors' model): (3, 3) float64 mapping reference px to
    band px, fitted by RANSAC to robust cross-spectral sparse matches (:func:`cross_spectral_matches`).

    Args:
        reference, band: (H, W) float bands in one frame (undistorted, the lens rotation
            applied), any units.
        init: a starting homography, returned when the matches are too few (identity when None).
    """
    return plane_from_matches(*cross_spectral_matches(reference, band), init=init)[0]


@dataclass(frozen=True)
class Parallax:
    """The parallax between a band (its lens rotation applied) and the reference.

    The band sees the scene point at reference pixel p at ``p + across(p)·normal − d(p)·baseline``
    in the common frame: ``d`` is the parallax (px, larger for nearer points, 0 at infinity)
    and ``across`` a small affine field across the baseline (what the lens rotations in the
    files leave: a fraction of a pixel to a few).

    Attributes:
        baseline: (2,) unit vector (x right, y down): the band's lens lies that way from the
            reference's (the project's ``I_left(x) ≈ I_right(x − d)`` once it is turned to +x).
        across: (3,) coefficients (a, b, c) of ``across(x, y) = a + b·x + c·y``, px.
        low, high: robust extremes (1st and 99th percentiles) of d over the matches, px.
        spread: how far the plane homography alone is off along the baseline, px, beyond
            the matches' noise (:func:`off_plane`).
        matches: how many matches measured it.
    """

    baseline: np.ndarray
    across: np.ndarray
    low: float
    high: float
    spread: float
    matches: int

    @property
    def normal(self) -> np.ndarray:
        """(2,) unit vector across the baseline."""
        return np.array([-self.baseline[1], self.baseline[0]])

    @property
    def negligible(self) -> bool:
        """True when the plane leaves less than :data:`CHEAP_PARALLAX` px: the cheap path."""
        return self.spread < CHEAP_PARALLAX

    def across_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``across(x, y)``, px, float32 of the shape of ``x``."""
        a, b, c = self.across
        return (a + b * np.asarray(x, np.float64) + c * np.asarray(y, np.float64)).astype(np.float32)


def _fit_across(points: np.ndarray, across: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Least-squares (a, b, c) of ``across ≈ a + b x + c y`` for every column of ``across``
    (N, A) over the rows ``keep`` (N, A) marks, all columns at once (normal equations):
    (3, A); zeros for a column with fewer than three rows."""
    design = np.stack([np.ones(len(points)), points[:, 0], points[:, 1]], axis=1)
    weights = keep.astype(np.float64)
    normal = np.einsum("na,nj,nk->ajk", weights, design, design)  # (A, 3, 3)
    right = np.einsum("na,nj->aj", weights * across, design)  # (A, 3)
    enough = keep.sum(axis=0) >= 3
    normal[~enough] = np.eye(3)
    right[~enough] = 0
    scale = np.array([1.0, 1e-3, 1e-3])  # columns in px are ~1e3 times the constant: condition the solve
    solved = np.linalg.solve(normal * scale[None, :, None] * scale[None, None, :], (right * scale)[..., None])[..., 0]
    return (solved * scale).T


SUPPORT_SHARE = 0.9
"""Directions whose fit keeps at least this share of the best one's matches are equally good;
of those the one with the smallest across offset (at the matches' centre) is taken."""


def _best_direction(points: np.ndarray, raw: np.ndarray, angles: np.ndarray,
                    keep: np.ndarray | None = None) -> tuple[int, np.ndarray, np.ndarray]:
    """Of ``angles`` (radians), the index of the best direction, its across fit (3,) and its
    supporting matches (N,) bool: the affine across each direction is fitted to the matches
    near its median (or ``keep``, (N, A)), then to those within :data:`LINE_TOLERANCE`; of the
    directions supported by :data:`SUPPORT_SHARE` of the most, the one whose across field is
    smallest at the matches' centre (what the lens rotations in the files say comes first: a
    scene at one depth leaves the direction and a constant offset undecided)."""
    normals = np.stack([-np.sin(angles), np.cos(angles)], axis=1)  # (A, 2)
    design = np.stack([np.ones(len(points)), points[:, 0], points[:, 1]], axis=1)
    across = raw @ normals.T  # (N, A)
    if keep is None:
        keep = np.abs(across - np.median(across, axis=0)) <= 4 * LINE_TOLERANCE
    for _ in range(2):
        fits = _fit_across(points, across, keep)
        keep = np.abs(across - design @ fits) <= LINE_TOLERANCE
    support = keep.sum(axis=0)
    centre = np.array([1.0, *points.mean(axis=0)]) @ fits  # (A,)
    candidates = np.flatnonzero(support >= SUPPORT_SHARE * support.max())
    best = int(candidates[np.argmin(np.abs(centre[candidates]))])
    return best, fits[:, best], keep[:, best]


def fit_direction(points: np.ndarray, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The baseline direction and across field that most displacements (``raw``, (N, 2), of the
    rotation alone, at reference ``points``) fit (:func:`_best_direction`): every direction in
    steps of :data:`DIRECTION_STEP_DEG`, then a tenth of that around the best. Returns
    (direction (2,), across (3,), (N,) bool supporting)."""
    angles = np.radians(np.arange(0, 360, DIRECTION_STEP_DEG))
    best, _, supporting = _best_direction(points, raw, angles)
    fine = angles[best] + np.radians(np.linspace(-DIRECTION_STEP_DEG, DIRECTION_STEP_DEG, 21))
    chosen, across, supporting = _best_direction(points, raw, fine, np.repeat(supporting[:, None], len(fine), axis=1))
    return np.array([np.cos(fine[chosen]), np.sin(fine[chosen])]), across, supporting


TURN_SIGNIFICANCE = 7.0
"""The direction :func:`fit_direction` chose is turned (:func:`across_slope`) only when the
matches' across residuals rise with their parallax by at least this many standard errors of
that slope: a scene at one depth (no spread of parallax) leaves the slope undecided, and the
direction as chosen. Not 3-5: the least-squares error takes the matches' errors as independent,
and they are not quite (what the affine across field leaves varies over the image). On the two
bench captures (one rig, so one direction per band) the turns at 9-72 errors agree to 0.5 deg
(Red 88.8 and 88.8, NIR 34.9 and 35.4, Red edge 34.7 and 34.9 deg; chosen before: 90.7 and 91.3,
39.0 and 42.8, 43.0 and 44.3); Blue's slope, 6.3 errors on IMG_0001 and 0.5 on IMG_0007, would
have turned one capture's Blue 0.8 deg away from the other's (docs/drone.md, "The parallax
direction from the matches' spread (2026-12-06)")."""


TURNS = 6
"""At most this many turns (:func:`across_slope`): each refits the across field and the matches
that support it (those within :data:`LINE_TOLERANCE` of a direction off by k miss the nearest
matches, so one turn falls short)."""


def across_slope(points: np.ndarray, raw: np.ndarray, direction: np.ndarray, field: np.ndarray) -> float:
    """k of the least-squares ``raw·normal ≈ a + b·x + c·y + k·d`` over the matches (``points``
    (N, 2), their displacements ``raw`` (N, 2); d = −raw·direction, the parallax) within
    4 × :data:`LINE_TOLERANCE` of the across field ``field`` (a, b, c) of ``direction``, then
    within 3 sigma of the fit (the matches that support a direction off by k, within
    :data:`LINE_TOLERANCE`, would leave out the ones k moves most and bias k to 0): how many px
    across the baseline each px of parallax moves a point, so that the true baseline is
    ``direction − k·normal`` (turned by −atan k). 0 where k is within :data:`TURN_SIGNIFICANCE`
    standard errors of 0. A direction that is off by some degrees shows only here: the across
    field absorbs it at the matches' own parallax, but a point d px nearer lies about k·d px
    off the searched line (IMG_0007's Red edge: k = 0.165, the direction 9.4 deg off, so 5 px
    across at a cable 30 px of parallax nearer than the matches; docs/drone.md, "The parallax
    direction from the matches' spread (2026-12-06)")."""
    normal = np.array([-direction[1], direction[0]])
    along, across = -(raw @ direction), raw @ normal
    design = np.stack([np.ones(len(points)), points[:, 0] * 1e-3, points[:, 1] * 1e-3, along], axis=1)
    keep = np.abs(across - design[:, :3] @ (np.asarray(field) * [1.0, 1e3, 1e3])) <= 4 * LINE_TOLERANCE
    for _ in range(3):  # again without the outliers of each fit
        if keep.sum() < 8:
            return 0.0
        coefficients, *_ = np.linalg.lstsq(design[keep], across[keep], rcond=None)
        residual = across - design @ coefficients
        sigma = float(np.sqrt(np.mean(residual[keep] ** 2)))
        keep = np.abs(residual) <= max(3 * sigma, 1e-6)
    inverse = np.linalg.pinv(design[keep].T @ design[keep])
    error = sigma * math.sqrt(max(float(inverse[3, 3]), 0.0))
    slope = float(coefficients[3])
    return slope if abs(slope) >= TURN_SIGNIFICANCE * error and error > 0 else 0.0


def measure_parallax(points_reference: np.ndarray, points_band: np.ndarray, homography: np.ndarray) -> Parallax:
    """The parallax direction, range and across field of a band from its matches with the
    reference (in the common frame, the band's lens rotation applied), and how far the plane
    ``homography`` (reference px -> band px, :func:`plane_from_matches`) is off.

    The lens translations are not in the files, so a scene point is displaced from the
    reference to the band by ``d·(−baseline)`` with d the larger the nearer the point: the
    displacements of the matches lie along one line, up to what the lens rotations leave
    (the across field). :func:`fit_direction` finds it; the sign makes d >= 0; then it is
    turned as long as the matches' across residuals still rise with their parallax
    (:func:`across_slope`, at most :data:`TURNS` times).
    """
    if len(points_reference) < MIN_MATCHES:
        return Parallax(np.array([1.0, 0.0]), np.zeros(3), 0.0, 0.0, 0.0, len(points_reference))
    raw = points_band - points_reference
    direction, across, supporting = fit_direction(points_reference, raw)
    if np.median(raw[supporting] @ direction) > 0:
        direction, across = -direction, -across  # the normal turns with the direction
    for _ in range(TURNS):  # the matches' spread of parallax shows the direction off: turn it, refit the across
        slope = across_slope(points_reference, raw, direction, across)
        if not slope:
            break
        turned = direction - slope * np.array([-direction[1], direction[0]])
        angle = np.array([math.atan2(turned[1], turned[0])])
        _, across, supporting = _best_direction(points_reference, raw, angle, supporting[:, None])
        direction = np.array([math.cos(angle[0]), math.sin(angle[0])])
    along = -(raw[supporting] @ direction)
    low, high = np.percentile(along, [1, 99])
    back = cv2.perspectiveTransform(points_band.reshape(-1, 1, 2), np.linalg.inv(homography)).reshape(-1, 2)
    parallax = Parallax(direction, across, float(low), float(high), 0.0, int(supporting.sum()))
    points = points_reference[supporting]
    noise = raw[supporting] @ parallax.normal - parallax.across_at(points[:, 0], points[:, 1])
    return replace(parallax, spread=off_plane((back - points_reference)[supporting] @ direction, noise))


def _half_spread(values: np.ndarray) -> float:
    """Half the distance between the 2.5th and 97.5th percentiles of ``values``."""
    low, high = np.percentile(values, [2.5, 97.5])
    return float(high - low) / 2


def off_plane(along: np.ndarray, noise: np.ndarray) -> float:
    """How far (px, each way) the plane leaves the scene along the baseline, beyond the
    matches' own noise: ``along`` (N,), the matches' residuals from the plane along the
    baseline, spread by parallax and noise; ``noise`` (M,), their residuals across the
    baseline from the parallax model's across field, spread by noise alone. With each spread
    the half distance between the 2.5th and 97.5th percentiles (a few near objects count: the
    5th-95th missed the near objects of a bench capture), the parallax's share is
    ``sqrt(max(along^2 - noise^2, 0))``. The cross-spectral matches of the nearly planar field
    capture spread by 0.3-0.4 px either way, which alone would pass :data:`CHEAP_PARALLAX`:
    beyond that noise, 0.00-0.27 px there, 0.45-8 px on the bench captures (docs/drone.md)."""
    spread, floor = _half_spread(along), _half_spread(noise)
    return float(np.sqrt(max(spread * spread - floor * floor, 0.0)))
