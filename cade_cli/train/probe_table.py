"""The table both edge probes print (``edge_assignment``, ``mask_headroom``; docs/research/refinement.md): per
set and map, the mean over pairs of EPE px / BMP3 % on all pixels and BMP3 on the non-occluded and depth-edge
ones, as ``cade benchmark`` scores them by region (docs/accuracy-by-region.md)."""

from __future__ import annotations

import numpy as np

from cade_cli.evaluation.metrics import score

HEADER = "| set | map | all EPE / BMP3 | non-occluded BMP3 | depth-edge BMP3 |\n|---|---|---|---|---|"


class RegionTable:
    """One set's rows: :meth:`add` each pair's map under its row name, then :meth:`print` the means."""

    def __init__(self, name: str) -> None:
        self.name, self.rows = name, {}

    def add(self, row: str, disparity: np.ndarray, gt: np.ndarray, regions: dict[str, np.ndarray]) -> None:
        s = score(disparity.astype(np.float32), gt, **regions)
        self.rows.setdefault(row, []).append([s["epe_all"], s["bad3_all"], s.get("bad3_nonocc", np.nan),
                                              s.get("bad3_edge", np.nan)])

    def print(self) -> dict[str, np.ndarray]:
        """Row name -> (EPE all, BMP3 all, BMP3 non-occluded, BMP3 edge), each the mean over the pairs added;
        printed in the order the rows were first added."""
        means = {row: np.mean(values, 0) for row, values in self.rows.items()}
        for row, v in means.items():
            print(f"| {self.name} | {row} | {v[0]:.2f} / {v[1]:.1f} | {v[2]:.1f} | {v[3]:.1f} |", flush=True)
        return means
