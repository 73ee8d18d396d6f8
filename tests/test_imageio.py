"""Reading images and bands: formats, value scaling, channel order, errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from cade_cli.errors import CadeError
from cade_cli.io.image_files import SUPPORTED_IMAGE_SUFFIXES
from cade_cli.io.images import load_image, read_band

GREY8 = np.array([[0, 1, 128], [200, 254, 255]], dtype=np.uint8)
GREY16 = np.array([[0, 1, 1000], [30000, 65534, 65535]], dtype=np.uint16)


def _bgr(rgb: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(rgb[..., ::-1])


def _rgb_texture(rng: np.random.Generator, dtype: type, high: int) -> np.ndarray:
    return rng.integers(0, high + 1, size=(5, 7, 3)).astype(dtype)


def _write_cv2(path: Path, image: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), image), f"test setup: cv2 could not write {path}"
    return path


# ---------------------------------------------------------------- lossless formats


@pytest.mark.parametrize("suffix", [".png", ".pgm", ".pnm", ".bmp", ".tif", ".tiff"])
def test_grey_8bit_scaled_by_255(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"grey{suffix}"
    if suffix in (".tif", ".tiff"):
        tifffile.imwrite(path, GREY8)
    else:
        _write_cv2(path, GREY8)
    image = load_image(path)
    assert image.dtype == np.float32
    assert image.shape == (2, 3)
    np.testing.assert_array_equal(image, GREY8.astype(np.float32) / np.float32(255))
    assert image[1, 2] == 1.0 and image[0, 0] == 0.0


@pytest.mark.parametrize("suffix", [".png", ".pgm", ".pnm", ".tif"])
def test_grey_16bit_scaled_by_65535(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"grey16{suffix}"
    if suffix == ".tif":
        tifffile.imwrite(path, GREY16)
    else:
        _write_cv2(path, GREY16)
    image = load_image(path)
    assert image.dtype == np.float32
    np.testing.assert_array_equal(image, GREY16.astype(np.float32) / np.float32(65535))
    assert image[1, 2] == 1.0


@pytest.mark.parametrize("suffix", [".png", ".ppm", ".pnm", ".bmp"])
def test_colour_8bit_is_rgb_order_and_exact(tmp_path: Path, suffix: str, rng: np.random.Generator) -> None:
    rgb = _rgb_texture(rng, np.uint8, 255)
    image = load_image(_write_cv2(tmp_path / f"colour{suffix}", _bgr(rgb)))
    assert image.shape == (5, 7, 3) and image.dtype == np.float32
    np.testing.assert_array_equal(image, rgb.astype(np.float32) / np.float32(255))


@pytest.mark.parametrize("suffix", [".png", ".ppm"])
def test_colour_16bit_is_rgb_order_and_exact(tmp_path: Path, suffix: str, rng: np.random.Generator) -> None:
    rgb = _rgb_texture(rng, np.uint16, 65535)
    image = load_image(_write_cv2(tmp_path / f"colour16{suffix}", _bgr(rgb)))
    np.testing.assert_array_equal(image, rgb.astype(np.float32) / np.float32(65535))


def test_pure_red_png_reads_as_red_channel(tmp_path: Path) -> None:
    bgr_red = np.zeros((4, 4, 3), dtype=np.uint8)
    bgr_red[..., 2] = 255
    image = load_image(_write_cv2(tmp_path / "red.png", bgr_red))
    assert (image[..., 0] == 1.0).all()
    assert (image[..., 1:] == 0.0).all()


def test_rgba_png_is_rgba_order(tmp_path: Path) -> None:
    bgra = np.zeros((3, 3, 4), dtype=np.uint8)
    bgra[..., 0], bgra[..., 1], bgra[..., 2], bgra[..., 3] = 10, 20, 30, 40  # B, G, R, A
    image = load_image(_write_cv2(tmp_path / "rgba.png", bgra))
    np.testing.assert_array_equal(image[0, 0] * 255, np.float32([30, 20, 10, 40]))


def test_jpeg_is_close_and_rgb_order(tmp_path: Path) -> None:
    bgr = np.zeros((16, 16, 3), dtype=np.uint8)
    bgr[..., 2] = 200  # red
    bgr[..., 0] = 50  # blue
    for suffix in (".jpg", ".jpeg"):
        image = load_image(_write_cv2(tmp_path / f"photo{suffix}", bgr))
        assert image.shape == (16, 16, 3)
        np.testing.assert_allclose(image.mean(axis=(0, 1)), np.array([200, 0, 50]) / 255, atol=4 / 255)


# ---------------------------------------------------------------- TIFF layouts


def test_tiff_interleaved_rgb(tmp_path: Path, rng: np.random.Generator) -> None:
    rgb = _rgb_texture(rng, np.uint16, 65535)
    tifffile.imwrite(tmp_path / "rgb.tif", rgb, photometric="rgb")
    np.testing.assert_array_equal(load_image(tmp_path / "rgb.tif"), rgb / np.float32(65535))


def test_tiff_planar_rgb(tmp_path: Path, rng: np.random.Generator) -> None:
    rgb = _rgb_texture(rng, np.uint8, 255)
    tifffile.imwrite(tmp_path / "planar.tif", np.moveaxis(rgb, -1, 0), photometric="rgb", planarconfig="separate")
    with tifffile.TiffFile(tmp_path / "planar.tif") as tif:
        assert tif.series[0].axes == "SYX"  # the layout this test is about
    np.testing.assert_array_equal(load_image(tmp_path / "planar.tif"), rgb / np.float32(255))


def test_tiff_planar_multispectral(tmp_path: Path, rng: np.random.Generator) -> None:
    bands = rng.integers(0, 65536, size=(5, 4, 6)).astype(np.uint16)
    tifffile.imwrite(tmp_path / "ms.tif", bands, photometric="minisblack", planarconfig="separate")
    image = load_image(tmp_path / "ms.tif")
    assert image.shape == (4, 6, 5)
    np.testing.assert_array_equal(image, np.moveaxis(bands, 0, -1) / np.float32(65535))


def test_tiff_multipage_pages_become_bands(tmp_path: Path, rng: np.random.Generator) -> None:
    pages = rng.integers(0, 256, size=(3, 4, 6)).astype(np.uint8)
    tifffile.imwrite(tmp_path / "pages.tif", pages, photometric="minisblack")
    with tifffile.TiffFile(tmp_path / "pages.tif") as tif:
        assert len(tif.pages) == 3
    image = load_image(tmp_path / "pages.tif")
    assert image.shape == (4, 6, 3)
    for index in range(3):
        np.testing.assert_array_equal(image[..., index], pages[index] / np.float32(255))


def test_tiff_appended_pages_become_bands(tmp_path: Path) -> None:
    path = tmp_path / "appended.tif"
    tifffile.imwrite(path, np.full((2, 3), 10, np.uint8))
    tifffile.imwrite(path, np.full((2, 3), 20, np.uint8), append=True)
    image = load_image(path)
    assert image.shape == (2, 3, 2)
    np.testing.assert_array_equal(image[0, 0] * 255, np.float32([10, 20]))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_tiff_float_kept_as_is(tmp_path: Path, dtype: type) -> None:
    values = np.array([[-3.5, 0.25, np.nan], [1e4, 2.0, 0.0]], dtype=dtype)
    tifffile.imwrite(tmp_path / "float.tif", values)
    image = load_image(tmp_path / "float.tif")
    assert image.dtype == np.float32
    np.testing.assert_array_equal(image, values.astype(np.float32))


def test_tiff_unsupported_dtype(tmp_path: Path) -> None:
    tifffile.imwrite(tmp_path / "int16.tif", np.zeros((3, 3), np.int16))
    with pytest.raises(CadeError, match=r"int16.*8-bit, 16-bit or float32"):
        load_image(tmp_path / "int16.tif")


def test_tiff_palette_is_refused(tmp_path: Path) -> None:
    colormap = np.zeros((3, 256), dtype=np.uint16)
    tifffile.imwrite(tmp_path / "pal.tif", np.zeros((3, 3), np.uint8), photometric="palette", colormap=colormap)
    with pytest.raises(CadeError, match="palette"):
        load_image(tmp_path / "pal.tif")


# ---------------------------------------------------------------- band selection


def test_single_band_with_none_or_zero(tmp_path: Path) -> None:
    path = _write_cv2(tmp_path / "grey.png", GREY8)
    for band in (None, 0):
        image, note = read_band(path, band)
        assert note is None
        assert image.shape == (2, 3) and image.dtype == np.float32
        np.testing.assert_array_equal(image, GREY8 / np.float32(255))


def test_colour_without_band_gives_luminance_and_note(tmp_path: Path, rng: np.random.Generator) -> None:
    rgb = _rgb_texture(rng, np.uint8, 255)
    path = _write_cv2(tmp_path / "left.png", _bgr(rgb))
    image, note = read_band(path)
    expected = (0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]) / 255
    assert image.shape == (5, 7) and image.dtype == np.float32
    np.testing.assert_allclose(image, expected, atol=1e-6)
    assert note is not None and "\n" not in note
    assert str(path) in note and "3 bands" in note and "luminance" in note


def test_rgba_luminance_ignores_alpha(tmp_path: Path, rng: np.random.Generator) -> None:
    rgb = _rgb_texture(rng, np.uint8, 255)
    alpha = rng.integers(0, 256, size=(5, 7, 1)).astype(np.uint8)
    rgba_path = _write_cv2(tmp_path / "rgba.png", np.concatenate([_bgr(rgb), alpha], axis=2))
    rgb_path = _write_cv2(tmp_path / "rgb.png", _bgr(rgb))
    from_rgba, note = read_band(rgba_path)
    np.testing.assert_array_equal(from_rgba, read_band(rgb_path)[0])
    assert note is not None and "4 bands" in note and "alpha" in note


def test_colour_band_index_picks_rgb_channel(tmp_path: Path) -> None:
    bgr = np.zeros((2, 2, 3), dtype=np.uint8)
    bgr[..., 2], bgr[..., 1], bgr[..., 0] = 255, 51, 0  # R=255, G=51, B=0
    path = _write_cv2(tmp_path / "c.png", bgr)
    red, note = read_band(path, 0)
    green, _ = read_band(path, 1)
    blue, _ = read_band(path, 2)
    assert note is None and red.shape == (2, 2) and red.flags.c_contiguous
    assert (red == 1.0).all() and (green == np.float32(51) / 255).all() and (blue == 0.0).all()


def test_tiff_rgb_without_band_gives_luminance(tmp_path: Path) -> None:
    rgb = np.zeros((2, 2, 3), dtype=np.uint8)
    rgb[..., 1] = 255
    tifffile.imwrite(tmp_path / "rgb.tif", rgb, photometric="rgb")
    image, note = read_band(tmp_path / "rgb.tif")
    np.testing.assert_allclose(image, 0.587, atol=1e-6)
    assert note is not None


@pytest.mark.parametrize("count", [2, 3, 5])
def test_multipage_or_non_colour_without_band_is_refused(tmp_path: Path, count: int) -> None:
    pages = np.zeros((count, 4, 4), dtype=np.uint8)
    tifffile.imwrite(tmp_path / "pages.tif", pages, photometric="minisblack")
    with pytest.raises(CadeError, match=rf"has {count} bands.*0-{count - 1}"):
        read_band(tmp_path / "pages.tif")


def test_multipage_band_selection(tmp_path: Path) -> None:
    pages = np.stack([np.full((3, 3), 1000 * (i + 1), np.uint16) for i in range(4)])
    tifffile.imwrite(tmp_path / "pages.tif", pages, photometric="minisblack")
    image, note = read_band(tmp_path / "pages.tif", 2)
    assert note is None
    np.testing.assert_array_equal(image, np.float32(3000) / np.float32(65535))


def test_band_out_of_range(tmp_path: Path) -> None:
    path = _write_cv2(tmp_path / "c.png", np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(CadeError, match=r"^band 5 is out of range: .*c\.png has 3 bands \(0-2\)$"):
        read_band(path, 5)
    with pytest.raises(CadeError, match="band -1 is out of range"):
        read_band(path, -1)
    grey = _write_cv2(tmp_path / "g.png", GREY8)
    with pytest.raises(CadeError, match=r"band 1 is out of range: .* 1 band \(0-0\)"):
        read_band(grey, 1)


# ---------------------------------------------------------------- errors


def _assert_cade_error(path: Path, pattern: str) -> None:
    for read in (load_image, read_band):
        with pytest.raises(CadeError, match=pattern) as caught:
            read(path)
        assert "\n" not in str(caught.value)
        assert str(path) in str(caught.value)


def test_missing_file(tmp_path: Path) -> None:
    _assert_cade_error(tmp_path / "nope.png", "does not exist")


def test_directory_instead_of_file(tmp_path: Path) -> None:
    (tmp_path / "dir.png").mkdir()
    _assert_cade_error(tmp_path / "dir.png", "is a directory")


def test_unsupported_extension_lists_supported(tmp_path: Path) -> None:
    (tmp_path / "anim.gif").write_bytes(b"GIF89a")
    with pytest.raises(CadeError) as caught:
        load_image(tmp_path / "anim.gif")
    assert ".gif" in str(caught.value)
    for suffix in SUPPORTED_IMAGE_SUFFIXES:
        assert suffix in str(caught.value)


def test_suffix_is_case_insensitive(tmp_path: Path) -> None:
    np.testing.assert_array_equal(load_image(_write_cv2(tmp_path / "G.PNG", GREY8)), GREY8 / np.float32(255))


@pytest.mark.parametrize("suffix", [".png", ".tif", ".jpg"])
def test_empty_file(tmp_path: Path, suffix: str) -> None:
    (tmp_path / f"empty{suffix}").write_bytes(b"")
    _assert_cade_error(tmp_path / f"empty{suffix}", "empty")


def test_empty_tiff_image(tmp_path: Path) -> None:
    with pytest.warns(UserWarning):
        tifffile.imwrite(tmp_path / "zero.tif", np.zeros((0, 4), np.uint8))
    _assert_cade_error(tmp_path / "zero.tif", "empty")


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".bmp", ".ppm", ".tif"])
def test_random_bytes_are_a_cade_error(tmp_path: Path, suffix: str, rng: np.random.Generator) -> None:
    path = tmp_path / f"noise{suffix}"
    path.write_bytes(rng.integers(0, 256, size=2000).astype(np.uint8).tobytes())
    _assert_cade_error(path, "cannot (decode|read)")


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".tif"])
def test_truncated_file_is_a_cade_error(tmp_path: Path, suffix: str, rng: np.random.Generator) -> None:
    whole = tmp_path / f"whole{suffix}"
    texture = rng.integers(0, 256, size=(64, 64)).astype(np.uint8)
    if suffix == ".tif":
        tifffile.imwrite(whole, texture)
    else:
        _write_cv2(whole, texture)
    data = whole.read_bytes()
    truncated = tmp_path / f"cut{suffix}"
    truncated.write_bytes(data[: len(data) // 2])
    _assert_cade_error(truncated, "cannot (decode|read)")


def test_tiff_without_images_is_a_cade_error(tmp_path: Path) -> None:
    path = tmp_path / "hollow.tif"
    path.write_bytes(b"II*\x00" + bytes(200))  # valid little-endian header, first IFD offset 0
    _assert_cade_error(path, "no images")
