"""Static int8 quantisation of an exported network (QDQ format, onnxruntime's quantiser).

The 2D convolutions of CadeNet2D are what int8 can speed up on a CPU (a Conv3D is not);
whether it pays is measured, not assumed: ``benchmarks/speed.py --model`` on the int8
card against its float32 twin, and ``cade benchmark`` for what it costs in accuracy.

Calibration sees generated CADE pairs only (fixed seeds, never a reporting set), made by
the same generator and transform as training; weights are quantised per output channel,
activations per tensor from their calibrated ranges. The card beside the int8 file is the
float32 card with the variant's file and sha256 replaced (and ``quantised`` recorded).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cade_cli.io.checksum import file_sha256
from cade_cli.train.textures import TexturePool

CALIBRATION_SEED = 2 * 10**6
"""Seeds ``CALIBRATION_SEED + i`` draw the calibration pairs (training uses ``[seed, step]``,
validation ``10**6 + i``)."""


class GeneratedCalibration:
    """onnxruntime's CalibrationDataReader over ``count`` generated pairs."""

    def __init__(self, card: dict, textures: list[str], *, count: int = 16, size: tuple[int, int] = (192, 320)):
        from cade_cli.train.batches import generated_pair

        pool = TexturePool([Path(folder) for folder in textures])
        config = card["train_config"]
        self._pairs = iter([
            generated_pair(np.random.default_rng(CALIBRATION_SEED + i), pool, *size, card["trained_levels"],
                           mode=config.get("training_mode", "cade"), kind=config.get("network_input"))
            for i in range(count)])

    def get_next(self) -> dict[str, np.ndarray] | None:
        pair = next(self._pairs, None)
        return None if pair is None else {"left": pair.left[None, None], "right": pair.right[None, None]}


def quantise_card(card_path: Path, out_card: Path, textures: list[str], *, count: int = 16) -> dict:
    """Write an int8 (QDQ) twin of every variant of the card at ``card_path`` beside
    ``out_card`` (``<stem>-int8.onnx`` names), and its card; returns the new card."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    card = json.loads(Path(card_path).read_text())
    variants = []
    for variant in card["variants"]:
        source = Path(card_path).with_name(variant["file"])
        target = out_card.with_name(f"{Path(variant['file']).stem}-int8.onnx")
        prepared = target.with_name(target.name + ".pre.onnx")
        quant_pre_process(str(source), str(prepared), skip_symbolic_shape=True)
        quantize_static(str(prepared), str(target), GeneratedCalibration(card, textures, count=count),
                        quant_format=QuantFormat.QDQ, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                        per_channel=True, op_types_to_quantize=["Conv", "ConvTranspose"],
                        calibrate_method=CalibrationMethod.MinMax)
        prepared.unlink()
        variants.append({**variant, "file": target.name, "sha256": file_sha256(target)})
    quantised = {**card, "name": out_card.stem, "variants": variants,
                 "quantised": {"format": "QDQ", "weights": "int8 per channel", "activations": "uint8 per tensor",
                               "ops": ["Conv", "ConvTranspose"], "calibration": f"{count} generated pairs, seeds "
                               f"{CALIBRATION_SEED} + i", "from": Path(card_path).name}}
    out_card.write_text(json.dumps(quantised, indent=2) + "\n")
    return quantised
