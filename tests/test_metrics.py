"""Metrics against values computed by hand on tiny maps; the fill stage they rely on."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.evaluation.metrics import (
    BAD_THRESHOLDS,
    METRIC_NAMES,
    bad_pixel_rate,
    d1_rate,
    end_point_error,
    invalid_percentage,
    score,
)
from cade_cli.matching.disparity import densify

NAN = np.nan

# 2x3 example. |pred - gt| = [[0, 2, 0.5], [-, 4, 0]]: the NaN GT pixel is never scored.
PRED = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], np.float32)
GT = np.array([[1.0, 4.0, 3.5], [NAN, 1.0, 6.0]], np.float32)
ALL = np.ones((2, 3), bool)


def test_end_point_error_by_hand():
    # 5 scored pixels: (0 + 2 + 0.5 + 4 + 0) / 5 = 1.3
    assert end_point_error(PRED, GT, ALL) == pytest.approx(1.3)
    # without the error-4 pixel: (0 + 2 + 0.5 + 0) / 4 = 0.625
    mask = ALL.copy()
    mask[1, 1] = False
    assert end_point_error(PRED, GT, mask) == pytest.approx(0.625)


@pytest.mark.parametrize(
    ("threshold", "expected"),
    [
        (0.0, 60.0),   # 2, 0.5, 4 > 0 -> 3/5
        (0.5, 40.0),   # 0.5 is not > 0.5 -> 2, 4 -> 2/5
        (1.0, 40.0),   # 2, 4
        (2.0, 20.0),   # 2 is not > 2 -> only 4
        (3.0, 20.0),
        (4.0, 0.0),    # 4 is not > 4
        (5.0, 0.0),
    ],
)
def test_bad_pixel_rate_by_hand_and_strict(threshold, expected):
    assert bad_pixel_rate(PRED, GT, ALL, threshold=threshold) == pytest.approx(expected)


def test_nan_and_inf_gt_are_excluded():
    gt = np.array([[1.0, NAN, np.inf]], np.float32)
    pred = np.array([[2.0, 100.0, 100.0]], np.float32)
    valid = np.ones((1, 3), bool)
    assert end_point_error(pred, gt, valid) == pytest.approx(1.0)
    assert bad_pixel_rate(pred, gt, valid, threshold=3.0) == 0.0


def test_no_scored_pixel_gives_nan():
    assert np.isnan(end_point_error(PRED, GT, np.zeros((2, 3), bool)))
    assert np.isnan(bad_pixel_rate(PRED, GT, np.zeros((2, 3), bool), threshold=3.0))
    all_nan = np.full((2, 3), NAN, np.float32)
    assert np.isnan(end_point_error(PRED, all_nan, ALL))


def test_float32_and_float64_agree():
    assert end_point_error(PRED.astype(np.float64), GT.astype(np.float64), ALL) == pytest.approx(
        end_point_error(PRED, GT, ALL), abs=1e-6
    )


def test_bad_inputs_raise_with_shapes():
    with pytest.raises(CadeError, match=r"gt has shape \(2, 3\) but pred has shape \(2, 2\)"):
        end_point_error(PRED[:, :2], GT, ALL)
    with pytest.raises(CadeError, match="bool"):
        end_point_error(PRED, GT, ALL.astype(np.uint8) * 255)
    with pytest.raises(CadeError, match="densify"):
        end_point_error(np.where(ALL, NAN, 0.0), GT, ALL)
    with pytest.raises(CadeError, match="threshold"):
        bad_pixel_rate(PRED, GT, ALL, threshold=-1.0)


# The metrics never fill; scored maps go through matching.disparity.densify first (the
# protocols call it, tests/test_protocols.py). These pin what that stage does to a map.

def test_densify_fills_from_background_side():
    pred = np.array([[NAN, 3.0, NAN, NAN, 7.0, NAN]], np.float32)
    valid = np.array([[False, True, False, False, True, False]])
    before = pred.copy()
    dense = densify(pred, valid)
    np.testing.assert_array_equal(dense, [[3, 3, 3, 3, 7, 7]])
    assert dense.dtype == np.float32
    assert invalid_percentage(pred, valid) == pytest.approx(400 / 6)
    np.testing.assert_array_equal(pred, before)  # caller's array untouched (NaN == NaN here)


def test_densify_and_invalid_share_treat_non_finite_as_invalid():
    pred = np.array([[9.0, NAN, 2.0], [1.0, 1.0, np.inf]], np.float32)
    np.testing.assert_array_equal(densify(pred, np.ones((2, 3), bool)), [[9, 2, 2], [1, 1, 1]])
    assert invalid_percentage(pred, np.ones((2, 3), bool)) == pytest.approx(200 / 6)


def test_densify_with_nothing_valid_gives_zeros():
    dense = densify(np.full((2, 3), NAN), np.zeros((2, 3), bool))
    np.testing.assert_array_equal(dense, np.zeros((2, 3)))
    assert invalid_percentage(np.full((2, 3), NAN), np.zeros((2, 3), bool)) == 100.0


def test_score_keys_depend_on_the_regions_and_confidence():
    plain = score(PRED, GT)
    assert list(plain) == ["epe_all", "bad1_all", "bad2_all", "bad3_all", "bad5_all", "d1_all", "invalid"]
    with_nonocc = score(PRED, GT, nonocc=ALL)
    assert list(with_nonocc) == [name for name in METRIC_NAMES
                                 if name.endswith(("_all", "_nonocc", "invalid")) and "auc" not in name]
    only_edge = score(PRED, GT, edge=ALL)
    assert [name for name in only_edge if name not in plain] == [
        "epe_edge", "bad1_edge", "bad2_edge", "bad3_edge", "bad5_edge", "d1_edge"]
    every = score(PRED, GT, nonocc=ALL, edge=ALL, occ=ALL, confidence=np.ones(PRED.shape))
    assert list(every) == list(METRIC_NAMES)
    # the all-pixel and non-occluded columns keep their places; the confidence columns come last
    assert METRIC_NAMES[:12] == tuple(f"{m}_{r}" for r in ("all", "nonocc")
                                      for m in ("epe", "bad1", "bad2", "bad3", "bad5", "d1"))
    assert METRIC_NAMES[-2:] == ("auc_conf_all", "auc_oracle_all")
    assert len(METRIC_NAMES) == 4 * (1 + len(BAD_THRESHOLDS) + 1) + 1 + 2


def test_each_region_scores_only_its_own_pixels():
    # errors [[0, 2, 0.5], [-, 4, 0]]: edge = the two middle pixels, occ = the error-4 pixel alone
    edge = np.zeros((2, 3), bool)
    edge[:, 1] = True
    occ = np.zeros((2, 3), bool)
    occ[1, 1] = True
    result = score(PRED, GT, nonocc=~occ, edge=edge & ~occ, occ=occ)
    assert result["epe_edge"] == pytest.approx(2.0) and result["bad1_edge"] == 100.0
    assert result["epe_occ"] == pytest.approx(4.0) and result["bad3_occ"] == 100.0
    assert result["epe_nonocc"] == pytest.approx(0.625) and result["bad3_nonocc"] == 0.0
    assert result["epe_all"] == pytest.approx(1.3)  # the regions leave the all-pixel figures alone
    assert score(PRED, GT, occ=np.zeros((2, 3), bool))["epe_occ"] != score(PRED, GT, occ=np.zeros((2, 3), bool))[
        "epe_occ"]  # an empty region scores NaN


def test_d1_needs_both_3_px_and_5_percent_by_hand():
    # GT (px) and error: outlier when the error is > 3 px and > 5 % of the GT
    #  10, 4:   > 3 and > 0.5        -> outlier
    # 100, 4:   > 3 but not > 5      -> fine (though a bad3 pixel)
    # 100, 6:   > 3 and > 5          -> outlier
    #  40, 2:   not > 3              -> fine
    #  20, 3:   exactly 3 is not > 3 -> fine
    #  50, 3.5: > 3 and > 2.5        -> outlier
    # unknown:  never scored
    gt = np.array([[10.0, 100.0, 100.0, 40.0, 20.0, 50.0, NAN]], np.float32)
    pred = gt + np.array([[4.0, -4.0, 6.0, 2.0, 3.0, -3.5, 0.0]], np.float32)
    pred[0, -1] = 9.0
    everything = np.ones(gt.shape, bool)
    assert d1_rate(pred, gt, everything) == pytest.approx(100 * 3 / 6)
    assert bad_pixel_rate(pred, gt, everything, threshold=3.0) == pytest.approx(100 * 4 / 6)
    without_first = everything.copy()
    without_first[0, 0] = False
    assert d1_rate(pred, gt, without_first) == pytest.approx(100 * 2 / 5)
    assert np.isnan(d1_rate(pred, gt, np.zeros(gt.shape, bool)))
    assert score(pred, gt, nonocc=without_first)["d1_nonocc"] == pytest.approx(40.0)


def test_score_values_by_hand():
    nonocc = ALL.copy()
    nonocc[1, 1] = False  # the error-4 pixel is "occluded"
    result = score(PRED, GT, nonocc=nonocc)
    assert result["epe_all"] == pytest.approx(1.3)
    assert result["bad1_all"] == pytest.approx(40.0)
    assert result["bad2_all"] == pytest.approx(20.0)
    assert result["bad5_all"] == 0.0
    assert result["epe_nonocc"] == pytest.approx(0.625)
    assert result["bad1_nonocc"] == pytest.approx(25.0)
    assert result["bad3_nonocc"] == 0.0
    assert result["invalid"] == 0.0


def test_score_counts_invalid_from_validity_and_never_fills():
    # middle pixel rejected by the matcher but dense: scored as it is, counted as invalid
    pred = np.array([[1.0, 99.0, 3.0]], np.float32)
    gt = np.array([[1.0, 1.0, 3.0]], np.float32)
    result = score(pred, gt, pred_valid=np.array([[True, False, True]]))
    assert result["epe_all"] == pytest.approx(98 / 3)
    assert result["invalid"] == pytest.approx(100 / 3)
    # an unfilled map is refused where GT exists, with the fix in the message ...
    with pytest.raises(CadeError, match="densify"):
        score(np.array([[1.0, NAN, 3.0]], np.float32), gt, pred_valid=np.array([[True, False, True]]))
    # ... and its filled copy scores 0: min(1, 3) = 1 is the GT
    filled = densify(np.array([[1.0, NAN, 3.0]], np.float32), np.array([[True, False, True]]))
    assert score(filled, gt)["epe_all"] == 0.0


def test_score_does_not_modify_its_inputs():
    pred, gt = PRED.copy(), GT.copy()
    score(pred, gt, nonocc=ALL, pred_valid=ALL)
    np.testing.assert_array_equal(pred, PRED)
    np.testing.assert_array_equal(gt, GT)


def test_identical_prediction_scores_zero(rng):
    gt = rng.uniform(0, 40, (12, 17)).astype(np.float32)
    gt[rng.random(gt.shape) < 0.2] = NAN
    pred = np.nan_to_num(gt, nan=5.0)
    result = score(pred, gt, nonocc=rng.random(gt.shape) < 0.7)
    assert all(value == 0.0 for value in result.values())
