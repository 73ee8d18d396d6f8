"""Rigs end to end, against ground truth built here: boards and textured planes rendered
through two synthetic cameras with known K, distortion, R and t (one band inverted)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from cade_cli.errors import CadeError
from cade_cli.io.disparity import read_disparity
from cade_cli.rigs.boards import detect_board, parse_board
from cade_cli.rigs.calibration import CameraImages, calibrate_rig, pair_views
from cade_cli.rigs.rectification import rectify_pair, stereo_rectification
from cade_cli.rigs.rig import Camera, Rig
from cade_cli.rigs.rig_file import RIG_VERSION, load_rig, rig_from_dict, rig_to_dict, save_rig
from cade_cli.rigs.self_check import correct_vertical_misalignment, measure_vertical_misalignment
from synthetic import smooth_texture
from cli_runner import run_cade

SIZE = (480, 360)  # width, height of both synthetic cameras
K_LEFT = np.array([[430.0, 0, 236], [0, 430.0, 184], [0, 0, 1]])
K_RIGHT = np.array([[445.0, 0, 245], [0, 445.0, 176], [0, 0, 1]])
DIST_LEFT = np.array([-0.12, 0.05, 0.0, 0.0, 0.0])
DIST_RIGHT = np.array([0.06, -0.02, 0.0, 0.0, 0.0])
BASELINE = 0.09  # metres: the right camera sits 9 cm right of the reference
R_RIGHT = cv2.Rodrigues(np.radians([0.4, -1.5, 0.6]))[0]  # X_right = R X_left + t
T_RIGHT = -R_RIGHT @ np.array([BASELINE, 0.004, -0.002])


def render_plane(texture: np.ndarray, metres_per_px: float, R_plane: np.ndarray, t_plane: np.ndarray,
                 K: np.ndarray, dist: np.ndarray, size=SIZE) -> np.ndarray:
    """What a camera (K, dist) sees of a textured plane: texture pixel (u, v) lies at
    X_cam = R_plane @ (u, v, 0) * metres_per_px + t_plane. (H, W) float32, 0.5 off the plane."""
    width, height = size
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    pixels = np.stack([x.ravel(), y.ravel()], axis=1).reshape(-1, 1, 2)
    normalised = cv2.undistortPoints(pixels, K, dist).reshape(-1, 2)  # ideal pinhole rays of every pixel
    to_ray = np.column_stack([R_plane[:, 0], R_plane[:, 1], t_plane])  # plane (X, Y, 1) -> ray
    plane = np.linalg.solve(to_ray, np.column_stack([normalised, np.ones(len(normalised))]).T).T
    plane = plane[:, :2] / plane[:, 2:3] / metres_per_px
    map_x = plane[:, 0].reshape(height, width).astype(np.float32)
    map_y = plane[:, 1].reshape(height, width).astype(np.float32)
    return cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.5)


def board_texture(board, px_per_square: int = 40) -> np.ndarray:
    """The board as seen head-on, [0, 1], edges softened a little; (0, 0) = the board origin."""
    if board.kind == "charuco":
        image = board.charuco.generateImage((board.columns * px_per_square, board.rows * px_per_square),
                                            marginSize=0, borderBits=1)
    else:  # OpenCV's chessboard corners: inner corner (i, j) at ((i + 1) s, (j + 1) s) of a (c+1) x (r+1) board
        squares = np.indices((board.rows + 1, board.columns + 1)).sum(axis=0) % 2
        image = np.kron(1 - squares, np.ones((px_per_square, px_per_square))) * 255
    texture = cv2.GaussianBlur(image.astype(np.float32) / 255, (0, 0), 0.8)
    return 0.1 + 0.8 * texture


def board_views(board, poses, *, invert_right: bool, rng) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Left and right pictures of ``board`` at each (rotation vector, translation) pose of the
    reference camera; the right band inverted and dimmer when ``invert_right``."""
    px_per_square = 40
    texture = board_texture(board, px_per_square)
    metres_per_px = board.square / px_per_square
    # texture pixel -> board coordinates: chessboard corner (0, 0) is one square in
    offset = np.array([board.square, board.square, 0.0]) if board.kind == "chessboard" else np.zeros(3)
    lefts, rights = [], []
    for rotation, translation in poses:
        R_board = cv2.Rodrigues(np.radians(rotation))[0]
        t_board = np.asarray(translation, float) - R_board @ offset
        left = render_plane(texture, metres_per_px, R_board, t_board, K_LEFT, DIST_LEFT)
        right = render_plane(texture, metres_per_px, R_RIGHT @ R_board, R_RIGHT @ t_board + T_RIGHT, K_RIGHT, DIST_RIGHT)
        if invert_right:
            right = 0.05 + 0.6 * (1 - right)
        lefts.append(np.clip(left + rng.normal(0, 0.01, left.shape), 0, 1).astype(np.float32))
        rights.append(np.clip(right + rng.normal(0, 0.01, right.shape), 0, 1).astype(np.float32))
    return lefts, rights


CHESS_POSES = [  # (rotation in degrees about x, y, z; board origin in the reference camera frame, metres)
    ((10, -20, 3), (-0.17, -0.10, 0.75)), ((-15, 15, -5), (-0.12, -0.08, 0.70)), ((20, 10, 8), (-0.15, -0.12, 0.80)),
    ((-10, -25, 2), (-0.16, -0.07, 0.72)), ((25, -5, -10), (-0.14, -0.09, 0.68)), ((-20, 25, 5), (-0.11, -0.10, 0.78)),
    ((5, 30, -3), (-0.13, -0.11, 0.74)), ((-25, -15, 12), (-0.18, -0.06, 0.76)),
]


def write_views(folder: Path, lefts, rights) -> tuple[list[Path], list[Path]]:
    folder.mkdir(exist_ok=True)
    paths = ([], [])
    for i, pair in enumerate(zip(lefts, rights), start=1):
        for side, image, listing in zip(("left", "right"), pair, paths):
            path = folder / f"{side}{i:02d}.png"
            cv2.imwrite(str(path), np.round(image * 255).astype(np.uint8))
            listing.append(path)
    return paths


@pytest.fixture(scope="module")
def chessboard_files(tmp_path_factory):
    board = parse_board("chessboard:9x6", square=0.03)
    lefts, rights = board_views(board, CHESS_POSES, invert_right=True, rng=np.random.default_rng(7))
    return board, write_views(tmp_path_factory.mktemp("chess"), lefts, rights)


def check_calibration(rig: Rig) -> None:
    left, right = rig.camera("left"), rig.camera("right")
    assert left.K[0, 0] == pytest.approx(K_LEFT[0, 0], rel=0.01)
    assert right.K[1, 1] == pytest.approx(K_RIGHT[1, 1], rel=0.01)
    assert np.linalg.norm(right.t) == pytest.approx(np.linalg.norm(T_RIGHT), rel=0.02)
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(right.R @ R_RIGHT.T)[0])) < 0.5
    assert rig.calibration.rms < 0.3
    assert rig.rectification.baseline == pytest.approx(np.linalg.norm(T_RIGHT), rel=0.02)
    # What matters downstream: true scene points land on the same row once rectified with the estimate.
    rng = np.random.default_rng(3)
    scene = np.column_stack([rng.uniform(-0.5, 0.5, 400), rng.uniform(-0.4, 0.4, 400), rng.uniform(0.8, 3.0, 400)])
    rows, inside = [], np.ones(len(scene), bool)
    for camera, K, dist, R, t, R_rect, P_rect in (
            (left, K_LEFT, DIST_LEFT, np.eye(3), np.zeros(3), rig.rectification.R1, rig.rectification.P1),
            (right, K_RIGHT, DIST_RIGHT, R_RIGHT, T_RIGHT, rig.rectification.R2, rig.rectification.P2)):
        seen, _ = cv2.projectPoints(scene, cv2.Rodrigues(R)[0], t, K, dist)  # the true cameras
        rows.append(cv2.undistortPoints(seen, camera.K, camera.dist, R=R_rect, P=P_rect).reshape(-1, 2)[:, 1])
        seen = seen.reshape(-1, 2)
        inside &= (seen[:, 0] >= 0) & (seen[:, 0] < SIZE[0]) & (seen[:, 1] >= 0) & (seen[:, 1] < SIZE[1])
    assert inside.sum() > 100
    assert np.median(np.abs(rows[0] - rows[1])[inside]) < 0.2
    assert np.percentile(np.abs(rows[0] - rows[1])[inside], 95) < 0.5


def test_chessboard_calibration_recovers_focal_lengths_and_baseline_with_an_inverted_band(chessboard_files):
    board, (lefts, rights) = chessboard_files
    found = calibrate_rig([CameraImages("left", "bp400", tuple(lefts)), CameraImages("right", "bp900", tuple(rights))],
                          board)
    assert all(d is not None for d in found.detections["right"].values())
    check_calibration(found.rig)


def test_charuco_calibration_with_partial_views_and_an_inverted_band(tmp_path):
    board = parse_board("charuco:7x5", square=0.05, marker=0.037, dictionary="DICT_4X4_50")
    poses = [(rotation, (x - 0.03, y - 0.04, z)) for rotation, (x, y, z) in CHESS_POSES]
    poses[0] = ((5, -10, 0), (0.12, -0.12, 0.7))  # the board's right part out of the left camera's view
    lefts, rights = board_views(board, poses, invert_right=True, rng=np.random.default_rng(8))
    first = detect_board(lefts[0], board)
    assert first is not None and 6 <= len(first.ids) < len(board.corners)  # partial view, still used
    assert detect_board(rights[1], board).inverted  # found in the inverted picture only
    files = write_views(tmp_path, lefts, rights)
    found = calibrate_rig([CameraImages("left", "vis", tuple(files[0])), CameraImages("right", "nir", tuple(files[1]))],
                          board)
    check_calibration(found.rig)


def test_three_cameras_are_each_calibrated_against_the_reference(chessboard_files, tmp_path):
    board, (lefts, rights) = chessboard_files
    R_middle = cv2.Rodrigues(np.radians([-0.3, 0.8, -0.4]))[0]
    t_middle = -R_middle @ np.array([0.045, -0.003, 0.001])
    texture, px_per_square = board_texture(board), 40
    middles = []
    for (rotation, translation), path in zip(CHESS_POSES, lefts):
        R_board = cv2.Rodrigues(np.radians(rotation))[0]
        t_board = np.asarray(translation, float) - R_board @ np.array([board.square, board.square, 0.0])
        image = render_plane(texture, board.square / px_per_square, R_middle @ R_board, R_middle @ t_board + t_middle,
                             K_LEFT, DIST_RIGHT)
        middles.append(tmp_path / path.name.replace("left", "middle"))
        cv2.imwrite(str(middles[-1]), np.round(image * 255).astype(np.uint8))
    found = calibrate_rig([CameraImages("left", "a", tuple(lefts)), CameraImages("right", "b", tuple(rights)),
                           CameraImages("middle", "c", tuple(middles))], board)
    check_calibration(found.rig)
    middle = found.rig.camera("middle")
    assert middle.K[0, 0] == pytest.approx(K_LEFT[0, 0], rel=0.01)
    np.testing.assert_allclose(middle.t, t_middle, atol=0.002)
    assert found.rig.rectification.cameras == ("left", "right")


def test_views_pair_by_number_and_a_missing_board_is_left_out_with_its_file_named(chessboard_files, tmp_path):
    board, (lefts, rights) = chessboard_files
    extra_left, blank = tmp_path / "left09.png", tmp_path / "right09.png"  # a ninth view, the board missing on the right
    extra_left.write_bytes(lefts[0].read_bytes())
    cv2.imwrite(str(blank), np.full((SIZE[1], SIZE[0]), 128, np.uint8))
    cameras = [CameraImages("left", "a", (*lefts, extra_left)), CameraImages("right", "b", (*rights, blank))]
    found = calibrate_rig(cameras, board)
    assert any("right09.png" in note and "not found" in note for note in found.notes)
    assert "9" not in {view["view"] for view in found.rig.calibration.views}
    assert "9" in {view["view"] for view in found.rig.calibration.rejected}
    check_calibration(found.rig)
    views = dict(pair_views(cameras))
    assert views["9"]["right"] == blank and views["9"]["left"] == extra_left
    assert views["3"]["left"].name == "left03.png" and views["3"]["right"].name == "right03.png"


def test_too_few_views_is_one_clear_error(chessboard_files):
    board, (lefts, rights) = chessboard_files
    with pytest.raises(CadeError, match="only 2 usable view"):
        calibrate_rig([CameraImages("left", "a", tuple(lefts[:2])), CameraImages("right", "b", tuple(rights[:2]))], board)


# --- the rig file -------------------------------------------------------------------------------------------------

def synthetic_rig() -> Rig:
    left = Camera("left", "bp400", SIZE, K=K_LEFT, dist=DIST_LEFT, R=np.eye(3), t=np.zeros(3))
    right = Camera("right", "bp900", SIZE, K=K_RIGHT, dist=DIST_RIGHT, R=R_RIGHT, t=T_RIGHT)
    rig = Rig("left", (left, right))
    return Rig("left", (left, right), rectification=stereo_rectification(rig))


def test_rig_file_round_trip(tmp_path):
    rig = synthetic_rig()
    path = tmp_path / "rig.json"
    save_rig(rig, path)
    again = load_rig(path)
    assert again.reference == "left" and again.names == ("left", "right")
    for name in ("left", "right"):
        for key in ("K", "dist", "R", "t"):
            np.testing.assert_array_equal(getattr(again.camera(name), key), getattr(rig.camera(name), key))
    np.testing.assert_array_equal(again.rectification.Q, rig.rectification.Q)
    assert json.loads(path.read_text())["version"] == RIG_VERSION
    assert rig_to_dict(again) == rig_to_dict(rig)


def test_plane_registered_camera_round_trips(tmp_path):
    data = rig_to_dict(synthetic_rig())
    data["cameras"].append({"name": "nir", "band": "nir", "image_size": [100, 80],
                            "to_reference": {"affine": [[1, 0, 2.5], [0, 1, -1]]}, "position": [0.05, 0.0]})
    rig = rig_from_dict(data)
    np.testing.assert_array_equal(rig.camera("nir").to_reference.homography, [[1, 0, 2.5], [0, 1, -1], [0, 0, 1]])
    save_rig(rig, tmp_path / "r.json")
    assert load_rig(tmp_path / "r.json").camera("nir").position == (0.05, 0.0)


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(version=RIG_VERSION + 1), f"version {RIG_VERSION + 1} file; this cade reads versions up to"),
    (lambda d: d.update(format="other"), "format must be 'cade-rig'"),
    (lambda d: d["cameras"][1].update(K=[[1, 0], [0, 1]]), r"cameras\[1\].K must be a 3x3 matrix, got shape \[2, 2\]"),
    (lambda d: d["cameras"][1].update(t=[0.1, float("nan"), 0]), r"cameras\[1\].t has a non-finite value"),
    (lambda d: d["cameras"][0].pop("image_size"), r"cameras\[0\].image_size is missing"),
    (lambda d: d["cameras"][1].pop("R"), r"cameras\[1\] \(right\) needs K, R and t \(missing R\)"),
    (lambda d: d.update(reference="middle"), "reference 'middle' is not one of the cameras"),
    (lambda d: d["rectification"].update(Q=[[1]]), r"rectification.Q must be a 4x4 matrix"),
])
def test_bad_rig_files_are_refused_with_the_file_and_key(tmp_path, change, message):
    data = rig_to_dict(synthetic_rig())
    change(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CadeError, match=message) as error:
        load_rig(path)
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


# --- rectification and the self-check ------------------------------------------------------------------------------

def scene_pair(depth: float, rng, *, invert_right: bool = True):
    """A textured fronto-parallel plane ``depth`` metres in front of the reference camera, in both cameras."""
    texture = smooth_texture(rng, (900, 1200), sigma=2.0)
    metres_per_px = 0.0012
    R_plane, t_plane = np.eye(3), np.array([-0.72, -0.54, depth])
    left = render_plane(texture, metres_per_px, R_plane, t_plane, K_LEFT, DIST_LEFT)
    right = render_plane(texture, metres_per_px, R_RIGHT @ R_plane, R_RIGHT @ t_plane + T_RIGHT, K_RIGHT, DIST_RIGHT)
    return left, ((1 - right) * 0.7 + 0.1 if invert_right else 0.05 + 0.8 * right**1.6)


def test_rectified_pair_has_points_on_the_same_rows(rng):
    rig = synthetic_rig()
    left, right = rectify_pair(rig, *scene_pair(1.5, rng, invert_right=False))
    found = measure_vertical_misalignment(left, right)
    assert found.worst(left.shape[1]) < 0.15 and found.matches > 50


def test_self_check_corrects_a_vertical_offset_and_roll_to_within_a_fifth_of_a_pixel(rng):
    rig = synthetic_rig()
    left, right = rectify_pair(rig, *scene_pair(1.5, rng))
    height, width = right.shape
    turned = cv2.getRotationMatrix2D(((width - 1) / 2, (height - 1) / 2), 0.15, 1.0)
    turned[1, 2] -= 0.8  # content 0.8 px up, 0.15 degrees turned
    bad = cv2.warpAffine(right, turned, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    before = measure_vertical_misalignment(left, bad)
    assert before.worst(width) > 0.8
    assert math.degrees(abs(before.roll)) == pytest.approx(0.15, abs=0.05)
    after = measure_vertical_misalignment(left, correct_vertical_misalignment(bad, before))
    assert after.worst(width) < 0.2


def test_self_check_without_texture_is_one_clear_error():
    flat = np.full((120, 160), 0.5, np.float32)
    with pytest.raises(CadeError, match="self-check found only 0 feature matches"):
        measure_vertical_misalignment(flat, flat)


# --- the commands ----------------------------------------------------------------------------------------------------


@pytest.fixture
def rig_scene(tmp_path, rng):
    path = tmp_path / "rig.json"
    save_rig(synthetic_rig(), path)
    left, right = scene_pair(1.2, rng, invert_right=False)  # another response, not inverted: for sgbm
    files = tmp_path / "left.png", tmp_path / "right.png"
    for file, image in zip(files, (left, right)):
        cv2.imwrite(str(file), np.round(image * 255).astype(np.uint8))
    return path, *files


def test_calibrate_command_writes_a_rig_file_and_detection_pictures(chessboard_files, tmp_path, capsys):
    _, (lefts, rights) = chessboard_files
    folder = lefts[0].parent
    out, vis = tmp_path / "rig.json", tmp_path / "detections"
    code, stdout, stderr = run_cade(["calibrate", "--camera", f"left:bp400:{folder}/left*.png", "--camera",
                                     f"right:bp900:{folder}/right*.png", "--board", "chessboard:9x6", "--square",
                                     0.03, "-o", out, "--vis", vis], capsys)
    assert code == 0, stderr
    check_calibration(load_rig(out))
    assert "RMS" in stdout and len(list(vis.glob("*.png"))) == 2 * len(lefts)


def test_disparity_with_a_rig_gives_the_plane_depth(rig_scene, tmp_path, capsys):
    rig, left, right = rig_scene
    out, depth, cloud = tmp_path / "d.pfm", tmp_path / "z.tif", tmp_path / "c.ply"
    code, stdout, stderr = run_cade(["disparity", "--rig", rig, left, right, "-o", out, "--depth", depth, "--points",
                                     cloud, "--max-disp", 64, "-m", "sgbm", "--fill", "none"], capsys)
    assert code == 0, stderr
    z = tifffile.imread(depth)
    assert z.dtype == np.float32 and np.isnan(z).any()
    assert np.nanmedian(z) == pytest.approx(1.2, rel=0.02)
    expected_disparity = synthetic_rig().rectification.focal * synthetic_rig().rectification.baseline / 1.2
    assert np.nanmedian(read_disparity(out)) == pytest.approx(expected_disparity, abs=1.0)
    raw = cloud.read_bytes()
    header, body = raw.split(b"end_header\n", 1)
    assert header.startswith(b"ply\nformat binary_little_endian 1.0\n")
    count = int(header.split(b"element vertex ")[1].split(b"\n")[0])
    vertices = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    assert len(vertices) == count == np.isfinite(z).sum()
    assert np.median(vertices["z"]) == pytest.approx(1.2, rel=0.02)  # the plane, in the reference camera's frame
    assert np.all(vertices["r"] == vertices["b"]) and vertices["g"].std() > 10  # grey from the textured band


def mirrored_rig() -> Rig:
    """The synthetic rig seen from its right camera: the reference is the RIGHT camera, the other one left of it."""
    return Rig("right", (Camera("right", "bp900", SIZE, K=K_RIGHT, dist=DIST_RIGHT, R=np.eye(3), t=np.zeros(3)),
                         Camera("left", "bp400", SIZE, K=K_LEFT, dist=DIST_LEFT, R=R_RIGHT.T, t=-R_RIGHT.T @ T_RIGHT)))


def test_disparity_with_the_other_camera_left_of_the_reference(rig_scene, tmp_path, capsys):
    """The reference is the RIGHT camera: the pair is matched mirrored, disparity stays >= 0."""
    _, left, right = rig_scene
    save_rig(mirrored_rig(), tmp_path / "mirrored.json")
    out, depth = tmp_path / "d.pfm", tmp_path / "z.tif"
    code, _, stderr = run_cade(["disparity", "--rig", tmp_path / "mirrored.json", right, left, "-o", out, "--depth",
                                depth, "--max-disp", 64, "-m", "sgbm", "--fill", "none"], capsys)
    assert code == 0, stderr
    plane_depth_in_right_camera = (R_RIGHT @ np.array([0, 0, 1.2]) + T_RIGHT)[2]
    assert np.nanmedian(tifffile.imread(depth)) == pytest.approx(plane_depth_in_right_camera, rel=0.03)
    assert np.nanmedian(read_disparity(out)) > 30
    # the self-check matches features on the mirrored geometry too (x_right = x_left + d)
    assert "rectification self-check: offset" in stderr and "feature matches" not in stderr


def test_a_right_camera_of_another_resolution_is_resampled_through_the_rig(tmp_path, rng, capsys):
    """The right camera has twice the resolution (K doubled): depth must not change."""
    double = np.diag([2.0, 2.0, 1.0]) @ K_RIGHT
    left_camera = Camera("left", "vis", SIZE, K=K_LEFT, dist=DIST_LEFT, R=np.eye(3), t=np.zeros(3))
    right_camera = Camera("right", "nir", (2 * SIZE[0], 2 * SIZE[1]), K=double, dist=DIST_RIGHT, R=R_RIGHT, t=T_RIGHT)
    save_rig(Rig("left", (left_camera, right_camera)), tmp_path / "rig.json")
    texture = smooth_texture(rng, (900, 1200), sigma=2.0)
    R_plane, t_plane = np.eye(3), np.array([-0.72, -0.54, 1.2])
    left = render_plane(texture, 0.0012, R_plane, t_plane, K_LEFT, DIST_LEFT)
    right = render_plane(texture, 0.0012, R_RIGHT @ R_plane, R_RIGHT @ t_plane + T_RIGHT, double, DIST_RIGHT,
                         size=(2 * SIZE[0], 2 * SIZE[1]))
    for name, image in (("left.png", left), ("right.png", 0.05 + 0.8 * right**1.6)):
        cv2.imwrite(str(tmp_path / name), np.round(image * 255).astype(np.uint8))
    depth = tmp_path / "z.tif"
    code, _, stderr = run_cade(["disparity", "--rig", tmp_path / "rig.json", tmp_path / "left.png",
                                tmp_path / "right.png", "-o", tmp_path / "d.pfm", "--depth", depth, "--max-disp", 64,
                                "-m", "sgbm", "--fill", "none"], capsys)
    assert code == 0, stderr
    assert np.nanmedian(tifffile.imread(depth)) == pytest.approx(1.2, rel=0.02)


def test_disparity_with_a_rig_in_the_original_frame(rig_scene, tmp_path, capsys):
    rig, left, right = rig_scene
    out = tmp_path / "d.tif"
    code, _, stderr = run_cade(["disparity", "--rig", rig, left, right, "-o", out, "--max-disp", 64, "-m", "sgbm",
                                "--frame", "original", "--fix-vertical"], capsys)
    assert code == 0, stderr
    disparity = read_disparity(out)
    assert disparity.shape == (SIZE[1], SIZE[0])  # the original left image's grid
    rectification = synthetic_rig().rectification
    assert np.nanmedian(disparity) == pytest.approx(rectification.focal * rectification.baseline / 1.2, abs=1.0)
    assert np.isfinite(disparity).mean() > 0.6  # alpha = 0: the rectified view leaves out the edges
    assert np.isfinite(disparity[100:260, 120:360]).all()
    assert "left as is (--fix-vertical)" in stderr  # a perfect rig: nothing to correct


def plane_disparity(depth: float = 1.2) -> float:
    """Rectified disparity (px) of the scene plane ``depth`` metres in front of the synthetic rig."""
    rectification = synthetic_rig().rectification
    return rectification.focal * rectification.baseline / depth


def searched_range(stdout: str) -> tuple[int, int]:
    """The ``searched [a, b]`` range of a `cade disparity` summary line."""
    low, high = stdout.split("searched [")[1].split("]")[0].split(", ")
    return int(low), int(high)


def test_disparity_with_a_rig_and_max_disp_auto_covers_the_plane(rig_scene, tmp_path, capsys):
    """The range is estimated on the rectified pair, in rectified px, and announced as without a rig."""
    rig, left, right = rig_scene
    out = tmp_path / "d.pfm"
    code, stdout, stderr = run_cade(["disparity", "--rig", rig, left, right, "-o", out, "--max-disp", "auto", "-m",
                                     "sgbm", "--fill", "none"], capsys)
    assert code == 0, stderr
    assert "note: --max-disp auto: searching [0, " in stderr
    low, high = searched_range(stdout)
    assert low == 0 and plane_disparity() + 2 <= high <= plane_disparity() + 20  # the plane, and a margin
    assert f"searching [{low}, {high}] px" in stderr
    assert np.nanmedian(read_disparity(out)) == pytest.approx(plane_disparity(), abs=1.0)


def test_both_bounds_auto_with_the_other_camera_left_of_the_reference(rig_scene, tmp_path, capsys):
    """A mirrored rig: the range is estimated on the pair as it is matched (mirrored), so it
    comes out positive around the plane, as a range given in rectified px would be."""
    _, left, right = rig_scene
    save_rig(mirrored_rig(), tmp_path / "mirrored.json")
    out = tmp_path / "d.pfm"
    code, stdout, stderr = run_cade(["disparity", "--rig", tmp_path / "mirrored.json", right, left, "-o", out,
                                     "--min-disp", "auto", "--max-disp", "auto", "-m", "sgbm", "--fill", "none"],
                                    capsys)
    assert code == 0, stderr
    assert "note: --min-disp and --max-disp auto: searching [" in stderr
    low, high = searched_range(stdout)
    found = np.nanmedian(read_disparity(out))
    assert 0 < low < found < high < 2 * found
    assert found == pytest.approx(plane_disparity(), abs=1.5)  # the plane, a little closer to the right camera


def test_disparity_with_a_rig_and_a_memory_limit_matches_tiles_as_the_whole_pair(rig_scene, tmp_path, capsys):
    """A --memory-limit the rectified pair does not fit: matched as tiles, which agree with the whole match."""
    from cade_cli.scale.memory import BASE_BYTES

    rig, left, right = rig_scene
    args = ["disparity", "--rig", rig, left, right, "--max-disp", 64, "-m", "sgbm", "--fill", "none", "--depth"]
    code, _, stderr = run_cade([*args, tmp_path / "whole.tif", "-o", tmp_path / "whole.pfm"], capsys)
    assert code == 0 and " tiles of " not in stderr, stderr
    limit = f"{(BASE_BYTES + 40 * 2**20) // 2**10}KB"  # 480x360 over 65 disparities: about 20 tiles
    code, stdout, stderr = run_cade([*args, tmp_path / "tiled.tif", "-o", tmp_path / "tiled.pfm", "--memory-limit",
                                     limit], capsys)
    assert code == 0, stderr
    assert "note: the pair does not fit --memory-limit" in stderr and " tiles of " in stderr
    assert "searched [0, 64]" in stdout
    whole, tiled = read_disparity(tmp_path / "whole.pfm"), read_disparity(tmp_path / "tiled.pfm")
    both = np.isfinite(whole) & np.isfinite(tiled)
    assert both.mean() > 0.75 and np.isfinite(tiled).mean() >= 0.95 * np.isfinite(whole).mean()
    assert np.mean(np.abs(tiled - whole)[both] <= 1.0) > 0.99
    assert np.nanmedian(tiled) == pytest.approx(plane_disparity(), abs=1.0)
    assert np.nanmedian(tifffile.imread(tmp_path / "tiled.tif")) == pytest.approx(1.2, rel=0.02)


def test_rectify_command_writes_the_pair_and_the_epipolar_picture(rig_scene, tmp_path, capsys):
    rig, left, right = rig_scene
    outputs = tmp_path / "l.png", tmp_path / "r.png", tmp_path / "lines.png"
    code, stdout, stderr = run_cade(["rectify", rig, left, right, "-o", outputs[0], outputs[1], "--epipolar",
                                     outputs[2]], capsys)
    assert code == 0, stderr
    assert cv2.imread(str(outputs[2])).shape == (SIZE[1], 2 * SIZE[0], 3)
    assert "self-check" in stderr


def test_rectify_warns_about_a_slightly_wrong_rig_and_fix_vertical_corrects_it(rig_scene, tmp_path, capsys):
    """The rig file's right camera is pitched 0.15 degrees off the truth: about 1 px of vertical offset."""
    _, left, right = rig_scene
    off = synthetic_rig()
    pitched = Camera("right", "bp900", SIZE, K=K_RIGHT, dist=DIST_RIGHT, t=T_RIGHT,
                     R=cv2.Rodrigues(np.radians([0.15, 0, 0]))[0] @ R_RIGHT)
    save_rig(Rig("left", (off.camera("left"), pitched)), tmp_path / "off.json")
    outputs = tmp_path / "l.tif", tmp_path / "r.tif"
    code, _, stderr = run_cade(["rectify", tmp_path / "off.json", left, right, "-o", *outputs], capsys)
    assert code == 0 and "warning: rectification self-check: vertical misalignment" in stderr, stderr
    assert measure_vertical_misalignment(*map(tifffile.imread, outputs)).worst(SIZE[0]) > 0.7
    code, _, stderr = run_cade(["rectify", tmp_path / "off.json", left, right, "-o", *outputs, "--fix-vertical"],
                               capsys)
    assert code == 0 and "corrected (--fix-vertical)" in stderr, stderr
    assert measure_vertical_misalignment(*map(tifffile.imread, outputs)).worst(SIZE[0]) < 0.2


@pytest.mark.parametrize("make_args, message", [
    (lambda rig, l, r, tmp: ["disparity", l, r, "-o", tmp / "d.pfm", "--depth", tmp / "z.tif"], "--depth needs --rig"),
    (lambda rig, l, r, tmp: ["disparity", "--rig", tmp / "missing.json", l, r, "-o", tmp / "d.pfm"], "does not exist"),
    (lambda rig, l, r, tmp: ["disparity", "--rig", rig, r, tmp / "small.png", "-o", tmp / "d.pfm"], "small.png is 100x80"),
    (lambda rig, l, r, tmp: ["rectify", tmp / "newer.json", l, r, "-o", tmp / "a.png", tmp / "b.png"], "upgrade cade"),
    (lambda rig, l, r, tmp: ["calibrate", "--camera", f"a:x:{tmp}/none*.png", "--camera", f"b:y:{tmp}/none*.png",
                             "--board", "chessboard:9x6", "--square", 0.03, "-o", tmp / "r.json"], "matches no image file"),
    (lambda rig, l, r, tmp: ["calibrate", "--camera", f"a:x:{l}", "--camera", f"b:y:{r}", "--board", "chess:9x6",
                             "--square", 0.03, "-o", tmp / "r.json"], "board 'chess:9x6' not understood"),
    (lambda rig, l, r, tmp: ["calibrate", "--camera", f"a:x:{l}", "--camera", f"b:y:{r}", "--board", "chessboard:9x6",
                             "--square", 0.03, "-o", tmp / "r.json"], "board not found"),
])
def test_command_errors_are_one_line(rig_scene, tmp_path, capsys, make_args, message):
    rig, left, right = rig_scene
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((80, 100), np.uint8))
    newer = json.loads(rig.read_text())
    newer["version"] = RIG_VERSION + 1
    (tmp_path / "newer.json").write_text(json.dumps(newer))
    code, stdout, stderr = run_cade(make_args(rig, left, right, tmp_path), capsys)
    assert code == 1
    lines = stderr.strip().splitlines()
    assert lines[-1].startswith("cade: error:") and message in lines[-1], stderr
    assert "Traceback" not in stderr
    assert not (tmp_path / "d.pfm").exists() and not (tmp_path / "r.json").exists()


def test_opencv_sample_pairs_calibrate_below_half_a_pixel(shared_data):
    folder = shared_data / "calibration" / "opencv-stereo-chessboard"
    cameras = [CameraImages(side, "grey", tuple(sorted(folder.glob(f"{side}*.jpg")))) for side in ("left", "right")]
    found = calibrate_rig(cameras, parse_board("chessboard:9x6", square=1.0))
    assert found.rig.calibration.rms <= 0.5
    assert len(found.rig.calibration.views) >= 10
    assert found.rig.rectification.baseline == pytest.approx(3.3, abs=0.2)  # in square units


def test_png_output_with_a_rig_refuses_a_range_beyond_it_before_matching(rig_scene, tmp_path, capsys, monkeypatch):
    """A 16-bit PNG holds 0 <= d < 256: a given bound outside it is refused up front, an auto one
    as soon as it is estimated, before the match; one line naming the user's file."""
    import cade_cli.rigs.rectification

    def no_matching(*args, **kwargs):
        raise AssertionError("matched before refusing the output")

    monkeypatch.setattr(cade_cli.rigs.rectification, "estimate_disparity_tiled", no_matching)
    rig, left, right = rig_scene
    out = tmp_path / "d.png"
    for bounds in (["--min-disp", "-3", "--max-disp", "40"], ["--min-disp", "-3", "--max-disp", "auto"]):
        code, _, stderr = run_cade(["disparity", "--rig", rig, left, right, "-o", out, "-m", "sgbm", *bounds], capsys)
        errors = [line for line in stderr.splitlines() if line.startswith("cade: error")]
        assert code != 0 and len(errors) == 1 and str(out) in errors[0] and "--min-disp of 0" in errors[0], stderr
        assert not out.exists()


def test_calibrate_warns_of_millimetres_and_suggests_the_board_it_finds(chessboard_files, tmp_path, capsys):
    """--square 30 (mm given as metres): a one-line warning; a wrong --board (the squares, 10x7,
    instead of the 9x6 inner corners): the error names the board searched and the size found."""
    _, (lefts, _) = chessboard_files
    folder = lefts[0].parent
    cameras = ["--camera", f"left:bp400:{folder}/left*.png", "--camera", f"right:bp900:{folder}/right*.png"]
    code, _, stderr = run_cade(["calibrate", *cameras, "--board", "chessboard:9x6", "--square", 30, "-o",
                                tmp_path / "mm.json"], capsys)
    warnings = [line for line in stderr.splitlines() if line.startswith("warning:")]
    assert code == 0 and len(warnings) == 1 and "--square 30 m is implausible" in warnings[0] and "0.025" in stderr
    code, _, stderr = run_cade(["calibrate", *cameras, "--board", "chessboard:9x6", "--square", 0.03, "-o",
                                tmp_path / "m.json"], capsys)
    assert code == 0 and "warning:" not in stderr
    code, _, stderr = run_cade(["calibrate", *cameras, "--board", "chessboard:10x7", "--square", 0.03, "-o",
                                tmp_path / "wrong.json"], capsys)
    assert code != 0 and len(stderr.strip().splitlines()) == 1, stderr
    assert f"chessboard:10x7 (inner corners) found in 0 of {len(lefts)} pictures" in stderr
    assert "try --board chessboard:9x6" in stderr and not (tmp_path / "wrong.json").exists()


def test_implausible_scale():
    from cade_cli.rigs.calibration import implausible_scale

    assert implausible_scale(0.025, 0.12) is None
    assert "a baseline of 83.18 m" in implausible_scale(0.4, 83.18)
    assert "--square 25 m" in implausible_scale(25, 83.18)


def test_the_widest_baseline_is_the_longest_camera_translation():
    from cade_cli.rigs.calibration import widest_baseline

    rig = mirrored_rig()
    assert widest_baseline(rig) == pytest.approx(float(np.linalg.norm(T_RIGHT)))
    far = Camera("far", "bp700", SIZE, K=K_RIGHT, dist=DIST_RIGHT, R=np.eye(3), t=np.array([0.3, 0.4, 0.0]))
    assert widest_baseline(Rig("right", (*rig.cameras, far))) == pytest.approx(0.5)
