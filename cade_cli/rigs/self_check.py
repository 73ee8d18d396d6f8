"""The rectification self-check: the vertical offset and the roll about the image centre that
rectification left, fitted robustly to the row differences of sparse feature matches
(:mod:`cade_cli.matching.sparse`), and the right image resampled to cancel them
(``--fix-vertical``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.sparse import sparse_matches


VERTICAL_TOLERANCE_PX = 0.5
"""Residual vertical misalignment above which the self-check warns."""

MIN_SELF_CHECK_MATCHES = 12
"""The fewest feature matches the self-check fits a vertical offset to."""

MIN_ROLL_MATCHES = 40
"""The fewest feature matches the self-check also fits a roll to; with fewer, the roll
is taken as 0 (a roll fitted to a few matches can be off by tenths of a degree)."""

MIN_CORRECTION_PX = 0.25
"""The smallest misalignment (px, anywhere across the width) :func:`align_vertically` corrects."""


@dataclass(frozen=True)
class VerticalMisalignment:
    """What is left of a pair's rectification error, as right-image row minus left-image row
    of the same scene point: ``dy(x) = offset + tan(roll) * (x - cx)``.

    Attributes:
        offset: vertical offset at the image centre, px (> 0: the right image shows things lower).
        roll: rotation of the right image against the left about the image centre, radians.
        residual: median |dy| of the matches after the fit, px (how well the model explains them).
        matches: number of inlier matches the fit rests on.
        centre: (cx, cy) the roll turns about, px.
    """

    offset: float
    roll: float
    residual: float
    matches: int
    centre: tuple[float, float]

    def worst(self, width: int) -> float:
        """The largest |dy| over the image width, px (the offset plus the roll at the far edge)."""
        half = width / 2
        return max(abs(self.offset + math.tan(self.roll) * dx) for dx in (-half, half))


def fit_vertical_misalignment(x: np.ndarray, dy: np.ndarray, *, size: tuple[int, int], min_band: float = 0.25,
                              min_roll_matches: int = MIN_ROLL_MATCHES) -> tuple[VerticalMisalignment, np.ndarray]:
    """Fit ``dy = offset + tan(roll) (x - cx)`` to matches, robustly.

    Least squares, repeated on the matches within 3 robust standard deviations (at
    least ``min_band`` px) of the previous fit, starting from those within 3 of the median
    (at least 0.5 px). With fewer than ``min_roll_matches`` matches only the offset is
    fitted (roll 0).

    Args:
        x: (N,) column of each match in the left band, px.
        dy: (N,) right-band row minus left-band row of each match, px.
        size: (width, height) of the band, px (the roll turns about its centre).
        min_band: the narrowest inlier band, px (the precision of the match positions).
        min_roll_matches: the fewest matches the roll is fitted from.

    Returns:
        (the fit, (N,) bool inlier mask).

    Raises:
        CadeError: fewer than :data:`MIN_SELF_CHECK_MATCHES` matches, or inliers.
    """
    x, dy = np.asarray(x, np.float64), np.asarray(dy, np.float64)
    if len(dy) < MIN_SELF_CHECK_MATCHES:
        raise _too_few_matches(len(dy))
    width, height = size
    centre = ((width - 1) / 2, (height - 1) / 2)
    design = np.stack([np.ones_like(x), x - centre[0]], axis=1)
    if len(dy) < min_roll_matches:
        design[:, 1] = 0  # offset only; lstsq gives the roll term 0
    inliers = np.abs(dy - np.median(dy)) <= max(3 * 1.4826 * np.median(np.abs(dy - np.median(dy))), 0.5)
    for _ in range(5):
        if inliers.sum() < MIN_SELF_CHECK_MATCHES:
            raise _too_few_matches(int(inliers.sum()))
        coefficients, *_ = np.linalg.lstsq(design[inliers], dy[inliers], rcond=None)
        residual = dy - design @ coefficients
        spread = 1.4826 * float(np.median(np.abs(residual[inliers])))
        inliers = np.abs(residual) <= max(3 * spread, min_band)
    offset, slope = (float(v) for v in coefficients)
    found = VerticalMisalignment(offset=offset, roll=math.atan(slope),
                                 residual=float(np.median(np.abs(residual[inliers]))) if inliers.any() else 0.0,
                                 matches=int(inliers.sum()), centre=centre)
    return found, inliers


def measure_vertical_misalignment(left: np.ndarray, right: np.ndarray, *, max_vertical: float = 8.0,
                                  max_disp: float | None = None, mirrored: bool = False) -> VerticalMisalignment:
    """Fit a vertical offset and roll to sparse matches between a rectified pair.

    SIFT features on :func:`gradient_image` of each band are matched (ratio test 0.8,
    mutual; :func:`sparse_matches`), kept where the row difference is within
    ``max_vertical`` px and the disparity ``x_left - x_right`` within [-8, ``max_disp`` + 8]
    px, and ``dy = offset + tan(roll) (x - cx)`` is fitted (:func:`fit_vertical_misalignment`).

    Args:
        left, right: (H, W) float bands of one rectified pair, same size, any range.
        max_vertical: the largest row difference considered, px.
        max_disp: the largest disparity considered, px (default: the image width).
        mirrored: the ``right`` camera is the one on the left (:func:`needs_mirroring`):
            its matches lie at x_right = x_left + d, so the disparity is ``x_right - x_left``.

    Raises:
        CadeError: images of different sizes, or fewer than :data:`MIN_SELF_CHECK_MATCHES`
            matches (too little texture shared by the bands).
    """
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    if left.shape != right.shape or left.ndim != 2:
        raise CadeError(f"the self-check needs two (H, W) bands of one size, got {left.shape} and {right.shape}")
    height, width = left.shape
    max_disp = float(width) if max_disp is None else float(max_disp)
    points_left, points_right = sparse_matches(left, right, detector="sift", features=4000)
    if not len(points_left):
        raise _too_few_matches(0)
    dy = points_right[:, 1] - points_left[:, 1]
    dx = (points_left[:, 0] - points_right[:, 0]) * (-1.0 if mirrored else 1.0)
    keep = (np.abs(dy) <= max_vertical) & (dx >= -8) & (dx <= max_disp + 8)
    found, _ = fit_vertical_misalignment(points_left[keep, 0], dy[keep], size=(width, height))
    return found


def _too_few_matches(count: int) -> CadeError:
    return CadeError(f"the rectification self-check found only {count} feature matches between the rectified images "
                     f"({MIN_SELF_CHECK_MATCHES} needed): too little shared texture; drop --fix-vertical")


def correct_vertical_misalignment(right: np.ndarray, misalignment: VerticalMisalignment) -> np.ndarray:
    """``right`` resampled so that the fitted offset and roll vanish: output pixel (x, y)
    takes ``right`` at the roll-rotated, offset position of (x, y) (bicubic, which softens
    the band less than bilinear; borders replicated). Works on (H, W) or (H, W, C) float images."""
    cx, cy = misalignment.centre
    c, s = math.cos(misalignment.roll), math.sin(misalignment.roll)
    # Where left pixel p = (x, y) lies in the right image: rotation about the centre, then the offset.
    forward = np.float64([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy + misalignment.offset]])
    height, width = right.shape[:2]
    return cv2.warpAffine(np.asarray(right, np.float32), forward, (width, height),
                          flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)


def align_vertically(left: np.ndarray, right: np.ndarray, *, max_disp: float | None = None,
                     min_correction: float = MIN_CORRECTION_PX, mirrored: bool = False) -> tuple[np.ndarray, VerticalMisalignment, bool]:
    """The self-check and its correction, as ``--fix-vertical`` and the rig benchmark run it.

    Measures the misalignment (:func:`measure_vertical_misalignment`) and, when it
    reaches ``min_correction`` px somewhere across the width, resamples ``right`` to
    cancel it (:func:`correct_vertical_misalignment`); a smaller one is left alone, since
    resampling softens the band more than such a residual costs the matcher.

    Returns:
        (``right``, corrected or as given; the misalignment measured; whether it was corrected).

    Raises:
        CadeError: too few matches to measure (:func:`measure_vertical_misalignment`).
    """
    found = measure_vertical_misalignment(left, right, max_disp=max_disp, mirrored=mirrored)
    if found.worst(right.shape[1]) < min_correction:
        return right, found, False
    return correct_vertical_misalignment(right, found), found, True
