"""Disparity files: round trips, on-disk conventions, errors, colouring, real GT."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from cade_cli.errors import CadeError
from cade_cli.io.disparity import DISPARITY_SUFFIXES, read_disparity, read_pfm, write_disparity, write_pfm
from cade_cli.io.images import read_band
from cade_cli.io.match_outputs import colorize_disparity, disparity_picture, write_visualization


def _signed_disparity(rng: np.random.Generator) -> np.ndarray:
    """(6, 9) float32 in [-40, 300) with a few NaNs."""
    values = rng.uniform(-40.0, 300.0, size=(6, 9)).astype(np.float32)
    values[rng.random(values.shape) < 0.2] = np.nan
    values[0, 0] = np.nan
    return values


def _only_file(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", [".pfm", ".tif", ".tiff", ".npy", ".PFM"])
def test_float_formats_round_trip_exactly(tmp_path: Path, suffix: str, rng: np.random.Generator) -> None:
    disparity = _signed_disparity(rng)
    path = tmp_path / f"disp{suffix}"
    write_disparity(path, disparity)
    back = read_disparity(path)
    assert back.dtype == np.float32 and back.shape == disparity.shape
    np.testing.assert_array_equal(back, disparity)  # NaN positions must match too
    assert _only_file(tmp_path) == [path.name]


def test_png_round_trip_on_the_256_grid(tmp_path: Path, rng: np.random.Generator) -> None:
    disparity = (rng.integers(1, 65536, size=(7, 5)) / 256).astype(np.float32)
    disparity[2, 3] = np.nan
    write_disparity(tmp_path / "d.png", disparity)
    np.testing.assert_array_equal(read_disparity(tmp_path / "d.png"), disparity)


def test_png_encoding_is_kitti(tmp_path: Path) -> None:
    disparity = np.array([[np.nan, 0.0, 0.001, 1.0], [10.3, 100.5, 255.5, 255.999]], dtype=np.float32)
    write_disparity(tmp_path / "d.png", disparity)
    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (2, 4)
    # NaN -> 0; 0 and 0.001 round to 0 but are valid -> 1; 255.999 * 256 rounds past 65535 -> 65535
    np.testing.assert_array_equal(raw, [[0, 1, 1, 256], [2637, 25728, 65408, 65535]])
    back = read_disparity(tmp_path / "d.png")
    assert np.isnan(back[0, 0]) and not np.isnan(back[0, 1:]).any()
    np.testing.assert_allclose(back[1, :3], disparity[1, :3], atol=1 / 512)
    assert back[1, 3] == np.float32(65535 / 256)


@pytest.mark.parametrize("bad", [256.0, 300.0, -0.5])
def test_png_refuses_values_outside_range_before_writing(tmp_path: Path, bad: float) -> None:
    path = tmp_path / "d.png"
    path.write_bytes(b"old")
    disparity = np.array([[1.0, np.nan], [bad, 2.0]], dtype=np.float32)
    with pytest.raises(CadeError, match=r"16-bit PNG.*\.pfm, \.tif or \.npy"):
        write_disparity(path, disparity)
    assert path.read_bytes() == b"old"
    assert _only_file(tmp_path) == ["d.png"]


def test_messages_name_the_output_not_its_staged_temporary(tmp_path: Path) -> None:
    """A command writes through a hidden stand-in (atomic_outputs): what goes wrong names the user's file."""
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.disparity import check_disparity_range

    path = tmp_path / "d.png"
    with pytest.raises(CadeError) as error, atomic_outputs([path]) as staged:
        write_disparity(staged[path], np.array([[300.0]], np.float32))
    assert str(path) in str(error.value) and ".tmp-" not in str(error.value)
    with pytest.raises(CadeError, match=r"search range is \[0, 256\].*--max-disp below 256") as error:
        check_disparity_range(tmp_path / ".d.tmp-0123456789abcdef.png", 0, 256)
    assert str(path) in str(error.value) and ".tmp-" not in str(error.value)
    check_disparity_range(path, 0, 255)  # fits
    check_disparity_range(tmp_path / "d.pfm", -80, 900)  # any range fits a float format


def test_all_nan_png(tmp_path: Path) -> None:
    write_disparity(tmp_path / "d.png", np.full((2, 2), np.nan, np.float32))
    assert np.isnan(read_disparity(tmp_path / "d.png")).all()


def test_infinities_count_as_invalid_and_input_is_not_modified(tmp_path: Path) -> None:
    disparity = np.array([[np.inf, -np.inf], [1.5, np.nan]], dtype=np.float32)
    kept = disparity.copy()
    for suffix in (".npy", ".tif", ".pfm"):
        write_disparity(tmp_path / f"d{suffix}", disparity)
        back = read_disparity(tmp_path / f"d{suffix}")
        np.testing.assert_array_equal(back, [[np.nan, np.nan], [1.5, np.nan]])
    np.testing.assert_array_equal(disparity, kept)


def test_float64_and_integer_input_are_written_as_float32(tmp_path: Path) -> None:
    write_disparity(tmp_path / "a.npy", np.array([[1.25, 2.0]], dtype=np.float64))
    write_disparity(tmp_path / "b.npy", np.array([[3, 4]], dtype=np.int32))
    assert np.load(tmp_path / "a.npy").dtype == np.float32
    np.testing.assert_array_equal(read_disparity(tmp_path / "b.npy"), [[3.0, 4.0]])


# ---------------------------------------------------------------- PFM layout


def test_pfm_bytes_are_little_endian_bottom_to_top(tmp_path: Path) -> None:
    disparity = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, np.nan]], dtype=np.float32)
    write_disparity(tmp_path / "d.pfm", disparity)
    raw = (tmp_path / "d.pfm").read_bytes()
    header = b"Pf\n3 2\n-1.0\n"
    assert raw[: len(header)] == header
    stored = struct.unpack("<6f", raw[len(header) :])
    assert stored == (4.0, 5.0, float("inf"), 1.0, 2.0, 3.0)  # bottom row first; NaN -> inf


def test_read_pfm_keeps_inf(tmp_path: Path) -> None:
    write_pfm(tmp_path / "d.pfm", np.array([[np.inf, 1.0]], dtype=np.float32))
    np.testing.assert_array_equal(read_pfm(tmp_path / "d.pfm"), [[np.inf, 1.0]])
    np.testing.assert_array_equal(read_disparity(tmp_path / "d.pfm"), [[np.nan, 1.0]])


def test_read_pfm_big_endian(tmp_path: Path) -> None:
    rows = np.array([[1.5, -2.0, 3.25], [np.inf, 7.0, 8.5]], dtype=np.float32)
    payload = np.ascontiguousarray(rows[::-1], dtype=">f4").tobytes()
    (tmp_path / "be.pfm").write_bytes(b"Pf\n3 2\n1.0\n" + payload)
    back = read_pfm(tmp_path / "be.pfm")
    assert back.dtype == np.float32 and back.dtype.byteorder in ("=", "<", "|")
    np.testing.assert_array_equal(back, rows)


@pytest.mark.parametrize("byte_order, scale", [("<f4", b"-0.003922"), (">f4", b"255.0")])
def test_read_pfm_colour(tmp_path: Path, byte_order: str, scale: bytes) -> None:
    colour = np.arange(2 * 4 * 3, dtype=np.float32).reshape(2, 4, 3)
    payload = np.ascontiguousarray(colour[::-1], dtype=byte_order).tobytes()
    (tmp_path / "c.pfm").write_bytes(b"PF\n4 2\n" + scale + b"\n" + payload)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), colour)
    with pytest.raises(CadeError, match="not one \\(H, W\\) disparity map"):
        read_disparity(tmp_path / "c.pfm")


def test_read_pfm_tolerates_header_whitespace(tmp_path: Path) -> None:
    """FlyingThings3D writes 'Pf \\n960 540 \\n-1.0\\n'; others use '\\r\\n'."""
    rows = np.array([[1.0, 2.0]], dtype=np.float32)
    for header in (b"Pf \n2 1 \n-1.0\n", b"Pf\r\n2 1\r\n-1\r\n", b"Pf\n2\n1\n-1.0\n"):
        (tmp_path / "w.pfm").write_bytes(header + rows.astype("<f4").tobytes())
        np.testing.assert_array_equal(read_pfm(tmp_path / "w.pfm"), rows)


@pytest.mark.parametrize(
    "content",
    [
        b"P5\n2 1\n255\n\x00\x00",
        b"Pf\n2 x\n-1.0\n" + bytes(8),
        b"Pf\n2 1\n0.0\n" + bytes(8),
        b"Pf\n0 1\n-1.0\n" + bytes(8),
        b"Pf\n2 1\n",
        b"Pf\n2 1\nnan\n" + bytes(8),
        bytes(range(256)) * 4,
    ],
)
def test_malformed_pfm_header(tmp_path: Path, content: bytes) -> None:
    (tmp_path / "bad.pfm").write_bytes(content)
    for read in (read_pfm, read_disparity):
        with pytest.raises(CadeError, match="not a valid PFM"):
            read(tmp_path / "bad.pfm")


def test_truncated_pfm(tmp_path: Path) -> None:
    (tmp_path / "cut.pfm").write_bytes(b"Pf\n3 2\n-1.0\n" + bytes(20))
    with pytest.raises(CadeError, match="truncated"):
        read_pfm(tmp_path / "cut.pfm")


# ---------------------------------------------------------------- read errors


def test_read_errors(tmp_path: Path, rng: np.random.Generator) -> None:
    with pytest.raises(CadeError, match="does not exist"):
        read_disparity(tmp_path / "nope.pfm")
    (tmp_path / "dir.pfm").mkdir()
    with pytest.raises(CadeError, match="is a directory"):
        read_disparity(tmp_path / "dir.pfm")
    (tmp_path / "d.exr").write_bytes(b"x")
    with pytest.raises(CadeError, match=r"unsupported extension \.exr.*\.pfm, \.tif, \.tiff, \.png, \.npy"):
        read_disparity(tmp_path / "d.exr")
    (tmp_path / "empty.npy").write_bytes(b"")
    with pytest.raises(CadeError, match="empty"):
        read_disparity(tmp_path / "empty.npy")


@pytest.mark.parametrize("suffix", [".pfm", ".tif", ".png", ".npy"])
def test_random_bytes_are_a_cade_error(tmp_path: Path, suffix: str, rng: np.random.Generator) -> None:
    path = tmp_path / f"noise{suffix}"
    path.write_bytes(rng.integers(0, 256, size=3000).astype(np.uint8).tobytes())
    with pytest.raises(CadeError) as caught:
        read_disparity(path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_wrong_content_is_refused(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "eight.png"), np.full((2, 2), 30, np.uint8))
    with pytest.raises(CadeError, match="uint8 PNG.*16-bit"):
        read_disparity(tmp_path / "eight.png")
    tifffile.imwrite(tmp_path / "int.tif", np.full((2, 2), 30, np.uint16))
    with pytest.raises(CadeError, match="uint16.*float32"):
        read_disparity(tmp_path / "int.tif")
    np.save(tmp_path / "cube.npy", np.zeros((2, 2, 2), np.float32))
    with pytest.raises(CadeError, match="shape \\(2, 2, 2\\)"):
        read_disparity(tmp_path / "cube.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(CadeError, match="obj.npy"):
        read_disparity(tmp_path / "obj.npy")


# ---------------------------------------------------------------- write errors


def test_write_errors_leave_nothing(tmp_path: Path) -> None:
    with pytest.raises(CadeError, match=r"unsupported extension \.jpg.*\.pfm, \.tif, \.tiff, \.png, \.npy"):
        write_disparity(tmp_path / "d.jpg", np.zeros((2, 2), np.float32))
    with pytest.raises(CadeError, match="unsupported extension \\(none\\)"):
        write_disparity(tmp_path / "d", np.zeros((2, 2), np.float32))
    with pytest.raises(CadeError, match=r"shape \(H, W\), got shape \(2, 2, 3\)"):
        write_disparity(tmp_path / "d.pfm", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(CadeError, match=r"got shape \(4,\)"):
        write_disparity(tmp_path / "d.npy", np.zeros(4, np.float32))
    with pytest.raises(CadeError, match="does not exist; create it first"):
        write_disparity(tmp_path / "missing" / "d.pfm", np.zeros((2, 2), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_existing_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "d.tif"
    path.write_bytes(b"old")

    def disk_full(*args: object, **kwargs: object) -> None:
        Path(args[0]).write_bytes(b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(tifffile, "imwrite", disk_full)
    with pytest.raises(CadeError, match="could not write .*No space left on device"):
        write_disparity(path, np.zeros((2, 2), np.float32))
    assert path.read_bytes() == b"old"
    assert _only_file(tmp_path) == ["d.tif"]


def test_suffixes_constant() -> None:
    assert DISPARITY_SUFFIXES == (".pfm", ".tif", ".tiff", ".png", ".npy")


# ---------------------------------------------------------------- visualization


def _turbo(level: int) -> np.ndarray:
    return cv2.applyColorMap(np.array([[level]], dtype=np.uint8), cv2.COLORMAP_TURBO)[0, 0]


def test_colorize_ends_and_invalid(tmp_path: Path) -> None:
    disparity = np.array([[2.0, 4.0, 6.0, np.nan]], dtype=np.float32)
    coloured = colorize_disparity(disparity)
    assert coloured.shape == (1, 4, 3) and coloured.dtype == np.uint8
    np.testing.assert_array_equal(coloured[0, 0], _turbo(0))
    np.testing.assert_array_equal(coloured[0, 1], _turbo(128))
    np.testing.assert_array_equal(coloured[0, 2], _turbo(255))
    np.testing.assert_array_equal(coloured[0, 3], [0, 0, 0])
    assert _turbo(0).any()  # the low end is not black, so invalid stays distinguishable
    assert _turbo(255)[2] > _turbo(255)[0]  # BGR: the warm end has more red than blue


def test_colorize_explicit_range_clips() -> None:
    disparity = np.array([[0.0, 10.0, 20.0, 30.0]], dtype=np.float32)
    coloured = colorize_disparity(disparity, vmin=10.0, vmax=20.0)
    np.testing.assert_array_equal(coloured[0], [_turbo(0), _turbo(0), _turbo(255), _turbo(255)])
    only_max = colorize_disparity(disparity, vmax=-5.0)
    np.testing.assert_array_equal(only_max[0], [_turbo(255)] * 4)
    with pytest.raises(CadeError, match="vmax 1.0 is below vmin 2.0"):
        colorize_disparity(disparity, vmin=2.0, vmax=1.0)


def test_colorize_degenerate_maps() -> None:
    assert not colorize_disparity(np.full((2, 3), np.nan, np.float32)).any()
    constant = colorize_disparity(np.full((2, 3), 7.0, np.float32))
    assert (constant == _turbo(0)).all()
    with pytest.raises(CadeError, match="shape"):
        colorize_disparity(np.zeros((2, 3, 3), np.float32))


def test_write_visualization(tmp_path: Path, rng: np.random.Generator) -> None:
    disparity = _signed_disparity(rng)
    write_visualization(tmp_path / "vis.png", disparity, value_range=(0.0, 100.0))
    written = cv2.imread(str(tmp_path / "vis.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(written, disparity_picture(disparity, value_range=(0.0, 100.0)))
    np.testing.assert_array_equal(written[:6, :9], colorize_disparity(disparity, vmin=0.0, vmax=100.0))
    with pytest.raises(CadeError, match=r"must be a \.png"):
        write_visualization(tmp_path / "vis.jpg", disparity)
    assert _only_file(tmp_path) == ["vis.png"]


# ---------------------------------------------------------------- real ground truth


def _warp_error(left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> float:
    """Mean |left - right warped by disparity| over finite, in-image pixels (x_right = x - d)."""
    height, width = disparity.shape
    map_x = np.arange(width, dtype=np.float32)[None, :] - disparity
    map_y = np.broadcast_to(np.arange(height, dtype=np.float32)[:, None], disparity.shape)
    valid = np.isfinite(map_x) & (map_x >= 0) & (map_x <= width - 1)
    warped = cv2.remap(right, np.where(valid, map_x, 0).astype(np.float32), np.ascontiguousarray(map_y), cv2.INTER_LINEAR)
    assert valid.mean() > 0.5
    return float(np.abs(warped - left)[valid].mean())


def _calib(path: Path) -> dict[str, str]:
    return dict(line.split("=", 1) for line in path.read_text().splitlines() if "=" in line)


MIDDLEBURY_SCENES = ("Adirondack", "ArtL", "Jadeplant", "Motorcycle", "Piano", "Pipes", "Playroom", "Playtable")


@pytest.mark.parametrize("scene", MIDDLEBURY_SCENES)
def test_middlebury2014_gt(shared_data: Path, scene: str) -> None:
    folder = shared_data / "middlebury2014" / "trainingQ" / scene
    left, _ = read_band(folder / "im0.png")
    right, _ = read_band(folder / "im1.png")
    disparity = read_disparity(folder / "disp0GT.pfm")
    assert disparity.shape == left.shape == right.shape
    finite = disparity[np.isfinite(disparity)]
    assert finite.size > 0.9 * disparity.size
    calib = _calib(folder / "calib.txt")
    assert float(calib["vmin"]) - 1 <= finite.min() and finite.max() <= float(calib["vmax"]) + 1
    right_way_up = _warp_error(left, right, disparity)
    upside_down = _warp_error(left, right, np.flipud(disparity))
    assert right_way_up < 0.8 * upside_down


def test_flyingthings3d_gt(shared_data: Path) -> None:
    root = shared_data / "flyingthings3d"
    files = sorted((root / "disparity").glob("*/*/*/left/*.pfm"))
    assert len(files) == 4
    for path in files:
        disparity = read_disparity(path)
        assert disparity.shape == (540, 960)
        assert np.isfinite(disparity).all() and (disparity > 0).all()
        frame = root / "frames_cleanpass" / path.relative_to(root / "disparity").with_suffix(".png")
        left, _ = read_band(frame)
        right, _ = read_band(frame.parent.parent / "right" / frame.name)
        assert _warp_error(left, right, disparity) < 0.8 * _warp_error(left, right, np.flipud(disparity))


def test_picture_writers_name_the_output_not_its_staged_temporary(tmp_path: Path) -> None:
    """The visualization and the rectified images are written through hidden stand-ins too:
    their refusals name the file the user asked for."""
    from cade_cli.rigs.outputs import write_rectified_image

    staged = tmp_path / ".vis.tmp-0123456789abcdef.jpg"
    with pytest.raises(CadeError, match="must be a .png") as error:
        write_visualization(staged, np.ones((4, 4), np.float32))
    assert str(tmp_path / "vis.jpg") in str(error.value) and ".tmp-" not in str(error.value)
    with pytest.raises(CadeError, match="use .png") as error:
        write_rectified_image(tmp_path / ".left.tmp-0123456789abcdef.bmp", np.ones((4, 4), np.float32))
    assert str(tmp_path / "left.bmp") in str(error.value) and ".tmp-" not in str(error.value)
    assert list(tmp_path.iterdir()) == []
