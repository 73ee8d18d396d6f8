#!/usr/bin/env python
"""Where the `cade` matcher's time goes, stage by stage, and how the network's time grows with its range.

For each Middlebury 2014 pair (the loop's scenes, :func:`cade_cli.evaluation.loop.map_scenes`;
protocol ``native``: grey, float32 in [0, 1]; range [0, ndisp - 1] from calib.txt) the
stages of the ``cade`` matcher (:class:`cade_cli.matching.learned.LearnedPipeline`) are
timed separately with the loop's :func:`~cade_cli.evaluation.timing.measure`: the color
agnostic transform of both bands, the network (the variant the runtime picks), the
refinement (SGM of the raw bands over the whole range), and visibility plus fill. Then
the network alone is timed with every exported variant on the same pairs, and a
least-squares line ``seconds = fixed + per_level * levels`` (levels = variant levels / 4,
the 1/4-resolution cost-volume depth) separates what the 2D parts cost (features,
refinement) from what the cost volume and its 3D aggregation cost.

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/cade_stages.py \\
        --data-dir ../shared/data/middlebury2014/trainingQ --markdown docs/speed-cade-stages.md
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from functools import partial
from pathlib import Path

import numpy as np

from cade_cli.allocator import retain_freed_memory
from cade_cli.data import get_dataset
from cade_cli.errors import CadeError
from cade_cli.evaluation.loop import map_scenes
from cade_cli.evaluation.protocols import get_protocol
from cade_cli.evaluation.timing import measure
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.disparity import densify, visible_in_right_view
from cade_cli.matching.network import choose_variant, onnx_session, run_network
from cade_cli.matching.refinement import RankSgbmRefinement
from cade_cli.model_card import read_card
from cade_cli.spectral import color_agnostic


def fastest(function, repeat: int) -> tuple[float, object]:
    """The fastest of ``repeat`` timed calls after one untimed call, and the last result."""
    seconds, result = measure(function, warmup=1, repeat=repeat)
    return min(seconds), result


def profile(scene, *, card, repeat: int) -> tuple[tuple, list[tuple[int, float]]] | None:
    """(stage row, [(1/4-resolution levels, network s/MP) per variant]) of one scene; None for
    a scene whose span needs a pyramid level (the stages below run at full size only)."""
    (left, right) = get_protocol("native").tasks[0].bands(scene.left, scene.right)
    span, megapixels = scene.max_disp, left.size / 1e6
    transform, (band_left, band_right) = fastest(lambda: (color_agnostic(left), color_agnostic(right)), repeat)
    variant, factor = choose_variant(card, span)
    if factor > 1:  # the stages below run at full size; the runtime would downscale first
        print(f"left out: {scene.name}: span {span} px needs a x{factor} pyramid level with {card.name}, "
              "which this script does not time", file=sys.stderr)
        return None
    session = onnx_session(variant.path, variant.sha256)
    network, raw = fastest(lambda: run_network(session, card.divisor, band_left, band_right), repeat)
    refinement, sharp = fastest(lambda: RankSgbmRefinement()(left, right, raw, DisparityRange(0, span)), repeat)

    def visibility_and_fill():
        visible = visible_in_right_view(raw)
        return densify(np.where(visible, sharp, np.float32(np.nan)), visible)

    validity, _ = fastest(visibility_and_fill, repeat)
    samples = []
    for other in card.variants:
        other_session = onnx_session(other.path, other.sha256)
        seconds, _ = fastest(lambda: run_network(other_session, card.divisor, band_left, band_right), repeat)
        samples.append((other.levels // 4, seconds / megapixels))
    return (scene.name, megapixels, span, variant.levels, transform, network, refinement, validity), samples


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="Middlebury 2014 folder (e.g. its trainingQ)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per measurement; the fastest is kept")
    parser.add_argument("--markdown", type=Path, help="also write the report here")
    parser.add_argument("--model", default=None,
                        help="a card name or path, as `cade --model` takes (default: the shipped one)")
    args = parser.parse_args(argv)
    retain_freed_memory()  # as the cade command does
    threads = int(os.environ.get("OMP_NUM_THREADS") or 0)
    card = read_card(args.model)
    try:
        reader = get_dataset("middlebury14")
        results = [result for _, result in map_scenes(
            partial(profile, card=card, repeat=args.repeat), reader, args.data_dir, reader.scene_names(args.data_dir),
            threads=threads or None)]
    except CadeError as error:
        raise SystemExit(str(error)) from None
    results = [result for result in results if result is not None]
    if not results:
        raise SystemExit("no scene fits the card's widest variant at full size")
    stage_rows = [row for row, _ in results]
    level_samples = [sample for _, samples in results for sample in samples]

    lines = [
        "# Where the `cade` matcher's time goes",
        "",
        f"- Command: `OMP_NUM_THREADS={threads or 'unset'} {shlex.join([Path(sys.executable).name] + sys.argv)}`",
        f"- Model: {card.name}; fastest of {args.repeat} timed runs after one untimed run, per stage",
        "",
        "| scene | MP | span | variant | transform s | network s | refinement s | validity + fill s "
        "| total s/MP |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    totals = np.zeros(4)
    for name, megapixels, span, levels, *stages in stage_rows:
        totals += np.array(stages) / megapixels
        lines.append(f"| {name} | {megapixels:.3f} | {span} | {levels} | "
                     + " | ".join(f"{s:.3f}" for s in stages) + f" | {sum(stages) / megapixels:.3f} |")
    share = totals / totals.sum() * 100
    lines += ["", "Mean s/MP per stage: " + ", ".join(
        f"{label} {value / len(stage_rows):.3f} ({pct:.0f} %)"
        for label, value, pct in zip(("transform", "network", "refinement", "validity + fill"), totals, share))
        + f"; all stages {totals.sum() / len(stage_rows):.3f} s/MP."]
    levels, per_mp = np.array(level_samples).T
    by_variant = {int(lv) * 4: float(np.mean(per_mp[levels == lv])) for lv in np.unique(levels)}
    lines += ["", "Network alone, mean s/MP over the scenes, per exported variant: "
              + ", ".join(f"{variant} → {value:.3f}" for variant, value in by_variant.items()) + "."]
    if len(by_variant) > 1:  # a card of one variant (CadeNet2D) has no line to fit
        per_level, fixed = np.polyfit(levels, per_mp, 1)
        lines.append(f"Least-squares line: {fixed:.3f} s/MP fixed (2D features, refinement, upsampling) "
                     f"+ {per_level * 1000:.2f} ms/MP per 1/4-resolution level (cost volume, 3D aggregation, "
                     f"soft-argmin); at the trained 32 levels the fixed part is "
                     f"{fixed / (fixed + 32 * per_level) * 100:.0f} % of the network's time.")
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
