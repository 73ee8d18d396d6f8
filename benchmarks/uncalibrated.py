#!/usr/bin/env python
"""Uncalibrated rectification (:mod:`cade_cli.rigs.uncalibrated`) on real pairs: the model chosen,
the residual it leaves, and the pair check's vertical offset before and after.

The pairs: the bundled ``samples/middlebury2005-art`` (red and blue bands, already rectified)
and, where ``--data-dir`` holds them, OpenCV's ``calibration/opencv-stereo-chessboard`` pairs
(an uncalibrated rig, 640 x 480 grey). Two measures independent of the SIFT matches the warp
rests on: the pair check (:func:`cade_cli.pair_check.check_pair`, ORB features) and, on the
chessboard pairs, the 9 x 6 inner corners ``cv2.findChessboardCorners`` finds in both images:
the |row difference| of each corner's two views, before and after the warps (median / largest).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/uncalibrated.py --data-dir ../shared/data
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.pair_check import check_pair
from cade_cli.rigs.uncalibrated import estimate_pair_rectification

ROOT = Path(__file__).resolve().parent.parent


def pairs(data_dir: Path | None) -> list[tuple[str, Path, Path]]:
    """(name, left, right) of every pair found."""
    art = ROOT / "samples" / "middlebury2005-art"
    found = [("samples Art R>B", art / "left_R.png", art / "right_B.png")]
    chessboard = None if data_dir is None else data_dir / "calibration" / "opencv-stereo-chessboard"
    if chessboard is not None and chessboard.is_dir():
        for left in sorted(chessboard.glob("left*.jpg")):
            found.append((f"opencv {left.stem}", left, chessboard / left.name.replace("left", "right")))
    return found


def grey(path: Path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255


def offset(left: np.ndarray, right: np.ndarray) -> str:
    found = check_pair(left, right, min_disp=-64, max_disp=160)
    return "-" if not found.conclusive else f"{found.vertical_offset:+.2f} px / {found.rotation:+.2f} deg"


def corner_rows(left: np.ndarray, right: np.ndarray, warps=None) -> str:
    """Median / largest |row difference| (px) of the chessboard's corners in both views, through ``warps``."""
    corners = []
    for band in (left, right):
        found, points = cv2.findChessboardCorners((band * 255).astype(np.uint8), (9, 6))
        if not found:
            return "-"
        corners.append(cv2.cornerSubPix((band * 255).astype(np.uint8), points, (5, 5), (-1, -1),
                                        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)))
    if warps is not None:
        corners = [cv2.perspectiveTransform(points.reshape(-1, 1, 2).astype(np.float64), np.asarray(warp, np.float64))
                   for points, warp in zip(corners, warps)]
    rows = np.abs(corners[1].reshape(-1, 2)[:, 1] - corners[0].reshape(-1, 2)[:, 1])
    return f"{np.median(rows):.2f} / {rows.max():.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=None)
    args = parser.parse_args()
    print("| pair | model | residual (median, px) | inliers / matches | pair check before | after | corners' rows "
          "before (px) | after |")
    print("|---|---|---|---|---|---|---|---|")
    for name, left_path, right_path in pairs(args.data_dir):
        left, right = grey(left_path), grey(right_path)
        before, corners_before = offset(left, right), corner_rows(left, right)
        try:
            found = estimate_pair_rectification(left, right)
        except CadeError as refused:
            print(f"| {name} | refused: {str(refused).split(': ', 1)[1].split(';')[0]} | | | {before} | | "
                  f"{corners_before} | |")
            continue
        after = offset(*found.rectify(left, right))
        corners_after = corner_rows(left, right, (found.left_warp, found.right_warp))
        print(f"| {name} | {found.model} | {found.residual:.2f} | {found.inliers} / {found.matches} | {before} | "
              f"{after} | {corners_before} | {corners_after} |")


if __name__ == "__main__":
    main()
