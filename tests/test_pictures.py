"""Pictures for people: colour bars, robust and fixed ranges, legends, the registration overlay."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.evaluation.error_maps import NO_ESTIMATE_COLOUR, NO_GT_COLOUR, error_picture, save_maps
from cade_cli.io.disparity import read_disparity, write_disparity
from cade_cli.io.match_outputs import colorize_disparity, disparity_picture
from cade_cli.io.pictures import ColourBar, format_value, parse_value_range, robust_range, with_legend
from cade_cli.io.registered import registration_picture
from cade_cli.registration import Registration
from cade_cli.batch.pairs import PairOptions
from cli_runner import run_cade, write_png16
from synthetic import render_pair


def _ramp(colormap: int) -> np.ndarray:
    return cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None, :], colormap)[0]


def _bar_levels(picture: np.ndarray, map_height: int, colormap: int) -> np.ndarray:
    """The colormap levels along the first row under the map that is all colormap colours."""
    index = {tuple(colour): level for level, colour in enumerate(_ramp(colormap))}
    for row in picture[map_height:]:
        levels = [index.get(tuple(colour)) for colour in row]
        inner = [level for level in levels if level is not None]
        if len(inner) > 0.9 * len(row):
            return np.array(inner)
    raise AssertionError("no row of the colour ramp under the map")


def _has_swatch(panel: np.ndarray, colour: tuple[int, int, int], side: int = 6) -> bool:
    """Whether ``panel`` holds a filled square of ``colour`` at least ``side`` px wide."""
    mask = np.all(panel == np.array(colour, np.uint8), axis=-1).astype(np.uint8)
    return bool(cv2.erode(mask, np.ones((side, side), np.uint8)).any())


def test_disparity_picture_has_a_colour_bar_under_the_map(rng) -> None:
    disparity = rng.uniform(5.0, 60.0, (50, 400)).astype(np.float32)
    picture = disparity_picture(disparity)
    assert picture.shape[0] > 50 + 40 and picture.shape[1] == 400
    low, high = robust_range(disparity)
    np.testing.assert_array_equal(picture[:50, :400], colorize_disparity(disparity, vmin=low, vmax=high))
    levels = _bar_levels(picture, 50, cv2.COLORMAP_TURBO)
    assert levels[0] == 0 and levels[-1] == 255 and (np.diff(levels) >= 0).all()  # the ramp, low to high
    assert _has_swatch(picture[50:], (0, 0, 0))  # "black = invalid / rejected"


def test_narrow_maps_get_a_panel_wide_enough_to_read() -> None:
    picture = disparity_picture(np.arange(12, dtype=np.float32).reshape(3, 4))
    assert picture.shape[1] >= 360
    np.testing.assert_array_equal(picture[:3, 4:], 255)  # padded white beside the map


def test_the_default_range_ignores_a_single_outlier() -> None:
    disparity = np.tile(np.linspace(10.0, 50.0, 100, dtype=np.float32), (40, 1))
    disparity[0, 0] = 107.0 * 50  # one wild match
    low, high = robust_range(disparity)
    assert 10.0 <= low < 11.0 and 49.0 < high <= 50.0
    coloured = disparity_picture(disparity)[:40, :100]
    ramp = _ramp(cv2.COLORMAP_TURBO)
    np.testing.assert_array_equal(coloured[20, 0], ramp[0])
    np.testing.assert_array_equal(coloured[20, 99], ramp[255])  # the rest spreads over the whole ramp
    np.testing.assert_array_equal(coloured[0, 0], ramp[255])  # the outlier is clipped to the end colour
    middle = {tuple(colour) for colour in coloured[20, 10:90]}
    assert len(middle) > 40


def test_a_fixed_range_gives_the_same_colour_to_the_same_disparity() -> None:
    first = np.array([[0.0, 30.0, 55.0, 120.0]], np.float32)
    second = np.array([[30.0, 55.0, 70.0, -5.0]], np.float32)
    one = disparity_picture(first, value_range=(0.0, 80.0))[:1, :4]
    two = disparity_picture(second, value_range=(0.0, 80.0))[:1, :4]
    np.testing.assert_array_equal(one[0, 1], two[0, 0])  # 30 px
    np.testing.assert_array_equal(one[0, 2], two[0, 1])  # 55 px
    ramp = _ramp(cv2.COLORMAP_TURBO)
    np.testing.assert_array_equal(one[0, 3], ramp[255])  # beyond the range: the end colours
    np.testing.assert_array_equal(two[0, 3], ramp[0])
    with pytest.raises(CadeError, match="min < max"):
        disparity_picture(first, value_range=(5.0, 5.0))


def test_invalid_pixels_are_black_and_said_so() -> None:
    disparity = np.array([[np.nan, 1.0], [2.0, np.inf]], np.float32)
    coloured = disparity_picture(disparity)[:2, :2]
    np.testing.assert_array_equal(coloured[0, 0], [0, 0, 0])
    np.testing.assert_array_equal(coloured[1, 1], [0, 0, 0])
    assert coloured[0, 1].any() and coloured[1, 0].any()
    everything_invalid = disparity_picture(np.full((4, 4), np.nan, np.float32))
    assert not everything_invalid[:4, :4].any()


@pytest.mark.parametrize("text, expected", [("0:80", (0.0, 80.0)), ("-16:16", (-16.0, 16.0)), ("2.5:7", (2.5, 7.0))])
def test_parse_value_range(text, expected) -> None:
    assert parse_value_range(text) == expected


@pytest.mark.parametrize("text", ["80:0", "5:5", "5", "a:b", "1:2:3", "nan:4", ":3", "0:inf"])
def test_parse_value_range_refuses(text) -> None:
    with pytest.raises(CadeError, match="--vis-range"):
        parse_value_range(text)


def test_format_value_fits_the_span() -> None:
    assert [format_value(v, 8.0) for v in (0.0, 2.0, 8.0)] == ["0.0", "2.0", "8.0"]
    assert format_value(71.96, 55.0) == "72" and format_value(-0.001, 1.0) == "0.00"


def test_with_legend_keeps_the_picture_and_wraps_long_text() -> None:
    picture = np.full((20, 600, 3), 77, np.uint8)
    short = with_legend(picture, lines=["one line"])
    long = with_legend(picture, lines=["word " * 80])
    np.testing.assert_array_equal(short[:20], picture)
    assert long.shape[0] > short.shape[0] and long.shape[1] == 600
    with pytest.raises(ValueError, match="uint8"):
        with_legend(picture.astype(np.float32))
    barred = with_legend(picture, bar=ColourBar(cv2.COLORMAP_INFERNO, 0.0, 8.0, "px of error"))
    assert _bar_levels(barred, 20, cv2.COLORMAP_INFERNO)[-1] == 255


# ---------------------------------------------------------------- error maps


def test_error_pictures_carry_their_scale_and_legend(tmp_path: Path) -> None:
    gt = np.tile(np.linspace(0.0, 40.0, 400, dtype=np.float32), (30, 1))
    gt[:, :20] = np.nan  # no ground truth
    estimate = gt + 3.0
    estimate[:, 20:30] = 40.0  # gross errors
    picture = error_picture(estimate, gt)
    assert picture.shape[0] > 30
    levels = _bar_levels(picture, 30, cv2.COLORMAP_INFERNO)
    assert levels[0] == 0 and levels[-1] == 255 and (np.diff(levels) >= 0).all()
    panel = picture[30:]
    assert _has_swatch(panel, NO_GT_COLOUR) and not _has_swatch(panel, NO_ESTIMATE_COLOUR)
    np.testing.assert_array_equal(picture[5, 5], NO_GT_COLOUR)
    np.testing.assert_array_equal(picture[5, 25], _ramp(cv2.COLORMAP_INFERNO)[255])  # >= 8 px: the end colour
    estimate[:, 100:110] = np.nan
    with_holes = error_picture(estimate, gt)
    assert _has_swatch(with_holes[30:], NO_ESTIMATE_COLOUR)
    np.testing.assert_array_equal(with_holes[5, 105], NO_ESTIMATE_COLOUR)  # not 0 px of error
    save_maps(tmp_path, "scene_L>R", estimate, gt)
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "scene_LtoR_error.png")), with_holes)


# ---------------------------------------------------------------- registration


def _registration(left: np.ndarray, registered: np.ndarray, valid: np.ndarray) -> Registration:
    return Registration(reference=left, registered=registered, valid=valid,
                        disparity=np.zeros(left.shape, np.float32))


def _mean_tint(picture: np.ndarray) -> float:
    return float(np.abs(picture[..., 2].astype(int) - picture[..., 1].astype(int)).mean())


def test_registration_overlay_is_grey_where_aligned_and_coloured_where_not(rng) -> None:
    pair = render_pair(rng, (60, 90), background=(6.0, 0.0))
    valid = np.ones(pair.left.shape, bool)
    valid[:, :6] = False
    aligned = registration_picture(_registration(pair.left, pair.left.copy(), valid))[:60, :90]
    shifted = registration_picture(_registration(pair.left, np.roll(pair.left, 5, axis=1), valid))[:60, :90]
    assert _mean_tint(aligned[valid]) < 1.0
    assert _mean_tint(shifted[valid]) > 30.0
    np.testing.assert_array_equal(aligned[valid][:, 0], aligned[valid][:, 2])  # magenta: red = blue
    tinted = aligned[~valid].astype(int)
    assert (tinted[:, 0] - tinted[:, 2] > 100).all()  # no valid registration: blue, unlike any overlay pixel
    checker = registration_picture(_registration(pair.left, np.roll(pair.left, 5, axis=1), valid), mode="checker")
    grey = checker[:60, :90][valid]
    assert (grey[:, 0] == grey[:, 1]).all() and (grey[:, 1] == grey[:, 2]).all()
    with pytest.raises(CadeError, match="--vis-mode"):
        registration_picture(_registration(pair.left, pair.left, valid), mode="blend")


@pytest.fixture
def shifted_pair(tmp_path, rng):
    """A pair shifted by 6 px on disk, with the right disparity (6 px) and a wrong one (0 px)."""
    pair = render_pair(rng, (60, 90), background=(6.0, 0.0))
    left = write_png16(tmp_path / "left.png", pair.left)
    right = write_png16(tmp_path / "right.png", pair.right)
    right_disparity, wrong_disparity = tmp_path / "six.pfm", tmp_path / "zero.pfm"
    write_disparity(right_disparity, np.full(pair.left.shape, 6.0, np.float32))
    write_disparity(wrong_disparity, np.zeros(pair.left.shape, np.float32))
    return left, right, right_disparity, wrong_disparity


def test_register_vis_shows_an_aligned_pair_grey(shifted_pair, tmp_path, capsys) -> None:
    left, right, six, zero = shifted_pair
    tints = []
    for disparity, name in ((six, "good"), (zero, "bad")):
        vis = tmp_path / f"{name}.png"
        code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / f"{name}.tif", "--disparity", disparity,
                                    "--vis", vis], capsys)
        assert code == 0, stderr
        picture = cv2.imread(str(vis))
        assert picture.shape[0] > 60
        tints.append(_mean_tint(picture[:60, 10:90]))
    assert tints[0] < 2.0 and tints[1] > 30.0
    code, _, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / "c.tif", "--disparity", six, "--vis",
                                tmp_path / "c.png", "--vis-mode", "checker"], capsys)
    assert code == 0, stderr
    assert (tmp_path / "c.png").exists()


@pytest.mark.parametrize("extra, message", [
    (["--vis", "v.jpg"], "unsupported extension .jpg"),
    (["--vis", "v.png", "--vis-mode", "blend"], "unknown --vis-mode 'blend'"),
    (["--vis-mode", "checker"], "--vis-mode says how --vis draws"),
])
def test_register_vis_is_checked_before_any_work(shifted_pair, tmp_path, capsys, extra, message) -> None:
    left, right, six, _ = shifted_pair
    extra = [tmp_path / item if item.startswith("v.") else item for item in extra]
    before = sorted(tmp_path.iterdir())
    code, stdout, stderr = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / "r.tif", "--disparity", six, *extra],
                                    capsys)
    assert code == 1 and stdout == ""
    assert stderr.count("\n") == 1 and stderr.startswith("cade: error: ") and message in stderr
    assert sorted(tmp_path.iterdir()) == before


# ---------------------------------------------------------------- --vis-range on the command line


@pytest.mark.parametrize("value, message", [("80:0", "MIN must be below MAX"), ("zero:80", "MIN:MAX"),
                                            ("40", "MIN:MAX")])
def test_bad_vis_range_is_refused_in_one_line_with_no_output(shifted_pair, tmp_path, capsys, value, message) -> None:
    left, right, _, _ = shifted_pair
    before = sorted(tmp_path.iterdir())
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "--vis", tmp_path / "v.png",
                                     "--max-disp", 16, "--vis-range", value], capsys)
    assert code == 1 and stdout == ""
    assert stderr.count("\n") == 1 and stderr.startswith("cade: error: --vis-range") and message in stderr
    assert sorted(tmp_path.iterdir()) == before


def test_vis_range_needs_vis(shifted_pair, tmp_path, capsys) -> None:
    left, right, _, _ = shifted_pair
    code, _, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "--vis-range", "0:8"], capsys)
    assert code == 1 and "add --vis" in stderr and not (tmp_path / "d.pfm").exists()
    code, _, stderr = run_cade(["batch", "--left", tmp_path / "left.png", "--right", tmp_path / "right.png", "-o",
                                tmp_path / "out", "--vis-range", "0:8"], capsys)
    assert code == 1 and "add --vis" in stderr


def test_vis_range_fixes_the_colours_of_the_written_picture(shifted_pair, tmp_path, capsys) -> None:
    left, right, _, _ = shifted_pair
    out, vis = tmp_path / "d.pfm", tmp_path / "v.png"
    code, _, stderr = run_cade(["disparity", left, right, "-o", out, "--vis", vis, "--max-disp", 16, "--fill", "none",
                                "-m", "sgbm", "--vis-range=-4:12"], capsys)
    assert code == 0, stderr
    picture = cv2.imread(str(vis))
    np.testing.assert_array_equal(picture[:60, :90], colorize_disparity(read_disparity(out), vmin=-4.0, vmax=12.0))


def test_batch_options_keep_old_records_valid() -> None:
    assert "vis_range" not in PairOptions(method="sgbm", vis=True).fingerprint()
    assert PairOptions(method="sgbm", vis=True, vis_range=(0.0, 8.0)).fingerprint()["vis_range"] == [0.0, 8.0]
    with pytest.raises(CadeError, match="add --vis"):
        PairOptions(method="sgbm", vis_range=(0.0, 8.0)).check()
