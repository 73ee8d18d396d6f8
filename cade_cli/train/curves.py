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

SETS = ("middlebury05-cs", "middlebury14Q-cs")
"""Validation sets drawn: the network alone, CS tasks R>B and B>R of both Middlebury sets."""


@dataclass
class RunCurve:
    name: str
    start: int
    steps: int
    points: dict[str, list[tuple[int, float, float]]] = field(default_factory=dict)
    """set -> [(step from the chain's start, EPE, bad-3 %)]."""


def read_run(folder: Path, runs: dict[str, RunCurve]) -> RunCurve:
    """The curve of the run in ``folder``; its ancestors (``init``) must be in ``runs``."""
    config = json.loads((folder / "config.json").read_text())
    parent = Path(config["init"]).parent.name if config.get("init") else None
    start = runs[parent].start + runs[parent].steps if parent in runs else 0
    curve = RunCurve(folder.name, start, int(config["steps"]))
    with (folder / "log.csv").open() as stream:
        for row in csv.DictReader(stream):
            if row["set"] in SETS and row["val_epe"]:
                curve.points.setdefault(row["set"], []).append(
                    (start + int(row["step"]), float(row["val_epe"]), float(row["val_bad3"])))
    return curve


def fill_final_points(curve: RunCurve, folder: Path, data_dir: Path | None) -> None:
    """Score the run's last checkpoint on the sets its log lacks."""
    missing = [name for name in SETS if name not in curve.points]
    checkpoint = folder / "last.pt"
    if not missing or data_dir is None or not checkpoint.is_file():
        return
    from cade_cli.train.export import load_checkpoint
    from cade_cli.train.fit import TrainConfig, evaluate, validation_sets

    net, state = load_checkpoint(checkpoint)
    config = TrainConfig(out=str(folder), textures=[], data_dir=str(data_dir), levels=net.levels)
    sets = validation_sets(config, synthetic=False)
    for name in missing:
        if name in sets:
            epe, bad3 = evaluate(net, sets[name], "cpu")
            curve.points[name] = [(curve.start + int(state["step"]), epe, bad3)]


def plot(curves: list[RunCurve], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for column, name in enumerate(SETS):
        for row, (metric, label) in enumerate(((1, "EPE (px)"), (2, "bad-3 (%)"))):
            axis = axes[row][column]
            for curve in curves:
                points = curve.points.get(name, [])
                if points:
                    axis.plot([p[0] for p in points], [p[metric] for p in points], marker="o", markersize=3,
                              label=curve.name)
            axis.set_title(f"{name}: network alone, {label.split(' ')[0]}")
            axis.set_ylabel(label)
            axis.grid(alpha=0.3)
    for axis in axes[1]:
        axis.set_xlabel("training steps (cumulative over the fine-tuning chain)")
    axes[0][0].legend(fontsize=8)
    figure.suptitle("CadeNet validation (R>B and B>R of each scene; python -m cade_cli.train curves)")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
