#!/usr/bin/env python
"""Whether onnxruntime's session options change the `cade` pipeline's time: the whole matcher on
Middlebury 2014 pairs, with the network run by sessions built with different options, taken in turn.

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/session_options.py \\
        --data-dir ../shared/data/middlebury2014/trainingQ --model cade-v11 \\
        --options 0,0,1 1,0,1 0,1,0 1,1,0 1,1,1

Each ``--options`` entry is ``SPIN,ARENA,PATTERN`` (1 on, 0 off): threads that busy-wait between a
run's nodes (they stop when a run returns either way: ``session.force_spinning_stop``), the CPU
memory arena, the memory pattern. The first entry is the baseline. Every session is built once;
on each pair each one runs once untimed, then ``--repeat`` timed rounds run the pair once with each
session, in alternating order, so a slow spell of a shared machine falls on all of them. Printed:
the mean seconds a pair, and the median over the timed runs of each one's time over the
baseline's in the same round. Pause training runs meanwhile.

The options that the shipped sessions use are :func:`cade_cli.matching.network.onnx_session`'s
(spinning off, no arena, the pattern on: the entry ``0,0,1``). Run alone (the network, nothing
else between runs) the arena and spinning looked faster; this measures them inside the matcher
instead (models/README.md, "Session 27").
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path


def build_session(path: Path, spin: str, arena: str, pattern: str, threads: int):
    import onnxruntime as ort

    from cade_cli.matching import network

    options = ort.SessionOptions()
    options.log_severity_level = 3
    options.intra_op_num_threads = threads
    options.add_session_config_entry(network.ALLOW_SPINNING, spin)
    options.add_session_config_entry("session.force_spinning_stop", "1")
    options.enable_cpu_mem_arena = arena == "1"
    options.enable_mem_pattern = pattern == "1"
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="Middlebury 2014 folder (e.g. its trainingQ)")
    parser.add_argument("--model", default="cade-v11", help="a card name or path, as `cade --model` takes")
    parser.add_argument("--options", nargs="+", default=["0,0,1", "1,1,0"], help="SPIN,ARENA,PATTERN entries")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=4, help="timed rounds per pair")
    args = parser.parse_args(argv)
    import time

    import cv2
    import numpy as np

    from cade_cli.allocator import retain_freed_memory
    from cade_cli.data import get_dataset
    from cade_cli.evaluation.protocols import get_protocol
    from cade_cli.matching import network
    from cade_cli.matching.base import DisparityRange
    from cade_cli.matching.learned import LearnedPipeline

    retain_freed_memory()  # as the cade command does
    cv2.setNumThreads(args.threads)
    built: dict[tuple[str, Path], object] = {}
    current = [args.options[0]]

    def session(path: Path, sha256: str):  # the variant the stage chose, built with the options in turn
        key = (current[0], path)
        if key not in built:
            built[key] = build_session(path, *current[0].split(","), args.threads)
        return built[key]

    network.onnx_session = session
    pipeline = LearnedPipeline(network=network.NetworkStage(args.model))
    times: dict[str, list[float]] = collections.defaultdict(list)
    for scene in get_dataset("middlebury14")(args.data_dir):
        left, right = get_protocol("native").tasks[0].bands(scene.left, scene.right)
        disparity_range = DisparityRange(0, scene.max_disp)
        for entry in args.options:
            current[0] = entry
            pipeline(left, right, disparity_range)  # untimed
        for round_ in range(args.repeat):
            for entry in (args.options if round_ % 2 == 0 else args.options[::-1]):
                current[0] = entry
                start = time.perf_counter()
                pipeline(left, right, disparity_range)
                times[entry].append(time.perf_counter() - start)
    baseline = np.array(times[args.options[0]])
    print(f"# onnxruntime session options inside the `cade` pipeline: {args.model}, {len(baseline)} timed runs each, "
          f"{args.threads} threads\n\n| spin, arena, pattern | s / pair | time / baseline's (median) |\n|---|---:|---:|")
    for entry, values in times.items():
        print(f"| {entry} | {np.mean(values):.4f} | {np.median(np.array(values) / baseline):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
