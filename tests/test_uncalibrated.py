"""Rectification without a calibration (cade_cli.rigs.uncalibrated, `cade rectify --uncalibrated`,
`--fix-vertical` without `--rig`): known shifts and rotations are recovered, results map back, bad pairs are refused."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.pair_check import check_pair
from cade_cli.rigs.uncalibrated import PairRectification, estimate_pair_rectification, match_in_original_frame
from cli_runner import run_cade, write_png16
from synthetic import render_pair

SHAPE = (200, 300)
DISPARITY = 12.0


@pytest.fixture(scope="module")
def cross_band_pair():
    """(left, right, disparity) of a textured scene (a plane at 12 px, a box at 24 px) seen
    through two filters: RIGHT's contrast is inverted and bent (1 - v^0.7)."""
    pair = render_pair(np.random.default_rng(7), SHAPE, background=(DISPARITY, 0.0), foreground=(24.0, 0.0))
    return pair.left.astype(np.float32), (1 - pair.right.astype(np.float32) ** 0.7), pair.disparity


def misaligned(band: np.ndarray, offset: float, degrees: float) -> tuple[np.ndarray, np.ndarray]:
    """``band`` rotated by ``degrees`` about its centre (a point right of the centre moves down for
    degrees > 0) and moved ``offset`` px down; and that map (3 x 3, original pixel -> misaligned pixel)."""
    height, width = band.shape
    cx, cy = (width - 1) / 2, (height - 1) / 2
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    forward = np.float64([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy + offset], [0, 0, 1]])
    moved = cv2.warpAffine(band, forward[:2], (width, height), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    return moved, forward


def grid(width: int, height: int, margin: int = 20) -> np.ndarray:
    y, x = np.mgrid[margin:height - margin:7j, margin:width - margin:9j]
    return np.stack([x.ravel(), y.ravel()], axis=1).reshape(-1, 1, 2)


@pytest.mark.parametrize("offset, degrees", [(2.5, 0.6), (-3.0, -1.0), (1.2, 0.3), (0.0, 1.5)])
def test_a_known_shift_and_rotation_are_recovered_on_a_cross_band_pair(cross_band_pair, offset, degrees):
    left, right, _ = cross_band_pair
    moved, forward = misaligned(right, offset, degrees)
    found = estimate_pair_rectification(left, moved)
    assert found.model == "vertical"
    assert found.offset == pytest.approx(offset, abs=0.3)
    assert found.rotation == pytest.approx(degrees, abs=0.1)
    # the warp undoes the misalignment: RIGHT's pixels come back to their rows (and columns)
    points = grid(SHAPE[1], SHAPE[0])
    back = cv2.perspectiveTransform(points, found.right_warp @ forward)
    assert np.abs(back - points).max() < 0.3
    assert found.residual < 0.3


def test_a_rectified_pair_is_left_as_it_is(cross_band_pair):
    left, right, _ = cross_band_pair
    found = estimate_pair_rectification(left, right)
    assert not found.warps() and "left as it is" in found.reason
    left_rect, right_rect = found.rectify(left, right)
    assert left_rect is left and right_rect is right


def test_a_perspective_difference_gets_a_full_rectification_that_aligns_the_rows(cross_band_pair):
    """RIGHT through a slight keystone (no offset and rotation undo it): the full rectification
    is chosen and puts each scene point's two views on one row."""
    left, right, disparity = cross_band_pair
    height, width = SHAPE
    centre = np.float64([[1, 0, -(width - 1) / 2], [0, 1, -(height - 1) / 2], [0, 0, 1]])
    keystone = np.linalg.inv(centre) @ np.float64([[1, 0, 0], [0, 1, 0], [0, 2e-4, 1]]) @ centre
    moved = cv2.warpPerspective(right, keystone, (width, height), flags=cv2.INTER_CUBIC,
                                borderMode=cv2.BORDER_REPLICATE)
    found = estimate_pair_rectification(left, moved)
    assert found.model == "projective"
    points = grid(width, height).reshape(-1, 2)
    seen = disparity[points[:, 1].astype(int), points[:, 0].astype(int)]
    in_right = np.stack([points[:, 0] - seen, points[:, 1]], axis=1)
    rows_left = cv2.perspectiveTransform(points.reshape(-1, 1, 2), found.left_warp)[:, 0, 1]
    rows_right = cv2.perspectiveTransform(in_right.reshape(-1, 1, 2), found.right_warp @ keystone)[:, 0, 1]
    assert np.median(np.abs(rows_right - rows_left)) < 0.3
    assert np.abs(rows_right - rows_left).max() < 1.0


@pytest.mark.parametrize("kind", ["noise", "flat"])
def test_a_pair_with_nothing_to_match_is_refused_with_one_line(kind):
    rng = np.random.default_rng(1)
    left, right = ((rng.random(SHAPE), rng.random(SHAPE)) if kind == "noise" else (np.zeros(SHAPE), np.zeros(SHAPE)))
    with pytest.raises(CadeError) as refused:
        estimate_pair_rectification(left.astype(np.float32), right.astype(np.float32))
    assert "\n" not in str(refused.value) and "cade calibrate" in str(refused.value)


def test_results_map_back_onto_the_original_left_image():
    """A rectified frame shifted by (3, 2) px from the original: the map read back on the original
    image holds at (x, y) what the rectified one holds at (x + 3, y + 2)."""
    height, width = 40, 60
    found = PairRectification(model="projective", left_warp=np.float64([[1, 0, 3], [0, 1, 2], [0, 0, 1]]),
                              right_warp=np.eye(3), size=(width, height), matches=0, inliers=0, residual=0.0,
                              offset=0.0, rotation=0.0, reason="")
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    disparity = (x + 100 * y).astype(np.float32)
    valid = np.ones((height, width), bool)
    valid[10, 20] = False
    unfilled, kept, dense, confidence = match_in_original_frame(found, disparity, valid, disparity.copy(),
                                                                np.ones((height, width), np.float32))
    assert unfilled[5, 7] == pytest.approx(disparity[7, 10])
    assert not kept[8, 17] and np.isnan(unfilled[8, 17]) and confidence[8, 17] == 0  # the rejected pixel
    assert not kept[-1, -1] and np.isnan(dense[-1, -1])  # outside the rectified view


# --- the commands ----------------------------------------------------------------------------------------------------


@pytest.fixture
def misaligned_files(tmp_path, cross_band_pair):
    """The scene with RIGHT through another filter's response (v^0.7, which census-sgm matches),
    moved 2.5 px down and rotated 0.6 degrees."""
    left, right, _ = cross_band_pair
    moved, _ = misaligned(1 - right, 2.5, 0.6)  # 1 - (1 - v^0.7) = v^0.7
    return write_png16(tmp_path / "left.png", left), write_png16(tmp_path / "right.png", moved)


def test_rectify_uncalibrated_writes_an_aligned_pair_and_its_warp(misaligned_files, tmp_path, capsys):
    left, right = misaligned_files
    outputs = tmp_path / "l_rect.tif", tmp_path / "r_rect.tif"
    code, out, err = run_cade(["rectify", "--uncalibrated", left, right, "-o", *outputs], capsys)
    assert code == 0, err
    record = json.loads((tmp_path / "l_rect.tif.rectification.json").read_text())
    assert record["model"] == "vertical" and record["vertical_offset_px"] == pytest.approx(2.5, abs=0.3)
    assert record["residual_vertical_px"] < 0.3 and record["left_warp"] == np.eye(3).tolist()
    import tifffile

    rectified = check_pair(*(tifffile.imread(path) for path in outputs), min_disp=0, max_disp=40)
    assert abs(rectified.vertical_offset) < 0.3 and abs(rectified.rotation) < 0.2
    assert "uncalibrated vertical rectification" in out


def test_rectify_uncalibrated_refuses_a_pair_without_shared_texture_and_writes_nothing(tmp_path, capsys):
    rng = np.random.default_rng(2)
    left, right = (write_png16(tmp_path / name, rng.random(SHAPE)) for name in ("l.png", "r.png"))
    code, _, err = run_cade(["rectify", "--uncalibrated", left, right, "-o", tmp_path / "a.png", tmp_path / "b.png"],
                            capsys)
    assert code == 1 and err.strip().count("\n") == 0 and "cannot rectify the pair without a calibration" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.png", "r.png"]


def test_rectify_without_a_rig_or_with_a_rig_and_uncalibrated_says_what_to_do(misaligned_files, tmp_path, capsys):
    left, right = misaligned_files
    code, _, err = run_cade(["rectify", left, right, "-o", tmp_path / "a.png", tmp_path / "b.png"], capsys)
    assert code == 1 and "--uncalibrated" in err
    code, _, err = run_cade(["rectify", "--uncalibrated", "rig.json", left, right, "-o", tmp_path / "a.png",
                             tmp_path / "b.png"], capsys)
    assert code == 1 and "takes no rig file" in err and "LEFT RIGHT" in err


def test_disparity_fix_vertical_without_a_rig_matches_the_corrected_pair(misaligned_files, cross_band_pair, tmp_path,
                                                                        capsys):
    left, right = misaligned_files
    plain, fixed = tmp_path / "plain.pfm", tmp_path / "fixed.pfm"
    method = ["-m", "census-sgm", "--max-disp", "32"]
    code, _, err = run_cade(["disparity", left, right, "-o", plain, *method], capsys)
    assert code == 0 and "pair check: the pair is not rectified" in err
    code, out, err = run_cade(["disparity", left, right, "-o", fixed, *method, "--fix-vertical", "--frame", "original",
                               "--fill", "none"], capsys)
    assert code == 0 and "pair check" not in err and "uncalibrated rectification: vertical offset +2.5" in err
    assert "original frame of the uncalibrated vertical rectification" in out
    from cade_cli.io.disparity import read_disparity

    truth = cross_band_pair[2][20:-20, 40:-20]
    right_to = {name: np.abs(read_disparity(path)[20:-20, 40:-20] - truth) < 1 for name, path in
                (("plain", plain), ("fixed", fixed))}
    assert right_to["fixed"].mean() > 0.6 and right_to["fixed"].mean() > right_to["plain"].mean() + 0.1
    record = json.loads((tmp_path / "fixed.pfm.rectification.json").read_text())
    assert record["frame"] == "original" and record["model"] == "vertical"


def test_register_fix_vertical_and_batch_fix_vertical_without_a_rig(misaligned_files, tmp_path, capsys):
    left, right = misaligned_files
    output = tmp_path / "r.tif"
    code, out, err = run_cade(["register", "--reference", left, "--moving", right, "-o", output, "-m", "sgbm",
                               "--max-disp", "32", "--fix-vertical"], capsys)
    assert code == 0 and "pair check" not in err and (tmp_path / "r.tif.rectification.json").exists()
    code, _, err = run_cade(["register", "--reference", left, "--moving", right, "-o", tmp_path / "r2.tif",
                             "--fix-vertical", "--disparity", tmp_path / "any.pfm"], capsys)
    assert code == 1 and "--fix-vertical" in err and not (tmp_path / "r2.tif").exists()
    manifest = tmp_path / "pairs.csv"
    manifest.write_text(f"left,right,output\n{left},{right},{tmp_path / 'b.pfm'}\n")
    code, _, err = run_cade(["batch", "--manifest", manifest, "-m", "sgbm", "--max-disp", "32", "--fix-vertical"],
                            capsys)
    assert code == 0, err
    record = json.loads((tmp_path / "b.pfm.cade.json").read_text())
    assert record["uncalibrated_rectification"]["vertical_offset_px"] == pytest.approx(2.5, abs=0.3)
    assert abs(record["pair_check"]["vertical_offset_px"]) < 0.5
    code, _, err = run_cade(["batch", "--manifest", manifest, "-m", "sgbm", "--frame", "original", "--force"], capsys)
    assert code == 1 and "--frame needs --rig" in err


# --- real pairs ------------------------------------------------------------------------------------------------------


def _grey(path):
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255


def test_the_bundled_art_pair_is_already_rectified():
    """samples/: the red and blue bands of Middlebury 2005 Art, rectified: nothing worth resampling."""
    from pathlib import Path

    folder = Path(__file__).resolve().parent.parent / "samples" / "middlebury2005-art"
    found = estimate_pair_rectification(_grey(folder / "left_R.png"), _grey(folder / "right_B.png"))
    assert found.model == "vertical" and abs(found.offset) < 0.5 and abs(found.rotation) < 0.2
    assert found.residual < 0.5


def test_real_unrectified_pairs_are_aligned_or_refused(shared_data):
    """OpenCV's stereo_calib pairs (an uncalibrated rig, 11-18 px apart vertically): each is either
    rectified, the independent pair check then measuring under a pixel, or refused in one line."""
    folder = shared_data / "calibration" / "opencv-stereo-chessboard"
    outcomes = []
    for number in ("01", "12"):
        left, right = _grey(folder / f"left{number}.jpg"), _grey(folder / f"right{number}.jpg")
        assert abs(check_pair(left, right, min_disp=-64, max_disp=160).vertical_offset) > 8
        try:
            found = estimate_pair_rectification(left, right)
        except CadeError as refused:
            assert "\n" not in str(refused)
            outcomes.append("refused")
            continue
        after = check_pair(*found.rectify(left, right), min_disp=-64, max_disp=160)
        assert abs(after.vertical_offset) < 1.0 and found.residual < 0.5
        outcomes.append(found.model)
    assert outcomes.count("refused") < len(outcomes)  # at least one is rectified
