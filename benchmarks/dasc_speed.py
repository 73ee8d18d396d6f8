#!/usr/bin/env python
"""Speed of the DASC cost volume: the BLAS band products of
:func:`cade_cli.matching.dasc.dasc_descriptor_cost` against the per-disparity ``einsum``
they replaced (:func:`cade_cli.matching.reference.dasc_descriptor_cost_reference`).

On a seeded random texture pair per case (``HxW:min:max``), with the ``dasc-sgm``
matcher's pattern (:data:`~cade_cli.matching.dasc.DASC_STEREO_PATTERN`), prints a Markdown
table: seconds for the two descriptors, for the volume from them (old, new), for the
whole :func:`~cade_cli.matching.dasc.dasc_cost` (descriptors + volume) and for the whole
``dasc-sgm`` matcher (cost, SGM, checks) with either volume, each the best of
``--repeat`` runs, and the largest |old - new| of the volumes. Set the thread count
through the environment (``OMP_NUM_THREADS=2``); run it on an otherwise idle machine.

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/dasc_speed.py --cases 240x720:0:399,496x744:0:127
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import replace

import cv2
import numpy as np

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.classical import dasc_sgm
from cade_cli.matching.cost import CostVolume
from cade_cli.matching.dasc import DASC_STEREO_PATTERN, dasc_descriptor, dasc_descriptor_cost
from cade_cli.matching.reference import dasc_descriptor_cost_reference


def best_seconds(run: Callable[[], object], repeat: int) -> tuple[float, object]:
    """Fastest of ``repeat`` calls of ``run``, s, and the last call's result."""
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - started)
    return min(times), result


def texture_pair(shape: tuple[int, int], shift: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A blurred random texture and the same texture ``shift`` px to the right, at another gain."""
    height, width = shape
    wide = cv2.GaussianBlur(rng.random((height, width + shift), dtype=np.float32), (0, 0), 1.5)
    return wide[:, shift:], 0.2 + 0.6 * wide[:, :width]


def einsum_dasc_cost(left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange) -> CostVolume:
    """The ``dasc-sgm`` matcher's cost as it was: the same descriptors, the per-disparity einsum."""
    left_descriptor, right_descriptor = (dasc_descriptor(band, pattern=DASC_STEREO_PATTERN) for band in (left, right))
    return CostVolume(dasc_descriptor_cost_reference(left_descriptor, right_descriptor, disparity_range),
                      disparity_range)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default="240x720:0:399,496x744:0:127",
                        help="comma-separated HxW:min:max (default: a 24 MP tile window and a Middlebury-Q size)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per measurement, the best is kept")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    lines = [f"`{shlex.join(['benchmarks/dasc_speed.py', *sys.argv[1:]])}`, "
             f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, {os.cpu_count()} CPUs "
             f"({platform.processor() or platform.machine()}), best of {args.repeat}", "",
             "| HxW | range | descriptors s | volume old s | volume new s | speedup | dasc_cost old s | "
             "dasc_cost new s | speedup | dasc-sgm old s | dasc-sgm new s | speedup | max abs diff |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    einsum_dasc_sgm = replace(dasc_sgm, cost=einsum_dasc_cost)
    for case in args.cases.split(","):
        size, low, high = case.split(":")
        height, width = (int(value) for value in size.lower().split("x"))
        disparity_range = DisparityRange(int(low), int(high))
        left, right = texture_pair((height, width), max(disparity_range.minimum, 0) + 7, rng)
        describe, descriptors = best_seconds(
            lambda: [dasc_descriptor(band, pattern=DASC_STEREO_PATTERN) for band in (left, right)], args.repeat)
        old, old_volume = best_seconds(lambda: dasc_descriptor_cost_reference(*descriptors, disparity_range),
                                       args.repeat)
        new, new_volume = best_seconds(lambda: dasc_descriptor_cost(*descriptors, disparity_range), args.repeat)
        difference = float(np.abs(old_volume - new_volume).max())
        del old_volume, new_volume
        matcher_old, _ = best_seconds(lambda: einsum_dasc_sgm(left, right, disparity_range), args.repeat)
        matcher_new, _ = best_seconds(lambda: dasc_sgm(left, right, disparity_range), args.repeat)
        lines.append(f"| {height}x{width} | {low}..{high} | {describe:.3f} | {old:.3f} | {new:.3f} | "
                     f"{old / new:.1f}x | {describe + old:.3f} | {describe + new:.3f} | "
                     f"{(describe + old) / (describe + new):.1f}x | {matcher_old:.3f} | {matcher_new:.3f} | "
                     f"{matcher_old / matcher_new:.1f}x | {difference:.1e} |")
        print(f"{case} done", file=sys.stderr, flush=True)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
