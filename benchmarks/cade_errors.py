"""Which stage of the ``cade`` matcher makes its gross errors, per scene.

For every scene and cross-spectral task (``cs`` protocol, optionally a subset), the learned
pipeline's stages are run one at a time (the same public stages ``cade`` runs):

* ``network``: :class:`~cade_cli.matching.network.NetworkStage` alone;
* ``sgbm``: the refinement's candidate (:meth:`RankSgbmRefinement.candidate`), where SGBM
  accepted it, else the network's value (no agreement bound);
* ``cade``: the shipped combination (candidate within 32 px of the network);
* ``oracle``: per pixel the better of network and accepted candidate: what a perfect
  choice between the two would reach.

Each pixel with ground truth whose final error exceeds 3 px (a BMP3 error) is put in one
class by where it came from: ``refined-wrong`` (the candidate replaced the network's value
and is wrong; ``broke`` counts those where the network was right), ``kept-rejected`` (the
network is wrong and SGBM rejected the match), ``kept-far`` (SGBM's accepted match is more
than 32 px away and the network's wrong value stayed; ``far-right`` counts those where the
candidate was right). Figures are over all pixels with GT, or a region of them (``--region``:
``nonocc``, or ``edge``, the non-occluded pixels near a depth jump, as ``cade benchmark`` scores
them: :func:`~cade_cli.evaluation.regions.region_masks`). ``--model`` runs a card other than the
default (the network and the refinement its card names: ``rank-sgbm-two-scales`` adds the
half-size match where the full-size one is rejected).

Usage:
    .venv/bin/python benchmarks/cade_errors.py --data-dir ../shared/data --dataset middlebury14 \\
        [--tasks R>B,G>B] [--region all|nonocc|edge] [--model CARD] [--markdown docs/cade-errors.md]
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

import numpy as np

from cade_cli.data import Scene, get_dataset
from cade_cli.evaluation.loop import map_scenes
from cade_cli.evaluation.metrics import bad_pixel_rate, end_point_error
from cade_cli.evaluation.protocols import Protocol, get_protocol
from cade_cli.evaluation.regions import region_masks
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.learned import card_refinement
from cade_cli.matching.network import DEFAULT_MODEL, NetworkStage
from cade_cli.matching.refinement import RankSgbmRefinement

BAD = 3.0
CLASSES = ("refined-wrong", "broke", "kept-rejected", "kept-far", "far-right")


def stage_maps(left: np.ndarray, right: np.ndarray, max_disp: int, refinement: RankSgbmRefinement,
               model: str = DEFAULT_MODEL) -> dict:
    """The stage maps (px) of one task and the candidate's acceptance."""
    network = NetworkStage(model)(left, right, DisparityRange(0, max_disp))
    candidate, accepted = refinement.candidate(left, right, network, max_disp)
    near = accepted & (np.abs(candidate - network) <= refinement.agreement)
    return {"network": network, "candidate": candidate, "accepted": accepted, "near": near,
            "sgbm": np.where(accepted, candidate, network), "cade": np.where(near, candidate, network)}


def analyse(maps: dict, gt: np.ndarray, region: np.ndarray) -> dict:
    scored = region & np.isfinite(gt)
    better = np.abs(maps["sgbm"] - gt) < np.abs(maps["network"] - gt)
    maps = {**maps, "oracle": np.where(maps["accepted"] & better, maps["sgbm"], maps["network"])}
    row = {}
    for name in ("network", "sgbm", "cade", "oracle"):
        row[f"{name}_epe"] = end_point_error(maps[name], gt, region)
        row[f"{name}_bmp3"] = bad_pixel_rate(maps[name], gt, region, threshold=BAD)
    error = {name: np.abs(maps[name] - gt)[scored] for name in ("network", "cade")}
    bad = error["cade"] > BAD
    near, accepted = maps["near"][scored], maps["accepted"][scored]
    network_ok, candidate_ok = error["network"] <= BAD, np.abs(maps["candidate"] - gt)[scored] <= BAD
    counts = {
        "refined-wrong": bad & near,
        "broke": bad & near & network_ok,
        "kept-rejected": bad & ~accepted,
        "kept-far": bad & accepted & ~near,
        "far-right": bad & accepted & ~near & candidate_ok,
    }
    row.update({name: float(100 * mask.mean()) for name, mask in counts.items()})
    return row


def scored_region(scene: Scene, region: str) -> np.ndarray:
    """The (H, W) bool pixels ``region`` (``all``, ``nonocc``, ``edge``) names in ``scene``."""
    if region == "all":
        return np.ones(scene.disparity.shape, bool)
    masks = region_masks(scene.disparity, nonocc=scene.nonocc)
    if region not in masks:
        raise SystemExit(f"{scene.name} has no {region} pixels (no occlusion mask or no depth jump)")
    return masks[region]


def analyse_scene(scene: Scene, *, protocol: Protocol, region: str, model: str = DEFAULT_MODEL) -> dict:
    """The mean over ``protocol``'s tasks of :func:`analyse` on one scene."""
    pixels = scored_region(scene, region)
    refinement = card_refinement(NetworkStage(model).card(), RankSgbmRefinement())
    rows = []
    for task in protocol.tasks:
        left, right = task.bands(scene.left, scene.right)
        rows.append(analyse(stage_maps(left, right, scene.max_disp, refinement, model), scene.disparity, pixels))
    return {key: float(np.mean([row[key] for row in rows])) for key in rows[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--dataset", default="middlebury14")
    parser.add_argument("--tasks", default=None, help="Comma-separated CS tasks (default: all six).")
    parser.add_argument("--region", choices=("all", "nonocc", "edge"), default="all")
    parser.add_argument("--model", default=None, help=f"a card name or path (default {DEFAULT_MODEL})")
    parser.add_argument("--markdown", type=Path, default=None)
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args()
    protocol = get_protocol("cs").select(args.tasks.split(",") if args.tasks else None)
    reader = get_dataset(args.dataset)
    rows = list(map_scenes(partial(analyse_scene, protocol=protocol, region=args.region,
                                                model=args.model or DEFAULT_MODEL), reader, args.data_dir,
                           reader.scene_names(args.data_dir), jobs=args.jobs))
    rows.append(("mean", {key: float(np.mean([r[key] for _, r in rows])) for key in rows[0][1]}))
    header = ("| scene | network EPE / BMP3 | sgbm | cade | oracle | BMP3 errors: refined-wrong (broke) | "
              "kept, SGBM rejected | kept, SGBM > 32 px away (SGBM right) |")
    lines = [f"# Where the cade matcher's gross errors come from ({args.dataset}, CS tasks "
             f"{', '.join(t.name for t in protocol.tasks)}, {args.region} pixels)", "",
             "`.venv/bin/python benchmarks/cade_errors.py " + " ".join(
                 f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if v is not None and k not in ("markdown", "jobs"))
             + "`", "", "Error classes are % of the scored pixels (their sum is cade's BMP3).", "",
             header, "|---|---|---|---|---|---|---|---|"]
    for name, r in rows:
        cells = [f"{r[f'{m}_epe']:.2f} / {r[f'{m}_bmp3']:.1f}" for m in ("network", "sgbm", "cade", "oracle")]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {r['refined-wrong']:.1f} ({r['broke']:.1f}) | "
                     f"{r['kept-rejected']:.1f} | {r['kept-far']:.1f} ({r['far-right']:.1f}) |")
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)


if __name__ == "__main__":
    main()
