"""The shipped CADE network, run through onnxruntime (no torch)."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from cade_cli import model_card
from cade_cli.errors import CadeError
from cade_cli.matching import MATCHERS, densify, get_matcher, network
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.learned import LearnedPipeline
from cade_cli.matching.network import choose_variant, pyramid_factor, shift_right_view, strips
from cade_cli.matching.refinement import RankSgbmRefinement, correlation, inverted_regions
from cade_cli.model_card import DEFAULT_MODEL, TIERS, ModelCard, ModelVariant, read_card
from synthetic import render_pair

CADE = MATCHERS["cade"]
REFINE = RankSgbmRefinement()


def dense(result) -> np.ndarray:
    return densify(result.disparity, result.valid)


@pytest.mark.parametrize("name", [DEFAULT_MODEL, *TIERS.values(), "cade-v4"])
def test_shipped_models_match_their_cards(name):
    card = read_card(name)
    assert card.variants
    for variant in card.variants:
        assert variant.path.is_file() and variant.levels % card.divisor == 0
        network.onnx_session(variant.path, variant.sha256)  # verifies the sha256


def test_a_retired_model_is_refused_by_name_with_the_commit_that_has_it(monkeypatch):
    monkeypatch.delenv(model_card.MODEL_DIR_ENV, raising=False)
    for name in model_card.RETIRED_MODELS:
        assert not (model_card.model_dir() / f"{name}.json").exists()
        with pytest.raises(CadeError, match=f"{name} is retired.*commit 85fb266") as refused:
            read_card(name)
        assert "\n" not in str(refused.value)


def test_a_session_follows_the_thread_count_set_after_the_first_was_built(monkeypatch):
    """`use_threads` sets $OMP_NUM_THREADS for pools created later: a model's session is kept per
    thread count, so a run after the change gets a session with the new count (the count moves
    the fast design's maps slightly), and a return to the old count finds the old session."""
    variant = read_card().variants[0]
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    one = network.onnx_session(variant.path, variant.sha256)
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    two = network.onnx_session(variant.path, variant.sha256)
    assert two is not one
    assert two.get_session_options().intra_op_num_threads == 2
    assert one.get_session_options().intra_op_num_threads == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert network.onnx_session(variant.path, variant.sha256) is one


def test_sessions_do_not_busy_wait_after_a_run():
    """Each run hands the cores to OpenCV's refinement; onnxruntime threads still spinning after
    it would hold them (docs/research/speed.md, 2026-11-22). Spinning threads burn about 50 ms of this
    process's CPU in the half second after a run; idle ones none (measured 2026-11-28)."""
    variant = read_card().variants[0]
    session = network.onnx_session(variant.path, variant.sha256)
    feeds = {item.name: np.zeros((1, 1, 64, 96), np.float32) for item in session.get_inputs()}
    session.run(None, feeds)
    started = time.process_time()
    time.sleep(0.5)
    assert time.process_time() - started < 0.01


def test_the_matcher_makes_no_blas_call(rng, monkeypatch):
    """A BLAS call leaves OpenBLAS's threads busy-waiting on the two cores the network and
    OpenCV need next; one np.dot in the inversion check cost about a fifth of the matcher's
    time (docs/research/speed.md, 2026-11-22)."""
    def refuse(*args, **kwargs):
        raise AssertionError("BLAS routine called by the cade matcher")

    for name in ("dot", "vdot", "inner", "matmul", "tensordot", "einsum"):
        monkeypatch.setattr(np, name, refuse)
    pair = render_pair(rng, (96, 160), background=(9.3, 0.0))
    result = CADE(pair.left, 1.0 - pair.right, max_disp=32)  # inverted contrast: the check's correlation runs
    assert np.abs(dense(result) - pair.disparity)[pair.reliable].mean() < 1.0


@pytest.mark.parametrize("shape", [(7, 9), (40, 3)])
def test_correlation_is_pearsons(rng, shape):
    left, right = rng.random(shape, dtype=np.float32), rng.random(shape, dtype=np.float32)
    right += 0.5 * left
    expected = np.corrcoef(left.ravel().astype(np.float64), right.ravel().astype(np.float64))[0, 1]
    assert correlation(left, right) == pytest.approx(expected, rel=1e-9)
    assert correlation(left, -right) == pytest.approx(-expected, rel=1e-9)
    assert correlation(left, np.full(shape, 0.3, np.float32)) == 0.0


def test_a_damaged_model_is_refused(tmp_path: Path, monkeypatch):
    card = read_card()
    for variant in card.variants:
        shutil.copy(variant.path, tmp_path / variant.path.name)
    narrowest = tmp_path / card.variants[0].path.name
    with open(narrowest, "r+b") as stream:
        stream.seek(-10, 2)
        stream.write(b"0123456789")
    shutil.copy(model_dir_card(), tmp_path)
    monkeypatch.setenv(model_card.MODEL_DIR_ENV, str(tmp_path))
    band = np.random.default_rng(0).random((32, 48)).astype(np.float32)
    with pytest.raises(CadeError, match="sha256"):
        CADE(band, band, max_disp=8)


def model_dir_card() -> Path:
    return model_card.card_path()


def test_a_card_is_parsed_once_per_version_of_its_file(tmp_path: Path):
    """The matcher reads the card on every pair and tile: an unchanged file gives the parsed card
    back from the cache; a changed one (here: a test-time pass added) is read again."""
    card = json.loads(model_card.card_path(DEFAULT_MODEL).read_text())
    path = tmp_path / "card.json"
    path.write_text(json.dumps(card))
    first = model_card.read_card(path)
    assert model_card.read_card(path) is first
    card["test_time_augmentation"] = ["upscaled-x1.5"]
    path.write_text(json.dumps(card, indent=1))  # another size, so another version whatever the clock
    changed = model_card.read_card(path)
    assert changed is not first and changed.test_time == ("upscaled-x1.5",)
    assert model_card.network_fingerprint(path)["test_time_augmentation"] == ["upscaled-x1.5"]


def test_variant_choice_prefers_full_resolution_then_the_narrowest_search():
    card = ModelCard("m", tuple(ModelVariant(Path(f"m{d}.onnx"), "", d) for d in (256, 128, 96, 192)), 8)
    margin = network.RANGE_MARGIN
    chosen = {span: (variant.levels, factor) for span in (10, 88, 89, 120, 121, 184, 185, 248, 249, 600)
              for variant, factor in [choose_variant(card, span)]}
    assert margin == 8 and chosen == {10: (96, 1), 88: (96, 1), 89: (128, 1), 120: (128, 1), 121: (192, 1),
                                      184: (192, 1), 185: (256, 1), 248: (256, 1), 249: (192, 2), 600: (192, 4)}


def test_a_missing_card_names_the_environment_variable(tmp_path: Path, monkeypatch):
    monkeypatch.setenv(model_card.MODEL_DIR_ENV, str(tmp_path))
    band = np.zeros((32, 48), np.float32)
    with pytest.raises(CadeError, match=model_card.MODEL_DIR_ENV):
        CADE(band, band, max_disp=8)
    model_card.card_path().write_text(json.dumps({"format": model_card.CARD_FORMAT, "file": "x.onnx"}))
    with pytest.raises(CadeError, match="malformed"):
        CADE(band, band, max_disp=8)


def test_raw_bands_are_refused():
    band = np.zeros((32, 48), np.float32)
    with pytest.raises(CadeError, match="cade"):
        CADE(band, band, max_disp=8, preprocess="none")


@pytest.mark.parametrize("shift", [-7, 0, 5])
def test_shift_right_view_moves_columns(shift):
    right = np.arange(40, dtype=np.float32).reshape(2, 20)
    shifted = shift_right_view(right, shift)
    for x in range(20):
        np.testing.assert_array_equal(shifted[:, x], right[:, min(max(x - shift, 0), 19)])


@pytest.mark.parametrize("span, searchable, factor", [(10, 120, 1), (120, 120, 1), (121, 120, 2), (500, 120, 8)])
def test_pyramid_factor(span, searchable, factor):
    assert pyramid_factor(span, searchable) == factor


@given(height=st.integers(1, 3000), width=st.integers(1, 4000), max_pixels=st.integers(10_000, 2_000_000))
def test_strips_tile_the_rows_within_the_pixel_budget(height, width, max_pixels):
    bands = strips(height, width, max_pixels=max_pixels, overlap=32)
    kept = [row for _, _, keep_start, keep_stop in bands for row in range(keep_start, keep_stop)]
    assert kept == list(range(height))
    for start, stop, keep_start, keep_stop in bands:
        assert 0 <= start <= keep_start < keep_stop <= stop <= height
        assert (stop - start) * width <= max(max_pixels, 128 * width)
        if len(bands) > 1:  # every kept row has context from its neighbours (or the border)
            assert keep_start - start >= 16 or start == 0
            assert stop - keep_stop >= 16 or stop == height


@pytest.mark.parametrize("scene", [dict(background=(9.3, 0.0)), dict(background=(6.0, 0.03), foreground=(20.0, 0.0))])
def test_recovers_rendered_disparity_across_bands(rng, scene):
    pair = render_pair(rng, (96, 160), **scene)
    other_band = 1.0 - (0.1 + 0.6 * pair.right**1.8)  # another filter: gamma, gain, inverted contrast
    result = CADE(pair.left, other_band, max_disp=32)
    error = np.abs(dense(result) - pair.disparity)[pair.reliable]
    assert error.mean() < 1.0
    assert result.valid[pair.reliable].mean() > 0.8


def test_occluded_pixels_are_invalid_and_filled_from_the_background(rng):
    pair = render_pair(rng, (96, 160), background=(6.0, 0.0), foreground=(21.0, 0.0))
    result = CADE(pair.left, pair.right, max_disp=32)
    assert pair.occluded.sum() > 100
    # background side (6 px; the foreground side would be 15 px off): cade-v4 0.51 px, cade-v11 0.80
    # on this pair (cade-v10 0.88; cade-v9, the shipped model for an hour on 2026-11-25: 1.23)
    assert np.median(np.abs(dense(result) - pair.disparity)[pair.occluded]) < 2.0
    assert result.valid[pair.reliable].mean() > 0.95
    # invalid: the left border (matches leave the right view) and around the occlusion
    # beside the foreground (rows 24..71, left edge at x = 53), hardly anywhere else
    rows, columns = np.nonzero(~result.valid)
    near_occlusion = (rows >= 20) & (rows < 76) & (np.abs(columns - 45) < 20)
    assert near_occlusion.sum() > 50 and (near_occlusion | (columns < 32)).mean() > 0.97


def test_negative_range_by_pre_shifting(rng):
    pair = render_pair(rng, (96, 160), background=(-11.6, 0.0))
    result = CADE(pair.left, pair.right, min_disp=-24, max_disp=8)
    assert np.abs(dense(result) - pair.disparity)[pair.reliable].mean() < 1.0
    assert np.nanmin(result.disparity) >= -24 and np.nanmax(result.disparity) <= 8


def test_widest_variant_runs_at_full_resolution(rng, monkeypatch):
    """A card with several range variants (cade-v4's: 96 and 128 levels of the same 3D weights; the
    test needs a 3D CadeNet, whose weights run at any range) runs the widest at full size for a span
    it covers; a CadeNet2D card (cade-v13) has one."""
    card = read_card("cade-v4")
    narrow, wide = card.variants[-2].levels, card.variants[-1].levels
    pair = render_pair(rng, (96, 2 * narrow + 96), background=(narrow - 3.4, 0.0), foreground=(narrow + 14.0, 0.0))
    chosen = []

    def recording(card, span):
        chosen.append(choose_variant(card, span))
        return chosen[-1]

    monkeypatch.setattr(network, "choose_variant", recording)
    result = get_matcher("cade", model="cade-v4")(pair.left, pair.right, max_disp=wide - network.RANGE_MARGIN)
    assert [(variant.levels, factor) for variant, factor in chosen] == [(wide, 1)]
    assert np.abs(dense(result) - pair.disparity)[pair.reliable].mean() < 1.0


def test_range_beyond_the_network_runs_on_a_pyramid_level(rng):
    widest = read_card().variants[-1].levels
    pair = render_pair(rng, (128, 2 * widest + 96), background=(widest + 21.0, 0.0))
    result = CADE(pair.left, pair.right, max_disp=widest + 40)
    assert np.abs(dense(result) - pair.disparity)[pair.reliable].mean() < 2.0


def test_strips_give_the_same_map_as_one_pass(rng, monkeypatch):
    pair = render_pair(rng, (200, 160), background=(7.0, 0.02), foreground=(15.0, 0.0))
    whole = CADE(pair.left, pair.right, max_disp=24)
    monkeypatch.setattr(network, "STRIP_PIXELS", 160 * 140)
    assert len(network.strips(200, 160, max_pixels=network.STRIP_PIXELS)) > 1
    split = CADE(pair.left, pair.right, max_disp=24)
    close = np.abs(dense(split) - dense(whole)) < 0.25
    assert close[pair.reliable].mean() > 0.98


def test_kernel_takes_raw_bands_and_output_is_unfilled(rng):
    # The matcher hands the kernel the raw bands (it transforms them itself), so the
    # refinement can match them; --preprocess cade is the only mode it accepts.
    assert CADE.preprocessing == ("cade",)
    pair = render_pair(rng, (64, 96), background=(5.0, 0.0))
    result = LearnedPipeline()(pair.left, pair.right, DisparityRange(0, 16))
    assert result.disparity.dtype == np.float32 and result.valid.dtype == bool
    assert result.valid.shape == pair.left.shape and not result.valid.all()  # the left border leaves the view
    assert np.array_equal(np.isnan(result.disparity), ~result.valid)


# ---- refinement: semi-global matching of the raw bands, overruling the network where they agree

REFINE_BANDS = {
    "same band": lambda band: band,
    "other filter (gain, gamma)": lambda band: 0.1 + 0.6 * band**1.8,
    "inverted contrast": lambda band: 1.0 - (0.1 + 0.6 * band**1.8),
}


@pytest.mark.parametrize("other_band", REFINE_BANDS.values(), ids=REFINE_BANDS.keys())
@pytest.mark.parametrize("offset", [-9.0, 5.0, 13.0, 27.0])
def test_refinement_corrects_an_estimate_that_is_off_within_the_agreement(rng, offset, other_band):
    pair = render_pair(rng, (96, 192), background=(8.3, 0.04), foreground=(19.6, 0.0))
    estimate = (pair.disparity + offset).astype(np.float32)  # a network that is off by `offset`
    assert abs(offset) < REFINE.agreement
    refined = REFINE(pair.left, other_band(pair.right), estimate, DisparityRange(0, 48))
    error = np.abs(refined - pair.disparity)[pair.reliable]
    assert np.median(error) < 0.3 and (error < 1).mean() > 0.9


def test_refinement_recovers_a_thin_structure_the_network_missed(rng):
    """A 10-px bar 24 px in front of the background (2.5 px at the network's 1/4 resolution),
    which the estimate (a network that blurred it away entirely) does not show."""
    pair = render_pair(rng, (96, 192), background=(6.0, 0.0), foreground=(30.0, 0.0), box=(16, 80, 120, 130), margin=1)
    bar = pair.reliable & (pair.disparity > 20)
    assert bar.sum() > 100
    estimate = np.full_like(pair.disparity, 6.0)
    refined = REFINE(pair.left, 0.1 + 0.6 * pair.right**1.8, estimate, DisparityRange(0, 48))
    assert np.median(np.abs(refined - pair.disparity)[bar]) < 0.5


def test_refinement_keeps_the_network_beyond_the_agreement(rng):
    pair = render_pair(rng, (96, 192), background=(8.3, 0.04), foreground=(19.6, 0.0))
    estimate = (pair.disparity + 1.5 * REFINE.agreement).astype(np.float32)
    refined = REFINE(pair.left, pair.right, estimate, DisparityRange(0, 80))
    assert (refined == estimate)[pair.reliable].mean() > 0.95


def test_refinement_leaves_unrelated_bands_to_the_network(rng):
    """Bands that share no structure (the R and G planes of random colour textures) must
    not overrule the network: SGBM's rejections keep its value."""
    pair = render_pair(rng, (96, 192), background=(8.3, 0.04), foreground=(19.6, 0.0))
    unrelated = render_pair(rng, (96, 192), background=(8.3, 0.04), foreground=(19.6, 0.0)).right
    estimate = (pair.disparity + 3.0).astype(np.float32)
    refined = REFINE(pair.left, unrelated, estimate, DisparityRange(0, 48))
    assert (refined == estimate)[pair.reliable].mean() > 0.6  # about 0.8; 0.3 without the rejections


def invert_columns(band: np.ndarray, first: int) -> np.ndarray:
    """``band`` with its contrast inverted from column ``first`` on."""
    return np.where(np.arange(band.shape[1])[None, :] >= first, 1.0 - band, band).astype(np.float32)


@pytest.mark.parametrize("inverted", ["nowhere", "everywhere", "right half", "small patch"])
def test_inverted_regions_find_where_contrast_is_reversed(rng, inverted):
    pair = render_pair(rng, (96, 384), background=(8.3, 0.0))
    other = 0.1 + 0.6 * pair.right**1.8
    if inverted == "everywhere":
        other = 1.0 - other
    elif inverted == "right half":
        other = invert_columns(other, 192)
    elif inverted == "small patch":  # 3 % of the view: below the share that counts as a region
        other[32:64, 176:208] = 1.0 - other[32:64, 176:208]
    flipped = inverted_regions(pair.left, other, pair.disparity)
    assert flipped.shape == pair.left.shape
    if inverted == "everywhere":
        assert flipped.all()
    elif inverted == "right half":  # matches land in the inverted half from column 192 + 8.3 on
        assert not flipped[:, :150].any() and flipped[:, 250:].mean() > 0.95
    else:
        assert not flipped.any()


def test_refinement_matches_across_a_regional_inversion(rng):
    """Half of the right band is inverted (as vegetation is between red and NIR): the
    flipped ranks let SGBM correct the estimate there too."""
    pair = render_pair(rng, (96, 384), background=(8.3, 0.04), foreground=(19.6, 0.0))
    other = invert_columns(0.1 + 0.6 * pair.right**1.8, 192)
    estimate = (pair.disparity + 5.0).astype(np.float32)
    refined = REFINE(pair.left, other, estimate, DisparityRange(0, 48))
    error = np.abs(refined - pair.disparity)
    for half in (np.s_[:, :180], np.s_[:, 220:]):
        assert np.median(error[half][pair.reliable[half]]) < 0.3


def test_a_single_disparity_leaves_nothing_to_refine(rng):
    """The refinement stage leaves a one-value range's estimate as it is; the matcher itself refuses
    such a range (issue 40: it would report every pixel valid at the one disparity)."""
    band = rng.random((16, 64)).astype(np.float32)
    estimate = np.full_like(band, 20.0)
    assert np.array_equal(REFINE(band, band, estimate, DisparityRange(20, 20)), estimate)
    with pytest.raises(CadeError, match=r"\[20, 20\] holds one value"):
        CADE(band, band, min_disp=20, max_disp=20)


def test_refinement_sharpens_the_network_on_a_rendered_pair(rng):
    pair = render_pair(rng, (96, 192), background=(7.4, 0.03), foreground=(17.2, 0.0))
    other = 0.1 + 0.6 * pair.right**1.8
    errors = {}
    for refine in (False, True):
        pipeline = LearnedPipeline(refinement=REFINE if refine else None)
        result = pipeline(pair.left, other, DisparityRange(0, 32))
        errors[refine] = np.abs(dense(result) - pair.disparity)[pair.reliable]
    assert (errors[True] < 0.5).mean() > (errors[False] < 0.5).mean() + 0.05
    assert errors[True].mean() <= errors[False].mean()


def test_two_passes_are_averaged_where_they_agree_and_the_surer_one_is_kept_where_not():
    first = network.NetworkOutput(np.array([[10.0, 10.0, 10.0]], np.float32), np.array([[0.5, 0.5, 4.0]], np.float32))
    second = network.NetworkOutput(np.array([[10.4, 20.0, 30.0]], np.float32), np.array([[0.5, 2.0, 0.5]], np.float32))
    fused = network.fuse_estimates(first, second)
    # equal uncertainty: the plain mean; 10 px apart: the surer first pass; 20 px apart: the surer second
    np.testing.assert_allclose(fused.disparity, [[10.2, 10.0, 30.0]], atol=1e-5)
    np.testing.assert_allclose(fused.uncertainty, [[0.5, 0.5, 0.5]], atol=1e-5)
    unequal = network.fuse_estimates(first, network.NetworkOutput(np.array([[11.0, 10, 10]], np.float32),
                                                                  np.array([[1.5, 0.5, 4.0]], np.float32)))
    assert 10.0 < unequal.disparity[0, 0] < 10.5  # inverse-variance weights lean on the surer pass


def test_a_card_with_test_time_augmentation_matches_the_pair_upside_down_too(rng, monkeypatch, tmp_path):
    """A card with test_time_augmentation vertical-flip (the shipped network's, in a folder of its own)
    runs the network twice, the second time on the flipped bands, and still recovers a rendered disparity."""
    card = json.loads(model_card.card_path(DEFAULT_MODEL).read_text())
    for variant in card["variants"]:
        (tmp_path / variant["file"]).symlink_to(model_card.card_path(DEFAULT_MODEL).parent / variant["file"])
    augmented = tmp_path / "flipped.json"
    augmented.write_text(json.dumps({**card, "name": "flipped", "test_time_augmentation": ["vertical-flip"]}))
    pair = render_pair(rng, (96, 160), background=(9.3, 0.0))
    other_band = 1.0 - (0.1 + 0.6 * pair.right**1.8)  # another filter: gamma, gain, inverted contrast
    passes = []
    plain_run = network.run_network_outputs
    monkeypatch.setattr(network, "run_network_outputs",
                        lambda session, divisor, left, right: passes.append(left.copy()) or plain_run(session, divisor, left, right))
    result = get_matcher("cade", model=str(augmented))(pair.left, other_band, max_disp=32)
    assert read_card(augmented).test_time == ("vertical-flip",) and len(passes) == 2
    np.testing.assert_array_equal(passes[1], passes[0][::-1])
    assert np.abs(dense(result) - pair.disparity)[pair.reliable].mean() < 1.0


def test_an_unknown_test_time_augmentation_is_refused(tmp_path):
    card = json.loads(model_card.card_path(DEFAULT_MODEL).read_text())
    card["test_time_augmentation"] = ["mirror"]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(card))
    with pytest.raises(CadeError, match="test_time_augmentation 'mirror'"):
        read_card(path)
