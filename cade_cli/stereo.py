"""Library entry point for disparity: choose the range, run a registered matcher."""

from __future__ import annotations

import math

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching import DisparityResult, get_matcher

DEFAULT_METHOD = "cade"
"""The CADE network: the lowest EPE of the registered matchers on every set and protocol
of the cross-spectral benchmark (docs/results.md)."""

DEFAULT_PREPROCESS = "auto"

MEMORY_LIMIT_BYTES = 8 * 2**30
"""Requests whose cost volumes (:attr:`~cade_cli.matching.Matcher.volume_bytes` per pixel
and disparity) would exceed this are refused."""


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
        :func:`~cade_cli.matching.densify` fills it.
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
    return matcher(left, right, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess)
