"""Inference time of candidate CadeNet2D designs, before any is trained (Accuracy III's speed budget).

    OMP_NUM_THREADS=2 .venv/bin/python benchmarks/design_speed.py --size 720x496

Each design is built with its untrained weights (the time depends on the graph and the size,
not on the weights), exported to ONNX the way a trained one is (:func:`cade_cli.train.export.export_onnx`)
and run by onnxruntime on random bands: two untimed runs, then the median of ``--runs``. The
first design is the campaign's; the ratio column is each design's time over it. Pause any
training run while timing: the seconds hold only on a quiet CPU.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

from cade_cli.train.export import export_onnx
from cade_cli.train.model import parameter_count
from cade_cli.train.networks import network_of

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


def int8_twin(path: Path, width: int, height: int) -> Path:
    """A static QDQ int8 twin (the export's settings, :mod:`cade_cli.train.quantize`), calibrated
    on random bands: enough for timing, not for accuracy."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class RandomBands:
        def __init__(self):
            rng = np.random.default_rng(1)
            self.feeds = iter([{name: rng.random((1, 1, height, width), dtype=np.float32) for name in ("left", "right")}
                               for _ in range(2)])

        def get_next(self):
            return next(self.feeds, None)

    prepared, target = path.with_suffix(".pre.onnx"), path.with_suffix(".int8.onnx")
    quant_pre_process(str(path), str(prepared), skip_symbolic_shape=True)
    quantize_static(str(prepared), str(target), RandomBands(), quant_format=QuantFormat.QDQ,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
                    op_types_to_quantize=["Conv", "ConvTranspose"], calibrate_method=CalibrationMethod.MinMax)
    return target


def seconds_per_run(path: Path, width: int, height: int, threads: int, runs: int) -> float:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    feeds = {item.name: rng.random((1, 1, height, width), dtype=np.float32) for item in session.get_inputs()}
    for _ in range(2):
        session.run(None, feeds)
    times = []
    for _ in range(runs):
        started = time.perf_counter()
        session.run(None, feeds)
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="720x496", help="WIDTHxHEIGHT of the bands (multiples of 16)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--only", nargs="*", help="designs to time besides the first (names from the table; default all)")
    parser.add_argument("--int8", action="store_true", help="also time each design's static int8 twin")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    torch.manual_seed(0)
    folder = Path(tempfile.mkdtemp())
    print(f"| design | parameters | s / run at {width}x{height} | ratio |" + (" int8 s / run | ratio |" if args.int8 else "")
          + "\n|---|---:|---:|---:|" + ("---:|---:|" if args.int8 else ""))
    reference = None
    for index, (name, config) in enumerate(DESIGNS.items()):
        if args.only and name not in args.only and index:
            continue
        net = network_of(config).eval()
        path = folder / f"design{index}.onnx"
        export_onnx(net, path)
        seconds = seconds_per_run(path, width, height, args.threads, args.runs)
        reference = reference or seconds
        row = f"| {name} | {parameter_count(net):,} | {seconds:.3f} | {seconds / reference:.2f} |"
        if args.int8:
            int8 = seconds_per_run(int8_twin(path, width, height), width, height, args.threads, args.runs)
            row += f" {int8:.3f} | {int8 / reference:.2f} |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
