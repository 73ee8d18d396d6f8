"""Library entry point for disparity: choose the range, run a registered matcher."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching import DisparityResult, get_matcher

DEFAULT_METHOD = "cade"
"""The CADE network: the lowest EPE of the registered matchers on every set and protocol
of the cross-spectral benchmark (docs/research/evaluation.md)."""

DEFAULT_PREPROCESS = "auto"

MEMORY_LIMIT_BYTES = 8 * 2**30
"""Requests whose cost volumes (:attr:`~cade_cli.matching.Matcher.volume_bytes` per pixel
and disparity) would exceed this are refused."""


TEXTURE_WINDOW = 9
"""Side, px, of the square neighbourhood :func:`textureless` looks at: a pixel whose 9x9
neighbourhood holds a single value (a blank, saturated or constant area) has nothing to
match, in any band."""


def textureless(band: np.ndarray, *, window: int = TEXTURE_WINDOW) -> np.ndarray:
    """Where ``band`` is exactly constant over the ``window`` x ``window`` neighbourhood.

    Args:
        band: (H, W) real image, any units.
        window: odd neighbourhood side, px (borders replicate the edge).

    Returns:
        (H, W) bool, True where the neighbourhood's minimum equals its maximum; a
        non-finite pixel is never flat.
    """
    values = np.asarray(band, np.float32)
    kernel = np.ones((window, window), np.uint8)
    low = cv2.erode(values, kernel, borderType=cv2.BORDER_REPLICATE)
    high = cv2.dilate(values, kernel, borderType=cv2.BORDER_REPLICATE)
    return (low == high) & np.isfinite(values)


def mark_textureless_invalid(result: DisparityResult, left: np.ndarray, right: np.ndarray) -> DisparityResult:
    """``result`` with every estimate that rests on a flat area (:func:`textureless`) invalid.

    A left pixel is flat when the left band is flat around it, or when the right band is
    flat around the pixel its disparity points to (y, x - d): with nothing to match in
    either band the matcher's value is a guess (a constant pair has no disparity at all).
    Those pixels get NaN disparity, ``valid`` False and confidence 0; the others are
    unchanged. Returns ``result`` itself when no estimate is affected.
    """
    left_flat, right_flat = textureless(left), textureless(right)
    valid = np.asarray(result.valid, bool)
    rows, columns = np.nonzero(valid & np.isfinite(result.disparity))
    target = np.clip(np.rint(columns - result.disparity[rows, columns]), 0, right_flat.shape[1] - 1).astype(np.intp)
    flat = left_flat.copy()
    flat[rows, columns] |= right_flat[rows, target]
    flat &= valid
    if not flat.any():
        return result
    confidence = None if result.confidence is None else np.where(flat, np.float32(0), result.confidence)
    return dataclasses.replace(
        result, disparity=np.where(flat, np.float32(np.nan), result.disparity), valid=valid & ~flat,
        confidence=confidence,
    )


def default_max_disparity(width: int) -> int:
    """Search bound used when the caller gives none: a quarter of the width, rounded up
    to a multiple of 8 and kept below the width. Rectified pairs from rigs whose baseline
    is small against the scene depth (most multispectral rigs) stay well inside it."""
    return max(1, min(width - 1, 8 * math.ceil(width / 4 / 8)))


def estimate_disparity(
    left: np.ndarray,
    right: np.ndarray,
    *,
    method: str = DEFAULT_METHOD,
    max_disp: int | None = None,
    min_disp: int = 0,
    preprocess: str = DEFAULT_PREPROCESS,
    model: str | None = None,
) -> DisparityResult:
    """Dense disparity of the left (reference) band against the right band.

    Args:
        left, right: (H, W) float bands of one rectified pair, any intensity units; the
            two may come from different spectral filters.
        method: a name from :data:`cade_cli.matching.MATCHERS`.
        max_disp, min_disp: inclusive search range in pixels, with
            I_left(y, x) ~ I_right(y, x - d). ``max_disp=None`` uses
            :func:`default_max_disparity`. A negative ``min_disp`` serves pairs
            pre-registered to a plane.
        preprocess: ``"cade"`` (color agnostic transform on both bands), ``"none"``, or
            ``"auto"``: the matcher's more accurate choice on cross-spectral pairs
            (the first of :attr:`~cade_cli.matching.Matcher.preprocessing`).
        model: for the learned methods, another network than the shipped one: a model
            card's path or a card name (:func:`cade_cli.matching.get_matcher`).

    Returns:
        :class:`~cade_cli.matching.DisparityResult`: unfilled (H, W) float32 disparity
        in pixels (NaN where invalid) plus its (H, W) bool validity;
        :func:`~cade_cli.matching.densify` fills it. Estimates that rest on a flat area
        of either band are invalid (:func:`mark_textureless_invalid`): a constant pair
        comes back 0 % valid.
    """
    matcher = get_matcher(method, model=model)
    left, right = np.asarray(left), np.asarray(right)
    if left.ndim != 2:
        raise CadeError(f"left image must be one band of shape (H, W), got shape {left.shape}; pick a band")
    if max_disp is None:
        max_disp = default_max_disparity(left.shape[1])
    volume_bytes = matcher.volume_bytes * left.size * (max_disp - min_disp + 1)
    if volume_bytes > MEMORY_LIMIT_BYTES:
        raise CadeError(
            f"a {left.shape[1]}x{left.shape[0]} pair over {max_disp - min_disp + 1} disparities needs about "
            f"{volume_bytes / 2**30:.0f} GB; lower --max-disp or downscale the images"
        )
    result = matcher(left, right, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess)
    return mark_textureless_invalid(result, left, right)
