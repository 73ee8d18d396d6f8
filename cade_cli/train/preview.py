"""A picture of generated training scenes, lever by lever (``python -m cade_cli.train preview``):
per scene its left and right views, its ground truth and the pixels the ``--edge-weight`` lever
weighs up, so a lever's data can be looked at before a run trains on it."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from cade_cli.io.pictures import colour_map
from cade_cli.train.batches import generated_scene
from cade_cli.train.fit import edge_weights
from cade_cli.train.real import RealScenes
from cade_cli.train.scenes import NO_PHOTOMETRIC
from cade_cli.train.textures import TexturePool

PREVIEW_LEVERS = ("none", "thin", "floating", "asymmetric")
"""The scene levers a preview can show (``none``: the layered scene without any of them)."""


def lever_scenes(lever: str, *, count: int, height: int, width: int, levels: int, seed: int, pool: TexturePool,
                 real: RealScenes | None = None) -> list:
    """``count`` scenes of :func:`~cade_cli.train.batches.generated_scene` with ``lever`` at share 1
    (every other lever off), each drawn from ``np.random.default_rng([seed, i])``, without the
    per-view camera model (:data:`~cade_cli.train.scenes.NO_PHOTOMETRIC`): what the lever changes
    shows (one view's changes, for ``asymmetric``), and the picture stays small."""
    if lever not in PREVIEW_LEVERS:
        raise ValueError(f"unknown lever {lever!r}; choose one of {', '.join(PREVIEW_LEVERS)}")
    levers = {} if lever == "none" else {lever: 1.0}
    return [generated_scene(np.random.default_rng([seed, i]), pool, height, width, levels, real=real,
                            photometric=NO_PHOTOMETRIC, **levers)
            for i in range(count)]


def scene_row(scene, *, label: str, levels: int) -> np.ndarray:
    """(H, 4 W + 6, 3) uint8 BGR: left view, right view, ground truth (turbo, 0 .. ``levels`` - 1 px;
    unknown black) and the edge pixels (:func:`~cade_cli.train.fit.edge_weights`) in white over the
    dimmed ground truth; ``label`` written on the left view."""
    def view(image: np.ndarray) -> np.ndarray:
        return cv2.cvtColor(np.rint(np.clip(image, 0, 1) * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)

    truth = colour_map(scene.disparity, colormap=cv2.COLORMAP_TURBO, low=0.0, high=float(levels - 1))
    target = torch.from_numpy(scene.disparity)[None, None]
    valid = torch.isfinite(target) & (target >= 0)
    edges = edge_weights(target, valid, 1.0)[0, 0].numpy() > 1
    weighted = (truth // 3).astype(np.uint8)
    weighted[edges] = 255
    left = view(scene.left)
    cv2.putText(left, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(left, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    gap = np.full((scene.disparity.shape[0], 2, 3), 255, np.uint8)
    return np.hstack([left, gap, view(scene.right), gap, truth, gap, weighted])


def lever_sheet(rows: list[np.ndarray]) -> np.ndarray:
    """The rows of :func:`scene_row` stacked with a 2 px white gap between them."""
    gap = np.full((2, rows[0].shape[1], 3), 255, np.uint8)
    return np.vstack([part for row in rows for part in (row, gap)][:-1])
