"""The pair check's measurements (:mod:`cade_cli.pair_check`): upright ORB features on gradient
bands, as many as the pair's area asks, matched within a band of rows and columns; the line the
row differences follow (a vertical offset and a roll), refined to sub-pixel.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np


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

MAX_ROTATION_DEG = 3.0

ROTATION_STEP_DEG = 0.2
"""Rotations voted for: -3..3 degrees in steps of 0.2 (1.25 px at the edge of a 718 px wide image)."""

MAX_HORIZONTAL_SHARE = 0.3
"""Features whose columns differ by more than this share of the width (or than the range
searched, widened by a quarter) are not matched: a scene's disparities stay well within it."""


def max_horizontal(width: int, min_disp: int, max_disp: int) -> float:
    """The largest |x_left - x_right| (px) a match may have: :data:`MAX_HORIZONTAL_SHARE` of
    ``width``, or the range searched widened by a quarter when that reaches further."""
    reach = max(abs(min_disp), abs(max_disp))
    return max(MAX_HORIZONTAL_SHARE * width, 1.25 * reach)


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
