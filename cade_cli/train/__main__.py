"""``python -m cade_cli.train fit|export|soup|compact|...``: train CadeNet on generated CADE pairs, export ONNX."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cade_cli.train.chooser_command import chooser
from cade_cli.train.preview_command import preview

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__)


@app.callback()
def main() -> None:
    """Train CadeNet on generated CADE pairs and export it to ONNX."""


def default_selfsup_cache(out: Path) -> Path:
    """``$CADE_CACHE_DIR/selfsup-pairs`` when that is set, else ``OUT/selfsup-pairs``."""
    import os

    from cade_cli.data.msir import CACHE_ENV

    root = os.environ.get(CACHE_ENV)
    return Path(root) / "selfsup-pairs" if root else out / "selfsup-pairs"


@app.command()
def fit(
    out: Annotated[Path, typer.Option(help="Run folder: config.json, log.csv, last.pt.")],
    textures: Annotated[list[Path], typer.Option(help="Folder of texture images (repeatable).")] = [],
    data_dir: Annotated[Path | None, typer.Option(help="Folder holding middlebury2014/ for validation.")] = None,
    steps: Annotated[int, typer.Option(min=1)] = 7000,
    batch: Annotated[int, typer.Option(min=1)] = 4,
    height: Annotated[int, typer.Option(min=64)] = 192,
    width: Annotated[int, typer.Option(min=64)] = 320,
    levels: Annotated[int, typer.Option(min=16, help="Search width: disparities 0 .. LEVELS - 1 px.")] = 128,
    lr: float = 1e-3,
    seed: int = 0,
    device: Annotated[str, typer.Option(help="cpu or cuda")] = "cpu",
    threads: Annotated[int, typer.Option(min=1)] = 2,
    workers: Annotated[int, typer.Option(min=0, help="Data-generating processes.")] = 1,
    validate_every: Annotated[int, typer.Option(min=1)] = 500,
    stop_after: Annotated[int | None, typer.Option(min=1, help="Stop (checkpointed) after this step.")] = None,
    resume: Annotated[bool, typer.Option(help="Continue from OUT/last.pt when it exists.")] = True,
    init: Annotated[Path | None, typer.Option(exists=True, dir_okay=False,
                                              help="Fine-tune: start a new run from this checkpoint's weights.")] = None,
    warmup: Annotated[int, typer.Option(min=0, help="Linear warm-up steps.")] = 200,
    padding: Annotated[str, typer.Option(help="2D padding mode: zeros (cade-v4) or replicate (cade-v1 ... v3).")]
    = "zeros",
    entry_kernel: Annotated[int, typer.Option(min=1, help="First 3D kernel size: 1 (cade-v4) or 3 (v1 ... v3).")]
    = 1,
    misaligned: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of training pairs whose right view is "
                                              "vertically misaligned by up to 1 px (the cade-v5 experiment: 0.5; "
                                              "the shipped cade-v4: 0).")]
    = 0.0,
    real_dir: Annotated[Path | None, typer.Option(help="Folder of real training scenes in the MiddEval3 layout "
                                                  "(../shared/data/train-real); never a reporting set.")] = None,
    real_share: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of training pairs cut from a real "
                                              "scene instead of rendered (needs --real-dir).")] = 0.0,
    real_hold_out: Annotated[str | None, typer.Option(help="Scenes of --real-dir never trained on, comma-separated: "
                                                      "fit the chooser on them (chooser --scenes).")] = None,
    channels3d: Annotated[int, typer.Option(min=1, help="Channels of the 3D aggregation (8: cade-v4/v6).")] = 8,
    census: Annotated[bool, typer.Option(help="A census cost volume of the input bands beside the learned "
                                         "correlation, into the 3D aggregation.")] = False,
    aggregation: Annotated[str, typer.Option(help="3d (3x3x3 kernels; every shipped model) or separable (a 2D "
                                             "kernel per disparity slice, then a 1D one along disparity).")]
    = "3d",
    second_scale: Annotated[bool, typer.Option(help="A 1/2-resolution stage: a local cost volume +-8 px around "
                                               "the 1/4 level's estimate, decided by a 2D CNN.")] = False,
    init_partial: Annotated[bool, typer.Option(help="With --init: load only the tensors whose shapes fit "
                                               "(a wider 3D part starts fresh; a CadeNet2D with more levels keeps the old "
                                               "disparities' weights, net2d.with_more_levels).")] = False,
    amp: Annotated[bool, typer.Option(help="Mixed precision (bf16 autocast; for --device cuda).")] = False,
    compile_network: Annotated[bool, typer.Option("--compile", help="Train through torch.compile (a few minutes "
                                                  "of compiling at each start, then faster steps; needs a C++ "
                                                  "compiler).")] = False,
    training_mode: Annotated[str, typer.Option(help="cade (11 bands + the color agnostic transform; every shipped "
                                               "model), csdl (the 4 weighted-sum bands + noise, no transform) or "
                                               "pristine (the same R, G or B on both sides, no transform): the "
                                               "training ablation, docs/research/evaluation.md.")] = "cade",
    network_input: Annotated[str | None, typer.Option(help="With --training-mode cade: cade-floor (the color "
                                                      "agnostic transform with a contrast floor; a lever) "
                                                      "instead of the paper's transform.")] = None,
    architecture: Annotated[str, typer.Option(help="cadenet (3D aggregation; cade-v1 ... v8), cadenet2d (the "
                                              "all-2D generation of Accuracy III) or a design of the Accuracy V "
                                              "bake-off: cadenet-convex, cadenet-iterative, cadenet-peak.")] = "cadenet",
    width2d: Annotated[int, typer.Option(min=8, help="cadenet2d: the 2D U-Net's channels at 1/4 resolution "
                                                     "(the bake-off's designs: their aggregation's).")] = 48,
    features2d: Annotated[int, typer.Option(min=4, help="cadenet2d and the bake-off's designs: channels of the "
                                            "1/4-resolution features "
                                            "(a multiple of the correlation's 4 groups).")] = 32,
    half_channels: Annotated[int, typer.Option(min=4, help="cadenet2d: channels of the 1/2-level refinement.")] = 16,
    full_refinement: Annotated[int, typer.Option(min=0, help="cadenet2d: channels of a full-resolution refinement "
                                                 "(0: none; the 1/2-level estimate upsampled).")] = 0,
    slice_channels: Annotated[int, typer.Option(min=0, help="cadenet2d: channels of a spatial aggregation shared by "
                                                "every disparity (0: none).")] = 0,
    scene_range: Annotated[float, typer.Option(min=0.01, max=1.0, help="Rendered scenes span (LEVELS - 1) x s, s "
                                               "drawn log-uniformly from [SCENE_RANGE, 1] (1: the whole range).")]
    = 1.0,
    eraser: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of pairs whose right view gets 1-2 "
                                          "rectangles painted over (occlusion augmentation).")] = 0.0,
    ground: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of rendered scenes with a ground under "
                                          "the objects (a road or floor from a horizon to near disparities at the "
                                          "bottom).")] = 0.0,
    shadows: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of rendered backgrounds and grounds "
                                           "with shadows cast on them (shade keeping 3-30 % of the light over 20-70 % of the "
                                           "surface).")] = 0.0,
    thin: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of rendered scenes with 1-6 thin structures "
                                        "(wires, poles, fronds 1-6 px wide) in front: sharp depth edges.")] = 0.0,
    floating: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of rendered scenes made of 10-40 "
                                            "floating objects over a real background (a texture photo or a "
                                            "--real-dir scene's left view).")] = 0.0,
    asymmetric: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of pairs with one view changed "
                                              "(vignetting, defocus, gamma, contrast, blur, noise, JPEG).")] = 0.0,
    edge_weight: Annotated[float, typer.Option(min=0.0, help="Loss weight W at depth edges: pixels within 3 px "
                                               "of a ground-truth jump > 2 px weigh 1 + W in a weighted mean "
                                               "(0: the plain mean).")] = 0.0,
    mask_evidence: Annotated[bool, typer.Option(help="cadenet-iterative: its convex mask also sees the 1/4 "
                                                "correlation at the nine estimates it combines.")] = False,
    fine_evidence: Annotated[bool, typer.Option(help="cadenet-iterative: its convex mask also sees, at each of "
                                                "those estimates, the cosine of the two views' 1/2 features for "
                                                "each 1/2 pixel of its cell.")] = False,
    mask_pick: Annotated[float, typer.Option(min=0.0, help="cadenet-iterative: weight of its convex mask's pick "
                                             "loss (the truth's likelihood under the mask's mixture of its nine "
                                             "candidates; 0: none).")] = 0.0,
    misaligned_offset: Annotated[float, typer.Option(min=0.0, help="Largest vertical offset of a misaligned pair, "
                                                     "px.")] = 1.0,
    feature_consistency: Annotated[float, typer.Option(min=0.0, help="Weight of the cross-spectral feature-"
                                                       "consistency loss (cadenet2d; 0: off).")] = 0.0,
    crop_schedule: Annotated[str | None, typer.Option(help="Progressive crops: STEP:HEIGHTxWIDTH,... (e.g. "
                                                      "0:160x288,5000:192x320); default HEIGHT x WIDTH throughout.")]
    = None,
    validate_rgb: Annotated[bool, typer.Option(help="Also validate on Middlebury's same-band tasks (R>R, G>G, "
                                               "B>B), for the RGB curves.")] = False,
    selfsup_dir: Annotated[Path | None, typer.Option(help="Folder of multi-lens captures without ground truth "
                                                    "(../shared/data/micasense): rectified band pairs train by a "
                                                    "self-supervised loss.")] = None,
    selfsup_cache: Annotated[Path | None, typer.Option(help="Where the rectified pairs are cached (default: "
                                                      "$CADE_CACHE_DIR/selfsup-pairs, else OUT/selfsup-pairs).")]
    = None,
    selfsup_share: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of training pairs cut from the "
                                                 "rectified real pairs (needs --selfsup-dir).")] = 0.0,
    selfsup_weight: Annotated[float, typer.Option(min=0.0, help="Weight of the self-supervised loss.")] = 1.0,
    time_budget: Annotated[float | None, typer.Option(min=1.0, help="Stop, checkpointed, after this many seconds "
                                                      "in this process (resume with the same command).")] = None,
    cpu_budget: Annotated[float | None, typer.Option(min=1.0, help="Stop, checkpointed, once the run has spent "
                                                     "this many CPU-seconds in all (its cpu_s, over resumes): "
                                                     "equal CPU-hours for a bake-off on a shared CPU.")] = None,
) -> None:
    """Train (or resume) a run."""
    if real_share > 0 and real_dir is None:
        raise typer.BadParameter("--real-share needs --real-dir", param_hint="--real-share")
    if selfsup_share > 0 and selfsup_dir is None:
        raise typer.BadParameter("--selfsup-share needs --selfsup-dir", param_hint="--selfsup-share")
    if selfsup_dir is not None and "msir-outdoor" in selfsup_dir.resolve().parts:
        raise typer.BadParameter("msir-outdoor is the shipping rule's real check: never trained on",
                                 param_hint="--selfsup-dir")
    if floating > 0 and not textures and real_dir is None:
        raise typer.BadParameter("--floating needs a real background: --textures (images) or --real-dir",
                                 param_hint="--floating")
    if real_hold_out and real_dir is None:
        raise typer.BadParameter("--real-hold-out needs --real-dir", param_hint="--real-hold-out")
    from cade_cli.train.config import TrainConfig
    from cade_cli.train.fit import train
    from cade_cli.train.pairs import TRAINING_MODES

    from cade_cli.train.model import AGGREGATIONS

    from cade_cli.train.networks import ARCHITECTURES

    if architecture not in ARCHITECTURES:
        raise typer.BadParameter(f"must be one of {', '.join(ARCHITECTURES)}", param_hint="--architecture")
    if aggregation not in AGGREGATIONS:
        raise typer.BadParameter(f"must be one of {', '.join(AGGREGATIONS)}", param_hint="--aggregation")
    if network_input is not None and (training_mode != "cade" or network_input not in ("cade", "cade-floor")):
        raise typer.BadParameter("cade or cade-floor, with --training-mode cade", param_hint="--network-input")
    if training_mode not in TRAINING_MODES:
        raise typer.BadParameter(f"must be one of {', '.join(TRAINING_MODES)}", param_hint="--training-mode")

    config = TrainConfig(out=str(out), textures=[str(t) for t in textures],
                         data_dir=str(data_dir) if data_dir else None, steps=steps, batch=batch, height=height,
                         width=width, levels=levels, lr=lr, seed=seed, device=device, threads=threads,
                         workers=workers, validate_every=validate_every, stop_after=stop_after,
                         init=str(init) if init else None, warmup=warmup, padding=padding,
                         entry_kernel=entry_kernel, misaligned=misaligned,
                         real_dir=str(real_dir) if real_dir else None, real_share=real_share, amp=amp, compile=compile_network,
                         real_hold_out=real_hold_out.split(",") if real_hold_out else [],
                         channels3d=channels3d, init_partial=init_partial, census=census, aggregation=aggregation,
                         second_scale=second_scale, training_mode=training_mode, time_budget_s=time_budget, cpu_budget_s=cpu_budget,
                         network_input=network_input, architecture=architecture, width2d=width2d, features2d=features2d,
                         half_channels=half_channels,
                         full_refinement=full_refinement, slice_channels=slice_channels, validate_rgb=validate_rgb, scene_range=scene_range,
                         eraser=eraser, ground=ground, shadows=shadows, misaligned_offset=misaligned_offset,
                         thin=thin, floating=floating, asymmetric=asymmetric, edge_weight=edge_weight, mask_evidence=mask_evidence,
                         fine_evidence=fine_evidence,
                         mask_pick=mask_pick,
                         feature_consistency=feature_consistency, crop_schedule=crop_schedule,
                         selfsup_dir=str(selfsup_dir) if selfsup_dir else None,
                         selfsup_cache=str(selfsup_cache or default_selfsup_cache(out)) if selfsup_dir else None,
                         selfsup_share=selfsup_share, selfsup_weight=selfsup_weight)
    train(config, resume=resume)


@app.command()
def validate(
    run: Annotated[Path, typer.Argument(exists=True, file_okay=False, help="A run's folder (its last.pt "
                                        "and log.csv).")],
    data_dir: Annotated[Path, typer.Option(exists=True, file_okay=False, help="Where the validation sets are.")]
    = Path("../shared/data"),
    threads: Annotated[int, typer.Option(min=1)] = 2,
) -> None:
    """Add RUN's validation rows at its last checkpoint's step (Middlebury, msir-outdoor) to its log.csv,
    as `fit` writes them: for a run trained where the sets were not (a lent GPU's, docs/gpu-recipe.md)."""
    from cade_cli.train.fit import validate_run

    missing = [name for name in ("last.pt", "log.csv") if not (run / name).is_file()]
    if missing:
        raise typer.BadParameter(f"{run} is not a run's folder: no {', '.join(missing)}", param_hint="RUN")
    for name, epe, bad3 in validate_run(run, data_dir, threads=threads):
        print(f"{run.name}: {name} EPE {epe:.3f} bad3 {bad3:.2f}%")


@app.command()
def export(
    checkpoint: Annotated[Path, typer.Argument(exists=True, dir_okay=False, help="A run's last.pt.")],
    onnx_path: Annotated[Path, typer.Option("--onnx", help="Where to write the model.")] = Path("models/cade-v4.onnx"),
    hardware: Annotated[str, typer.Option(help="Where the training ran, for the card.")] = "",
    output: Annotated[str, typer.Option(help="The disparity output: disparity (after the refinement net; "
                                             "shipped) or coarse (soft-argmin upsampled: faster, less accurate).")]
    = "disparity",
    runtime_refinement: Annotated[str, typer.Option(help="What the cade matcher does after this network: rank-sgbm "
                                                    "(SGBM of the rank-transformed bands; every model before "
                                                    "Accuracy III), rank-sgbm-network-range, "
                                                    "rank-sgbm-two-scales (its rejects offered a half-size "
                                                    "SGBM's match) or none (the network's map as it is).")]
    = "rank-sgbm",
    mask_uncertainty: Annotated[bool, typer.Option(help="cadenet-iterative: its uncertainty output also carries "
                                                   "its convex mask's doubt (the spread of the candidates it "
                                                   "blends), for the chooser.")] = False,
) -> None:
    """Export CHECKPOINT to ONNX (the trained range and the other range variants), verify each
    against PyTorch, write the JSON card beside them."""
    from cade_cli.train.export import export_checkpoint
    from cade_cli.train.model import EXPORT_OUTPUTS

    from cade_cli.model_card import RUNTIME_REFINEMENTS

    if output not in EXPORT_OUTPUTS:
        raise typer.BadParameter(f"must be one of {', '.join(EXPORT_OUTPUTS)}", param_hint="--output")
    if runtime_refinement not in RUNTIME_REFINEMENTS:
        raise typer.BadParameter(f"must be one of {', '.join(RUNTIME_REFINEMENTS)}", param_hint="--runtime-refinement")
    card = export_checkpoint(checkpoint, onnx_path, onnx_path.with_suffix(".json"),
                             extra={"hardware": hardware} if hardware else None, output=output,
                             runtime_refinement=runtime_refinement, mask_uncertainty=mask_uncertainty)
    for variant in card["variants"]:
        path = onnx_path.with_name(variant["file"])
        print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB, {variant['levels']} levels), "
              f"sha256 {variant['sha256']}")
    print(f"max |ONNX - PyTorch| = {card['onnx_vs_torch_max_abs_diff']:.2e} px")


@app.command()
def quantise(
    card: Annotated[Path, typer.Argument(exists=True, dir_okay=False, help="An exported model's card (.json).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="The int8 card to write; its ONNX files go beside it.")],
    textures: Annotated[list[Path], typer.Option(help="Texture folders for the generated calibration pairs.")] = [],
    count: Annotated[int, typer.Option(min=1, help="Calibration pairs.")] = 16,
) -> None:
    """Write a static int8 (QDQ) twin of CARD's network, calibrated on generated pairs."""
    from cade_cli.train.quantize import quantise_card

    quantised = quantise_card(card, out, [str(t) for t in textures], count=count)
    for variant in quantised["variants"]:
        print(f"wrote {out.with_name(variant['file'])} ({variant['levels']} levels), sha256 {variant['sha256']}")
    print(f"wrote {out}")


@app.command()
def curves(
    runs: Annotated[list[Path], typer.Argument(exists=True, file_okay=False, help="Run folders, ancestors first.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="PNG to write.")] = Path("docs/learning-curves.png"),
    data_dir: Annotated[Path | None, typer.Option(help="Folder holding middlebury2005/ and middlebury2014/, to "
                                                  "score runs whose log lacks a validation set.")] = None,
) -> None:
    """Draw validation EPE / bad-3 of RUNS against training steps into one PNG."""
    from cade_cli.train.curves import fill_final_points, plot, read_run

    chain = {}
    for folder in runs:
        curve = read_run(folder, chain)
        fill_final_points(curve, folder, data_dir)
        chain[folder.name] = curve
    plot(list(chain.values()), output)
    print(f"wrote {output}")


@app.command()
def soup(
    checkpoints: Annotated[list[Path], typer.Argument(exists=True, dir_okay=False, help="Runs' last.pt, "
                                                      "fine-tuned from one initialisation.")],
    out: Annotated[Path, typer.Option(help="Where to write the averaged checkpoint (export it with `export`).")],
) -> None:
    """Average the weights of CHECKPOINTS of one design into one checkpoint (a uniform model soup)."""
    import torch

    from cade_cli.train.checkpoints import average_checkpoints

    try:
        averaged = average_checkpoints(checkpoints)
    except ValueError as error:
        raise typer.BadParameter(str(error), param_hint="CHECKPOINTS") from None
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(averaged, out)
    print(f"wrote {out}: the mean of {len(checkpoints)} checkpoints")


@app.command()
def compact(
    checkpoint: Annotated[Path, typer.Argument(exists=True, dir_okay=False, help="A run's last.pt (any form).")],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Where to write it (default: over CHECKPOINT, "
                                             "atomically).")] = None,
    weights_only: Annotated[bool, typer.Option(help="Keep the weights, config and step only: for a finished run "
                                               "(export, soup, --init still read it; it cannot be resumed).")]
    = False,
) -> None:
    """Rewrite CHECKPOINT compactly: the optimiser's moments in bfloat16 (it resumes as before), or
    weights only; print its size before and after."""
    from cade_cli.train.checkpoints import compact_checkpoint

    target = out or checkpoint
    before, after = compact_checkpoint(checkpoint, target, weights_only=weights_only)
    form = "weights only" if weights_only else "compact"
    print(f"{checkpoint}: {before / 1e6:.2f} MB -> {target}: {after / 1e6:.2f} MB ({form})")


app.command()(chooser)  # its options and body: cade_cli/train/chooser_command.py
app.command()(preview)  # its options and body: cade_cli/train/preview_command.py

if __name__ == "__main__":
    app()
