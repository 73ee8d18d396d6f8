"""Aggregation stage: semi-global matching (Hirschmüller, PAMI 2008) over 8 paths.

Along each path r the cost is propagated as

    L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d+-1) + P1, min_k L_r(p-r, k) + P2)
                - min_k L_r(p-r, k)

and the eight L_r are summed. Paths start fresh at the image border (L_r = C there).

The recursion is sequential along a path but independent across the rows (or columns)
it sweeps, so each sweep is a loop over columns (or rows) with NumPy working on whole
(rows x disparities) slices. The six paths with a horizontal component advance one
column per step and run together in one stacked array (three left-to-right, three
right-to-left); the two vertical paths advance one row per step. See
:func:`cade_cli.matching.reference.sgm_aggregate_reference` for the plain loop version
the tests compare against.
"""

from __future__ import annotations

import numpy as np

from cade_cli.matching.cost import CostVolume


def sgm_aggregate(cost: CostVolume, *, p1: float, p2: float) -> CostVolume:
    """Sum of the 8-path SGM aggregations of a lower-is-better cost volume.

    Args:
        cost: (H, W, D) volume, lower is better.
        p1: penalty for a disparity change of 1 px between neighbours along a path.
        p2: penalty for larger changes (p2 >= p1), in the cost volume's units.

    Returns:
        A new (H, W, D) float32 volume, lower is better, in cost units x 8.
    """
    if not cost.lower_is_better:
        raise ValueError("SGM needs a lower-is-better cost volume; negate it first")
    if p2 < p1:
        raise ValueError(f"p2 ({p2}) must be >= p1 ({p1})")
    values = np.ascontiguousarray(cost.values, dtype=np.float32)
    total = _sweep(values, p1, p2, horizontal=False)
    by_column = np.ascontiguousarray(values.transpose(1, 0, 2))
    total += _sweep(by_column, p1, p2, horizontal=True).transpose(1, 0, 2)
    return CostVolume(total, cost.disparity_range)


def _sweep(values: np.ndarray, p1: float, p2: float, *, horizontal: bool) -> np.ndarray:
    """Aggregate along the paths that advance over axis 0 of ``values`` (N, M, D).

    ``horizontal=True``: axis 0 is the image column (``values`` is the transposed
    volume) and the six paths with a horizontal step run; axis 1 is the image row, and
    a diagonal path takes its predecessor from the neighbouring row.
    ``horizontal=False``: axis 0 is the image row and the two vertical paths run.
    """
    steps, lanes, count = values.shape
    # Each path is (direction along axis 0, offset along axis 1 of its predecessor).
    if horizontal:
        paths = [(+1, -1), (+1, 0), (+1, +1), (-1, -1), (-1, 0), (-1, +1)]
    else:
        paths = [(+1, 0), (-1, 0)]
    n_paths = len(paths)
    total = np.zeros_like(values)
    previous = np.zeros((n_paths, lanes, count), np.float32)  # zeros = fresh start
    shifted = np.zeros_like(previous)
    best = np.empty_like(previous)
    neighbour = np.empty((n_paths, lanes, count - 1), np.float32)
    # Forward paths come first in ``paths``, so both groups are plain slices (views).
    forward, backward = slice(0, n_paths // 2), slice(n_paths // 2, n_paths)

    for step in range(steps):
        positions = (step, steps - 1 - step)
        # Predecessors: shift each path's previous lane array by its lane offset,
        # zero (= fresh start) where the predecessor would fall outside the image.
        for i, (direction, offset) in enumerate(paths):
            if step == 0 or offset == 0:
                shifted[i] = previous[i] if step else 0.0
            elif offset > 0:
                shifted[i, offset:] = previous[i, :-offset]
                shifted[i, :offset] = 0.0
            else:
                shifted[i, :offset] = previous[i, -offset:]
                shifted[i, offset:] = 0.0
        minimum = shifted.min(axis=2, keepdims=True)
        np.minimum(shifted, minimum + np.float32(p2), out=best)
        np.add(shifted[:, :, :-1], np.float32(p1), out=neighbour)
        np.minimum(best[:, :, 1:], neighbour, out=best[:, :, 1:])
        np.add(shifted[:, :, 1:], np.float32(p1), out=neighbour)
        np.minimum(best[:, :, :-1], neighbour, out=best[:, :, :-1])
        best -= minimum
        best[forward] += values[positions[0]]
        best[backward] += values[positions[1]]
        previous, best = best, previous
        total[positions[0]] += previous[forward].sum(axis=0)
        total[positions[1]] += previous[backward].sum(axis=0)
    return total
