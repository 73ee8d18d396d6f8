"""Two rewrites of cadenet-iterative's 1/4 re-matching (the correlation volume and hat_lookup), tried for speed on
2026-12-06 and not kept: both give the same network (same weights, same output within float error), and neither is
faster in onnxruntime on the CPU than the shipped form: stack within the runs' spread, matmul slower
(docs/research/network-design.md, 2026-12-06).

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/results/2026-12-06-iterative-twins/lookup_variants.py --variant stack
    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/results/2026-12-06-iterative-twins/lookup_variants.py --variant matmul

``stack``: the volume built group-major (torch.stack over the disparity axis) so that the lookup needs no transpose;
``matmul``: each update's reads as one batched MatMul per pixel, (groups x levels) @ (levels x offsets), the volume
transposed once. Untrained weights nudged off zero (so that the updates act), random bands at 720x496, 2 threads,
the two graphs timed in alternating rounds; run it on a quiet CPU.
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch
import torch.nn.functional as F

from cade_cli.train import export, net_iterative
from cade_cli.train.net2d import normalised_correlation


def unit_groups(x: torch.Tensor, groups: int) -> torch.Tensor:
    batch, channels, height, width = x.shape
    grouped = x.view(batch, groups, channels // groups, height, width)
    return (grouped / (grouped.pow(2).sum(dim=2, keepdim=True) + 1e-6).sqrt()).view(batch, channels, height, width)


def rematched_stack(self, disparity, left, right, update, steps, factor):
    levels, groups = self.levels // factor, self.groups
    batch, channels, height, width = left.shape
    unit_left, padded = unit_groups(left, groups), F.pad(unit_groups(right, groups), (levels - 1, 0))
    slices = [(unit_left * padded[..., levels - 1 - d:levels - 1 - d + width]).view(batch, groups, channels // groups,
                                                                               height, width).sum(dim=2)
              for d in range(levels)]
    grouped = torch.stack(slices, dim=2).reshape(batch, groups * levels, height, width)
    reach = max(abs(offset) for offset in self.offsets)
    shifts = torch.arange(-reach, levels + reach, dtype=grouped.dtype).view(1, -1, 1, 1)
    for _ in range(steps):
        hat = F.relu(1.0 - (shifts - disparity).abs())
        reads = []
        for offset in self.offsets:
            weight = hat[:, reach - offset:reach - offset + levels]
            reads.extend((grouped[:, g * levels:(g + 1) * levels] * weight).sum(dim=1, keepdim=True)
                         for g in range(groups))
        disparity = disparity + update(torch.cat(reads, dim=1), left, disparity, net_iterative.DISPARITY_SCALE / factor)
    return disparity


def rematched_matmul(self, disparity, left, right, update, steps, factor):
    levels, groups, count = self.levels // factor, self.groups, len(self.offsets)
    volume = normalised_correlation(left, right, levels, groups)
    batch, _, height, width = volume.shape
    reach = max(abs(offset) for offset in self.offsets)
    pixels_first = volume.view(batch, levels, groups, height * width).permute(0, 3, 2, 1)  # (B, hw, groups, levels)
    shifts = torch.arange(-reach, levels + reach, dtype=volume.dtype).view(1, -1, 1, 1)
    for _ in range(steps):
        hat = F.relu(1.0 - (shifts - disparity).abs())
        weights = torch.cat([hat[:, reach - offset:reach - offset + levels] for offset in self.offsets], dim=1)
        weights = weights.view(batch, count, levels, height * width).permute(0, 3, 2, 1)  # (B, hw, levels, K)
        reads = torch.matmul(pixels_first, weights).permute(0, 3, 2, 1).reshape(batch, count * groups, height, width)
        disparity = disparity + update(reads, left, disparity, net_iterative.DISPARITY_SCALE / factor)
    return disparity


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variant", choices=("stack", "matmul"), required=True)
    parser.add_argument("--runs", type=int, default=9)
    args = parser.parse_args()
    torch.manual_seed(0)
    net = net_iterative.CadeNetIterative(192, features=24, width=32).eval()
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.1, 0.1)
                module.running_var.uniform_(0.5, 1.5)
        for parameter in net.parameters():
            parameter.add_(0.01 * torch.randn_like(parameter))
    folder = Path(tempfile.mkdtemp())
    export.export_onnx(net, folder / "shipped.onnx")
    net_iterative.CadeNetIterative.rematched = {"stack": rematched_stack, "matmul": rematched_matmul}[args.variant]
    export.export_onnx(net, folder / "variant.onnx")
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    sessions = [ort.InferenceSession(str(folder / name), options, providers=["CPUExecutionProvider"])
                for name in ("shipped.onnx", "variant.onnx")]
    rng = np.random.default_rng(0)
    feeds = {entry.name: rng.random((1, 1, 496, 720), dtype=np.float32) for entry in sessions[0].get_inputs()}
    outputs = [session.run(None, feeds)[0] for session in sessions]
    print(f"max |shipped - {args.variant}| = {float(np.abs(outputs[0] - outputs[1]).max()):.2e} px")
    times: list[list[float]] = [[], []]
    for _ in range(args.runs):
        for session, taken in zip(sessions, times):
            started = time.perf_counter()
            session.run(None, feeds)
            taken.append(time.perf_counter() - started)
    shipped, variant = (statistics.median(taken) for taken in times)
    print(f"shipped {shipped:.3f} s, {args.variant} {variant:.3f} s a run at 720x496: ratio {variant / shipped:.2f}")


if __name__ == "__main__":
    main()
