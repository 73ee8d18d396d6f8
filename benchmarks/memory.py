#!/usr/bin/env python
"""Peak resident memory of one ``cade disparity`` run on a large generated pair.

Writes a textured pair (left, and right shifted by a known disparity with a gamma change:
a cross-band pair) of ``--width`` x ``--height`` to a temporary folder, runs the CLI in a
child process and reports the child's peak RSS (``resource.getrusage``), wall time, and
the EPE against the known shift::

    .venv/bin/python benchmarks/memory.py --width 3000 --height 2000 --max-disp 200
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from cade_cli.evaluation.metrics import end_point_error
from cade_cli.io.disparity import read_disparity


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=3000)
    parser.add_argument("--height", type=int, default=2000)
    parser.add_argument("--disparity", type=float, default=150.0, help="true constant disparity (px)")
    parser.add_argument("--max-disp", type=int, default=200)
    parser.add_argument("--method", default="cade")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(0)
    small = rng.random((args.height // 12, (args.width + int(args.disparity) + 8) // 12)).astype(np.float32)
    texture = cv2.resize(small, (args.width + int(args.disparity) + 8, args.height), interpolation=cv2.INTER_CUBIC)
    texture = np.clip(cv2.normalize(texture, None, 0, 1, cv2.NORM_MINMAX), 0, 1)  # rounding can dip below 0
    shift = int(args.disparity)
    left = texture[:, :args.width]
    right = texture[:, shift:shift + args.width] ** 2.2  # I_left(x) = I_right(x - d), another "filter"
    with tempfile.TemporaryDirectory() as folder:
        paths = [Path(folder) / name for name in ("left.png", "right.png", "disp.pfm")]
        for path, band in zip(paths, (left, right)):
            cv2.imwrite(str(path), np.round(np.clip(band, 0, 1) * 65535).astype(np.uint16))
        command = [str(Path(sys.executable).with_name("cade")), "disparity", str(paths[0]), str(paths[1]),
                   "-o", str(paths[2]), "--method", args.method, "--max-disp", str(args.max_disp)]
        started = time.perf_counter()
        subprocess.run(command, check=True)
        seconds = time.perf_counter() - started
        peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        estimate = read_disparity(paths[2])
    margin = args.max_disp + 8
    scored = estimate[:, margin:-8]  # the CLI writes a dense map by default (--fill row)
    epe = end_point_error(scored, np.full(scored.shape, args.disparity, np.float32), np.isfinite(scored))
    print(f"{args.method} on {args.width}x{args.height} ({args.width * args.height / 1e6:.1f} MP), "
          f"range [0, {args.max_disp}]: peak RSS {peak_mb:.0f} MB, {seconds:.1f} s wall (incl. start-up and I/O), "
          f"EPE {epe:.2f} px against the true {args.disparity:g} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
