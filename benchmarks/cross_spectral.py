#!/usr/bin/env python
"""Cross-spectral accuracy of the classical matchers, with and without the CADE transform.

The benchmark loop (:func:`cade_cli.evaluation.loop.run_benchmark`) on Middlebury 2005
(ThirdSize) and Middlebury 2014 (MiddEval3 Q), protocol ``cs`` restricted to a few
tasks (``R>B`` = left red against right blue). Scores are over all pixels with ground
truth, each map filled as ``cade benchmark`` fills it (EPE in px, BMP3 = % with error
> 3 px), averaged over tasks and scenes. Search range: [0, the scene's max_disp]
(ndisp - 1 from calib.txt for 2014; from the GT for 2005, :func:`cade_cli.data.max_disp_from_gt`).

    .venv/bin/python benchmarks/cross_spectral.py --data-dir ../shared/data \\
        [--tasks R>B,B>R] [--methods sgbm,census-sgm,zncc-sgm] [--jobs 1] [--markdown FILE]

`cade benchmark` runs the full protocol (all six tasks, nonocc masks); this script backs
the figures quoted for the core toolkit.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from cade_cli.errors import CadeError
from cade_cli.evaluation.loop import run_benchmark
from cade_cli.evaluation.report import markdown_row

DATASETS = {"middlebury2005-third": "middlebury05", "middlebury2014-Q": "middlebury14"}
"""Column label -> dataset name."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--tasks", default="R>B,B>R")
    parser.add_argument("--methods", default="sgbm,census-sgm,zncc-sgm")
    parser.add_argument("--preprocess", default="none,cade")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes, one scene each")
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    tasks, methods, preprocessing = (value.split(",") for value in (args.tasks, args.methods, args.preprocess))
    try:
        runs = {label: run_benchmark(dataset=name, data_dir=args.data_dir, methods=methods, protocols=["cs"],
                                     preprocess=preprocessing, tasks=tasks, jobs=args.jobs)
                for label, name in DATASETS.items()}
    except CadeError as error:
        raise SystemExit(str(error)) from None

    scenes = ", ".join(f"{len(run.config['scenes'])} scenes of {label}" for label, run in runs.items())
    lines = ["# Cross-spectral accuracy of the classical matchers", "",
             f"Produced by `{shlex.join(['.venv/bin/python', 'benchmarks/cross_spectral.py', *sys.argv[1:]])}`.",
             f"Tasks {', '.join(tasks)} (left band > right band), EPE in px and BMP3 (% of pixels off by more than "
             f"3 px) over all pixels with ground truth, averaged over tasks and scenes: {scenes}; search "
             "[0, max_disp] per scene (2014: ndisp - 1; 2005: from the GT).", "",
             markdown_row(["method", "preprocess", *(f"{label} {metric}" for label in DATASETS
                                                     for metric in ("EPE", "BMP3")), "s/pair"]),
             "|---|---|" + "---:|---:|" * len(DATASETS) + "---:|"]
    for method in methods:
        for preprocess in preprocessing:
            cells, records = [], []
            for run in runs.values():
                row = next(r for r in run.summary() if (r["method"], r["preprocess"]) == (method, preprocess))
                cells += [f"{row['scores']['epe_all']:.2f}", f"{row['scores']['bad3_all']:.1f}"]
                records += [r for r in run.records if (r.method, r.preprocess) == (method, preprocess)]
            seconds = sum(r.seconds for r in records) / sum(r.matcher_runs for r in records)
            lines.append(markdown_row([method, preprocess, *cells, f"{seconds:.2f}"]))
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
