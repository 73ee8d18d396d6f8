"""The pseudo ground truth of the msir-outdoor benchmark, task by task: its partners, shift,
range and coverage, and the score of the façade plane alone (docs/msir-outdoor.md). It builds and caches the pseudo ground truths on
a first run (cade_cli.data.msir; a minute or two per reference camera on 2 cores).

    python benchmarks/msir_pseudo_gt.py ../shared/data
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from cade_cli.data import get_dataset
from cade_cli.errors import CadeError


def coverage_table(data_dir: Path) -> str:
    """One Markdown row per task of the dataset under ``data_dir``. "plane" scores the map
    d = shift everywhere: the affine (façade-plane) registration with no parallax, the
    baseline a matcher must beat (EPE px / BMP3 % over the pseudo-GT pixels)."""
    lines = ["| task | baseline | partners | shift px | pseudo-GT d px (1st-99th pct) | std px | coverage % | "
             "nonocc % | max_disp | plane EPE / BMP3 | load s |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    reader = get_dataset("msir-outdoor")
    for name in reader.scene_names(data_dir):
        start = time.perf_counter()
        (scene,) = reader(data_dir, scenes=[name])
        seconds = time.perf_counter() - start
        known = np.isfinite(scene.disparity)
        low, high = np.percentile(scene.disparity[known], [1, 99]) if known.any() else (np.nan, np.nan)
        info = scene.metadata
        plane = np.abs(scene.disparity[known] - info["shift"])
        lines.append(f"| {name} | {info['baseline_mm']} mm | {', '.join(info['partners'])} | {info['shift']} | "
                     f"{low:.2f} - {high:.2f} | {scene.disparity[known].std():.2f} | {100 * known.mean():.1f} | "
                     f"{100 * scene.nonocc.mean():.1f} | {scene.max_disp} | {plane.mean():.2f} / {100 * np.mean(plane > 3):.2f} | "
                     f"{seconds:.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data_dir", type=Path, help="the data folder holding msir-outdoor (or that folder)")
    arguments = parser.parse_args()
    try:
        print(coverage_table(arguments.data_dir))
    except CadeError as error:
        raise SystemExit(f"msir_pseudo_gt: error: {error}") from None


if __name__ == "__main__":
    main()
