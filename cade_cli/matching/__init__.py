"""Stereo matchers behind one registry: ``MATCHERS[name](left, right, max_disp=...)``.

Each matcher is a pipeline of stages (Pandora's split): cost volume
(:mod:`~cade_cli.matching.cost`) -> aggregation (:mod:`~cade_cli.matching.sgm`) ->
disparity and validation (:mod:`~cade_cli.matching.disparity`). All return a
:class:`~cade_cli.matching.base.DisparityResult`: a dense float32 map plus a validity mask.
"""

from __future__ import annotations

from cade_cli.errors import lookup
from cade_cli.matching.base import (
    PREPROCESS_CHOICES,
    DisparityRange,
    DisparityResult,
    Matcher,
)
from cade_cli.matching.classical import OpenCvSgbm, census_sgm, zncc_sgm
from cade_cli.matching.learned import CadeNetwork

MATCHERS: dict[str, Matcher] = {
    matcher.name: matcher
    for matcher in (
        # Census and ZNCC are already invariant to gain and offset: the CADE transform
        # only adds noise for them; SGBM's absolute-difference cost needs it.
        Matcher("census-sgm", "Census 7x7 Hamming cost + 8-path SGM, LR check (own implementation)",
                census_sgm, 7, best_preprocess="none"),
        Matcher("zncc-sgm", "1 - ZNCC 5x5 cost + 8-path SGM, LR check (own implementation)",
                zncc_sgm, 5, best_preprocess="none"),
        Matcher("sgbm", "OpenCV StereoSGBM, 8 paths, 5x5 blocks (mono-modal reference)",
                OpenCvSgbm(), 5, best_preprocess="cade"),
        # The network was trained on color-agnostic bands only (it applies the transform
        # itself: its refinement matches the raw bands); memory is bounded by strips and
        # a pyramid, not by the range.
        Matcher("cade", "CADE network on color-agnostic bands (ONNX via onnxruntime; models/cade-v4), "
                "refined by SGM of the rank-transformed raw bands over the whole range, kept within 32 px of "
                "its estimate",
                CadeNetwork(), 8, best_preprocess="cade", accepts_raw=False, transforms_itself=True,
                volume_bytes=0),
    )
}


def get_matcher(name: str) -> Matcher:
    """The registered matcher called ``name``; raises :class:`CadeError` listing the choices."""
    return lookup(MATCHERS, name, kind="method")


__all__ = ["MATCHERS", "PREPROCESS_CHOICES", "DisparityRange", "DisparityResult", "Matcher", "get_matcher"]
