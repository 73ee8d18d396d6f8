"""Pseudo ground truth for one camera of a plane-registered array, from its same-band
neighbours: classical matchers, several baselines, kept only where independent estimates agree.

A real array rarely has ground truth, but a camera usually has neighbours that see nearly
the same band. Each such *partner* is matched against the reference camera along its own
baseline (:func:`~cade_cli.rigs.array.match_camera`: both views turned so that the
baseline is +x, a signed range, the matcher's left-right check, back in the reference
view), giving an estimate of the one plane-relative disparity ``delta`` in **px per unit
baseline** (:mod:`cade_cli.rigs.array`). Then:

1. per partner, every matcher of :data:`PSEUDO_GT_METHODS` must have an estimate and the
   estimates must lie within ``tolerance`` of each other; the partner's estimate is their
   mean (NaN elsewhere), so no single matcher's habits make the truth;
2. across partners, a pixel is kept when the two closest partner estimates (two different
   cameras: different baselines or directions) lie within ``tolerance``; its value is the
   mean of the partner estimates within ``tolerance / 2`` of that pair's midpoint (the pair
   itself always is). Elsewhere it is NaN.

The learned matcher is never used here: a judge built from it would favour it.
:func:`rereferenced` turns a rig's plane mappings so that any of its cameras can be the
reference.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.rigs.array import MIN_OVERLAP, match_camera, warp_camera
from cade_cli.rigs.array_geometry import array_geometry
from cade_cli.rigs.rig import PlaneMapping, Rig

PSEUDO_GT_METHODS: tuple[str, ...] = ("sgbm", "census-sgm")
"""The classical matchers whose agreement makes each partner's estimate (never ``cade``)."""

PSEUDO_GT_PREPROCESS = "none"
"""The partners see neighbouring bands of the reference: the matchers run on the raw bands."""

AGREEMENT_TOLERANCE = 0.5
"""Largest spread, px per unit baseline, between estimates that count as agreeing."""

PSEUDO_GT_SEARCH: tuple[float, float] = (-8.0, 8.0)
"""Signed range searched, px per unit baseline (each partner: times its baseline ratio)."""


@dataclass(frozen=True)
class PseudoTruth:
    """The pseudo ground truth of a reference view.

    Attributes:
        disparity: (H, W) float32, px per unit baseline, positive nearer than the plane;
            NaN where fewer than two partners agree.
        partners: the partner cameras' names, in the order of ``estimates``.
        estimates: per partner (H, W) float32, its matchers' agreed estimate, NaN elsewhere.
        unit: the unit baseline, metres.
    """

    disparity: np.ndarray
    partners: tuple[str, ...]
    estimates: tuple[np.ndarray, ...]
    unit: float

    @property
    def coverage(self) -> float:
        """Share of the reference view with a pseudo ground truth."""
        return float(np.isfinite(self.disparity).mean())


def rereferenced(rig: Rig, reference: str) -> Rig:
    """``rig`` with ``reference`` as its reference camera: each camera's plane mapping is
    composed with the inverse of the new reference's (an affine stays an affine), the new
    reference's own is exactly the identity. Positions are unchanged (baselines are taken
    relative to the reference's position).

    Raises:
        CadeError: an unknown camera, a camera without a plane mapping, a mapping that
            cannot be inverted.
    """
    new = rig.camera(reference)
    if any(camera.to_reference is None for camera in rig.cameras):
        raise CadeError("every camera needs a to_reference plane mapping to change the reference")
    try:
        inverse = np.linalg.inv(new.to_reference.homography)
    except np.linalg.LinAlgError:
        raise CadeError(f"camera {reference}: its to_reference cannot be inverted") from None
    cameras = []
    for camera in rig.cameras:
        mapping = camera.to_reference
        if camera.name == new.name:
            composed = PlaneMapping("affine", np.array([[1.0, 0, 0], [0, 1.0, 0]]))
        elif mapping.kind == "affine" and new.to_reference.kind == "affine":
            composed = PlaneMapping("affine", (inverse @ mapping.homography)[:2])
        else:
            product = inverse @ mapping.homography
            composed = PlaneMapping("homography", product / product[2, 2])
        cameras.append(dataclasses.replace(camera, to_reference=composed))
    return dataclasses.replace(rig, reference=reference, cameras=tuple(cameras))


def agreeing_estimates(estimates: Sequence[np.ndarray], tolerance: float) -> np.ndarray:
    """The across-partner rule (module docstring, step 2) on (H, W) maps with NaN holes.

    Returns:
        (H, W) float32: the mean of the estimates near the closest agreeing pair, NaN
        where no two estimates lie within ``tolerance``.
    """
    stack = np.stack([np.asarray(e, np.float32) for e in estimates])
    if len(stack) < 2:
        return np.full(stack.shape[1:], np.nan, np.float32)
    best_gap = np.full(stack.shape[1:], np.inf, np.float32)
    midpoint = np.full(stack.shape[1:], np.nan, np.float32)
    for i in range(len(stack)):
        for j in range(i + 1, len(stack)):
            with np.errstate(invalid="ignore"):
                gap = np.abs(stack[i] - stack[j])
                closer = gap < best_gap  # False where either is NaN
            best_gap = np.where(closer, gap, best_gap)
            midpoint = np.where(closer, (stack[i] + stack[j]) / 2, midpoint)
    with np.errstate(invalid="ignore"):
        near = np.abs(stack - midpoint[None]) <= tolerance / 2 + 1e-6
    total = np.where(near, stack, 0).sum(axis=0)
    count = near.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        kept = (best_gap <= tolerance) & (count >= 2)
        return np.where(kept, total / np.maximum(count, 1), np.nan).astype(np.float32)


def partner_estimate(votes: Sequence[np.ndarray], tolerance: float) -> np.ndarray:
    """One partner's estimate from its matchers' (H, W) votes (module docstring, step 1):
    their mean where all are finite and within ``tolerance`` of each other, else NaN."""
    stack = np.stack([np.asarray(v, np.float32) for v in votes])
    with np.errstate(invalid="ignore"):
        agree = np.all(np.isfinite(stack), axis=0) & (stack.max(axis=0) - stack.min(axis=0) <= tolerance)
    return np.where(agree, stack.mean(axis=0), np.nan).astype(np.float32)


def pseudo_ground_truth(
    rig: Rig,
    images: Mapping[str, np.ndarray],
    partners: Sequence[str],
    *,
    methods: Sequence[str] = PSEUDO_GT_METHODS,
    tolerance: float = AGREEMENT_TOLERANCE,
    search: tuple[float, float] = PSEUDO_GT_SEARCH,
) -> PseudoTruth:
    """The pseudo ground truth of ``rig``'s reference view from ``partners``.

    Args:
        rig: a plane-registered rig (``to_reference`` + ``position`` for every camera);
            its reference is the view the truth is for (:func:`rereferenced` picks one).
        images: camera name -> (H, W) band, for the reference and every partner.
        partners: two or more cameras that see (nearly) the reference's band.
        methods: classical matchers (:data:`PSEUDO_GT_METHODS`); the learned one is refused.
        tolerance: agreement tolerance, px per unit baseline.
        search: signed range, px per unit baseline.

    Raises:
        CadeError: fewer than two partners, the reference among them, a learned matcher,
            a missing image, a partner that barely overlaps the reference view.
    """
    if len(set(partners)) < 2 or rig.reference in partners:
        raise CadeError(f"a pseudo ground truth needs two or more partners other than the reference "
                        f"{rig.reference}, got {', '.join(partners) or 'none'}")
    if any(method.startswith("cade") for method in methods):
        raise CadeError("the pseudo ground truth must not come from the learned matcher it is meant to judge")
    missing = [name for name in (rig.reference, *partners) if name not in images]
    if missing:
        raise CadeError(f"no image for camera(s) {', '.join(missing)}")
    geometry = array_geometry(rig)
    reference = np.asarray(images[rig.reference], np.float32)
    by_name = {camera.name: camera for camera in geometry.cameras}
    estimates = []
    for name in partners:
        camera = by_name[rig.camera(name).name]
        warped, inside = warp_camera(np.asarray(images[name], np.float32), camera, reference.shape)
        if inside.mean() < MIN_OVERLAP:
            raise CadeError(f"camera {name} sees {100 * inside.mean():.1f}% of the reference view; check its mapping")
        votes = [match_camera(reference, warped, inside, camera, unit=geometry.unit, search=search, method=method,
                              preprocess=PSEUDO_GT_PREPROCESS) for method in methods]
        estimates.append(partner_estimate(votes, tolerance))
    return PseudoTruth(agreeing_estimates(estimates, tolerance), tuple(partners), tuple(estimates), geometry.unit)
