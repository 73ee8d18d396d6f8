"""Training batches: each step's generated (or real) pairs, drawn from
``np.random.default_rng([seed, step])``, cropped as the run's crop schedule says, and
collated into tensors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from cade_cli.train.asymmetric import one_view_changed
from cade_cli.train.config import TrainConfig
from cade_cli.train.floating import render_floating
from cade_cli.train.pairs import CadePair, network_input_of
from cade_cli.train.pairs import training_pair as mode_pair
from cade_cli.train.real import RealScenes
from cade_cli.train.scenes import Misalignment, Photometric, StereoScene, erased, render_scene
from cade_cli.train.selfsup_pairs import SelfSupPairs
from cade_cli.train.textures import TexturePool


class GeneratedBatches(torch.utils.data.Dataset):
    """Item ``step`` is the training batch for that step (deterministic in seed and step)."""

    def __init__(self, config: TrainConfig):
        self.config = config
        self.pool: TexturePool | None = None
        self.real: RealScenes | None = None
        self.selfsup: SelfSupPairs | None = None

    def __len__(self) -> int:
        return self.config.steps

    def __getitem__(self, step: int) -> dict[str, torch.Tensor]:
        config = self.config
        if self.pool is None:
            self.pool = TexturePool([Path(folder) for folder in config.textures])
            self.real = (RealScenes(Path(config.real_dir), hold_out=config.real_hold_out)
                         if config.real_dir and (config.real_share > 0 or config.floating > 0) else None)
            self.selfsup = SelfSupPairs(Path(config.selfsup_cache)) if config.selfsup_share > 0 else None
        rng = np.random.default_rng([config.seed, step])
        height, width = crop_at(config, step)
        return collate([training_pair(rng, self.pool, self.real, config, height, width, selfsup=self.selfsup)
                        for _ in range(config.batch)])


def crop_at(config: TrainConfig, step: int) -> tuple[int, int]:
    """The training crop (height, width) at ``step``: the last entry of ``config.crop_schedule``
    that has begun, else ``config.height`` x ``config.width``."""
    size = (config.height, config.width)
    for begin, height, width in parse_crop_schedule(config.crop_schedule):
        if step >= begin:
            size = (height, width)
    return size


def parse_crop_schedule(text: str | None) -> list[tuple[int, int, int]]:
    """``"0:160x288,5000:192x320"`` -> [(0, 160, 288), (5000, 192, 320)]: from each step on,
    that crop (sides multiples of 16; steps increasing)."""
    if not text:
        return []
    entries = []
    for item in text.split(","):
        try:
            begin, size = item.split(":")
            height, width = (int(side) for side in size.lower().split("x"))
            entries.append((int(begin), height, width))
        except ValueError:
            raise ValueError(f"crop schedule entry {item!r} is not STEP:HEIGHTxWIDTH") from None
        if height % 16 or width % 16 or height < 64 or width < 64:
            raise ValueError(f"crop {height}x{width} must have sides of at least 64 that are multiples of 16")
    if [begin for begin, _, _ in entries] != sorted({begin for begin, _, _ in entries}):
        raise ValueError(f"crop schedule steps must increase: {text!r}")
    return entries


def training_pair(rng: np.random.Generator, pool: TexturePool, real: RealScenes | None, config: TrainConfig,
                  height: int | None = None, width: int | None = None, *, selfsup: SelfSupPairs | None = None):
    """One CADE training pair of ``height`` x ``width`` (default: the config's): with
    probability ``config.selfsup_share`` a crop of a rectified real pair without ground truth
    (``selfsup``), else cut from a real scene with probability ``config.real_share``, else
    rendered (no random draw for a share of 0, so earlier runs reproduce)."""
    height, width = height or config.height, width or config.width
    second_left = config.feature_consistency > 0
    if selfsup is not None and rng.random() < config.selfsup_share:
        return selfsup_pair(selfsup, rng, config, height, width, second_left=second_left)
    if real is not None and config.real_share > 0 and rng.random() < config.real_share:
        scene = erased(real.draw(rng, height, width, limit=config.levels - 1), rng, config.eraser)
        scene = one_view_changed(scene, rng, config.asymmetric)
        return mode_pair(scene, rng, config.training_mode, config.network_input, second_left=second_left)
    return generated_pair(rng, pool, height, width, config.levels, misaligned=config.misaligned,
                          mode=config.training_mode, kind=config.network_input, scene_range=config.scene_range,
                          misaligned_offset=config.misaligned_offset, eraser=config.eraser, second_left=second_left,
                          ground=config.ground, shadows=config.shadows, thin=config.thin, floating=config.floating,
                          asymmetric=config.asymmetric, real=real)


def generated_pair(rng: np.random.Generator, pool: TexturePool, height: int, width: int, levels: int, *,
                   mode: str = "cade", kind: str | None = None, second_left: bool = False, **levers):
    """One training pair (``mode``: :data:`TRAINING_MODES`) of a freshly rendered scene
    (:func:`generated_scene`, which ``levers`` go to)."""
    scene = generated_scene(rng, pool, height, width, levels, **levers)
    return mode_pair(scene, rng, mode, kind, second_left=second_left)


def generated_scene(rng: np.random.Generator, pool: TexturePool, height: int, width: int, levels: int, *,
                    misaligned: float = 0.0, scene_range: float = 1.0, misaligned_offset: float = 1.0,
                    eraser: float = 0.0, ground: float = 0.0, shadows: float = 0.0, thin: float = 0.0,
                    floating: float = 0.0, asymmetric: float = 0.0, real: RealScenes | None = None,
                    photometric: Photometric = Photometric()) -> StereoScene:
    """A freshly rendered RGB scene as training sees it before it becomes a pair: disparities
    below ``levels - 1`` px (times a per-scene share drawn from [``scene_range``, 1] when that
    is below 1); a share ``misaligned`` of the pairs has a vertically misaligned right view (by
    up to ``misaligned_offset`` px), a share ``eraser`` an erased patch
    (:func:`~cade_cli.train.scenes.erased`), a share ``ground`` a ground under the objects
    (:func:`~cade_cli.train.scenes.ground_layer`), a share ``shadows`` of the backgrounds and
    grounds shadows cast on them (:func:`~cade_cli.train.scenes.cast_shadow`), a share ``thin``
    thin structures (:func:`~cade_cli.train.scenes.thin_layers`), a share ``floating`` is floating
    objects over a real background instead (:func:`~cade_cli.train.floating.render_floating`:
    photos from ``pool`` or ``real``'s left views), a share ``asymmetric`` one view changed
    (:func:`~cade_cli.train.asymmetric.one_view_changed`). Every share of 0 draws nothing, so
    earlier runs' scenes are unchanged."""
    limit = levels - 1
    if scene_range < 1:  # no draw otherwise: earlier runs' scenes unchanged
        limit *= float(np.exp(rng.uniform(np.log(scene_range), 0.0)))
    misalignment = Misalignment(share=misaligned, offset=misaligned_offset)
    if floating > 0 and rng.random() < floating:
        scene = render_floating(rng, height, width, limit=limit, textures=pool, real=real, photometric=photometric,
                                misalignment=misalignment, thin=thin)
    else:
        scene = render_scene(rng, height, width, limit=limit, textures=pool, photometric=photometric,
                             misalignment=misalignment, ground=ground, shadows=shadows, thin=thin)
    return one_view_changed(erased(scene, rng, eraser), rng, asymmetric)


def selfsup_pair(selfsup: SelfSupPairs, rng: np.random.Generator, config: TrainConfig, height: int, width: int, *,
                 second_left: bool = False) -> CadePair:
    """A crop of a rectified real pair (:meth:`SelfSupPairs.draw`) as a training pair: no
    ground truth (disparity NaN), its guides for the self-supervised loss; the left view
    stands in for its second band (``second_left``: the feature-consistency loss sees nothing)."""
    crop = selfsup.draw(rng, height, width, network_input_of(config.training_mode, config.network_input))
    return CadePair(left=crop.left, right=crop.right, disparity=np.full((height, width), np.nan, np.float32),
                    nonoccluded=np.zeros((height, width), bool), bands=crop.bands,
                    left_alt=crop.left if second_left else None, guides=crop.guides)


def collate(pairs) -> dict[str, torch.Tensor]:
    return {
        "left": torch.from_numpy(np.stack([p.left for p in pairs])[:, None]),
        "right": torch.from_numpy(np.stack([p.right for p in pairs])[:, None]),
        "disparity": torch.from_numpy(np.stack([p.disparity for p in pairs])[:, None]),
        "nonoccluded": torch.from_numpy(np.stack([p.nonoccluded for p in pairs])[:, None]),
        **({"left_alt": torch.from_numpy(np.stack([p.left_alt for p in pairs])[:, None])}
           if pairs[0].left_alt is not None else {}),
        **(guides_of(pairs) if any(p.guides is not None for p in pairs) else {}),
    }


def guides_of(pairs) -> dict[str, torch.Tensor]:
    """``guides`` (B, 4, H, W; zeros for the pairs without) and ``selfsup`` (B,) bool."""
    height, width = pairs[0].left.shape
    empty = np.zeros((4, height, width), np.float32)
    return {"guides": torch.from_numpy(np.stack([empty if p.guides is None else p.guides for p in pairs])),
            "selfsup": torch.tensor([p.guides is not None for p in pairs])}
