"""The pair check (cade_cli.pair_check): known faults are found and measured, rectified pairs stay silent."""

from __future__ import annotations

import dataclasses

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


def test_the_check_never_changes_the_disparity_written(shifted_files, tmp_path, capsys, monkeypatch):
    """The same shifted pair, with the check warning and with the check replaced by one that
    finds nothing: the maps written are the same bytes."""
    import cade_cli.pair_check

    left, _, shifted = shifted_files
    warned, silent = tmp_path / "warned.pfm", tmp_path / "silent.pfm"
    code, _, err = run_cade(["disparity", left, shifted, "-o", warned, "-m", "sgbm", "--max-disp", "32"], capsys)
    assert code == 0 and "warning: pair check:" in err
    real_check = cade_cli.pair_check.check_pair

    def finds_nothing(*args, **kwargs):
        return dataclasses.replace(real_check(*args, **kwargs), problems=())

    monkeypatch.setattr(cade_cli.pair_check, "check_pair", finds_nothing)
    code, _, err = run_cade(["disparity", left, shifted, "-o", silent, "-m", "sgbm", "--max-disp", "32"], capsys)
    assert code == 0 and "pair check" not in err
    assert warned.read_bytes() == silent.read_bytes()


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



def test_register_warns_about_a_swapped_pair_and_names_the_options_that_fix_it(shifted_files, tmp_path, capsys):
    left, right, _ = shifted_files
    output = tmp_path / "r.tif"
    code, out, err = run_cade(["register", "--reference", right, "--moving", left, "-o", output, "-m", "sgbm",
                               "--max-disp", "32"], capsys)
    assert code == 0 and output.exists()
    warnings = [line for line in err.splitlines() if line.startswith("warning: pair check:")]
    assert len(warnings) == 1 and "swapped" in warnings[0] and "--reference" in warnings[0]
    code, out, err = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / "ok.tif", "-m",
                               "sgbm", "--max-disp", "32"], capsys)
    assert code == 0 and "pair check" not in err and "vertical offset" in out


@pytest.mark.parametrize("given", [False, True])
def test_register_strict_refuses_a_swapped_pair_with_one_line_and_writes_nothing(shifted_files, tmp_path, capsys,
                                                                                 given):
    """Estimated, or from a given disparity map (checked against that map's range)."""
    left, right, _ = shifted_files
    source = ["-m", "sgbm", "--max-disp", "32"]
    if given:
        disparity = tmp_path / "given.npy"
        np.save(disparity, np.full((240, 360), DISPARITY, np.float32))
        source = ["--disparity", disparity]
    output, picture = tmp_path / "r.tif", tmp_path / "r.png"
    code, _, err = run_cade(["register", "--reference", right, "--moving", left, "-o", output, "--vis", picture,
                             "--strict", *source], capsys)
    assert code == 1
    assert err.strip().count("\n") == 0 and err.startswith("cade: error: pair check:") and "swapped" in err
    assert not output.exists() and not picture.exists()


def test_register_in_the_old_positional_order_still_works_and_says_it_is_deprecated(shifted_files, tmp_path,
                                                                                    capsys):
    left, right, _ = shifted_files
    old, new = tmp_path / "old.tif", tmp_path / "new.tif"
    code, _, err = run_cade(["register", right, left, "-o", old, "--disparity", _constant_map(tmp_path)], capsys)
    assert code == 0 and "pair check" not in err
    deprecations = [line for line in err.splitlines() if "deprecated" in line]
    assert len(deprecations) == 1 and f"--reference {left} --moving {right}" in deprecations[0]
    code, _, err = run_cade(["register", "--reference", left, "--moving", right, "-o", new, "--disparity",
                             _constant_map(tmp_path)], capsys)
    assert code == 0 and "deprecated" not in err
    assert old.read_bytes() == new.read_bytes()


@pytest.mark.parametrize("bands", [["--reference", "L"], ["--moving", "R"], ["L", "R", "--reference", "L"], ["L"]])
def test_register_with_its_bands_half_named_refuses_with_one_line(shifted_files, tmp_path, capsys, bands):
    left, right, _ = shifted_files
    named = [{"L": left, "R": right}.get(item, item) for item in bands]
    output = tmp_path / "r.tif"
    code, _, err = run_cade(["register", *named, "-o", output, "--disparity", _constant_map(tmp_path)], capsys)
    assert code == 1 and err.strip().count("\n") == 0 and "--reference" in err and "--moving" in err
    assert not output.exists()


def _constant_map(folder):
    path = folder / "constant.npy"
    np.save(path, np.full((240, 360), DISPARITY, np.float32))
    return path


def dominant_line_reference(x, dy, *, width, band=1.0):
    """The slow, obviously-correct :func:`~cade_cli.pair_features.dominant_line`: one rotation at a time."""
    from cade_cli.pair_features import MAX_ROTATION_DEG, ROTATION_STEP_DEG

    best_count, best_residual = -1, dy
    angles = np.arange(-MAX_ROTATION_DEG, MAX_ROTATION_DEG + 1e-9, ROTATION_STEP_DEG)
    for angle in sorted(angles, key=abs):
        residual = dy - np.tan(np.radians(angle)) * (x - (width - 1) / 2)
        values, counts = np.unique(np.floor(residual).astype(np.int64), return_counts=True)
        lookup = dict(zip(values.tolist(), counts.tolist()))
        windows = [lookup.get(v - 1, 0) + c + lookup.get(v + 1, 0) for v, c in zip(values.tolist(), counts.tolist())]
        peak = int(np.argmax(windows))
        if windows[peak] > best_count:
            best_count, best_residual = windows[peak], residual - (values[peak] + 0.5)
    return np.abs(best_residual) <= band


def test_dominant_line_agrees_with_its_reference(rng):
    from cade_cli.pair_features import dominant_line

    for _ in range(200):
        count = int(rng.integers(1, 150))
        x, dy = rng.uniform(0, 700, count), rng.uniform(-30, 30, count)
        on_line = int(rng.integers(0, count + 1))
        slope = np.tan(np.radians(rng.uniform(-3, 3)))
        dy[:on_line] = rng.normal(rng.uniform(-8, 8), 0.3, on_line) + slope * (x[:on_line] - 350)
        if rng.random() < 0.3:
            dy = np.round(dy)  # ties between windows
        np.testing.assert_array_equal(dominant_line(x, dy, width=700), dominant_line_reference(x, dy, width=700))


def test_masked_matching_agrees_with_brute_force_knn(art_pair):
    """The banded matcher (cv2.batchDistance with a mask) keeps what a knnMatch with the same mask keeps."""
    from cade_cli.matching.sparse import gradient_image, gradient_matches

    left, right = (gradient_image(band) for band in art_pair)
    found_left, found_right = gradient_matches(left, right, detector="orb", features=600, max_vertical=20)
    orb = cv2.ORB_create(nfeatures=600, nlevels=1, fastThreshold=5)
    (key_left, desc_left), (key_right, desc_right) = (orb.detectAndCompute(image, None) for image in (left, right))
    rows_left, rows_right = (np.float32([key.pt[1] for key in keys]) for keys in (key_left, key_right))
    allowed = (np.abs(rows_left[:, None] - rows_right[None, :]) <= 20).astype(np.uint8)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    backward = {m[0].queryIdx: m[0].trainIdx
                for m in matcher.knnMatch(desc_right, desc_left, k=1, mask=allowed.T.copy()) if m}
    expected = {(key_left[m[0].queryIdx].pt, key_right[m[0].trainIdx].pt)
                for m in matcher.knnMatch(desc_left, desc_right, k=2, mask=allowed)
                if len(m) == 2 and m[0].distance < 0.8 * m[1].distance and backward.get(m[0].trainIdx) == m[0].queryIdx}
    assert len(expected) > 50
    assert {(tuple(a), tuple(b)) for a, b in zip(found_left, found_right)} == expected


def test_matches_further_apart_than_max_horizontal_are_not_made(art_pair):
    from cade_cli.matching.sparse import gradient_image, gradient_matches

    left, right = (gradient_image(band) for band in art_pair)
    found_left, found_right = gradient_matches(left, right, detector="orb", features=600, max_vertical=20,
                                               max_horizontal=30)
    assert len(found_left) > 20
    assert np.all(np.abs(found_left[:, 0] - found_right[:, 0]) <= 30 + 1e-3)
    assert np.all(np.abs(found_left[:, 1] - found_right[:, 1]) <= 20 + 1e-3)


@pytest.mark.parametrize("scene", ["Art", "Moebius"])
def test_a_shifted_cross_band_pair_is_measured(shared_data, scene):
    """Red against blue, the right band 3 px lower: upright descriptors match across the bands
    (steered ORB left both of these inconclusive)."""
    folder = shared_data / "middlebury2005" / scene
    left, right = (cv2.imread(str(folder / name)).astype(np.float32) / 255 for name in ("view1.png", "view5.png"))
    red, blue = np.ascontiguousarray(left[:, :, 2]), np.ascontiguousarray(right[:, :, 0])
    found = check_pair(red, shifted_down(blue, 3.0), max_disp=80)
    assert found.problems == ("vertical",)
    assert found.vertical_offset == pytest.approx(3.0, abs=0.5)


def test_the_feature_count_follows_the_image_area():
    from cade_cli.pair_features import FEATURES, MIN_FEATURES, feature_count

    assert feature_count(347, 277) == pytest.approx(347 * 277 / 320, abs=1)
    assert feature_count(1400, 1000) == FEATURES
    assert feature_count(64, 48) == MIN_FEATURES


@pytest.mark.parametrize("threads", [1, 2])
def test_the_result_does_not_depend_on_the_thread_count(art_pair, threads):
    left, right = art_pair
    before = cv2.getNumThreads()
    try:
        cv2.setNumThreads(threads)
        found = check_pair(left, shifted_down(right, 3.0), max_disp=80)
    finally:
        cv2.setNumThreads(before)
    cv2.setNumThreads(1)
    try:
        reference = check_pair(left, shifted_down(right, 3.0), max_disp=80)
    finally:
        cv2.setNumThreads(before)
    assert found == reference
