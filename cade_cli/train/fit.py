"""Training loop: generated CADE pairs (:mod:`~cade_cli.train.batches`) -> CadeNet, with CSV log,
validation (:mod:`~cade_cli.train.validation`) and checkpoints (:mod:`~cade_cli.train.checkpoints`).

Every batch is drawn from ``np.random.default_rng([seed, step])``, so a run resumed from
a checkpoint sees exactly the batches the uninterrupted run would have seen.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import asdict
from pathlib import Path

import torch
import torch.nn.functional as F

from cade_cli.evaluation.regions import EDGE_JUMP, EDGE_RADIUS
from cade_cli.train.batches import GeneratedBatches, parse_crop_schedule
from cade_cli.train.checkpoints import restore, save_checkpoint
from cade_cli.train.config import TrainConfig
from cade_cli.train.model import parameter_count
from cade_cli.train.net_blocks import neighbours3x3
from cade_cli.train.networks import network_of
from cade_cli.train.pairs import TRAINING_MODES
from cade_cli.train.selfsup_loss import selfsup_loss
from cade_cli.train.selfsup_pairs import build_cache
from cade_cli.train.validation import evaluate, validation_sets


def learning_rate(config: TrainConfig, step: int, cpu_s: float = 0.0) -> float:
    """Linear warm-up, then cosine decay to 5 % of ``lr`` at the last step; with a CPU budget, at
    the last step or when the budget is spent (``cpu_s`` of it so far), whichever comes first."""
    if step < config.warmup:
        return config.lr * (step + 1) / config.warmup
    progress = (step - config.warmup) / max(1, config.steps - config.warmup)
    if config.cpu_budget_s is not None:
        progress = max(progress, cpu_s / config.cpu_budget_s)
    return config.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress))))


def loss_terms(out: dict[str, torch.Tensor], target: torch.Tensor, levels: int, coarse_weight: float,
               edge_weight: float = 0.0):
    """The supervised loss (smooth L1 of the fine, coarse and half-level estimates over the pixels
    with ground truth in range) and that mask. With ``edge_weight`` W > 0 each term is the mean
    weighted by :func:`edge_weights` (1 + W at depth edges, 1 elsewhere, divided by the weights'
    sum: the loss keeps the scale of a per-pixel mean); W = 0 computes the plain mean, as before."""
    mask = (target >= 0) & (target < levels)
    if edge_weight > 0:
        weights = edge_weights(target, mask, edge_weight)[mask]
        weights = weights / weights.sum().clamp(min=1e-6)

        def term(estimate: torch.Tensor) -> torch.Tensor:
            return (F.smooth_l1_loss(estimate[mask], target[mask], reduction="none") * weights).sum()
    else:
        def term(estimate: torch.Tensor) -> torch.Tensor:
            return F.smooth_l1_loss(estimate[mask], target[mask])
    fine = term(out["disparity"])
    coarse = term(out["coarse"])
    if "half" in out:  # the second scale's estimate is supervised like the 1/4 level's
        coarse = coarse + term(out["half"])
    return fine + coarse_weight * coarse, mask


def pick_loss(quarter: torch.Tensor, mask_logits: torch.Tensor, target: torch.Tensor, levels: int, *,
              factor: int = 4, scale: float = 1.0) -> torch.Tensor:
    """The convex mask's pick loss: for each full-resolution pixel with ground truth in range, the negative
    log-likelihood of the truth under the mixture the mask puts on its cell's nine 1/4 candidates (each a
    Laplacian of ``scale`` px about the candidate, weighted as :func:`~cade_cli.train.net_blocks.convex_upsample`
    weighs it), averaged. The blend's L1 loss is met as well by two surfaces' average as by the right one where
    the candidates agree on neither; this one is low only where the mask puts its weight on a candidate near the
    truth, so it teaches the mask to pick. The candidates are detached: it trains the mask, not the estimate.
    ``quarter`` (B, 1, h, w), px at 1/4; ``mask_logits`` (B, 9·factor², h, w); ``target`` (B, 1, h·factor,
    w·factor), px."""
    batch, _, height, width = quarter.shape
    log_weights = F.log_softmax(mask_logits.float().view(batch, 9, factor * factor, height, width), dim=1)
    options = factor * neighbours3x3(quarter.detach().float()).unsqueeze(2)  # (B, 9, 1, h, w)
    truth = F.pixel_unshuffle(target, factor).unsqueeze(1)  # (B, 1, factor², h, w)
    valid = (truth >= 0) & (truth < levels)
    truth = torch.where(valid, truth, torch.zeros_like(truth))  # no inf in the sum, whose gradient would be NaN
    log_likelihood = torch.logsumexp(log_weights - (options - truth).abs() / scale, dim=1, keepdim=True)
    return -log_likelihood[valid].mean() if bool(valid.any()) else log_likelihood.sum() * 0


def edge_weights(target: torch.Tensor, valid: torch.Tensor, weight: float, *, jump: float = EDGE_JUMP,
                 radius: int = EDGE_RADIUS) -> torch.Tensor:
    """(B, 1, H, W) per-pixel loss weights: 1 + ``weight`` within ``radius`` px (Euclidean) of a jump of
    more than ``jump`` px between two 4-neighbours that both have ground truth (``valid``), 1 elsewhere:
    the benchmark's edge region (:mod:`cade_cli.evaluation.regions`, the same constants), in torch on
    the batch's device, and without its restriction to non-occluded pixels (an occluded pixel beside
    a jump is weighed up too). ``target``: (B, 1, H, W) disparity, px (anything where not ``valid``)."""
    known = torch.where(valid, target, torch.zeros_like(target))
    edge = torch.zeros_like(valid)
    across = (known[..., :, 1:] - known[..., :, :-1]).abs() > jump
    across &= valid[..., :, 1:] & valid[..., :, :-1]
    down = (known[..., 1:, :] - known[..., :-1, :]).abs() > jump
    down &= valid[..., 1:, :] & valid[..., :-1, :]
    edge[..., :, 1:] |= across
    edge[..., :, :-1] |= across
    edge[..., 1:, :] |= down
    edge[..., :-1, :] |= down
    offsets = torch.arange(-radius, radius + 1, device=target.device, dtype=torch.float32)
    disk = ((offsets[:, None] ** 2 + offsets[None, :] ** 2) <= radius * radius).float()[None, None]
    near = F.conv2d(edge.float(), disk, padding=radius) > 0.5
    return 1.0 + weight * near.float()


def feature_consistency(net: torch.nn.Module, features: torch.Tensor, left_alt: torch.Tensor) -> torch.Tensor:
    """1 - cosine, averaged over pixels, between the left view's 1/4 features (``features``,
    from the forward pass) and those of the same view in another band (``left_alt``)."""
    _, alt = net.features(left_alt)
    return (1.0 - F.cosine_similarity(features, alt, dim=1)).mean()


def check(config: TrainConfig) -> None:
    """Raise ValueError, before anything is written, for options that do not go together."""
    if config.training_mode not in TRAINING_MODES:
        raise ValueError(f"unknown training mode {config.training_mode!r}; choose one of {', '.join(TRAINING_MODES)}")
    parse_crop_schedule(config.crop_schedule)  # a malformed schedule fails before anything is written
    if config.feature_consistency > 0 and config.architecture != "cadenet2d":
        raise ValueError("the feature-consistency loss needs the cadenet2d architecture")
    if ((config.mask_evidence or config.fine_evidence or config.mask_pick > 0)
            and config.architecture != "cadenet-iterative"):
        raise ValueError("the convex mask's evidence and pick loss need the cadenet-iterative architecture")
    if config.selfsup_share > 0 and not (config.selfsup_dir and config.selfsup_cache):
        raise ValueError("the self-supervised share needs selfsup_dir and selfsup_cache")


def train(config: TrainConfig, *, resume: bool = True) -> Path:
    """Train (or continue) the run in ``config.out``; returns the final checkpoint path."""
    check(config)
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
    stepped = torch.compile(net) if config.compile else net  # the same parameters; validation runs ``net``
    (out / "config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    log, with_cpu = open_log(out / "log.csv", start)
    writer = csv.writer(log)
    validation = validation_sets(config)
    if config.selfsup_share > 0 and not any(Path(config.selfsup_cache).glob("*--*.npz")):
        # once (a cache holding pairs is used as it is), before the clocks start: data preparation
        build_cache(Path(config.selfsup_dir), Path(config.selfsup_cache), log=lambda line: print(line, flush=True))
    print(f"CadeNet: {parameter_count(net)} parameters; steps {start}..{config.steps}", flush=True)

    batches = torch.utils.data.DataLoader(
        torch.utils.data.Subset(GeneratedBatches(config), range(start, min(config.steps, config.stop_after or config.steps))),
        batch_size=None, num_workers=config.workers, persistent_workers=False, prefetch_factor=4 if config.workers else None,
        pin_memory=device_type == "cuda",
    )
    started, cpu_started = time.time(), time.process_time()
    running_loss, running_epe, seen = 0.0, 0.0, 0
    done = start
    net.train()
    for step, batch in enumerate(batches, start=start):
        rate = learning_rate(config, step, cpu_before + time.process_time() - cpu_started)
        for group in optimizer.param_groups:
            group["lr"] = rate
        done = step + 1
        measured = optimise(stepped, optimizer, batch, config, device_type)
        if measured is not None:
            running_loss, running_epe, seen = running_loss + measured[0], running_epe + measured[1], seen + 1
        else:  # a batch without ground truth, or an overflow (bf16): one NaN step would poison the run
            print(f"step {done}: loss or gradient not finite (or no ground truth); step skipped", flush=True)
        elapsed = elapsed_before + time.time() - started
        cpu = cpu_before + time.process_time() - cpu_started
        cpu_column = [f"{cpu:.0f}"] if with_cpu else []
        if done % 50 == 0:
            writer.writerow([done, f"{elapsed:.0f}", f"{rate:.2e}",
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
                writer.writerow(validation_row(done, f"{elapsed:.0f}", cpu_column, name, epe, bad3))
                print(f"  validation {name}: EPE {epe:.2f} bad3 {bad3:.1f}%", flush=True)
            log.flush()
            net.train()
        out_of_time = ((config.time_budget_s is not None and time.time() - started > config.time_budget_s)
                       or (config.cpu_budget_s is not None and cpu > config.cpu_budget_s))
        if done % config.checkpoint_every == 0 or done in (config.steps, config.stop_after) or out_of_time:
            save_checkpoint(checkpoint_path, net, optimizer, done, elapsed, config, cpu)
        if out_of_time:
            print(f"time budget spent ({time.time() - started:.0f} s in this process, {cpu:.0f} CPU-s in the run): "
                  f"stopped after step {done} (checkpointed)", flush=True)
            break
    if done >= config.steps:  # the line a queue reads (runs/bakeoff-queue.sh): a step-bounded run is not relaunched
        print(f"finished: step {done} of {config.steps} (checkpointed)", flush=True)
    log.close()
    return checkpoint_path


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
    """One optimiser step on ``batch``: (loss, training EPE px; 0 for a batch of self-supervised
    pairs only), or None when the step was skipped (neither ground truth nor self-supervised
    pairs in the batch, or a loss or gradient that is not finite)."""
    batch = {key: value.to(config.device, non_blocking=True) for key, value in batch.items()}
    with torch.autocast(device_type, dtype=torch.bfloat16, enabled=config.amp):
        out = net(batch["left"], batch["right"])
        out = {key: value.float() for key, value in out.items()}
        loss, mask = loss_terms(out, batch["disparity"], config.levels, config.coarse_weight, config.edge_weight)
        if config.mask_pick > 0:
            loss = loss + config.mask_pick * pick_loss(out["quarter"], out["mask"], batch["disparity"], config.levels)
        if config.feature_consistency > 0:
            loss = loss + config.feature_consistency * feature_consistency(net, out["features"], batch["left_alt"])
        chosen = batch["selfsup"] if "selfsup" in batch else None
        if chosen is not None:
            unsupervised = config.selfsup_weight * selfsup_loss(out["disparity"], batch["guides"], chosen)
            loss = unsupervised if not bool(mask.any()) else loss + unsupervised
    optimizer.zero_grad(set_to_none=True)
    if not ((bool(mask.any()) or chosen is not None) and bool(torch.isfinite(loss))):
        return None
    loss.backward()
    if not bool(torch.isfinite(torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0))):
        return None
    optimizer.step()
    epe = (out["disparity"] - batch["disparity"]).detach().abs()[mask].mean().item() if bool(mask.any()) else 0.0
    return loss.item(), epe


def validation_row(step: int, elapsed: str, cpu: list[str], name: str, epe: float, bad3: float) -> list:
    """A log row of one validation set's figures, in :func:`open_log`'s columns (``cpu``: the
    ``cpu_s`` cell, or nothing for a log begun without that column)."""
    return [step, elapsed, "", "", "", name, f"{epe:.3f}", f"{bad3:.2f}", *cpu]


def validate_run(run: Path, data_dir: Path, *, threads: int = 2) -> list[tuple[str, float, float]]:
    """Score ``run``'s last checkpoint on the validation sets that ``fit`` would have scored with
    ``data_dir`` (Middlebury 2014 Q and 2005, cross-spectral and same-band whether or not the run
    validated the same-band sets itself, and msir-outdoor; not the synthetic set, which every run
    scores) and append the rows to its ``log.csv`` at the checkpoint's step, as ``fit`` writes them:
    for a run trained where those sets were not, on a lent GPU (docs/gpu-recipe.md). A set already in
    the log at that step is left as it is. Returns the rows added: (set, EPE px, bad-3 %)."""
    from cade_cli.train.export import load_checkpoint

    torch.set_num_threads(threads)
    net, checkpoint = load_checkpoint(run / "last.pt")
    fields = TrainConfig.__dataclass_fields__  # a checkpoint of an older TrainConfig may hold keys it has lost
    config = TrainConfig(**{**{key: value for key, value in checkpoint["config"].items() if key in fields},
                            "data_dir": str(data_dir), "device": "cpu", "threads": threads, "validate_rgb": True})
    log_path = run / "log.csv"
    header, *rows = csv.reader(log_path.read_text().splitlines())
    step = checkpoint["step"]
    at_step = [row for row in rows if int(row[0]) == step]
    logged = {row[5] for row in at_step if row[6]}
    added = [(name, *evaluate(net, pairs, "cpu"))
             for name, pairs in validation_sets(config, synthetic=False).items() if name not in logged]
    # the step's clocks as fit's rows at that step have them, else the checkpoint's
    elapsed = at_step[0][1] if at_step else f"{checkpoint.get('elapsed_s', 0.0):.0f}"
    cpu = ([at_step[0][8] if at_step else f"{checkpoint.get('cpu_s', 0.0):.0f}"] if "cpu_s" in header else [])
    with log_path.open("a", newline="") as log:
        writer = csv.writer(log)
        for name, epe, bad3 in added:
            writer.writerow(validation_row(step, elapsed, cpu, name, epe, bad3))
    return added
