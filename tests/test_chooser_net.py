"""The convolutional chooser: its file, its strips, its place in the pipeline and its fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.matching import chooser_net
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.chooser import AGREE, Chooser
from cade_cli.matching.chooser_net import MATCH_PLANES, PLANES, ChooserNet, chooser_planes, load_chooser, sampled_at
from cade_cli.spectral import network_input
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


def textured_pair(rng: np.random.Generator, shape: tuple[int, int], disparity: int) -> tuple[np.ndarray, np.ndarray]:
    """A smoothed-noise left band and its right view at one whole ``disparity`` (left(x) = right(x - disparity))."""
    import cv2

    left = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 1.0) * 255
    right = np.zeros_like(left)
    right[:, :shape[1] - disparity] = left[:, disparity:]
    return left, right


def test_the_matching_evidence_is_the_right_band_where_each_candidate_puts_the_match():
    rng = np.random.default_rng(11)
    left, right = textured_pair(rng, (40, 80), 7)
    true, wrong = np.full((40, 80), 7.0, np.float32), np.full((40, 80), 12.0, np.float32)
    planes = chooser_planes(left, true, np.ones_like(true), wrong, np.ones((40, 80), bool), right,
                            PLANES + MATCH_PLANES)
    assert planes.shape == (len(PLANES) + len(MATCH_PLANES), 40, 80)
    band = 2 * network_input(left, "cade") - 1  # centred
    at_true, at_wrong, match_true, match_wrong = planes[len(PLANES):, :, 12:-12]
    np.testing.assert_allclose(at_true, band[:, 12:-12], atol=1e-5)
    np.testing.assert_allclose(match_true, band[:, 12:-12] ** 2, atol=1e-4)
    assert match_true.mean() > 0.2 > 0.05 > abs(match_wrong.mean())
    assert np.corrcoef(at_wrong.ravel(), band[:, 12:-12].ravel())[0, 1] < 0.3
    np.testing.assert_allclose(match_wrong, band[:, 12:-12] * at_wrong, atol=1e-5)
    half = sampled_at(right, np.full((40, 80), 6.5, np.float32))  # between two columns: their mean
    np.testing.assert_allclose(half[:, 10:-10], (right[:, 3:-17] + right[:, 4:-16]) / 2, rtol=1e-5, atol=1e-3)
    assert not sampled_at(right, np.full((40, 80), np.nan, np.float32)).any()
    with pytest.raises(ValueError, match="right band"):
        chooser_planes(left, true, np.ones_like(true), wrong, np.ones((40, 80), bool), None, PLANES + MATCH_PLANES)


def test_the_pipeline_gives_the_chooser_the_right_band_shifted_with_the_range(tmp_path: Path, monkeypatch):
    """The refinement matches against the right band shifted by the range's minimum and hands the chooser maps
    shifted alike: the evidence must be the right band where the match truly lies, whatever the minimum."""
    torch = pytest.importorskip("torch")
    from cade_cli.train.chooser_net import ChooserCNN, export_net

    net = ChooserCNN(len(PLANES) + len(MATCH_PLANES), 4)
    with torch.no_grad():
        net.out.weight.zero_()
        net.out.bias.fill_(-30.0)
    chooser = export_net(net, tmp_path / "chooser.onnx", PLANES + MATCH_PLANES)
    assert load_chooser(chooser.to_dict(), tmp_path).planes == PLANES + MATCH_PLANES
    seen = []
    monkeypatch.setattr(ChooserNet, "probability", lambda self, planes: (seen.append(planes), np.zeros(
        planes.shape[1:], np.float32))[1])
    path = card_copy(tmp_path, "matching-chooser", chooser=chooser.to_dict())
    pair = render_pair(np.random.default_rng(4), (64, 160), background=(14.0, 0.0), foreground=(30.0, 0.0))
    correlations = []
    for minimum in (0, 9):
        seen.clear()
        stage = NetworkStage(model=str(path))
        LearnedPipeline(network=stage)(pair.left, pair.right, DisparityRange(minimum, minimum + 31))
        (planes,) = seen
        band, at_network = planes[len(PLANES) - 1, :, 40:], planes[len(PLANES), :, 40:]
        correlations.append(np.corrcoef(band.ravel(), at_network.ravel())[0, 1])
    assert min(correlations) > 0.5


def evidence_caches(folder: Path, rng: np.random.Generator, scenes: int = 3) -> list[Path]:
    """Scenes where only the bands say which candidate is right: in each 8 x 8 block, at random, one of the network's
    value and SGBM's match is the truth and the other lies 6 px off it (above in some scenes, below in others), so
    that the two maps' differences, jumps and spreads are alike whichever is right."""
    files = []
    for index in range(scenes):
        left, right = textured_pair(rng, (48, 96), 10)
        gt = np.full((48, 96), 10.0, np.float32)
        blocks = np.kron(rng.random((6, 12)) < 0.5, np.ones((8, 8))).astype(bool)
        off = gt + rng.choice([-6.0, 6.0])
        files.append(folder / f"scene{index}.npz")
        np.savez(files[-1], gt=gt, RB_network=np.where(blocks, off, gt), RB_uncertainty=np.ones_like(gt),
                 RB_candidate=np.where(blocks, gt, off), RB_accepted=np.ones(gt.shape, bool), RB_left=left,
                 RB_right=right)
    return files


def test_fitting_learns_the_candidate_that_the_bands_match(tmp_path: Path):
    """Where nothing but the bands tells the candidates apart, the chooser with the matching evidence learns to take
    SGBM's match exactly where it is the truth; without it, it cannot (the same fit, the usual planes)."""
    pytest.importorskip("torch")
    from cade_cli.train.chooser import tasks_of
    from cade_cli.train.chooser_net import MATCHING, export_net, fit_net

    rng = np.random.default_rng(12)
    (tmp_path / "held-out").mkdir()
    train, (test,) = evidence_caches(tmp_path, rng), evidence_caches(tmp_path / "held-out", rng, scenes=1)
    ((gt, task),) = list(tasks_of(test))
    truth = task["candidate"] == gt
    agreement = {}
    for planes in (PLANES, MATCHING):
        net = fit_net(train, width=8, steps=300, crop=32, batch=4, lr=5e-3, planes=planes, log=lambda _: None)
        chooser = export_net(net, tmp_path / f"{len(planes)}.onnx", planes)
        taken = chooser.take(task["left"], task["network"], task["uncertainty"], task["candidate"], task["accepted"],
                             task["right"])
        agreement[len(planes)] = float((taken == truth)[:, 16:].mean())
    assert agreement[len(MATCHING)] > 0.9 > 0.7 > agreement[len(PLANES)]


def test_the_matching_evidence_without_the_convolutional_chooser_is_refused_before_any_work(tmp_path: Path):
    pytest.importorskip("torch")
    from typer.testing import CliRunner

    from cade_cli.train.__main__ import app

    result = CliRunner().invoke(app, ["chooser", "--real-dir", str(tmp_path), "--cache", str(tmp_path / "cache"),
                                      "--model", "cade-v13", "--match-evidence"])
    assert result.exit_code == 2 and "--context" in result.output
    assert not (tmp_path / "cache").exists()
