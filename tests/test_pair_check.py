"""The pair check (cade_cli.pair_check): known faults are found and measured, rectified pairs stay silent."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cade_cli.evaluation.degradations import roll, vertical_shift
from cade_cli.pair_check import check_pair
from cli_runner import run_cade, write_png16
from synthetic import render_pair

DISPARITY = 12.0


@pytest.fixture
def textured_pair(rng):
    """(left, right) of a seeded textured plane at 12 px, 240 x 360 px, in [0, 1]."""
    pair = render_pair(rng, (240, 360), background=(DISPARITY, 0.0))
    return pair.left.astype(np.float32), pair.right.astype(np.float32)


@pytest.fixture
def art_pair(shared_data):
    """The grey Middlebury 2005 Art pair (ThirdSize, rectified, disparities about 10..77 px)."""
    folder = shared_data / "middlebury2005" / "Art"
    left, right = (cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255
                   for name in ("view1.png", "view5.png"))
    return left, right


def shifted_down(band: np.ndarray, rows: float) -> np.ndarray:
    """``band`` with its content moved down by ``rows`` px: a scene point's right row is ``rows`` lower."""
    return vertical_shift(band, -rows)


def test_a_rectified_synthetic_pair_is_silent_and_its_disparity_measured(textured_pair):
    found = check_pair(*textured_pair, min_disp=0, max_disp=32)
    assert found.conclusive and found.problems == ()
    assert abs(found.vertical_offset) < 0.3
    assert found.disparity[0] == pytest.approx(DISPARITY, abs=1.5)
    assert found.disparity[1] == pytest.approx(DISPARITY, abs=1.5)
    assert found.describe() == ""


@pytest.mark.parametrize("rows", [3.0, 6.0])
def test_a_vertical_shift_is_measured_within_a_pixel(textured_pair, rows):
    left, right = textured_pair
    found = check_pair(left, shifted_down(right, rows), min_disp=0, max_disp=32)
    assert found.vertical_offset == pytest.approx(rows, abs=1.0)
    assert "vertical" in found.problems
    assert f"vertical offset {found.vertical_offset:+.2f} px" in found.describe()
    assert "--fix-vertical" in found.describe()


@pytest.mark.parametrize("degrees", [1.0, 2.0])
def test_a_rotation_is_detected(textured_pair, degrees):
    left, right = textured_pair
    found = check_pair(left, roll(right, degrees), min_disp=0, max_disp=32)
    assert "vertical" in found.problems
    assert abs(found.rotation) == pytest.approx(degrees, abs=0.5)


def test_a_swapped_pair_is_flagged(textured_pair):
    left, right = textured_pair
    found = check_pair(right, left, min_disp=0, max_disp=32)
    assert found.problems == ("swapped",)
    assert found.negative_share > 0.9
    assert "swapped" in found.describe()


def test_a_swapped_pair_searched_over_both_signs_is_not_called_swapped(textured_pair):
    left, right = textured_pair
    found = check_pair(right, left, min_disp=-32, max_disp=32)
    assert found.problems == ()


def test_a_range_that_misses_the_scene_is_flagged_and_a_range_suggested(textured_pair):
    found = check_pair(*textured_pair, min_disp=20, max_disp=60)
    assert found.problems == ("range",)
    assert found.outside_share > 0.9
    low, high = found.suggested
    assert low <= DISPARITY - 1 and high >= DISPARITY + 1
    assert f"--min-disp {low} --max-disp {high}" in found.describe()


def test_a_flat_pair_is_inconclusive_and_silent():
    flat = np.full((120, 160), 0.5, np.float32)
    found = check_pair(flat, flat, max_disp=16)
    assert not found.conclusive and found.problems == ()
    assert "unmeasured" in found.summary()


def test_the_check_reads_its_inputs_without_changing_them(textured_pair):
    left, right = textured_pair
    before = left.copy(), right.copy()
    check_pair(left, right, max_disp=32)
    assert np.array_equal(left, before[0]) and np.array_equal(right, before[1])


def test_bands_of_different_sizes_are_refused(textured_pair):
    from cade_cli.errors import CadeError

    with pytest.raises(CadeError, match="one size"):
        check_pair(textured_pair[0], textured_pair[1][:, :-1], max_disp=32)


# --- a real pair ---------------------------------------------------------------------------------------------------


def test_the_real_art_pair_is_silent_grey_and_cross_band(shared_data):
    folder = shared_data / "middlebury2005" / "Books"
    left, right = (cv2.imread(str(folder / name)).astype(np.float32) / 255 for name in ("view1.png", "view5.png"))
    grey = check_pair(left.mean(axis=2), right.mean(axis=2), max_disp=80)
    red_blue = check_pair(np.ascontiguousarray(left[:, :, 2]), np.ascontiguousarray(right[:, :, 0]), max_disp=80)
    assert grey.conclusive and grey.problems == ()
    assert red_blue.problems == ()


@pytest.mark.parametrize("rows", [3.0, 6.0])
def test_a_shifted_real_pair_is_measured_within_a_pixel(art_pair, rows):
    left, right = art_pair
    found = check_pair(left, shifted_down(right, rows), max_disp=80)
    assert found.vertical_offset == pytest.approx(rows, abs=1.0)
    assert found.problems == ("vertical",)


def test_the_real_pair_swapped_or_searched_too_low_is_flagged(art_pair):
    left, right = art_pair
    assert check_pair(left, right, max_disp=80).problems == ()
    assert check_pair(right, left, max_disp=80).problems == ("swapped",)
    assert check_pair(left, right, max_disp=8).problems == ("range",)


# --- the command ---------------------------------------------------------------------------------------------------


@pytest.fixture
def shifted_files(tmp_path, textured_pair):
    left, right = textured_pair
    return (write_png16(tmp_path / "left.png", left), write_png16(tmp_path / "right.png", right),
            write_png16(tmp_path / "right_down6.png", shifted_down(right, 6.0)))


def test_disparity_warns_about_a_shifted_pair_and_reports_the_offset(shifted_files, tmp_path, capsys):
    left, _, shifted = shifted_files
    output = tmp_path / "d.pfm"
    code, out, err = run_cade(["disparity", left, shifted, "-o", output, "-m", "sgbm", "--max-disp", "32"], capsys)
    assert code == 0 and output.exists()
    warnings = [line for line in err.splitlines() if line.startswith("warning: pair check:")]
    assert len(warnings) == 1 and "vertical offset +" in warnings[0] and "--fix-vertical" in warnings[0]
    assert "vertical offset +" in out


def test_disparity_of_a_rectified_pair_gives_no_warning(shifted_files, tmp_path, capsys):
    left, right, _ = shifted_files
    code, out, err = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "-m", "sgbm", "--max-disp", "32"],
                              capsys)
    assert code == 0 and "pair check" not in err
    assert "vertical offset" in out


def test_strict_refuses_a_shifted_pair_with_one_line_and_writes_nothing(shifted_files, tmp_path, capsys):
    left, _, shifted = shifted_files
    output = tmp_path / "d.pfm"
    code, out, err = run_cade(["disparity", left, shifted, "-o", output, "-m", "sgbm", "--max-disp", "32", "--strict",
                               "--vis", tmp_path / "d.png"], capsys)
    assert code == 1
    assert err.strip().count("\n") == 0 and err.startswith("cade: error: pair check:")
    assert not output.exists() and not (tmp_path / "d.png").exists()
    assert list(tmp_path.glob("d*")) == []


def test_batch_strict_fails_the_shifted_pair_only_and_records_the_offset(shifted_files, tmp_path, capsys):
    import json

    left, right, shifted = shifted_files
    manifest = tmp_path / "pairs.csv"
    manifest.write_text(f"left,right,output\n{left},{right},{tmp_path / 'ok.pfm'}\n"
                        f"{left},{shifted},{tmp_path / 'bad.pfm'}\n")
    code, _, err = run_cade(["batch", "--manifest", manifest, "-m", "sgbm", "--max-disp", "32", "--strict"], capsys)
    assert code == 1
    assert (tmp_path / "ok.pfm").exists() and not (tmp_path / "bad.pfm").exists()
    assert "pair check: the pair is not rectified" in err
    record = json.loads((tmp_path / "ok.pfm.cade.json").read_text())
    assert abs(record["pair_check"]["vertical_offset_px"]) < 0.5
    code, _, err = run_cade(["batch", "--manifest", manifest, "-m", "sgbm", "--max-disp", "32", "--force"], capsys)
    assert code == 0 and (tmp_path / "bad.pfm").exists()
    assert sum("warning:" in line and "pair check" in line for line in err.splitlines()) == 1
    record = json.loads((tmp_path / "bad.pfm.cade.json").read_text())
    assert record["pair_check"]["vertical_offset_px"] == pytest.approx(6.0, abs=1.0)
