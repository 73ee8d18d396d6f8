"""Disparity error metrics, scored the Middlebury way; one definition of each.

Conventions (see ``shared/data/README.md``):

* Disparities are in pixels of the image they belong to; ground truth (GT) marks
  unknown pixels with NaN (or +-inf) in memory -- readers convert a format's own marker
  (0 in PNG, inf in PFM) once, where the file is read. Every metric scores only pixels
  whose GT is finite, intersected with the caller's mask.
* Predictions are scored *dense* (MiddEval3). The metrics never fill: a matcher's
  unfilled map goes through the one fill stage,
  :func:`cade_cli.matching.disparity.densify`, first (the protocols do that for every
  map they return), and a NaN left at a scored pixel is an error.
* Regions: ``all`` = every pixel with finite GT; ``nonocc`` = those that the dataset's
  occlusion mask marks non-occluded (MiddEval3: ``mask0nocc.png == 255``).
"""

from __future__ import annotations

import numpy as np

from cade_cli.errors import CadeError

BAD_THRESHOLDS: tuple[float, ...] = (1.0, 2.0, 3.0, 5.0)
"""Thresholds tau in pixels of the bad-pixel rates ``bad<tau>`` (|d - d_gt| > tau)."""

REGIONS: tuple[str, ...] = ("all", "nonocc")
"""Pixel sets scored by :func:`score`; ``nonocc`` only when an occlusion mask is given."""


def _bad_name(threshold: float) -> str:
    return f"bad{threshold:g}"


METRIC_NAMES: tuple[str, ...] = tuple(
    f"{metric}_{region}"
    for region in REGIONS
    for metric in ("epe", *(_bad_name(t) for t in BAD_THRESHOLDS))
) + ("invalid",)
"""Every key :func:`score` can return, in a stable order for table columns:
``epe_all, bad1_all, bad2_all, bad3_all, bad5_all, epe_nonocc, ..., bad5_nonocc, invalid``."""


def _check_same_shape(**arrays: np.ndarray) -> None:
    shapes = {name: np.shape(array) for name, array in arrays.items()}
    reference_name, reference = next(iter(shapes.items()))
    if len(reference) != 2:
        raise CadeError(f"{reference_name} must be a (H, W) disparity map, got shape {reference}")
    for name, shape in shapes.items():
        if shape != reference:
            raise CadeError(
                f"{name} has shape {shape} but {reference_name} has shape {reference}; "
                f"score maps of the same resolution (resize and rescale the disparity first)"
            )


def _check_bool(name: str, mask: np.ndarray) -> None:
    if mask.dtype != bool:
        raise CadeError(f"{name} must be a bool mask, got dtype {mask.dtype}; compare it, e.g. mask == 255")


def _scored_errors(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """|pred - gt| (float64, 1-D) over ``valid & isfinite(gt)``; checks inputs."""
    pred, gt, valid = np.asarray(pred), np.asarray(gt), np.asarray(valid)
    _check_same_shape(pred=pred, gt=gt, valid=valid)
    _check_bool("valid", valid)
    scored = valid & np.isfinite(gt)
    errors = np.abs(pred[scored].astype(np.float64) - gt[scored].astype(np.float64))
    if not np.isfinite(errors).all():
        count = int((~np.isfinite(errors)).sum())
        raise CadeError(
            f"prediction is NaN or infinite at {count} scored pixels; fill it with "
            f"cade_cli.matching.densify(disparity, valid) before scoring"
        )
    return errors


def end_point_error(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> float:
    """Mean absolute disparity error (EPE) in pixels.

    Args:
        pred: (H, W) float predicted disparity in pixels; must be finite wherever scored.
        gt: (H, W) float GT disparity in pixels; NaN / inf = unknown.
        valid: (H, W) bool mask of pixels to score. It is ANDed with ``isfinite(gt)``,
            so pixels without GT never count.

    Returns:
        mean of |pred - gt| over the scored pixels, in pixels; NaN when no pixel is
        scored (empty mask or no finite GT), without a warning.

    Raises:
        CadeError: shapes differ, ``valid`` is not bool, or ``pred`` is non-finite at a
            scored pixel.
    """
    errors = _scored_errors(pred, gt, valid)
    return float(errors.mean()) if errors.size else float("nan")


def bad_pixel_rate(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray, *, threshold: float) -> float:
    """Percentage of scored pixels whose error exceeds ``threshold`` (strictly: > tau).

    Args:
        pred, gt, valid: as for :func:`end_point_error` (scored pixels are
            ``valid & isfinite(gt)``).
        threshold: tau in pixels, >= 0. An error of exactly tau is *not* bad.

    Returns:
        percentage in [0, 100]; NaN when no pixel is scored.
    """
    if not threshold >= 0:
        raise CadeError(f"threshold must be >= 0 px, got {threshold}")
    errors = _scored_errors(pred, gt, valid)
    return float(100.0 * np.count_nonzero(errors > threshold) / errors.size) if errors.size else float("nan")


def invalid_percentage(pred: np.ndarray, pred_valid: np.ndarray) -> float:
    """Percentage in [0, 100] of the image's pixels that the matcher rejected
    (``~pred_valid``) or left non-finite; 0 for an empty map."""
    pred, pred_valid = np.asarray(pred), np.asarray(pred_valid)
    _check_same_shape(pred=pred, pred_valid=pred_valid)
    _check_bool("pred_valid", pred_valid)
    valid = pred_valid & np.isfinite(pred)
    return float(100.0 * (1.0 - valid.mean())) if valid.size else 0.0


def score(
    pred: np.ndarray,
    gt: np.ndarray,
    *,
    nonocc: np.ndarray | None = None,
    pred_valid: np.ndarray | None = None,
) -> dict[str, float]:
    """All metrics of one dense prediction against its GT, keyed as in :data:`METRIC_NAMES`.

    Args:
        pred: (H, W) float predicted disparity in pixels, dense (finite wherever GT is):
            a matcher's map after :func:`cade_cli.matching.disparity.densify`.
        gt: (H, W) float GT disparity in pixels; NaN / inf = unknown (not scored).
        nonocc: (H, W) bool, True = non-occluded; adds the ``*_nonocc`` keys.
        pred_valid: (H, W) bool, the matcher's own validity (before the fill); None =
            every finite pixel valid. Only ``invalid`` depends on it.

    Returns:
        ``epe_all`` (px), ``bad1_all`` ... ``bad5_all`` (%), the same with ``_nonocc``
        when ``nonocc`` is given, and ``invalid``: percentage of *all* image pixels that
        the matcher rejected (:func:`invalid_percentage`). Keys follow :data:`METRIC_NAMES`
        order. Errors are NaN when a region has no pixel with finite GT.

    Raises:
        CadeError: shapes differ, a mask is not bool, ``pred`` is not finite at a pixel
            with GT.
    """
    pred = np.asarray(pred)
    if pred_valid is None:
        pred_valid = np.ones(pred.shape, bool)
    regions = {"all": np.ones(pred.shape, bool)}
    if nonocc is not None:
        regions["nonocc"] = np.asarray(nonocc)
    results: dict[str, float] = {}
    for region, mask in regions.items():
        results[f"epe_{region}"] = end_point_error(pred, gt, mask)
        for threshold in BAD_THRESHOLDS:
            results[f"{_bad_name(threshold)}_{region}"] = bad_pixel_rate(pred, gt, mask, threshold=threshold)
    results["invalid"] = invalid_percentage(pred, np.asarray(pred_valid))
    return {name: results[name] for name in METRIC_NAMES if name in results}
