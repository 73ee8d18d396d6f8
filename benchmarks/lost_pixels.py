#!/usr/bin/env python
"""Where a candidate loses pixels a shipped model got right: the bad-3 pixels of map B that are good
in map A, described against the scene (row band, image border, ground-truth disparity, brightness,
texture, B's signed error, the pixels whose match lies outside the right view), and their largest clusters.

    .venv/bin/python benchmarks/lost_pixels.py --gt GT --image LEFT A.pfm B.pfm

GT: any ground truth ``cade_cli.io.disparity.read_disparity`` reads (KITTI's PNG, PFM); LEFT: the
left image; A, B: the two disparity maps (e.g. from ``cade benchmark --save-dir``), NaN counted as 0
as the benchmark scores them after its fill. Prints one block of figures.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from cade_cli.io.disparity import read_disparity

BAD_PX = 3.0


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gt", type=Path, required=True)
    parser.add_argument("--image", type=Path, required=True)
    parser.add_argument("shipped", type=Path)
    parser.add_argument("candidate", type=Path)
    args = parser.parse_args(argv)
    gt = read_disparity(args.gt)
    valid = np.isfinite(gt) & (gt > 0)
    grey = cv2.imread(str(args.image), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    a, b = (np.nan_to_num(read_disparity(path)) for path in (args.shipped, args.candidate))
    bad_a, bad_b = ((np.abs(d - np.nan_to_num(gt)) > BAD_PX) & valid for d in (a, b))
    lost = bad_b & ~bad_a
    height, width = gt.shape
    rows, cols = np.nonzero(lost)
    texture = cv2.blur(np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0)), (9, 9))
    print(f"valid {valid.sum()}, bad-3 shipped {bad_a.sum()}, candidate {bad_b.sum()}: "
          f"lost {lost.sum()}, won {(bad_a & ~bad_b).sum()}")
    thirds = [np.mean((rows >= height * k / 3) & (rows < height * (k + 1) / 3)) for k in range(3)]
    print("lost pixels by row third (top, middle, bottom): " + ", ".join(f"{100 * t:.0f} %" for t in thirds))
    print(f"in the left / right tenth of the columns: {100 * np.mean(cols < width / 10):.0f} % / "
          f"{100 * np.mean(cols > width * 0.9):.0f} %")
    for name, values in (("ground-truth disparity", gt), ("grey level", grey), ("texture (|d/dx|, 9x9)", texture)):
        print(f"{name}: median {np.median(values[lost]):.1f} where lost, {np.median(values[valid]):.1f} over all valid")
    print(f"signed error where lost: candidate median {np.median((b - gt)[lost]):+.2f} px, "
          f"shipped {np.median((a - gt)[lost]):+.2f} px")
    unseen = valid & (np.arange(width)[None, :] < np.nan_to_num(gt))  # x - d < 0: no match in the right view
    if unseen.any():
        seen = valid & ~unseen
        print(f"out of the right view (x < true disparity): {100 * unseen.sum() / valid.sum():.1f} % of the valid "
              f"pixels, {100 * (lost & unseen).sum() / max(lost.sum(), 1):.0f} % of the lost ones; bad-3 there "
              f"{100 * bad_a[unseen].mean():.1f} % shipped, {100 * bad_b[unseen].mean():.1f} % candidate (in view "
              f"{100 * bad_a[seen].mean():.1f} %, {100 * bad_b[seen].mean():.1f} %)")
    else:
        print("out of the right view (x < true disparity): no valid pixel")
    count, _, stats, _ = cv2.connectedComponentsWithStats(lost.astype(np.uint8))
    largest = sorted(stats[1:], key=lambda s: -s[4])[:5]
    print("largest clusters (x, y, w, h, pixels): " + "; ".join(", ".join(str(int(v)) for v in s) for s in largest))


if __name__ == "__main__":
    main()
