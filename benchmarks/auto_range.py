#!/usr/bin/env python
"""How well ``--max-disp auto`` (and ``--min-disp auto``) does on the benchmark sets.

For every scene of each dataset and the cross-spectral tasks ``R>B`` and ``B>R``:

* coverage: the share of the scene's ground-truth disparities inside the estimated range
  (:func:`cade_cli.scale.range.estimate_range`), over all GT pixels and over the GT pixels whose
  match lies inside the right image (x - d >= 0: the only ones a matcher can find), for
  ``--max-disp auto`` (minimum 0) and for both bounds estimated;
* accuracy: each matcher's EPE (all GT pixels, dense map) through the one benchmark loop
  (:func:`cade_cli.evaluation.loop.run_benchmark`), once with the dataset's range
  [0, max_disp] and once with ``--max-disp auto`` (:class:`AutoRange` resolves the range
  per task, then calls the same matcher).

    .venv/bin/python benchmarks/auto_range.py --data-dir ../shared/data \\
        [--datasets middlebury14,middlebury05,kitti2015,kitti2012,flyingthings3d] \\
        [--methods cade,census-sgm,sgbm] [--markdown docs/bench/auto-range.md]
"""

from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cade_cli.allocator import retain_freed_memory
from cade_cli.data import get_dataset
from cade_cli.errors import CadeError
from cade_cli.evaluation.loop import run_benchmark
from cade_cli.evaluation.protocols import get_protocol
from cade_cli.evaluation.report import markdown_row
from cade_cli.matching import MATCHERS
from cade_cli.scale.range import AUTO, resolve_range

DATASETS = ("middlebury14", "middlebury05", "kitti2015", "kitti2012", "flyingthings3d")
COVERAGE_TARGET = 0.99
EPE_TOLERANCE = 0.05


@dataclass(frozen=True)
class AutoRange:
    """A registered matcher whose range is estimated per pair (``--max-disp auto``): the
    ``max_disp`` the loop passes is ignored, ``min_disp`` kept."""

    matcher: object

    def resolve_preprocess(self, preprocess: str) -> str:
        return self.matcher.resolve_preprocess(preprocess)

    def __call__(self, left, right, *, max_disp, min_disp=0, preprocess="auto"):
        searched, _ = resolve_range(left, right, min_disp=min_disp, max_disp=AUTO)
        return self.matcher(left, right, max_disp=searched.maximum, min_disp=searched.minimum, preprocess=preprocess)


def coverage_rows(dataset: str, data_dir: Path, tasks: list[str]) -> list[dict]:
    """Per scene and task: the estimated ranges and the share of GT they cover."""
    chosen = [task for task in get_protocol("cs").tasks if task.name in tasks]
    rows = []
    for scene in get_dataset(dataset)(data_dir):
        gt = scene.disparity
        known = np.isfinite(gt)
        columns = np.broadcast_to(np.arange(gt.shape[1])[None, :], gt.shape)
        visible = known & (columns - np.where(known, gt, 0) >= 0)
        for task in chosen:
            left, right = task.bands(scene.left, scene.right)
            row = {"dataset": dataset, "scene": scene.name, "task": task.name, "max_disp": scene.max_disp,
                   "gt": (float(gt[known].min()), float(gt[known].max()))}
            for mode, minimum in (("max", 0), ("both", AUTO)):
                searched, _ = resolve_range(left, right, min_disp=minimum, max_disp=AUTO)
                inside = (gt >= searched.minimum) & (gt <= searched.maximum)
                row[mode] = {"range": (searched.minimum, searched.maximum),
                             "all": float(inside[known].mean()), "visible": float(inside[visible].mean())}
            rows.append(row)
    return rows


def epe_by_scene(dataset: str, data_dir: Path, methods: list[str], tasks: list[str], jobs: int) -> dict:
    """(method, scene) -> (EPE with [0, max_disp], EPE with the auto range), means over the tasks."""
    matchers = {**{name: MATCHERS[name] for name in methods},
                **{f"{name}@auto": AutoRange(MATCHERS[name]) for name in methods}}
    run = run_benchmark(dataset=dataset, data_dir=data_dir, methods=list(matchers), protocols=["cs"],
                        preprocess=["auto"], tasks=tasks, matchers=matchers, jobs=jobs)
    found: dict = {}
    for record in run.records:
        method, _, auto = record.method.partition("@")
        found.setdefault((method, record.scene), ([], []))[1 if auto else 0].append(record.scores["epe_all"])
    return {key: (float(np.mean(true)), float(np.mean(auto))) for key, (true, auto) in found.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--methods", default="cade,census-sgm,sgbm")
    parser.add_argument("--tasks", default="R>B,B>R")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes, one scene each")
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    retain_freed_memory()
    datasets, methods, tasks = (value.split(",") for value in (args.datasets, args.methods, args.tasks))
    try:
        coverage = [row for name in datasets for row in coverage_rows(name, args.data_dir, tasks)]
        epe = {name: epe_by_scene(name, args.data_dir, methods, tasks, args.jobs) for name in datasets}
    except CadeError as error:
        raise SystemExit(str(error)) from None

    lines = ["# `--max-disp auto`: coverage of the ground truth and EPE", "",
             f"Produced by `{shlex.join(['.venv/bin/python', 'benchmarks/auto_range.py', *sys.argv[1:]])}`.",
             f"Tasks {', '.join(tasks)} of each scene. Coverage: share of the GT disparities inside the estimated "
             "range, over all GT pixels and over those whose match lies inside the right image (x - d >= 0); "
             "'max': `--max-disp auto` (minimum 0), 'both': `--min-disp auto --max-disp auto`. The worst task of "
             "each scene is shown.", "",
             markdown_row(["dataset", "scene", "GT range", "dataset range", "auto max: range", "covered (all)",
                           "covered (visible)", "auto both: range", "covered (all)", "covered (visible)"]),
             "|---|---|---|---|---|---:|---:|---|---:|---:|"]
    failures = []
    for dataset in datasets:
        for scene in dict.fromkeys(row["scene"] for row in coverage if row["dataset"] == dataset):
            rows = [row for row in coverage if row["dataset"] == dataset and row["scene"] == scene]
            worst = {mode: min(rows, key=lambda row: row[mode]["all"]) for mode in ("max", "both")}
            cells = [dataset, scene, f"{rows[0]['gt'][0]:.1f}..{rows[0]['gt'][1]:.1f}", f"0..{rows[0]['max_disp']}"]
            for mode in ("max", "both"):
                row = worst[mode][mode]
                cells += [f"{row['range'][0]}..{row['range'][1]} ({worst[mode]['task']})", f"{100 * row['all']:.2f}%",
                          f"{100 * row['visible']:.2f}%"]
                if row["all"] < COVERAGE_TARGET:
                    failures.append(f"coverage {mode}: {dataset} {scene} {worst[mode]['task']} covers "
                                    f"{100 * row['all']:.2f}% of its GT ({100 * row['visible']:.2f}% of the visible GT)")
            lines.append(markdown_row(cells))
    lines += ["", f"EPE (px, all GT pixels, mean of the tasks) with the dataset's range and with `--max-disp auto`; "
              f"ratio = auto / dataset range (target <= {1 + EPE_TOLERANCE:.2f}).", "",
              markdown_row(["dataset", "method", "EPE dataset range", "EPE auto", "ratio", "worst scene (ratio)"]),
              "|---|---|---:|---:|---:|---|"]
    for dataset in datasets:
        for method in methods:
            scenes = {scene: values for (name, scene), values in epe[dataset].items() if name == method}
            true, auto = (float(np.mean([values[i] for values in scenes.values()])) for i in (0, 1))
            worst = max(scenes, key=lambda scene: scenes[scene][1] / scenes[scene][0])
            ratio = scenes[worst][1] / scenes[worst][0]
            lines.append(markdown_row([dataset, method, f"{true:.3f}", f"{auto:.3f}", f"{auto / true:.3f}",
                                       f"{worst} ({ratio:.3f})"]))
            if auto / true > 1 + EPE_TOLERANCE:
                failures.append(f"EPE {dataset} {method}: {auto:.3f} px with auto against {true:.3f} px")
            for scene, (scene_true, scene_auto) in scenes.items():
                if scene_auto / scene_true > 1 + EPE_TOLERANCE:
                    failures.append(f"EPE {dataset} {scene} {method}: {scene_auto:.3f} px with auto against "
                                    f"{scene_true:.3f} px (ratio {scene_auto / scene_true:.3f})")
    lines += ["", "Where the targets are missed (coverage >= 99 % of all GT; EPE within 5 %):", ""]
    lines += [f"- {failure}" for failure in failures] or ["- nowhere"]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown is not None:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
