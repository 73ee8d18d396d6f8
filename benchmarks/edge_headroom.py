"""How many of a model's depth-edge errors are the wrong surface of two nearby ones, and whether the
bands themselves can tell which surface is right.

    .venv/bin/python benchmarks/edge_headroom.py --dataset middlebury14 --model cade-v13-accurate \
        --cache /tmp/edge-headroom/m14 [--protocol cs] [--markdown table.md]

The model (a card without the edge filter) is run on every pair as ``benchmarks/edge_filter_sweep.py``
runs it and the maps are cached there (one .npz per pair; a cache made by the sweep before it kept the
right band is refilled). Each map gets the accurate tier's edge filter
(:func:`~cade_cli.matching.edges.snap_to_edges`), then, at every pixel whose ``radius`` window spans
more than :data:`JUMP` px of disparity (a depth edge of the map), three candidates are put side by
side: the pixel's own value, the window's lowest (the farther surface) and its highest (the nearer).
Rows, scored on all, non-occluded, depth-edge and occluded pixels (mean over pairs):

- ``as shipped``: the filtered map;
- ``oracle, radius R``: each candidate pixel given the candidate nearest the ground truth, an upper
  bound on any step that only re-assigns a pixel to one of the surfaces around it (it uses the
  ground truth; it is not a matcher);
- ``local pick``: the candidate whose 7 × 7 window matches best between the two bands (zero-mean
  normalised cross-correlation, each window pixel weighted by its grey-level likeness to the centre in
  the left band, as adaptive-support matchers weigh them), the own value kept unless another scores
  :data:`PICK_MARGIN` higher: what the bands alone say;
- ``consistency pick`` (with ``--mirrored``): the candidate the right view's map agrees with best
  (``|D_right(x − c) − c|``, the left–right check), the own value kept unless another agrees by
  :data:`CONSISTENCY_MARGIN` px more. The right view's map is the same model's on the mirrored pair
  (the right band flipped left to right as the left, the left band flipped as the right), cached
  beside the map.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from cade_cli.data.catalogue import get_dataset
from cade_cli.evaluation.metrics import score
from cade_cli.evaluation.regions import region_masks
from cade_cli.matching import densify, get_matcher
from cade_cli.matching.edges import guide_band, snap_to_edges

sys.path.insert(0, str(Path(__file__).resolve().parent))
from edge_filter_sweep import REGIONS, cache_maps, report, table  # noqa: E402

JUMP = 2.0
"""Px: a window whose disparities span more than this holds a depth edge (the benchmark's edge jump)."""
PICK_MARGIN = 0.05
"""How much higher (in correlation) another candidate must score than the own value to replace it."""
CONSISTENCY_MARGIN = 1.0
"""Px by which another candidate must agree better with the right view's map than the own value."""
WINDOW = 3
"""Half-side of the local pick's correlation window, px."""
LIKENESS = 10.0
"""Grey levels (of 255) over which a window pixel's weight falls by 1/e in the local pick."""


def candidates(disparity: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows and columns of the pixels whose window spans more than :data:`JUMP` px, and their (N, 3)
    candidates: own value, the window's lowest, its highest."""
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    low, high = cv2.erode(disparity, kernel), cv2.dilate(disparity, kernel)
    rows, columns = np.nonzero(high - low > JUMP)
    return rows, columns, np.stack([disparity[rows, columns], low[rows, columns], high[rows, columns]], 1)


def assign(disparity: np.ndarray, rows: np.ndarray, columns: np.ndarray, options: np.ndarray,
           pick: np.ndarray) -> np.ndarray:
    """A copy of ``disparity`` with each (row, column) given its candidate ``options[i, pick[i]]``."""
    out = disparity.copy()
    out[rows, columns] = options[np.arange(len(pick)), pick]
    return out


def oracle(disparity: np.ndarray, gt: np.ndarray, radius: int) -> np.ndarray:
    """``disparity`` with each edge pixel given the candidate nearest ``gt`` (kept where GT is unknown)."""
    rows, columns, options = candidates(disparity, radius)
    error = np.abs(options - gt[rows, columns][:, None])
    pick = np.where(np.isfinite(error[:, 0]), np.argmin(np.nan_to_num(error, nan=np.inf), axis=1), 0)
    return assign(disparity, rows, columns, options, pick)


def window_correlation(left: np.ndarray, right: np.ndarray, guide: np.ndarray, rows: np.ndarray,
                       columns: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """(N,) weighted zero-mean normalised cross-correlation of ``left``'s window at each (row, column)
    and ``right``'s at column − disparity (one disparity over the window, linear interpolation), each
    window pixel weighted by its likeness to the centre in ``guide`` (the left band on 0–255)."""
    height, width = left.shape
    offsets = np.arange(-WINDOW, WINDOW + 1)
    dy, dx = (grid.ravel() for grid in np.meshgrid(offsets, offsets, indexing="ij"))
    y = np.clip(rows[:, None] + dy, 0, height - 1)
    x = np.clip(columns[:, None] + dx, 0, width - 1)
    ours = left[y, x]
    weight = np.exp(-np.abs(guide[y, x] - guide[rows, columns][:, None]) / LIKENESS)
    source = x - disparity[:, None]
    first = np.floor(source).astype(np.int64)
    weight = weight * ((first >= 0) & (first + 1 < width))
    first = np.clip(first, 0, width - 2)
    fraction = source - first
    theirs = right[y, first] * (1 - fraction) + right[y, first + 1] * fraction
    total = weight.sum(1, keepdims=True) + 1e-6
    ours = ours - (weight * ours).sum(1, keepdims=True) / total
    theirs = theirs - (weight * theirs).sum(1, keepdims=True) / total
    return (weight * ours * theirs).sum(1) / np.sqrt((weight * ours**2).sum(1) * (weight * theirs**2).sum(1) + 1e-3)


def stretched(band: np.ndarray) -> np.ndarray:
    """``band`` as float32 scaled so that its 0.5th to 99.5th percentiles span 255 (the correlation's
    small constant is then small against any band's variance, whatever its units)."""
    band = np.asarray(band, np.float32)
    low, high = np.percentile(band, [0.5, 99.5])
    return band * np.float32(255.0 / max(float(high - low), 1e-6))


def local_pick(disparity: np.ndarray, left: np.ndarray, right: np.ndarray, radius: int) -> np.ndarray:
    """``disparity`` with each edge pixel given the candidate the bands match best at (module docstring)."""
    rows, columns, options = candidates(disparity, radius)
    left, right = (stretched(band) for band in (left, right))
    guide = guide_band(left).astype(np.float32)
    match = np.stack([window_correlation(left, right, guide, rows, columns, options[:, k]) for k in range(3)], 1)
    match[:, 0] += PICK_MARGIN
    pick = np.argmax(match, axis=1)
    return assign(disparity, rows, columns, options, pick)


def consistency_pick(disparity: np.ndarray, right_view: np.ndarray, radius: int) -> np.ndarray:
    """``disparity`` with each edge pixel given the candidate the right view's map agrees with best."""
    rows, columns, options = candidates(disparity, radius)
    target = np.round(columns[:, None] - options).astype(np.int64)
    disagreement = np.abs(right_view[rows[:, None], np.clip(target, 0, disparity.shape[1] - 1)] - options)
    disagreement = np.where(target < 0, np.inf, disagreement)
    disagreement[:, 0] -= CONSISTENCY_MARGIN
    pick = np.argmin(np.nan_to_num(disagreement, nan=np.inf), axis=1)
    return assign(disparity, rows, columns, options, pick)


def right_view_map(path: Path, matcher, max_disp: int) -> np.ndarray:
    """``matcher``'s (filled) map of the right view of ``path``'s pair, from the mirrored pair; cached as
    ``<pair>.right-view.npy`` beside it."""
    cached = path.with_suffix(".right-view.npy")
    if cached.exists():
        return np.load(cached)
    pair = np.load(path)
    result = matcher(np.ascontiguousarray(pair["right"][:, ::-1]), np.ascontiguousarray(pair["left"][:, ::-1]),
                     max_disp=max_disp, min_disp=0, preprocess="cade")
    right_view = np.ascontiguousarray(densify(result.disparity, result.valid)[:, ::-1])
    np.save(cached, right_view)
    return right_view


def headroom(files: list[Path], radii: list[int], *, mirrored: dict | None = None) -> tuple[dict, dict]:
    """The rows' (setting, region) -> (mean EPE, mean BMP3) over ``files``, and the settings' names;
    ``mirrored`` maps each file to its right view's map (adds the consistency rows)."""
    names = {"as shipped (edge filter)": ("shipped", 0), **{f"oracle, radius {r}": ("oracle", r) for r in radii},
             f"local pick, radius {max(radii)}": ("local", max(radii))}
    if mirrored is not None:
        names.update({f"consistency pick, radius {r}": ("consistency", r) for r in radii})
    scores: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for path in files:
        pair = np.load(path)
        gt, nonocc = pair["gt"], pair["nonocc"]
        regions = region_masks(gt, nonocc=nonocc if nonocc.size else None)
        shipped = snap_to_edges(pair["disparity"], pair["left"])
        for name, (kind, radius) in names.items():
            if kind == "shipped":
                disparity = shipped
            elif kind == "oracle":
                disparity = oracle(shipped, gt, radius)
            elif kind == "local":
                disparity = local_pick(shipped, pair["left"], pair["right"], radius)
            else:
                disparity = consistency_pick(shipped, mirrored[path], radius)
            scored = score(disparity, gt, **regions)
            for region in ("all", *regions):
                scores.setdefault((name, region), []).append((scored[f"epe_{region}"], scored[f"bad3_{region}"]))
    return {key: tuple(np.mean(values, axis=0)) for key, values in scores.items()}, names


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    parser.add_argument("--model", default="cade-v13-accurate", help="a card without the edge filter")
    parser.add_argument("--protocol", default="cs")
    parser.add_argument("--radii", default="2,4", help="comma-separated window half-sides, px")
    parser.add_argument("--cache", type=Path, required=True, help="folder for the cached maps (reused)")
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    parser.add_argument("--mirrored", action="store_true",
                        help="add the consistency rows (runs the model once more per pair, on the mirrored pair)")
    arguments = parser.parse_args(argv)
    radii = [int(value) for value in arguments.radii.split(",")]
    files = cache_maps(arguments.dataset, arguments.data_dir, arguments.model, arguments.protocol, arguments.cache)
    mirrored = None
    if arguments.mirrored:
        scenes = {scene.name.replace("/", "_"): scene.max_disp
                  for scene in get_dataset(arguments.dataset)(arguments.data_dir)}
        matcher = get_matcher("cade", model=arguments.model)
        mirrored = {path: right_view_map(path, matcher, scenes[path.stem.rsplit("_", 1)[0]]) for path in files}
    scores, names = headroom(files, radii, mirrored=mirrored)
    text = (f"{arguments.dataset}, {arguments.protocol}, {arguments.model}'s maps with the edge filter, {len(files)} "
            f"pairs (EPE px / BMP3 %, mean over pairs; regions: {', '.join(REGIONS)})\n\n" + table(scores, names))
    return report(text, arguments.markdown)


if __name__ == "__main__":
    sys.exit(main())
