"""Where an exported network's inference time goes: onnxruntime's own profile, by op type and node.

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/network_profile.py models/cade-v13.onnx --size 720x496

The network runs on random bands of the given size (the time depends on the size, not the
content), after two untimed runs; the shares are of the summed kernel time of the timed runs.
Run it on a quiet machine: the shares hold under load, the seconds do not.
"""

from __future__ import annotations

import argparse
import collections
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort


def stage_of(node: str) -> str:
    """The module that made a node (``/net/<module>/...``), or what the top level of the graph
    does (the correlation volume, soft-argmin), or onnxruntime's own layout reorders."""
    parts = node.strip("/").split("/")
    if parts[0] == "net" and len(parts) > 2:
        return parts[1]
    if parts[0] == "net":
        return "top level (volume, soft-argmin, glue)"
    return "layout reorders (onnxruntime)" if "Reorder" in node else "other"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("onnx", type=Path, help="an exported network (.onnx)")
    parser.add_argument("--size", default="720x496", help="WIDTHxHEIGHT of the bands (multiples of the divisor)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--top", type=int, default=12, help="nodes listed")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    options = ort.SessionOptions()
    options.intra_op_num_threads = args.threads
    options.enable_profiling = True
    options.profile_file_prefix = str(Path(tempfile.mkdtemp()) / "profile")
    session = ort.InferenceSession(str(args.onnx), options, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    feeds = {item.name: rng.random((1, 1, height, width), dtype=np.float32) for item in session.get_inputs()}
    for _ in range(2):
        session.run(None, feeds)
    started = time.perf_counter()
    for _ in range(args.runs):
        session.run(None, feeds)
    seconds = (time.perf_counter() - started) / args.runs
    with open(session.end_profiling(), encoding="utf-8") as file:
        events = [e for e in json.load(file) if e.get("cat") == "Node" and e["name"].endswith("_kernel_time")]
    by_op, by_stage, by_node = collections.Counter(), collections.Counter(), collections.Counter()
    for event in events:
        node = event["name"].removesuffix("_kernel_time")
        by_op[event["args"]["op_name"]] += event["dur"]
        by_node[node] += event["dur"]
        by_stage[stage_of(node)] += event["dur"]
    total = sum(by_op.values()) or 1
    print(f"{args.onnx.name}: {width}x{height}, {args.threads} threads, {seconds:.3f} s per run (mean of {args.runs})")
    print("\n| stage (module) | share |\n|---|---:|")
    for stage, duration in by_stage.most_common():
        print(f"| {stage} | {100 * duration / total:.1f} % |")
    print("\n| op type | share |\n|---|---:|")
    for op, duration in by_op.most_common(10):
        print(f"| {op} | {100 * duration / total:.1f} % |")
    print("\n| node | share |\n|---|---:|")
    for node, duration in by_node.most_common(args.top):
        print(f"| `{node}` | {100 * duration / total:.1f} % |")


if __name__ == "__main__":
    main()
