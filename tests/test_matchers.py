"""Every registered matcher recovers disparities we rendered ourselves."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.matching import LEARNED_METHODS, MATCHERS, densify, get_matcher
from synthetic import render_pair, smooth_texture

SCENES = {
    "constant": dict(background=(6.0, 0.0), foreground=None),
    "piecewise-planar": dict(background=(5.0, 0.05), foreground=(14.0, 0.05)),
    "both-signs": dict(background=(-4.0, 0.03), foreground=(6.0, -0.04)),
}


def search_range(disparity: np.ndarray) -> tuple[int, int]:
    return min(0, int(np.floor(disparity.min())) - 2), int(np.ceil(disparity.max())) + 2


# Every matcher with every preprocessing it accepts (the CADE network takes CADE bands only).
MATCHER_PREPROCESS = [(name, preprocess) for name, matcher in MATCHERS.items() for preprocess in matcher.preprocessing]


# The network's sub-pixel precision is coarser than a parabola fit on an SGM cost
# (docs/research/network-design.md), so it is held to 1 px mean error here, the others to 0.5 px.
MEAN_ERROR_BOUND = {"cade": 1.0, "cade-network": 1.0}


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("name, preprocess", MATCHER_PREPROCESS)
def test_recovers_rendered_disparity(rng, name, preprocess, scene):
    pair = render_pair(rng, (80, 120), **SCENES[scene])
    low, high = search_range(pair.disparity)
    result = MATCHERS[name](pair.left, pair.right, min_disp=low, max_disp=high, preprocess=preprocess)
    assert result.disparity.shape == pair.left.shape and result.disparity.dtype == np.float32
    assert np.array_equal(np.isnan(result.disparity), ~result.valid)  # unfilled: NaN exactly where invalid
    error = np.abs(densify(result.disparity, result.valid) - pair.disparity)[pair.reliable]
    assert error.mean() < MEAN_ERROR_BOUND.get(name, 0.5)
    assert result.valid[pair.reliable].mean() > 0.9


@pytest.mark.parametrize("name", ["census-sgm", "zncc-sgm"])
def test_cross_band_pair_with_cade(rng, name):
    """A monotone, nonlinear change of gain and gamma between the views (two filters)."""
    pair = render_pair(rng, (80, 120), **SCENES["piecewise-planar"])
    other_band = 0.1 + 0.4 * pair.right**2.2
    low, high = search_range(pair.disparity)
    result = MATCHERS[name](pair.left, other_band, min_disp=low, max_disp=high, preprocess="cade")
    assert np.abs(densify(result.disparity, result.valid) - pair.disparity)[pair.reliable].mean() < 0.5


@pytest.mark.parametrize("low, high", [(-30, -5), (-30, 0)])
@pytest.mark.parametrize("name", list(MATCHERS))
def test_range_entirely_below_zero(rng, name, low, high):
    """A texture shifted by a known NEGATIVE disparity (right(x) = left(x - d), d = -17) is
    found over a range that never reaches above zero."""
    texture = smooth_texture(rng, (64, 200))
    left, right = texture[:, 30:170].copy(), texture[:, 13:153].copy()
    result = MATCHERS[name](left, right, min_disp=low, max_disp=high)
    inner = (slice(8, -8), slice(8, -8 - 17))  # away from the borders and the pixels RIGHT does not see
    error = np.abs(densify(result.disparity, result.valid) + 17)[inner]
    assert error.mean() < MEAN_ERROR_BOUND.get(name, 0.1)
    assert result.valid[inner].mean() > 0.9


@pytest.mark.parametrize("name", [name for name in MATCHERS if name not in LEARNED_METHODS])
def test_identical_images_give_zero_disparity(rng, name):
    # The integer winner is exactly 0 everywhere; the parabola may move it by < 0.5 px
    # where the neighbouring costs are asymmetric, as they are on random texture.
    band = rng.random((40, 60)).astype(np.float32)
    result = MATCHERS[name](band, band, min_disp=-5, max_disp=5)
    assert np.array_equal(np.rint(densify(result.disparity, result.valid)), np.zeros((40, 60), np.float32))
    assert result.valid[:, 16:-5].all()  # OpenCV rejects x < min_disp + 16 (its rounded range)


def test_network_on_identical_images_stays_near_zero(rng):
    # Pixel-scale white noise is unlike anything the network was trained on (textures
    # there are at least a few pixels across), so it is held to a looser standard.
    band = rng.random((40, 60)).astype(np.float32)
    result = MATCHERS["cade"](band, band, min_disp=-5, max_disp=5)
    error = np.abs(densify(result.disparity, result.valid))
    assert np.median(error) < 0.5 and (error < 1).mean() > 0.85


def test_float64_input_agrees_with_float32(rng):
    pair = render_pair(rng, (48, 80))
    as32 = MATCHERS["census-sgm"](pair.left, pair.right, max_disp=12)
    as64 = MATCHERS["census-sgm"](pair.left.astype(np.float64), pair.right.astype(np.float64), max_disp=12)
    np.testing.assert_array_equal(as32.disparity, as64.disparity)  # NaN where invalid, in both


def test_inputs_are_not_modified(rng):
    pair = render_pair(rng, (48, 80))
    left, right = pair.left.copy(), pair.right.copy()
    MATCHERS["zncc-sgm"](left, right, max_disp=12, preprocess="cade")
    assert np.array_equal(left, pair.left) and np.array_equal(right, pair.right)


@pytest.mark.parametrize(
    "left_shape, right_shape, kwargs, message",
    [
        ((20, 30), (20, 31), dict(max_disp=5), "differ in size"),
        ((4, 30), (4, 30), dict(max_disp=5), "smaller than"),
        ((20, 30), (20, 30), dict(min_disp=-30, max_disp=-2), "does not fit"),
        ((20, 30), (20, 30), dict(max_disp=30), "does not fit"),
        ((20, 30), (20, 30), dict(max_disp=5, min_disp=6), "below min"),
        ((20, 30), (20, 30), dict(max_disp=5, preprocess="magic"), "unknown preprocess"),
        ((20, 30, 3), (20, 30, 3), dict(max_disp=5), "one band"),
    ],
)
def test_bad_requests_raise_cade_error(left_shape, right_shape, kwargs, message):
    with pytest.raises(CadeError, match=message):
        MATCHERS["census-sgm"](np.zeros(left_shape), np.zeros(right_shape), **kwargs)


def test_unknown_matcher_lists_choices():
    with pytest.raises(CadeError, match="census-sgm"):
        get_matcher("nope")


@pytest.mark.parametrize("name, expected", [("census-sgm", "none"), ("zncc-sgm", "none"), ("sgbm", "cade")])
def test_auto_preprocess_runs_the_matchers_choice(rng, name, expected):
    pair = render_pair(rng, (48, 80))
    other_band = 0.1 + 0.4 * pair.right**2.2
    auto = MATCHERS[name](pair.left, other_band, max_disp=12, preprocess="auto")
    chosen = MATCHERS[name](pair.left, other_band, max_disp=12, preprocess=expected)
    other = MATCHERS[name](pair.left, other_band, max_disp=12, preprocess={"none": "cade", "cade": "none"}[expected])
    assert np.array_equal(auto.disparity, chosen.disparity, equal_nan=True)
    assert not np.array_equal(auto.disparity, other.disparity, equal_nan=True)
