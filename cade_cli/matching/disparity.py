"""Disparity stage (winner-takes-all + sub-pixel), validation (left-right check, visibility)
and the one fill stage (:func:`densify`)."""

from __future__ import annotations

import numpy as np

from cade_cli.matching.cost import CostVolume, overlap


def _lower_is_better(cost: CostVolume) -> np.ndarray:
    """The volume's values, negated when higher is better (unsigned ones as float32)."""
    values = cost.values
    if not cost.lower_is_better:
        values = -values.astype(np.float32) if np.issubdtype(values.dtype, np.unsignedinteger) else -values
    return values


def best_level(cost: CostVolume) -> np.ndarray:
    """(H, W) int index k of the best cost per pixel (the first of equal ones); the
    disparity is ``cost.disparity_range.minimum + k``."""
    return np.argmin(_lower_is_better(cost), axis=2)


def winner_takes_all(cost: CostVolume, *, subpixel: bool = True, best: np.ndarray | None = None) -> np.ndarray:
    """Best disparity per pixel of the reference view of ``cost``.

    With ``subpixel``, a parabola through the best cost and its two neighbours refines
    the integer winner (offset clipped to +-0.5 px; none at the ends of the range).
    ``best`` is :func:`best_level` of ``cost`` when the caller already has it (the
    confidence stage needs it too).

    Returns:
        (H, W) float32 disparity in pixels.
    """
    values = _lower_is_better(cost)
    if best is None:
        best = np.argmin(values, axis=2)
    disparity = best.astype(np.float32) + np.float32(cost.disparity_range.minimum)
    if not subpixel or values.shape[2] < 3:
        return disparity
    inner = np.clip(best, 1, values.shape[2] - 2)

    def at(index: np.ndarray) -> np.ndarray:  # float, as integer costs would wrap when subtracted
        return np.take_along_axis(values, index[..., None], axis=2)[..., 0].astype(np.float32)

    before, centre, after = at(inner - 1), at(inner), at(inner + 1)
    curvature = before - 2.0 * centre + after
    usable = (best == inner) & (curvature > 0)
    offset = np.where(usable, (before - after) / (2.0 * np.where(usable, curvature, 1.0)), 0.0)
    return disparity + np.clip(offset, -0.5, 0.5).astype(np.float32)


def right_view_cost(cost: CostVolume) -> CostVolume:
    """The same costs indexed from the right view: ``R[y, xr, k] = C[y, xr + d_k, k]``.

    Right pixels whose match would lie outside the left image get the worst cost.
    """
    values = cost.values
    worst = values.max() if cost.lower_is_better else values.min()
    right = np.full_like(values, worst)
    width = values.shape[1]
    for k, d in enumerate(range(cost.disparity_range.minimum, cost.disparity_range.maximum + 1)):
        left_cols, right_cols = overlap(width, d)
        right[:, right_cols, k] = values[:, left_cols, k]
    return CostVolume(right, cost.disparity_range, cost.lower_is_better)


def left_right_check(left_disparity: np.ndarray, right_disparity: np.ndarray, *, tolerance: float = 1.0) -> np.ndarray:
    """Pixels whose left disparity is confirmed by the right view.

    Left pixel (y, x) with disparity d is consistent when the right view's disparity at
    (y, round(x - d)) is within ``tolerance`` px of d. Pixels whose match falls outside
    the right image are inconsistent.

    Returns:
        (H, W) bool mask, True = consistent.
    """
    height, width = left_disparity.shape
    columns = np.arange(width)[None, :]
    matched = np.rint(columns - left_disparity).astype(np.int64)
    inside = (matched >= 0) & (matched < width)
    rows = np.arange(height)[:, None]
    seen = right_disparity[rows, np.clip(matched, 0, width - 1)]
    return inside & (np.abs(seen - left_disparity) <= tolerance)


def visible_in_right_view(disparity: np.ndarray, *, tolerance: float = 1.0) -> np.ndarray:
    """Pixels of the left view that the right view sees, judged from the left disparity alone.

    Left pixel x with disparity d lands on x - d in the right view. A nearer surface
    hides it when some pixel x' > x on the same row lands left of it: x' - d(x') <
    x - d(x) - ``tolerance`` (x' > x then implies d(x') > d(x)). Pixels landing outside
    the right image are not visible either. One pass per row (a running minimum from
    the right), so it costs far less than a second, right-view disparity map.

    Returns:
        (H, W) bool mask, True = visible (not occluded, inside the right view).
    """
    disparity = np.asarray(disparity, np.float32)
    width = disparity.shape[1]
    landing = np.arange(width, dtype=np.float32)[None, :] - disparity
    nearest_right = np.minimum.accumulate(landing[:, ::-1], axis=1)[:, ::-1]  # min over x' >= x
    hidden = np.zeros(disparity.shape, bool)
    hidden[:, :-1] = nearest_right[:, 1:] < landing[:, :-1] - tolerance
    return ~hidden & (landing >= 0) & (landing <= width - 1)


def fill_invalid_along_rows(disparity: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Dense copy of ``disparity`` with invalid pixels filled from the background side.

    Each invalid pixel takes the smaller (farther, i.e. background) of the nearest valid
    values to its left and right on the same row, or the only one that exists, as
    MiddEval3 does before scoring. Rows without any valid pixel take the median of all
    valid pixels; with no valid pixel at all the map is returned unchanged.

    Args:
        disparity: (H, W) float disparity; values at invalid pixels are ignored.
        valid: (H, W) bool mask.

    Returns:
        (H, W) float32 array; ``disparity`` is not modified.
    """
    disparity = np.asarray(disparity, np.float32)
    valid = np.asarray(valid, bool)
    if valid.all() or not valid.any():
        return disparity.copy()
    height, width = disparity.shape
    columns = np.arange(width, dtype=np.int32)
    last_valid = np.maximum.accumulate(np.where(valid, columns, np.int32(-1)), axis=1)
    next_valid = np.minimum.accumulate(np.where(valid, columns, np.int32(width))[:, ::-1], axis=1)[:, ::-1]
    # Gather through flat indices: much faster than indexing with a (rows, columns) pair.
    row_starts = (np.arange(height, dtype=np.int64) * width)[:, None]
    flat = disparity.ravel()
    from_left = flat[row_starts + np.maximum(last_valid, 0)]
    from_left[last_valid < 0] = np.inf
    from_right = flat[row_starts + np.minimum(next_valid, width - 1)]
    from_right[next_valid >= width] = np.inf
    filled = np.where(valid, disparity, np.minimum(from_left, from_right))
    empty_rows = ~valid.any(axis=1)
    if empty_rows.any():
        filled[empty_rows] = np.median(disparity[valid])
    return filled.astype(np.float32, copy=False)


def densify(disparity: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The fill stage: a dense map from a matcher's unfilled one.

    Pixels where ``valid`` is False or ``disparity`` is not finite take the background-side
    value along their row (:func:`fill_invalid_along_rows`, as MiddEval3 fills before
    scoring). With no valid pixel at all the map is all zeros. This is the only place
    where the CLI, the registration and the benchmark fill a disparity map.

    Args:
        disparity: (H, W) float disparity in pixels, NaN (or anything) where invalid.
        valid: (H, W) bool, True where the matcher trusts its estimate.

    Returns:
        (H, W) float32, finite everywhere; the inputs are not modified.
    """
    disparity, valid = np.asarray(disparity), np.asarray(valid, bool)
    valid = valid & np.isfinite(disparity)
    if not valid.any():
        return np.zeros(disparity.shape, np.float32)
    return fill_invalid_along_rows(np.where(valid, disparity, np.float32(0)), valid)
