"""A probe: can a small learned head, given the two bands and a finished map, tell which of two nearby
surfaces an edge pixel belongs to? (Accuracy V, docs/research/refinement.md, 2026-12-07.)

    .venv/bin/python -m cade_cli.train.edge_assignment --train DIR --evaluate NAME=DIR [--evaluate ...] \
        [--steps 3000] [--seed 0]

Each DIR holds one .npz per pair as ``benchmarks/edge_headroom.py --cache DIR`` writes them (the bands, the
model's filled map before the edge filter, the ground truth, the non-occluded mask; ``--dataset middeval3``
caches the real training scenes). Every map gets the accurate tier's edge filter first. At each pixel whose
window of radius :data:`RADIUS` spans more than :data:`JUMP` px, the candidates are the pixel's own value, the
window's lowest and its highest (as the headroom's oracle has them). The head sees the color-agnostic bands
(as the network does) through a shared feature extractor, the right band's features fetched at each candidate
(linear in x), their product and absolute difference, and where the own value lies between the two surfaces;
it is fitted on the ``--train`` pairs' crops with the ground truth's decisive cases as labels (keep the own
value where it is within 1 px; take another candidate where the own value is off by more than 3 px and that one
is within 1 px). Printed per ``--evaluate`` set: the filtered map, the oracle, and the head's picks at three
margins (another candidate replaces the own value only where its probability beats the own value's by the
margin), EPE / BMP3 on all pixels and BMP3 on the non-occluded and depth-edge ones, the mean over pairs.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cade_cli.evaluation.regions import region_masks
from cade_cli.matching.edges import snap_to_edges
from cade_cli.spectral import CONTRAST_FLOOR, color_agnostic
from cade_cli.train.probe_table import HEADER, RegionTable

RADIUS = 4
"""Half-side of the window whose lowest and highest values are the other candidates, px."""
JUMP = 2.0
"""Px: a window spanning more than this holds a depth edge (the headroom's and the benchmark's jump)."""
MARGINS = (0.0, 0.3, 0.6)
CROP = 96
BATCH = 8
RENDERED_SEED = 1000
"""``--rendered``'s pairs come from the streams (this + ``--seed``, i): apart from the chooser's rendered pairs
(``chooser --synthetic``, seed 0)."""


def pair(path: Path) -> dict[str, np.ndarray]:
    """One cached pair: bands transformed, the map filtered, its candidates, ground truth and masks."""
    cached = np.load(path)
    disparity = snap_to_edges(cached["disparity"], cached["left"])
    kernel = np.ones((2 * RADIUS + 1,) * 2, np.uint8)
    low, high = cv2.erode(disparity, kernel), cv2.dilate(disparity, kernel)
    return {"left": color_agnostic(cached["left"], floor=CONTRAST_FLOOR),
            "right": color_agnostic(cached["right"], floor=CONTRAST_FLOOR),
            "own": disparity, "low": low, "high": high, "edge": high - low > JUMP,
            "gt": cached["gt"].astype(np.float32), "nonocc": cached["nonocc"]}


def options(x: dict[str, np.ndarray]) -> np.ndarray:
    """(3, H, W): each pixel's candidates, its own value, the window's lowest and its highest."""
    return np.stack([x["own"], x["low"], x["high"]])


def errors(x: dict[str, np.ndarray]) -> np.ndarray:
    """(3, H, W): each candidate's distance from the ground truth, inf where the truth is unknown."""
    error = np.abs(options(x) - x["gt"][None])
    return np.where(np.isfinite(error), error, np.inf)


def labels(x: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) candidate index (0 own, 1 lowest, 2 highest) and (H, W) weight: 1 at the decisive edge
    pixels (the own value within 1 px, or off by more than 3 px with another candidate within 1 px)."""
    error = errors(x)
    known = np.isfinite(x["gt"]) & x["edge"]
    keep = error[0] < 1.0
    switch = (error[0] > 3.0) & (error.min(0) < 1.0)
    return np.where(keep, 0, np.argmin(error, 0)), (known & (keep | switch)).astype(np.float32)


def fetch(features: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
    """``features`` (B, C, H, W) at x - ``disparity`` (B, 1, H, W), linear in x, clamped to the image."""
    batch, channels, height, width = features.shape
    x = (torch.arange(width, dtype=features.dtype).view(1, 1, 1, width) - disparity).clamp(0, width - 1)
    x0 = x.floor()
    fraction = x - x0
    index0 = x0.long().expand(batch, channels, height, width)
    index1 = (index0 + 1).clamp(max=width - 1)
    return torch.gather(features, 3, index0) * (1 - fraction) + torch.gather(features, 3, index1) * fraction


class AssignmentHead(nn.Module):
    """Shared 3-layer features of each band, the right band's fetched at the three candidates, then five
    convolutions (dilations 1, 2, 4, 8, 1) to three logits per pixel."""

    def __init__(self, features: int = 16, width: int = 32) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(1, features, 3, padding=1), nn.ReLU(), nn.Conv2d(features, features, 3, padding=1), nn.ReLU(),
            nn.Conv2d(features, features, 3, padding=1))
        layers: list[nn.Module] = [nn.Conv2d(4 * features + 9, width, 3, padding=1), nn.ReLU()]
        for dilation in (2, 4, 8, 1):
            layers += [nn.Conv2d(width, width, 3, padding=dilation, dilation=dilation), nn.ReLU()]
        self.head = nn.Sequential(*layers, nn.Conv2d(width, 3, 1))

    def forward(self, left, right, own, low, high):  # noqa: D102 (all (B, 1, H, W))
        left_features, right_features = self.features(left), self.features(right)
        parts = [left_features]
        for candidate in (own, low, high):
            fetched = fetch(right_features, candidate)
            parts += [fetched, (left_features * fetched).mean(1, keepdim=True),
                      (left_features - fetched).abs().mean(1, keepdim=True)]
        span = (high - low).clamp(min=1e-3)
        parts += [(own - low) / span, (high - own) / span, torch.log1p(span)]
        return self.head(torch.cat(parts, 1))


def inputs(x: dict[str, np.ndarray], window=(slice(None), slice(None))) -> list[torch.Tensor]:
    return [torch.from_numpy(np.ascontiguousarray(x[key][window]))[None, None]
            for key in ("left", "right", "own", "low", "high")]


def fit(model: AssignmentHead, train: list[dict], steps: int, rng: np.random.Generator) -> None:
    """Adam, one-cycle learning rate to 2e-3, :data:`BATCH` crops of :data:`CROP` px centred on decisive
    pixels, the weighted cross-entropy of :func:`labels`."""
    targets = [labels(x) for x in train]
    usable = [i for i, (_, weight) in enumerate(targets) if weight.any() and min(train[i]["own"].shape) >= CROP]
    optimiser = torch.optim.Adam(model.parameters(), 1e-3)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, 2e-3, total_steps=steps)
    start = time.time()
    for step in range(steps):
        crops: list[list[torch.Tensor]] = [[] for _ in range(7)]
        for _ in range(BATCH):
            i = usable[rng.integers(len(usable))]
            label, weight = targets[i]
            height, width = weight.shape
            rows, columns = np.nonzero(weight)
            j = rng.integers(len(rows))
            top = int(np.clip(rows[j] - CROP // 2, 0, height - CROP))
            left = int(np.clip(columns[j] - CROP // 2, 0, width - CROP))
            window = (slice(top, top + CROP), slice(left, left + CROP))
            for k, tensor in enumerate(inputs(train[i], window)):
                crops[k].append(tensor)
            crops[5].append(torch.from_numpy(label[window])[None])
            crops[6].append(torch.from_numpy(weight[window])[None])
        label_batch, weight_batch = torch.cat(crops[5]), torch.cat(crops[6])
        logits = model(*(torch.cat(c) for c in crops[:5]))
        loss = (F.cross_entropy(logits, label_batch, reduction="none") * weight_batch).sum() / weight_batch.sum()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        schedule.step()
        if step % 500 == 0 or step == steps - 1:
            print(f"step {step} loss {loss.item():.3f} {time.time() - start:.0f} s", flush=True)


def pick(model: AssignmentHead, x: dict[str, np.ndarray], margin: float) -> np.ndarray:
    """The map with each edge pixel given the head's candidate, where it beats the own value by ``margin``."""
    with torch.no_grad():
        probability = torch.softmax(model(*inputs(x))[0], 0).numpy()
    choice = np.where(probability.max(0) - probability[0] > margin, np.argmax(probability, 0), 0)
    taken = np.take_along_axis(options(x), choice[None], 0)[0]
    return np.where(x["edge"], taken, x["own"])


def evaluate(model: AssignmentHead, name: str, pairs: list[dict]) -> dict[str, np.ndarray]:
    """Row name -> (EPE all, BMP3 all, BMP3 non-occluded, BMP3 edge), the mean over ``pairs``; printed."""
    table = RegionTable(name)
    for x in pairs:
        regions = region_masks(x["gt"], nonocc=x["nonocc"] if x["nonocc"].size else None)
        oracle = np.take_along_axis(options(x), np.argmin(errors(x), 0)[None], 0)[0]
        maps = {"filtered map": x["own"], "oracle": np.where(x["edge"], oracle, x["own"])}
        maps.update({f"head, margin {m}": pick(model, x, m) for m in MARGINS})
        for row, disparity in maps.items():
            table.add(row, disparity, x["gt"], regions)
    return table.print()


def cache_rendered(out: Path, *, model: str, count: int, seed: int, textures: Path,
                   real_dir: Path | None = None) -> list[Path]:
    """``count`` rendered pairs (:func:`~cade_cli.train.chooser_synthetic.cache_rendered`: the training campaign's
    scenes, two of the eleven bands) in ``out`` as ``benchmarks/edge_headroom.py --cache`` stores a real pair:
    the bands, ``model``'s filled map (a card without the edge filter), the truth, no non-occluded mask. Pair ``i``
    comes from its own stream (``seed``, ``i``); existing files are kept."""
    from cade_cli.matching import densify, get_matcher
    from cade_cli.model_card import read_card
    from cade_cli.train import chooser_synthetic

    if read_card(model).edge_filter != "none":  # pair() filters the map: it must come unfiltered, as a real pair's
        raise ValueError(f"{model} already filters its map; give the card without the filter")
    matcher = get_matcher("cade", model=model)

    def store(left, right, gt, span):
        result = matcher(left, right, max_disp=span, min_disp=0, preprocess="cade")
        return {"left": left, "right": right, "disparity": densify(result.disparity, result.valid), "gt": gt,
                "nonocc": np.zeros(0, bool)}

    return chooser_synthetic.cache_rendered(out, "rendered", store, count=count, seed=seed, textures=textures,
                                            real_dir=real_dir)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", type=Path, required=True, help="folder of cached training pairs (.npz)")
    parser.add_argument("--evaluate", action="append", default=[], metavar="NAME=DIR")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rendered", type=int, default=0, metavar="N",
                        help="also fit on N rendered pairs (cached in --rendered-cache, made with --model)")
    parser.add_argument("--rendered-cache", type=Path)
    parser.add_argument("--textures", type=Path, default=Path("../shared/data/textures"))
    parser.add_argument("--real-dir", type=Path, default=Path("../shared/data/train-real"))
    parser.add_argument("--model", default="cade-v13-accurate", help="the card whose maps the caches hold")
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    files = sorted(args.train.glob("*.npz"))
    if args.rendered:
        if args.rendered_cache is None:
            parser.error("--rendered needs --rendered-cache")
        try:
            files += cache_rendered(args.rendered_cache, model=args.model, count=args.rendered,
                                    seed=RENDERED_SEED + args.seed, textures=args.textures, real_dir=args.real_dir)
        except ValueError as error:
            parser.error(str(error))
    train = [pair(p) for p in files]
    if not train:
        parser.error(f"no .npz pairs in {args.train}")
    model = AssignmentHead()
    fit(model, train, args.steps, np.random.default_rng(args.seed))
    print(HEADER)
    for spec in args.evaluate:
        name, _, folder = spec.partition("=")
        evaluate(model, name, [pair(p) for p in sorted(Path(folder).glob("*.npz"))])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
