"""Dataset readers: synthetic trees in each official layout with known GT, then the real data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli.data import DATASETS, Scene, get_dataset, max_disp_from_gt, nonoccluded_mask, read_calib
from cade_cli.errors import CadeError

H, W = 12, 18


def write_rgb(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), rgb[:, :, ::-1] if rgb.ndim == 3 else rgb)


def write_grey(path: Path, values: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), values)


def write_pfm(path: Path, values: np.ndarray) -> None:
    """PFM bytes by hand: header, little-endian float32 rows bottom-to-top."""
    path.parent.mkdir(parents=True, exist_ok=True)
    height, width = values.shape
    path.write_bytes(f"Pf\n{width} {height}\n-1.0\n".encode() + values[::-1].astype("<f4").tobytes())


def texture(rng: np.random.Generator, height: int = H, width: int = W) -> np.ndarray:
    return rng.integers(0, 256, (height, width, 3), dtype=np.uint8)


def views(folder: Path, names: tuple[str, str], rng: np.random.Generator, *, height: int = H, width: int = W):
    left, right = texture(rng, height, width), texture(rng, height, width)
    write_rgb(folder / names[0], left)
    write_rgb(folder / names[1], right)
    return left, right


def only(iterator) -> Scene:
    scenes = list(iterator)
    assert len(scenes) == 1
    return scenes[0]


# --- shared rules -------------------------------------------------------------------------

@pytest.mark.parametrize(
    ("values", "expected"),
    [([[3.0]], 16), ([[16.0]], 16), ([[16.01]], 24), ([[1.0, 16.5]], 24), ([[24.0]], 24), ([[np.nan]], 16),
     ([[np.nan, 70.2]], 72)],
)
def test_max_disp_from_gt_rounds_up_to_multiple_of_8_at_least_16(values, expected):
    assert max_disp_from_gt(np.array(values, dtype=np.float32)) == expected


def test_get_dataset_unknown_name_lists_choices():
    assert get_dataset("kitti2015") is DATASETS["kitti2015"]
    with pytest.raises(CadeError, match="unknown dataset 'kitti'.*middlebury05.*folder"):
        get_dataset("kitti")


def test_registry_holds_every_reader():
    assert set(DATASETS) == {"middlebury05", "middlebury06", "middlebury14", "middeval3", "flyingthings3d",
                             "kitti2015", "kitti2012", "msir-outdoor", "folder"}


# --- Middlebury 2005 / 2006 ---------------------------------------------------------------

def middlebury_2view(folder: Path, rng, *, width: int, left_gt: np.ndarray, right_gt: np.ndarray):
    left, right = views(folder, ("view1.png", "view5.png"), rng, height=left_gt.shape[0], width=width)
    write_grey(folder / "disp1.png", left_gt.astype(np.uint8))
    write_grey(folder / "disp5.png", right_gt.astype(np.uint8))
    return left, right


@pytest.mark.parametrize("dataset", ["middlebury05", "middlebury06"])
@pytest.mark.parametrize(("width", "resolution", "divisor"),
                         [(1380, "FullSize", 1), (690, "HalfSize", 2), (460, "ThirdSize", 3)])
def test_middlebury_2view_divides_by_resolution(tmp_path, rng, dataset, width, resolution, divisor):
    encoded = np.full((2, width), 12, dtype=np.uint8)
    encoded[1, 5] = 0
    left, right = middlebury_2view(tmp_path / "Art", rng, width=width, left_gt=encoded, right_gt=encoded)
    scene = only(DATASETS[dataset](tmp_path))
    assert (scene.name, scene.resolution) == ("Art", resolution)
    expected = np.full((2, width), 12 / divisor, dtype=np.float32)
    expected[1, 5] = np.nan
    np.testing.assert_array_equal(scene.disparity, expected)
    assert scene.disparity.dtype == np.float32
    np.testing.assert_array_equal(scene.left, left.astype(np.float32) / 255)
    np.testing.assert_array_equal(scene.right, right.astype(np.float32) / 255)
    assert scene.max_disp == 16


def test_middlebury_2view_nonocc_from_left_right_consistency(tmp_path, rng):
    # ThirdSize: stored value 6 -> d = 2 px. Hand-placed exceptions, expected mask by hand.
    left_gt = np.full((1, 460), 6, dtype=np.uint8)
    right_gt = np.full((1, 460), 6, dtype=np.uint8)
    expected = np.ones((1, 460), dtype=bool)
    expected[0, :2] = False        # x - 2 < 0: the match falls outside the right image
    right_gt[0, 8] = 0             # x = 10 lands on unknown right GT
    expected[0, 10] = False
    right_gt[0, 18] = 15           # x = 20 lands on d_right = 5 px, 3 px off
    expected[0, 20] = False
    left_gt[0, 30] = 0             # no left GT -> never non-occluded
    expected[0, 30] = False
    left_gt[0, 40] = 7             # d = 2.33 -> x' = round(37.67) = 38, d_right 2: within 1 px
    left_gt[0, 50] = 10            # d = 3.33 -> x' = round(46.67) = 47, consistent there (floor: 46, unknown)
    right_gt[0, 47] = 10
    right_gt[0, 46] = 0
    expected[0, 49] = False        # x = 49 (d = 2) lands on 47: 1.33 px off
    expected[0, 48] = False        # x = 48 (d = 2) lands on 46: unknown
    middlebury_2view(tmp_path / "middlebury2005" / "Books", rng, width=460, left_gt=left_gt, right_gt=right_gt)
    scene = only(DATASETS["middlebury05"](tmp_path))  # parent folder accepted
    np.testing.assert_array_equal(scene.nonocc, expected)
    assert scene.max_disp == 16 and scene.resolution == "ThirdSize"


def test_middlebury_2view_max_disp_from_gt(tmp_path, rng):
    encoded = np.full((2, 460), 200, dtype=np.uint8)   # 66.67 px at ThirdSize -> 67 -> 72
    middlebury_2view(tmp_path / "Art", rng, width=460, left_gt=encoded, right_gt=encoded)
    assert only(DATASETS["middlebury05"](tmp_path)).max_disp == 72


def test_middlebury_2view_unknown_width_is_an_error(tmp_path, rng):
    encoded = np.full((H, W), 12, dtype=np.uint8)
    middlebury_2view(tmp_path / "Art", rng, width=W, left_gt=encoded, right_gt=encoded)
    with pytest.raises(CadeError, match="18 px wide.*ThirdSize"):
        list(DATASETS["middlebury05"](tmp_path))


def test_nonoccluded_mask_shape_mismatch_is_an_error():
    with pytest.raises(CadeError, match="shapes differ"):
        nonoccluded_mask(np.zeros((2, 3), np.float32), np.zeros((3, 2), np.float32))


# --- Middlebury 2014 ----------------------------------------------------------------------

CALIB = """cam0=[1038.018 0 322.037; 0 1038.018 243.393; 0 0 1]
cam1=[1038.018 0 375.308; 0 1038.018 243.393; 0 0 1]
doffs=53.271
baseline=176.252
width=18
height=12
ndisp=20
isint=0
vmin=2
vmax=9.5
"""


def middlebury14_scene(folder: Path, rng, *, gt: np.ndarray, mask: np.ndarray | None = None,
                       right_gt: np.ndarray | None = None) -> None:
    views(folder, ("im0.png", "im1.png"), rng, height=gt.shape[0], width=gt.shape[1])
    (folder / "calib.txt").write_text(CALIB)
    if mask is not None:
        write_pfm(folder / "disp0GT.pfm", gt)
        write_grey(folder / "mask0nocc.png", mask)
    else:
        write_pfm(folder / "disp0.pfm", gt)
    if right_gt is not None:
        write_pfm(folder / "disp1.pfm", right_gt)


def training_gt() -> tuple[np.ndarray, np.ndarray]:
    gt = np.tile(np.linspace(2.0, 9.5, W, dtype=np.float32), (H, 1))
    gt[3, 4] = np.inf
    mask = np.full((H, W), 255, dtype=np.uint8)
    mask[0, :3] = 128
    mask[5, 5] = 0
    mask[3, 4] = 255  # inconsistent file: 255 where GT is inf -> still not non-occluded
    return gt, mask


def test_middlebury14_training_layout(tmp_path, rng):
    gt, mask = training_gt()
    middlebury14_scene(tmp_path / "middlebury2014" / "trainingQ" / "Adirondack", rng, gt=gt, mask=mask)
    scene = only(DATASETS["middlebury14"](tmp_path))
    assert (scene.name, scene.resolution, scene.max_disp) == ("Adirondack", "Q", 19)
    expected = gt.copy()
    expected[3, 4] = np.nan
    np.testing.assert_array_equal(scene.disparity, expected)
    expected_mask = mask == 255
    expected_mask[3, 4] = False
    np.testing.assert_array_equal(scene.nonocc, expected_mask)
    assert scene.metadata["vmin"] == 2 and scene.metadata["vmax"] == 9.5 and scene.metadata["ndisp"] == 20
    assert scene.metadata["cam0"].shape == (3, 3) and scene.metadata["cam0"][0, 2] == pytest.approx(322.037)


def test_middlebury14_root_may_be_the_training_folder(tmp_path, rng):
    gt, mask = training_gt()
    middlebury14_scene(tmp_path / "trainingH" / "Piano", rng, gt=gt, mask=mask)
    scene = only(DATASETS["middlebury14"](tmp_path / "trainingH"))
    assert (scene.name, scene.resolution) == ("Piano", "H")


def test_middlebury14_resolution_choice(tmp_path, rng):
    gt, mask = training_gt()
    middlebury14_scene(tmp_path / "trainingH" / "Piano", rng, gt=gt, mask=mask)
    middlebury14_scene(tmp_path / "trainingQ" / "Pipes", rng, gt=gt, mask=mask)
    reader = DATASETS["middlebury14"]
    assert reader.scene_names(tmp_path) == ["Pipes"]                    # Q preferred
    assert reader.scene_names(tmp_path, resolution="H") == ["Piano"]
    assert only(reader(tmp_path, resolution="H")).resolution == "H"
    with pytest.raises(CadeError, match="no middlebury14 scenes at resolution F.*training"):
        reader.scene_names(tmp_path, resolution="F")
    with pytest.raises(CadeError, match="no resolution option 'X'; use one of Q, H, F"):
        reader.scene_names(tmp_path, resolution="X")


def test_middlebury14_perfect_layout_derives_nonocc_from_disp1(tmp_path, rng):
    gt = np.full((H, W), 2.0, dtype=np.float32)
    gt[0, 9] = np.inf
    right_gt = np.full((H, W), 2.0, dtype=np.float32)
    right_gt[1, 5] = 6.0          # left (1, 7) lands here: inconsistent
    middlebury14_scene(tmp_path / "Motorcycle-perfect", rng, gt=gt, right_gt=right_gt)
    middlebury14_scene(tmp_path / "Piano-perfect", rng, gt=gt)
    reader = DATASETS["middlebury14"]
    assert reader.scene_names(tmp_path) == ["Motorcycle", "Piano"]
    motorcycle, piano = reader(tmp_path)
    expected = np.ones((H, W), dtype=bool)
    expected[:, :2] = False
    expected[0, 9] = False
    expected[1, 7] = False
    np.testing.assert_array_equal(motorcycle.nonocc, expected)
    assert np.isnan(motorcycle.disparity[0, 9]) and motorcycle.resolution == "F" and motorcycle.max_disp == 19
    assert piano.nonocc is None


def test_read_calib_requires_ndisp(tmp_path):
    (tmp_path / "calib.txt").write_text("vmin=2\n")
    with pytest.raises(CadeError, match="no integer ndisp"):
        read_calib(tmp_path / "calib.txt")


# --- FlyingThings3D -----------------------------------------------------------------------

def test_flyingthings3d_layout(tmp_path, rng):
    names = ["TEST/B/0149/0015", "TRAIN/A/0000/0006"]
    gts = {}
    for name, top in zip(names, (30.5, 3.0)):
        sequence, frame = name.rsplit("/", 1)
        views(tmp_path / "frames_cleanpass" / sequence, (f"left/{frame}.png", f"right/{frame}.png"), rng)
        gts[name] = np.linspace(1.0, top, H * W, dtype=np.float32).reshape(H, W)
        write_pfm(tmp_path / "disparity" / sequence / "left" / f"{frame}.pfm", gts[name])
    reader = DATASETS["flyingthings3d"]
    assert reader.scene_names(tmp_path) == names
    scenes = list(reader(tmp_path, scenes=["TRAIN/A/0000/0006", "TEST/B/0149/0015"]))  # order as asked
    assert [scene.name for scene in scenes] == names[::-1]
    for scene in scenes:
        np.testing.assert_array_equal(scene.disparity, gts[scene.name])
        assert scene.nonocc is None and scene.resolution == "18x12" and scene.left.shape == (H, W, 3)
    assert [scene.max_disp for scene in scenes] == [16, 32]


# --- KITTI --------------------------------------------------------------------------------

KITTI_FOLDERS = {
    "kitti2015": ("image_2", "image_3", "disp_occ_0", "disp_noc_0"),
    "kitti2012": ("colored_0", "colored_1", "disp_occ", "disp_noc"),
}


def kitti_gt() -> tuple[np.ndarray, np.ndarray]:
    occ = np.zeros((H, W), dtype=np.uint16)
    occ[4:, :] = 10 * 256 + 128          # 10.5 px
    occ[6, 7] = 65535                    # 255.996 px
    noc = occ.copy()
    noc[4:, :3] = 0
    return occ, noc


@pytest.mark.parametrize("dataset", sorted(KITTI_FOLDERS))
def test_kitti_official_training_layout(tmp_path, rng, dataset):
    left, right, occ_dir, noc_dir = KITTI_FOLDERS[dataset]
    base = tmp_path / "training"
    occ, noc = kitti_gt()
    for stem in ("000000_10", "000001_10"):
        views(base, (f"{left}/{stem}.png", f"{right}/{stem}.png"), rng)
        write_grey(base / occ_dir / f"{stem}.png", occ)
        write_grey(base / noc_dir / f"{stem}.png", noc)
    write_rgb(base / left / "000000_11.png", texture(rng))  # second flow frame: not a stereo scene
    reader = DATASETS[dataset]
    assert reader.scene_names(tmp_path) == ["000000_10", "000001_10"]
    scene = only(reader(tmp_path, scenes=["000001_10"]))
    expected = np.where(occ > 0, occ / np.float32(256), np.nan).astype(np.float32)
    np.testing.assert_array_equal(scene.disparity, expected)
    assert scene.disparity[5, 5] == 10.5 and scene.disparity[6, 7] == pytest.approx(255.996, abs=1e-3)
    np.testing.assert_array_equal(scene.nonocc, noc > 0)
    assert scene.max_disp == 256 and scene.resolution == "18x12"


@pytest.mark.parametrize("dataset", sorted(KITTI_FOLDERS))
def test_kitti_flat_layout_under_parent_without_noc(tmp_path, rng, dataset):
    left, right, occ_dir, _ = KITTI_FOLDERS[dataset]
    base = tmp_path / "kitti" / dataset[-4:]
    views(base, (f"{left}/000000_10.png", f"{right}/000000_10.png"), rng)
    write_grey(base / occ_dir / "000000_10.png", kitti_gt()[0])
    scene = only(DATASETS[dataset](tmp_path))
    assert scene.name == "000000_10" and scene.nonocc is None


# --- any folder ---------------------------------------------------------------------------

def test_folder_reader_matches_stems_and_formats(tmp_path, rng):
    grey = rng.integers(0, 256, (H, W), dtype=np.uint8)
    write_grey(tmp_path / "left" / "a.png", grey)
    write_rgb(tmp_path / "right" / "a.bmp", texture(rng))
    gt_a = np.full((H, W), 4.25, dtype=np.float32)
    gt_a[0, 0] = np.nan
    (tmp_path / "gt").mkdir()
    np.save(tmp_path / "gt" / "a.npy", gt_a)
    views(tmp_path, ("left/b.png", "right/b.png"), rng)
    write_pfm(tmp_path / "gt" / "b.pfm", np.full((H, W), np.inf, dtype=np.float32))
    reader = DATASETS["folder"]
    assert reader.scene_names(tmp_path) == ["a", "b"]
    a, b = reader(tmp_path)
    np.testing.assert_array_equal(a.left, np.repeat(grey[:, :, None], 3, axis=2) / np.float32(255))
    np.testing.assert_array_equal(a.disparity, gt_a)
    assert a.nonocc is None and a.max_disp == 16 and a.resolution == "18x12"
    assert np.isnan(b.disparity).all() and b.max_disp == 16


def test_folder_reader_missing_partner_file_is_an_error(tmp_path, rng):
    views(tmp_path, ("left/a.png", "right/a.png"), rng)
    views(tmp_path, ("left/b.png", "right/b.png"), rng)
    write_pfm(tmp_path / "gt" / "a.pfm", np.ones((H, W), np.float32))
    with pytest.raises(CadeError, match=r"gt has no file for b \(found in left/\)"):
        DATASETS["folder"].scene_names(tmp_path)


def test_folder_reader_size_mismatch_is_an_error(tmp_path, rng):
    views(tmp_path, ("left/a.png", "right/a.png"), rng)
    write_pfm(tmp_path / "gt" / "a.pfm", np.ones((H, W + 1), np.float32))
    with pytest.raises(CadeError, match="scene a: .* sizes differ"):
        list(DATASETS["folder"](tmp_path))


# --- laziness and errors ------------------------------------------------------------------

def test_scene_names_reads_no_image_and_iteration_loads_one_at_a_time(tmp_path, rng):
    encoded = np.full((2, 460), 12, dtype=np.uint8)
    middlebury_2view(tmp_path / "Art", rng, width=460, left_gt=encoded, right_gt=encoded)
    for name in ("view1.png", "view5.png", "disp1.png", "disp5.png"):
        (tmp_path / "Broken" / name).parent.mkdir(exist_ok=True)
        (tmp_path / "Broken" / name).write_bytes(b"not a png")
    reader = DATASETS["middlebury05"]
    assert reader.scene_names(tmp_path) == ["Art", "Broken"]
    scenes = reader(tmp_path)            # no file read yet
    assert next(scenes).name == "Art"
    with pytest.raises(CadeError, match="Broken"):
        next(scenes)


@pytest.mark.parametrize("dataset", sorted(DATASETS))
def test_missing_root_is_an_error(tmp_path, dataset):
    with pytest.raises(CadeError, match="does not exist.*--data-dir"):
        DATASETS[dataset].scene_names(tmp_path / "nowhere")


@pytest.mark.parametrize(("dataset", "expected"), [
    ("middlebury05", "view1.png"), ("middlebury14", "disp0GT.pfm"), ("flyingthings3d", "frames_cleanpass"),
    ("kitti2015", "image_2"), ("kitti2012", "colored_0"), ("msir-outdoor", "corners.npy"),
    ("folder", "left, right, gt"),
])
def test_no_scenes_names_the_expected_layout(tmp_path, dataset, expected):
    (tmp_path / "unrelated").mkdir()
    with pytest.raises(CadeError, match=f"no {dataset} scenes found in .*expected .*{expected}"):
        list(DATASETS[dataset](tmp_path))


def test_unknown_scene_lists_available_before_loading(tmp_path, rng):
    encoded = np.full((2, 460), 12, dtype=np.uint8)
    middlebury_2view(tmp_path / "Art", rng, width=460, left_gt=encoded, right_gt=encoded)
    with pytest.raises(CadeError, match="unknown middlebury05 scene.* Cones in .*; available: Art$"):
        DATASETS["middlebury05"](tmp_path, scenes=["Cones"])


def test_resolution_option_on_a_dataset_without_one(tmp_path):
    with pytest.raises(CadeError, match="drop the resolution option"):
        DATASETS["kitti2015"].scene_names(tmp_path, resolution="Q")


# --- the development data -----------------------------------------------------------------

def test_shared_middlebury05_is_thirdsize(shared_data):
    scenes = list(DATASETS["middlebury05"](shared_data))
    assert [s.name for s in scenes] == ["Art", "Books", "Dolls", "Laundry", "Moebius", "Reindeer"]
    for scene in scenes:
        assert scene.resolution == "ThirdSize" and scene.left.shape[0] == 370
        assert scene.left.shape == scene.right.shape == (*scene.disparity.shape, 3)
        top = np.nanmax(scene.disparity)
        assert 40 < top <= 80 and scene.max_disp >= top
        assert 0.6 < scene.nonocc.mean() < 0.95 and np.isfinite(scene.disparity[scene.nonocc]).all()


def test_shared_middlebury14_gt_within_calib_bounds(shared_data):
    scenes = list(DATASETS["middlebury14"](shared_data))
    assert [s.name for s in scenes] == ["Adirondack", "ArtL", "Jadeplant", "Motorcycle", "Piano", "Pipes",
                                        "Playroom", "Playtable"]
    for scene in scenes:
        finite = scene.disparity[np.isfinite(scene.disparity)]
        assert scene.resolution == "Q" and scene.left.shape == scene.right.shape == (*scene.disparity.shape, 3)
        assert scene.metadata["vmin"] - 1 <= finite.min() and finite.max() <= scene.metadata["vmax"] + 1
        assert scene.max_disp == scene.metadata["ndisp"] - 1 >= finite.max()
        assert 0.5 < scene.nonocc.mean() < 1 and np.isfinite(scene.disparity[scene.nonocc]).all()


def test_shared_flyingthings3d_is_dense(shared_data):
    scenes = list(DATASETS["flyingthings3d"](shared_data))
    assert [s.name for s in scenes] == ["TEST/A/0000/0006", "TEST/B/0149/0015", "TRAIN/A/0000/0006",
                                        "TRAIN/B/0749/0015"]
    for scene in scenes:
        assert scene.left.shape == scene.right.shape == (540, 960, 3) and scene.resolution == "960x540"
        assert np.isfinite(scene.disparity).all() and scene.disparity.min() > 0
        assert scene.max_disp >= scene.disparity.max()


@pytest.mark.parametrize("dataset", ["kitti2015", "kitti2012"])
def test_shared_kitti_is_sparse_and_plausible(shared_data, dataset):
    scenes = list(DATASETS[dataset](shared_data))
    assert [s.name for s in scenes] == ["000000_10", "000001_10"]
    for scene in scenes:
        known = np.isfinite(scene.disparity)
        assert scene.left.shape == scene.right.shape == (*scene.disparity.shape, 3)
        assert 0.05 < known.mean() < 0.6
        assert 0 < scene.disparity[known].min() and scene.disparity[known].max() < 256
