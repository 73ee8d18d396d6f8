"""Confidence that travels with each matcher's result, and how the evaluation scores it:
in [0, 1], 0 where invalid, lower where matching is ambiguous, free of side effects on the
disparity, ranked against the true errors by the sparsification curve, written by the CLI."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from cade_cli.evaluation.loop import run_benchmark
from cade_cli.evaluation.metrics import score, sparsification_auc, sparsification_curve
from cade_cli.evaluation.protocols import run_protocol
from cade_cli.evaluation.report import confidence_table, markdown
from cade_cli.matching import MATCHERS, DisparityResult
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.network import NetworkStage, choose_variant, onnx_session, pad_to_divisor, run_network_outputs
from cade_cli.model_card import read_card
from cade_cli.spectral import color_agnostic
from synthetic import render_pair
from cli_runner import run_cade

SHAPE = (96, 160)
BACKGROUND, FOREGROUND = 6.0, 16.0
PATCH = (12, 40, 12, 44)  # rows and columns (first, last excluded) of a constant patch on the background
NOISE = 0.005  # standard deviation of the sensor noise, in the bands' [0, 1] units


def textureless_pair(rng):
    """A rendered pair (background plane, nearer rectangle that occludes part of it) whose
    background carries a flat patch: the same constant in both views at its true position,
    then faint sensor noise on both views (without it, a census signature is exactly 0
    across the patch at every disparity, and SGM carries the surrounding plane's
    evidence through it, rightly confident)."""
    pair = render_pair(rng, SHAPE, background=(BACKGROUND, 0.0), foreground=(FOREGROUND, 0.0))
    top, bottom, first, last = PATCH
    shift = int(BACKGROUND)
    left, right = pair.left.copy(), pair.right.copy()
    left[top:bottom, first:last] = 0.5
    right[top:bottom, first - shift:last - shift] = 0.5
    left, right = (view + rng.normal(0, NOISE, SHAPE).astype(np.float32) for view in (left, right))
    flat = np.zeros(SHAPE, bool)
    flat[top + 3:bottom - 3, first + 3:last - 3] = True  # away from the patch's textured rim
    textured = pair.reliable.copy()
    textured[max(top - 8, 0):bottom + 8, max(first - 8, 0):last + 8] = False
    return dataclasses.replace(pair, left=left, right=right), flat, textured


@pytest.fixture(scope="module")
def scene():
    return textureless_pair(np.random.default_rng(7))


@pytest.mark.parametrize("name", list(MATCHERS))
def test_confidence_is_in_unit_range_and_zero_where_invalid(scene, name):
    pair, _, _ = scene
    result = MATCHERS[name](pair.left, pair.right, max_disp=24)
    confidence = result.confidence
    assert confidence.shape == pair.left.shape and confidence.dtype == np.float32
    assert np.isfinite(confidence).all() and confidence.min() >= 0 and confidence.max() <= 1
    assert (confidence[~result.valid] == 0).all()
    assert confidence[result.valid].mean() > 0.1  # not degenerate


@pytest.mark.parametrize("name", list(MATCHERS))
def test_flat_and_occluded_pixels_are_less_confident_than_textured_visible_ones(scene, name):
    pair, flat, textured = scene
    result = MATCHERS[name](pair.left, pair.right, max_disp=24)
    confidence = result.confidence
    assert pair.occluded.sum() > 50 and flat.sum() > 200
    if name == "cade-network":
        # The network's uncertainty alone: occlusions less confident (cade-v13 0.39 against 0.65
        # on texture; cade-v11 0.56 against 0.66), but not the flat patch (cade-v13 0.66; cade-v11
        # 0.57), where the network's map is right (cade-v13 0.24 px off, 0.39 on texture): its
        # context reaches across the patch, so a lower confidence there would be the wrong answer.
        # ``cade``, whose SGBM finds no unique match on the patch, is less confident there.
        assert confidence[pair.occluded].mean() < 0.9 * confidence[textured].mean()
        assert np.nanmean(np.abs(result.disparity - pair.disparity)[flat]) < 1.0
    else:
        assert confidence[pair.occluded].mean() < 0.8 * confidence[textured].mean()
        assert confidence[flat].mean() < 0.8 * confidence[textured].mean()


@pytest.mark.parametrize("name", list(MATCHERS))
def test_disparity_is_bit_identical_without_the_confidence(scene, name):
    pair, _, _ = scene
    matcher = MATCHERS[name]
    without = dataclasses.replace(matcher, kernel=dataclasses.replace(matcher.kernel, confidence=False))
    for preprocess in matcher.preprocessing:
        on = matcher(pair.left, pair.right, max_disp=24, min_disp=-3, preprocess=preprocess)
        off = without(pair.left, pair.right, max_disp=24, min_disp=-3, preprocess=preprocess)
        assert off.confidence is None and on.confidence is not None
        assert np.array_equal(on.disparity, off.disparity, equal_nan=True)
        assert np.array_equal(on.valid, off.valid)


def test_network_uncertainty_leaves_its_disparity_bit_identical(rng):
    pair = render_pair(rng, (200, 160), background=(7.0, 0.02), foreground=(15.0, 0.0))
    card = read_card()
    variant, _ = choose_variant(card, 24)
    session = onnx_session(variant.path, variant.sha256)
    left, right = color_agnostic(pair.left), color_agnostic(pair.right)
    both = run_network_outputs(session, card.divisor, left, right)
    (alone,) = session.run(["disparity"], {"left": pad_to_divisor(left, card.divisor)[0][None, None],
                                           "right": pad_to_divisor(right, card.divisor)[0][None, None]})
    assert np.array_equal(both.disparity, alone[0, 0, :200, :160])
    assert both.uncertainty.shape == (200, 160) and (both.uncertainty >= 0).all()
    stage = NetworkStage()
    estimate = stage.estimate(pair.left, pair.right, DisparityRange(0, 24))
    assert np.array_equal(estimate.disparity, stage(pair.left, pair.right, DisparityRange(0, 24)))


# ---- the sparsification curve


def test_sparsification_curve_by_hand():
    errors = np.array([4.0, 1.0, 0.0, 3.0])
    kept, epe = sparsification_curve(errors, np.array([0.1, 0.5, 0.9, 0.3]))
    np.testing.assert_allclose(kept, [0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(epe, [0.0, 0.5, 4 / 3, 2.0])  # kept by decreasing confidence: 0, 1, 3, 4
    # ties leave in random order: the curve is the expectation, each tied error counts as their mean
    _, tied = sparsification_curve(errors, np.array([0.5, 0.5, 0.9, 0.1]))
    np.testing.assert_allclose(tied, [0.0, 2.5 / 2, 5.0 / 3, 2.0])


def test_perfect_confidence_reaches_the_oracle_and_constant_confidence_the_epe(rng):
    errors = rng.exponential(2.0, 5000)
    oracle = sparsification_auc(errors, -errors)
    assert sparsification_auc(errors, 1.0 / (1.0 + errors)) == pytest.approx(oracle, rel=1e-12)
    assert sparsification_auc(errors, np.full(errors.shape, 0.7)) == pytest.approx(errors.mean(), rel=1e-12)
    random = [sparsification_auc(errors, rng.random(errors.size)) for _ in range(20)]
    assert np.mean(random) == pytest.approx(errors.mean(), rel=0.02)
    assert oracle < 0.5 * errors.mean()
    assert sparsification_auc(errors, errors) > errors.mean()  # the worst order


def test_score_adds_the_two_areas_over_all_pixels_with_gt(rng):
    gt = rng.uniform(0, 20, (30, 40))
    gt[:3] = np.nan
    pred = gt + rng.normal(0, 1, gt.shape)
    pred[:3] = 0.0
    error = np.abs(pred - gt)
    perfect = score(pred, gt, confidence=np.exp(-np.nan_to_num(error)))
    assert perfect["auc_conf_all"] == pytest.approx(perfect["auc_oracle_all"])
    constant = score(pred, gt, confidence=np.full(gt.shape, 0.5))
    assert constant["auc_conf_all"] == pytest.approx(constant["epe_all"])
    assert "auc_conf_all" not in score(pred, gt)


# ---- the evaluation carries it


def test_protocols_keep_it_zero_where_filled_and_take_the_median_for_rgb(rng):
    left_rgb, right_rgb = (rng.random((6, 8, 3)).astype(np.float32) for _ in range(2))
    level = {0: 0.2, 1: 0.6, 2: 0.9}

    def matcher(left, right):
        channel = int(np.argmin([np.abs(left - left_rgb[:, :, c]).max() for c in range(3)]))
        valid = np.ones(left.shape, bool)
        valid[0, channel] = False
        disparity = np.where(valid, np.float32(3), np.float32(np.nan))
        return DisparityResult(disparity, valid, np.where(valid, np.float32(level[channel]), np.float32(0)))

    *tasks, combined = run_protocol("rgb", matcher, left_rgb, right_rgb)
    assert [task.confidence[1, 1] for task in tasks] == pytest.approx([0.2, 0.6, 0.9])
    assert combined.confidence[1, 1] == pytest.approx(0.6)  # the median of the three
    # pixel (0, c) is invalid in task c (confidence 0 there), valid in the two others
    assert combined.valid[0, :3].all()
    np.testing.assert_allclose(combined.confidence[0, :3], [0.6, 0.2, 0.2])

    def plain_matcher(left, right):
        return DisparityResult(np.ones(left.shape, np.float32), np.ones(left.shape, bool))

    (plain,) = run_protocol("native", plain_matcher, left_rgb, right_rgb)
    assert plain.confidence is None


@pytest.fixture
def folder_dataset(tmp_path, rng) -> Path:
    root = tmp_path / "mine"
    for sub in ("left", "right", "gt"):
        (root / sub).mkdir(parents=True)
    pair = render_pair(rng, (48, 80), background=(5.0, 0.02), foreground=(11.0, 0.0))
    rgb = lambda band: (np.stack([0.2 + 0.6 * band, band**1.5, band], axis=2) * 255).astype(np.uint8)  # noqa: E731
    cv2.imwrite(str(root / "left" / "only.png"), rgb(pair.left))
    cv2.imwrite(str(root / "right" / "only.png"), rgb(pair.right))
    np.save(root / "gt" / "only.npy", pair.disparity)
    return root


def test_benchmark_records_and_reports_the_areas(folder_dataset):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["census-sgm", "sgbm"],
                        protocols=["cs", "rgb"], preprocess=["none"])
    for record in run.records:
        scores = record.scores
        assert list(scores)[-2:] == ["auc_conf_all", "auc_oracle_all"]
        assert scores["auc_oracle_all"] <= scores["auc_conf_all"]
    header, rows = confidence_table(run)
    assert header[:5] == ["method", "CS random", "CS AUC", "CS oracle", "CS gain %"]
    assert [row[0] for row in rows] == ["census-sgm + none", "sgbm + none"]
    assert "sparsification" in markdown(run)


# ---- the command line


@pytest.fixture
def pair_files(tmp_path, scene):
    pair, _, _ = scene
    paths = []
    for name, band in (("left.png", pair.left), ("right.png", 0.1 + 0.5 * pair.right**2.0)):
        cv2.imwrite(str(tmp_path / name), np.rint(np.clip(band, 0, 1) * 65535).astype(np.uint16))
        paths.append(tmp_path / name)
    return paths


@pytest.mark.parametrize("method", ["census-sgm", "sgbm", "cade"])
def test_cli_writes_the_confidence_tiff(pair_files, tmp_path, capsys, method):
    left, right = pair_files
    out, valid, conf = tmp_path / "d.pfm", tmp_path / "v.png", tmp_path / "conf.tif"
    code, _, stderr = run_cade(["disparity", left, right, "-o", out, "--max-disp", 24, "--method", method,
                                "--validity", valid, "--confidence", conf], capsys)
    assert code == 0, stderr
    confidence = tifffile.imread(conf)
    assert confidence.dtype == np.float32 and confidence.shape == SHAPE
    assert confidence.min() >= 0 and confidence.max() <= 1
    assert (confidence[cv2.imread(str(valid), cv2.IMREAD_UNCHANGED) == 0] == 0).all()


@pytest.mark.parametrize("name", ["conf.png", "conf.pfm", "conf"])
def test_cli_refuses_another_confidence_format_before_any_work(pair_files, tmp_path, capsys, name):
    left, right = pair_files
    out = tmp_path / "d.pfm"
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", out, "--max-disp", 24,
                                     "--confidence", tmp_path / name], capsys)
    assert code != 0 and stdout == ""
    assert len(stderr.strip().splitlines()) == 1 and ".tif" in stderr
    assert not out.exists() and not (tmp_path / name).exists()


def test_cli_refuses_the_confidence_on_another_output(pair_files, tmp_path, capsys):
    left, right = pair_files
    same = tmp_path / "same.tif"
    code, _, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "--max-disp", 24,
                                "--validity", same, "--confidence", same], capsys)
    assert code != 0 and "--confidence" in stderr and len(stderr.strip().splitlines()) == 1
    assert not same.exists() and not (tmp_path / "d.pfm").exists()
