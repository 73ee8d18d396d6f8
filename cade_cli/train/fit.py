"""Training loop: generated CADE pairs -> CadeNet, with CSV log, validation, checkpoints.

Every batch is drawn from ``np.random.default_rng([seed, step])``, so a run resumed from
a checkpoint sees exactly the batches the uninterrupted run would have seen.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from cade_cli.evaluation.metrics import bad_pixel_rate, end_point_error
from cade_cli.matching.network import pad_to_divisor
from cade_cli.train.model import DIVISOR, adapt_state_dict, parameter_count, transferable
from cade_cli.train.networks import network_of
from cade_cli.train.pairs import TRAINING_MODES, network_input_of
from cade_cli.train.pairs import training_pair as mode_pair
from cade_cli.train.real import RealScenes
from cade_cli.train.scenes import Misalignment, TexturePool, erased, render_scene


@dataclass
class TrainConfig:
    out: str
    textures: list[str]
    data_dir: str | None = None
    steps: int = 7000
    batch: int = 4
    height: int = 192
    width: int = 320
    levels: int = 128
    """CadeNet's search width: disparities 0 .. levels - 1 px (the model card's ``levels``)."""
    lr: float = 1e-3
    warmup: int = 200
    seed: int = 0
    device: str = "cpu"
    threads: int = 2
    workers: int = 1
    validate_every: int = 500
    checkpoint_every: int = 250
    coarse_weight: float = 0.5
    stop_after: int | None = None
    """Leave the loop after this step (checkpointed) although the schedule runs to ``steps``."""
    init: str | None = None
    """Start from this checkpoint's weights (fine-tuning: new optimizer, new schedule from step 0);
    a 3x3x3 entry kernel there is reduced to a 1x1x1 one here (``adapt_state_dict``)."""
    padding: str = "zeros"
    """CadeNet's 2D padding mode; cade-v1 … v3 were trained with "replicate"."""
    entry_kernel: int = 1
    """CadeNet's first 3D kernel size; cade-v1 … v3 were trained with 3."""
    channels3d: int = 8
    """Channels of CadeNet's 3D aggregation (8 in cade-v1 … v6; 16 for the accurate tier)."""
    aggregation: str = "3d"
    """CadeNet's aggregation (:data:`~cade_cli.train.model.AGGREGATIONS`): 3x3x3 kernels
    (every shipped model) or separable 2D + 1D ones (the Accuracy II lever)."""
    second_scale: bool = False
    """CadeNet's 1/2-resolution stage between the 1/4 level and the refinement (the
    second-scale lever of Accuracy II; :class:`~cade_cli.train.model.SecondScale`)."""
    census: bool = False
    """Feed CadeNet's aggregation a census cost volume beside the correlation (the
    Accuracy II lever; with ``init`` and ``init_partial`` it starts as the checkpoint)."""
    init_partial: bool = False
    """With ``init``: take only the tensors whose shapes fit (:func:`transferable`), e.g. a
    wider 3D part starting fresh beside cade-v6's 2D features and refinement."""
    misaligned: float = 0.0
    """Share of training pairs whose right view is vertically misaligned
    (:class:`~cade_cli.train.scenes.Misalignment`: up to 1 px, plus a slight roll and zoom);
    cade-v1 … v4 saw perfectly rectified pairs only. Validation pairs stay rectified."""
    real_dir: str | None = None
    """Folder of real training scenes (MiddEval3 layout, ``../shared/data/train-real``)."""
    real_share: float = 0.0
    """Share of training pairs cut from a real scene instead of rendered (needs ``real_dir``);
    cade-v1 … v4: 0."""
    amp: bool = False
    """Mixed precision: the forward pass and the loss under bf16 autocast (the GPU recipe,
    docs/gpu-recipe.md); weights, gradients and the optimizer stay float32."""
    training_mode: str = "cade"
    """How a scene becomes a training pair (:data:`~cade_cli.train.pairs.TRAINING_MODES`):
    ``cade`` (every shipped model), or the paper's comparison modes ``csdl`` and ``pristine``
    (the training ablation); the exported card's ``input`` follows from it."""
    network_input: str | None = None
    """The ``cade`` mode's transform, when not the paper's (``cade-floor``: the contrast-floor
    lever, :data:`~cade_cli.spectral.CONTRAST_FLOOR`); None: the mode's own."""
    architecture: str = "cadenet"
    """The network (:data:`~cade_cli.train.model.ARCHITECTURES`): ``cadenet`` (3D
    aggregation, every model up to cade-v8) or ``cadenet2d`` (the all-2D generation)."""
    width2d: int = 48
    """``cadenet2d``: the 2D U-Net's channels at 1/4 resolution."""
    full_refinement: int = 0
    """``cadenet2d``: channels of a full-resolution refinement after the 1/2-level one (0: none)."""
    slice_channels: int = 0
    """``cadenet2d``: channels of the per-disparity aggregation shared by every disparity (0: none)."""
    scene_range: float = 1.0
    """Rendered scenes limit their disparities to ``(levels - 1) * s``, s drawn log-uniformly
    from [``scene_range``, 1] per scene (1: every scene spans the whole range, as before):
    small and large baselines both, instead of a range mostly filled with near objects."""
    eraser: float = 0.0
    """Share of pairs whose right view gets 1-2 rectangles painted over (:func:`~cade_cli.train.scenes.erased`)."""
    misaligned_offset: float = 1.0
    """The misaligned pairs' largest vertical offset, px (:class:`~cade_cli.train.scenes.Misalignment`)."""
    feature_consistency: float = 0.0
    """Weight of the cross-spectral feature-consistency loss (FCStereo-style): the 1/4
    features of the left view in two different bands pulled together (1 - cosine); the
    ``cadenet2d`` architecture only. 0: off (no second band is drawn)."""
    crop_schedule: str | None = None
    """Progressive crops, ``"STEP:HxW,..."`` (:func:`parse_crop_schedule`): small crops early
    (cheap steps, local matching), larger ones later (context); None: ``height`` x ``width``."""
    validate_rgb: bool = False
    """Also validate on Middlebury's same-band tasks (the ``*-rgb`` sets of :func:`validation_sets`)."""
    time_budget_s: float | None = None
    """Leave the loop, checkpointed, once this many seconds have passed in this process
    (the GPU recipe works in calls of at most 10 minutes, each resuming the last)."""


class GeneratedBatches(torch.utils.data.Dataset):
    """Item ``step`` is the training batch for that step (deterministic in seed and step)."""

    def __init__(self, config: TrainConfig):
        self.config = config
        self.pool: TexturePool | None = None
        self.real: RealScenes | None = None

    def __len__(self) -> int:
        return self.config.steps

    def __getitem__(self, step: int) -> dict[str, torch.Tensor]:
        config = self.config
        if self.pool is None:
            self.pool = TexturePool([Path(folder) for folder in config.textures])
            self.real = RealScenes(Path(config.real_dir)) if config.real_share > 0 else None
        rng = np.random.default_rng([config.seed, step])
        height, width = crop_at(config, step)
        return collate([training_pair(rng, self.pool, self.real, config, height, width) for _ in range(config.batch)])


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
                  height: int | None = None, width: int | None = None):
    """One CADE training pair of ``height`` x ``width`` (default: the config's): cut from a
    real scene with probability ``config.real_share`` (no random draw for that when the
    share is 0, so earlier runs reproduce), else rendered."""
    height, width = height or config.height, width or config.width
    second_left = config.feature_consistency > 0
    if real is not None and rng.random() < config.real_share:
        scene = erased(real.draw(rng, height, width, limit=config.levels - 1), rng, config.eraser)
        return mode_pair(scene, rng, config.training_mode, config.network_input, second_left=second_left)
    return generated_pair(rng, pool, height, width, config.levels, misaligned=config.misaligned,
                          mode=config.training_mode, kind=config.network_input, scene_range=config.scene_range,
                          misaligned_offset=config.misaligned_offset, eraser=config.eraser, second_left=second_left)


def generated_pair(rng: np.random.Generator, pool: TexturePool, height: int, width: int, levels: int, *,
                   misaligned: float = 0.0, mode: str = "cade", kind: str | None = None, scene_range: float = 1.0,
                   misaligned_offset: float = 1.0, eraser: float = 0.0, second_left: bool = False):
    """One training pair (``mode``: :data:`TRAINING_MODES`) of a freshly rendered scene;
    disparities below ``levels - 1`` px (times a per-scene share drawn from
    [``scene_range``, 1] when that is below 1); a share ``misaligned`` of the pairs has a
    vertically misaligned right view (by up to ``misaligned_offset`` px), a share
    ``eraser`` an erased patch (:func:`~cade_cli.train.scenes.erased`)."""
    limit = levels - 1
    if scene_range < 1:  # no draw otherwise: earlier runs' scenes unchanged
        limit *= float(np.exp(rng.uniform(np.log(scene_range), 0.0)))
    scene = render_scene(rng, height, width, limit=limit, textures=pool,
                         misalignment=Misalignment(share=misaligned, offset=misaligned_offset))
    return mode_pair(erased(scene, rng, eraser), rng, mode, kind, second_left=second_left)


def collate(pairs) -> dict[str, torch.Tensor]:
    return {
        "left": torch.from_numpy(np.stack([p.left for p in pairs])[:, None]),
        "right": torch.from_numpy(np.stack([p.right for p in pairs])[:, None]),
        "disparity": torch.from_numpy(np.stack([p.disparity for p in pairs])[:, None]),
        "nonoccluded": torch.from_numpy(np.stack([p.nonoccluded for p in pairs])[:, None]),
        **({"left_alt": torch.from_numpy(np.stack([p.left_alt for p in pairs])[:, None])}
           if pairs[0].left_alt is not None else {}),
    }


def learning_rate(config: TrainConfig, step: int) -> float:
    """Linear warm-up, then cosine decay to 5 % of ``lr`` at the last step."""
    if step < config.warmup:
        return config.lr * (step + 1) / config.warmup
    progress = (step - config.warmup) / max(1, config.steps - config.warmup)
    return config.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress))))


def loss_terms(out: dict[str, torch.Tensor], target: torch.Tensor, levels: int, coarse_weight: float):
    mask = (target >= 0) & (target < levels)
    fine = F.smooth_l1_loss(out["disparity"][mask], target[mask])
    coarse = F.smooth_l1_loss(out["coarse"][mask], target[mask])
    if "half" in out:  # the second scale's estimate is supervised like the 1/4 level's
        coarse = coarse + F.smooth_l1_loss(out["half"][mask], target[mask])
    return fine + coarse_weight * coarse, mask


def feature_consistency(net: torch.nn.Module, features: torch.Tensor, left_alt: torch.Tensor) -> torch.Tensor:
    """1 - cosine, averaged over pixels, between the left view's 1/4 features (``features``,
    from the forward pass) and those of the same view in another band (``left_alt``)."""
    _, alt = net.features(left_alt)
    return (1.0 - F.cosine_similarity(features, alt, dim=1)).mean()


@torch.no_grad()
def predict(net: torch.nn.Module, left: np.ndarray, right: np.ndarray, device: str) -> np.ndarray:
    """(H, W) float32 disparity (px) of one pair of CADE bands (H, W), any size: padded as the
    runtime pads (:func:`cade_cli.matching.network.pad_to_divisor`), then cropped back."""
    padded = [pad_to_divisor(band, getattr(net, "divisor", DIVISOR))[0] for band in (left, right)]
    tensors = [torch.from_numpy(band)[None, None].to(device) for band in padded]
    disparity = net(*tensors)["disparity"][0, 0, : left.shape[0], : left.shape[1]]
    return disparity.cpu().numpy()


def validation_sets(config: TrainConfig, *, synthetic: bool = True) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Fixed validation pairs: 24 generated CS pairs (seed 10**6 + i, never a training
    seed; made in the run's training mode; only with ``synthetic``) and, when ``data_dir``
    holds them, Middlebury 2014 Q and Middlebury 2005 in the CS tasks R>B and B>R (sets
    ``*-cs``) and, with ``config.validate_rgb``, in the same-band tasks R>R, G>G and B>B
    pooled (``*-rgb``; the benchmark's RGB protocol merges them by median instead), downscaled
    by powers of 2 until the scene's range fits the model, each band given as the runtime
    gives it to a network of this mode (:func:`~cade_cli.spectral.network_input`)."""
    import cv2

    from cade_cli.errors import CadeError
    from cade_cli.spectral import network_input

    kind = network_input_of(config.training_mode, config.network_input)
    rgb = config.validate_rgb
    sets = {}
    if synthetic:
        pool = TexturePool([Path(folder) for folder in config.textures])
        pairs = (generated_pair(np.random.default_rng([10**6 + i]), pool, 256, 384, config.levels,
                                mode=config.training_mode, kind=config.network_input) for i in range(24))
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
                gt = cv2.resize(scene.disparity, size, interpolation=cv2.INTER_NEAREST) / scale
                for tasks, pairs in ((((0, 2), (2, 0)), cross), (((0, 0), (1, 1), (2, 2)), same)):
                    pairs.extend((network_input(left[..., a], kind), network_input(right[..., b], kind), gt)
                                 for a, b in tasks)
            sets[f"{name}-cs"] = cross
            if rgb:
                sets[f"{name}-rgb"] = same
    return sets


def evaluate(net: torch.nn.Module, pairs, device: str) -> tuple[float, float]:
    """EPE (px) and bad-3 (%) over all pixels with finite ground truth of all ``pairs``
    together (pooled: each pixel weighs the same), with the benchmark's metrics."""
    predictions, truths = zip(*((predict(net, left, right, device).ravel(), gt.ravel()) for left, right, gt in pairs))
    prediction, gt = np.concatenate(predictions)[None], np.concatenate(truths)[None]  # one (1, N) map
    everywhere = np.ones(gt.shape, bool)  # the metrics skip pixels without GT themselves
    return end_point_error(prediction, gt, everywhere), bad_pixel_rate(prediction, gt, everywhere, threshold=3.0)


def train(config: TrainConfig, *, resume: bool = True) -> Path:
    """Train (or continue) the run in ``config.out``; returns the final checkpoint path."""
    if config.training_mode not in TRAINING_MODES:
        raise ValueError(f"unknown training mode {config.training_mode!r}; choose one of {', '.join(TRAINING_MODES)}")
    parse_crop_schedule(config.crop_schedule)  # a malformed schedule fails before anything is written
    if config.feature_consistency > 0 and config.architecture != "cadenet2d":
        raise ValueError("the feature-consistency loss needs the cadenet2d architecture")
    torch.set_num_threads(config.threads)
    device_type = torch.device(config.device).type
    if device_type == "cuda":
        torch.backends.cudnn.benchmark = True  # fixed crop size: let cuDNN pick its fastest kernels
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint_path = out / "last.pt"
    torch.manual_seed(config.seed)
    net = network_of(asdict(config)).to(config.device)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    start, elapsed_before, cpu_before = restore(net, optimizer, config, checkpoint_path if resume else None)
    (out / "config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    log, with_cpu = open_log(out / "log.csv", start)
    writer = csv.writer(log)
    validation = validation_sets(config)
    print(f"CadeNet: {parameter_count(net)} parameters; steps {start}..{config.steps}", flush=True)

    batches = torch.utils.data.DataLoader(
        torch.utils.data.Subset(GeneratedBatches(config), range(start, min(config.steps, config.stop_after or config.steps))),
        batch_size=None, num_workers=config.workers, persistent_workers=False, prefetch_factor=4 if config.workers else None,
        pin_memory=device_type == "cuda",
    )
    started, cpu_started = time.time(), time.process_time()
    running_loss, running_epe, seen = 0.0, 0.0, 0
    net.train()
    for step, batch in enumerate(batches, start=start):
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(config, step)
        done = step + 1
        measured = optimise(net, optimizer, batch, config, device_type)
        if measured is not None:
            running_loss, running_epe, seen = running_loss + measured[0], running_epe + measured[1], seen + 1
        else:  # a batch without ground truth, or an overflow (bf16): one NaN step would poison the run
            print(f"step {done}: loss or gradient not finite (or no ground truth); step skipped", flush=True)
        elapsed = elapsed_before + time.time() - started
        cpu = cpu_before + time.process_time() - cpu_started
        cpu_column = [f"{cpu:.0f}"] if with_cpu else []
        if done % 50 == 0:
            writer.writerow([done, f"{elapsed:.0f}", f"{learning_rate(config, step):.2e}",
                             f"{running_loss / max(seen, 1):.4f}", f"{running_epe / max(seen, 1):.3f}", "train", "", "",
                             *cpu_column])
            log.flush()
            print(f"step {done} {elapsed:.0f}s loss {running_loss / max(seen, 1):.3f} "
                  f"epe {running_epe / max(seen, 1):.2f}", flush=True)
            running_loss, running_epe, seen = 0.0, 0.0, 0
        if done % config.validate_every == 0 or done == config.steps:
            net.eval()
            for name, pairs in validation.items():
                epe, bad3 = evaluate(net, pairs, config.device)
                writer.writerow([done, f"{elapsed:.0f}", "", "", "", name, f"{epe:.3f}", f"{bad3:.2f}", *cpu_column])
                print(f"  validation {name}: EPE {epe:.2f} bad3 {bad3:.1f}%", flush=True)
            log.flush()
            net.train()
        out_of_time = config.time_budget_s is not None and time.time() - started > config.time_budget_s
        if done % config.checkpoint_every == 0 or done in (config.steps, config.stop_after) or out_of_time:
            save_checkpoint(checkpoint_path, net, optimizer, done, elapsed, config, cpu)
        if out_of_time:
            print(f"time budget of {config.time_budget_s:.0f} s spent: stopped after step {done} (checkpointed)",
                  flush=True)
            break
    log.close()
    return checkpoint_path


def restore(net: torch.nn.Module, optimizer, config: TrainConfig, checkpoint: Path | None) -> tuple[int, float, float]:
    """Load the run's ``checkpoint`` when there is one (net, optimizer, random state), else
    ``config.init``'s weights when given; returns (step, wall seconds, CPU seconds) so far."""
    if checkpoint is not None and checkpoint.exists():
        state = torch.load(checkpoint, map_location=config.device, weights_only=False)
        net.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        torch.set_rng_state(state["torch_rng"])
        return state["step"], state["elapsed_s"], state.get("cpu_s", 0.0)
    if config.init:
        initial = torch.load(config.init, map_location=config.device, weights_only=False)["model"]
        if config.init_partial:
            net.load_state_dict(transferable(initial, net), strict=False)
        else:
            net.load_state_dict(adapt_state_dict(initial, net))
    return 0, 0.0, 0.0


def open_log(path: Path, start: int):
    """The run's log, open for appending from step ``start`` (a new one with its header at step 0),
    and whether its rows carry the ``cpu_s`` column (logs begun before it keep their columns)."""
    if path.exists() and start > 0:  # a run killed between checkpoints logged steps it will now redo: drop them
        rows = path.read_text().splitlines(keepends=True)
        path.write_text("".join(rows[:1] + [row for row in rows[1:] if int(row.split(",", 1)[0]) <= start]))
        return path.open("a", newline=""), "cpu_s" in rows[0]
    log = path.open("w", newline="")
    csv.writer(log).writerow(["step", "elapsed_s", "lr", "loss", "train_epe", "set", "val_epe", "val_bad3", "cpu_s"])
    return log, True


def optimise(net: torch.nn.Module, optimizer, batch: dict, config: TrainConfig,
             device_type: str) -> tuple[float, float] | None:
    """One optimiser step on ``batch``: (loss, training EPE px), or None when the step was
    skipped (no ground truth in the batch, or a loss or gradient that is not finite)."""
    batch = {key: value.to(config.device, non_blocking=True) for key, value in batch.items()}
    with torch.autocast(device_type, dtype=torch.bfloat16, enabled=config.amp):
        out = net(batch["left"], batch["right"])
        out = {key: value.float() for key, value in out.items()}
        loss, mask = loss_terms(out, batch["disparity"], config.levels, config.coarse_weight)
        if config.feature_consistency > 0:
            loss = loss + config.feature_consistency * feature_consistency(net, out["features"], batch["left_alt"])
    optimizer.zero_grad(set_to_none=True)
    if not (bool(mask.any()) and bool(torch.isfinite(loss))):
        return None
    loss.backward()
    if not bool(torch.isfinite(torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0))):
        return None
    optimizer.step()
    return loss.item(), (out["disparity"] - batch["disparity"]).detach().abs()[mask].mean().item()


def save_checkpoint(path: Path, net, optimizer, step: int, elapsed: float, config: TrainConfig,
                    cpu: float = 0.0) -> None:
    """``elapsed``: wall-clock seconds of training so far; ``cpu``: CPU seconds of the training
    process so far (all its threads; the data workers' only with ``workers`` 0)."""
    temporary = path.with_name(path.name + ".tmp")
    torch.save({"model": net.state_dict(), "optimizer": optimizer.state_dict(), "step": step, "elapsed_s": elapsed,
                "cpu_s": cpu, "config": asdict(config), "torch_rng": torch.get_rng_state()}, temporary)
    os.replace(temporary, path)
