"""The CADE building blocks against slow references written from METHOD.md sections 2-3."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cade_cli.errors import CadeError
from cade_cli.spectral import BAND_NAMES, FLAT_TOLERANCE, color_agnostic, synthesize_bands

# ---------------------------------------------------------------------------------------
# Color agnostic transform (METHOD.md section 3)
# ---------------------------------------------------------------------------------------


def _window_values(image: np.ndarray, row: int, column: int, window: int) -> np.ndarray:
    """The window x window neighbourhood of (row, column), borders replicated by clamping."""
    height, width = image.shape
    half = window // 2
    rows = [min(max(row + dy, 0), height - 1) for dy in range(-half, half + 1)]
    columns = [min(max(column + dx, 0), width - 1) for dx in range(-half, half + 1)]
    return np.array([[image[r, c] for c in columns] for r in rows], dtype=np.float64)


def color_agnostic_reference(image: np.ndarray, window: int) -> np.ndarray:
    """Per-pixel loops, float64, straight from METHOD.md section 3 (population variance)."""
    return _reference_with_flat_mask(image, window)[0]


def _reference_with_flat_mask(image: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """The reference transform and the mask of flat windows (0 by rule, not by clipping)."""
    x = np.asarray(image, dtype=np.float64)
    height, width = x.shape
    filtered = np.empty_like(x)
    for row in range(height):
        for column in range(width):
            filtered[row, column] = np.median(_window_values(x, row, column, window))
    flat_limit = FLAT_TOLERANCE * (x.max() - x.min())
    result = np.zeros_like(x)
    flat = np.zeros(x.shape, bool)
    for row in range(height):
        for column in range(width):
            values = _window_values(filtered, row, column, window)
            mu = values.mean()
            sigma = np.sqrt(((values - mu) ** 2).sum() / values.size)
            if sigma <= flat_limit:
                flat[row, column] = True
                continue
            standardized = (filtered[row, column] - mu) / sigma
            result[row, column] = min(max(0.5 + 0.5 * standardized, 0.0), 1.0)
    return result, flat


def _image_with_flat_patches(seed: int, shape: tuple[int, int]) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = rng.random(shape)
    image[: shape[0] // 2, : shape[1] // 2] = 0.25  # a flat corner: windows inside it are flat
    image[-3:, -4:] = 0.75
    return image


@pytest.mark.parametrize("window", [3, 5, 7])  # 7 takes the NumPy median fallback
@pytest.mark.parametrize("shape", [(9, 11), (12, 7), (7, 13)])
def test_agrees_with_reference_on_random_images(window, shape):
    image = np.random.default_rng(window * 100 + shape[0]).random(shape)
    fast = color_agnostic(image, window=window)
    np.testing.assert_allclose(fast, color_agnostic_reference(image, window), atol=1e-5, rtol=0)


@pytest.mark.parametrize("window", [3, 5, 7])
@pytest.mark.parametrize("shape", [(12, 11), (14, 16)])
def test_agrees_with_reference_with_flat_regions(window, shape):
    image = _image_with_flat_patches(window + shape[1], shape)
    expected, flat = _reference_with_flat_mask(image, window)
    assert flat.sum() >= 4 and (~flat).sum() >= 20  # the flat rule really is exercised
    fast = color_agnostic(image, window=window)
    np.testing.assert_allclose(fast, expected, atol=1e-5, rtol=0)
    # Deep inside the flat corner every window is flat.
    half = window // 2
    corner = fast[: shape[0] // 2 - half, : shape[1] // 2 - half]
    assert corner.size > 0 and np.all(corner == 0.0)


@pytest.mark.parametrize("value", [0.0, 0.3, 255.0, -7.5])
def test_constant_image_gives_zeros(value):
    result = color_agnostic(np.full((8, 10), value), window=3)
    assert result.dtype == np.float32 and result.shape == (8, 10)
    assert np.all(result == 0.0)


def test_structure_visible_on_simple_edge():
    """A step edge: the bright side of the edge is above 0.5, the dark side below."""
    image = np.zeros((9, 10))
    image[:, 5:] = 1.0
    result = color_agnostic(image, window=3)
    assert np.all(result[:, 4] < 0.5) and np.all(result[:, 5] > 0.5)
    assert np.all(result[:, :3] == 0.0) and np.all(result[:, 7:] == 0.0)  # flat far from the edge


_AFFINE_IMAGE = _image_with_flat_patches(7, (16, 18))
_AFFINE_EXPECTED = color_agnostic(_AFFINE_IMAGE, window=3)


@settings(max_examples=30, deadline=None)
@given(
    scale=st.floats(min_value=1e-3, max_value=1e3, allow_nan=False),
    offset=st.floats(min_value=-1e3, max_value=1e3, allow_nan=False),
)
def test_invariant_under_positive_affine_intensity_change(scale, offset):
    changed = color_agnostic(scale * _AFFINE_IMAGE + offset, window=3)
    np.testing.assert_allclose(changed, _AFFINE_EXPECTED, atol=1e-4, rtol=0)
    # The flat rule decides identically (relative tolerance), not just approximately.
    np.testing.assert_array_equal(changed == 0.0, _AFFINE_EXPECTED == 0.0)


@pytest.mark.parametrize("window", [3, 5, 7])
def test_contrast_inversion_mirrors_output(window):
    image = _image_with_flat_patches(11, (15, 17))
    forward = color_agnostic(image, window=window)
    inverted = color_agnostic(-2.0 * image + 1.0, window=window)
    unclipped = (forward > 1e-4) & (forward < 1.0 - 1e-4)
    assert unclipped.sum() > 50
    np.testing.assert_allclose(inverted[unclipped], 1.0 - forward[unclipped], atol=1e-5, rtol=0)
    flat = _reference_with_flat_mask(image, window)[1]
    assert flat.any() and np.all(inverted[flat] == 0.0)  # flat windows stay 0, not 1


def test_output_dtype_range_shape_and_input_untouched(rng):
    image = rng.normal(5.0, 3.0, size=(20, 31))
    before = image.copy()
    result = color_agnostic(image, window=5)
    assert result.dtype == np.float32 and result.shape == image.shape
    assert result.min() >= 0.0 and result.max() <= 1.0
    assert np.array_equal(image, before)
    # Both clipping bounds are reached on a noisy image, so the clip is really there.
    assert result.min() == 0.0 and result.max() == 1.0


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64, np.int32])
def test_accepts_integer_and_float_dtypes(rng, dtype):
    values = rng.integers(0, 200, size=(10, 12))
    image = values.astype(dtype)
    result = color_agnostic(image, window=3)
    assert result.dtype == np.float32
    np.testing.assert_allclose(result, color_agnostic_reference(values, 3), atol=1e-5, rtol=0)


def test_window_default_is_three(rng):
    image = rng.random((10, 10))
    assert np.array_equal(color_agnostic(image), color_agnostic(image, window=3))


@pytest.mark.parametrize(
    "image, window",
    [
        (np.zeros((8, 8, 3)), 3),        # 3-D: an RGB image, not a band
        (np.zeros(16), 3),               # 1-D
        (np.random.default_rng(0).random((8, 8)), 4),  # even window
        (np.random.default_rng(0).random((8, 8)), 2),
        (np.random.default_rng(0).random((8, 8)), 1),  # too small
        (np.random.default_rng(0).random((8, 8)), 0),
        (np.random.default_rng(0).random((8, 8)), -3),
        (np.random.default_rng(0).random((2, 8)), 3),  # image smaller than the window
        (np.random.default_rng(0).random((8, 6)), 7),
    ],
)
def test_bad_input_raises(image, window):
    with pytest.raises(CadeError):
        color_agnostic(image, window=window)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_input_raises(rng, bad):
    image = rng.random((8, 8))
    image[3, 4] = bad
    with pytest.raises(CadeError):
        color_agnostic(image, window=3)


# ---------------------------------------------------------------------------------------
# Spectral band synthesis (METHOD.md section 2)
# ---------------------------------------------------------------------------------------


def bands_reference(rgb: np.ndarray, r: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pixel loops in float64 with the given coefficients r0..r16."""
    height, width, _ = rgb.shape
    out = {name: np.zeros((height, width)) for name in BAND_NAMES}

    def weighted(weights, values):
        total = sum(weights)
        return sum(w * v for w, v in zip(weights, values)) / total

    for y in range(height):
        for x in range(width):
            red, green, blue = (float(v) for v in rgb[y, x])
            out["R"][y, x] = red
            out["G"][y, x] = green
            out["B"][y, x] = blue
            out["BG"][y, x] = weighted(r[0:2], (blue, green))
            out["BR"][y, x] = weighted(r[2:4], (blue, red))
            out["GR"][y, x] = weighted(r[4:6], (green, red))
            out["BGR"][y, x] = weighted(r[6:9], (blue, green, red))
            out["BnG"][y, x] = min(r[9] * blue, r[10] * green)
            out["GnR"][y, x] = min(r[11] * green, r[12] * red)
            out["BuG"][y, x] = max(r[13] * blue, r[14] * green)
            out["GuR"][y, x] = max(r[15] * green, r[16] * red)
    return out


def test_band_names_are_the_eleven_of_the_method():
    assert BAND_NAMES == ("R", "G", "B", "BG", "BR", "GR", "BGR", "BnG", "GnR", "BuG", "GuR")


@pytest.mark.parametrize("seed", [0, 1, 12345])
def test_bands_match_per_pixel_reference(seed):
    rgb = np.random.default_rng(seed + 1000).random((6, 9, 3))
    bands = synthesize_bands(rgb, np.random.default_rng(seed))
    r = np.random.default_rng(seed).uniform(0.0, 1.0, size=17)
    expected = bands_reference(rgb, r)
    assert list(bands) == list(BAND_NAMES)
    for name in BAND_NAMES:
        band = bands[name]
        assert band.shape == (6, 9) and band.dtype == np.float32, name
        assert band.min() >= 0.0 and band.max() <= 1.0, name
        np.testing.assert_allclose(band, expected[name], atol=1e-6, rtol=0, err_msg=name)


def test_plain_channels_are_copied_exactly(rng):
    rgb = rng.random((5, 7, 3)).astype(np.float32)
    bands = synthesize_bands(rgb, rng)
    for index, name in enumerate("RGB"):
        assert np.array_equal(bands[name], rgb[..., index])


def test_input_is_not_modified(rng):
    rgb = rng.random((5, 7, 3)).astype(np.float32)
    before = rgb.copy()
    bands = synthesize_bands(rgb, rng)
    bands["R"][:] = -1.0  # writing into a returned band must not reach the caller's image
    assert np.array_equal(rgb, before)


def test_fresh_coefficients_on_every_call(rng):
    rgb = rng.random((6, 6, 3))
    first = synthesize_bands(rgb, rng)
    second = synthesize_bands(rgb, rng)
    assert not np.allclose(first["BG"], second["BG"])
    assert np.array_equal(first["G"], second["G"])


class _ZeroCoefficients:
    """A stand-in generator whose every draw is 0: the denominators all vanish."""

    def uniform(self, low=0.0, high=1.0, size=None):
        return np.zeros(size)


def test_zero_weights_fall_back_to_plain_mean(rng):
    rgb = rng.random((5, 6, 3))
    bands = synthesize_bands(rgb, _ZeroCoefficients())
    red, green, blue = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    for name in BAND_NAMES:
        assert np.isfinite(bands[name]).all(), name
    np.testing.assert_allclose(bands["BG"], (blue + green) / 2, atol=1e-6)
    np.testing.assert_allclose(bands["BR"], (blue + red) / 2, atol=1e-6)
    np.testing.assert_allclose(bands["GR"], (green + red) / 2, atol=1e-6)
    np.testing.assert_allclose(bands["BGR"], (blue + green + red) / 3, atol=1e-6)
    for name in ("BnG", "GnR", "BuG", "GuR"):
        assert np.all(bands[name] == 0.0), name


def test_saturated_pixels_stay_in_unit_range():
    rgb = np.ones((4, 4, 3), np.float32)
    rng = np.random.default_rng(0)
    for _ in range(200):
        bands = synthesize_bands(rgb, rng)
        for name in BAND_NAMES:
            assert bands[name].max() <= 1.0, name


@pytest.mark.parametrize("shape", [(8, 8), (8, 8, 4), (8, 8, 1), (3, 8, 8), (8,)])
def test_bad_rgb_shape_raises(rng, shape):
    with pytest.raises(CadeError):
        synthesize_bands(np.zeros(shape), rng)
