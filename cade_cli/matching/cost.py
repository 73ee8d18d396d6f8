"""Matching-cost stage: a cost volume from a pair of bands.

A cost volume ``C`` has shape (H, W, D): ``C[y, x, k]`` is the cost of matching left
pixel (y, x) with right pixel (y, x - d) for d = ``disparity_range.minimum + k``.
Lower is better for every volume built here (Census: Hamming distance, ZNCC: 1 - ZNCC),
and :class:`CostVolume` carries that flag so later stages read it instead of guessing.
Entries whose right pixel falls outside the image get the volume's worst cost, so an
out-of-view match never beats an in-view one.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.matching.base import DisparityRange


@dataclass(frozen=True)
class CostVolume:
    """(H, W, D) matching costs over ``disparity_range`` (see module docstring); float32,
    or unsigned integers where the cost is a count (Census) or was quantized."""

    values: np.ndarray
    disparity_range: DisparityRange
    lower_is_better: bool = True


def census_transform(image: np.ndarray, *, window: int = 7) -> np.ndarray:
    """Census signature of every pixel: bit k set where neighbour k is darker than the centre.

    Args:
        image: (H, W) float band.
        window: odd window side, 3..7 (a 7x7 window gives 48 bits in a uint64).

    Returns:
        (H, W) uint64 signatures; borders are replicated.
    """
    if window % 2 == 0 or not 3 <= window <= 7:
        raise ValueError(f"census window must be odd and in 3..7, got {window}")
    signature = np.zeros(image.shape, np.uint64)
    for bit, neighbour in enumerate(_neighbours(image, window)):
        signature |= (neighbour < image).astype(np.uint64) << np.uint64(bit)
    return signature


RANK_ROWS = 128
"""Rows of image :func:`rank_transform` compares at once."""


def rank_transform(image: np.ndarray, *, window: int = 7) -> np.ndarray:
    """Rank of every pixel in its window: how many of its neighbours are darker than it.

    The number of set bits of :func:`census_transform`'s signature (Zabih & Woodfill,
    ECCV 1994), kept as an image: like Census it depends only on the order of
    intensities, so any gain, offset or gamma change between bands leaves it unchanged,
    and ordinary image matchers (OpenCV's SGBM) can run on it.

    Returns:
        (H, W) uint8 ranks in [0, window**2 - 1]; borders are replicated.
    """
    if window % 2 == 0 or window < 3:
        raise ValueError(f"rank window must be odd and at least 3, got {window}")
    image = image.astype(np.float32, copy=False)
    radius, (height, width) = window // 2, image.shape
    padded = np.pad(image, radius, mode="edge")
    rank = np.zeros(image.shape, np.uint8)
    # Block by block of RANK_ROWS rows, so that a block's 48 comparisons read it from the cache
    # (the same ranks as whole images, in 45 % of the time on a Middlebury Q band).
    for top in range(0, height, RANK_ROWS):
        bottom = min(height, top + RANK_ROWS)
        centre, block = padded[top + radius:bottom + radius, radius:radius + width], rank[top:bottom]
        for neighbour in _padded_neighbours(padded, window, top, bottom, width):
            # OpenCV's compare gives 255 where darker: subtracting it adds 1 modulo 256 (the same
            # ranks as summing the bool planes ``neighbour < image``, in 60 % of the time)
            np.subtract(block, cv2.compare(neighbour, centre, cv2.CMP_LT), out=block)
    return rank


def _neighbours(image: np.ndarray, window: int) -> Iterator[np.ndarray]:
    """For each neighbour in a ``window`` x ``window`` box (row by row, centre skipped),
    the (H, W) plane of that neighbour's values: views of the float32 copy of ``image``
    padded by replicating its borders."""
    height, width = image.shape
    padded = np.pad(image.astype(np.float32, copy=False), window // 2, mode="edge")
    return _padded_neighbours(padded, window, 0, height, width)


def _padded_neighbours(padded: np.ndarray, window: int, top: int, bottom: int, width: int) -> Iterator[np.ndarray]:
    """:func:`_neighbours`' planes for the image rows ``top`` .. ``bottom`` - 1 only, read from the
    image already ``padded`` by ``window // 2`` on every side."""
    radius = window // 2
    for dy in range(window):
        for dx in range(window):
            if dy != radius or dx != radius:
                yield padded[top + dy:bottom + dy, dx:dx + width]


def census_cost(
    left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange, *, window: int = 7
) -> CostVolume:
    """Census cost volume: Hamming distance between census signatures.

    Returns:
        uint8 (H, W, D) volume of bit counts in [0, window**2 - 1]; out-of-view
        entries get the maximum. Integer costs let SGM aggregate exactly and fast.
    """
    left_signature = census_transform(left, window=window)
    right_signature = census_transform(right, window=window)
    bits = window * window - 1
    height, width = left.shape
    # Fill one contiguous (H, W) plane per disparity, then reorder to (H, W, D) once:
    # far faster than writing every plane with a stride of D bytes.
    planes = np.full((disparity_range.count, height, width), bits, np.uint8)
    for k, d in enumerate(range(disparity_range.minimum, disparity_range.maximum + 1)):
        left_cols, right_cols = overlap(width, d)
        planes[k][:, left_cols] = np.bitwise_count(left_signature[:, left_cols] ^ right_signature[:, right_cols])
    return CostVolume(np.ascontiguousarray(planes.transpose(1, 2, 0)), disparity_range)


def zncc_cost(
    left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange, *, window: int = 5
) -> CostVolume:
    """1 - ZNCC over a ``window`` x ``window`` box, in [0, 2] (0 = perfectly correlated).

    Where either window is flat (standard deviation below 1e-4 of the band's range) the
    correlation is undefined and the cost is 1, the value of uncorrelated windows.
    Out-of-view entries cost 2.
    """
    box = (window, window)

    def local_mean(x: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(x, cv2.CV_64F, box, normalize=True, borderType=cv2.BORDER_REPLICATE)

    left64 = left.astype(np.float64) - float(left.mean())
    right64 = right.astype(np.float64) - float(right.mean())
    mean_left, mean_right = local_mean(left64), local_mean(right64)
    std_left = np.sqrt(np.maximum(local_mean(left64 * left64) - mean_left**2, 0.0))
    std_right = np.sqrt(np.maximum(local_mean(right64 * right64) - mean_right**2, 0.0))
    flat_threshold = 1e-4 * max(float(np.ptp(left64)), float(np.ptp(right64)), 1e-12)

    height, width = left.shape
    volume = np.full((height, width, disparity_range.count), 2.0, np.float32)
    for k, d in enumerate(range(disparity_range.minimum, disparity_range.maximum + 1)):
        left_cols, right_cols = overlap(width, d)
        shifted_right = np.zeros_like(right64)
        shifted_right[:, left_cols] = right64[:, right_cols]
        # The box windows of the shifted product must see the same pixels as the
        # unshifted statistics, so shift the right statistics rather than recompute them.
        cross = local_mean(left64 * shifted_right)[:, left_cols]
        mu_l, mu_r = mean_left[:, left_cols], mean_right[:, right_cols]
        sd_l, sd_r = std_left[:, left_cols], std_right[:, right_cols]
        denominator = sd_l * sd_r
        flat = (sd_l < flat_threshold) | (sd_r < flat_threshold)
        zncc = (cross - mu_l * mu_r) / np.where(flat, 1.0, denominator)
        volume[:, left_cols, k] = np.where(flat, 1.0, 1.0 - np.clip(zncc, -1.0, 1.0))
    return CostVolume(volume, disparity_range)


def quantize(cost: CostVolume, *, scale: float) -> CostVolume:
    """Integer version of a non-negative float volume: ``rint(values * scale)`` as uint8.

    SGM aggregates integer volumes exactly and several times faster; with costs in
    [0, 2] (1 - ZNCC) a scale of 32 keeps steps of 1/32 in ZNCC, well below the noise.
    """
    levels = np.rint(cost.values * np.float32(scale))
    if levels.size and (levels.min() < 0 or levels.max() > 255):
        raise ValueError(f"costs times {scale} leave the uint8 range; lower the scale")
    return CostVolume(levels.astype(np.uint8), cost.disparity_range, cost.lower_is_better)


def overlap(width: int, disparity: int) -> tuple[slice, slice]:
    """Columns where left x and right x - disparity both lie inside a row of ``width``."""
    if disparity >= 0:
        return slice(disparity, width), slice(0, width - disparity)
    return slice(0, width + disparity), slice(-disparity, width)
