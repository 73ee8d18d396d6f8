#!/usr/bin/env python
"""How the matchers cope with an imperfect multispectral rig.

Benchmark pairs are rectified to a fraction of a pixel and their bands come from one
sensor; two cameras behind different filters are not. This script runs the benchmark
loop (:func:`cade_cli.evaluation.loop.run_benchmark`) on cross-spectral tasks of a
dataset with the RIGHT band degraded one way at a time (vertical offset, roll, blur,
noise, vignetting, contrast inversion: :mod:`cade_cli.evaluation.degradations` lists
them) and scores each matcher on all pixels with ground truth (EPE px / BMP3 %, each
map filled as `cade benchmark` fills it)::

    .venv/bin/python benchmarks/rig_imperfections.py --data-dir ../shared/data \\
        [--dataset middlebury14] [--tasks G>B,R>B] [--methods cade,census-sgm,sgbm] [--jobs 1] \\
        [--markdown docs/rig-imperfections.md] [--fix-vertical]

Each matcher runs with its ``auto`` preprocessing over [0, the dataset's max_disp]. The
degradations are deterministic (noise seed 0). With ``--fix-vertical`` every matcher runs
behind the rectification self-check (:class:`~cade_cli.evaluation.degradations.VerticallyCorrected`:
vertical offset and roll measured on sparse features and corrected before matching), as
``cade disparity --rig --fix-vertical`` does.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from cade_cli.errors import CadeError
from cade_cli.evaluation.degradations import DEGRADATIONS, VerticallyCorrected
from cade_cli.evaluation.loop import run_benchmark
from cade_cli.evaluation.report import markdown_row
from cade_cli.matching import MATCHERS


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="folder holding the dataset (or its parent)")
    parser.add_argument("--dataset", default="middlebury14", help="a `cade benchmark` dataset name")
    parser.add_argument("--tasks", default="G>B,R>B", help="left band > right band, comma-separated")
    parser.add_argument("--methods", default="cade,census-sgm,sgbm")
    parser.add_argument("--degradations", default=",".join(DEGRADATIONS), help="comma-separated, of the above")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes, one scene each")
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    parser.add_argument("--fix-vertical", action="store_true",
                        help="correct the measured vertical offset and roll of each pair before matching")
    args = parser.parse_args(argv)
    tasks, methods, degradations = (value.split(",") for value in (args.tasks, args.methods, args.degradations))
    matchers = {name: VerticallyCorrected(matcher) for name, matcher in MATCHERS.items()} if args.fix_vertical \
        else MATCHERS
    try:
        run = run_benchmark(dataset=args.dataset, data_dir=args.data_dir, methods=methods, protocols=["cs"],
                            preprocess=["auto"], tasks=tasks, degradations=degradations, jobs=args.jobs,
                            matchers=matchers, on_scene_done=lambda scene, _: print(f"{scene} done", file=sys.stderr, flush=True))
    except CadeError as error:
        raise SystemExit(str(error)) from None

    scores = {(row["degradation"], row["method"]): row["scores"] for row in run.summary(by=("degradation", "method"))}
    lines = ["# Matchers on an imperfect rig: the right band degraded one way at a time", "",
             f"command: `{shlex.join(['.venv/bin/python', 'benchmarks/rig_imperfections.py', *sys.argv[1:]])}`", "",
             f"{args.dataset}, {len(run.config['scenes'])} scenes, tasks {', '.join(tasks)}; the right band "
             "degraded; EPE px / BMP3 % over all pixels with ground truth, mean over scenes and tasks"
             + ("; every pair's vertical offset and roll measured and corrected before matching (--fix-vertical)."
                if args.fix_vertical else "."), "",
             markdown_row(["right band", *methods]), "|---|" + "---:|" * len(methods)]
    for degradation in degradations:
        cells = [f"{scores[degradation, m]['epe_all']:.2f} / {scores[degradation, m]['bad3_all']:.1f}"
                 for m in methods]
        lines.append(markdown_row([degradation, *cells]))
    seconds = {row["method"]: row["seconds_per_pair"] for row in run.summary(by=("method",))}
    lines += ["", "mean seconds per pair: " + ", ".join(f"{m} {seconds[m]:.2f}" for m in methods)]
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
