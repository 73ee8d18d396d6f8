"""Fit the learned chooser (:class:`cade_cli.matching.chooser.Chooser`) and score it.

:func:`cache_candidates` stores the cade matcher's two candidates per scene and CS task
(the network's map and uncertainty, SGBM's match of the rank images and where SGBM
accepted it, the left band, the GT). The chooser is fitted on the train-real caches only
and scored on the reporting sets' caches against the fixed 32 px rule and the oracle (the
better of the two candidates per pixel). The fit weighs each pixel by how much the choice
matters: a pixel where one candidate is within 3 px of the truth and the other is not
counts most. Only the pixels the pipeline asks the chooser about are fitted on: disputed
(:func:`~cade_cli.matching.chooser.disputed`) and visible in the right view (elsewhere
the pipeline marks the pixel invalid and fills it). ``edge_weight`` W weighs the pixels near a
ground-truth depth jump (the benchmark's depth-edge band, :mod:`cade_cli.evaluation.regions`)
1 + W times more, where the whole matcher's errors are mostly the choice's
(docs/research/refinement.md, 2026-12-07). Which of these choices to keep was
decided by 3-fold cross-validation over the train-real scenes, never on a reporting set. ``python -m cade_cli.train chooser`` runs it all and can write the chooser
into the model's card, where the runtime finds it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from cade_cli.data import get_dataset
from cade_cli.evaluation.metrics import score as score_map
from cade_cli.evaluation.protocols import get_protocol
from cade_cli.evaluation.regions import EDGE_RADIUS, depth_jumps, near
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.chooser import EDGE_FEATURES, FEATURES, Chooser, chooser_features, disputed
from cade_cli.matching.disparity import densify, visible_in_right_view
from cade_cli.matching.learned import card_refinement
from cade_cli.matching.network import NetworkStage
from cade_cli.matching.refinement import RankSgbmRefinement

BAD = 3.0
"""px: a pick matters when it moves a pixel across the benchmark's BMP3 threshold (``bad3``)."""
AGREEMENT = RankSgbmRefinement().agreement
"""px: the refinement's fixed rule, which the learned chooser is scored against."""


PROTOCOLS = ("cs", "rgb")
"""The tasks cached per scene: the six cross-band pairs and the three same-band ones."""
CS_TASKS = tuple(task.name.replace(">", "") for task in get_protocol("cs").tasks)
SAME_BAND_TASKS = tuple(task.name.replace(">", "") for task in get_protocol("rgb").tasks)


def candidate_stages(model: str, candidates: str | None = None) -> tuple[NetworkStage, RankSgbmRefinement]:
    """``model``'s network and the refinement its card's ``runtime_refinement`` names (or ``candidates`` names)."""
    network = NetworkStage(model=model)
    card = network.card()
    if candidates is not None:
        card = replace(card, refinement=candidates)
    return network, card_refinement(card, RankSgbmRefinement())


def task_candidates(network: NetworkStage, refinement: RankSgbmRefinement, left: np.ndarray, right: np.ndarray,
                    span: int, key: str) -> dict[str, np.ndarray]:
    """One task's cached arrays, named ``{key}_{name}``: the network's map and uncertainty over 0 .. ``span`` px,
    SGBM's match and where SGBM accepted it, and both bands (what :func:`tasks_of` reads back)."""
    estimate = network.estimate(left, right, DisparityRange(0, span))
    candidate, accepted = refinement.candidate(left, right, estimate.disparity, span)
    return {f"{key}_network": estimate.disparity, f"{key}_uncertainty": estimate.uncertainty,
            f"{key}_candidate": candidate, f"{key}_accepted": accepted, f"{key}_left": left, f"{key}_right": right}


def cache_candidates(dataset: str, data_dir: Path, out: Path, *, model: str,
                     scenes: Sequence[str] | None = None, candidates: str | None = None) -> list[Path]:
    """One npz per scene of ``dataset`` (all, or those named in ``scenes``) in ``out`` (kept
    when it exists), the candidates of ``model``'s network and the rank-SGBM refinement for
    every task of :data:`PROTOCOLS`; returns the files. The refinement is the one the card's
    ``runtime_refinement`` names, or the one ``candidates`` names."""
    out.mkdir(parents=True, exist_ok=True)
    network, refinement = candidate_stages(model, candidates)
    files = []
    for scene in get_dataset(dataset)(data_dir, scenes=scenes):
        target = out / f"{scene.name.replace('/', '-')}.npz"
        files.append(target)
        if target.exists():
            add_right_bands(target, scene)
            continue
        stored = {"gt": scene.disparity.astype(np.float32)}
        for task in cached_tasks():
            left, right = task.bands(scene.left, scene.right)
            stored.update(task_candidates(network, refinement, left, right, scene.max_disp, key_of(task)))
        save_atomically(target, stored)
        print(f"cached {dataset} {scene.name}", flush=True)
    return files


def cached_tasks():
    """Every task of :data:`PROTOCOLS`, in the order the cache stores them."""
    return (task for protocol in PROTOCOLS for task in get_protocol(protocol).tasks)


def key_of(task) -> str:
    """A task's name in a cache (its arrays' prefix): "R>G" -> "RG"."""
    return task.name.replace(">", "")


def save_atomically(target: Path, arrays: dict[str, np.ndarray]) -> None:
    """``arrays`` as a compressed npz at ``target``, through a temporary file: never a half-written cache."""
    temporary = target.with_suffix(".partial.npz")
    np.savez_compressed(temporary, **arrays)
    temporary.replace(target)


def add_right_bands(target: Path, scene) -> None:
    """Give a cache written before the right bands were stored (2026-12-07) each task's right band, from ``scene``
    (what :func:`task_candidates` stores now; the other arrays as they were, no network run)."""
    with np.load(target) as stored:
        lacking = [task for task in cached_tasks() if f"{key_of(task)}_left" in stored.files
                   and f"{key_of(task)}_right" not in stored.files]
        if not lacking:  # read the arrays only where some must be added: a fit calls this for every cached scene
            return
        arrays = {key: stored[key] for key in stored.files}
    for task in lacking:
        arrays[f"{key_of(task)}_right"] = task.bands(scene.left, scene.right)[1]
    save_atomically(target, arrays)
    print(f"added the right bands to {target.name}", flush=True)


def tasks_of(cache: Path, tasks: tuple[str, ...] | None = None):
    """(gt, {key: array}) per task of one cached scene (those named in ``tasks``, e.g. "RB")."""
    stored = np.load(cache)
    gt = stored["gt"]
    prefixes = sorted({key.split("_")[0] for key in stored.files if key != "gt"})
    for prefix in prefixes:
        if tasks is not None and prefix not in tasks:
            continue
        names = ("network", "uncertainty", "candidate", "accepted", "left", "right")
        yield gt, {name: stored[f"{prefix}_{name}"] for name in names if f"{prefix}_{name}" in stored.files}


def features_of(task: dict, names: tuple[str, ...] = FEATURES) -> np.ndarray:
    return chooser_features(task["left"], task["network"], task["uncertainty"], task["candidate"], task["accepted"],
                            names=names)


def feature_names(edge_features: bool) -> tuple[str, ...]:
    """The chooser's inputs: :data:`FEATURES`, or with :data:`EDGE_FEATURES` before the bias."""
    return (*FEATURES[:-1], *EDGE_FEATURES, FEATURES[-1]) if edge_features else FEATURES


def asked_pixels(gt: np.ndarray, task: dict) -> np.ndarray:
    """(H, W) bool: the pixels of a cached task the pipeline asks the chooser about and the truth can judge:
    disputed, visible in the right view (the pipeline decides there only), with ground truth."""
    network = task["network"]
    return disputed(network, task["candidate"], task["accepted"]) & np.isfinite(gt) & visible_in_right_view(network)


def choice_targets(network: np.ndarray, candidate: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Label (float32, 1 where SGBM's match is nearer the truth) and weight (as the module docstring says; float64,
    so that a further factor rounds once, at the caller's cast) of pixels with their network value, SGBM's match and
    the truth (arrays of one shape, finite truth)."""
    error_network, error_candidate = np.abs(network - gt), np.abs(candidate - gt)
    decisive = (error_candidate <= BAD) != (error_network <= BAD)
    weight = 0.05 + 2.0 * decisive + np.minimum(np.abs(error_candidate - error_network), 10) / 10
    return (error_candidate < error_network).astype(np.float32), weight


def samples(caches: list[Path], rng: np.random.Generator, per_task: int = 20000, tasks: tuple[str, ...] | None = None,
            edge_weight: float = 0.0, names: tuple[str, ...] = FEATURES):
    """(features, label, weight) of up to ``per_task`` disputed, visible pixels of each task: label 1
    where SGBM's match is nearer the truth; the weight as the module docstring says."""
    xs, ys, ws = [], [], []
    for cache in caches:
        edges = None
        for gt, task in tasks_of(cache, tasks):
            if edges is None and edge_weight > 0:
                edges = near(depth_jumps(gt), radius=EDGE_RADIUS)
            features = features_of(task, names)
            rows, cols = np.nonzero(asked_pixels(gt, task))
            if len(rows) == 0:
                continue
            pick = rng.choice(len(rows), size=min(per_task, len(rows)), replace=False)
            rows, cols = rows[pick], cols[pick]
            label, weight = choice_targets(task["network"][rows, cols], task["candidate"][rows, cols], gt[rows, cols])
            if edges is not None:
                weight = weight * (1.0 + edge_weight * edges[rows, cols])
            xs.append(features[rows, cols]), ys.append(label), ws.append(weight.astype(np.float32))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(ws)


def fit(caches: list[Path], *, hidden: int = 16, steps: int = 3000, seed: int = 0,
        tasks: tuple[str, ...] | None = None, edge_weight: float = 0.0, edge_features: bool = False) -> Chooser:
    """The chooser fitted on the disputed, visible pixels of ``tasks`` (default: every
    cached task) of ``caches``, those near a depth jump weighed 1 + ``edge_weight`` times more;
    with ``edge_features`` it also sees :data:`~cade_cli.matching.chooser.EDGE_FEATURES`."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    names = feature_names(edge_features)
    x, y, w = (torch.from_numpy(a) for a in samples(caches, rng, tasks=tasks, edge_weight=edge_weight, names=names))
    first = torch.nn.Linear(len(names), hidden, bias=False)  # the bias is the last feature
    second = torch.nn.Linear(hidden, 1)
    optimizer = torch.optim.Adam([*first.parameters(), *second.parameters()], lr=1e-2)
    for step in range(steps):
        batch = torch.randint(0, len(x), (8192,))
        logits = second(torch.relu(first(x[batch]))).squeeze(1)
        loss = (torch.nn.functional.binary_cross_entropy_with_logits(logits, y[batch], reduction="none")
                * w[batch]).sum() / w[batch].sum()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if step % 500 == 0:
            print(f"chooser step {step} loss {loss.item():.4f}", flush=True)
    with torch.no_grad():
        output = torch.cat([second.weight[0], second.bias]).numpy()
        return Chooser(first.weight.T.numpy().copy(), output.copy(), features=names)


def score(caches: list[Path], chooser: Chooser | None, tasks: tuple[str, ...] | None = CS_TASKS
          ) -> dict[str, tuple[float, float]]:
    """Mean over scenes of the mean over tasks: EPE / BMP3 (all GT pixels) of the network,
    the fixed rule, the chooser and the oracle, each as the pipeline finishes it (invalid
    where the network's surface is hidden in the right view, then filled along rows)."""
    per_scene = []
    for cache in caches:
        rows = []
        for gt, task in tasks_of(cache, tasks):
            network, candidate, accepted = task["network"], task["candidate"], task["accepted"]
            maps = {"network": network,
                    "fixed": np.where(accepted & (np.abs(candidate - network) <= AGREEMENT), candidate, network)}
            if chooser is not None:
                taken = chooser.take(task["left"], network, task["uncertainty"], candidate, accepted, task.get("right"))
                maps["learned"] = np.where(taken, candidate, network)
            better = np.abs(candidate - gt) < np.abs(network - gt)
            maps["oracle"] = np.where(accepted & better, candidate, network)
            valid = visible_in_right_view(network)
            maps = {name: densify(np.where(valid, m, np.float32(np.nan)), valid) for name, m in maps.items()}
            scored = {name: score_map(m, gt) for name, m in maps.items()}  # the benchmark's metrics, all pixels
            rows.append({name: (metrics["epe_all"], metrics["bad3_all"]) for name, metrics in scored.items()})
        per_scene.append({name: tuple(np.mean([r[name][i] for r in rows]) for i in range(2)) for name in rows[0]})
    return {name: tuple(float(np.mean([s[name][i] for s in per_scene])) for i in range(2)) for name in per_scene[0]}


def report(result: dict[str, tuple[float, float]]) -> str:
    return ", ".join(f"{name} {epe:.3f} / {bmp:.2f}" for name, (epe, bmp) in result.items())
