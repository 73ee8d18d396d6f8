"""A run's checkpoint (``last.pt``): written compactly (float32 weights, the optimiser's moments in
bfloat16), restored from that form or from the full one of earlier runs, rewritten compactly
(``python -m cade_cli.train compact``), and averaged into a soup.

A checkpoint is a dict: ``model`` (the state dict), ``optimizer`` (Adam's state dict, or None
for weights only), ``step``, ``elapsed_s``, ``cpu_s``, ``config``, ``torch_rng`` and, from this
module on, ``format`` (:data:`COMPACT` or :data:`WEIGHTS_ONLY`; absent: the full float32 form).
"""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path

import torch

from cade_cli.train.config import TrainConfig
from cade_cli.train.model import adapt_state_dict, transferable
from cade_cli.train.net2d import CadeNet2D, fewer_levels, with_more_levels

COMPACT = "compact-1"
"""``format`` of a resumable checkpoint whose Adam moments are stored in :data:`MOMENT_DTYPE`."""

WEIGHTS_ONLY = "weights-only"
"""``format`` of a finished run's checkpoint: weights, config and step; nothing to resume with."""

MOMENTS = ("exp_avg", "exp_avg_sq", "max_exp_avg_sq")
"""Adam's per-parameter running moments: the bulk of a checkpoint (twice the weights), stored
in :data:`MOMENT_DTYPE`. Its ``step`` counts stay float32 (bfloat16 holds integers only to 256)."""

MOMENT_DTYPE = torch.bfloat16
"""bfloat16 rather than float16: float32's exponent range, so a second moment of 1e-12 (a
squared small gradient) does not flush to zero and turn the next step into ``m / eps``; its
8-bit mantissa moves Adam's step ``m / sqrt(v)`` by at most about 0.4 %."""


def optimizer_moments(state: dict, dtype: torch.dtype) -> dict:
    """An optimiser state dict with its :data:`MOMENTS` cast to ``dtype`` (the rest as it is)."""
    moments = {index: {key: value.to(dtype) if key in MOMENTS else value for key, value in entry.items()}
               for index, entry in state["state"].items()}
    return {**state, "state": moments}


def compacted(state: dict, *, weights_only: bool = False) -> dict:
    """``state`` (a checkpoint in any form) in the compact form, or weights only."""
    if weights_only or state.get("optimizer") is None:
        kept = {key: value for key, value in state.items() if key not in ("optimizer", "torch_rng")}
        return {**kept, "optimizer": None, "format": WEIGHTS_ONLY}
    return {**state, "optimizer": optimizer_moments(state["optimizer"], MOMENT_DTYPE), "format": COMPACT}


def write_checkpoint(state: dict, path: Path) -> None:
    """Write ``state`` to ``path`` whole or not at all (a temporary, then a rename)."""
    temporary = path.with_name(path.name + ".tmp")
    torch.save(state, temporary)
    os.replace(temporary, path)


def save_checkpoint(path: Path, net, optimizer, step: int, elapsed: float, config: TrainConfig,
                    cpu: float = 0.0) -> None:
    """The run's compact checkpoint. ``elapsed``: wall-clock seconds of training so far; ``cpu``:
    CPU seconds of the training process so far (all its threads; the data workers' only with
    ``workers`` 0)."""
    write_checkpoint(compacted({"model": net.state_dict(), "optimizer": optimizer.state_dict(), "step": step,
                                "elapsed_s": elapsed, "cpu_s": cpu, "config": asdict(config),
                                "torch_rng": torch.get_rng_state()}), path)


def restore(net: torch.nn.Module, optimizer, config: TrainConfig, checkpoint: Path | None) -> tuple[int, float, float]:
    """Load the run's ``checkpoint`` when there is one (net, optimizer, random state; compact or
    full), else ``config.init``'s weights when given; returns (step, wall seconds, CPU seconds) so far.

    Raises:
        ValueError: ``checkpoint`` holds weights only (a finished run's: start a new run from it).
    """
    if checkpoint is not None and checkpoint.exists():
        state = torch.load(checkpoint, map_location=config.device, weights_only=False)
        if state.get("optimizer") is None:
            raise ValueError(f"{checkpoint} holds weights only (a finished run's); start a new run from it with "
                             "--init, or move it away to train from scratch")
        net.load_state_dict(state["model"])
        optimizer.load_state_dict(optimizer_moments(state["optimizer"], torch.float32))
        torch.set_rng_state(state["torch_rng"].cpu())  # loaded onto config.device; the CPU generator takes a CPU tensor
        return state["step"], state["elapsed_s"], state.get("cpu_s", 0.0)
    if config.init:
        initial = torch.load(config.init, map_location=config.device, weights_only=False)["model"]
        if config.init_partial and isinstance(net, CadeNet2D) and fewer_levels(initial, net):
            net.load_state_dict(with_more_levels(initial, net))
        elif config.init_partial:
            net.load_state_dict(transferable(initial, net), strict=False)
        else:
            net.load_state_dict(adapt_state_dict(initial, net))
    return 0, 0.0, 0.0


def compact_checkpoint(source: Path, out: Path, *, weights_only: bool = False) -> tuple[int, int]:
    """Rewrite the checkpoint ``source`` compactly (or as weights only) into ``out`` (may be
    ``source``); returns the sizes before and after, bytes."""
    before = source.stat().st_size
    write_checkpoint(compacted(torch.load(source, map_location="cpu", weights_only=False),
                               weights_only=weights_only), out)
    return before, out.stat().st_size


def average_checkpoints(paths: list[Path]) -> dict:
    """A checkpoint whose weights are the mean of ``paths``' (a uniform "model soup",
    Wortsman et al., ICML 2022: fine-tunes of one initialisation average into one model);
    BatchNorm's running statistics are averaged too, integer buffers taken from the first.
    The result has the first checkpoint's config and step and no optimiser state (export it;
    do not resume from it).

    Raises:
        ValueError: fewer than two checkpoints, or checkpoints of different designs.
    """
    if len(paths) < 2:
        raise ValueError("a soup needs at least two checkpoints")
    checkpoints = [torch.load(path, map_location="cpu", weights_only=False) for path in paths]
    first = checkpoints[0]
    for path, checkpoint in zip(paths[1:], checkpoints[1:]):
        if checkpoint["model"].keys() != first["model"].keys() or any(
                checkpoint["model"][key].shape != value.shape for key, value in first["model"].items()):
            raise ValueError(f"{path} holds another design than {paths[0]}")
    model = {key: (torch.stack([c["model"][key] for c in checkpoints]).mean(0) if value.is_floating_point() else value)
             for key, value in first["model"].items()}
    return {**first, "model": model, "optimizer": None, "format": WEIGHTS_ONLY, "soup_of": [str(path) for path in paths]}
