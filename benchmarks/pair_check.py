#!/usr/bin/env python
"""The pair check (:mod:`cade_cli.pair_check`): its false alarms, what it catches, and its cost.

For every scene of each dataset found under ``--data-dir`` and each task (the grey pair
and cross-spectral band pairs, by default ``grey,R>B,B>R``):

* false alarms: the rectified pair, in order, checked against the dataset's range
  [0, max_disp]: any problem reported is a false alarm (target: none);
* faults it should catch, each made from the same pair: the right band shifted down 3 and
  6 px (:func:`cade_cli.evaluation.degradations.vertical_shift`), rotated 1 and 2 degrees
  (:func:`~cade_cli.evaluation.degradations.roll`), LEFT and RIGHT swapped, and ranges
  that miss the scene: below it, [0, d5 / 2] (d5: the 5th percentile of the GT
  disparities), and above it, [dmax + 8, dmax + 8 + max_disp]; for the shifts, the error
  of the measured offset (px);
* cost (Middlebury 2014 Q, grey pair): seconds of :func:`cade_cli.pair_check.check_pair`
  against the ``sgbm`` matcher, the fastest (``preprocess="auto"``, range [0, max_disp], as
  ``cade disparity -m sgbm`` runs it), on each thread count of ``--threads``: the two calls
  alternate (check, sgbm, check, ...), so that a change of the machine's load hits both,
  and each keeps the median of ``--repeat`` runs.

The default datasets are every Middlebury, KITTI and FlyingThings3D set the readers know,
``middeval3`` included (the real Middlebury 2001/2003/2006 scenes of ``train-real``, read
for false alarms and faults only); a set absent from ``--data-dir`` is named in the report.

    .venv/bin/python benchmarks/pair_check.py --data-dir ../shared/data \\
        [--datasets middlebury05,middlebury06,middlebury14,middeval3,kitti2012,kitti2015,flyingthings3d] \\
        [--tasks grey,R>B,B>R] [--repeat 7] [--threads 1,2] [--markdown docs/pair-check.md]
"""

from __future__ import annotations

import argparse
import gc
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from cade_cli.data import get_dataset
from cade_cli.errors import CadeError
from cade_cli.evaluation.degradations import roll, vertical_shift
from cade_cli.evaluation.protocols import get_protocol
from cade_cli.evaluation.report import markdown_row
from cade_cli.evaluation.timing import use_threads
from cade_cli.pair_check import RANGE_MISS_SHARE, SWAPPED_SHARE, VERTICAL_TOLERANCE_PX, check_pair
from cade_cli.stereo import estimate_disparity

DATASETS = ("middlebury05", "middlebury06", "middlebury14", "middeval3", "kitti2012", "kitti2015", "flyingthings3d")
TIMED_DATASET = "middlebury14"
COST_TARGET = 0.10
"""The check must cost less than this share of sgbm's time."""
FAULTS = ("vshift-3", "vshift-6", "roll-1", "roll-2", "swapped", "range-below", "range-above")
EXPECTED = {"vshift-3": "vertical", "vshift-6": "vertical", "roll-1": "vertical", "roll-2": "vertical",
            "swapped": "swapped", "range-below": "range", "range-above": "range"}
"""The problem each fault must raise."""


def task_named(name: str):
    """The protocol task called ``name`` (``grey`` or a band pair such as ``R>B``)."""
    for protocol in ("native", "cs", "rgb"):
        for task in get_protocol(protocol).tasks:
            if task.name == name:
                return task
    raise CadeError(f"unknown task {name!r}; use grey or a band pair such as R>B")


def faulted(fault: str, left: np.ndarray, right: np.ndarray, gt: np.ndarray, max_disp: int):
    """(left, right, min_disp, max_disp, true vertical offset px or None) of a pair given ``fault``."""
    if fault.startswith("vshift-"):
        rows = float(fault.split("-")[1])
        return left, vertical_shift(right, -rows), 0, max_disp, rows  # content moves down: dy = +rows
    if fault.startswith("roll-"):
        return left, roll(right, float(fault.split("-")[1])), 0, max_disp, None
    if fault == "swapped":
        return right, left, 0, max_disp, None
    known = gt[np.isfinite(gt)]
    if fault == "range-below":
        return left, right, 0, max(1, int(np.percentile(known, 5) / 2)), None
    if fault == "range-above":
        low = int(np.ceil(known.max())) + 8
        return left, right, low, low + max_disp, None
    raise ValueError(f"unknown fault {fault!r}")


def interleaved_medians(calls, *, repeat: int) -> list[float]:
    """Median seconds of each of ``calls`` over ``repeat`` rounds that run them in turn (after
    one untimed round), so that a change of the machine's load hits them alike."""
    for call in calls:
        call()
    seconds: list[list[float]] = [[] for _ in calls]
    for _ in range(repeat):
        for call, times in zip(calls, seconds):
            gc.collect()
            start = time.perf_counter()
            call()
            times.append(time.perf_counter() - start)
    return [float(np.median(times)) for times in seconds]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--tasks", default="grey,R>B,B>R")
    parser.add_argument("--repeat", type=int, default=7, help="timed runs per scene and thread count (median)")
    parser.add_argument("--threads", default="1,2", help="thread counts the cost is measured on, e.g. 1,2")
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    thread_counts = [int(count) for count in args.threads.split(",")]
    use_threads(thread_counts[0])
    tasks = [task_named(name) for name in args.tasks.split(",")]
    pairs = alarms = 0
    pairs_of: dict[str, int] = {}
    alarm_lines: list[str] = []
    missing: list[str] = []
    caught = {(fault, kind): [0, 0] for fault in FAULTS for kind in ("grey", "cross-band")}
    offset_errors: list[float] = []
    worst_clean = {"vertical_worst": 0.0, "negative_share": 0.0, "outside_share": 0.0}
    timing_rows: dict[int, list[list[str]]] = {count: [] for count in thread_counts}
    ratios: dict[int, list[float]] = {count: [] for count in thread_counts}
    for name in args.datasets.split(","):
        try:
            scenes = list(get_dataset(name).scene_names(args.data_dir))
        except CadeError:
            missing.append(name)
            continue
        for scene in get_dataset(name)(args.data_dir, scenes=scenes):
            for task in tasks:
                left, right = task.bands(scene.left, scene.right)
                clean = check_pair(left, right, min_disp=0, max_disp=scene.max_disp)
                pairs += 1
                pairs_of[name] = pairs_of.get(name, 0) + 1
                if clean.conclusive:
                    for key in worst_clean:
                        worst_clean[key] = max(worst_clean[key], getattr(clean, key))
                if clean.problems:
                    alarms += 1
                    alarm_lines.append(f"- {name} {scene.name} {task.name}: {clean.describe()}")
                for fault in FAULTS:
                    *pair, low, high, true_offset = faulted(fault, left, right, scene.disparity, scene.max_disp)
                    found = check_pair(*pair, min_disp=low, max_disp=high)
                    kind = "grey" if task.grey else "cross-band"
                    caught[fault, kind][0] += EXPECTED[fault] in found.problems
                    caught[fault, kind][1] += 1
                    if true_offset is not None and found.conclusive:
                        offset_errors.append(abs(found.vertical_offset - true_offset))
            if name == TIMED_DATASET:
                left, right = task_named("grey").bands(scene.left, scene.right)
                for count in thread_counts:
                    use_threads(count)
                    check, sgbm = interleaved_medians(
                        (lambda: check_pair(left, right, max_disp=scene.max_disp),
                         lambda: estimate_disparity(left, right, method="sgbm", max_disp=scene.max_disp)),
                        repeat=args.repeat)
                    ratios[count].append(check / sgbm)
                    timing_rows[count].append([scene.name, f"{left.shape[1]}x{left.shape[0]}",
                                               f"0..{scene.max_disp}", f"{1000 * check:.2f}", f"{1000 * sgbm:.1f}",
                                               f"{100 * check / sgbm:.1f}%"])
            print(f"{name} {scene.name}: done", file=sys.stderr)

    command = shlex.join([".venv/bin/python", "benchmarks/pair_check.py", *(argv if argv is not None else sys.argv[1:])])
    lines = ["# Pair check: false alarms, faults caught, cost", "",
             f"Produced by `{command}`.", "",
             f"Tasks {', '.join(task.name for task in tasks)} of every scene of the datasets found"
             + (f" ({', '.join(missing)}: not in the data folder)" if missing else "") + ".", "",
             "## False alarms on rectified pairs", "",
             f"**{alarms} of {pairs}** rectified pairs (searched over the dataset's range [0, max_disp]) got a "
             f"warning ({', '.join(f'{name} {count}' for name, count in pairs_of.items())}). Largest values measured on them: vertical misalignment "
             f"{worst_clean['vertical_worst']:.2f} px (warned from {VERTICAL_TOLERANCE_PX} px), share of negative "
             f"disparities {100 * worst_clean['negative_share']:.1f}% (swapped above {100 * SWAPPED_SHARE:.0f}%), "
             f"share outside the range {100 * worst_clean['outside_share']:.1f}% (warned above "
             f"{100 * RANGE_MISS_SHARE:.0f}%).", ""]
    lines += alarm_lines + ([""] if alarm_lines else [])
    lines += ["## Faults caught", "",
              "Each rectified pair above, made faulty one way at a time: the right band shifted down 3 or 6 px, "
              "rotated 1 or 2 degrees about the centre, LEFT and RIGHT swapped, or searched below the scene, "
              "[0, d5 / 2] (d5: the 5th percentile of the GT disparities), or above it, [dmax + 8, dmax + 8 + "
              "max_disp]. A miss is nearly always an inconclusive check: too few matches between the bands.", "",
              markdown_row(["fault", "reported as", "caught, grey pair", "caught, cross-band"]),
              "|---|---|---:|---:|"]
    for fault in FAULTS:
        cells = [f"{hit}/{total} ({100 * hit / max(total, 1):.0f}%)"
                 for hit, total in (caught[fault, kind] for kind in ("grey", "cross-band"))]
        lines.append(markdown_row([fault, EXPECTED[fault], *cells]))
    if offset_errors:
        lines += ["", f"Measured vertical offset of the shifted pairs: error median {np.median(offset_errors):.2f} "
                  f"px, worst {max(offset_errors):.2f} px ({len(offset_errors)} measurements)."]
    for count in thread_counts:
        if not ratios[count]:
            continue
        lines += ["", f"## Cost ({TIMED_DATASET}, grey pair, {count} thread(s), median of {args.repeat}, "
                  "check and sgbm alternating)", "",
                  markdown_row(["scene", "size", "range", "check ms", "sgbm ms", "check / sgbm"]),
                  "|---|---|---|---:|---:|---:|", *(markdown_row(row) for row in timing_rows[count]), "",
                  f"Mean {100 * float(np.mean(ratios[count])):.1f}%, worst {100 * max(ratios[count]):.1f}% of "
                  f"sgbm's time (target < {100 * COST_TARGET:.0f}% on every pair)."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown is not None:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
