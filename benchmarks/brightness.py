"""Gross errors of learned matchers by how bright the scene is where they fall.

For every scene and cross-spectral task (``cs`` protocol, optionally a subset) each model
runs through the ``cade`` matcher (``cade_cli.matching.get_matcher("cade", model=...)``,
the chooser and fill included, as ``cade benchmark`` runs it). Each pixel with ground truth
is put in a brightness class by the left band's local mean (a 15 x 15 box mean of the raw
band, as a share of the band's 99th percentile); the table gives each class's BMP3 (error
> 3 px) per model, pooled over scenes and tasks, and its share of the scored pixels.

Accuracy III used it to find where the later checkpoints lose on KITTI 2012 (shade on the
road: models/README.md, sessions 23 and 24).

Usage:
    .venv/bin/python benchmarks/brightness.py --data-dir ../shared/data --dataset kitti2012 \\
        --models cade-v13,cade-v13-accurate [--tasks R>B] [--edges 0,0.1,0.2,0.4] [--markdown FILE]
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from cade_cli.data import Scene, get_dataset
from cade_cli.evaluation.loop import map_scenes
from cade_cli.evaluation.protocols import Protocol, get_protocol
from cade_cli.matching import densify, get_matcher

BAD = 3.0
BOX = 15


def brightness(band: np.ndarray) -> np.ndarray:
    """Local mean of ``band`` (15 x 15 box) as a share of its 99th percentile."""
    scale = max(float(np.percentile(band, 99)), 1e-6)
    return cv2.blur(band.astype(np.float32), (BOX, BOX)) / scale


def count_scene(scene: Scene, *, models: tuple[str, ...], protocol: Protocol, edges: tuple[float, ...]) -> np.ndarray:
    """(model, class, [bad, scored]) pixel counts of one scene over ``protocol``'s tasks."""
    counts = np.zeros((len(models), len(edges), 2), np.int64)
    known = np.isfinite(scene.disparity)
    bounds = (*edges, np.inf)
    matchers = [get_matcher("cade", model=model) for model in models]
    for task in protocol.tasks:
        left, right = task.bands(scene.left, scene.right)
        level = brightness(left)
        classes = [known & (lo <= level) & (level < hi) for lo, hi in zip(bounds, bounds[1:])]
        for m, matcher in enumerate(matchers):
            result = matcher(left, right, max_disp=scene.max_disp, min_disp=0)
            bad = np.abs(densify(result.disparity, result.valid) - scene.disparity) > BAD
            for k, pixels in enumerate(classes):
                counts[m, k] = (np.count_nonzero(bad & pixels), np.count_nonzero(pixels))
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--dataset", default="kitti2012")
    parser.add_argument("--models", default="cade-v13", help="Comma-separated model cards (names or paths).")
    parser.add_argument("--tasks", default=None, help="Comma-separated CS tasks (default: all six).")
    parser.add_argument("--edges", default="0,0.1,0.2,0.4",
                        help="Lower bounds of the brightness classes (share of the band's 99th percentile).")
    parser.add_argument("--markdown", type=Path, default=None)
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args()
    models = tuple(args.models.split(","))
    edges = tuple(float(edge) for edge in args.edges.split(","))
    protocol = get_protocol("cs").select(args.tasks.split(",") if args.tasks else None)
    reader = get_dataset(args.dataset)
    count = partial(count_scene, models=models, protocol=protocol, edges=edges)
    total = sum(counts for _, counts in map_scenes(count, reader, args.data_dir, reader.scene_names(args.data_dir),
                                                    jobs=args.jobs))
    bounds = [*(f"{edge:g}" for edge in edges), "∞"]
    names = [f"[{lo}, {hi})" for lo, hi in zip(bounds, bounds[1:])]
    scored = total[0, :, 1]
    lines = [f"# BMP3 by brightness ({args.dataset}, CS tasks {', '.join(t.name for t in protocol.tasks)}, "
             "all pixels with GT)", "",
             "`.venv/bin/python benchmarks/brightness.py --data-dir DATA --dataset "
             f"{args.dataset} --models {args.models}" + (f" --tasks {args.tasks}" if args.tasks else "")
             + f" --edges {args.edges}`", "",
             "Classes: the left band's 15 x 15 box mean as a share of its 99th percentile.", "",
             "| model | " + " | ".join(names) + " | all |", "|---" * (len(names) + 2) + "|",
             "| share of pixels | " + " | ".join(f"{100 * n / max(scored.sum(), 1):.1f} %" for n in scored) + " | |"]
    for model, counts in zip(models, total):
        rates = [100 * bad / max(n, 1) for bad, n in counts]
        overall = 100 * counts[:, 0].sum() / max(counts[:, 1].sum(), 1)
        lines.append(f"| {model} | " + " | ".join(f"{rate:.1f}" for rate in rates) + f" | {overall:.1f} |")
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)


if __name__ == "__main__":
    main()
