"""The vendors' band alignment, reimplemented with OpenCV: one homography per band onto the
reference band, found by ECC (``cv2.findTransformECC``, ``MOTION_HOMOGRAPHY``) on gradient
images, coarse to fine, as MicaSense's ``imageprocessing`` (``imageutils.align``) does.

Exact only for a plane at one distance (or a camera that only rotates): it is the anchor that
parallax-correct registration is measured against, and ``--plane-only``'s result.
"""

from __future__ import annotations

import re

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.sparse import sparse_matches

ECC_LEVELS = 3
"""Pyramid levels (full resolution and two halvings): MicaSense's ``int(width / (1280 / 3)) - 1``
halvings for a 1280 px wide band."""
ECC_ITERATIONS = 100
"""Most ECC iterations per level (MicaSense allows 2500, to a stop at 1e-9). Against 300 (to a
stop at 1e-7), 100 gave the same residual shift to 0.001 px on NIR of the field and a bench
capture (cade_cli.capture.alignment), and the Sequoia's Red converged before 100; 50 did not."""
ECC_EPSILON = 1e-6
"""ECC stops when the correlation coefficient changes by less than this."""
MIN_CORRELATION = 0.2
"""Below this final ECC correlation of the gradient images the bands share too little
structure for the homography to mean anything."""
LOCAL_WINDOW = 61
"""Side, px, of the window each pixel is standardised in before ECC's gradients (MicaSense
equalises each band in a disk of radius 30 px): faint texture (a canopy) then weighs as much
as strong edges (a bright platform) in the fit."""
GRADIENT_SIGMA = 1.0
"""Gaussian smoothing (px) before the Sobel gradient, as MicaSense's ``gaussian(normalize(.))``."""


def gradient_magnitude(band: np.ndarray, *, sigma: float = GRADIENT_SIGMA, local: int = 0) -> np.ndarray:
    """Gradient image of one band, independent of its contrast and of the sign of it.

    The band is scaled by its own 1st and 99th percentiles of finite values (with ``local`` >
    0: standardised by the mean and standard deviation in a ``local`` px box around each
    pixel, clipped to +-3 standard deviations), smoothed by a
    Gaussian of ``sigma`` px, and replaced by ``sqrt(gx^2 + gy^2)`` of 3x3 Sobel gradients;
    NaN (not seen) becomes 0, as do pixels within 4 px of one (no false edge at the
    border of what was seen).

    Args:
        band: (H, W) real array; NaN where invalid.

    Returns:
        (H, W) float32, >= 0. The input is not modified.
    """
    band = np.asarray(band, np.float32)
    if band.ndim != 2:
        raise CadeError(f"a band is one image of shape (H, W), got shape {band.shape}")
    finite = np.isfinite(band)
    if not finite.any():
        raise CadeError("the band has no finite value to align")
    low, high = np.percentile(band[finite], [1, 99])
    scaled = np.where(finite, (band - low) / max(float(high - low), 1e-12), 0.0).astype(np.float32)
    if not finite.all():  # fill the unseen with the nearest seen values' level: no step at the border
        scaled[~finite] = float(np.median(scaled[finite]))
    if local > 0:
        box = (local, local)
        mean = cv2.boxFilter(scaled, cv2.CV_32F, box, borderType=cv2.BORDER_REFLECT)
        variance = np.maximum(cv2.boxFilter(scaled * scaled, cv2.CV_32F, box, borderType=cv2.BORDER_REFLECT)
                              - mean * mean, 0.0)
        scaled = np.clip((scaled - mean) / np.sqrt(variance + 1e-6), -3.0, 3.0)
    if sigma > 0:
        scaled = cv2.GaussianBlur(scaled, (0, 0), sigma)
    gx = cv2.Sobel(scaled, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(scaled, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.sqrt(gx * gx + gy * gy)
    if not finite.all():
        near_unseen = cv2.dilate((~finite).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        magnitude[near_unseen] = 0.0
    return magnitude


def _level_scale(level: int) -> np.ndarray:
    """Maps pixel coordinates of pyramid ``level`` (0 = full size, each level halved by area
    averaging) to full-size pixel coordinates (pixel centres at integers)."""
    factor = 2.0 ** level
    offset = (factor - 1.0) / 2.0
    return np.array([[factor, 0, offset], [0, factor, offset], [0, 0, 1]])


def _pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    pyramid = [image]
    for _ in range(levels - 1):
        pyramid.append(cv2.resize(pyramid[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    return pyramid


def ecc_homography(reference: np.ndarray, band: np.ndarray, *, init: np.ndarray | None = None,
                   levels: int = ECC_LEVELS, iterations: int = ECC_ITERATIONS,
                   epsilon: float = ECC_EPSILON, min_correlation: float = MIN_CORRELATION) -> np.ndarray:
    """The homography that maps ``band``'s pixel coordinates onto ``reference``'s.

    ECC maximises the correlation of the two bands' :func:`gradient_magnitude` images, each
    band locally standardised first (:data:`LOCAL_WINDOW`; so a band whose contrast differs,
    or is inverted, still aligns, and faint texture counts), on a pyramid of ``levels``
    (each half the size of the one before), from the coarsest to full size, each level
    starting from the one before. Pixel centres are at integer coordinates, (x, y) = (column, row).

    Args:
        reference, band: (H, W) real arrays of one size; NaN where invalid.
        init: (3, 3) starting homography, band pixels -> reference pixels (e.g. the lens
            rotation ``K_ref R_ref^T R_band K_band^-1``); identity when None.
        levels: pyramid levels, >= 1 (1: full size only).
        iterations, epsilon: ECC's stopping rule at each level.
        min_correlation: the final correlation below which the result is refused.

    Returns:
        (3, 3) float64 H with H[2, 2] = 1: ``reference ~ H @ (x, y, 1)`` for a band pixel (x, y).
        Warp the band onto the reference with ``cv2.warpPerspective(band, np.linalg.inv(H),
        size, flags=cv2.WARP_INVERSE_MAP)``, or ``cv2.warpPerspective(band, H, size)``.

    Raises:
        CadeError: shapes differ, bands too small for the pyramid, or ECC does not converge
            (too little shared structure, or a start too far from the answer).
    """
    reference, band = np.asarray(reference, np.float32), np.asarray(band, np.float32)
    if reference.shape != band.shape or reference.ndim != 2:
        raise CadeError(f"reference {reference.shape} and band {band.shape} must be two (H, W) images of one size")
    if not 1 <= levels or min(reference.shape) / 2 ** (levels - 1) < 16:
        raise CadeError(f"{levels} pyramid levels do not fit a {reference.shape[1]}x{reference.shape[0]} band; "
                        "use fewer levels")
    start = np.eye(3) if init is None else np.asarray(init, np.float64)
    if start.shape != (3, 3) or not np.isfinite(start).all() or abs(np.linalg.det(start)) < 1e-12:
        raise CadeError(f"init must be an invertible, finite 3x3 homography, got {np.shape(init)}")
    to_band = np.linalg.inv(start)  # ECC's warp: template (reference) pixels -> input (band) pixels
    pyramids = [_pyramid(gradient_magnitude(image, local=LOCAL_WINDOW), levels) for image in (reference, band)]
    seen = _pyramid(np.isfinite(band).astype(np.float32), levels)  # ECC's mask is the input's (the band's)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, iterations, epsilon)
    correlation = 0.0
    for level in reversed(range(levels)):
        scale = _level_scale(level)
        warp = np.linalg.inv(scale) @ to_band @ scale
        mask = (seen[level] > 0.999).astype(np.uint8)
        try:
            correlation, warp = cv2.findTransformECC(pyramids[0][level], pyramids[1][level],
                                                     (warp / warp[2, 2]).astype(np.float32),
                                                     cv2.MOTION_HOMOGRAPHY, criteria, mask, 1)
        except cv2.error as error:
            raise CadeError(f"ECC did not converge at pyramid level {level} ({_opencv_reason(error)}); the bands "
                            "share too little structure or the start is too far off: give a better init") from None
        to_band = scale @ warp.astype(np.float64) @ np.linalg.inv(scale)
    if not np.isfinite(to_band).all() or not correlation >= min_correlation:
        raise CadeError(f"ECC ended at a gradient correlation of {correlation:.2f} (below {min_correlation}): the "
                        "bands share too little structure for one homography")
    homography = np.linalg.inv(to_band)
    return homography / homography[2, 2]


def _opencv_reason(error: Exception) -> str:
    """OpenCV's reason (``error: (-7:Iterations do not converge) ...`` -> ``Iterations do not converge``)."""
    found = re.search(r"\(-?\d+:([^)]*)\)", str(error))
    return found.group(1) if found else type(error).__name__


FEATURE_INLIERS = 12
"""Fewest RANSAC inliers :func:`feature_homography` accepts (a homography has 8 degrees of
freedom; 12 matches within :data:`RANSAC_THRESHOLD` of one seldom agree by chance)."""
RANSAC_THRESHOLD = 3.0
"""px: a feature match farther than this from the homography is an outlier."""


def feature_homography(reference: np.ndarray, band: np.ndarray) -> tuple[np.ndarray, int]:
    """A homography (band pixels -> reference pixels) from sparse feature matches on gradient
    images (:func:`cade_cli.matching.sparse.sparse_matches`, SIFT) and RANSAC, as
    OpenDroneMap's multispectral alignment finds one; a start for :func:`ecc_homography` where
    the lens rotations are far off (close range). Returns it and its number of inliers.

    Raises:
        CadeError: fewer than :data:`FEATURE_INLIERS` inliers.
    """
    filled = [np.where(np.isfinite(image), image, np.nanmedian(image)).astype(np.float32)
              for image in (np.asarray(reference, np.float32), np.asarray(band, np.float32))]
    on_reference, on_band = sparse_matches(filled[0], filled[1])
    homography, inliers = (None, None) if len(on_band) < 4 else cv2.findHomography(
        on_band, on_reference, cv2.RANSAC, RANSAC_THRESHOLD)
    count = 0 if inliers is None else int(inliers.sum())
    if homography is None or count < FEATURE_INLIERS:
        raise CadeError(f"only {count} feature matches agree on one homography (need {FEATURE_INLIERS}): the bands "
                        "share too little structure")
    return homography / homography[2, 2], count


def warp_band(band: np.ndarray, homography: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``band`` (H, W) resampled onto the reference grid of ``size`` (width, height) through
    ``homography`` (band -> reference pixels), bilinear, NaN where the band was not seen."""
    band = np.asarray(band, np.float32)
    to_band = np.linalg.inv(np.asarray(homography, np.float64))
    warped = cv2.warpPerspective(band, to_band, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return warped
