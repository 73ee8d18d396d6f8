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
  occlusion mask marks non-occluded (MiddEval3: ``mask0nocc.png == 255``); ``edge`` and
  ``occ`` = depth-edge and occluded pixels, defined once in
  :func:`cade_cli.evaluation.regions.region_masks`.
* Confidence (:attr:`cade_cli.matching.DisparityResult.confidence`) is scored by its
  sparsification curve (:func:`sparsification_curve`): how fast the EPE of the kept pixels
  falls when the least confident ones are removed first. Its area (``auc_conf_all``) lies
  between the oracle's (``auc_oracle_all``: pixels removed by their true error) and a
  random order's, which is ``epe_all`` itself.
"""

from __future__ import annotations

import numpy as np

from cade_cli.errors import CadeError

BAD_THRESHOLDS: tuple[float, ...] = (1.0, 2.0, 3.0, 5.0)
"""Thresholds tau in pixels of the bad-pixel rates ``bad<tau>`` (|d - d_gt| > tau)."""

REGIONS: tuple[str, ...] = ("all", "nonocc", "edge", "occ")
"""Pixel sets scored by :func:`score`; each but ``all`` only when its mask is given
(:func:`cade_cli.evaluation.regions.region_masks`)."""


def _bad_name(threshold: float) -> str:
    return f"bad{threshold:g}"


D1_THRESHOLDS: tuple[float, float] = (3.0, 0.05)
"""KITTI's D1 outlier: |d - d_gt| > 3 px AND > 5 % of d_gt (:func:`d1_rate`)."""

METRIC_NAMES: tuple[str, ...] = tuple(
    f"{metric}_{region}"
    for region in REGIONS
    for metric in ("epe", *(_bad_name(t) for t in BAD_THRESHOLDS), "d1")
) + ("invalid", "auc_conf_all", "auc_oracle_all")
"""Every key :func:`score` can return, in a stable order for table columns:
``epe_all, bad1_all, bad2_all, bad3_all, bad5_all, d1_all, epe_nonocc, ..., d1_nonocc``, the same
for ``edge`` and ``occ``, ``invalid``,
then the sparsification areas of the confidence and of the oracle (px, all pixels with GT;
only for predictions that carry a confidence)."""


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


def d1_rate(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> float:
    """KITTI's D1: percentage of scored pixels whose error is an outlier, i.e. exceeds both
    3 px and 5 % of the GT disparity (strictly, :data:`D1_THRESHOLDS`), as the KITTI 2015
    development kit counts them. Unlike ``bad3`` it forgives large near disparities a
    3 px miss that is small relative to them.

    Args:
        pred, gt, valid: as for :func:`end_point_error` (scored pixels are
            ``valid & isfinite(gt)``).

    Returns:
        percentage in [0, 100]; NaN when no pixel is scored.
    """
    pred, gt, valid = np.asarray(pred), np.asarray(gt), np.asarray(valid)
    errors = _scored_errors(pred, gt, valid)
    if not errors.size:
        return float("nan")
    reference = np.abs(gt[valid & np.isfinite(gt)].astype(np.float64))
    pixels, relative = D1_THRESHOLDS
    return float(100.0 * np.count_nonzero((errors > pixels) & (errors > relative * reference)) / errors.size)


def invalid_percentage(pred: np.ndarray, pred_valid: np.ndarray) -> float:
    """Percentage in [0, 100] of the image's pixels that the matcher rejected
    (``~pred_valid``) or left non-finite; 0 for an empty map."""
    pred, pred_valid = np.asarray(pred), np.asarray(pred_valid)
    _check_same_shape(pred=pred, pred_valid=pred_valid)
    _check_bool("pred_valid", pred_valid)
    valid = pred_valid & np.isfinite(pred)
    return float(100.0 * (1.0 - valid.mean())) if valid.size else 0.0


def sparsification_curve(errors: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sparsification curve: EPE of the pixels kept when the least confident go first.

    Pixels are removed in order of increasing ``confidence``; pixels of equal confidence
    leave in random order, and the curve is the expectation over that order (each error
    replaced by the mean error of its tie group), so a constant confidence gives the flat
    curve of a random order, at ``errors.mean()``. ``confidence = -errors`` gives the
    oracle's curve.

    Args:
        errors: (N,) absolute disparity errors in px, finite.
        confidence: (N,) real scores of the same pixels, higher = more trusted.

    Returns:
        ``(kept, epe)``: (N,) float64 arrays; ``kept[k - 1] = k / N`` is the fraction kept
        and ``epe[k - 1]`` the mean error of the k most confident pixels, px. Empty for N = 0.
    """
    errors = np.asarray(errors, np.float64).ravel()
    confidence = np.asarray(confidence).ravel()
    if errors.shape != confidence.shape:
        raise CadeError(f"errors has {errors.size} pixels but confidence {confidence.size}; give one score per error")
    if not (np.isfinite(errors).all() and np.isfinite(confidence).all()):
        raise CadeError("errors and confidence must be finite; score only pixels with GT, after densify")
    count = errors.size
    if count == 0:
        return np.empty(0), np.empty(0)
    order = np.argsort(-confidence, kind="stable")
    ranked, sorted_errors = confidence[order], errors[order]
    starts = np.flatnonzero(np.r_[True, ranked[1:] != ranked[:-1]])
    sizes = np.diff(np.r_[starts, count])
    tie_means = np.add.reduceat(sorted_errors, starts) / sizes
    kept = np.arange(1, count + 1, dtype=np.float64)
    return kept / count, np.cumsum(np.repeat(tie_means, sizes)) / kept


def sparsification_auc(errors: np.ndarray, confidence: np.ndarray) -> float:
    """Area under :func:`sparsification_curve` over the kept fraction (0, 1], px.

    The mean of the curve over its N points: ``errors.mean()`` for a random (or
    constant) confidence, the smallest possible value for the oracle order
    (``confidence = -errors``); lower is better. NaN for no pixel.
    """
    _, epe = sparsification_curve(errors, confidence)
    return float(epe.mean()) if epe.size else float("nan")


def score(
    pred: np.ndarray,
    gt: np.ndarray,
    *,
    nonocc: np.ndarray | None = None,
    edge: np.ndarray | None = None,
    occ: np.ndarray | None = None,
    pred_valid: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
) -> dict[str, float]:
    """All metrics of one dense prediction against its GT, keyed as in :data:`METRIC_NAMES`.

    Args:
        pred: (H, W) float predicted disparity in pixels, dense (finite wherever GT is):
            a matcher's map after :func:`cade_cli.matching.disparity.densify`.
        gt: (H, W) float GT disparity in pixels; NaN / inf = unknown (not scored).
        nonocc: (H, W) bool, True = non-occluded; adds the ``*_nonocc`` keys.
        edge, occ: (H, W) bool, depth-edge and occluded pixels
            (:func:`cade_cli.evaluation.regions.region_masks`); add the ``*_edge`` and
            ``*_occ`` keys.
        pred_valid: (H, W) bool, the matcher's own validity (before the fill); None =
            every finite pixel valid. Only ``invalid`` depends on it.
        confidence: (H, W) float, the matcher's confidence (higher = more trusted); adds
            ``auc_conf_all`` and ``auc_oracle_all`` (:func:`sparsification_auc` over all
            pixels with GT, px).

    Returns:
        ``epe_all`` (px), ``bad1_all`` ... ``bad5_all`` and ``d1_all`` (%, :func:`d1_rate`), the same with
        ``_nonocc``, ``_edge``, ``_occ`` for each of those masks given, ``invalid``: percentage of
        *all* image pixels that the matcher rejected (:func:`invalid_percentage`), and with
        ``confidence`` the two sparsification areas. Keys follow :data:`METRIC_NAMES` order.
        Errors are NaN when a region has no pixel with finite GT.

    Raises:
        CadeError: shapes differ, a mask is not bool, ``pred`` is not finite at a pixel
            with GT.
    """
    pred = np.asarray(pred)
    if pred_valid is None:
        pred_valid = np.ones(pred.shape, bool)
    regions = {"all": np.ones(pred.shape, bool)}
    for region, mask in (("nonocc", nonocc), ("edge", edge), ("occ", occ)):
        if mask is not None:
            regions[region] = np.asarray(mask)
    results: dict[str, float] = {}
    for region, mask in regions.items():
        results[f"epe_{region}"] = end_point_error(pred, gt, mask)
        for threshold in BAD_THRESHOLDS:
            results[f"{_bad_name(threshold)}_{region}"] = bad_pixel_rate(pred, gt, mask, threshold=threshold)
        results[f"d1_{region}"] = d1_rate(pred, gt, mask)
    results["invalid"] = invalid_percentage(pred, np.asarray(pred_valid))
    if confidence is not None:
        confidence = np.asarray(confidence)
        _check_same_shape(pred=pred, confidence=confidence)
        errors = _scored_errors(pred, gt, regions["all"])
        trusted = confidence[np.isfinite(np.asarray(gt))]
        results["auc_conf_all"] = sparsification_auc(errors, trusted)
        results["auc_oracle_all"] = sparsification_auc(errors, -errors)
    return {name: results[name] for name in METRIC_NAMES if name in results}
