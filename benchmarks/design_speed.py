"""Inference time of candidate CadeNet2D designs, before any is trained (Accuracy III's speed budget).

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/design_speed.py --size 720x496

Each design is built with its untrained weights (the time depends on the graph and the size,
not on the weights), exported to ONNX the way a trained one is (:func:`cade_cli.train.export.export_onnx`)
and run by onnxruntime on random bands: two untimed runs each, then ``--runs`` rounds in which
every design runs once in turn (so a drift of the machine's speed reaches all designs alike;
timing one design after another let the first one measured take up to twice the time of the
same design timed again at the end); the median of its rounds. The first design is the
reference (the campaign's, or the fast design's with ``--fast``); the ratio column is each
design's time over it. Pause any training run while timing: the seconds hold only on a quiet
CPU.

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/design_speed.py --fast --runs 15
    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/design_speed.py --bakeoff --runs 5
    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/design_speed.py --iterative --runs 9
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

# torch and the train package load in main only, so that --help answers at once; the inputs' names are read
# from the exported graphs themselves (random_feeds)

CAMPAIGN = {"architecture": "cadenet2d", "levels": 192, "slice_channels": 4}
DESIGNS = {
    "campaign (f32 w48 s4, 192 levels)": CAMPAIGN,
    "campaign, 128 levels": {**CAMPAIGN, "levels": 128},
    "w32": {**CAMPAIGN, "width2d": 32},
    "f24 w32": {**CAMPAIGN, "features2d": 24, "width2d": 32},
    "f24 w32, no slices": {**CAMPAIGN, "features2d": 24, "width2d": 32, "slice_channels": 0},
    "f24 w32, 128 levels": {**CAMPAIGN, "features2d": 24, "width2d": 32, "levels": 128},
    "f16 w24 h12, 128 levels": {**CAMPAIGN, "features2d": 16, "width2d": 24, "half_channels": 12, "levels": 128},
    "f16 w24 h12": {**CAMPAIGN, "features2d": 16, "width2d": 24, "half_channels": 12},
    "f16 w32 h12, 128 levels": {**CAMPAIGN, "features2d": 16, "width2d": 32, "half_channels": 12, "levels": 128},
    "f16 w24 h8, 128 levels, no slices": {**CAMPAIGN, "features2d": 16, "width2d": 24, "half_channels": 8,
                                          "levels": 128, "slice_channels": 0},
    "f16 w32 h8, 128 levels, no slices": {**CAMPAIGN, "features2d": 16, "width2d": 32, "half_channels": 8,
                                          "levels": 128, "slice_channels": 0},
    "f16 w32 h8, 128 levels (the fast design)": {**CAMPAIGN, "features2d": 16, "width2d": 32, "half_channels": 8,
                                                 "levels": 128},
    "f16 w32 h8, 96 levels": {**CAMPAIGN, "features2d": 16, "width2d": 32, "half_channels": 8, "levels": 96},
    "f16 w32 h8, 192 levels": {**CAMPAIGN, "features2d": 16, "width2d": 32, "half_channels": 8},
    "f24 w32 h8, 128 levels, no slices": {**CAMPAIGN, "features2d": 24, "width2d": 32, "half_channels": 8,
                                          "levels": 128, "slice_channels": 0},
    "f32 w64 (wider)": {**CAMPAIGN, "width2d": 64},
}
FAST = {**CAMPAIGN, "features2d": 16, "width2d": 32, "half_channels": 8}
FAST_DESIGNS = {
    "the fast design (f16 w32 h8, 192 levels: cade-v12, cade-v13)": FAST,
    **{f"the fast design, {levels} levels": {**FAST, "levels": levels} for levels in (128, 96, 64)},
    "the fast design, no per-disparity stage": {**FAST, "slice_channels": 0},
    "the fast design, U-Net w24": {**FAST, "width2d": 24},
    "lean: U-Net w24, h4, no per-disparity stage": {**FAST, "width2d": 24, "half_channels": 4, "slice_channels": 0},
    "lean, 96 levels": {**FAST, "width2d": 24, "half_channels": 4, "slice_channels": 0, "levels": 96},
    "leaner: f12, U-Net w16, h4, no per-disparity stage, 96 levels": {
        **FAST, "features2d": 12, "width2d": 16, "half_channels": 4, "slice_channels": 0, "levels": 96},
}
"""``--fast``: the shipped fast design against narrower searches (its weights depend on the
range, so a narrower twin is a network of its own) and smaller stages (Accuracy IV, item 3)."""
BAKEOFF = {
    "control: CadeNet2D, the fast design (cade-v13)": FAST,
    "cadenet-convex (f24 w48)": {"architecture": "cadenet-convex", "levels": 192, "features2d": 24, "width2d": 48},
    "cadenet-iterative (f24 w32)": {"architecture": "cadenet-iterative", "levels": 192, "features2d": 24,
                                    "width2d": 32},
    "cadenet-peak (f16 w32)": {"architecture": "cadenet-peak", "levels": 192, "features2d": 16, "width2d": 32},
}
"""``--bakeoff``: the Accuracy V design bake-off's designs (2026-11-28), untrained, at the flags of
their ``runs/bakeoff-2026-11-28-<design>/command.sh``, against the control."""
ITERATIVE = {"architecture": "cadenet-iterative", "levels": 192, "features2d": 24, "width2d": 32}
ITERATIVE_TWINS = {
    "control: CadeNet2D, the fast design (cade-v13)": FAST,
    "cadenet-iterative f24 w32 (the campaign's, runs/campaign-2026-12-06-iterative)": ITERATIVE,
    "cadenet-iterative f24 w32 with the mask's evidence (the longer schedule's, since 2026-12-07)":
        {**ITERATIVE, "mask_evidence": True},
    "cadenet-iterative f24 w32 with the mask's evidence and the 1/2 features' cosine at its candidates":
        {**ITERATIVE, "mask_evidence": True, "fine_evidence": True},
    "cadenet-iterative f16 w32": {**ITERATIVE, "features2d": 16},
    "cadenet-iterative f16 w24": {**ITERATIVE, "features2d": 16, "width2d": 24},
    "cadenet-iterative f16 w16": {**ITERATIVE, "features2d": 16, "width2d": 16},
    "cadenet-iterative f24 w32, 128 levels": {**ITERATIVE, "levels": 128},
    "cadenet-iterative f16 w24, 128 levels": {**ITERATIVE, "features2d": 16, "width2d": 24, "levels": 128},
}
"""``--iterative``: smaller twins of the chosen design (2026-12-06), untrained, against the shipped fast
design: which of them could be the fast tier, at or below OpenCV StereoSGBM's time (issue 51 item 5)."""


def random_feeds(session: ort.InferenceSession, rng: np.random.Generator, width: int, height: int) -> dict:
    """One random band per input of an exported network, by the graph's own input names."""
    return {node.name: rng.random((1, 1, height, width), dtype=np.float32) for node in session.get_inputs()}


def int8_twin(path: Path, width: int, height: int) -> Path:
    """A static QDQ int8 twin (the export's settings, :mod:`cade_cli.train.quantize`), calibrated
    on random bands: enough for timing, not for accuracy."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class RandomBands:
        def __init__(self):
            rng = np.random.default_rng(1)
            session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
            self.feeds = iter([random_feeds(session, rng, width, height) for _ in range(2)])

        def get_next(self):
            return next(self.feeds, None)

    prepared, target = path.with_suffix(".pre.onnx"), path.with_suffix(".int8.onnx")
    quant_pre_process(str(path), str(prepared), skip_symbolic_shape=True)
    quantize_static(str(prepared), str(target), RandomBands(), quant_format=QuantFormat.QDQ,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
                    op_types_to_quantize=["Conv", "ConvTranspose"], calibrate_method=CalibrationMethod.MinMax)
    return target


def gflops(net: torch.nn.Module, width: int, height: int) -> float:
    """Billions of floating-point operations of one eval forward pass at ``width`` x ``height``, as
    torch's FlopCounterMode counts them (convolutions and matrix products, 2 per multiply-add; not
    the element-wise correlation products or the soft-argmin)."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    band = torch.rand(1, 1, height, width)
    counter = FlopCounterMode(display=False)
    with torch.no_grad(), counter:
        net(band, band)
    return counter.get_total_flops() / 1e9


def seconds_per_run(paths: list[Path], width: int, height: int, threads: int, runs: int) -> list[float]:
    """The median seconds of one run of each network in ``paths``, timed in ``runs`` rounds of
    one run each (module docstring), after two untimed runs each."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    sessions = [ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"]) for path in paths]
    rng = np.random.default_rng(0)
    feeds = random_feeds(sessions[0], rng, width, height)
    for session in sessions:
        for _ in range(2):
            session.run(None, feeds)
    times: list[list[float]] = [[] for _ in sessions]
    for _ in range(runs):
        for session, taken in zip(sessions, times):
            started = time.perf_counter()
            session.run(None, feeds)
            taken.append(time.perf_counter() - started)
    return [statistics.median(taken) for taken in times]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="720x496", help="WIDTHxHEIGHT of the bands (multiples of 16)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--runs", type=int, default=5, help="rounds: each design runs once a round")
    parser.add_argument("--fast", action="store_true", help="the fast design's table (FAST_DESIGNS) instead of DESIGNS")
    parser.add_argument("--bakeoff", action="store_true",
                        help="the design bake-off's table (BAKEOFF) instead of DESIGNS")
    parser.add_argument("--iterative", action="store_true",
                        help="the chosen design's smaller twins (ITERATIVE_TWINS) against the fast design")
    parser.add_argument("--only", nargs="*", help="designs to time besides the first (names from the table; default all)")
    parser.add_argument("--int8", action="store_true", help="also time each design's static int8 twin")
    parser.add_argument("--keep", type=Path, help="write the exported designs here (designN.onnx, in table order), "
                        "e.g. for benchmarks/network_profile.py")
    args = parser.parse_args()
    import torch

    from cade_cli.train import export
    from cade_cli.train.model import parameter_count
    from cade_cli.train.networks import network_of

    width, height = (int(v) for v in args.size.lower().split("x"))
    torch.manual_seed(0)
    folder = args.keep or Path(tempfile.mkdtemp())
    folder.mkdir(parents=True, exist_ok=True)
    table = (ITERATIVE_TWINS if args.iterative else BAKEOFF if args.bakeoff else FAST_DESIGNS if args.fast
             else DESIGNS)
    designs = [(name, config) for index, (name, config) in enumerate(table.items())
               if not args.only or name in args.only or not index]
    nets, paths = [], []
    for index, (_, config) in enumerate(designs):
        nets.append(network_of(config).eval())
        paths.append(folder / f"design{index}.onnx")
        export.export_onnx(nets[-1], paths[-1])
    seconds = seconds_per_run(paths, width, height, args.threads, args.runs)
    int8 = (seconds_per_run([int8_twin(path, width, height) for path in paths], width, height, args.threads, args.runs)
            if args.int8 else [])
    print(f"| design | parameters | GFLOPs | s / run at {width}x{height} | ratio |"
          + (" int8 s / run | ratio |" if args.int8 else "") + "\n|---|---:|---:|---:|---:|"
          + ("---:|---:|" if args.int8 else ""))
    for index, ((name, _), net) in enumerate(zip(designs, nets)):
        row = (f"| {name} | {parameter_count(net):,} | {gflops(net, width, height):.1f} | {seconds[index]:.3f} "
               f"| {seconds[index] / seconds[0]:.2f} |")
        if args.int8:
            row += f" {int8[index]:.3f} | {int8[index] / seconds[0]:.2f} |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
