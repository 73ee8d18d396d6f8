"""Sparse feature matches between two bands: keypoints on gradient magnitude (the same for a
band and its inverse, and similar across spectral bands), matched by descriptor. The rig
self-check (:mod:`cade_cli.rigs.self_check`) and the pair check (:mod:`cade_cli.pair_check`)
fit their vertical offset and roll to these.
"""

from __future__ import annotations

import cv2
import numpy as np


def gradient_image(band: np.ndarray) -> np.ndarray:
    """(H, W) uint8 gradient magnitude of a band (Gaussian sigma 1, Sobel), divided by its
    local mean (31x31 box) and scaled: the same for a band and its inverse, and similar
    across bands that see the same edges with different contrasts."""
    values = np.asarray(band, np.float32)
    smooth = cv2.GaussianBlur(values, (0, 0), 1.0)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.sqrt(gx * gx + gy * gy)
    local = cv2.blur(magnitude, (31, 31)) + 1e-3 * float(magnitude.max() + 1e-12)
    normalised = magnitude / local
    return np.clip(normalised * 64, 0, 255).astype(np.uint8)


FEATURE_DETECTORS = ("sift", "orb")
"""Detectors :func:`sparse_matches` offers: ``sift`` (precise, the rig self-check's) and
``orb`` (about ten times cheaper, the pair check's: :mod:`cade_cli.pair_check`)."""


def sparse_matches(left: np.ndarray, right: np.ndarray, *, detector: str = "sift", features: int = 4000,
                   max_vertical: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sparse feature matches between two bands that may come from different filters.

    Features are detected on :func:`gradient_image` of each band (so a contrast inversion
    or a different response of the filters matters little) and matched mutually, with
    Lowe's ratio test (0.8): :func:`gradient_matches`.

    Args:
        left, right: (H, W) float bands, any range; sizes may differ.
        detector: ``sift`` (float descriptors, L2) or ``orb`` (binary, Hamming, one
            scale: the two views of a pair share their scale), :data:`FEATURE_DETECTORS`.
        features: the most features detected per band.
        max_vertical: only features whose rows differ by at most this many px are
            candidates (and compete in the ratio test); None: any two.

    Returns:
        (points_left, points_right): (N, 2) float64 (x, y) px of the N matches, in the
        pixels of each band; N may be 0.
    """
    return gradient_matches(gradient_image(left), gradient_image(right), detector=detector, features=features,
                            max_vertical=max_vertical)


ORB_FAST_THRESHOLD = 5
"""FAST threshold of the ``orb`` detector (grey levels of :func:`gradient_image`)."""


def gradient_matches(left: np.ndarray, right: np.ndarray, *, detector: str = "sift", features: int = 4000,
                     max_vertical: float | None = None, max_horizontal: float | None = None,
                     fast_threshold: int = ORB_FAST_THRESHOLD, patch_size: int = 31) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sparse_matches` of two :func:`gradient_image` results (uint8, (H, W)).

    ``fast_threshold`` and ``patch_size`` (px, odd) tune the ``orb`` detector: a higher
    threshold and a smaller patch are cheaper and suit small images. With
    ``max_vertical``, the distances are computed only between the allowed pairs
    (``cv2.batchDistance`` with a mask), which is several times cheaper than all of them;
    ``max_horizontal`` (px, with ``max_vertical`` only) also keeps apart the features whose
    columns differ by more (fewer wrong candidates: more matches pass the ratio test).
    """
    if detector == "sift":
        finder, norm = cv2.SIFT_create(nfeatures=features, contrastThreshold=0.02), cv2.NORM_L2
    elif detector == "orb":
        finder, norm = cv2.ORB_create(nfeatures=features, nlevels=1, fastThreshold=fast_threshold,
                                      edgeThreshold=patch_size, patchSize=patch_size), cv2.NORM_HAMMING
    else:
        raise ValueError(f"unknown detector {detector!r}; expected one of {FEATURE_DETECTORS}")
    key_left, desc_left = finder.detectAndCompute(left, None)
    key_right, desc_right = finder.detectAndCompute(right, None)
    if desc_left is None or desc_right is None or len(key_left) < 2 or len(key_right) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    points_left, points_right = (np.float64([key.pt for key in keys]).reshape(-1, 2) for keys in (key_left, key_right))
    if max_vertical is None:
        matcher = cv2.BFMatcher(norm)
        forward = matcher.knnMatch(desc_left, desc_right, k=2)
        backward = {m[0].queryIdx: m[0].trainIdx for m in matcher.knnMatch(desc_right, desc_left, k=1) if m}
        pairs = [(m[0].queryIdx, m[0].trainIdx) for m in forward
                 if len(m) == 2 and m[0].distance < 0.8 * m[1].distance and backward.get(m[0].trainIdx) == m[0].queryIdx]
        if not pairs:
            return np.zeros((0, 2)), np.zeros((0, 2))
        first, second = np.array(pairs).T
        return points_left[first], points_right[second]
    rows_left = np.empty((len(points_left), len(points_right)), np.float32)
    rows_left[:] = points_left[:, 1:2]
    allowed = cv2.inRange(rows_left - np.float32(points_right[:, 1]), -max_vertical, max_vertical)  # 255: a candidate
    if max_horizontal is not None:
        rows_left[:] = points_left[:, :1]  # now columns
        allowed &= cv2.inRange(rows_left - np.float32(points_right[:, 0]), -max_horizontal, max_horizontal)
    dtype = cv2.CV_32S if norm == cv2.NORM_HAMMING else cv2.CV_32F
    distance, nearest = cv2.batchDistance(desc_left, desc_right, dtype, normType=norm, K=2, mask=allowed)
    _, back = cv2.batchDistance(desc_right, desc_left, dtype, normType=norm, K=1, mask=np.ascontiguousarray(allowed.T))
    best, back = nearest[:, 0], back[:, 0]
    keep = ((nearest[:, 1] >= 0) & (best >= 0)
            & (distance[:, 0].astype(np.float64) < 0.8 * distance[:, 1].astype(np.float64)))
    keep[keep] = back[best[keep]] == np.flatnonzero(keep)
    return points_left[keep], points_right[best[keep]]
