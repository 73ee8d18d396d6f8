"""Camera arrays (cade_cli.rigs.array): a rendered 3x3 array with known geometry and known
per-band responses; the fused disparity is measured against the truth, and every
registered band against the band rendered from the reference viewpoint."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.rigs.array import fuse_votes, masked_median, register_array
from cade_cli.rigs.array_cube import read_array_cube, write_array_cube
from cade_cli.rigs.array_geometry import ArrayCamera, array_geometry, baseline_frame, plane_mapping_from_points
from cade_cli.rigs.array_score import gradient_correlation, score_cubes
from cade_cli.rigs.rig_file import rig_from_dict
from synthetic import smooth_texture

SHAPE = (120, 160)
LAYERS = (  # (disparity, px per unit baseline; support in reference px: rows, columns)
    (-2.0, None),
    (3.0, (slice(20, 100), slice(20, 75))),
    (6.0, (slice(45, 90), slice(95, 140))),
)
"""A background behind the registration plane (negative disparity) and two planes in front
of it; the nearest, a box, hides parts of the others from every camera but the reference."""

RESPONSES = (
    lambda v: v,
    lambda v: 1.0 - v,                               # inverted contrast
    lambda v: v**2.2,
    lambda v: 0.5 + 0.5 * np.sin(2.5 * np.pi * v),   # not monotonic
    lambda v: 0.2 + 0.6 * np.sqrt(v),
    lambda v: np.abs(v - 0.5) * 2,                   # folds the range
    lambda v: 1.0 - v**1.5,
    lambda v: 0.3 + 0.4 * v,
    lambda v: np.clip(1.5 * v - 0.2, 0, 1),
)
"""Per-camera intensity responses: what a different filter would make of one scene."""


@dataclass(frozen=True)
class RenderedArray:
    rig: dict
    images: list[np.ndarray]  # per camera, rig order
    disparity: np.ndarray     # (H, W) reference view, px per unit baseline
    truth: list[np.ndarray]   # per camera: its band rendered from the reference viewpoint
    edges: np.ndarray         # (H, W) bool: within 3 px of a depth edge
    reference: int            # index of the reference camera


def _render(textures, coordinates_x, coordinates_y, offset):
    """The scene at reference-plane points (x, y) seen from a camera at ``offset`` (unit baselines):
    the nearest layer whose support holds the point it sees, sampled in that layer's texture."""
    image = np.zeros(coordinates_x.shape, np.float32)
    depth = np.full(coordinates_x.shape, -np.inf, np.float32)
    for (disparity, support), texture in zip(LAYERS, textures):
        x = coordinates_x + disparity * offset[0]  # the reference pixel of the layer's point seen here
        y = coordinates_y + disparity * offset[1]
        sampled = cv2.remap(texture, (x + 40).astype(np.float32), (y + 40).astype(np.float32), cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REFLECT)
        covered = np.ones(x.shape, bool)
        if support is not None:
            rows, columns = support
            covered = (y >= rows.start) & (y <= rows.stop - 1) & (x >= columns.start) & (x <= columns.stop - 1)
        nearer = covered & (disparity > depth)
        image = np.where(nearer, sampled, image)
        depth = np.where(nearer, disparity, depth)
    return image, depth


GRID = tuple((float(i % 3 - 1), float(i // 3 - 1)) for i in range(9))
"""A 3x3 array, unit baseline 1: positions (x right, y down) -1, 0, +1, camera 4 in the centre."""


def render_array(rng: np.random.Generator, *, shape=SHAPE, jitter: bool = True, positions=GRID,
                 reference: int = 4) -> RenderedArray:
    """An array of cameras at ``positions`` (unit baselines), camera ``reference`` the
    reference. Each camera's image is in its own pixels, which a known mapping takes onto
    the reference: a small random affine, or for the last camera a homography (the
    identity for every camera when ``jitter`` is False)."""
    height, width = shape
    textures = [smooth_texture(rng, (height + 80, width + 80), sigma=1.2) for _ in LAYERS]
    grid_x, grid_y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    cameras, images, truth = [], [], []
    reference_view, disparity = _render(textures, grid_x, grid_y, (0.0, 0.0))
    for index, position in enumerate(positions):
        mapping = np.eye(3)
        if index != reference and jitter:  # a small scale, shear and shift of this camera's pixels
            mapping[:2] = [[1 + rng.uniform(-0.02, 0.02), rng.uniform(-0.01, 0.01), rng.uniform(-4, 4)],
                           [rng.uniform(-0.01, 0.01), 1 + rng.uniform(-0.02, 0.02), rng.uniform(-4, 4)]]
            if index == len(positions) - 1:  # and a projective one
                mapping[2, :2] = [2e-5, -3e-5]
        # camera pixel u shows the reference-plane point H u
        mapped = mapping @ np.stack([grid_x.ravel(), grid_y.ravel(), np.ones(grid_x.size)])
        plane_x = (mapped[0] / mapped[2]).reshape(shape).astype(np.float32)
        plane_y = (mapped[1] / mapped[2]).reshape(shape).astype(np.float32)
        view, _ = _render(textures, plane_x, plane_y, position)
        response = RESPONSES[index]
        images.append(response(view).astype(np.float32))
        truth.append(response(reference_view).astype(np.float32))
        to_reference = {"affine": mapping[:2].tolist()} if not mapping[2, :2].any() else {"homography": mapping.tolist()}
        cameras.append({"name": f"c{index}", "band": f"band{index}", "image_size": [width, height],
                        "to_reference": to_reference, "position": list(position)})
    rig = {"format": "cade-rig", "version": 1, "reference": f"c{reference}", "cameras": cameras}
    edges = cv2.dilate((cv2.Laplacian(disparity, cv2.CV_32F) != 0).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    return RenderedArray(rig, images, disparity, truth, edges, reference)


def _reference_first(rendered: RenderedArray) -> list[np.ndarray]:
    """The images in ``register_array``'s order: the reference's, then the others in rig order."""
    index = rendered.reference
    return [rendered.images[index], *(image for i, image in enumerate(rendered.images) if i != index)]


@pytest.fixture(scope="module")
def rendered() -> RenderedArray:
    return render_array(np.random.default_rng(7))


@pytest.fixture(scope="module")
def census_registration(rendered):
    geometry = array_geometry(rig_from_dict(rendered.rig))
    return register_array(_reference_first(rendered), geometry, method="census-sgm", search=(-8, 8))


def _errors(fused: np.ndarray, rendered: RenderedArray) -> tuple[float, float]:
    """(EPE, bad-1 share) of ``fused`` away from depth edges and the border."""
    scored = ~rendered.edges
    scored[:10], scored[-10:], scored[:, :10], scored[:, -10:] = False, False, False, False
    error = np.abs(fused - rendered.disparity)[scored]
    return float(error.mean()), float((error > 1.0).mean())


def test_the_renderer_has_parallax_and_occlusion(rendered):
    """The test scene is not trivially aligned: on the plane alone the bands disagree."""
    assert set(np.unique(rendered.disparity)) == {-2.0, 3.0, 6.0}
    inverted = rendered.images[1]  # a camera above the reference: inverted contrast, shifted
    assert not np.allclose(inverted, rendered.truth[1], atol=0.05)


def test_plane_geometry_reads_positions_in_image_axes(rendered):
    geometry = array_geometry(rig_from_dict(rendered.rig))
    assert geometry.reference.name == "c4"
    assert [c.name for c in geometry.cameras] == [f"c{i}" for i in (0, 1, 2, 3, 5, 6, 7, 8)]
    assert geometry.unit == pytest.approx(1.0)
    np.testing.assert_allclose(geometry.cameras[0].baseline, [-1, -1])  # top left
    np.testing.assert_allclose(geometry.cameras[4].baseline, [1, 0])    # right


def test_fused_disparity_matches_the_truth_census(rendered, census_registration):
    epe, bad1 = _errors(census_registration.disparity, rendered)
    print(f"fused disparity vs truth, census-sgm: EPE {epe:.3f} px, bad-1 {100 * bad1:.2f} %")  # pytest -s shows it
    assert epe < 0.35 and bad1 < 0.05, (epe, bad1)
    # Every camera alone is wrong or silent more often than the fusion (occlusion, folded responses).
    single = [_errors(np.nan_to_num(vote, nan=np.inf), rendered)[1] for vote in census_registration.votes]
    assert bad1 < min(single) / 2, (bad1, single)


def test_corner_reference_of_a_2x2_array():
    """The reference at a corner: every other camera on one side of it (right, below and
    diagonal), so all occlusions fall on one side and each pixel has at most 3 votes. Two
    of the three bands are inverted or folded, which census-sgm cannot match (its votes
    there are off by 5-6 px, so no median could save it): cade can."""
    rendered = render_array(np.random.default_rng(3), positions=((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)),
                            reference=0)
    assert "homography" in rendered.rig["cameras"][3]["to_reference"]
    registration = register_array(_reference_first(rendered), array_geometry(rig_from_dict(rendered.rig)),
                                  method="cade", search=(-8, 8))
    epe, bad1 = _errors(registration.disparity, rendered)
    print(f"fused disparity vs truth, 2x2, cade: EPE {epe:.3f} px, bad-1 {100 * bad1:.2f} %")
    assert epe < 0.3 and bad1 < 0.06, (epe, bad1)
    for k, i in enumerate((1, 2, 3)):
        valid = registration.valid[k] & ~rendered.edges
        error = np.abs(registration.registered[k] - rendered.truth[i])[valid]
        assert valid.mean() > 0.6 and error.mean() < 0.06, (i, valid.mean(), error.mean())


def test_registered_bands_match_the_reference_geometry(rendered, census_registration):
    others = [i for i in range(9) if i != 4]
    for k, i in enumerate(others):
        valid = census_registration.valid[k] & ~rendered.edges
        assert valid.mean() > 0.6
        error = np.abs(census_registration.registered[k] - rendered.truth[i])[valid]
        assert error.mean() < 0.06, (i, error.mean())  # steep responses (sin, fold) magnify interpolation


def test_plane_only_registration_is_worse_and_scores_lower(rendered, census_registration, tmp_path):
    geometry = array_geometry(rig_from_dict(rendered.rig))
    plane = register_array(_reference_first(rendered), geometry, parallax=False)
    assert not plane.votes and np.all(plane.disparity == 0)
    for path, registration in (("plane.tif", plane), ("fused.tif", census_registration)):
        write_array_cube(tmp_path / path, registration, details={"method": "x"})
    cubes = [read_array_cube(tmp_path / name) for name in ("plane.tif", "fused.tif")]
    assert cubes[1].bands[0] == "band4" and cubes[1].cameras[0] == "c0"
    scores = score_cubes(cubes)
    for k, i in enumerate((0, 1, 2, 3, 5, 6, 7, 8)):
        assert scores[1][k].gradient_correlation > scores[0][k].gradient_correlation + 0.1, i
        scored = cubes[0].valid[k] & cubes[1].valid[k] & ~rendered.edges
        error_plane, error_fused = (np.abs(cube.registered[k] - rendered.truth[i])[scored].mean() for cube in cubes)
        assert error_plane > 3 * error_fused, (i, error_plane, error_fused)


def test_fused_disparity_matches_the_truth_cade(rendered):
    geometry = array_geometry(rig_from_dict(rendered.rig))
    registration = register_array(_reference_first(rendered), geometry, method="cade", search=(-8, 8))
    epe, bad1 = _errors(registration.disparity, rendered)
    print(f"fused disparity vs truth, cade: EPE {epe:.3f} px, bad-1 {100 * bad1:.2f} %")
    assert epe < 0.5 and bad1 < 0.08, (epe, bad1)


def test_cube_file_keeps_bands_and_names(census_registration, tmp_path):
    path = tmp_path / "cube.tif"
    write_array_cube(path, census_registration)
    cube = read_array_cube(path)
    assert cube.description["bands"][:2] == ["band4", "band0"] and cube.description["bands"][-1] == "valid:band8"
    assert len(cube.description["bands"]) == 17
    np.testing.assert_array_equal(cube.reference, census_registration.reference)
    np.testing.assert_array_equal(cube.valid[3], census_registration.valid[3])


def test_not_a_cube_is_refused(tmp_path):
    import tifffile

    path = tmp_path / "plain.tif"
    tifffile.imwrite(path, np.zeros((3, 8, 8), np.float32), photometric="minisblack")
    with pytest.raises(CadeError, match="not an array cube"):
        read_array_cube(path)


@pytest.mark.parametrize("direction", [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (2, -1)])
def test_baseline_frame_turns_the_baseline_into_plus_x(direction):
    frame = baseline_frame(np.array(direction, float), (30, 50))
    turned = frame.matrix[:, :2] @ (np.array(direction, float) / math.hypot(*direction))
    np.testing.assert_allclose(turned, [1, 0], atol=1e-12)
    # Every pixel of the view lands inside the frame, and comes back where it was.
    image = np.random.default_rng(1).random((30, 50)).astype(np.float32)
    back, kept = frame.from_frame(frame.to_frame(image), np.ones(frame.size[::-1], bool), image.shape)
    assert kept[2:-2, 2:-2].all()
    tolerance = 1e-6 if frame.exact else 0.2
    assert np.abs(back - image)[2:-2, 2:-2].mean() < tolerance


def test_masked_median_ignores_missing_votes():
    votes = np.array([[[1.0, np.nan]], [[5.0, np.nan]], [[2.0, 4.0]], [[np.nan, np.nan]]], np.float32)
    median, count = masked_median(votes)
    np.testing.assert_array_equal(count, [[3, 1]])
    np.testing.assert_allclose(median, [[2.0, 4.0]])
    median, count = masked_median(votes[:2])
    assert median[0, 0] == 3.0 and np.isnan(median[0, 1]) and count[0, 1] == 0


def test_an_outlying_vote_does_not_count():
    cameras = [ArrayCamera(f"c{i}", "b", (8, 6), np.array([1.0, 0.0])) for i in range(3)]
    votes = [np.full((6, 8), 2.0, np.float32), np.full((6, 8), 2.2, np.float32), np.full((6, 8), 7.0, np.float32)]
    fused, kept = fuse_votes(votes, cameras, unit=1.0)
    np.testing.assert_allclose(fused, 2.1, atol=1e-6)  # the median of the two that agree, not 2.2
    assert (kept == 2).all()


def test_bad_inputs_are_one_clear_error(rendered):
    geometry = array_geometry(rig_from_dict(rendered.rig))
    images = _reference_first(rendered)
    with pytest.raises(CadeError, match="9 cameras .* 8 images"):
        register_array(images[:-1], geometry, parallax=False)
    with pytest.raises(CadeError, match="is 80x60, the rig says 160x120"):
        register_array([*images[:-1], images[-1][::2, ::2]], geometry, parallax=False)
    far = json.loads(json.dumps(rendered.rig))
    far["cameras"][0]["to_reference"] = {"affine": [[1, 0, 5000], [0, 1, 0]]}
    with pytest.raises(CadeError, match="camera c0 sees 0.0% of the reference view"):
        register_array(images, array_geometry(rig_from_dict(far)), parallax=False)
    single = dict(rendered.rig, cameras=rendered.rig["cameras"][4:5])
    with pytest.raises(CadeError, match="at least two cameras"):
        array_geometry(rig_from_dict(single))


def test_calibrated_rig_is_the_plane_at_infinity():
    """A calibrated array of parallel, identical cameras: the reference plane is the plane
    at infinity, the baseline the camera centre (-R^T t)."""
    K = [[100.0, 0, 40], [0, 100.0, 30], [0, 0, 1]]
    eye = np.eye(3).tolist()
    rig = rig_from_dict({"format": "cade-rig", "version": 1, "reference": "a", "cameras": [
        {"name": "a", "band": "x", "image_size": [80, 60], "K": K, "R": eye, "t": [0, 0, 0]},
        {"name": "b", "band": "y", "image_size": [80, 60], "K": K, "R": eye, "t": [-0.1, 0, 0]},
    ]})
    geometry = array_geometry(rig)
    camera = geometry.cameras[0]
    np.testing.assert_allclose(camera.baseline, [0.1, 0])
    cx, cy = camera.camera_pixels(np.array([10.0, 50.0]), np.array([5.0, 40.0]))
    np.testing.assert_allclose(cx, [10, 50], atol=1e-4)
    np.testing.assert_allclose(cy, [5, 40], atol=1e-4)


def test_calibrated_array_registers_like_a_plane_registered_one():
    """The rendered array as a calibrated rig: identical intrinsics, no rotation, camera
    centres at the positions (t = -C, metres); its plane is the plane at infinity."""
    rendered = render_array(np.random.default_rng(11), jitter=False)
    K = [[200.0, 0, 80], [0, 200.0, 60], [0, 0, 1]]
    cameras = []
    for camera in rendered.rig["cameras"]:
        x, y = camera["position"]
        cameras.append({"name": camera["name"], "band": camera["band"], "image_size": camera["image_size"], "K": K,
                        "dist": [0, 0, 0, 0, 0], "R": np.eye(3).tolist(), "t": [-x, -y, 0.0]})
    rig = rig_from_dict({"format": "cade-rig", "version": 1, "reference": "c4", "cameras": cameras})
    registration = register_array(_reference_first(rendered), array_geometry(rig), method="census-sgm", search=(-8, 8))
    epe, bad1 = _errors(registration.disparity, rendered)
    assert epe < 0.35 and bad1 < 0.05, (epe, bad1)
    np.testing.assert_allclose(registration.reference, rendered.images[4], atol=1e-5)


def test_calibrated_camera_pixels_follow_distortion_and_rotation():
    """A reference-plane pixel maps to where OpenCV projects its ray, rotated into the
    camera, through the camera's distortion: undistorting it gives the ray back."""
    K_reference = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    K = np.array([[310.0, 0, 158], [0, 305.0, 123], [0, 0, 1]])
    dist = np.array([-0.12, 0.03, 0.001, -0.002, 0.0])
    R, _ = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))
    camera = ArrayCamera("b", "y", (320, 240), np.array([0.1, 0.0]), K=K, dist=dist, rotation=R,
                         K_reference=K_reference)
    x, y = np.meshgrid(np.linspace(10, 310, 7), np.linspace(10, 230, 5))
    cx, cy = camera.camera_pixels(x, y)
    rays = cv2.undistortPoints(np.stack([cx.ravel(), cy.ravel()], 1)[:, None].astype(np.float64), K, dist)[:, 0]
    back = (K_reference @ R.T @ np.vstack([rays.T, np.ones(len(rays))]))
    np.testing.assert_allclose(back[0] / back[2], x.ravel(), atol=0.02)
    np.testing.assert_allclose(back[1] / back[2], y.ravel(), atol=0.02)


def test_affine_from_points_recovers_a_known_affine():
    rng = np.random.default_rng(3)
    truth = np.array([[0.99, -0.01, 20.0], [0.005, 1.01, -13.0]])
    points = rng.uniform(0, 1000, (8, 2))
    mapping, rms = plane_mapping_from_points(points, points @ truth[:, :2].T + truth[:, 2])
    np.testing.assert_allclose(mapping.matrix, truth, atol=1e-9)
    assert rms < 1e-9 and mapping.kind == "affine"
    with pytest.raises(CadeError, match="at least 3"):
        plane_mapping_from_points(points[:2], points[:2])


def test_gradient_correlation_prefers_aligned_bands_whatever_the_contrast():
    band = smooth_texture(np.random.default_rng(5), (80, 100), sigma=1.2)
    valid = np.ones(band.shape, bool)
    assert gradient_correlation(band, 1 - band, valid) > 0.99
    shifted = np.roll(band, 2, axis=1)
    assert gradient_correlation(band, shifted, valid) < gradient_correlation(band, band**2, valid) - 0.3


# --- the commands ----------------------------------------------------------------------------------------------------


def _run(args, capsys) -> tuple[int, str, str]:
    from cade_cli import cli

    with pytest.raises(SystemExit) as exit_info:
        cli.main([str(a) for a in args])
    captured = capsys.readouterr()
    return exit_info.value.code, captured.out, captured.err


@pytest.fixture
def array_files(rendered, tmp_path):
    """The rendered array on disk: its rig file and one 16-bit PNG per camera, named after it."""
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps(rendered.rig))
    paths = []
    for camera, image in zip(rendered.rig["cameras"], rendered.images):
        path = tmp_path / f"{camera['name']}.png"
        cv2.imwrite(str(path), np.rint(np.clip(image, 0, 1) * 65535).astype(np.uint16))
        paths.append(path)
    return rig, paths


def test_register_array_and_array_score_commands(array_files, rendered, tmp_path, capsys):
    rig, paths = array_files
    shuffled = paths[::-1]  # named after their cameras: the order does not matter
    code, out, err = _run(["register-array", rig, *shuffled, "-o", tmp_path / "fused.tif", "--method", "census-sgm",
                           "--min-disp", "-8", "--max-disp", "8", "--disparity", tmp_path / "fused.pfm",
                           "--vis", tmp_path / "fused.png"], capsys)
    assert code == 0, err
    assert "9 cameras onto c4" in out and "census-sgm" in out
    from cade_cli.io.disparity import read_disparity

    epe, _ = _errors(np.nan_to_num(read_disparity(tmp_path / "fused.pfm"), nan=0.0), rendered)
    assert epe < 0.35
    assert cv2.imread(str(tmp_path / "fused.png")).shape == (*SHAPE, 3)
    cube = read_array_cube(tmp_path / "fused.tif")
    assert cube.description["method"] == "census-sgm" and cube.description["search"] == [-8.0, 8.0]
    code, out, err = _run(["register-array", rig, *paths, "-o", tmp_path / "plane.tif", "--plane-only"], capsys)
    assert code == 0 and "plane only" in out, err
    code, out, err = _run(["array-score", tmp_path / "plane.tif", tmp_path / "fused.tif"], capsys)
    assert code == 0, err
    rows = [line for line in out.splitlines() if line.strip("│ ").startswith("c")]
    assert len(rows) == 8
    for row in rows:  # NGC plane-only, NGC fused: the fused registration aligns every band better
        cells = [cell.strip() for cell in row.strip("│").split("│")]
        assert float(cells[4]) > float(cells[3]) + 0.1, row


def test_register_array_refuses_bad_inputs_in_one_line(array_files, tmp_path, capsys):
    rig, paths = array_files
    code, _, err = _run(["register-array", rig, *paths[:-1], "-o", tmp_path / "cube.tif"], capsys)
    assert code == 1 and "9 cameras" in err and "8 images" in err and len(err.strip().splitlines()) == 1
    small = tmp_path / "small" / "c8.png"
    small.parent.mkdir()
    cv2.imwrite(str(small), np.zeros((60, 80), np.uint8))
    code, _, err = _run(["register-array", rig, *paths[:-1], small, "-o", tmp_path / "cube.tif", "--plane-only"],
                        capsys)
    assert code == 1 and "camera c8 is 80x60, the rig says 160x120" in err
    code, _, err = _run(["register-array", rig, *paths, "-o", tmp_path / "cube.tif", "--plane-only",
                         "--disparity", tmp_path / "d.pfm"], capsys)
    assert code == 1 and "--disparity needs the parallax" in err
    missing = tmp_path / "gone" / "c8.png"  # an empty range is refused before any image is read
    code, _, err = _run(["register-array", rig, *paths[:-1], missing, "-o", tmp_path / "cube.tif",
                         "--min-disp", "4", "--max-disp", "2"], capsys)
    assert code == 1 and "--max-disp 2 is not above --min-disp 4" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "cube.tif").exists()


def test_msir_rig_and_parallax_beat_the_affine_alone(shared_data, tmp_path, capsys):
    """MSIR outdoor (a real 3x3 array, no ground truth): the rig the benchmark script writes
    holds the affines NOTES.md lists, and registering the parallax aligns every band better
    than the affine alone (census-sgm at a quarter resolution, for speed)."""
    import subprocess
    import sys
    from pathlib import Path

    from cade_cli.rigs.rig_file import load_rig

    folder = shared_data / "msir-outdoor"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "msir_alignment.py"
    rig_file = tmp_path / "msir.json"
    done = subprocess.run([sys.executable, script, "rig", folder, "-o", rig_file], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    rig = load_rig(rig_file)
    assert rig.reference == "Cam-4" and [c.band for c in rig.cameras] == [f"cam{i}" for i in range(9)]
    cam0 = rig.camera("Cam-0")
    np.testing.assert_allclose(cam0.to_reference.matrix, [[0.9985, -0.0005, 22.75], [0.0014, 0.9974, -12.89]],
                               atol=0.01)  # NOTES.md
    assert cam0.position == (0.04, -0.04)  # X = +40 mm is image right, Y = +40 mm the top row (y down here)
    images = [folder / "scene" / f"Cam-{i}.png" for i in range(9)]
    fast = ["--method", "census-sgm", "--match-scale", "0.25"]
    for name, options in (("plane.tif", ["--plane-only"]), ("fused.tif", fast)):
        code, _, err = _run(["register-array", rig_file, *images, "-o", tmp_path / name, *options], capsys)
        assert code == 0, err
    plane, fused = score_cubes([read_array_cube(tmp_path / "plane.tif"), read_array_cube(tmp_path / "fused.tif")])
    gains = [after.gradient_correlation - before.gradient_correlation for before, after in zip(plane, fused)]
    assert min(gains) > 0 and np.mean(gains) > 0.01, gains


def test_array_score_refuses_cubes_of_two_scenes_sizes_or_band_sets(rng):
    """Cubes are compared only when they register one capture: same size, same cameras, and
    (nearly) the same reference band; otherwise one line saying what differs."""
    from cade_cli.rigs.array_cube import ArrayCube

    def cube(reference, cameras=("c0", "c1")):
        bands = tuple(reference.copy() for _ in cameras)
        return ArrayCube(reference, bands, tuple(np.ones(reference.shape, bool) for _ in cameras), "ref", cameras,
                         ("b",) * (len(cameras) + 1), {})

    scene, other = smooth_texture(rng, (40, 60)), smooth_texture(rng, (40, 60))
    assert len(score_cubes([cube(scene), cube(scene + 0.01 * rng.random(scene.shape).astype(np.float32))])) == 2
    with pytest.raises(CadeError, match=r"b.tif and a.tif have different reference bands \(correlation"):
        score_cubes([cube(scene), cube(other)], names=["a.tif", "b.tif"])
    with pytest.raises(CadeError, match=r"cube 2 and cube 1 differ in size \(50x40 vs 60x40\)"):
        score_cubes([cube(scene), cube(scene[:, :50].copy())])
    with pytest.raises(CadeError, match=r"hold other bands \(2: c0 vs 3: c0, c1\)"):
        score_cubes([cube(scene), cube(scene, cameras=("c0",))])


def test_register_array_estimates_each_cameras_range_with_auto(array_files, rendered, tmp_path, capsys):
    """--min-disp/--max-disp auto: each camera searches the range a coarse match of its own pair
    finds, and the fused map is as good as with the range given (-2, 3 and 6 px per unit baseline)."""
    rig, paths = array_files
    code, out, err = _run(["register-array", rig, *paths, "-o", tmp_path / "auto.tif", "--method", "census-sgm",
                           "--min-disp", "auto", "--max-disp", "auto", "--disparity", tmp_path / "auto.pfm"], capsys)
    assert code == 0, err
    assert "over [auto, auto] px per" in out
    from cade_cli.io.disparity import read_disparity

    epe, bad1 = _errors(np.nan_to_num(read_disparity(tmp_path / "auto.pfm"), nan=0.0), rendered)
    assert epe < 0.35 and bad1 < 0.05, (epe, bad1)
    assert read_array_cube(tmp_path / "auto.tif").description["search"] == ["auto", "auto"]
    code, _, err = _run(["register-array", rig, *paths, "-o", tmp_path / "x.tif", "--max-disp", "far"], capsys)
    assert code == 1 and "--max-disp 'far' is not a number of px per unit baseline or 'auto'" in err
    assert not (tmp_path / "x.tif").exists()
