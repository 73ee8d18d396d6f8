"""Checks of the self-supervised lever's data and loss (issue 38 item 5, models/README.md "Session 26").

``rectified CACHE``: each cached rectified pair (cade_cli.train.selfsup_pairs) checked by a classical
matcher: 40 textured 31x31 patches of the left view's gradient image found in the right's by normalised
correlation in a 2D window; the median vertical offset, the share within 1 px, the share of d >= 0 and
the 10/50/90th percentiles of d (the parallax must be horizontal and positive).

``loss CACHE CHECKPOINT...``: the self-supervised loss (cade_cli.train.selfsup_loss) of 16 fixed crops
(192x320, seed 123) for constant disparities and for each checkpoint's network (does the loss tell the
network's answer from a wrong one; did a run lower it). Needs the train extra (torch).

    .venv/bin/python benchmarks/selfsup_checks.py rectified runs/lever-selfsup/selfsup-pairs
    .venv/bin/python benchmarks/selfsup_checks.py loss runs/lever-selfsup/selfsup-pairs runs/lever-selfsup/last.pt
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np


def rectified(cache: Path) -> None:
    from cade_cli.pair_features import gradient_band

    rng = np.random.default_rng(0)
    for path in sorted(cache.glob("*--*.npz")):
        data = np.load(path)
        left, right = data["left"], data["right"]
        gl, gr = (gradient_band(np.nan_to_num(view)).astype(np.float32) for view in (left, right))
        seen = np.isfinite(left) & np.isfinite(right)
        rows, columns = left.shape
        half, reach_x, reach_y = 15, int(data["high"]) + 12, 4
        found = []
        for _ in range(400):
            y = int(rng.integers(half + reach_y, rows - half - reach_y))
            x = int(rng.integers(half + reach_x, columns - half - 12))
            if not seen[y - half - reach_y:y + half + reach_y + 1, x - half - reach_x:x + half + 13].all():
                continue
            template = gl[y - half:y + half + 1, x - half:x + half + 1]
            if template.std() < np.percentile(gl, 70) * 0.3:
                continue
            window = gr[y - half - reach_y:y + half + reach_y + 1, x - half - reach_x:x + half + 13]
            scores = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
            row, column = np.unravel_index(int(np.argmax(scores)), scores.shape)
            if scores[row, column] >= 0.6:
                found.append((row - reach_y, reach_x - column))
            if len(found) >= 40:
                break
        if not found:
            print(f"{path.name}: no patches")
            continue
        dy, d = np.array(found).T
        print(f"{path.name:60s} n={len(found):2d} dy median {np.median(dy):+.1f} |dy|<=1 {np.mean(np.abs(dy) <= 1):.2f} "
              f"d>=0 {np.mean(d >= 0):.2f} d p10/50/90 {np.percentile(d, 10):.0f}/{np.median(d):.0f}/"
              f"{np.percentile(d, 90):.0f}")


def loss(cache: Path, checkpoints: list[str]) -> None:
    import torch

    from cade_cli.train.config import TrainConfig
    from cade_cli.train.networks import network_of
    from cade_cli.train.selfsup_loss import selfsup_loss
    from cade_cli.train.selfsup_pairs import SelfSupPairs

    torch.set_num_threads(1)
    pairs = SelfSupPairs(cache)
    rng = np.random.default_rng(123)
    crops = [pairs.draw(rng, 192, 320, "cade-floor") for _ in range(16)]
    left, right = (torch.from_numpy(np.stack([getattr(c, side) for c in crops]))[:, None] for side in ("left", "right"))
    guides = torch.from_numpy(np.stack([c.guides for c in crops]))
    chosen = torch.ones(len(crops), dtype=torch.bool)
    for d in (2.0, 5.0, 10.0):
        print(f"constant d={d:g}: {selfsup_loss(torch.full((len(crops), 1, 192, 320), d), guides, chosen).item():.4f}")
    for path in checkpoints:
        state = torch.load(path, weights_only=False, map_location="cpu")
        net = network_of({**vars(TrainConfig(out="unused", textures=[])), **state["config"]})
        net.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state["model"].items()})
        net.eval()
        with torch.no_grad():
            values = [selfsup_loss(net(left[i:i + 4], right[i:i + 4])["disparity"], guides[i:i + 4],
                                   chosen[i:i + 4]).item() for i in range(0, len(crops), 4)]
        print(f"{path}: {np.mean(values):.4f}")


def main(argv: list[str]) -> int:
    if len(argv) >= 2 and argv[0] == "rectified":
        rectified(Path(argv[1]))
    elif len(argv) >= 3 and argv[0] == "loss":
        loss(Path(argv[1]), argv[2:])
    else:
        print(__doc__, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
