"""The learned choice between the network's disparity and the rank-SGBM match."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.chooser import AGREE, EDGE_FEATURES, FEATURES, Chooser, chooser_features, disputed
from cade_cli.matching.learned import LearnedPipeline, card_refinement
from cade_cli.matching.network import NetworkStage
from cade_cli.matching.refinement import RankSgbmRefinement
from cade_cli.model_card import read_card
from cards import card_copy
from chooser_caches import near_far_agreement, near_far_caches
from synthetic import render_pair


def candidates(seed: int = 0, shape: tuple[int, int] = (48, 64)):
    rng = np.random.default_rng(seed)
    network = rng.uniform(0, 40, shape).astype(np.float32)
    candidate = (network + rng.normal(0, 8, shape)).astype(np.float32)
    return (rng.random(shape).astype(np.float32), network, rng.uniform(0, 5, shape).astype(np.float32),
            candidate, rng.random(shape) < 0.7)


def constant_chooser(bias: float) -> Chooser:
    return Chooser(np.zeros((len(FEATURES), 4), np.float32), np.array([0, 0, 0, 0, bias], np.float32))


def test_features_depend_on_differences_only_so_a_shifted_range_changes_nothing():
    left, network, uncertainty, candidate, accepted = candidates()
    features = chooser_features(left, network, uncertainty, candidate, accepted)
    shifted = chooser_features(left, network - 12, uncertainty, candidate - 12, accepted)
    assert features.shape == (48, 64, len(FEATURES)) and features.dtype == np.float32
    assert np.all(np.isfinite(features))
    np.testing.assert_allclose(features, shifted, atol=1e-4)


def test_a_rejected_match_is_never_taken():
    left, network, uncertainty, candidate, accepted = candidates(1)
    rng = np.random.default_rng(2)
    chooser = Chooser(rng.normal(size=(len(FEATURES), 8)).astype(np.float32),
                      rng.normal(size=9).astype(np.float32))
    taken = chooser.take(left, network, uncertainty, candidate, accepted)
    assert not np.any(taken & ~accepted)
    asked = disputed(network, candidate, accepted)
    assert 0 < asked.sum() < accepted.sum()
    assert np.all(constant_chooser(30).take(left, network, uncertainty, candidate, accepted) == accepted)
    # a chooser that gives nothing to SGBM still takes the matches that agree within AGREE px
    never = constant_chooser(-30).take(left, network, uncertainty, candidate, accepted)
    assert np.all(never == (accepted & ~asked))
    assert np.all(np.abs(candidate - network)[never] <= AGREE)


def test_features_of_a_mask_are_those_pixels_of_the_full_map():
    left, network, uncertainty, candidate, accepted = candidates(6)
    full = chooser_features(left, network, uncertainty, candidate, accepted)
    asked = disputed(network, candidate, accepted)
    np.testing.assert_array_equal(chooser_features(left, network, uncertainty, candidate, accepted, where=asked),
                                  full[asked])


def test_the_weights_round_trip_through_a_card_dict():
    rng = np.random.default_rng(3)
    chooser = Chooser(rng.normal(size=(len(FEATURES), 5)).astype(np.float32), rng.normal(size=6).astype(np.float32))
    again = Chooser.from_dict(json.loads(json.dumps(chooser.to_dict())))
    features = rng.random((4, 5, len(FEATURES))).astype(np.float32)
    np.testing.assert_allclose(again.probability(features), chooser.probability(features), atol=1e-6)


WITH_EDGES = (*FEATURES[:-1], *EDGE_FEATURES, "bias")


def test_the_edge_features_say_which_surface_each_value_lies_on():
    """A step from 10 px (columns < 30) to 30 px: at a background pixel beside it the network's value
    lies on the lower surface and a match that took the near surface's value on the higher one;
    far from the step the window is flat and the jump reads 0. The other features are unchanged."""
    shape = (20, 60)
    network = np.where(np.arange(60)[None, :] < 30, 10.0, 30.0).astype(np.float32).repeat(20, axis=0)
    candidate = network.copy()
    candidate[:, 27:30] = 30.0  # SGBM took the near surface's value left of the step (fattening)
    left, uncertainty, accepted = np.ones(shape, np.float32), np.ones(shape, np.float32), np.ones(shape, bool)
    features = chooser_features(left, network, uncertainty, candidate, accepted, names=WITH_EDGES)
    plain = chooser_features(left, network, uncertainty, candidate, accepted)
    edge = {name: features[..., WITH_EDGES.index(name)] for name in EDGE_FEATURES}
    np.testing.assert_array_equal(features[..., [WITH_EDGES.index(name) for name in FEATURES]], plain)
    assert np.allclose(edge["network_jump"][:, 26:34], 20 / 32) and np.allclose(edge["network_jump"][:, :20], 0)
    assert np.allclose(edge["network_side"][:, 28], 0) and np.allclose(edge["network_side"][:, 31], 1)
    assert np.allclose(edge["candidate_side"][:, 28], 1) and np.allclose(edge["candidate_side"][:, 25], 0)


def test_a_chooser_names_its_inputs_and_a_card_with_unknown_ones_is_refused():
    rng = np.random.default_rng(4)
    chooser = Chooser(rng.normal(size=(len(WITH_EDGES), 5)).astype(np.float32), rng.normal(size=6).astype(np.float32),
                      features=WITH_EDGES)
    again = Chooser.from_dict(json.loads(json.dumps(chooser.to_dict())))
    assert again.features == WITH_EDGES
    assert Chooser.from_dict({"hidden": np.zeros((len(FEATURES), 2)).tolist(), "output": [0, 0, 0]}).features == FEATURES
    for features in ([*FEATURES[:-1], "sharpness", "bias"], [*FEATURES[1:], FEATURES[0]], FEATURES[:-1]):
        with pytest.raises(ValueError, match="known ones, the bias last"):
            Chooser.from_dict({**chooser.to_dict(), "features": list(features)})


def model_with_chooser(folder: Path, bias: float) -> Path:
    """A copy of the shipped card in ``folder`` (its ONNX files linked) whose chooser
    always (bias > 0) or never (bias < 0) takes the accepted match."""
    return card_copy(folder, "chooser-test", chooser=constant_chooser(bias).to_dict())


@pytest.mark.parametrize("bias", [30.0, -30.0])
def test_the_pipeline_uses_the_cards_chooser_instead_of_the_32_px_rule(tmp_path: Path, bias: float):
    """A chooser that never gives a disputed pixel to SGBM leaves the network's value
    wherever the match lies more than AGREE px away; one that always does takes SGBM's
    accepted match wherever it exists, however far from the network's."""
    pair = render_pair(np.random.default_rng(4), (64, 128), background=(6.0, 0.0), foreground=(20.0, 0.0))
    disparity_range = DisparityRange(0, 31)
    path = model_with_chooser(tmp_path, bias)
    assert read_card(path).chooser is not None
    stage = NetworkStage(model=str(path))
    result = LearnedPipeline(network=stage)(pair.left, pair.right, disparity_range)
    network = stage(pair.left, pair.right, disparity_range)
    refinement = card_refinement(read_card(path), RankSgbmRefinement())  # the shipped card's, as the pipeline's
    match, accepted = refinement.candidate(pair.left, pair.right, network, 31)
    taken = accepted if bias > 0 else accepted & (np.abs(match - network) <= AGREE)
    expected = np.where(taken, np.clip(match, 0, 31), network)
    np.testing.assert_allclose(result.disparity[result.valid], expected[result.valid], atol=1e-5)


@pytest.mark.parametrize("edge_features", [False, True])
def test_fitting_learns_which_candidate_to_trust(tmp_path: Path, edge_features: bool):
    """Synthetic caches: SGBM's match is right where it lies within 4 px of the network's
    value and wrong (by 20 px) elsewhere, and the network is off by 5 px everywhere. The
    fitted chooser must take the near matches and leave the far ones."""
    pytest.importorskip("torch")
    from cade_cli.train.chooser import fit

    rng = np.random.default_rng(5)
    chooser = fit(near_far_caches(tmp_path, rng), hidden=8, steps=300, edge_features=edge_features)
    assert chooser.features == (WITH_EDGES if edge_features else FEATURES)
    assert near_far_agreement(chooser, rng) > 0.95


def test_both_tiers_name_shipped_cards_whose_choosers_load():
    """--model fast / accurate: each tier's card is shipped, its files verify, and its
    chooser (fitted by `python -m cade_cli.train chooser`) has the runtime's inputs: the
    perceptron's features, or the convolutional chooser's planes and a file that verifies."""
    from cade_cli.matching.chooser_net import PLANES, ChooserNet, load_chooser
    from cade_cli.matching.network import onnx_session
    from cade_cli.model_card import DEFAULT_MODEL, TIERS

    assert TIERS["fast"] == DEFAULT_MODEL
    for tier, name in TIERS.items():
        card = read_card(tier)
        assert card.name == name
        for variant in card.variants:
            onnx_session(variant.path, variant.sha256)
        assert card.chooser is not None
        chooser = load_chooser(card.chooser, card.variants[0].path.parent)
        if isinstance(chooser, ChooserNet):
            assert chooser.planes == PLANES
            onnx_session(chooser.path, chooser.sha256)
        else:
            assert chooser.features == FEATURES
            assert chooser.hidden.shape[0] == len(FEATURES) and chooser.output.shape == (chooser.hidden.shape[1] + 1,)


def test_the_edge_weight_weighs_only_the_pixels_near_a_depth_jump(tmp_path: Path):
    """A cached scene with one depth jump (10 px to 30 px at column 30): with edge weight W the
    disputed pixels within 3 px of it weigh 1 + W times what they weigh without; the others, the
    features and the labels are those of the fit without it."""
    pytest.importorskip("torch")
    from cade_cli.train.chooser import samples

    rng = np.random.default_rng(6)
    shape = (20, 60)
    gt = np.where(np.arange(60)[None, :] < 30, 10.0, 30.0).astype(np.float32).repeat(20, axis=0)
    columns = np.broadcast_to(np.arange(60, dtype=np.float32), shape)  # the left band: a ramp
    network = (gt + rng.uniform(-6, 6, shape)).astype(np.float32)
    np.savez(tmp_path / "scene.npz", gt=gt, RB_network=network, RB_uncertainty=np.ones(shape, np.float32),
             RB_candidate=(gt + rng.uniform(-6, 6, shape)).astype(np.float32), RB_accepted=np.ones(shape, bool),
             RB_left=columns / 60)
    plain = samples([tmp_path / "scene.npz"], np.random.default_rng(0), per_task=400)
    weighed = samples([tmp_path / "scene.npz"], np.random.default_rng(0), per_task=400, edge_weight=4.0)
    np.testing.assert_array_equal(plain[0], weighed[0])
    np.testing.assert_array_equal(plain[1], weighed[1])
    ratio = weighed[2] / plain[2]
    assert set(np.round(ratio, 5)) == {1.0, 5.0}
    assert 0 < (ratio == 5.0).mean() < 8 / 60  # within the band of columns 26..33 (8 of 60; the pixels the
    # network hides from the right view, left of the jump, are not sampled)


def test_a_real_scenes_cache_written_before_the_right_bands_gets_each_tasks_right_band(tmp_path: Path):
    """cache_candidates' scenes cached without their right bands (as before 2026-12-07) get each task's, as the
    task's bands are made (no network run: the other arrays as they were); a complete cache is not rewritten."""
    from types import SimpleNamespace

    from cade_cli.evaluation.protocols import get_protocol
    from cade_cli.train.chooser import add_right_bands, save_atomically, tasks_of

    rng = np.random.default_rng(8)
    scene = SimpleNamespace(left=rng.integers(0, 255, (20, 30, 3)).astype(np.uint8),
                            right=rng.integers(0, 255, (20, 30, 3)).astype(np.uint8))
    tasks = get_protocol("cs").tasks[:2]
    keys = [task.name.replace(">", "") for task in tasks]
    arrays = {"gt": rng.random((20, 30)).astype(np.float32)}
    for task, key in zip(tasks, keys):
        arrays.update({f"{key}_{name}": rng.random((20, 30)).astype(np.float32)
                       for name in ("network", "uncertainty", "candidate")})
        arrays.update({f"{key}_accepted": np.ones((20, 30), bool),
                       f"{key}_left": task.bands(scene.left, scene.right)[0]})
    target = tmp_path / "scene.npz"
    save_atomically(target, arrays)
    add_right_bands(target, scene)
    for (_, task), spec in zip(tasks_of(target), sorted(tasks, key=lambda t: t.name.replace(">", ""))):
        np.testing.assert_array_equal(task["right"], spec.bands(scene.left, scene.right)[1])
    with np.load(target) as stored:
        for key, value in arrays.items():
            np.testing.assert_array_equal(stored[key], value)
    written = target.stat().st_mtime_ns
    add_right_bands(target, scene)
    assert target.stat().st_mtime_ns == written
