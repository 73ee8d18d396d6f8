"""Confidence stage: how far each matcher trusts each of its valid estimates.

Every kernel ends with one of these functions and hands the map on in
:attr:`~cade_cli.matching.base.DisparityResult.confidence`: (H, W) float32 in [0, 1],
higher = more likely right, exactly 0 where the estimate is invalid. The values rank the
pixels of one map (mask what the matcher is unsure of with ``confidence >= t``, or drop
its least confident share); they are not calibrated probabilities, and each matcher
measures something else:

* ``census-sgm`` / ``zncc-sgm``: :func:`peak_ratio_confidence` of the aggregated SGM cost,
  ``1 - C(best) / C(second best)``, the runner-up taken at least 2 levels away from the
  winner. The left-right check is already the validity; its residual (0..1 px) ranked
  worse than the ratio and added nothing to it (docs/confidence.md).
* ``sgbm``: OpenCV returns no costs and already applies its left-right check
  (``disp12MaxDiff``) and uniqueness test to the validity, so
  :func:`neighbourhood_confidence` grades the valid pixels by their surroundings: the
  share of valid pixels around them and how much the disparity varies there.
* ``cade``: :func:`network_confidence`: the mean of the network's own vote,
  ``exp(-uncertainty / 2 px)`` (the spread of its soft-argmin distribution), and the
  refinement's, ``exp(-|SGBM - network| / 2 px)`` where SGBM's full-resolution match was
  accepted (0 where it was not). ``cade-network`` has only the first vote.

Each costs a few per cent of its matcher's time (docs/confidence.md).
"""

from __future__ import annotations

import cv2
import numpy as np

from cade_cli.matching.cost import CostVolume

VALID_SHARE_WINDOW = 15
"""Side (px) of the window in which :func:`neighbourhood_confidence` counts valid pixels."""
SPREAD_WINDOW = 5
"""Side (px) of the window over which it measures the disparity's standard deviation."""
SPREAD_SCALE = 2.0
"""Standard deviation (px) at which that factor falls to 1/e."""
UNCERTAINTY_SCALE = 2.0
"""Network uncertainty (px) at which :func:`network_confidence`'s network vote falls to 1/e."""
AGREEMENT_SCALE = 2.0
"""|SGBM - network| (px) at which its refinement vote falls to 1/e."""


def peak_ratio_confidence(cost: CostVolume, best: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``1 - C(best) / C(runner-up)`` of a non-negative, lower-is-better cost volume.

    The runner-up is the lowest cost at least 2 levels from ``best``: the levels next to
    the winner belong to the same minimum. Near 1: the winner stands out; near 0: another
    disparity costs about as much (repetitive texture, no texture, occlusion). Where both
    costs are 0 the pixel is ambiguous (0); with fewer than 4 levels there is no
    runner-up (1).

    Args:
        cost: (H, W, D) volume, lower is better, non-negative (SGM's aggregated cost).
        best: (H, W) integer index of the winning level (:func:`~cade_cli.matching.disparity.best_level`).
        valid: (H, W) bool; the confidence is 0 where it is False.

    Returns:
        (H, W) float32 in [0, 1].
    """
    if not cost.lower_is_better:
        raise ValueError("the peak ratio needs a lower-is-better, non-negative cost volume")
    values = cost.values
    count = values.shape[2]
    if count < 4:
        return np.asarray(valid, np.float32)
    top = np.iinfo(values.dtype).max if np.issubdtype(values.dtype, np.integer) else np.inf
    winner = np.take_along_axis(values, best[..., None], axis=2)[..., 0].astype(np.float32)
    runner_up = np.empty(best.shape, np.float32)
    rows = 32  # blocks of rows: the masked copy stays in cache
    for start in range(0, values.shape[0], rows):
        block = values[start:start + rows].copy()
        block_best = best[start:start + rows, :, None]
        for offset in (-1, 0, 1):
            np.put_along_axis(block, np.clip(block_best + offset, 0, count - 1), top, axis=2)
        runner_up[start:start + rows] = block.min(axis=2)
    ratio = np.divide(winner, runner_up, out=np.ones_like(winner), where=runner_up > 0)
    return np.where(valid, np.clip(1.0 - ratio, 0.0, 1.0), 0.0).astype(np.float32)


def neighbourhood_confidence(disparity: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Confidence of a matcher that gives no costs, from its map alone.

    ``share * exp(-spread / SPREAD_SCALE)`` at valid pixels: ``share`` is the fraction of
    valid pixels in the ``VALID_SHARE_WINDOW`` square around the pixel (rejects cluster
    where matching fails: occlusions, weak texture), ``spread`` the standard deviation
    (px) of the valid disparities in the ``SPREAD_WINDOW`` square (a noisy surface).

    Args:
        disparity: (H, W) float disparity, px; ignored where ``valid`` is False.
        valid: (H, W) bool.

    Returns:
        (H, W) float32 in [0, 1], 0 where ``valid`` is False.
    """
    mask = np.asarray(valid, bool)
    weight = mask.astype(np.float32)
    values = np.where(mask, disparity, 0).astype(np.float32)
    share = cv2.blur(weight, (VALID_SHARE_WINDOW, VALID_SHARE_WINDOW))
    box = (SPREAD_WINDOW, SPREAD_WINDOW)
    count = np.maximum(cv2.blur(weight, box), np.float32(1e-6))
    mean = cv2.blur(values, box) / count
    spread = np.sqrt(np.maximum(cv2.blur(values * values, box) / count - mean * mean, 0))
    confidence = np.clip(share, 0, 1) * np.exp(-spread / np.float32(SPREAD_SCALE))
    return np.where(mask, confidence, 0).astype(np.float32)


def network_confidence(uncertainty: np.ndarray, valid: np.ndarray, *,
                       agreement: np.ndarray | None = None) -> np.ndarray:
    """Confidence of the learned matcher from the network's uncertainty and the refinement.

    The network votes ``exp(-uncertainty / UNCERTAINTY_SCALE)``; with ``agreement``, the
    refinement votes ``exp(-agreement / AGREEMENT_SCALE)`` where it is finite and 0
    elsewhere, and the confidence is the mean of the two votes.

    Args:
        uncertainty: (H, W) float, px: the standard deviation of the network's disparity
            distribution (its ``uncertainty`` output).
        valid: (H, W) bool; the confidence is 0 where it is False.
        agreement: (H, W) float, px: |SGBM's match - the network's disparity| where the
            refinement took SGBM's match, ``inf`` where it kept the network's value; None
            without a refinement.

    Returns:
        (H, W) float32 in [0, 1].
    """
    vote = np.exp(-np.maximum(np.asarray(uncertainty, np.float32), 0) / np.float32(UNCERTAINTY_SCALE))
    if agreement is not None:
        vote = 0.5 * vote + 0.5 * np.exp(-np.asarray(agreement, np.float32) / np.float32(AGREEMENT_SCALE))
    return np.where(valid, vote, 0).astype(np.float32)
