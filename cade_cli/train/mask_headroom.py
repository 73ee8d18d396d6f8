"""How much a better convex mask could give: is the right surface among the convex upsampler's nine candidates?
(Accuracy V, docs/research/refinement.md, 2026-12-07, later.)

    .venv/bin/python -m cade_cli.train.mask_headroom CHECKPOINT SET [SET ...] [--data-dir DIR]

CHECKPOINT is a cadenet-iterative run's checkpoint (any form, e.g. ``init.pt`` of
runs/campaign-2026-12-07-extended: the first campaign's last weights). A SET is a dataset of ``cade benchmark``
(``middlebury14``, ``middlebury05``, ...: every scene of it under ``--data-dir``, each of the six cross-spectral
tasks, as ``--protocol cs`` makes them), or NAME=DIR with DIR a folder of one .npz per pair as
``benchmarks/edge_headroom.py --cache DIR`` writes them (raw bands, ground truth, non-occluded mask). The network
alone runs on each pair (its input transform, padded as the runtime pads). Its last stage makes each
full-resolution pixel a convex combination of the nine 1/4-resolution estimates around its cell. Rows (mean over
pairs, EPE px / BMP3 % on all pixels, BMP3 on the non-occluded and depth-edge ones):

- ``network``: the network's map (the soft convex combination);
- ``hard pick``: each pixel given the one candidate its mask weighs most;
- ``oracle``: each pixel given the candidate nearest the ground truth (an upper bound on any mask: it uses the
  truth). Where the oracle is far below the network, the 1/4 estimate holds the right surface next to the pixel
  and the mask does not pick it.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from cade_cli.data.catalogue import get_dataset
from cade_cli.evaluation.protocols import get_protocol
from cade_cli.evaluation.regions import region_masks
from cade_cli.matching.network import pad_to_divisor
from cade_cli.spectral import network_input
from cade_cli.train.net_blocks import convex_weights, neighbours3x3
from cade_cli.train.networks import network_of
from cade_cli.train.probe_table import HEADER, RegionTable

ROWS = ("network", "hard pick", "oracle")


def candidates(net: torch.nn.Module, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The network's (H, W) map of the network-input bands ``left``, ``right``, the (9, H, W) candidates of its
    convex upsampling (full-resolution px) and the (H, W) index of the one its mask weighs most."""
    height, width = left.shape
    padded = [torch.from_numpy(pad_to_divisor(band, net.divisor)[0])[None, None] for band in (left, right)]
    with torch.no_grad():
        out = net(*padded)
    disparity = out["disparity"][0, 0, :height, :width].numpy()
    factor = 4  # the x4 mask from 1/4: the campaign's design (steps2 0)
    options = factor * neighbours3x3(out["quarter"])  # (1, 9, h, w)
    options = options.repeat_interleave(factor, 2).repeat_interleave(factor, 3)[0, :, :height, :width].numpy()
    heaviest = convex_weights(out["mask"], factor).argmax(1).float()  # (1, factor², h, w)
    heaviest = F.pixel_shuffle(heaviest, factor)[0, 0, :height, :width].numpy().astype(np.int64)
    return disparity, options, heaviest


def maps(disparity: np.ndarray, options: np.ndarray, heaviest: np.ndarray, gt: np.ndarray) -> dict[str, np.ndarray]:
    """The three rows' maps of one pair (:data:`ROWS`)."""
    error = np.abs(options - gt[None])
    nearest = np.argmin(np.where(np.isfinite(error), error, np.inf), 0)
    return {"network": disparity,
            "hard pick": np.take_along_axis(options, heaviest[None], 0)[0],
            "oracle": np.take_along_axis(options, nearest[None], 0)[0]}


def pairs(spec: str, data_dir: Path) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]:
    """(left band, right band, ground truth, non-occluded mask or None) of each pair of one SET argument."""
    name, _, folder = spec.partition("=")
    if folder:
        for path in sorted(Path(folder).glob("*.npz")):
            pair = np.load(path)
            yield pair["left"], pair["right"], pair["gt"], pair["nonocc"] if pair["nonocc"].size else None
        return
    for scene in get_dataset(name)(data_dir):
        for task in get_protocol("cs").tasks:
            yield *task.bands(scene.left, scene.right), scene.disparity, scene.nonocc


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("sets", nargs="+", metavar="SET", help="a dataset name, or NAME=DIR of cached pairs")
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data"), help="where the datasets lie")
    args = parser.parse_args(argv)
    state = torch.load(args.checkpoint, map_location="cpu", weights_only=False)
    if state["config"].get("architecture") != "cadenet-iterative":
        parser.error(f"{args.checkpoint} is not a cadenet-iterative run's checkpoint")
    net = network_of(state["config"])
    net.load_state_dict(state["model"])
    net.eval()
    kind = state["config"].get("network_input", "cade")
    print(HEADER)
    for spec in args.sets:
        table = RegionTable(spec.partition("=")[0])
        for left, right, gt, nonocc in pairs(spec, args.data_dir):
            gt = gt.astype(np.float32)
            regions = region_masks(gt, nonocc=nonocc)
            found = candidates(net, network_input(left, kind), network_input(right, kind))
            for row, disparity in maps(*found, gt).items():
                table.add(row, disparity, gt, regions)
        table.print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
