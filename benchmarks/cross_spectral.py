#!/usr/bin/env python
"""Cross-spectral accuracy of the classical matchers, with and without the CADE transform.

Each RGB stereo pair of Middlebury 2005 (ThirdSize) and Middlebury 2014 (MiddEval3 Q)
is split into channels; a task matches one channel of the left view against another
channel of the right view (``R>B`` = left red against right blue). Scores are over all
pixels with ground truth (EPE in px, BMP3 = % with error > 3 px) and averaged over
tasks and scenes. Search range: [0, ndisp - 1] from calib.txt for 2014; [0, 80] for
2005 ThirdSize (its largest GT disparity is about 77 px).

    .venv/bin/python benchmarks/cross_spectral.py --data-dir ../shared/data \
        [--tasks R>B,B>R] [--methods sgbm,census-sgm,zncc-sgm]

`cade benchmark` (the full protocol, all six tasks, nonocc masks) supersedes this
script once it exists; this one backs the figures quoted for the core toolkit.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from cade_cli.datasets import get_dataset
from cade_cli.matching import MATCHERS

CHANNELS = {"R": 0, "G": 1, "B": 2}

# Dataset reader -> search bound: Middlebury 2005 ships no ndisp, so a fixed 80 px
# covers ThirdSize (largest GT about 77 px); Middlebury 2014 uses ndisp - 1 (the reader's).
DATASETS = {"middlebury2005-third": ("middlebury05", 80), "middlebury2014-Q": ("middlebury14", None)}


def load(data_dir: Path, reader_name: str, max_disp: int | None):
    for scene in get_dataset(reader_name)(data_dir):
        yield scene.name, scene.left, scene.right, scene.disparity, max_disp or scene.max_disp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--tasks", default="R>B,B>R")
    parser.add_argument("--methods", default="sgbm,census-sgm,zncc-sgm")
    parser.add_argument("--preprocess", default="none,cade")
    args = parser.parse_args()
    tasks = [tuple(task.split(">")) for task in args.tasks.split(",")]
    methods, preprocessing = args.methods.split(","), args.preprocess.split(",")

    print(f"command: {shlex.join(sys.argv)}\n")
    print("| method | preprocess | " + " | ".join(f"{name} EPE | {name} BMP3" for name in DATASETS) + " | s/pair |")
    print("|---|---|" + "---:|---:|" * len(DATASETS) + "---:|")
    pairs = {name: list(load(args.data_dir, *spec)) for name, spec in DATASETS.items()}
    for method in methods:
        for preprocess in preprocessing:
            cells, seconds, runs = [], 0.0, 0
            for scenes in pairs.values():
                epe, bmp3 = [], []
                for _, left, right, gt, max_disp in scenes:
                    for left_band, right_band in tasks:
                        started = time.perf_counter()
                        result = MATCHERS[method](
                            left[..., CHANNELS[left_band]], right[..., CHANNELS[right_band]],
                            max_disp=max_disp, preprocess=preprocess,
                        )
                        seconds += time.perf_counter() - started
                        runs += 1
                        error = np.abs(result.disparity - gt)[np.isfinite(gt)]
                        epe.append(error.mean())
                        bmp3.append(100.0 * (error > 3).mean())
                cells += [f"{np.mean(epe):.2f}", f"{np.mean(bmp3):.1f}"]
            print(f"| {method} | {preprocess} | " + " | ".join(cells) + f" | {seconds / runs:.2f} |", flush=True)
    print(f"\ntasks: {', '.join('>'.join(t) for t in tasks)}; pixels: all with ground truth")


if __name__ == "__main__":
    main()
