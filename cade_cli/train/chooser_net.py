"""Fit the convolutional chooser (:class:`cade_cli.matching.chooser_net.ChooserNet`) on the candidate caches of
:func:`cade_cli.train.chooser.cache_candidates` and export it to ONNX.

Its data are the perceptron's (:mod:`cade_cli.train.chooser`): every cached task of the train-real scenes, the
disputed pixels visible in the right view labelled 1 where SGBM's match is nearer the truth and weighed by how much
the choice matters (the same weights); but it sees whole crops of the feature planes
(:func:`~cade_cli.matching.chooser_net.chooser_planes`) instead of single pixels, so it can learn where a pixel
lies relative to the image's edge and to the two maps' jumps around it. The other pixels of a crop carry no loss.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from cade_cli.io.checksum import file_sha256
from cade_cli.matching.chooser_net import MATCHING, PLANES, ChooserNet, chooser_planes
from cade_cli.train.chooser import asked_pixels, choice_targets, tasks_of
from cade_cli.train.export import write_onnx

DILATIONS = (1, 2, 4, 8, 1)
"""The residual 3 x 3 layers' dilations: together with the first layer, 17 px of reach on each side."""


class ChooserCNN(nn.Module):
    """:data:`~cade_cli.matching.chooser_net.PLANES` (B, P, H, W) -> logit (B, 1, H, W) of P(SGBM's match is the
    better one): a 3 x 3 convolution to ``width`` channels, residual dilated 3 x 3 layers (:data:`DILATIONS`), a
    1 x 1 convolution to the logit. Zero padding: an image's border reads as no feature, in training as at run time.
    ``separable``: each residual layer a depthwise dilated 3 x 3 then a 1 x 1 across channels (the same reach, about
    half the run time at 24 channels). ``dilations``: the residual layers' (each adds its dilation to the reach)."""

    def __init__(self, planes: int = len(PLANES), width: int = 24, separable: bool = False,
                 dilations: tuple[int, ...] = DILATIONS):
        super().__init__()
        self.entry = nn.Sequential(nn.Conv2d(planes, width, 3, padding=1), nn.ReLU())

        def layer(dilation: int) -> nn.Sequential:
            if separable:
                return nn.Sequential(nn.Conv2d(width, width, 3, padding=dilation, dilation=dilation, groups=width),
                                     nn.Conv2d(width, width, 1), nn.ReLU())
            return nn.Sequential(nn.Conv2d(width, width, 3, padding=dilation, dilation=dilation), nn.ReLU())

        self.body = nn.ModuleList(layer(d) for d in dilations)
        self.out = nn.Conv2d(width, 1, 1)

    def forward(self, planes: torch.Tensor) -> torch.Tensor:
        x = self.entry(planes)
        for layer in self.body:
            x = x + layer(x)
        return self.out(x)


def targets(gt: np.ndarray, task: dict) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 label and weight of a cached task (:func:`cade_cli.train.chooser.choice_targets`), the weight 0
    where the runtime does not ask the chooser or there is no truth (:func:`cade_cli.train.chooser.asked_pixels`)."""
    label, weight = choice_targets(task["network"], task["candidate"], np.where(np.isfinite(gt), gt, 0))
    return label, np.where(asked_pixels(gt, task), weight, 0).astype(np.float32)


def examples(caches: list[Path], tasks: tuple[str, ...] | None = None, planes: tuple[str, ...] = PLANES
             ) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """(planes (P, H, W) float16, label, weight) of every task of ``caches`` (those named in ``tasks``); ``planes``:
    which (with :data:`~cade_cli.matching.chooser_net.MATCHING` the caches must hold the right bands:
    :func:`cade_cli.train.chooser.cache_candidates` adds them to an older cache)."""
    found = []
    for cache in caches:
        for gt, task in tasks_of(cache, tasks):
            stack = chooser_planes(task["left"], task["network"], task["uncertainty"], task["candidate"],
                                   task["accepted"], task.get("right"), planes)
            label, weight = targets(gt, task)
            found.append((torch.from_numpy(stack).half(), torch.from_numpy(label), torch.from_numpy(weight)))
    return found


def fit_net(caches: list[Path], *, width: int = 24, separable: bool = False, dilations: tuple[int, ...] = DILATIONS,
            steps: int = 3000, seed: int = 0, crop: int = 96, batch: int = 8, lr: float = 2e-3, tasks: tuple[str, ...] | None = None,
            planes: tuple[str, ...] = PLANES, log=print) -> ChooserCNN:
    """The network fitted on random ``crop`` x ``crop`` windows of the tasks of ``caches`` (``batch`` a step, Adam
    with a cosine from ``lr``): the weighted binary cross-entropy of its logit at the asked pixels (:func:`targets`).
    Deterministic given ``seed`` and torch's thread count. ``width``, ``separable``, ``dilations``:
    :class:`ChooserCNN`'s; ``planes``: its inputs (:func:`examples`)."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    data = examples(caches, tasks, planes)
    if not data:
        raise ValueError("no cached task to fit on")
    net = ChooserCNN(len(planes), width, separable, dilations)
    optimizer = torch.optim.Adam(net.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps)
    for step in range(steps):
        crops = []
        for _ in range(batch):
            planes, label, weight = data[rng.integers(len(data))]
            side_y, side_x = min(crop, planes.shape[1]), min(crop, planes.shape[2])
            top = rng.integers(0, planes.shape[1] - side_y + 1)
            left = rng.integers(0, planes.shape[2] - side_x + 1)
            window = (slice(top, top + side_y), slice(left, left + side_x))
            crops.append([F.pad(t, (0, crop - side_x, 0, crop - side_y))  # zero weight in any padding
                          for t in (planes[(slice(None), *window)].float(), label[window], weight[window])])
        planes, label, weight = (torch.stack(group) for group in zip(*crops))
        loss = (F.binary_cross_entropy_with_logits(net(planes)[:, 0], label, reduction="none") * weight).sum()
        loss = loss / weight.sum().clamp_min(1e-6)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
        if step % 500 == 0:
            log(f"chooser network step {step} loss {loss.item():.4f}")
    return net.eval()


def export_net(net: ChooserCNN, path: Path, planes: tuple[str, ...] = PLANES) -> ChooserNet:
    """Write ``net`` (fitted on ``planes``) as ONNX (input ``planes``, output ``logit``, height and width dynamic)
    to ``path`` (through a temporary file: an interrupted export leaves no half-written model); the runtime chooser
    pinned to it."""
    write_onnx(net.eval(), (torch.rand(1, len(planes), 64, 96),), path, ["planes"], ["logit"])
    return ChooserNet(path, file_sha256(path), planes=planes)
