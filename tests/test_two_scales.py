"""The refinement's second SGBM at half size (a card's ``runtime_refinement:
rank-sgbm-two-scales``): where the full-size search finds no unique match, the half-size one
offers its own; everywhere else the full-size search decides as before."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.learned import LearnedPipeline, card_refinement
from cade_cli.matching.network import NetworkStage
from cade_cli.matching.refinement import RankSgbmRefinement
from cade_cli.model_card import RUNTIME_REFINEMENTS, card_path, read_card
from cards import card_copy
from synthetic import _sample, render_pair, smooth_texture

TWO_SCALES = RankSgbmRefinement(half_size=True)


def shifted_texture(rng: np.random.Generator, shape: tuple[int, int], disparity: float, *, sigma: float,
                    noise: float) -> tuple[np.ndarray, np.ndarray]:
    """A texture with features about ``sigma`` px wide and its copy shifted by ``disparity`` px
    (the right view), each with its own Gaussian noise."""
    height, width = shape
    texture = smooth_texture(rng, (height, width + 64), sigma)
    columns = np.broadcast_to(np.arange(width, dtype=np.float32)[None, :], shape)
    left, right = _sample(texture, columns + 32), _sample(texture, columns + 32 + disparity)
    return tuple((view + rng.normal(0, noise, shape)).astype(np.float32) for view in (left, right))


@pytest.mark.parametrize("width", [192, 191])
def test_the_half_size_match_recovers_a_slanted_plane_in_full_size_px(width):
    """A plane at 20 + 0.1 y px (odd widths too: the half size is rounded up, its px rescaled
    by the true ratio): the enlarged match lies within a quarter px of the truth at most pixels."""
    pair = render_pair(np.random.default_rng(6), (96, width), background=(20.0, 0.1))
    estimate = (pair.disparity + 3).astype(np.float32)
    matched, accepted = TWO_SCALES.half_size_candidate(pair.left, pair.right, estimate, 63)
    assert matched.shape == pair.left.shape and accepted.dtype == bool
    kept = accepted & pair.reliable
    assert kept.sum() > 0.8 * pair.reliable.sum()
    error = np.abs(matched - pair.disparity)[kept]
    assert np.median(error) < 0.25 and (error < 1).mean() > 0.95


def test_the_half_size_match_fills_what_the_full_size_search_rejects():
    """Coarse texture under noise: the full-size SGBM finds no unique minimum at most pixels, the
    half-size one (its blocks see twice as far) does. The two-scale candidate is the full-size
    match wherever that was accepted and the half-size match at the pixels it fills, which lie
    near the true 12 px."""
    left, right = shifted_texture(np.random.default_rng(0), (96, 192), 12.0, sigma=8, noise=0.03)
    estimate = np.full(left.shape, 15.0, np.float32)
    inside = np.zeros(left.shape, bool)
    inside[4:-4, 20:-4] = True
    full, full_accepted = TWO_SCALES.full_size_candidate(left, right, estimate, 47)
    half, half_accepted = TWO_SCALES.half_size_candidate(left, right, estimate, 47)
    both, both_accepted = TWO_SCALES.candidate(left, right, estimate, 47)
    assert (full_accepted & inside).sum() < 0.5 * (half_accepted & inside).sum()
    assert np.array_equal(both_accepted, full_accepted | half_accepted)
    assert np.array_equal(both[full_accepted], full[full_accepted])
    filled = half_accepted & ~full_accepted
    assert np.array_equal(both[filled], half[filled])
    assert np.median(np.abs(both[filled & inside] - 12.0)) < 1.0


def test_without_the_flag_the_candidate_is_the_full_size_search():
    left, right = shifted_texture(np.random.default_rng(1), (64, 128), 9.0, sigma=3, noise=0.01)
    estimate = np.full(left.shape, 9.0, np.float32)
    plain = RankSgbmRefinement().candidate(left, right, estimate, 31)
    full = TWO_SCALES.full_size_candidate(left, right, estimate, 31)
    assert all(np.array_equal(a, b) for a, b in zip(plain, full))


@pytest.mark.parametrize("refinement, field, value", [
    ("rank-sgbm", "half_size", False), ("rank-sgbm-two-scales", "half_size", True),
    ("rank-sgbm-network-range", "network_range", 4), ("rank-sgbm-two-scales", "network_range", None),
])
def test_each_runtime_refinement_configures_the_refinement(refinement, field, value):
    assert refinement in RUNTIME_REFINEMENTS
    card = read_card(card_path())
    configured = card_refinement(replace(card, refinement=refinement), RankSgbmRefinement())
    assert getattr(configured, field) == value


def test_a_card_asks_for_the_two_scale_search(tmp_path: Path, monkeypatch):
    shipped = card_path("cade-v4")  # a card with the default refinement
    assert read_card(shipped).refinement == "rank-sgbm"
    path = card_copy(tmp_path, "two-scales", source="cade-v4", runtime_refinement="rank-sgbm-two-scales")
    assert read_card(path).refinement == "rank-sgbm-two-scales"
    halves = []
    original = RankSgbmRefinement.half_size_candidate

    def spy(self, *args):
        halves.append(args[0].shape)
        return original(self, *args)

    monkeypatch.setattr(RankSgbmRefinement, "half_size_candidate", spy)
    pair = render_pair(np.random.default_rng(4), (64, 160), background=(10.0, 0.0), foreground=(16.0, 0.0))
    for model in (str(shipped), str(path)):
        LearnedPipeline(network=NetworkStage(model=model))(pair.left, pair.right, DisparityRange(0, 40))
    assert halves == [(64, 160)]  # once, for the card that asks
