"""The benchmark loop: dataset x protocol x method, scored the paper's way.

One loop over work units (scene, protocol, method, preprocess), each scored into flat
records; summaries average the records over tasks and scenes. Deterministic: units run
in a fixed order and results are sorted the same way whatever ``jobs`` is.
"""

from __future__ import annotations

import json
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from cade_cli.allocator import retain_freed_memory
from cade_cli.datasets import get_dataset
from cade_cli.matching import get_matcher
from cade_cli.metrics import METRIC_NAMES, score
from cade_cli.protocols import get_protocol, run_protocol

@dataclass(frozen=True)
class Unit:
    """One piece of work: every task of ``protocol`` on one scene with one method."""

    dataset: str
    data_dir: str
    scene: str
    protocol: str
    method: str
    preprocess: str


@dataclass(frozen=True)
class Record:
    """Scores of one scored prediction (one CS task, or the RGB median map)."""

    dataset: str
    resolution: str
    scene: str
    protocol: str
    method: str
    preprocess: str
    task: str
    seconds: float
    matcher_runs: int
    scores: dict[str, float]


@dataclass
class BenchmarkRun:
    """Everything a benchmark produced: its configuration and one record per scored map."""

    config: dict
    records: list[Record] = field(default_factory=list)

    def summary(self) -> list[dict]:
        """Mean of every metric and of seconds per (method, preprocess, protocol), in config order."""
        rows = []
        for method in self.config["methods"]:
            for preprocess in self.config["preprocess"]:
                for protocol in self.config["protocols"]:
                    chosen = [r for r in self.records
                              if (r.method, r.preprocess, r.protocol) == (method, preprocess, protocol)]
                    if not chosen:
                        continue
                    means = {name: float(np.nanmean([r.scores.get(name, np.nan) for r in chosen]))
                             for name in sorted({k for r in chosen for k in r.scores})}
                    pairs = {(r.scene, r.task) for r in chosen}
                    rows.append({
                        "method": method, "preprocess": preprocess, "protocol": protocol,
                        "scores": means, "maps": len(pairs),
                        "seconds_per_pair": float(sum(r.seconds for r in chosen) / sum(r.matcher_runs for r in chosen)),
                    })
        return rows

    def to_json(self) -> str:
        return json.dumps(
            {"config": self.config, "summary": self.summary(), "records": [asdict(r) for r in self.records]},
            indent=1, allow_nan=True,
        )


def run_benchmark(
    *,
    dataset: str,
    data_dir: Path,
    methods: Sequence[str],
    protocols: Sequence[str],
    preprocess: Sequence[str],
    scenes: Sequence[str] | None = None,
    jobs: int = 1,
    save_dir: Path | None = None,
    on_unit_done: Callable[[Unit], None] | None = None,
    on_start: Callable[[int], None] | None = None,
) -> BenchmarkRun:
    """Run every (scene, protocol, method, preprocess) combination and score it.

    Args:
        dataset: a name from :data:`cade_cli.datasets.DATASETS`.
        data_dir: where that dataset lies (its official layout).
        methods: names from :data:`cade_cli.matching.MATCHERS`.
        protocols: names from :data:`cade_cli.protocols.PROTOCOLS` (``cs``, ``rgb``, ``native``).
        preprocess: values of the matchers' ``preprocess`` (``none``, ``cade``, ``auto``);
            ``none`` is skipped for matchers that only take color-agnostic bands.
        scenes: restrict to these scene names (default: all).
        jobs: worker processes (1 = run in this process).
        save_dir: when given, each scored disparity (PFM) and a colourised error map
            (PNG) are written under ``save_dir/<method>+<preprocess>/<protocol>/``.
        on_unit_done: called after each unit, e.g. to advance a progress bar.
        on_start: called once with the number of units before the first runs.
    """
    for method in methods:
        get_matcher(method)
    for protocol in protocols:
        get_protocol(protocol)
    reader = get_dataset(dataset)
    if scenes:
        reader(Path(data_dir), scenes=scenes)  # checks the names; loads nothing
    scene_names = [name for name in reader.scene_names(Path(data_dir)) if not scenes or name in set(scenes)]
    units = [
        Unit(dataset, str(data_dir), scene, protocol, method, pre)
        for scene in scene_names for protocol in protocols for method in methods for pre in preprocess
        if pre != "none" or get_matcher(method).accepts_raw  # the CADE network has no raw-band mode
    ]
    config = {
        "dataset": dataset, "data_dir": str(data_dir), "scenes": scene_names, "methods": list(methods),
        "protocols": list(protocols), "preprocess": list(preprocess), "metrics": list(METRIC_NAMES),
    }
    run = BenchmarkRun(config)
    if on_start is not None:
        on_start(len(units))
    save = str(save_dir) if save_dir is not None else None
    for unit, records in _map(units, jobs, save):
        run.records.extend(records)
        if on_unit_done is not None:
            on_unit_done(unit)
    return run


def _map(units: list[Unit], jobs: int, save_dir: str | None) -> Iterable[tuple[Unit, list[Record]]]:
    if jobs <= 1:
        for unit in units:
            yield unit, run_unit(unit, save_dir)
        return
    with ProcessPoolExecutor(max_workers=jobs, initializer=retain_freed_memory) as pool:
        futures = [pool.submit(run_unit, unit, save_dir) for unit in units]
        for unit, future in zip(units, futures):  # in submission order: deterministic
            yield unit, future.result()


def run_unit(unit: Unit, save_dir: str | None = None) -> list[Record]:
    """Run and score every task of one unit (a module-level function, so it pickles)."""
    scene = next(iter(get_dataset(unit.dataset)(Path(unit.data_dir), scenes=[unit.scene])))
    matcher = get_matcher(unit.method)

    def match(left_band: np.ndarray, right_band: np.ndarray):
        return matcher(left_band, right_band, max_disp=scene.max_disp, min_disp=0, preprocess=unit.preprocess)

    protocol = get_protocol(unit.protocol)
    # A combined map (the RGB median) costs one matcher run per task it combines.
    runs = len(protocol.tasks) if protocol.combine else 1
    records = []
    for result in run_protocol(unit.protocol, match, scene.left, scene.right):
        if not result.scored:
            continue
        scores = score(result.disparity, scene.disparity, nonocc=scene.nonocc, pred_valid=result.valid)
        records.append(Record(
            dataset=unit.dataset, resolution=scene.resolution, scene=scene.name, protocol=unit.protocol,
            method=unit.method, preprocess=unit.preprocess, task=result.name, seconds=result.seconds,
            matcher_runs=runs, scores=scores,
        ))
        if save_dir is not None:
            _save_maps(Path(save_dir), unit, scene.name, result.name, result.disparity, scene.disparity)
    return records


def _save_maps(root: Path, unit: Unit, scene: str, task: str, disparity: np.ndarray, gt: np.ndarray) -> None:
    import cv2

    from cade_cli.disparity_io import write_disparity

    folder = root / f"{unit.method}+{unit.preprocess}" / unit.protocol
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{scene.replace('/', '_')}_{task.replace('>', 'to')}"
    write_disparity(folder / f"{stem}.pfm", disparity)
    error = np.abs(disparity - gt)
    # 0 px black ... >= 8 px white-hot; pixels without ground truth dark blue.
    scaled = np.clip(np.nan_to_num(error, nan=0.0) / 8.0 * 255.0, 0, 255).astype(np.uint8)
    colour = cv2.applyColorMap(scaled, cv2.COLORMAP_INFERNO)
    colour[~np.isfinite(gt)] = (80, 0, 0)
    cv2.imwrite(str(folder / f"{stem}_error.png"), colour)
