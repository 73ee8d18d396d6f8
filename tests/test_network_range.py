"""The refinement's SGBM narrowed to the network's own range (a card's
``runtime_refinement: rank-sgbm-network-range``): fewer disparities searched, the same
matches inside them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.classical import opencv_sgbm_levels
from cade_cli.matching.learned import NETWORK_RANGE_MARGIN, LearnedPipeline
from cade_cli.matching.network import NetworkStage
from cade_cli.matching.refinement import RankSgbmRefinement
from cade_cli.model_card import RUNTIME_REFINEMENTS, card_path, read_card
from cards import card_copy
from synthetic import render_pair

NARROW = RankSgbmRefinement(network_range=4)


def test_the_whole_range_is_searched_unless_asked():
    network = np.full((32, 48), 20, np.float32)
    assert RankSgbmRefinement().searched_range(network, DisparityRange(-5, 90)) == DisparityRange(-5, 90)


@pytest.mark.parametrize("low, high", [(20.0, 30.0), (3.0, 70.0), (60.0, 88.0), (-4.0, 1.0)])
def test_the_searched_range_covers_the_networks_own_with_the_margin(low, high):
    rng = np.random.default_rng(0)
    network = rng.uniform(low, high, (64, 96)).astype(np.float32)
    whole = DisparityRange(-5, 90)
    searched = NARROW.searched_range(network, whole)
    assert whole.minimum <= searched.minimum and searched.maximum <= whole.maximum
    assert searched.minimum <= max(whole.minimum, low - 4) and searched.maximum >= min(whole.maximum, high + 4 - 1)
    # no more disparities than OpenCV searches for the network's range and the margins
    assert searched.count <= opencv_sgbm_levels(int(np.ceil(high)) - int(np.floor(low)) + 9)
    assert searched.count < whole.count or high - low > 60


def test_a_narrowed_search_finds_the_same_matches_inside_the_networks_range():
    """A plane at 30-33 px with a box at 40 px, in a range of 0..95: the network's range (here
    the truth, off by 2 px) is searched; SGBM's matches there are those of the whole search."""
    pair = render_pair(np.random.default_rng(3), (96, 192), background=(30.0, 0.02), foreground=(40.0, 0.0))
    estimate = (pair.disparity + 2).astype(np.float32)
    whole = DisparityRange(0, 95)
    searched = NARROW.searched_range(estimate, whole)
    assert searched.count <= 32 < whole.count
    narrow = NARROW(pair.left, 0.1 + 0.6 * pair.right**1.8, estimate, whole)
    full = RankSgbmRefinement()(pair.left, 0.1 + 0.6 * pair.right**1.8, estimate, whole)
    error = np.abs(narrow - pair.disparity)[pair.reliable]
    assert np.median(error) < 0.3 and (error < 1).mean() > 0.9
    assert (np.abs(narrow - full)[pair.reliable] < 0.5).mean() > 0.95


def test_a_card_asks_for_the_narrowed_search(tmp_path: Path, monkeypatch):
    assert "rank-sgbm-network-range" in RUNTIME_REFINEMENTS
    shipped = card_path()
    path = card_copy(tmp_path, "narrow", runtime_refinement="rank-sgbm-network-range")
    assert read_card(path).refinement == "rank-sgbm-network-range"
    searched = []
    original = RankSgbmRefinement.refine_span

    def spy(self, left, right, disparity, span, **kwargs):
        searched.append((self.network_range, span))
        return original(self, left, right, disparity, span, **kwargs)

    monkeypatch.setattr(RankSgbmRefinement, "refine_span", spy)
    pair = render_pair(np.random.default_rng(4), (64, 160), background=(10.0, 0.0), foreground=(16.0, 0.0))
    for model in (str(path), str(shipped)):
        LearnedPipeline(network=NetworkStage(model=model))(pair.left, pair.right, DisparityRange(0, 100))
    (margin, narrow), (whole_margin, whole) = searched
    assert margin == NETWORK_RANGE_MARGIN and whole_margin is None
    assert narrow < 32 and whole == 100


def test_where_the_network_lies_outside_the_narrowed_search_its_value_is_kept():
    """Pixels the narrowed search cannot reach (a few beyond the percentiles) keep the network's
    value, even where SGBM accepted a match inside the search."""
    pair = render_pair(np.random.default_rng(5), (96, 192), background=(30.0, 0.0), foreground=(40.0, 0.0))
    estimate = pair.disparity.astype(np.float32).copy()
    # outside the rest, under the 0.5 % of the samples the percentiles drop, and within the 32 px agreement
    # of the true 30 px that SGBM finds there
    estimate[0, 100:120] = 61.0
    whole = DisparityRange(0, 95)
    searched = NARROW.searched_range(estimate, whole)
    assert searched.maximum < 61
    refined, taken = NARROW.refine(pair.left, pair.right, estimate, whole)
    assert np.all(refined[0, 100:120] == 61.0) and not taken[0, 100:120].any()
    assert taken[1:].mean() > 0.5  # elsewhere SGBM's matches are taken as before
