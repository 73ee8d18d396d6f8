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

from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.pair_features import describe_band, gradient_band, match_features

MIN_MATCHES = 12
"""Fewer matches than this: no plane is fitted (the rotation alone stays)."""
PLANE_THRESHOLD = 1.5
"""RANSAC reprojection threshold of the plane homography, px."""
LINE_TOLERANCE = 1.0
"""A match lies on a parallax direction when its residual is within this many px of the line."""
DIRECTION_STEP_DEG = 0.5
CHEAP_PARALLAX = 0.3
"""Below this parallax (px, each way from the plane, robust extremes of the matches) the band
is registered by the plane homography alone: a high flight."""


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
    """The parallax a plane homography leaves between a band and the reference.

    Attributes:
        baseline: (2,) unit vector (x right, y down): the band's lens lies that way from the
            reference's, so a point nearer than the plane at reference pixel p is seen by the
            band at ``p - d·baseline`` with d > 0 (the project's ``I_left(x) ≈ I_right(x − d)``
            once the baseline is turned to +x).
        low, high: robust extremes (1st and 99th percentiles) of d over the matches, px.
        matches: how many matches measured it.
        measured: False when the matches show no parallax direction (the plane explains them).
    """

    baseline: np.ndarray
    low: float
    high: float
    matches: int
    measured: bool

    @property
    def negligible(self) -> bool:
        """True when the parallax stays within :data:`CHEAP_PARALLAX` px of the plane everywhere."""
        return not self.measured or max(abs(self.low), abs(self.high)) < CHEAP_PARALLAX


def _direction(residuals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The direction most residual vectors lie along (those longer than the tolerance vote):
    ((2,) unit vector, (N,) bool on the line)."""
    length = np.hypot(residuals[:, 0], residuals[:, 1])
    voters = length > 2 * LINE_TOLERANCE
    angles = np.radians(np.arange(0, 180, DIRECTION_STEP_DEG))
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (A, 2)
    across = np.abs(residuals[voters] @ np.stack([-directions[:, 1], directions[:, 0]], axis=1).T)  # (V, A)
    best = directions[int(np.argmax((across <= LINE_TOLERANCE).sum(axis=0)))]
    on_line = np.abs(residuals @ np.array([-best[1], best[0]])) <= LINE_TOLERANCE
    support = residuals[on_line & voters]
    if len(support) >= 3:  # refine: the principal axis of the supporting residuals
        _, vectors = np.linalg.eigh(support.T @ support)
        best = vectors[:, -1] * np.sign(vectors[:, -1] @ best)
        on_line = np.abs(residuals @ np.array([-best[1], best[0]])) <= LINE_TOLERANCE
    return best, on_line


def measure_parallax(points_reference: np.ndarray, points_band: np.ndarray, homography: np.ndarray,
                     *, min_support: int = 8) -> Parallax:
    """The parallax direction and range of a band from its matches with the reference.

    The residual of each match is taken in the reference frame (the band point mapped back
    by ``homography``, minus the reference point). The direction most residuals lie along is
    the baseline's; its sign makes the parallax relative to the rotation alone (the
    homography's identity: points at infinity) positive, i.e. nearer points have larger d.

    Args:
        points_reference, points_band: (N, 2) matches in the common frame.
        homography: (3, 3) reference px -> band px (:func:`plane_from_matches`).
        min_support: fewer matches off the plane along one direction than this: no parallax.
    """
    if len(points_reference) == 0:
        return Parallax(np.array([1.0, 0.0]), 0.0, 0.0, 0, False)
    back = cv2.perspectiveTransform(points_band.reshape(-1, 1, 2), np.linalg.inv(homography)).reshape(-1, 2)
    residuals = back - points_reference
    direction, on_line = _direction(residuals)
    off_plane = on_line & (np.hypot(residuals[:, 0], residuals[:, 1]) > 2 * LINE_TOLERANCE)
    if off_plane.sum() < min_support:
        along = -(residuals[on_line] @ direction)
        low, high = (np.percentile(along, [1, 99]) if len(along) else (0.0, 0.0))
        return Parallax(direction, float(low), float(high), int(on_line.sum()), False)
    # Sign: the displacement relative to the rotation alone (the common frame, no homography) is
    # -d·baseline with d >= 0 for every point in front of the camera.
    raw = points_band - points_reference
    if np.median(raw[on_line] @ direction) > 0:
        direction = -direction
    along = -(residuals[on_line] @ direction)
    low, high = np.percentile(along, [1, 99])
    return Parallax(direction, float(low), float(high), int(on_line.sum()), True)
