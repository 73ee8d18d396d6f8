#!/usr/bin/env python
"""Where a `cade` pair's time goes inside the matcher as it runs: the network, the refinement's
parts (rank transforms, contrast-inversion check, SGBM), the chooser, visibility and confidence.

Unlike benchmarks/cade_stages.py, which times each stage alone, this runs the whole matcher
(:class:`cade_cli.matching.learned.LearnedPipeline` with the card's chooser and refinement) on
Middlebury 2014 pairs (protocol ``native``, range [0, ndisp - 1]) and times each part where the
pipeline calls it (``time.perf_counter`` around the call: wall time; parts that run side by side on
two threads, ``cade_cli.matching.side_by_side``, add both threads' times, so a row can exceed its
share of the pair). One untimed run per pair, then ``--repeat`` timed ones; mean seconds a pair.

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/pipeline_profile.py \\
        --data-dir ../shared/data/middlebury2014/trainingQ --model cade-v13 --threads 2
"""

from __future__ import annotations

import argparse
import collections
import functools
import sys
import time
from pathlib import Path

PARTS = (  # (module, attribute, label): the calls timed, in pipeline order
    ("cade_cli.matching.network", "NetworkStage.estimate", "network (with the bands' transforms)"),
    ("cade_cli.matching.learned", "visible_in_right_view", "visibility"),
    ("cade_cli.matching.refinement", "rank_transform", "rank transforms (both bands)"),
    ("cade_cli.matching.refinement", "inverted_regions", "contrast-inversion check"),
    ("cade_cli.matching.refinement", "SGBM.compute", "SGBM of the ranks"),
    ("cade_cli.matching.chooser", "chooser_features", "chooser features"),
    ("cade_cli.matching.chooser", "Chooser.probability", "chooser perceptron"),
    ("cade_cli.matching.chooser_net", "chooser_planes", "chooser planes (the network chooser's input)"),
    ("cade_cli.matching.chooser_net", "ChooserNet.probability", "chooser network"),
    ("cade_cli.matching.learned", "network_confidence", "confidence"),
)


def timed(function, label: str, totals: dict):
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            totals[label] += time.perf_counter() - start
    return wrapper


def instrument(totals: dict) -> None:
    """Wrap every part of :data:`PARTS` where the pipeline looks it up."""
    import importlib

    for module_name, attribute, label in PARTS:
        module = importlib.import_module(module_name)
        if attribute == "SGBM.compute":  # OpenCV's matcher object: wrap the builder's product
            build = module.sgbm_matcher

            class Timed:
                def __init__(self, matcher, label=label):
                    self.matcher, self.label = matcher, label

                def getNumDisparities(self):  # noqa: N802 (OpenCV's name)
                    return self.matcher.getNumDisparities()

                def compute(self, left, right):
                    return timed(self.matcher.compute, self.label, totals)(left, right)

            module.sgbm_matcher = lambda *args, _build=build, **kwargs: Timed(_build(*args, **kwargs))
        elif "." in attribute:
            owner_name, method = attribute.split(".")
            owner = getattr(module, owner_name)
            setattr(owner, method, timed(getattr(owner, method), label, totals))
        else:
            setattr(module, attribute, timed(getattr(module, attribute), label, totals))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="Middlebury 2014 folder (e.g. its trainingQ)")
    parser.add_argument("--model", default=None, help="a card name or path, as `cade --model` takes")
    parser.add_argument("--threads", type=int, default=2, help="OpenCV's threads (set OMP_NUM_THREADS alike)")
    parser.add_argument("--repeat", type=int, default=2, help="timed runs per pair")
    args = parser.parse_args(argv)
    import cv2

    from cade_cli.allocator import retain_freed_memory
    from cade_cli.data import get_dataset
    from cade_cli.evaluation.protocols import get_protocol
    from cade_cli.matching.base import DisparityRange
    from cade_cli.matching.learned import LearnedPipeline
    from cade_cli.matching.network import NetworkStage
    from cade_cli.model_card import DEFAULT_MODEL

    retain_freed_memory()  # as the cade command does
    cv2.setNumThreads(args.threads)
    totals: dict[str, float] = collections.defaultdict(float)
    instrument(totals)
    pipeline = LearnedPipeline(network=NetworkStage(args.model or DEFAULT_MODEL))
    whole, pairs = 0.0, 0
    for scene in get_dataset("middlebury14")(args.data_dir):
        left, right = get_protocol("native").tasks[0].bands(scene.left, scene.right)
        disparity_range = DisparityRange(0, scene.max_disp)
        before = dict(totals)
        pipeline(left, right, disparity_range)  # untimed: sessions, allocations
        totals.clear()
        totals.update(before)
        for _ in range(args.repeat):
            start = time.perf_counter()
            pipeline(left, right, disparity_range)
            whole += time.perf_counter() - start
            pairs += 1
    print(f"# `cade` pipeline profile: {args.model or DEFAULT_MODEL}, {pairs // args.repeat} pairs x {args.repeat} runs, "
          f"{args.threads} threads\n\n| part | s / pair | share of the pair |\n|---|---:|---:|")
    for _, _, label in PARTS:
        print(f"| {label} | {totals[label] / pairs:.4f} | {totals[label] / whole * 100:.0f} % |")
    print(f"| **the whole pair** | {whole / pairs:.4f} | 100 % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
