#!/usr/bin/env python
"""How the matchers cope with an imperfect multispectral rig.

Benchmark pairs are rectified to a fraction of a pixel and their bands come from one
sensor. Two cameras behind different filters are not: rectification leaves a vertical
offset or a slight roll, one band is softer (NIR focuses behind visible light) or
noisier, lenses vignette, and some materials reverse their contrast between bands
(vegetation is dark in red, bright in NIR). This script takes cross-spectral tasks of a
benchmark dataset, degrades the RIGHT band in one of those ways at a time, and scores
each matcher on all pixels with ground truth (EPE px / BMP3 %, invalid pixels filled as
`cade benchmark` fills them):

    none          the band as it is
    vshift-0.5    rows moved by 0.5 px (bilinear), a typical residual after calibration
    vshift-1      rows moved by 1 px
    roll-0.2      rotated by 0.2 degrees about the image centre
    blur-1.5      Gaussian blur, sigma 1.5 px
    noise-6       Gaussian noise, sigma 6/255 of the band's [0, 1] range
    vignette      brightness falling to 40 % in the corners
    invert-half   contrast inverted in the right half of the image only
    invert        contrast inverted everywhere

    .venv/bin/python benchmarks/rig_imperfections.py --data-dir ../shared/data \\
        [--dataset middlebury14] [--tasks G>B,R>B] [--methods cade,census-sgm,sgbm] \\
        [--markdown docs/rig-imperfections.md]

Each matcher runs with its ``auto`` preprocessing (``Matcher.best_preprocess``) over
[0, the dataset's max_disp]. The degradations are deterministic (noise seed 0).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from cade_cli.datasets import get_dataset
from cade_cli.metrics import score
from cade_cli.stereo import estimate_disparity

CHANNELS = {"R": 0, "G": 1, "B": 2}


def _vertical_shift(band: np.ndarray, rows: float) -> np.ndarray:
    """Content moves up by ``rows``: output row y shows input row y + rows."""
    height, width = band.shape
    shift = np.float32([[1, 0, 0], [0, 1, rows]])
    return cv2.warpAffine(band, shift, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def _roll(band: np.ndarray, degrees: float) -> np.ndarray:
    height, width = band.shape
    rotation = cv2.getRotationMatrix2D((width / 2, height / 2), degrees, 1.0)
    return cv2.warpAffine(band, rotation, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _vignette(band: np.ndarray) -> np.ndarray:
    height, width = band.shape
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    radius2 = ((x - width / 2) ** 2 + (y - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
    return band * (1 - 0.6 * radius2)


def _invert_right_half(band: np.ndarray) -> np.ndarray:
    right_half = np.arange(band.shape[1])[None, :] >= band.shape[1] // 2
    return np.where(right_half, 1 - band, band)


DEGRADATIONS = {
    "none": lambda band: band,
    "vshift-0.5": lambda band: _vertical_shift(band, 0.5),
    "vshift-1": lambda band: _vertical_shift(band, 1.0),
    "roll-0.2": lambda band: _roll(band, 0.2),
    "blur-1.5": lambda band: cv2.GaussianBlur(band, (0, 0), 1.5),
    "noise-6": lambda band: band + np.random.default_rng(0).normal(0, 6 / 255, band.shape).astype(np.float32),
    "vignette": _vignette,
    "invert-half": _invert_right_half,
    "invert": lambda band: 1 - band,
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="folder holding the dataset (or its parent)")
    parser.add_argument("--dataset", default="middlebury14", help="a `cade benchmark` dataset name")
    parser.add_argument("--tasks", default="G>B,R>B", help="left band > right band, comma-separated")
    parser.add_argument("--methods", default="cade,census-sgm,sgbm")
    parser.add_argument("--degradations", default=",".join(DEGRADATIONS), help="comma-separated, of the above")
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    tasks = [tuple(task.split(">")) for task in args.tasks.split(",")]
    methods, degradations = args.methods.split(","), args.degradations.split(",")
    unknown = [name for name in degradations if name not in DEGRADATIONS] + [
        band for task in tasks for band in task if band not in CHANNELS]
    if unknown or any(len(task) != 2 for task in tasks):
        raise SystemExit(f"unknown degradation or task: {', '.join(unknown) or args.tasks}")

    scenes = list(get_dataset(args.dataset)(args.data_dir))
    epe = {(d, m): [] for d in degradations for m in methods}
    bmp3 = {(d, m): [] for d in degradations for m in methods}
    seconds = {m: 0.0 for m in methods}
    for scene in scenes:
        print(f"{scene.name} ...", file=sys.stderr, flush=True)
        for left_band, right_band in tasks:
            left = scene.left[..., CHANNELS[left_band]]
            for degradation in degradations:
                right = DEGRADATIONS[degradation](scene.right[..., CHANNELS[right_band]]).astype(np.float32)
                for method in methods:
                    started = time.perf_counter()
                    result = estimate_disparity(left, right, method=method, max_disp=scene.max_disp,
                                                preprocess="auto")
                    seconds[method] += time.perf_counter() - started
                    metrics = score(result.disparity, scene.disparity, nonocc=scene.nonocc, pred_valid=result.valid)
                    epe[degradation, method].append(metrics["epe_all"])
                    bmp3[degradation, method].append(metrics["bad3_all"])

    lines = ["# Matchers on an imperfect rig: the right band degraded one way at a time", "",
             f"command: `{shlex.join(['.venv/bin/python', 'benchmarks/rig_imperfections.py', *sys.argv[1:]])}`", "",
             f"{args.dataset}, {len(scenes)} scenes, tasks {', '.join('>'.join(t) for t in tasks)}; the right band "
             "degraded; EPE px / BMP3 % over all pixels with ground truth, mean over scenes and tasks.", "",
             "| right band | " + " | ".join(methods) + " |", "|---|" + "---:|" * len(methods)]
    for degradation in degradations:
        cells = [f"{np.mean(epe[degradation, m]):.2f} / {np.mean(bmp3[degradation, m]):.1f}" for m in methods]
        lines.append(f"| {degradation} | " + " | ".join(cells) + " |")
    runs = len(scenes) * len(tasks) * len(degradations)
    lines += ["", "mean seconds per pair: " + ", ".join(f"{m} {seconds[m] / runs:.2f}" for m in methods)]
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
