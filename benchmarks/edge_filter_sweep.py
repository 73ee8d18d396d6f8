"""How the edge filter's settings score by region (cade_cli/matching/edges.py), on a model's maps.

    .venv/bin/python benchmarks/edge_filter_sweep.py --dataset middlebury14 --model cade-v13-accurate \
        --cache /tmp/edge-sweep/m14-accurate [--protocol cs] [--markdown table.md]

The model (a card without the edge filter) is run on every pair of the dataset (the ``cade`` matcher,
each task's map filled by ``densify`` as ``cade benchmark`` scores it) and the maps are cached in
``--cache`` (one .npz per pair: both bands, the map, ground truth, occlusion mask); then each setting
of :func:`~cade_cli.matching.edges.snap_to_edges` is applied to the filled maps and scored on all,
non-occluded, depth-edge and occluded pixels (cade_cli/evaluation/regions.py), mean over pairs.
The filter here runs after the fill; in the matcher it runs before it (on the network's own values
at occluded pixels), so the rows differ slightly from a `cade benchmark` run of a card with the filter.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from cade_cli.data.catalogue import get_dataset
from cade_cli.evaluation.metrics import score
from cade_cli.evaluation.protocols import get_protocol
from cade_cli.evaluation.regions import region_masks
from cade_cli.matching import densify, get_matcher
from cade_cli.matching.edges import snap_to_edges
from cade_cli.model_card import read_card

SETTINGS = {
    "none": None,
    "default": {},
    "no guide (a plain median)": {"flat_guide": True},
    "radius 5": {"radius": 5},
    "radius 10": {"radius": 10},
    "sigma 5": {"sigma": 5.0},
    "sigma 20": {"sigma": 20.0},
    "every move (min_move 0)": {"min_move": 0.0},
    "min_move 0.5": {"min_move": 0.5},
    "min_move 2": {"min_move": 2.0},
}
REGIONS = ("all", "nonocc", "edge", "occ")


def cache_maps(dataset: str, data_dir: Path, model: str, protocol: str, cache: Path) -> list[Path]:
    """One .npz per (scene, task) in ``cache``, computed once (existing files are kept)."""
    if read_card(model).edge_filter != "none":
        raise SystemExit(f"{model} already filters its map; give the card without the filter")
    matcher = get_matcher("cade", model=model)
    cache.mkdir(parents=True, exist_ok=True)
    files = []
    for scene in get_dataset(dataset)(data_dir):
        for task in get_protocol(protocol).tasks:
            path = cache / f"{scene.name.replace('/', '_')}_{task.name.replace('>', 'to')}.npz"
            files.append(path)
            if path.exists() and "right" in np.load(path).files:  # caches before 2026-12-07 kept the left band only
                continue
            left, right = task.bands(scene.left, scene.right)
            result = matcher(left, right, max_disp=scene.max_disp, min_disp=0, preprocess="cade")
            nonocc = scene.nonocc if scene.nonocc is not None else np.zeros(0, bool)
            np.savez_compressed(path, left=left, right=right, disparity=densify(result.disparity, result.valid),
                                gt=scene.disparity, nonocc=nonocc)
            print(f"cached {path.name}", file=sys.stderr, flush=True)
    return files


def sweep(files: list[Path], settings: dict) -> dict[tuple[str, str], tuple[float, float]]:
    """(setting, region) -> (mean EPE px, mean BMP3 %) over the pairs that have the region, each pair
    scored as `cade benchmark` scores it (:func:`~cade_cli.evaluation.metrics.score`)."""
    scores: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for path in files:
        pair = np.load(path)
        gt, nonocc = pair["gt"], pair["nonocc"]
        regions = region_masks(gt, nonocc=nonocc if nonocc.size else None)
        for name, options in settings.items():
            if options is None:
                disparity = pair["disparity"]
            else:
                options = dict(options)
                reference = np.zeros_like(pair["left"]) if options.pop("flat_guide", False) else pair["left"]
                disparity = snap_to_edges(pair["disparity"], reference, **options)
            scored = score(disparity, gt, **regions)
            for region in ("all", *regions):
                scores.setdefault((name, region), []).append((scored[f"epe_{region}"], scored[f"bad3_{region}"]))
    return {key: tuple(np.mean(values, axis=0)) for key, values in scores.items()}


def table(scores: dict, settings: dict) -> str:
    present = [region for region in REGIONS if any((name, region) in scores for name in settings)]
    lines = ["| setting | " + " | ".join(f"{region} EPE / BMP3" for region in present) + " |",
             "|---|" + "---|" * len(present)]
    for name in settings:
        cells = [f"{scores[name, region][0]:.2f} / {scores[name, region][1]:.1f}" if (name, region) in scores
                 else "" for region in present]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def report(text: str, markdown: Path | None) -> int:
    """Print ``text``, also write it to ``markdown`` when given; the script's exit status (0)."""
    print(text)
    if markdown is not None:
        markdown.write_text(text)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    parser.add_argument("--model", default="cade-v13-accurate")
    parser.add_argument("--protocol", default="cs")
    parser.add_argument("--cache", type=Path, required=True, help="folder for the cached maps (reused)")
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    arguments = parser.parse_args(argv)
    files = cache_maps(arguments.dataset, arguments.data_dir, arguments.model, arguments.protocol, arguments.cache)
    text = (f"{arguments.dataset}, {arguments.protocol}, {arguments.model}'s maps, {len(files)} pairs "
            f"(EPE px / BMP3 %, mean over pairs)\n\n" + table(sweep(files, SETTINGS), SETTINGS))
    return report(text, arguments.markdown)


if __name__ == "__main__":
    sys.exit(main())
