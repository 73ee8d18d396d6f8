"""The pixel sets a prediction is scored on besides all pixels: non-occluded, depth edges, occluded.

One definition, used by the benchmark loop once per scene (:func:`region_masks`):

* ``nonocc``: pixels with ground truth (GT) that the dataset marks visible in the other view
  (:attr:`cade_cli.data.Scene.nonocc`: Middlebury 2014 ``mask0nocc.png == 255``; Middlebury
  2005/2006 a left-right check of both views' GT, :func:`cade_cli.data.nonoccluded_mask`;
  KITTI ``disp_noc``).
* ``occ``: pixels with GT that are not ``nonocc`` (Middlebury 2014: ``mask0nocc.png == 128``;
  2005/2006: the right GT at x - d disagrees by more than 1 px, is unknown or out of view;
  KITTI: in ``disp_occ`` but not in ``disp_noc``).
* ``edge``: non-occluded pixels within :data:`EDGE_RADIUS` px (Euclidean) of a depth jump,
  a pair of 4-neighbours that both have GT and differ by more than :data:`EDGE_JUMP` px
  (both pixels of the pair are on the jump). Without occlusion information, every pixel
  with GT within that distance.

A dataset without occlusion information (FlyingThings3D as stored here, a plain folder) gets
only ``edge``; the loop scores ``all`` itself. A scene without a depth jump has no ``edge`` and
one where every pixel with GT is visible no ``occ``: those regions are left out, not scored
as empty (NaN).
"""

from __future__ import annotations

import cv2
import numpy as np

from cade_cli.errors import CadeError

EDGE_JUMP = 2.0
"""A depth jump: |d - d'| > this many px between 4-neighbours that both have GT."""
EDGE_RADIUS = 3
"""Edge pixels lie within this many px (Euclidean) of a depth jump."""


def depth_jumps(gt: np.ndarray, *, jump: float = EDGE_JUMP) -> np.ndarray:
    """Pixels on a GT depth jump: a 4-neighbour has GT and differs by more than ``jump`` px.

    Args:
        gt: (H, W) float GT disparity in px; NaN / inf = unknown (never on a jump).
        jump: threshold in px, >= 0.

    Returns:
        (H, W) bool; both pixels of a jumping pair are True.
    """
    gt = np.asarray(gt, np.float64)
    if gt.ndim != 2:
        raise CadeError(f"gt must be a (H, W) disparity map, got shape {gt.shape}")
    if not jump >= 0:
        raise CadeError(f"jump must be >= 0 px, got {jump}")
    known = np.isfinite(gt)
    values = np.where(known, gt, 0.0)
    on_jump = np.zeros(gt.shape, bool)
    for axis in (0, 1):
        first = [slice(None)] * 2
        second = [slice(None)] * 2
        first[axis], second[axis] = slice(None, -1), slice(1, None)
        first, second = tuple(first), tuple(second)
        pair = known[first] & known[second] & (np.abs(values[first] - values[second]) > jump)
        on_jump[first] |= pair
        on_jump[second] |= pair
    return on_jump


def near(mask: np.ndarray, *, radius: float) -> np.ndarray:
    """(H, W) bool: pixels within ``radius`` px (Euclidean, centre to centre) of a True pixel of ``mask``."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return np.zeros(mask.shape, bool)
    distance = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return distance <= radius + 1e-6


def region_masks(gt: np.ndarray, *, nonocc: np.ndarray | None, jump: float = EDGE_JUMP,
                 radius: float = EDGE_RADIUS) -> dict[str, np.ndarray]:
    """The scored pixel sets of one scene besides ``all`` (see the module docstring).

    Args:
        gt: (H, W) float GT disparity in px, NaN / inf = unknown.
        nonocc: (H, W) bool, True = visible in the other view; None where the dataset has
            no occlusion information.
        jump, radius: the depth-jump threshold and the edge band's radius, px.

    Returns:
        ``{"nonocc", "edge", "occ"}`` -> (H, W) bool masks (each within the pixels with GT),
        or ``{"edge"}`` alone when ``nonocc`` is None; ``edge`` and ``occ`` only when they
        hold a pixel.

    Raises:
        CadeError: ``nonocc`` is not a bool mask of ``gt``'s shape.
    """
    gt = np.asarray(gt)
    known = np.isfinite(gt)
    close = near(depth_jumps(gt, jump=jump), radius=radius) & known
    if nonocc is None:
        return {"edge": close} if close.any() else {}
    nonocc = np.asarray(nonocc)
    if nonocc.shape != gt.shape or nonocc.dtype != bool:
        raise CadeError(f"nonocc must be a bool mask of the GT's shape {gt.shape}, got {nonocc.dtype} {nonocc.shape}")
    visible = nonocc & known
    masks = {"nonocc": visible, "edge": close & visible, "occ": known & ~visible}
    return {name: mask for name, mask in masks.items() if name == "nonocc" or mask.any()}
