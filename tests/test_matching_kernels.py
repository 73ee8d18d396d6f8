"""Fast kernels against their slow references, and the disparity/validation stages."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.cost import RANK_ROWS, CostVolume, census_cost, census_transform, rank_transform, zncc_cost
from cade_cli.matching.disparity import (
    fill_invalid_along_rows,
    left_right_check,
    right_view_cost,
    visible_in_right_view,
    winner_takes_all,
)
from cade_cli.matching.reference import census_cost_reference, sgm_aggregate_reference, zncc_cost_reference
from cade_cli.matching.sgm import sgm_aggregate
from synthetic import render_pair


@pytest.mark.parametrize("window", [3, 5, 7])
@pytest.mark.parametrize("limits", [(0, 4), (-3, 2)])
def test_census_cost_matches_reference(rng, window, limits):
    left = rng.random((9, 13)).astype(np.float32)
    right = rng.random((9, 13)).astype(np.float32)
    disparity_range = DisparityRange(*limits)
    fast = census_cost(left, right, disparity_range, window=window).values
    slow = census_cost_reference(left, right, disparity_range, window=window)
    assert fast.dtype == np.uint8
    np.testing.assert_array_equal(fast, slow)


@pytest.mark.parametrize("window", [3, 5, 7])
def test_rank_is_the_census_bit_count(rng, window):
    image = rng.random((11, 17)).astype(np.float32)
    np.testing.assert_array_equal(rank_transform(image, window=window),
                                  np.bitwise_count(census_transform(image, window=window)))


def test_rank_block_by_block_is_the_census_bit_count_of_the_whole_image(rng):
    """rank_transform compares RANK_ROWS rows at a time: an image of several blocks and a
    partial one, with ties (8 grey levels), must get the ranks of the whole-image census."""
    image = np.floor(rng.random((2 * RANK_ROWS + 37, 23)) * 8).astype(np.float32)
    np.testing.assert_array_equal(rank_transform(image), np.bitwise_count(census_transform(image)))


def test_rank_ignores_gain_offset_and_gamma_and_flips_with_contrast(rng):
    image = rng.random((20, 30)).astype(np.float32) + 0.05  # distinct values: no ties
    rank = rank_transform(image)
    assert rank.dtype == np.uint8 and rank.max() <= 48 and len(np.unique(rank)) > 20
    np.testing.assert_array_equal(rank_transform(3.0 * image**2.2 + 7.0), rank)
    inner = (slice(3, -3), slice(3, -3))  # replicated borders create ties
    np.testing.assert_array_equal(rank_transform(1.0 - image)[inner], 48 - rank[inner])


def test_zncc_cost_matches_reference_inside(rng):
    left = rng.random((12, 20)).astype(np.float32)
    right = rng.random((12, 20)).astype(np.float32)
    disparity_range = DisparityRange(-2, 5)
    fast = zncc_cost(left, right, disparity_range, window=5).values
    slow = zncc_cost_reference(left, right, disparity_range, window=5)
    inside = np.isfinite(slow)
    assert inside.sum() > 200
    np.testing.assert_allclose(fast[inside], slow[inside], atol=1e-4)


def test_zncc_is_zero_for_an_affine_copy(rng):
    left = rng.random((15, 30)).astype(np.float32)
    right = 0.3 * left + 0.5  # same structure, different gain and offset
    volume = zncc_cost(left, right, DisparityRange(0, 3), window=5).values
    np.testing.assert_allclose(volume[:, :, 0], 0.0, atol=1e-4)


@pytest.mark.parametrize("shape", [(6, 7, 4), (5, 9, 1), (1, 6, 3), (7, 1, 5)])
def test_sgm_matches_reference(rng, shape):
    cost = rng.random(shape).astype(np.float32)
    fast = sgm_aggregate(CostVolume(cost, DisparityRange(0, shape[2] - 1)), p1=0.2, p2=0.7).values
    slow = sgm_aggregate_reference(cost, p1=0.2, p2=0.7)
    np.testing.assert_allclose(fast, slow, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("shape", [(6, 7, 4), (3, 5, 2)])
def test_integer_sgm_is_exact(rng, shape):
    cost = rng.integers(0, 49, size=shape).astype(np.uint8)
    fast = sgm_aggregate(CostVolume(cost, DisparityRange(0, shape[2] - 1)), p1=7, p2=72).values
    slow = sgm_aggregate_reference(cost.astype(np.float64), p1=7, p2=72)
    assert fast.dtype == np.uint16
    np.testing.assert_array_equal(fast, slow)


def test_integer_sgm_widens_its_dtypes_for_large_costs(rng):
    cost = rng.integers(0, 3000, size=(4, 5, 3)).astype(np.uint16)
    fast = sgm_aggregate(CostVolume(cost, DisparityRange(0, 2)), p1=100, p2=5000).values
    np.testing.assert_array_equal(fast, sgm_aggregate_reference(cost.astype(np.float64), p1=100, p2=5000))


def test_integer_sgm_needs_whole_penalties():
    with pytest.raises(ValueError, match="whole"):
        sgm_aggregate(CostVolume(np.zeros((3, 3, 3), np.uint8), DisparityRange(0, 2)), p1=0.5, p2=2)


def test_sgm_rejects_p2_below_p1():
    with pytest.raises(ValueError, match="p2"):
        sgm_aggregate(CostVolume(np.zeros((3, 3, 3), np.float32), DisparityRange(0, 2)), p1=1.0, p2=0.5)


def test_winner_takes_all_finds_a_parabola_vertex():
    # Costs sampled from (d - 2.3)^2 on d = -1..5: the parabola fit is exact.
    disparities = np.arange(-1, 6, dtype=np.float32)
    values = ((disparities - 2.3) ** 2)[None, None, :].repeat(2, 0).repeat(3, 1)
    estimate = winner_takes_all(CostVolume(values.astype(np.float32), DisparityRange(-1, 5)))
    np.testing.assert_allclose(estimate, 2.3, atol=1e-5)


def test_winner_takes_all_reads_the_higher_is_better_flag():
    values = np.zeros((1, 1, 4), np.float32)
    values[0, 0, 1] = 1.0
    score = CostVolume(values, DisparityRange(0, 3), lower_is_better=False)
    assert winner_takes_all(score, subpixel=False)[0, 0] == 1.0


def test_right_view_cost_reindexes_columns(rng):
    values = rng.random((2, 8, 3)).astype(np.float32)
    right = right_view_cost(CostVolume(values, DisparityRange(1, 3))).values
    # right pixel xr at disparity d pairs with left pixel xr + d
    assert right[1, 2, 0] == values[1, 3, 0]
    assert right[0, 4, 2] == values[0, 7, 2]
    assert right[0, 5, 2] == values.max()  # left pixel 8 does not exist


def test_left_right_check_flags_inconsistent_and_out_of_view_pixels():
    left = np.full((1, 6), 2.0, np.float32)
    right = np.full((1, 6), 2.0, np.float32)
    right[0, 3] = 5.0  # left pixel 5 maps to right pixel 3, which disagrees
    valid = left_right_check(left, right, tolerance=1.0)
    assert valid.tolist() == [[False, False, True, True, True, False]]


def test_fill_takes_the_background_side():
    disparity = np.array([[np.nan, 3.0, np.nan, np.nan, 7.0, np.nan]], np.float32)
    valid = np.isfinite(disparity)
    filled = fill_invalid_along_rows(disparity, valid)
    assert filled.tolist() == [[3.0, 3.0, 3.0, 3.0, 7.0, 7.0]]
    assert np.isnan(disparity[0, 0])  # input untouched


def test_fill_matches_a_per_pixel_reference_on_random_masks(rng):
    for _ in range(200):
        height, width = rng.integers(1, 9, size=2)
        disparity = rng.random((height, width)).astype(np.float32)
        valid = rng.random((height, width)) < rng.random()
        expected = disparity.copy()
        if valid.any() and not valid.all():
            for y, x in zip(*np.nonzero(~valid)):
                row = np.nonzero(valid[y])[0]
                if row.size == 0:
                    expected[y, x] = np.median(disparity[valid])
                    continue
                sides = [disparity[y, row[row < x].max()]] if (row < x).any() else []
                sides += [disparity[y, row[row > x].min()]] if (row > x).any() else []
                expected[y, x] = min(sides)
        assert np.array_equal(fill_invalid_along_rows(disparity, valid), expected)


def test_fill_uses_global_median_for_empty_rows():
    disparity = np.array([[1.0, 2.0, 9.0], [0.0, 0.0, 0.0]], np.float32)
    valid = np.array([[True, True, True], [False, False, False]])
    assert fill_invalid_along_rows(disparity, valid)[1].tolist() == [2.0, 2.0, 2.0]


def test_winner_takes_all_on_unsigned_costs_refines_both_ways():
    # Integer volumes must not wrap around when neighbouring costs are subtracted.
    values = np.array([[[9, 2, 4, 9], [9, 4, 2, 9]]], np.uint16).transpose(0, 1, 2)
    estimate = winner_takes_all(CostVolume(values, DisparityRange(0, 3)))
    # vertex offset = (before - after) / (2 * (before - 2 centre + after)) = +-5 / 18
    assert estimate[0, 0] == pytest.approx(1 + 5 / 18) and estimate[0, 1] == pytest.approx(2 - 5 / 18)


def test_visibility_flags_what_a_nearer_surface_hides_and_what_leaves_the_view():
    disparity = np.full((3, 80), 5.0, np.float32)
    disparity[:, 40:60] = 20.0  # lands on 20..39, where background pixels 25..44 land
    visible = visible_in_right_view(disparity, tolerance=1.0)
    # background x lands on x - 5; hidden once the block lands more than 1 px left of it
    expected = np.ones(80, bool)
    expected[:5] = False          # x - 5 < 0: outside the right view
    expected[27:40] = False       # x - 5 >= 22 > 20 + 1
    np.testing.assert_array_equal(visible, np.broadcast_to(expected, (3, 80)))


def test_visibility_of_a_rendered_scene_matches_its_occlusions(rng):
    pair = render_pair(rng, (64, 120), background=(6.0, 0.0), foreground=(21.0, 0.0))
    visible = visible_in_right_view(pair.disparity)
    assert pair.occluded.sum() > 100
    assert (~visible)[pair.occluded].mean() > 0.8  # the 1-px tolerance spares 2 px of each 15-px strip
    assert visible[pair.reliable].all()
