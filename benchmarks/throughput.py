#!/usr/bin/env python
"""Throughput of ``cade batch``: pairs per minute with 1 and 2 local jobs and on a Dask cluster.

Generates ``--pairs`` cross-band pairs (a smooth random texture; the right view shifted by
a known disparity, slanted along the rows, through another 'filter': a gamma), then runs
the same ``cade batch`` command three times into separate folders:

* ``--jobs 1`` (one process, all cores);
* ``--jobs 2`` (two worker processes, cores shared);
* ``--scheduler`` on a Dask ``LocalCluster`` of 2 worker processes on 127.0.0.1 (one thread each).

For each it reports pairs per minute (the batch's own timing, from its JSON log, and the
command's wall time including start-up), the scaling efficiency against one job
(rate / (workers x the 1-job rate)), each worker's peak resident memory (from the log),
the network's load time (the first pair of each worker minus the median of its other
pairs) and that time amortised over the pairs the worker ran; and whether the outputs of
the three runs are identical byte for byte::

    .venv/bin/python benchmarks/throughput.py --pairs 50 [--width 640 --height 480]
        [--method cade] [--max-disp 64] [--markdown docs/bench/throughput.md]
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from cade_cli.evaluation.report import markdown_row


def write_pairs(folder: Path, count: int, width: int, height: int, max_disp: int, rng: np.random.Generator) -> None:
    """``count`` cross-band pairs as 16-bit PNGs in ``folder/left`` and ``folder/right`` (same names)."""
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
    rows = np.arange(height, dtype=np.float32)[:, None]
    columns = np.arange(width, dtype=np.float32)[None, :]
    for index in range(count):
        wide = width + max_disp + 8
        small = rng.random((height // 8, wide // 8)).astype(np.float32)
        texture = cv2.normalize(cv2.resize(small, (wide, height), interpolation=cv2.INTER_CUBIC), None, 0, 1,
                                cv2.NORM_MINMAX)
        near, far = sorted(rng.uniform(4, max_disp * 0.8, size=2))
        disparity = far + (near - far) * rows / max(1, height - 1) + 0 * columns  # nearer towards the bottom
        left = texture[:, max_disp:max_disp + width]
        source = (columns + max_disp + disparity).astype(np.float32)  # right(x) = left(x + d)
        right = cv2.remap(texture, source, np.broadcast_to(rows, source.shape).astype(np.float32), cv2.INTER_LINEAR)
        for side, band in (("left", left), ("right", np.clip(right, 0, 1) ** 2.2)):
            cv2.imwrite(str(folder / side / f"{index:04d}.png"), np.rint(np.clip(band, 0, 1) * 65535).astype(np.uint16))


def run_batch(folder: Path, name: str, extra: list[str], *, method: str, max_disp: int) -> dict:
    out = folder / name
    command = [str(Path(sys.executable).with_name("cade")), "batch", "--left", str(folder / "left" / "*.png"),
               "--right", str(folder / "right" / "*.png"), "-o", str(out), "--method", method,
               "--max-disp", str(max_disp), *extra]
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    log = json.loads((out / "cade-batch-log.json").read_text())
    by_worker = defaultdict(list)
    for entry in log["pairs"]:
        by_worker[entry["worker"]].append(entry)
    loads, amortised = [], []
    for entries in by_worker.values():  # in completion order, so a worker's first pair comes first
        if len(entries) >= 3:
            load = entries[0]["seconds"] - statistics.median(e["seconds"] for e in entries[1:])
            loads.append(load)
            amortised.append(load / len(entries))
    return {
        "name": name, "pairs": log["summary"]["done"], "seconds": log["summary"]["seconds"], "wall": wall,
        "workers": len(by_worker), "peak_mb": [max(e["peak_rss_mb"] for e in entries) for entries in by_worker.values()],
        "load": statistics.mean(loads) if loads else float("nan"),
        "amortised": statistics.mean(amortised) if amortised else float("nan"),
        "outputs": {path.name: path.read_bytes() for path in sorted(out.glob("*.pfm"))},
        "command": command,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=50)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--method", default="cade")
    parser.add_argument("--max-disp", type=int, default=64)
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    args = parser.parse_args(argv)

    from distributed import LocalCluster

    runs = []
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        write_pairs(folder, args.pairs, args.width, args.height, args.max_disp, np.random.default_rng(0))
        options = dict(method=args.method, max_disp=args.max_disp)
        runs.append(run_batch(folder, "1 job", ["--jobs", "1"], **options))
        runs.append(run_batch(folder, "2 jobs", ["--jobs", "2"], **options))
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as cluster:
            runs.append(run_batch(folder, "Dask LocalCluster, 2 workers",
                                  ["--scheduler", cluster.scheduler_address, "--threads", "1"], **options))
    base = runs[0]["pairs"] / runs[0]["seconds"]
    identical = all(run["outputs"] == runs[0]["outputs"] for run in runs[1:])
    lines = ["# `cade batch` throughput", "",
             f"Produced by `{shlex.join(['.venv/bin/python', 'benchmarks/throughput.py', *sys.argv[1:]])}`: "
             f"{args.pairs} generated cross-band pairs of {args.width}x{args.height}, `--method {args.method} "
             f"--max-disp {args.max_disp}`, on a {__import__('os').cpu_count()}-core machine. Rate: pairs per "
             "minute over the batch (its log's timing) and over the whole command (start-up included); "
             "efficiency: rate / (workers x the 1-job rate); model load: a worker's first pair minus the median "
             "of its other pairs, and that divided by the pairs it ran.", "",
             markdown_row(["run", "workers", "pairs/min (batch)", "pairs/min (command)", "efficiency",
                           "peak RSS per worker (MiB)", "model load (s)", "load per pair (s)"]),
             "|---|---:|---:|---:|---:|---|---:|---:|"]
    for run in runs:
        rate = run["pairs"] / run["seconds"]
        lines.append(markdown_row([
            run["name"], str(run["workers"]), f"{60 * rate:.1f}", f"{60 * run['pairs'] / run['wall']:.1f}",
            f"{rate / (run['workers'] * base):.2f}", ", ".join(f"{mb:.0f}" for mb in sorted(run["peak_mb"])),
            f"{run['load']:.2f}", f"{run['amortised']:.3f}"]))
    lines += ["", f"Outputs of the three runs identical byte for byte: {'yes' if identical else 'NO'}."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown is not None:
        args.markdown.write_text(text)
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
