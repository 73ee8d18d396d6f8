"""``python -m cade_cli.train chooser``: fit the learned chooser between the network's map and the rank-SGBM
match on the real training scenes (:mod:`cade_cli.train.chooser`), score it, and write it into a model's card."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _fit_network(train: list[Path], onnx: Path, *, width: int, separable: bool, dilations: tuple[int, ...] | None,
                 steps: int, seed: int, match_evidence: bool):
    """The convolutional chooser fitted on the caches ``train`` and exported to ``onnx`` (``dilations`` None: its
    default, :data:`cade_cli.train.chooser_net.DILATIONS`; ``match_evidence``: its planes are
    :data:`cade_cli.matching.chooser_net.MATCHING`)."""
    from cade_cli.matching.chooser_net import MATCHING, PLANES
    from cade_cli.train.chooser_net import DILATIONS, export_net, fit_net

    planes = MATCHING if match_evidence else PLANES
    return export_net(fit_net(train, width=width, separable=separable, dilations=dilations or DILATIONS, steps=steps,
                              seed=seed, planes=planes), onnx, planes)


def _check_options(candidates, context, edge_weight, edge_features, synthetic, textures, match_evidence,
                   dilations: str | None) -> tuple[int, ...] | None:
    """A usage error for options that do not go together (or a refinement that searches nothing); else
    ``--context-dilations``' value (:func:`_dilations`)."""
    from cade_cli.model_card import RUNTIME_REFINEMENTS

    searched = tuple(name for name in RUNTIME_REFINEMENTS if name != "none")
    if candidates is not None and candidates not in searched:
        raise typer.BadParameter(f"must be one of {', '.join(searched)}", param_hint="--candidates")
    if context and (edge_weight or edge_features):
        raise typer.BadParameter("the convolutional chooser takes neither --edge-weight nor --edge-features",
                                 param_hint="--context")
    if match_evidence and not context:
        raise typer.BadParameter("the matching evidence is read by the convolutional chooser: add --context",
                                 param_hint="--match-evidence")
    if synthetic and textures is None:
        raise typer.BadParameter("rendering pairs needs --textures", param_hint="--synthetic")
    return _dilations(dilations)


def _dilations(text: str | None) -> tuple[int, ...] | None:
    """``--context-dilations``' value as a tuple (None where not given); a usage error unless it is positive
    integers, comma-separated."""
    if text is None:
        return None
    try:
        dilations = tuple(int(value) for value in text.split(","))
    except ValueError:
        dilations = ()
    if not dilations or min(dilations) < 1:
        raise typer.BadParameter("must be positive integers, comma-separated", param_hint="--context-dilations")
    return dilations


def _score_reporting_sets(chosen, data_dir: Path, datasets: list[str], cache: Path, suffix: str, model: str,
                          refinement: str) -> None:
    """Print the chooser's scores (and the fixed rule's, the network's, the oracle's) on each reporting set."""
    from cade_cli.train.chooser import SAME_BAND_TASKS, cache_candidates, report, score

    for name in datasets:
        files = cache_candidates(name, data_dir, cache / f"{name}{suffix}", model=model, candidates=refinement)
        print(f"{name} CS: {report(score(files, chosen))}", flush=True)
        if name.startswith("middlebury"):
            print(f"{name} same-band: {report(score(files, chosen, SAME_BAND_TASKS))}", flush=True)


def _training_caches(real_dir: Path, folder: Path, scenes: str | None, model: str, refinement: str) -> list[Path]:
    """The candidate caches of the real training scenes (those named in ``scenes``, comma-separated; default all)."""
    from cade_cli.train.chooser import cache_candidates

    names = scenes.split(",") if scenes else None
    return cache_candidates("middeval3", real_dir, folder, model=model, scenes=names, candidates=refinement)


def _provenance(*, real_dir, cache, scenes, model, hidden, steps, seed, candidates, edge_weight, edge_features,
                context, context_width, context_separable, context_dilations, match_evidence, synthetic, textures,
                real_scenes, refinement) -> dict:
    """A card's record of where and how its chooser was fitted: the command's options as given."""
    command = (f"python -m cade_cli.train chooser --real-dir {real_dir} --cache {cache} "
               + (f"--scenes {scenes} " if scenes else "")
               + f"--model {model} --hidden {hidden} --steps {steps} --seed {seed} --write-card"
               + (f" --candidates {candidates}" if candidates else "")
               + (f" --edge-weight {edge_weight:g}" if edge_weight else "")
               + (" --edge-features" if edge_features else "")
               + (f" --context --context-width {context_width}" if context else "")
               + (" --context-separable" if context and context_separable else "")
               + (f" --context-dilations {context_dilations}" if context and context_dilations else "")
               + (" --match-evidence" if match_evidence else "")
               + (f" --synthetic {synthetic} --textures {textures}" if synthetic else ""))
    fitted_on = (f"train-real ({real_scenes} scenes x 6 cross-band and 3 same-band tasks"
                 + (f": {scenes})" if scenes else ")") + (f" and {synthetic} rendered pairs" if synthetic else ""))
    return {"fitted_on": fitted_on, "command": command, "fitted_on_refinement": refinement}


def _write_card(model: str, chooser: dict) -> None:
    """Store ``chooser`` (the fitted chooser's dict with where and how it was fitted) in ``model``'s card."""
    import json

    from cade_cli.model_card import card_path

    path = card_path(model)
    card = json.loads(path.read_text())
    card["chooser"] = chooser
    path.write_text(json.dumps(card, indent=2) + "\n")
    print(f"wrote the chooser into {path}")


def chooser(
    real_dir: Annotated[Path, typer.Option(exists=True, file_okay=False, help="Real training scenes "
                                           "(../shared/data/train-real, MiddEval3 layout): the chooser is fitted "
                                           "on these only.")],
    cache: Annotated[Path, typer.Option(help="Folder for the candidate caches (one npz per scene; reused).")],
    scenes: Annotated[str | None, typer.Option(help="Fit on these scenes of --real-dir only, comma-separated (those "
                                               "the network's run held out: fit --real-hold-out); default all.")] = None,
    model: Annotated[str, typer.Option(help="The network whose candidates are chosen between (card name or path).")]
    = "cade-v4",
    data_dir: Annotated[Path | None, typer.Option(help="Folder of the reporting sets, to score the chooser "
                                                  "against the fixed 32 px rule.")] = None,
    datasets: Annotated[str, typer.Option(help="Reporting sets scored with --data-dir, comma-separated.")]
    = "middlebury14,middlebury05,kitti2015,kitti2012,flyingthings3d",
    hidden: Annotated[int, typer.Option(min=1)] = 32,
    steps: Annotated[int, typer.Option(min=1)] = 4000,
    seed: int = 0,
    write_card: Annotated[bool, typer.Option(help="Store the chooser in the model's card (the runtime then uses "
                                             "it instead of the 32 px rule).")] = False,
    candidates: Annotated[str | None, typer.Option(help="Fit on the matches of this runtime refinement "
                                                   "(rank-sgbm, rank-sgbm-network-range, rank-sgbm-two-scales) "
                                                   "instead of the card's own.")] = None,
    edge_weight: Annotated[float, typer.Option(min=0.0, help="Weigh the pixels within 3 px of a ground-truth "
                                               "depth jump > 2 px 1 + W times more (0: as before).")] = 0.0,
    edge_features: Annotated[bool, typer.Option(help="Also give the chooser the network's local jump and where "
                                                "its value and SGBM's match lie between the surfaces around it.")]
    = False,
    context: Annotated[bool, typer.Option(help="Fit the convolutional chooser instead (it sees the feature planes "
                                          "around each pixel, about 35 px; cade_cli.matching.chooser_net): an ONNX "
                                          "file beside the card (with --write-card) or in --cache.")] = False,
    context_width: Annotated[int, typer.Option(min=1, help="--context: channels of its layers.")] = 24,
    context_separable: Annotated[bool, typer.Option(help="--context: depthwise-separable layers (about half the "
                                                    "run time at 24 channels).")] = False,
    context_dilations: Annotated[str | None, typer.Option(help="--context: its residual layers' dilations, "
                                                          "comma-separated (each adds its dilation to the reach; "
                                                          "default cade_cli.train.chooser_net.DILATIONS, 17 px).")]
    = None,
    match_evidence: Annotated[bool, typer.Option(help="--context: also read the right band where each candidate puts "
                                                 "the match, and that times the left band (their correlation).")] = False,
    synthetic: Annotated[int, typer.Option(min=0, help="Also fit on this many freshly rendered pairs, which the "
                                           "network never saw (the training campaign's scene generator; needs "
                                           "--textures; cached in --cache; cade_cli.train.chooser_synthetic).")] = 0,
    textures: Annotated[Path | None, typer.Option(exists=True, file_okay=False, help="--synthetic: the texture "
                                                  "folder the scenes are rendered from (../shared/data/textures).")]
    = None,
) -> None:
    """Fit the learned chooser between the network's disparity and the rank-SGBM match, on
    the six cross-band and three same-band tasks of every train-real scene; print its
    EPE / BMP3 (all pixels, as the pipeline finishes them) beside the fixed 32 px rule's."""
    from cade_cli.model_card import card_path, read_card
    from cade_cli.train.chooser import fit, report, score

    dilations = _check_options(candidates, context, edge_weight, edge_features, synthetic, textures, match_evidence,
                               context_dilations)
    fitted_refinement = candidates or read_card(model).refinement
    # one cache folder per refinement: a scene's npz is reused as it is
    suffix = "" if fitted_refinement == "rank-sgbm" else f"-{fitted_refinement}"
    train_real = _training_caches(real_dir, cache / f"train-real{suffix}", scenes, model, fitted_refinement)
    train = list(train_real)
    if synthetic:
        from cade_cli.train.chooser_synthetic import cache_synthetic

        train += cache_synthetic(cache / f"synthetic{suffix}", model=model, count=synthetic, seed=0,
                                 textures=textures, real_dir=real_dir, candidates=fitted_refinement)
    if context:
        onnx = card_path(model).with_name(f"{card_path(model).stem}-chooser.onnx") if write_card else cache / "chooser.onnx"
        chosen = _fit_network(train, onnx, width=context_width, separable=context_separable, dilations=dilations,
                              steps=steps, seed=seed, match_evidence=match_evidence)
    else:
        chosen = fit(train, hidden=hidden, steps=steps, seed=seed, edge_weight=edge_weight,
                     edge_features=edge_features)
    print(f"train-real CS: {report(score(train_real, chosen))}")
    if data_dir is not None:
        _score_reporting_sets(chosen, data_dir, datasets.split(","), cache, suffix, model, fitted_refinement)
    if write_card:
        _write_card(model, {**chosen.to_dict(), **_provenance(
            real_dir=real_dir, cache=cache, scenes=scenes, model=model, hidden=hidden, steps=steps, seed=seed,
            candidates=candidates, edge_weight=edge_weight, edge_features=edge_features, context=context,
            context_width=context_width, context_separable=context_separable, context_dilations=context_dilations,
            match_evidence=match_evidence, synthetic=synthetic, textures=textures, real_scenes=len(train_real),
            refinement=fitted_refinement)})
