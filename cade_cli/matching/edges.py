"""Depth edges put back where the image has them: a weighted median of the disparity map, its
weights from the reference band (a card's ``runtime_edge_filter: weighted-median``).

The network estimates disparity on a ¼-size grid and upsamples it, so near a depth edge its map
passes through values between the two surfaces over a few pixels, or puts the edge a few pixels
off the image's. The weighted median (Ma et al., "Constant time weighted median filtering for
stereo matching and beyond", ICCV 2013; OpenCV's implementation is Zhang et al., CVPR 2014) gives
each pixel the median of the disparities around it, each counted by how alike its grey level in
the reference band is: an in-between value is replaced by one of the two surfaces, the one the
pixel resembles. Only the reference (left) band is used, so the bands' different spectra do not
matter.

Only gross moves are taken: a pixel the median moves by at most :data:`MIN_MOVE` keeps its own
value. Smaller moves are not edge corrections but smoothing, and a weighted median leans a slanted
surface towards the pixels of like grey level (a few tenths of a px): that cost drone registration
more than it gained (docs/research/refinement.md, 2026-11-29). OpenCV quantises a float map to 256
levels (of each band of rows it is given); a moved pixel takes the mean of its neighbours' own values
within a level (the map's span / 255) of the median, so the map keeps sub-pixel values there too
(:func:`snap_to_edges`).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

RADIUS = 7
"""Px: the median's window is (2 × RADIUS + 1)², wider than the network's ¼-size blur (Middlebury 2014 and
2005 CS, 2026-11-29: radius 5 and 10 score within a few tenths of it; docs/research/refinement.md)."""
SIGMA = 10.0
"""The grey-level spread (of 255) over which a neighbour's weight falls by 1/e
(``exp(-|ΔI|² / (2σ²))``, OpenCV's ``WMF_EXP``); 5 to 20 score alike."""
NEIGHBOURS = 2
"""Px: the window a moved pixel's sub-pixel value is taken from."""
BAND_ROWS = 128
"""Rows of each band the median is computed on at once (with ``radius`` rows of context above and
below), the bands spread over OpenCV's threads: fixed, so the map does not depend on the thread count."""
MIN_MOVE = 1.0
"""Px: the median replaces a pixel only where it moves it by more than this."""


def guide_band(band: np.ndarray) -> np.ndarray:
    """(H, W) uint8: ``band`` stretched between its 0.5th and 99.5th percentiles (any range or dtype;
    a constant band gives a constant guide, which makes the weighted median a plain one)."""
    band = np.asarray(band, np.float32)
    finite = band[np.isfinite(band)]
    if finite.size == 0:
        return np.zeros(band.shape, np.uint8)
    low, high = np.percentile(finite, [0.5, 99.5])
    scaled = (np.nan_to_num(band, nan=low) - low) * (255.0 / max(float(high - low), 1e-6))
    return np.clip(scaled, 0, 255).astype(np.uint8)


def banded_weighted_median(guide: np.ndarray, values: np.ndarray, known: np.ndarray, *, radius: int,
                           sigma: float) -> np.ndarray:
    """OpenCV's weighted median of ``values`` (``known`` False: does not vote), one band of
    :data:`BAND_ROWS` rows at a time, each with ``radius`` rows of context, on OpenCV's threads
    (the call itself runs on one core; OpenCV lets go of the GIL)."""
    rows = values.shape[0]
    voting = known.astype(np.uint8)

    def band(first: int) -> np.ndarray:
        last = min(first + BAND_ROWS, rows)
        top, bottom = max(first - radius, 0), min(last + radius, rows)
        median = cv2.ximgproc.weightedMedianFilter(guide[top:bottom], values[top:bottom], radius, sigma=sigma,
                                                   weightType=cv2.ximgproc.WMF_EXP, mask=voting[top:bottom])
        return median[first - top:last - top]

    with ThreadPoolExecutor(max(1, cv2.getNumThreads())) as pool:
        return np.vstack(list(pool.map(band, range(0, rows, BAND_ROWS))))


def snap_to_edges(disparity: np.ndarray, reference: np.ndarray, *, radius: int = RADIUS, sigma: float = SIGMA,
                  neighbours: int = NEIGHBOURS, min_move: float = MIN_MOVE) -> np.ndarray:
    """The weighted median of ``disparity`` guided by ``reference`` (module docstring).

    Args:
        disparity: (H, W) float map; non-finite values are left as they are and do not vote.
        reference: (H, W) band the map is in the view of (the left band).
        radius, sigma: the window's half-side in px and the grey-level spread of the weights.
        neighbours: half-side of the window a moved pixel's sub-pixel value comes from.
        min_move: px; smaller moves are not taken.

    Returns:
        (H, W) float32: each pixel the median's value where it moved the pixel by more than
        ``min_move`` and by more than a quantisation level (the span / 255), as the mean of its
        neighbours' values within one level of it; the pixel's own value elsewhere.
    """
    disparity = np.asarray(disparity, np.float32)
    finite = np.isfinite(disparity)
    if not finite.any():
        return disparity.copy()
    low, high = float(disparity[finite].min()), float(disparity[finite].max())
    level = max((high - low) / 255.0, 1e-3)
    dense = np.where(finite, disparity, np.float32(low))
    median = banded_weighted_median(guide_band(reference), dense, finite, radius=radius, sigma=sigma)
    moved = finite & (np.abs(median - dense) > max(level, min_move))
    if not moved.any():
        return disparity.copy()
    total = np.zeros(disparity.shape, np.float32)
    count = np.zeros(disparity.shape, np.float32)
    padded = np.pad(dense, neighbours, mode="edge")
    padded_finite = np.pad(finite, neighbours, mode="edge")
    rows, columns = disparity.shape
    for dy in range(2 * neighbours + 1):
        for dx in range(2 * neighbours + 1):
            value = padded[dy:dy + rows, dx:dx + columns]
            close = padded_finite[dy:dy + rows, dx:dx + columns] & (np.abs(value - median) <= level)
            total += np.where(close, value, np.float32(0))
            count += close
    snapped = np.where(count > 0, total / np.maximum(count, 1), median)
    return np.where(moved, snapped, disparity).astype(np.float32)
