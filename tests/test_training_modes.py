"""The training ablation's modes (pristine / CSDL / CADE pairs) and the runtime honouring a
card's ``input`` (a pristine or CSDL network sees rescaled bands, not CADE transforms)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.matching.base import DisparityRange
from cade_cli.model_card import card_path, read_card
from cade_cli.spectral import color_agnostic, normalised
from cade_cli.train.pairs import CSDL_BANDS, PRISTINE_BANDS, cade_pair, network_input_of, training_pair
from cade_cli.train.scenes import StereoScene


def _scene(seed: int = 0, *, same_views: bool = False) -> StereoScene:
    rng = np.random.default_rng(seed)
    left = rng.random((40, 56, 3), dtype=np.float32)
    right = left.copy() if same_views else rng.random((40, 56, 3), dtype=np.float32)
    disparity = np.zeros((40, 56), np.float32)
    return StereoScene(left=left, right=right, disparity=disparity, nonoccluded=np.ones((40, 56), bool))


def test_cade_mode_is_the_cade_pair_itself():
    scene = _scene()
    a = training_pair(scene, np.random.default_rng(3), "cade")
    b = cade_pair(scene, np.random.default_rng(3))
    assert a.bands == b.bands
    np.testing.assert_array_equal(a.left, b.left)
    np.testing.assert_array_equal(a.right, b.right)


def test_pristine_pairs_show_both_views_through_the_same_channel_untransformed():
    scene = _scene(same_views=True)
    for seed in range(6):
        pair = training_pair(scene, np.random.default_rng(seed), "pristine")
        left_name, right_name = pair.bands
        assert left_name == right_name and left_name in PRISTINE_BANDS
        np.testing.assert_array_equal(pair.left, pair.right)  # identical views, identical channel
        channel = scene.left[..., PRISTINE_BANDS.index(left_name)]
        np.testing.assert_allclose(pair.left, normalised(channel), atol=1e-6)  # no color agnostic transform
        assert pair.left.min() == 0.0 and pair.left.max() == pytest.approx(1.0)


def test_csdl_pairs_draw_weighted_sum_bands_independently_with_noise():
    scene = _scene(same_views=True)
    names, differ = set(), 0
    for seed in range(20):
        pair = training_pair(scene, np.random.default_rng(seed), "csdl")
        names.update(pair.bands)
        differ += not np.array_equal(pair.left, pair.right)
        assert 0.0 <= pair.left.min() and pair.right.max() <= 1.0
        assert not np.allclose(pair.left, color_agnostic(pair.left))
    assert names <= set(CSDL_BANDS) and len(names) > 1
    assert differ == 20  # even the same band of the same view differs: noise per view


def test_unknown_mode_is_refused():
    with pytest.raises(ValueError, match="training mode"):
        training_pair(_scene(), np.random.default_rng(0), "grey")


def test_a_card_says_how_its_network_takes_its_bands(tmp_path: Path, monkeypatch):
    import cade_cli.matching.network as network

    assert read_card("cade-v4").input == "cade" and network_input_of("pristine") == "normalised"
    shipped = card_path("cade-v4")
    card = json.loads(shipped.read_text())
    for variant in card["variants"]:
        (tmp_path / variant["file"]).symlink_to((shipped.parent / variant["file"]).resolve())
    seen = []

    def capture(session, divisor, left, right):
        seen.append((left, right))
        return network.NetworkOutput(np.zeros_like(left), np.zeros_like(left))

    monkeypatch.setattr(network, "run_network_outputs", capture)
    rng = np.random.default_rng(1)
    left, right = (rng.random((48, 64), dtype=np.float32) * 200 + 20 for _ in range(2))
    for kind, expected in (("normalised", normalised), ("cade", color_agnostic)):
        (tmp_path / f"{kind}.json").write_text(json.dumps({**card, "input": kind}))
        network.NetworkStage(model=str(tmp_path / f"{kind}.json")).estimate(left, right, DisparityRange(0, 40))
        np.testing.assert_array_equal(seen[-1][0], expected(left))
        np.testing.assert_array_equal(seen[-1][1], expected(right))
    (tmp_path / "odd.json").write_text(json.dumps({**card, "input": "raw"}))
    with pytest.raises(CadeError, match="input 'raw'"):
        read_card(tmp_path / "odd.json")


@pytest.mark.parametrize("mode, chosen, expected", [("pristine", None, "normalised"), ("cade", None, "cade"),
                                                    ("cade", "cade-floor", "cade-floor")])
def test_a_run_in_a_mode_exports_a_card_with_that_modes_input(tmp_path: Path, small_validation, mode, chosen,
                                                              expected):
    pytest.importorskip("torch")
    from cade_cli.train.config import TrainConfig
    from cade_cli.train.export import export_checkpoint
    from cade_cli.train.fit import train

    config = TrainConfig(out=str(tmp_path / mode), textures=[], steps=1, batch=1, height=32, width=64, levels=16,
                         workers=0, validate_every=1, training_mode=mode, network_input=chosen)
    card = export_checkpoint(train(config), tmp_path / f"{mode}.onnx", tmp_path / f"{mode}.json", other_ranges=())
    assert card["input"] == expected and card["train_config"]["training_mode"] == mode
    assert read_card(tmp_path / f"{mode}.json").input == expected
    log = (tmp_path / mode / "log.csv").read_text()
    assert ",synthetic," in log  # validated on pairs of its own mode


def test_the_contrast_floor_keeps_a_plain_wall_plain_and_the_transform_affine_invariant():
    from cade_cli.spectral import network_input

    rng = np.random.default_rng(0)
    wall = 100 + rng.normal(0, 1, (48, 48))  # one grey level of sensor noise
    texture = np.tile(np.linspace(0, 255, 48), (48, 1)) + rng.normal(0, 20, (48, 48))
    band = np.concatenate([wall, texture], axis=1)
    paper, floored = network_input(band, "cade"), network_input(band, "cade-floor")
    assert paper[:, 4:44].std() > 0.25  # the paper's transform stretches the noise to full contrast
    assert floored[:, 4:44].std() < 0.1 and abs(float(floored[:, 4:44].mean()) - 0.5) < 0.05
    assert floored[:, 52:].std() > 0.15  # texture stays
    np.testing.assert_allclose(network_input(3 * band + 7, "cade-floor"), floored, atol=1e-5)


def test_a_network_input_is_chosen_in_the_cade_mode_only():
    scene = _scene()
    floored = training_pair(scene, np.random.default_rng(3), "cade", "cade-floor")
    assert floored.bands == training_pair(scene, np.random.default_rng(3), "cade").bands
    with pytest.raises(ValueError, match="cade training mode only"):
        training_pair(scene, np.random.default_rng(3), "pristine", "cade-floor")
