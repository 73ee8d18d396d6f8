#!/usr/bin/env python
"""Where the `cade` matcher's time goes, stage by stage, and how the network's time grows with its range.

For each MiddEval3 pair (grey, float32 in [0, 1], range [0, ndisp - 1] from calib.txt)
the stages of :class:`cade_cli.matching.learned.CadeNetwork` are timed separately:
the color agnostic transform of both bands, the network (the variant the runtime
picks), the refinement (SGM of the raw bands over the whole range), and validity plus fill. Then the network alone is timed
with every exported variant on the same pairs, and a least-squares line
``seconds = fixed + per_level * levels`` (levels = max_disp / 4, the 1/4-resolution
cost-volume depth) separates what the 2D parts cost (features, refinement) from what
the cost volume and its 3D aggregation cost.

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/cade_stages.py \\
        --data-dir ../shared/data/middlebury2014/trainingQ --markdown docs/speed-cade-stages.md
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from cade_cli.allocator import retain_freed_memory
from cade_cli.datasets import read_calib
from cade_cli.matching import learned
from cade_cli.matching.disparity import fill_invalid_along_rows, visible_in_right_view
from cade_cli.spectral import color_agnostic


def best_of(function, repeat: int) -> tuple[float, object]:
    """The fastest of ``repeat`` timed calls (after one untimed call) and the last result."""
    result = function()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="MiddEval3 folder holding <Scene>/im0.png ...")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per measurement; the fastest is kept")
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    retain_freed_memory()  # as the cade command does
    threads = int(os.environ.get("OMP_NUM_THREADS") or 0)
    if threads:
        cv2.setNumThreads(threads)
    folders = sorted(folder for folder in args.data_dir.iterdir() if (folder / "im0.png").is_file())
    if not folders:
        raise SystemExit(f"no MiddEval3 scene under {args.data_dir}")
    card = learned.ModelCard.load()

    stage_rows, level_samples = [], []
    for folder in folders:
        left, right = (cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
                       for name in ("im0.png", "im1.png"))
        span = read_calib(folder / "calib.txt")["ndisp"] - 1
        megapixels = left.size / 1e6
        transform, (band_left, band_right) = best_of(lambda: (color_agnostic(left), color_agnostic(right)),
                                                     args.repeat)
        variant, factor = card.variant_for(span)
        if factor > 1:  # the stages below run at full size; the runtime would downscale first
            raise SystemExit(f"{folder.name}: span {span} px needs a x{factor} pyramid level, which this "
                             f"script does not time; use a smaller resolution")
        session = learned._session(variant.path, variant.sha256)
        network, raw = best_of(lambda: learned.CadeNetwork._run(session, card.divisor, band_left, band_right),
                               args.repeat)
        refinement, sharp = best_of(lambda: learned.refine_semiglobal(left, right, raw, span), args.repeat)
        validity, _ = best_of(lambda: fill_invalid_along_rows(sharp, visible_in_right_view(raw)), args.repeat)
        stage_rows.append((folder.name, megapixels, span, variant.max_disp, transform, network, refinement, validity))
        for other in card.variants:
            other_session = learned._session(other.path, other.sha256)
            seconds, _ = best_of(lambda: learned.CadeNetwork._run(other_session, card.divisor, band_left, band_right),
                                 args.repeat)
            level_samples.append((other.max_disp // 4, seconds / megapixels))

    lines = [
        "# Where the `cade` matcher's time goes",
        "",
        f"- Command: `OMP_NUM_THREADS={threads or 'unset'} {shlex.join([Path(sys.executable).name] + sys.argv)}`",
        f"- Model: {learned.MODEL_NAME}; fastest of {args.repeat} timed runs after one untimed run, per stage",
        "",
        "| scene | MP | span | variant | transform s | network s | refinement s | validity + fill s "
        "| total s/MP |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    totals = np.zeros(4)
    for name, megapixels, span, max_disp, *stages in stage_rows:
        totals += np.array(stages) / megapixels
        lines.append(f"| {name} | {megapixels:.3f} | {span} | {max_disp} | "
                     + " | ".join(f"{s:.3f}" for s in stages) + f" | {sum(stages) / megapixels:.3f} |")
    share = totals / totals.sum() * 100
    lines += ["", "Mean s/MP per stage: " + ", ".join(
        f"{label} {value / len(stage_rows):.3f} ({pct:.0f} %)"
        for label, value, pct in zip(("transform", "network", "refinement", "validity + fill"), totals, share))
        + f"; all stages {totals.sum() / len(stage_rows):.3f} s/MP."]
    levels, per_mp = np.array(level_samples).T
    per_level, fixed = np.polyfit(levels, per_mp, 1)
    by_variant = {int(lv) * 4: float(np.mean(per_mp[levels == lv])) for lv in np.unique(levels)}
    lines += ["", "Network alone, mean s/MP over the scenes, per exported variant: "
              + ", ".join(f"{max_disp} → {value:.3f}" for max_disp, value in by_variant.items()) + ".",
              f"Least-squares line: {fixed:.3f} s/MP fixed (2D features, refinement, upsampling) "
              f"+ {per_level * 1000:.2f} ms/MP per 1/4-resolution level (cost volume, 3D aggregation, "
              f"soft-argmin); at the trained 32 levels the fixed part is "
              f"{fixed / (fixed + 32 * per_level) * 100:.0f} % of the network's time."]
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
