"""Slow, obviously-correct versions of the fast kernels, for tests only.

Plain Python loops straight from the definitions; use them on tiny images.
"""

from __future__ import annotations

import numpy as np

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.cost import overlap

SGM_DIRECTIONS: tuple[tuple[int, int], ...] = (
    (0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1),
)
"""(dy, dx) steps of the eight SGM paths; a path reaches (y, x) from (y - dy, x - dx)."""


def census_cost_reference(
    left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange, *, window: int = 7
) -> np.ndarray:
    """Census Hamming cost (bit count), by loops; out-of-view entries get the bit count."""
    height, width = left.shape
    radius = window // 2

    def signature(image: np.ndarray, y: int, x: int) -> list[bool]:
        bits = []
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                if dy == 0 and dx == 0:
                    continue
                ny = min(max(y + dy, 0), height - 1)  # replicated border
                nx = min(max(x + dx, 0), width - 1)
                bits.append(bool(image[ny, nx] < image[y, x]))
        return bits

    n_bits = window * window - 1
    volume = np.full((height, width, disparity_range.count), n_bits, np.int64)
    for y in range(height):
        for x in range(width):
            left_bits = signature(left, y, x)
            for k, d in enumerate(range(disparity_range.minimum, disparity_range.maximum + 1)):
                if 0 <= x - d < width:
                    right_bits = signature(right, y, x - d)
                    volume[y, x, k] = sum(a != b for a, b in zip(left_bits, right_bits))
    return volume


def zncc_cost_reference(
    left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange, *, window: int = 5
) -> np.ndarray:
    """1 - ZNCC over windows that lie fully inside both images, by loops.

    Entries whose window touches a border are NaN here (the fast version pads them);
    compare interior entries only.
    """
    height, width = left.shape
    radius = window // 2
    volume = np.full((height, width, disparity_range.count), np.nan)
    for y in range(radius, height - radius):
        for x in range(radius, width - radius):
            a = left[y - radius:y + radius + 1, x - radius:x + radius + 1].astype(np.float64).ravel()
            for k, d in enumerate(range(disparity_range.minimum, disparity_range.maximum + 1)):
                xr = x - d
                if radius <= xr < width - radius:
                    b = right[y - radius:y + radius + 1, xr - radius:xr + radius + 1].astype(np.float64).ravel()
                    a0, b0 = a - a.mean(), b - b.mean()
                    volume[y, x, k] = 1.0 - (a0 @ b0) / np.sqrt((a0 @ a0) * (b0 @ b0))
    return volume


def sgm_aggregate_reference(cost: np.ndarray, *, p1: float, p2: float) -> np.ndarray:
    """Sum over the eight :data:`SGM_DIRECTIONS` of the SGM path costs, by loops."""
    height, width, count = cost.shape
    total = np.zeros((height, width, count), np.float64)
    for dy, dx in SGM_DIRECTIONS:
        path = np.zeros((height, width, count), np.float64)
        rows = range(height) if dy >= 0 else range(height - 1, -1, -1)
        columns = range(width) if dx >= 0 else range(width - 1, -1, -1)
        for y in rows:
            for x in columns:
                py, px = y - dy, x - dx
                if not (0 <= py < height and 0 <= px < width):
                    path[y, x] = cost[y, x]
                    continue
                previous = path[py, px]
                smallest = previous.min()
                for d in range(count):
                    candidates = [previous[d], smallest + p2]
                    if d > 0:
                        candidates.append(previous[d - 1] + p1)
                    if d < count - 1:
                        candidates.append(previous[d + 1] + p1)
                    path[y, x, d] = cost[y, x, d] + min(candidates) - smallest
        total += path
    return total


def dasc_descriptor_reference(
    image: np.ndarray, *, pattern: np.ndarray, patch_radius: int = 2, epsilon: float = 0.09, sigma: float = 0.5,
    blur_sigma: float = 1.0,
) -> np.ndarray:
    """DASC descriptor (:func:`cade_cli.matching.dasc.dasc_descriptor`) pixel by pixel,
    from the guided filter's explicit kernel (He et al., ECCV 2010, eq. 19):

        W(c, j) = 1/n^2 sum over the n-pixel boxes w_k holding c and j of
                  1 + (I_c - mean_k) (I_j - mean_k) / (var_k + epsilon).

    For pair (p, q) the entry at x is the W(x + p, .)-weighted correlation of I around
    x + p with I around x + q. The band is prepared as the fast version does
    (:func:`~cade_cli.matching.dasc.dasc_prepare`). Entries at pixels whose boxes leave the
    image (within max |offset| + 2 * patch_radius of a border) are NaN here (the fast
    version replicates the border); compare interior pixels only.

    Returns:
        (H, W, K) float64.
    """
    from cade_cli.matching.dasc import FLAT_VARIANCE, dasc_prepare

    band = dasc_prepare(image, blur_sigma=blur_sigma).astype(np.float64)
    pattern = np.asarray(pattern).reshape(-1, 4)
    height, width = band.shape
    r = patch_radius
    n = (2 * r + 1) ** 2
    margin = int(np.abs(pattern).max()) + 2 * r
    weights_at: dict[tuple[int, int], np.ndarray] = {}

    def weights(cy: int, cx: int) -> np.ndarray:
        """W(c, j) for j in the (4r + 1)^2 square around c."""
        if (cy, cx) not in weights_at:
            w = np.zeros((4 * r + 1, 4 * r + 1))
            for ky in range(cy - r, cy + r + 1):  # box centres k whose box holds c
                for kx in range(cx - r, cx + r + 1):
                    box = band[ky - r:ky + r + 1, kx - r:kx + r + 1]
                    mean, var = box.mean(), box.var()
                    term = 1.0 + (band[cy, cx] - mean) * (box - mean) / (var + epsilon)
                    oy, ox = ky - r - (cy - 2 * r), kx - r - (cx - 2 * r)
                    w[oy:oy + 2 * r + 1, ox:ox + 2 * r + 1] += term / n**2
            weights_at[(cy, cx)] = w
        return weights_at[(cy, cx)]

    descriptor = np.full((height, width, len(pattern)), np.nan)
    for y in range(margin, height - margin):
        for x in range(margin, width - margin):
            entries = []
            for py, px, qy, qx in pattern:
                cy, cx, sy, sx = y + py, x + px, y + qy, x + qx
                w = weights(cy, cx)
                a = band[cy - 2 * r:cy + 2 * r + 1, cx - 2 * r:cx + 2 * r + 1]
                b = band[sy - 2 * r:sy + 2 * r + 1, sx - 2 * r:sx + 2 * r + 1]
                mean_a, mean_b = (w * a).sum(), (w * b).sum()
                var_a, var_b = (w * a * a).sum() - mean_a**2, (w * b * b).sum() - mean_b**2
                if var_a < FLAT_VARIANCE or var_b < FLAT_VARIANCE:
                    correlation = 1.0
                else:
                    correlation = ((w * a * b).sum() - mean_a * mean_b) / np.sqrt(var_a * var_b)
                    correlation = min(max(correlation, -1.0), 1.0)
                entries.append(np.exp(-(1.0 - correlation) / sigma))
            entries = np.array(entries)
            descriptor[y, x] = entries / np.sqrt((entries**2).sum())
    return descriptor


def dasc_descriptor_cost_reference(
    left_descriptor: np.ndarray, right_descriptor: np.ndarray, disparity_range: DisparityRange
) -> np.ndarray:
    """:func:`cade_cli.matching.dasc.dasc_descriptor_cost` one disparity at a time:
    ``1 - <left(y, x), right(y, x - d)>`` over the columns where both lie in the image, 1
    elsewhere, clipped to [0, 1] (the per-disparity ``einsum`` the fast version replaced).

    Returns:
        float32 (H, W, D).
    """
    height, width, _ = left_descriptor.shape
    planes = np.ones((disparity_range.count, height, width), np.float32)
    for k, d in enumerate(range(disparity_range.minimum, disparity_range.maximum + 1)):
        left_cols, right_cols = overlap(width, d)
        planes[k][:, left_cols] -= np.einsum("hwk,hwk->hw", left_descriptor[:, left_cols],
                                             right_descriptor[:, right_cols])
    np.clip(planes, 0.0, 1.0, out=planes)
    return np.ascontiguousarray(planes.transpose(1, 2, 0))
