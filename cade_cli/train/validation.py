"""Validation during training: fixed generated pairs and the Middlebury sets, predicted as
the runtime pads them, scored with the benchmark's metrics (pooled EPE and bad-3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from cade_cli.evaluation.metrics import bad_pixel_rate, end_point_error
from cade_cli.matching.network import pad_to_divisor
from cade_cli.train.batches import generated_pair
from cade_cli.train.config import TrainConfig
from cade_cli.train.model import DIVISOR
from cade_cli.train.pairs import network_input_of
from cade_cli.train.textures import TexturePool


SYNTHETIC_PAIRS = 24
"""Generated validation pairs of every run (seeds 10**6 + i)."""
SYNTHETIC_SIZE = (256, 384)
"""(height, width) of each generated validation pair, px."""


@torch.no_grad()
def predict(net: torch.nn.Module, left: np.ndarray, right: np.ndarray, device: str) -> np.ndarray:
    """(H, W) float32 disparity (px) of one pair of CADE bands (H, W), any size: padded as the
    runtime pads (:func:`cade_cli.matching.network.pad_to_divisor`), then cropped back."""
    padded = [pad_to_divisor(band, getattr(net, "divisor", DIVISOR))[0] for band in (left, right)]
    tensors = [torch.from_numpy(band)[None, None].to(device) for band in padded]
    disparity = net(*tensors)["disparity"][0, 0, : left.shape[0], : left.shape[1]]
    return disparity.cpu().numpy()


def validation_sets(config: TrainConfig, *, synthetic: bool = True) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Fixed validation pairs: :data:`SYNTHETIC_PAIRS` generated CS pairs of :data:`SYNTHETIC_SIZE`
    (seed 10**6 + i, never a training
    seed; made in the run's training mode; only with ``synthetic``) and, when ``data_dir``
    holds them, Middlebury 2014 Q and Middlebury 2005 in the CS tasks R>B and B>R (sets
    ``*-cs``) and, with ``config.validate_rgb``, in the same-band tasks R>R, G>G and B>B
    pooled (``*-rgb``; the benchmark's RGB protocol merges them by median instead), downscaled
    by powers of 2 until the scene's range fits the model, each band given as the runtime
    gives it to a network of this mode (:func:`~cade_cli.spectral.network_input`). The ground
    truth stays at the scene's resolution: :func:`evaluate` scores a downscaled scene's map
    brought back to it, in the scene's px, over all its pixels (until 2026-11-25 it scored it
    at the downscaled size, in those px: a 128-level network's Jadeplant, run at half size,
    counted an eighth of what a 192-level network's did). With ``data_dir`` holding ``msir-outdoor``, the
    set of that name: real visible/near-infrared pairs (:func:`real_cross_spectral_set`)."""
    import cv2

    from cade_cli.errors import CadeError
    from cade_cli.spectral import network_input

    kind = network_input_of(config.training_mode, config.network_input)
    rgb = config.validate_rgb
    sets = {}
    if synthetic:
        pool = TexturePool([Path(folder) for folder in config.textures])
        height, width = SYNTHETIC_SIZE
        pairs = (generated_pair(np.random.default_rng([10**6 + i]), pool, height, width, config.levels,
                                mode=config.training_mode, kind=config.network_input)
                 for i in range(SYNTHETIC_PAIRS))
        sets["synthetic"] = [(pair.left, pair.right, pair.disparity) for pair in pairs]
    if config.data_dir and Path(config.data_dir).is_dir():
        from cade_cli.data import get_dataset
        from cade_cli.matching.network import RANGE_MARGIN, pyramid_factor

        for name, dataset, resolution in (("middlebury14Q", "middlebury14", "Q"),
                                          ("middlebury05", "middlebury05", None)):
            cross, same = [], []
            try:
                scenes = list(get_dataset(dataset)(Path(config.data_dir), resolution=resolution))
            except CadeError:
                continue
            for scene in scenes:
                scale = pyramid_factor(scene.max_disp, config.levels - RANGE_MARGIN)  # as the runtime does
                size = (scene.left.shape[1] // scale, scene.left.shape[0] // scale)
                left, right = (cv2.resize(view, size, interpolation=cv2.INTER_AREA) for view in (scene.left, scene.right))
                gt = scene.disparity
                for tasks, pairs in ((((0, 2), (2, 0)), cross), (((0, 0), (1, 1), (2, 2)), same)):
                    pairs.extend((network_input(left[..., a], kind), network_input(right[..., b], kind), gt)
                                 for a, b in tasks)
            sets[f"{name}-cs"] = cross
            if rgb:
                sets[f"{name}-rgb"] = same
        real = real_cross_spectral_set(Path(config.data_dir), kind, config.levels - RANGE_MARGIN)
        if real:
            sets["msir-outdoor"] = real
    return sets


def real_cross_spectral_set(data_dir: Path, kind: str, levels: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The real visible/near-infrared pairs of ``msir-outdoor`` (the shipping rule's real check,
    docs/msir-outdoor.md) against their pseudo ground truth, at the size the runtime matches them
    (full size: their range fits any network); empty when the data dir does not hold them. Building the pseudo ground truth
    takes minutes the first time (then it is cached by the dataset)."""
    import cv2

    from cade_cli.data import get_dataset
    from cade_cli.errors import CadeError
    from cade_cli.matching.network import pyramid_factor
    from cade_cli.spectral import network_input

    try:
        scenes = list(get_dataset("msir-outdoor")(data_dir))
    except CadeError:
        return []
    pairs = []
    for scene in scenes:
        scale = pyramid_factor(scene.max_disp, levels)  # as the runtime does
        size = (scene.left.shape[1] // scale, scene.left.shape[0] // scale)
        left, right = (cv2.resize(view[..., 0], size, interpolation=cv2.INTER_AREA) for view in (scene.left, scene.right))
        pairs.append((network_input(left, kind), network_input(right, kind), scene.disparity))
    return pairs


def at_truth_scale(disparity: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """A map of a downscaled pair brought to the ground truth's size and px (bilinear, times
    the scale); a map of the truth's size as it is."""
    import cv2

    if disparity.shape == gt.shape:
        return disparity
    scale = gt.shape[1] / disparity.shape[1]
    return cv2.resize(disparity, (gt.shape[1], gt.shape[0]), interpolation=cv2.INTER_LINEAR) * np.float32(scale)


def evaluate(net: torch.nn.Module, pairs, device: str) -> tuple[float, float]:
    """EPE (px) and bad-3 (%) over all pixels with finite ground truth of all ``pairs``
    together (pooled: each pixel weighs the same), with the benchmark's metrics."""
    predictions, truths = zip(*((at_truth_scale(predict(net, left, right, device), gt).ravel(), gt.ravel())
                                for left, right, gt in pairs))
    prediction, gt = np.concatenate(predictions)[None], np.concatenate(truths)[None]  # one (1, N) map
    everywhere = np.ones(gt.shape, bool)  # the metrics skip pixels without GT themselves
    return end_point_error(prediction, gt, everywhere), bad_pixel_rate(prediction, gt, everywhere, threshold=3.0)
