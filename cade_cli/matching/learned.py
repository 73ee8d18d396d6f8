"""The learned matcher (method ``cade``) as a pipeline of named stages, like
:class:`~cade_cli.matching.classical.SgmPipeline`:

network (:class:`~cade_cli.matching.network.NetworkStage`: the ONNX network on the
bands' color-agnostic transforms) -> visibility (:func:`~cade_cli.matching.disparity.visible_in_right_view`
on the network's surface: a pixel is invalid where a nearer surface lands left of it in the
right view, or its match leaves the image) -> refinement
(:class:`~cade_cli.matching.refinement.RankSgbmRefinement` of the raw bands, at the
visible pixels only; where SGBM's match and the network disagree, the card's learned
:class:`~cade_cli.matching.chooser.Chooser` (or :class:`~cade_cli.matching.chooser_net.ChooserNet`, which
sees around the pixel) decides which to keep, or without one the 32 px agreement rule) -> edges
(where the card asks for it, :func:`~cade_cli.matching.edges.snap_to_edges`: the map's weighted median
guided by the left band moves depth edges to the image's) -> confidence (:func:`~cade_cli.matching.confidence.network_confidence`:
the network's uncertainty and whether the refinement's SGBM match agreed with it) -> the
unfilled result (NaN where invalid; filling is the caller's stage,
:func:`~cade_cli.matching.disparity.densify`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from cade_cli.matching.base import DisparityRange, DisparityResult
from cade_cli.matching.chooser_net import load_chooser
from cade_cli.matching.confidence import network_confidence
from cade_cli.matching.disparity import visible_in_right_view
from cade_cli.matching.edges import snap_to_edges
from cade_cli.matching.network import NetworkStage
from cade_cli.matching.refinement import RankSgbmRefinement
from cade_cli.model_card import ModelCard

NETWORK_RANGE_MARGIN = 4
"""Px searched beyond the network's own range by a card whose ``runtime_refinement`` is
``rank-sgbm-network-range`` (:attr:`RankSgbmRefinement.network_range`)."""


def card_refinement(card: ModelCard, refinement: RankSgbmRefinement) -> RankSgbmRefinement:
    """``refinement`` as the card's ``runtime_refinement`` asks for it (the matcher and the
    chooser's fitting both use this, so a chooser sees the matches it will be asked about)."""
    if card.refinement == "rank-sgbm-network-range":
        return replace(refinement, network_range=NETWORK_RANGE_MARGIN)
    if card.refinement == "rank-sgbm-two-scales":
        return replace(refinement, half_size=True)
    return refinement


@dataclass(frozen=True)
class LearnedPipeline:
    """Kernel of the ``cade`` matcher.

    Attributes:
        network: the network stage (which model, from which folder).
        refinement: the full-resolution refinement; None returns the network's map, and so
            does a card whose ``runtime_refinement`` is ``none`` (neither runs the card's edge filter).
        confidence: compute the confidence (False: ``DisparityResult.confidence`` is
            None; the disparity and validity are the same either way).
    """

    network: NetworkStage = field(default_factory=NetworkStage)
    refinement: RankSgbmRefinement | None = field(default_factory=RankSgbmRefinement)
    confidence: bool = True

    def __call__(self, left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange, *,
                 preprocess: str = "cade") -> DisparityResult:
        """Disparity of the raw bands ``left`` against ``right`` (the network sees their
        color-agnostic transforms, ``preprocess`` must be ``"cade"``; the refinement
        matches the raw bands)."""
        network, uncertainty = self.network.estimate(left, right, disparity_range)
        # Visibility is judged on the network's surface: the refinement's per-pixel
        # corrections would scatter it. Occluded pixels have nothing to match: not refined.
        valid = visible_in_right_view(network)
        disparity, agreement = network, None
        card = self.network.card()
        if self.refinement is not None and card.refinement != "none":
            weights = card.chooser  # the card's learned choice, else the 32 px rule
            chooser = load_chooser(weights, card.variants[0].path.parent) if weights is not None else None
            choose = None if chooser is None else (
                lambda shifted_network, match, accepted, shifted_right: chooser.take(
                    left, shifted_network, uncertainty, match, accepted, shifted_right))
            refinement = card_refinement(card, self.refinement)
            refined, taken = refinement.refine(left, right, network, disparity_range, choose=choose)
            disparity = np.clip(refined, disparity_range.minimum, disparity_range.maximum)
            agreement = np.where(taken, np.abs(refined - network), np.float32(np.inf))
            if card.edge_filter == "weighted-median":
                disparity = snap_to_edges(disparity, left)
        confidence = network_confidence(uncertainty, valid, agreement=agreement) if self.confidence else None
        return DisparityResult(np.where(valid, disparity, np.float32(np.nan)), valid, confidence)
