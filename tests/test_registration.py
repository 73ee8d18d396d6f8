"""Registering a band onto the reference view, checked on pairs with rendered disparity."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.registration import register, warp_to_reference
from synthetic import render_pair

PLANAR = dict(background=(5.0, 0.05), foreground=(14.0, 0.05))


def _other_band(band: np.ndarray) -> np.ndarray:
    """A monotone, nonlinear change of gain and gamma: the band seen through another filter."""
    return (0.1 + 0.4 * band.astype(np.float64) ** 2.2).astype(np.float32)


@pytest.mark.parametrize("scene", [dict(background=(6.0, 0.0)), PLANAR])
def test_warp_with_true_disparity_reproduces_left(rng, scene):
    pair = render_pair(rng, (64, 96), **scene)
    registered, inside = warp_to_reference(pair.right, pair.disparity)
    assert registered.shape == pair.left.shape and registered.dtype == np.float32
    assert inside[pair.reliable].all()
    error = np.abs(registered - pair.left)[pair.reliable]
    assert error.mean() < 0.02
    # Without the warp the views disagree: the test can tell a warp from a copy.
    assert np.abs(pair.right - pair.left)[pair.reliable].mean() > 0.05


def test_warp_with_zero_disparity_is_identity(rng):
    band = rng.random((12, 17)).astype(np.float32)
    registered, inside = warp_to_reference(band, np.zeros_like(band))
    np.testing.assert_allclose(registered, band, atol=1e-6)
    assert inside.all()


def test_warp_integer_shift_moves_columns(rng):
    band = rng.random((6, 20)).astype(np.float32)
    registered, inside = warp_to_reference(band, np.full(band.shape, 3.0, np.float32))
    np.testing.assert_allclose(registered[:, 3:], band[:, :-3], atol=1e-6)  # left(x) = right(x - d)
    assert not inside[:, :3].any() and inside[:, 3:].all()


def test_inside_marks_samples_within_the_moving_image(rng):
    height, width = 9, 15
    # Multiples of 0.25 are exact in float32, so x - d is exact and the borders
    # (x - d == 0 and x - d == W - 1) are hit exactly.
    disparity = (rng.integers(-4 * width, 4 * width, size=(height, width)) / 4.0).astype(np.float32)
    disparity[0, :] = np.arange(width)                # x - d == 0: inside
    disparity[1, :] = np.arange(width) - (width - 1)  # x - d == W - 1: inside
    disparity[2, :] = np.arange(width) + 0.25         # x - d == -0.25: outside
    disparity[3, :] = np.arange(width) - (width - 1) - 0.25  # x - d == W - 0.75: outside
    _, inside = warp_to_reference(rng.random((height, width)), disparity)
    source = np.arange(width)[None, :] - disparity.astype(np.float64)
    expected = (source >= 0) & (source <= width - 1)
    np.testing.assert_array_equal(inside, expected)
    assert inside[:2].all() and not inside[2:4].any()
    assert 0 < inside[4:].mean() < 1


def test_warp_rejects_size_mismatch(rng):
    with pytest.raises(CadeError):
        warp_to_reference(rng.random((10, 12)), np.zeros((10, 13), np.float32))


# ---------------------------------------------------------------------------------------
# register with a given disparity
# ---------------------------------------------------------------------------------------


def test_register_with_true_disparity(rng):
    pair = render_pair(rng, (64, 96), **PLANAR)
    reference_before = pair.left.copy()
    disparity_before = pair.disparity.copy()
    result = register(pair.right, pair.left, disparity=pair.disparity)
    assert np.array_equal(result.reference, reference_before)
    assert np.array_equal(pair.left, reference_before) and np.array_equal(pair.disparity, disparity_before)
    for array in (result.reference, result.registered, result.disparity):
        assert array.shape == pair.left.shape and array.dtype == np.float32
    assert result.valid.dtype == bool and result.valid[pair.reliable].all()
    np.testing.assert_array_equal(result.disparity, pair.disparity)  # nothing to fill
    assert np.abs(result.registered - pair.left)[pair.reliable].mean() < 0.02


def _with_holes(pair) -> np.ndarray:
    disparity = pair.disparity.copy()
    disparity[20:30, 40:55] = np.nan
    disparity[5, :] = np.nan  # a whole row without any valid pixel
    return disparity


def test_nan_disparity_is_not_valid(rng):
    pair = render_pair(rng, (64, 96), **PLANAR)
    disparity = _with_holes(pair)
    result = register(pair.right, pair.left, disparity=disparity)
    holes = np.isnan(disparity)
    assert not result.valid[holes].any()
    source = np.arange(96)[None, :] - pair.disparity
    inside = (source >= 0) & (source <= 95)
    np.testing.assert_array_equal(result.valid, ~holes & inside)
    assert np.isfinite(result.disparity).all()
    # Filled values come from the same row (background side) or, for an empty row, the median.
    assert np.all(result.disparity[20:30, 40:55] >= np.nanmin(disparity[20:30]) - 1e-6)
    assert np.all(result.disparity[20:30, 40:55] <= np.nanmax(disparity[20:30]) + 1e-6)


def test_fill_none_puts_nan_exactly_where_invalid(rng):
    pair = render_pair(rng, (64, 96), **PLANAR)
    result = register(pair.right, pair.left, disparity=_with_holes(pair), fill="none")
    np.testing.assert_array_equal(np.isnan(result.registered), ~result.valid)
    assert (~result.valid).sum() > 150  # holes plus the left border (x - d < 0)
    assert np.abs(result.registered - pair.left)[pair.reliable & result.valid].mean() < 0.02


def test_fill_row_leaves_everything_finite(rng):
    pair = render_pair(rng, (64, 96), **PLANAR)
    disparity = _with_holes(pair)
    filled = register(pair.right, pair.left, disparity=disparity, fill="row")
    bare = register(pair.right, pair.left, disparity=disparity, fill="none")
    assert np.isfinite(filled.registered).all()
    np.testing.assert_array_equal(filled.valid, bare.valid)
    np.testing.assert_array_equal(filled.registered[bare.valid], bare.registered[bare.valid])


def test_default_fill_is_row(rng):
    pair = render_pair(rng, (32, 48))
    disparity = _with_holes(pair)
    assert np.isfinite(register(pair.right, pair.left, disparity=disparity).registered).all()


def test_register_rejects_mismatched_disparity(rng):
    pair = render_pair(rng, (32, 48))
    with pytest.raises(CadeError):
        register(pair.right, pair.left, disparity=pair.disparity[:, :-1])
    with pytest.raises(CadeError):
        register(pair.right, pair.left, disparity=pair.disparity.T)


def test_register_rejects_mismatched_moving_band(rng):
    pair = render_pair(rng, (32, 48))
    with pytest.raises(CadeError):
        register(pair.right[:, :-2], pair.left, disparity=pair.disparity)


def test_register_rejects_all_nan_disparity(rng):
    pair = render_pair(rng, (32, 48))
    with pytest.raises(CadeError):
        register(pair.right, pair.left, disparity=np.full(pair.left.shape, np.nan, np.float32))


@pytest.mark.parametrize("fill", ["nearest", "", "ROW", None])
def test_register_rejects_unknown_fill(rng, fill):
    pair = render_pair(rng, (32, 48))
    with pytest.raises(CadeError):
        register(pair.right, pair.left, disparity=pair.disparity, fill=fill)


# ---------------------------------------------------------------------------------------
# register estimating the disparity itself
# ---------------------------------------------------------------------------------------


def test_register_cross_band_pair_estimating_disparity(rng):
    pair = render_pair(rng, (64, 96), **PLANAR)
    moving = _other_band(pair.right)
    max_disp = int(np.ceil(pair.disparity.max())) + 2
    result = register(moving, pair.left, method="census-sgm", preprocess="cade", max_disp=max_disp)
    assert np.array_equal(result.reference, pair.left)
    assert np.isfinite(result.registered).all()  # default fill="row"
    assert result.valid[pair.reliable].mean() > 0.9
    assert np.abs(result.disparity - pair.disparity)[pair.reliable].mean() < 0.5
    target = _other_band(pair.left)
    assert np.abs(result.registered - target)[pair.reliable].mean() < 0.02
    # Unregistered, the bands are far apart: the comparison can fail.
    assert np.abs(moving - target)[pair.reliable].mean() > 0.02


def test_register_rejects_multichannel_bands_with_given_disparity(rng):
    bands = rng.random((20, 30, 3)).astype(np.float32)
    with pytest.raises(CadeError):
        register(bands, bands, disparity=np.zeros((20, 30, 3), np.float32))
