"""Learning curves: validation EPE and bad-3 against training steps, one picture.

Runs chain through their ``init`` checkpoint (cade-v2 fine-tunes cade-v1, ...), so each
run is drawn from the step its ancestors ended at. The points are the validation rows of
each run's ``log.csv`` (written by :func:`cade_cli.train.fit.train`: the network alone on
fixed pairs). Runs from before a validation set existed are given the point their final
checkpoint scores on it (``runs/<run>/last.pt``, evaluated here with the same functions),
so every run has a value at its end.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

SETS = ("middlebury05-cs", "middlebury14Q-cs", "middlebury05-rgb", "middlebury14Q-rgb", "msir-outdoor")
"""Validation sets drawn (those some run has): the network alone, CS tasks R>B and B>R and
same-band tasks R>R, G>G, B>B of both Middlebury sets, and the real visible/near-infrared pairs of
msir-outdoor against their pseudo ground truth (:func:`~cade_cli.train.validation.validation_sets`)."""


@dataclass
class RunCurve:
    name: str
    start: int
    steps: int
    points: dict[str, list[tuple[int, float, float, float | None]]] = field(default_factory=dict)
    """set -> [(step from the chain's start, EPE, bad-3 %, CPU-hours over the chain or None)]:
    CPU-hours from the log's ``cpu_s`` (logs since Accuracy III), the training process's
    CPU time, all threads, added to the ancestors' last."""
    cpu_hours: float = 0.0
    """CPU-hours over the chain at the run's last logged step."""


def read_run(folder: Path, runs: dict[str, RunCurve]) -> RunCurve:
    """The curve of the run in ``folder``; its ancestors (``init``) must be in ``runs``. A run
    ends at its last logged step (a run stopped early hands that step on to its children)."""
    config = json.loads((folder / "config.json").read_text())
    parent = runs.get(Path(config["init"]).parent.name) if config.get("init") else None
    start = parent.start + parent.steps if parent else 0
    cpu_start = parent.cpu_hours if parent else 0.0
    curve = RunCurve(folder.name, start, 0, cpu_hours=cpu_start)
    with (folder / "log.csv").open() as stream:
        for row in csv.DictReader(stream):
            curve.steps = max(curve.steps, int(row["step"]))
            cpu = cpu_start + float(row["cpu_s"]) / 3600 if row.get("cpu_s") else None
            curve.cpu_hours = max(curve.cpu_hours, cpu or 0.0)
            if row["set"] in SETS and row["val_epe"]:
                curve.points.setdefault(row["set"], []).append(
                    (start + int(row["step"]), float(row["val_epe"]), float(row["val_bad3"]), cpu))
    curve.steps = curve.steps or int(config["steps"])
    return curve


def fill_final_points(curve: RunCurve, folder: Path, data_dir: Path | None) -> None:
    """Score the run's last checkpoint on the sets its log lacks."""
    missing = [name for name in SETS if name not in curve.points]
    checkpoint = folder / "last.pt"
    if not missing or data_dir is None or not checkpoint.is_file():
        return
    from cade_cli.train.config import TrainConfig
    from cade_cli.train.export import load_checkpoint
    from cade_cli.train.validation import evaluate, validation_sets

    net, state = load_checkpoint(checkpoint)
    config = TrainConfig(out=str(folder), textures=[], data_dir=str(data_dir), levels=net.levels)
    sets = validation_sets(config, synthetic=False)
    for name in missing:
        if name in sets:
            epe, bad3 = evaluate(net, sets[name], "cpu")
            curve.points[name] = [(curve.start + int(state["step"]), epe, bad3, None)]


def plot(curves: list[RunCurve], path: Path) -> None:
    """One PNG: a column per validation set some run has; rows EPE and bad-3 against steps
    and, when some run logged its CPU time, against CPU-hours (equal-compute comparisons)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = [name for name in SETS if any(curve.points.get(name) for curve in curves)] or list(SETS[:2])
    with_cpu = any(p[3] is not None for curve in curves for points in curve.points.values() for p in points)
    axes_x = [(0, "training steps (cumulative over the fine-tuning chain)")]
    if with_cpu:
        axes_x.append((3, "CPU-hours (training process, all threads; cumulative over the chain)"))
    rows = [(x, metric, label, xlabel) for x, xlabel in axes_x for metric, label in ((1, "EPE (px)"), (2, "bad-3 (%)"))]
    figure, axes = plt.subplots(len(rows), len(sets), figsize=(4.2 * len(sets), 3.3 * len(rows)), squeeze=False)
    for column, name in enumerate(sets):
        for row, (x, metric, label, xlabel) in enumerate(rows):
            axis = axes[row][column]
            for index, curve in enumerate(curves):  # one colour per run in every panel
                points = [p for p in curve.points.get(name, []) if p[x] is not None]
                if points:
                    axis.plot([p[x] for p in points], [p[metric] for p in points], marker="o", markersize=3,
                              label=curve.name, color=f"C{index % 10}")
            axis.set_title(f"{name}: network alone, {label.split(' ')[0]}", fontsize=9)
            axis.set_ylabel(label)
            axis.set_xlabel(xlabel, fontsize=8)
            axis.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    figure.suptitle("Validation of the network alone (cs: R>B and B>R; rgb: R>R, G>G, B>B of each scene; "
                    "python -m cade_cli.train curves)")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
