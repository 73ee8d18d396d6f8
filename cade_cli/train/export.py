"""Export a trained CadeNet checkpoint to ONNX and write its model card.

The exported graph is ``forward(left, right) -> (disparity, uncertainty)``: inputs
``left``/``right`` (1, 1, H, W) float32 color-agnostic bands with H and W multiples of
:data:`~cade_cli.train.model.DIVISOR`; outputs (1, 1, H, W) float32 disparity and
uncertainty in pixels. Height and width are dynamic. By default ``disparity`` is the
refinement net's output; ``output="coarse"`` exports the soft-argmin map upsampled to
full resolution instead, without the refinement net
(:data:`~cade_cli.train.model.EXPORT_OUTPUTS`; the card records which).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch

from cade_cli.io.checksum import file_sha256
from cade_cli.model_card import DEFAULT_CONTEXT_PX, write_card
from cade_cli.train.model import DIVISOR, CadeNet, ExportWrapper, parameter_count
from cade_cli.train.networks import network_of
from cade_cli.train.pairs import network_input_of

OPSET = 17
INPUT_NAMES = ["left", "right"]
OUTPUT_NAMES = ["disparity", "uncertainty"]


INPUT_TRANSFORMS = {"cade": "cade_cli.spectral.color_agnostic (window 3) on each band",
                    "normalised": "cade_cli.spectral.normalised (min..max to [0, 1]) on each band",
                    "cade-floor": "cade_cli.spectral.color_agnostic (window 3, contrast floor "
                                  "cade_cli.spectral.CONTRAST_FLOOR) on each band"}
"""The card's ``input_transform`` text for each ``input`` (:data:`cade_cli.spectral.NETWORK_INPUTS`)."""


CONTEXT_PX = {"cadenet": DEFAULT_CONTEXT_PX, "cadenet2d": 128, "cadenet-convex": 128, "cadenet-iterative": 128,
              "cadenet-peak": 128}
"""The card's ``context_px`` (a tiled window's collar, :func:`cade_cli.scale.windows.method_collar`):
the 3D CadeNet moves its estimate by more than 0.01 px up to about 50 px away (:data:`DEFAULT_CONTEXT_PX`); CadeNet2D's U-Net
down to 1/16 sees further (cade-v9 on a rendered 400x240 pair, 100 px cores: a 64 px collar left
2.3 % of the pixels away from seams more than 0.1 px off the untiled map, up to 1.17 px; 128 px
left 0.1 %, up to 0.22 px). The bake-off's designs (``cadenet-convex``, ``-iterative``, ``-peak``) reach as far
down (1/16, or 1/8 with dilated blocks) and take CadeNet2D's collar until one is measured."""

OTHER_RANGES = (96, 160, 192, 224, 256)
"""Besides the trained range, each export also writes the same weights searching these
ranges: wider ones keep wide scenes at full resolution instead of downscaling them, the
narrower 96 runs spans up to 88 px a fifth faster (see docs/research/network-design.md)."""


def load_checkpoint(path: Path) -> tuple[CadeNet, dict]:
    state = torch.load(path, map_location="cpu", weights_only=False)
    config = state["config"]
    net = network_of(config)
    net.load_state_dict(state["model"])
    return net.eval(), state


def with_range(net: CadeNet, levels: int) -> CadeNet:
    """The same weights searching ``levels`` px wide (no weight depends on the range)."""
    if levels == net.levels:
        return net
    wide = CadeNet(levels, **net.design)
    wide.load_state_dict(net.state_dict())
    return wide.eval()


def export_onnx(net: CadeNet, path: Path, *, output: str = "disparity", sample_size: tuple[int, int] = (192, 256)) -> None:
    """Write ``net`` as ONNX (legacy TorchScript exporter: no onnxscript dependency);
    ``output``: which map becomes the ``disparity`` output (:data:`EXPORT_OUTPUTS`)."""
    example = (torch.rand(1, 1, *sample_size), torch.rand(1, 1, *sample_size))
    write_onnx(ExportWrapper(net, output).eval(), example, path, INPUT_NAMES, OUTPUT_NAMES)


def write_onnx(module: torch.nn.Module, example: tuple, path: Path, input_names: list[str],
               output_names: list[str]) -> None:
    """``module`` (in eval mode) as ONNX at ``path``: the legacy TorchScript exporter, :data:`OPSET`, every input's
    and output's height and width (axes 2, 3) dynamic; written through a temporary file, so that an interrupted
    export leaves no half-written model."""
    temporary = path.with_name(path.name + ".tmp")
    with warnings.catch_warnings():  # "constant folding not applied" for the cost volume's slices
        warnings.simplefilter("ignore", UserWarning)
        torch.onnx.export(
            module, example, str(temporary), input_names=input_names, output_names=output_names,
            dynamic_axes={name: {2: "height", 3: "width"} for name in input_names + output_names},
            opset_version=OPSET, dynamo=False,
        )
    temporary.replace(path)


def verify_onnx(net: CadeNet, path: Path, *, output: str = "disparity", sizes=((96, 128), (208, 336)),
                seed: int = 0) -> float:
    """Max |ONNX - PyTorch| over both outputs on random inputs of several sizes (px)."""
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(seed)
    worst = 0.0
    wrapper = ExportWrapper(net, output).eval()
    for height, width in sizes:
        left, right = (rng.random((1, 1, height, width), dtype=np.float32) for _ in range(2))
        with torch.no_grad():
            expected = [t.numpy() for t in wrapper(torch.from_numpy(left), torch.from_numpy(right))]
        got = session.run(OUTPUT_NAMES, {"left": left, "right": right})
        worst = max(worst, *(float(np.abs(a - b).max()) for a, b in zip(got, expected)))
    return worst


def architecture_text(net, output: str) -> str:
    """The card's one-line ``architecture``."""
    if hasattr(net, "describe"):  # the bake-off's designs say it themselves
        return net.describe(output)
    if not isinstance(net, CadeNet):
        design = net.design
        return (f"CadeNet2D: 2D features (1/2, 1/4 res) -> normalised group-wise correlation ({design['groups']} "
                f"groups)" + (f" -> per-disparity 2D aggregation ({design['slice_channels']} channels, shared)"
                                if design.get("slice_channels") else "")
                + f" -> 2D U-Net ({design['width']} channels at 1/4) -> soft-argmin -> 1/2-res warped-feature "
                f"refinement" + (" -> full-res refinement" if design["refine_channels"] else " -> bilinear x2")
                + ("" if output == "disparity" else " (coarse output: refinements not exported)"))
    return ("CadeNet: 2D features (1/4 res) -> group-wise correlation (8 groups) -> "
            + ("separable (2D + 1D) " if net.design["aggregation"] == "separable" else "3D ")
            + "hourglass -> soft-argmin"
            + (" -> 1/2-res local cost volume (+-8 px) + 2D CNN" if net.design.get("second_scale") else "")
            + (" -> full-res refinement" if output == "disparity" else
               " -> bilinear x4 (refinement net trained, not exported)"))


def export_checkpoint(checkpoint: Path, onnx_path: Path, card_path: Path, *, extra: dict | None = None,
                      other_ranges: tuple[int, ...] = OTHER_RANGES, output: str = "disparity",
                      runtime_refinement: str = "rank-sgbm", mask_uncertainty: bool = False) -> dict:
    """Export every range variant, verify each against PyTorch, write the JSON card the runtime reads.
    ``mask_uncertainty``: a ``cadenet-iterative`` network's ``uncertainty`` also carries its convex mask's
    doubt (:meth:`~cade_cli.train.net_iterative.CadeNetIterative.with_mask_uncertainty`).

    The trained width goes to ``onnx_path``, another width of R levels (disparities
    0 .. R - 1) to ``<stem>-R.onnx`` beside it; the card (:mod:`cade_cli.model_card`)
    lists them narrowest first."""
    net, state = load_checkpoint(checkpoint)
    if mask_uncertainty:
        if not hasattr(net, "with_mask_uncertainty"):
            raise ValueError("--mask-uncertainty needs a cadenet-iterative checkpoint")
        net.with_mask_uncertainty()
    network_input = network_input_of(state["config"].get("training_mode", "cade"), state["config"].get("network_input"))
    if not isinstance(net, CadeNet):
        other_ranges = ()  # the all-2D generation's weights depend on the range: one variant, the pyramid beyond
    targets = sorted([(net.levels, onnx_path)] + [(r, onnx_path.with_name(f"{onnx_path.stem}-{r}.onnx"))
                                                    for r in set(other_ranges) if r != net.levels])
    variants, max_difference = [], 0.0
    for levels, path in targets:
        variant_net = with_range(net, levels)
        export_onnx(variant_net, path, output=output)
        max_difference = max(max_difference, verify_onnx(variant_net, path, output=output))
        variants.append({"levels": levels, "file": path.name, "sha256": file_sha256(path)})
    return write_card(
        card_path, name=onnx_path.stem, divisor=getattr(net, "divisor", DIVISOR), trained_levels=net.levels,
        variants=variants, architecture=architecture_text(net, output),
        output=output, parameters=parameter_count(net), design=net.design, inputs=INPUT_NAMES, outputs=OUTPUT_NAMES,
        input=network_input, input_transform=INPUT_TRANSFORMS[network_input], opset=OPSET,
        onnx_vs_torch_max_abs_diff=max_difference, steps=state["step"], train_wall_time_s=round(state["elapsed_s"]),
        train_cpu_time_s=round(state.get("cpu_s", 0.0)), runtime_refinement=runtime_refinement,
        train_config=state["config"], context_px=CONTEXT_PX[net.design.get("architecture", "cadenet")],
        **(extra or {}),
    )
