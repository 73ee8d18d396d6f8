"""CPU cost of a training step, per sample, for each network design (Accuracy III's budget:
the new generation's step at least 2x cheaper per sample than today's).

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/train_step.py --textures ../shared/data/textures

Each design gets the same generated batches (seed 0); the first ``--warmup`` steps are not
timed. Reported: data (rendering the batch), compute (forward, loss, backward, Adam) and
their sum, in seconds per step and per sample. Pause any training run while timing.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, replace

import torch

from cade_cli.train.batches import GeneratedBatches
from cade_cli.train.config import TrainConfig
from cade_cli.train.fit import loss_terms
from cade_cli.train.model import parameter_count
from cade_cli.train.networks import network_of

DESIGNS = {
    "cadenet (cade-v6/v7: 3D, 128 levels)": {"architecture": "cadenet", "levels": 128},
    "cadenet (3D, 192 levels: the campaign's control)": {"architecture": "cadenet", "levels": 192},
    "cadenet2d (192 levels)": {"architecture": "cadenet2d", "levels": 192},
    "cadenet2d + per-disparity aggregation (the campaign)": {"architecture": "cadenet2d", "levels": 192,
                                                              "slice_channels": 4},
    "cadenet2d f16 w32 h8, 128 levels, no per-disparity stage": {
        "architecture": "cadenet2d", "levels": 128, "features2d": 16, "width2d": 32, "half_channels": 8},
    "cadenet2d f16 w32 h8, 128 levels (session 20's fast design)": {
        "architecture": "cadenet2d", "levels": 128, "features2d": 16, "width2d": 32, "half_channels": 8,
        "slice_channels": 4},
    "cadenet2d f16 w32 h8, 192 levels (the fast design from session 21)": {
        "architecture": "cadenet2d", "levels": 192, "features2d": 16, "width2d": 32, "half_channels": 8,
        "slice_channels": 4},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--textures", action="append", default=[])
    parser.add_argument("--batch", type=int, default=4)
    parser.add_argument("--height", type=int, default=192)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--only", nargs="*", help="the designs to time (names from the table; default all)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"batch {args.batch} x {args.height}x{args.width}, {args.threads} threads, {args.steps} timed steps")
    print("| design | parameters | data s/step | compute s/step | s/sample |")
    print("|---|---:|---:|---:|---:|")
    for name, design in DESIGNS.items():
        if args.only and name not in args.only:
            continue
        config = TrainConfig(out="", textures=args.textures, batch=args.batch, height=args.height, width=args.width,
                             steps=args.warmup + args.steps)
        config = replace(config, **design)
        torch.manual_seed(0)
        net = network_of(asdict(config))
        optimizer = torch.optim.Adam(net.parameters(), lr=1e-4)
        batches = GeneratedBatches(config)
        data_s = compute_s = 0.0
        for step in range(args.warmup + args.steps):
            started = time.perf_counter()
            batch = batches[step]
            rendered = time.perf_counter()
            out = net(batch["left"], batch["right"])
            loss, _ = loss_terms(out, batch["disparity"], config.levels, config.coarse_weight)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            if step >= args.warmup:
                data_s += rendered - started
                compute_s += time.perf_counter() - rendered
        data_s, compute_s = data_s / args.steps, compute_s / args.steps
        print(f"| {name} | {parameter_count(net):,} | {data_s:.3f} | {compute_s:.3f} | "
              f"{(data_s + compute_s) / args.batch:.3f} |", flush=True)


if __name__ == "__main__":
    main()
