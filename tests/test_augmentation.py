"""The network stage's test-time augmentation (cade_cli.matching.augmentation): the second scale and the
mirrored pair's left-right check, each against disparities it must recover."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from cade_cli import model_card
from cade_cli.matching import augmentation, densify, get_matcher, network
from cade_cli.matching.augmentation import NetworkOutput
from cade_cli.model_card import DEFAULT_MODEL, read_card
from synthetic import render_pair


def augmented_card(tmp_path, entries: list[str]):
    """The shipped network's card with ``test_time_augmentation`` ``entries``, in a folder of its own."""
    card = json.loads(model_card.card_path(DEFAULT_MODEL).read_text())
    tmp_path.mkdir(exist_ok=True)
    for variant in card["variants"]:
        (tmp_path / variant["file"]).symlink_to(model_card.card_path(DEFAULT_MODEL).parent / variant["file"])
    path = tmp_path / "augmented.json"
    path.write_text(json.dumps({**card, "name": "augmented", "test_time_augmentation": entries}))
    return path


def test_the_second_scale_is_lowered_to_the_searchable_span_and_skipped_when_too_small():
    assert augmentation.second_scale(2.0, 60, 184) == 2.0
    assert augmentation.second_scale(2.0, 120, 184) == pytest.approx(184 / 120)
    assert augmentation.second_scale(1.5, 170, 184) is None  # 1.08: not worth a pass


def test_an_upscaled_pass_runs_on_enlarged_bands_and_returns_disparity_in_the_levels_pixels():
    seen = []

    def run(left, right):  # a network that finds 6 px everywhere, uncertain by 3 px, on what it is given
        seen.append((left.shape, right.shape, float(left.max())))
        return NetworkOutput(np.full(left.shape, 6.0, np.float32), np.full(left.shape, 3.0, np.float32))

    band = np.linspace(0, 1, 40 * 64, dtype=np.float32).reshape(40, 64)
    output = augmentation.upscaled_pass(run, lambda raw: raw + 10.0, band, band, (64, 40), 2.0)
    assert seen == [((80, 128), (80, 128), pytest.approx(11.0, abs=0.01))]  # enlarged (bicubic), then made input
    assert output.disparity.shape == (40, 64)
    np.testing.assert_allclose(output.disparity, 3.0, atol=1e-5)  # 6 px of the enlarged pair
    np.testing.assert_allclose(output.uncertainty, 1.5, atol=1e-5)


def test_on_a_pyramid_level_the_second_scale_shrinks_the_raw_bands_by_area():
    """Level bands of 32 x 20 (a quarter of the raw 64 x 40 pair's area) enlarged 1.5 times: 48 x 30, still below
    the raw size, so one-pixel stripes average to grey instead of aliasing."""
    seen = []

    def run(left, right):
        seen.append((left.shape, float(left.min()), float(left.max())))
        return NetworkOutput(np.zeros_like(left), np.zeros_like(left))

    stripes = np.tile(np.array([0.0, 1.0], np.float32), (40, 32))
    augmentation.upscaled_pass(run, lambda raw: raw, stripes, stripes, (32, 20), 1.5)
    (shape, low, high), = seen
    assert shape == (30, 48) and 0.2 < low <= high < 0.8  # bicubic: 0.07 to 0.93


def test_the_right_views_estimate_is_sampled_where_each_left_pixel_lands():
    ramp = np.tile(np.arange(32, dtype=np.float32), (4, 1))  # the right view's value: its own column
    warped, inside = augmentation.warp_to_left(NetworkOutput(ramp, ramp), np.full((4, 32), 5.0, np.float32))
    np.testing.assert_allclose(warped.disparity[:, 5:], ramp[:, :-5], atol=1e-5)
    assert not inside[:, :5].any() and inside[:, 5:].all()


def test_the_left_right_check_averages_consistent_pixels_and_keeps_the_plain_pass_elsewhere():
    plain = NetworkOutput(np.full((2, 40), 10.0, np.float32), np.full((2, 40), 0.5, np.float32))
    right = np.full((2, 40), 10.4, np.float32)
    right[:, 20:25] = 30.0  # seen from the right, columns 20-24 hold another surface
    fused = augmentation.left_right_fuse(plain, NetworkOutput(right, np.full((2, 40), 0.5, np.float32)))
    for consistent in (np.s_[:, 10:29], np.s_[:, 36:]):  # left x lands on right x - 10
        np.testing.assert_allclose(fused.disparity[consistent], 10.2, atol=1e-5, err_msg="consistent: the mean")
    np.testing.assert_allclose(fused.disparity[:, 30:35], 10.0, atol=1e-5, err_msg="inconsistent: the plain pass")
    np.testing.assert_allclose(fused.disparity[:, :10], 10.0, atol=1e-5, err_msg="outside the right view")


def test_the_mirrored_pass_recovers_the_right_views_disparity(rng):
    """The shipped network on the pair mirrored and swapped gives the right view's disparity: the
    foreground rectangle appears shifted left by its disparity, not mirrored."""
    pair = render_pair(rng, (96, 192), background=(6.0, 0.0), foreground=(18.0, 0.0))
    card = read_card(DEFAULT_MODEL)
    session = network.onnx_session(card.variants[0].path, card.variants[0].sha256)
    bands = [network.network_input(band, card.input) for band in (pair.left, 0.1 + 0.6 * pair.right ** 1.8)]
    run = functools.partial(network.run_network_outputs, session, card.divisor)
    right_view = augmentation.mirrored_pass(run, *bands)
    columns = np.arange(192)
    foreground = pair.disparity[48, :] > 12  # the left view's foreground columns on a middle row
    expected = np.where(foreground[np.clip(columns + 18, 0, 191)], 18.0, 6.0)
    away = np.ones(192, bool)
    for edge in np.flatnonzero(np.diff(expected)):
        away[max(0, edge - 4):edge + 6] = False
    away[:8] = away[-8:] = False
    rows = slice(32, 64)  # inside the rectangle's rows, away from its top and bottom
    assert np.abs(right_view.disparity[rows][:, away] - expected[away]).mean() < 1.0


@pytest.mark.parametrize("entries", [["upscaled-x2", "mirrored"], ["upscaled-x1.5"]])
def test_a_card_with_a_second_scale_and_the_mirrored_pair_recovers_a_rendered_disparity(rng, monkeypatch, tmp_path,
                                                                                       entries):
    path = augmented_card(tmp_path, entries)
    pair = render_pair(rng, (96, 160), background=(9.3, 0.0))
    other_band = 1.0 - (0.1 + 0.6 * pair.right**1.8)  # another filter: gamma, gain, inverted contrast
    passes = []
    plain_run = network.run_network_outputs
    monkeypatch.setattr(network, "run_network_outputs", lambda session, divisor, left, right:
                        passes.append((left.copy(), right.copy())) or plain_run(session, divisor, left, right))
    result = get_matcher("cade", model=str(path))(pair.left, other_band, max_disp=32)
    assert read_card(path).test_time == tuple(entries) and len(passes) == len(entries) + 1
    factor = {"upscaled-x2": 2, "upscaled-x1.5": 1.5}[entries[0]]
    assert passes[1][0].shape == (round(96 * factor), round(160 * factor))
    if "mirrored" in entries:
        np.testing.assert_array_equal(passes[2][0], passes[0][1][:, ::-1])
        np.testing.assert_array_equal(passes[2][1], passes[0][0][:, ::-1])
    assert np.abs(densify(result.disparity, result.valid) - pair.disparity)[pair.reliable].mean() < 1.0


def test_the_memory_plan_counts_the_pair_enlarged_for_a_second_scale(tmp_path):
    from cade_cli.scale.memory import ENLARGED_PIXEL_BYTES, tile_memory_bytes

    plain = tile_memory_bytes("cade", 400, 300, 64)
    mirrored = tile_memory_bytes("cade", 400, 300, 64, model=str(augmented_card(tmp_path / "a", ["mirrored"])))
    enlarged = tile_memory_bytes("cade", 400, 300, 64, model=str(augmented_card(tmp_path / "b", ["upscaled-x2"])))
    assert mirrored == plain and enlarged == plain + ENLARGED_PIXEL_BYTES * 4 * 400 * 300
