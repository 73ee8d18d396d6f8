"""DASC descriptor (cade_cli.matching.dasc) and the dasc-sgm matcher."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cade_cli.matching import MATCHERS, densify
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.dasc import (DASC_PATTERN, dasc_cost, dasc_descriptor, dasc_descriptor_cost,
                                   dasc_sampling_pattern)
from cade_cli.matching.reference import dasc_descriptor_cost_reference, dasc_descriptor_reference
from cli_runner import run_cade, write_png16
from synthetic import render_pair, smooth_texture


def test_default_pattern_is_the_documented_one():
    assert DASC_PATTERN.shape == (128, 4) and np.abs(DASC_PATTERN).max() <= 15
    assert not (DASC_PATTERN[:, :2] == DASC_PATTERN[:, 2:]).all(axis=1).any()  # p != q
    assert np.array_equal(DASC_PATTERN, dasc_sampling_pattern(128, rng=np.random.default_rng(2015)))


@pytest.mark.parametrize("shape, pattern", [
    ((24, 30), dasc_sampling_pattern(6, radius=4, rng=np.random.default_rng(3))),
    ((48, 50), DASC_PATTERN[:8]),  # the default pattern's reach (15 px), a few of its pairs
])
def test_descriptor_agrees_with_reference(rng, shape, pattern):
    image = 40.0 + 200.0 * smooth_texture(rng, shape, sigma=1.0)
    slow = dasc_descriptor_reference(image, pattern=pattern)
    fast = dasc_descriptor(image, pattern=pattern)
    interior = np.isfinite(slow[..., 0])
    assert interior.sum() >= 50 and fast.dtype == np.float32 and fast.shape == slow.shape
    np.testing.assert_allclose(fast[interior], slow[interior], atol=1e-4)


def test_descriptor_has_unit_norm_and_positive_entries(rng):
    descriptor = dasc_descriptor(smooth_texture(rng, (40, 50)))
    assert descriptor.shape == (40, 50, 128)
    np.testing.assert_allclose(np.linalg.norm(descriptor, axis=2), 1.0, atol=1e-5)
    assert descriptor.min() > 0 and descriptor.max() <= 1


@settings(max_examples=5, deadline=None)
@given(gain=st.floats(0.01, 100.0), offset=st.floats(-1000.0, 1000.0), seed=st.integers(0, 2**16))
def test_descriptor_is_invariant_to_gain_and_offset(gain, offset, seed):
    image = smooth_texture(np.random.default_rng(seed), (40, 48)).astype(np.float64)
    pattern = DASC_PATTERN[:32]
    np.testing.assert_allclose(dasc_descriptor(gain * image + offset, pattern=pattern),
                               dasc_descriptor(image, pattern=pattern), atol=2e-4)


def test_cost_is_zero_for_identical_descriptors_and_one_out_of_view(rng):
    band = smooth_texture(rng, (32, 40))
    cost = dasc_cost(band, band, DisparityRange(-2, 3), pattern=DASC_PATTERN[:16])
    assert cost.values.shape == (32, 40, 6) and cost.lower_is_better
    np.testing.assert_allclose(cost.values[:, :, 2], 0.0, atol=1e-5)  # d = 0
    assert (cost.values[:, :3, 5] == 1).all() and (cost.values[:, -2:, 0] == 1).all()
    assert cost.values.min() >= 0 and cost.values.max() <= 1


@pytest.mark.parametrize("low, high", [(0, 20), (-7, 9), (-3, 0), (-20, 21), (0, 37)])
def test_cost_agrees_with_the_per_disparity_reference(rng, low, high):
    """Ranges of one sign and of both, and ranges about as wide as the 38 px wide image
    (every block of products then reaches past its edges): the band products give the
    einsum loop's volume, and the volume a column off does not match it."""
    left, right = rng.random((2, 13, 38)).astype(np.float32)
    disparity_range = DisparityRange(low, high)
    pattern = DASC_PATTERN[:24]
    slow = dasc_descriptor_cost_reference(dasc_descriptor(left, pattern=pattern),
                                          dasc_descriptor(right, pattern=pattern), disparity_range)
    fast = dasc_cost(left, right, disparity_range, pattern=pattern).values
    assert fast.dtype == np.float32 and fast.shape == slow.shape == (13, 38, high - low + 1)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-5)
    assert np.abs(fast[:, 1:] - slow[:, :-1]).max() > 1e-2 and np.abs(fast[..., 1:] - slow[..., :-1]).max() > 1e-2


def test_descriptor_cost_is_the_same_for_every_block_size(rng, monkeypatch):
    """Blocks of rows and columns that do not divide the image give the same volume."""
    import cade_cli.matching.dasc as dasc

    left, right = (descriptor / np.linalg.norm(descriptor, axis=2, keepdims=True)
                   for descriptor in rng.random((2, 11, 45, 16)).astype(np.float32))
    disparity_range = DisparityRange(-4, 30)
    slow = dasc_descriptor_cost_reference(left, right, disparity_range)
    for columns, product_bytes in (((1, 1), 1), ((7, 7), 4 * 7 * 41 * 3), ((16, 128), 2**20)):
        monkeypatch.setattr(dasc, "PRODUCT_COLUMNS", columns)
        monkeypatch.setattr(dasc, "PRODUCT_BYTES", product_bytes)
        np.testing.assert_allclose(dasc_descriptor_cost(left, right, disparity_range), slow, rtol=0, atol=1e-5)


@settings(max_examples=4, deadline=None)
@given(disparity=st.integers(-6, 12), seed=st.integers(0, 2**16))
def test_dasc_sgm_recovers_a_shifted_texture(disparity, seed):
    """A texture and the same texture shifted by a known integer disparity (and seen through
    another gain and offset): >95 % of the interior within 1 px."""
    height, width, margin = 56, 96, 16
    wide = smooth_texture(np.random.default_rng(seed), (height, width + 20))
    left = wide[:, 6:6 + width]
    right = 0.3 + 0.5 * wide[:, 6 + disparity:6 + disparity + width]  # right(x - d) = left(x)
    result = MATCHERS["dasc-sgm"](left, right, min_disp=-8, max_disp=14)
    interior = (slice(margin, height - margin), slice(margin + max(disparity, 0), width - margin + min(disparity, 0)))
    error = np.abs(densify(result.disparity, result.valid) - disparity)[interior]
    assert (error <= 1).mean() > 0.95


def test_dasc_sgm_is_registered_and_runs_from_the_cli(rng, tmp_path, capsys):
    assert MATCHERS["dasc-sgm"].preprocessing == ("none", "cade")
    pair = render_pair(rng, (72, 112), background=(6.0, 0.0), foreground=(12.0, 0.0))
    left, right = write_png16(tmp_path / "l.png", pair.left), write_png16(tmp_path / "r.png", pair.right)
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.npy", "--max-disp", 20,
                                     "--method", "dasc-sgm"], capsys)
    assert code == 0, stderr
    assert "dasc-sgm" in stdout
    estimate = np.load(tmp_path / "d.npy")
    assert np.abs(estimate - pair.disparity)[pair.reliable].mean() < 0.5
