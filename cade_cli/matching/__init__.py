"""Stereo matchers behind one registry: ``MATCHERS[name](left, right, max_disp=...)``.

Each matcher is a pipeline of stages (Pandora's split): cost volume
(:mod:`~cade_cli.matching.cost`) -> aggregation (:mod:`~cade_cli.matching.sgm`) ->
disparity and validation (:mod:`~cade_cli.matching.disparity`). All return a
:class:`~cade_cli.matching.base.DisparityResult`: an unfilled float32 map (NaN where
invalid) plus its validity; :func:`~cade_cli.matching.disparity.densify` is the one fill stage.
"""

from __future__ import annotations

from dataclasses import replace

from cade_cli.errors import CadeError, lookup
from cade_cli.matching.base import (
    PREPROCESS_CHOICES,
    DisparityRange,
    DisparityResult,
    Matcher,
)
from cade_cli.matching.classical import OpenCvSgbm, census_sgm, dasc_sgm, zncc_sgm
from cade_cli.matching.disparity import densify
from cade_cli.matching.learned import LearnedPipeline
from cade_cli.matching.network import NetworkStage

MATCHERS: dict[str, Matcher] = {
    matcher.name: matcher
    for matcher in (
        # Census and ZNCC are already invariant to gain and offset: the CADE transform
        # only adds noise for them; SGBM's absolute-difference cost needs it.
        Matcher("census-sgm", "Census 7x7 Hamming cost + 8-path SGM, LR check (own implementation)",
                census_sgm, 7, preprocessing=("none", "cade")),
        Matcher("zncc-sgm", "1 - ZNCC 5x5 cost + 8-path SGM, LR check (own implementation)",
                zncc_sgm, 5, preprocessing=("none", "cade")),
        Matcher("sgbm", "OpenCV StereoSGBM, 8 paths, 5x5 blocks (mono-modal reference)",
                OpenCvSgbm(), 5, preprocessing=("cade", "none")),
        # The network was trained on color-agnostic bands only (it applies the transform
        # itself: its refinement matches the raw bands); memory is bounded by strips and
        # a pyramid, not by the range.
        Matcher("cade", "CADE network on color-agnostic bands (ONNX via onnxruntime; models/cade-v13), "
                "refined by SGM of the rank-transformed raw bands over the whole range (and at half size where "
                "that finds no unique match), a learned chooser deciding where the two disagree",
                LearnedPipeline(), 8, preprocessing=("cade",), volume_bytes=0),
        # The same network without the refinement: to see what the network alone does
        # (benchmarks/cade_errors.py, the training ablation), not a better matcher.
        Matcher("cade-network", "the CADE network alone (cade without the full-resolution refinement)",
                LearnedPipeline(refinement=None), 8, preprocessing=("cade",), volume_bytes=0),
        # DASC (Kim et al., CVPR 2015) is built from each band's self-correlation, made
        # for cross-spectral pairs; it holds two (H, W, 128) float32 descriptor maps on
        # top of the cost volume (cade_cli.matching.dasc).
        Matcher("dasc-sgm", "DASC descriptor (adaptive self-correlation, 128 patch pairs in 15x15) cost + 8-path SGM, "
                "LR check (own implementation)",
                dasc_sgm, 5, preprocessing=("none", "cade"), volume_bytes=36),
    )
}


LEARNED_METHODS: tuple[str, ...] = tuple(name for name, m in MATCHERS.items() if isinstance(m.kernel, LearnedPipeline))
"""The methods that run a network (and so take a ``model``)."""


def get_matcher(name: str, *, model: str | None = None) -> Matcher:
    """The registered matcher called ``name``; raises :class:`CadeError` listing the choices.

    ``model`` (a model card's path, or a card name in :func:`cade_cli.model_card.model_dir`)
    makes a learned matcher run that network instead of the shipped one; the classical
    matchers have no model and refuse it."""
    matcher = lookup(MATCHERS, name, kind="method")
    if model is None:
        return matcher
    if name not in LEARNED_METHODS:
        raise CadeError(f"method {name} has no network; --model applies to {', '.join(LEARNED_METHODS)}")
    kernel = replace(matcher.kernel, network=NetworkStage(model=str(model)))
    return replace(matcher, kernel=kernel, summary=f"{matcher.summary}; model {model}")


def method_fingerprint(name: str, *, model: str | None = None) -> dict:
    """What of the method ``name``'s network decides its output, as a batch record stores it
    (pairs and drone captures alike): for a learned method the sha256 of each network file its
    model card names, and the card's non-default runtime settings
    (:func:`cade_cli.model_card.network_fingerprint`); ``{}`` for a classical matcher."""
    if name not in LEARNED_METHODS:
        return {}
    from cade_cli.model_card import network_fingerprint

    return network_fingerprint(model)


__all__ = ["LEARNED_METHODS", "MATCHERS", "PREPROCESS_CHOICES", "DisparityRange", "DisparityResult", "Matcher", "densify",
           "get_matcher", "method_fingerprint"]
