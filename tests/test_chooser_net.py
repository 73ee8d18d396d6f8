"""The convolutional chooser: its file, its strips, its place in the pipeline and its fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.matching import chooser_net
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.chooser import AGREE, Chooser
from cade_cli.matching.chooser_net import PLANES, ChooserNet, chooser_planes, load_chooser
from cade_cli.matching.learned import LearnedPipeline, card_refinement
from cade_cli.matching.network import NetworkStage
from cade_cli.matching.refinement import RankSgbmRefinement
from cade_cli.model_card import network_fingerprint, read_card
from cards import card_copy
from chooser_caches import near_far_agreement, near_far_caches
from synthetic import render_pair


WIDE = (1, 2, 4, 8, 16, 1)
"""``--context-dilations 1,2,4,8,16,1``: 33 px of reach."""


def exported(folder: Path, *, seed: int = 0, bias: float | None = None, width: int = 4, separable: bool = False,
             dilations: tuple[int, ...] | None = None):
    """A small random ChooserCNN (or, with ``bias``, one whose logit is ``bias`` everywhere) and its file."""
    torch = pytest.importorskip("torch")
    from cade_cli.train.chooser_net import DILATIONS, ChooserCNN, export_net

    torch.manual_seed(seed)
    net = ChooserCNN(len(PLANES), width, separable, dilations or DILATIONS)
    if bias is not None:
        with torch.no_grad():
            net.out.weight.zero_()
            net.out.bias.fill_(bias)
    return net, export_net(net, folder / "chooser.onnx")


@pytest.mark.parametrize(("separable", "dilations"), [(False, None), (True, None), (False, WIDE)])
def test_the_file_gives_the_torch_networks_probability_and_strips_add_up_to_one_run(tmp_path: Path, monkeypatch,
                                                                                     separable: bool, dilations):
    torch = pytest.importorskip("torch")
    net, chooser = exported(tmp_path, separable=separable, dilations=dilations)
    planes = np.random.default_rng(1).normal(0, 1, (len(PLANES), 600, 40)).astype(np.float32)
    with torch.no_grad():
        expected = torch.sigmoid(net(torch.from_numpy(planes)[None]))[0, 0].numpy()
    whole = chooser.probability(planes)
    np.testing.assert_allclose(whole, expected, atol=1e-5)
    monkeypatch.setattr(chooser_net, "STRIP_PIXELS", 256 * 40)  # three strips of 256 rows
    np.testing.assert_allclose(chooser.probability(planes), whole, atol=1e-6)


@pytest.mark.parametrize(("dilations", "reach"), [(None, 17), (WIDE, 33)])
def test_a_pixel_sees_as_far_as_its_dilations_reach_and_no_farther(tmp_path: Path, dilations, reach: int):
    _, chooser = exported(tmp_path, dilations=dilations, width=16)
    planes = np.random.default_rng(2).normal(0, 1, (len(PLANES), 9, 101)).astype(np.float32)
    base = chooser.probability(planes)[4, 50]
    changed = []
    for offset in (reach, reach + 1):  # a whole column that far to the right changed
        moved = planes.copy()
        moved[:, :, 50 + offset] += 5.0
        changed.append(bool(chooser.probability(moved)[4, 50] != base))
    assert changed == [True, False]


def test_a_card_names_the_kind_and_a_damaged_file_or_unknown_kind_is_one_clear_error(tmp_path: Path):
    _, chooser = exported(tmp_path)
    loaded = load_chooser(chooser.to_dict(), tmp_path)
    assert loaded == chooser and isinstance(load_chooser(
        Chooser(np.zeros((12, 2), np.float32), np.zeros(3, np.float32)).to_dict(), tmp_path), Chooser)
    planes = chooser_planes(*(np.random.default_rng(2).random((3, 40, 50)).astype(np.float32)),
                            np.ones((40, 50), np.float32), np.ones((40, 50), bool))
    assert planes.shape == (len(PLANES), 40, 50)
    for broken in ({**chooser.to_dict(), "kind": "forest"}, {**chooser.to_dict(), "planes": list(PLANES[1:])},
                   {"kind": "network"}):
        with pytest.raises(CadeError, match="chooser is malformed"):
            load_chooser(broken, tmp_path)
    damaged = ChooserNet(chooser.path, "0" * 64)
    with pytest.raises(CadeError, match="sha256"):
        damaged.probability(planes)


@pytest.mark.parametrize("bias", [30.0, -30.0])
def test_the_pipeline_uses_a_cards_network_chooser(tmp_path: Path, bias: float):
    """A network chooser that always (bias > 0) or never (< 0) gives a disputed pixel to SGBM: the pipeline takes
    SGBM's accepted match everywhere, or only where it agrees with the network's value; the card's fingerprint
    names the chooser's file."""
    _, chooser = exported(tmp_path, bias=bias)
    path = card_copy(tmp_path, "network-chooser", chooser=chooser.to_dict())
    assert network_fingerprint(str(path))["chooser_sha256"] == chooser.sha256
    pair = render_pair(np.random.default_rng(4), (64, 128), background=(6.0, 0.0), foreground=(20.0, 0.0))
    stage = NetworkStage(model=str(path))
    result = LearnedPipeline(network=stage)(pair.left, pair.right, DisparityRange(0, 31))
    network = stage(pair.left, pair.right, DisparityRange(0, 31))
    match, accepted = card_refinement(read_card(path), RankSgbmRefinement()).candidate(pair.left, pair.right,
                                                                                        network, 31)
    taken = accepted if bias > 0 else accepted & (np.abs(match - network) <= AGREE)
    expected = np.where(taken, np.clip(match, 0, 31), network)
    np.testing.assert_allclose(result.disparity[result.valid], expected[result.valid], atol=1e-5)


def test_fitting_learns_which_candidate_to_trust(tmp_path: Path):
    """Synthetic caches (tests/chooser_caches.py, as the perceptron's test): the fitted, exported network must take
    the near matches and leave the far ones (nine in ten: pixel by pixel at random, which a network that sees its
    neighbours learns more slowly than the perceptron does)."""
    pytest.importorskip("torch")
    from cade_cli.train.chooser_net import export_net, fit_net

    rng = np.random.default_rng(5)
    net = fit_net(near_far_caches(tmp_path, rng), width=8, steps=400, crop=32, batch=4, lr=5e-3, log=lambda _: None)
    assert near_far_agreement(export_net(net, tmp_path / "fitted.onnx"), rng) > 0.9
