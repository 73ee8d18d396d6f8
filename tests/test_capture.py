"""cade register-capture: the band files' metadata (real captures when present, a tag removed),
and a synthetic five-band capture rendered from a known rig over a known height map, registered
within half a pixel; the plane-only and cheap paths; the files written; the dense search's reach
beyond the nearest match (``--near``)."""

from __future__ import annotations

import inspect
import json
import shutil

import numpy as np
import pytest
import tifffile

from capture_scenes import BLACK_LEVEL, write_capture
from cli_runner import run_cade
from cade_cli.capture.lens import BrownLens, FisheyeLens
from cade_cli.capture.metadata import read_band_file
from cade_cli.capture.model import load_capture
from cade_cli.capture.parallax import Parallax
from cade_cli.capture.register import NEAR_FACTOR, NEAR_LIMIT, register_capture, saturation_level, search_range
from cade_cli.errors import CadeError

MICASENSE = {"rededge-m-bench": ["IMG_0001", "IMG_0007"], "rededge-m-field": ["IMG_0008"]}
REDEDGE_BANDS = [("Blue", 475, 0), ("Green", 560, 1), ("Red", 668, 2), ("NIR", 840, 3), ("Red edge", 717, 4)]
SEQUOIA_BANDS = {"GRE": ("Green", 550, 0), "RED": ("Red", 660, 1), "REG": ("Red edge", 735, 2),
                 "NIR": ("NIR", 790, 3)}


def border_error(capture, registration, truth, *, margin: int = 8):
    """Per band: (errors px on the valid pixels whose true match lies inside the band, share of
    those pixels kept valid)."""
    width, height = capture.size
    scores = {}
    for band, (u, v), valid in zip(capture.bands, registration.sampled, registration.valid):
        tu, tv = truth[band.name]
        inside = (tu > margin) & (tu < width - 1 - margin) & (tv > margin) & (tv < height - 1 - margin)
        scores[band.name] = (np.hypot(u - tu, v - tv)[valid & inside], (valid & inside).sum() / inside.sum())
    return scores


def test_every_real_band_file_is_read(shared_data):
    folder = shared_data / "micasense"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    for sub, shots in MICASENSE.items():
        for shot in shots:
            bands = [read_band_file(folder / sub / f"{shot}_{k}.tif") for k in range(1, 6)]
            assert [(b.name, b.wavelength, b.rig_index) for b in bands] == REDEDGE_BANDS
            assert len({b.capture_id for b in bands}) == 1 and bands[0].capture_id
            for band in bands:
                assert band.camera == "MicaSense RedEdge-M" and band.size == (1280, 960)
                assert band.black_level == 4800
                assert isinstance(band.lens, BrownLens) and 1400 < band.lens.focal < 1470
                assert np.allclose(band.rotation @ band.rotation.T, np.eye(3))
                assert band.calibration_picture is None  # MicaSense tags no panel shot
            assert np.allclose(bands[1].rotation, np.eye(3))  # Green is the rig reference
    for path in sorted((folder / "sequoia-tabletop").glob("*.TIF")):
        band = read_band_file(path)
        assert (band.name, band.wavelength, band.rig_index) == SEQUOIA_BANDS[path.stem.split("_")[-1]]
        assert isinstance(band.lens, FisheyeLens) and 1050 < band.lens.focal < 1070
        assert 4900 < band.black_level < 5800
        assert band.calibration_picture == 0  # Camera:CalibrationPicture="0": not a panel shot
    capture = load_capture(sorted((folder / "sequoia-tabletop").glob("*.TIF")))
    assert capture.reference_band.name == "Green" and capture.names() == ["Green", "Red", "Red edge", "NIR"]
    _, (width, height) = capture.frame  # the fisheye's corners, undistorted, reach beyond the raw size
    assert 1280 < width <= 1.5 * 1280 and 960 < height <= 1.5 * 960


def test_lens_models_invert():
    x, y = np.meshgrid(np.linspace(-0.45, 0.45, 31), np.linspace(-0.35, 0.35, 23))
    for lens in (BrownLens(1450, (650, 480), -0.11, 0.19, -0.14, -1e-4, 4e-4),
                 FisheyeLens(1061, (620, 480), (0, 1, 0.0096, -0.145), (1660, 0, 0, 1660))):
        u, v = lens.pixels(x, y)
        back_x, back_y = lens.rays(u, v)
        assert np.abs(back_x - x).max() * lens.focal < 1e-3 and np.abs(back_y - y).max() * lens.focal < 1e-3


def test_saturation_level_follows_the_bit_depth():
    assert saturation_level(np.array([16, 4800, 65520], np.uint16)) == 65520  # 12 bit scaled by 16
    assert saturation_level(np.array([64, 65472], np.uint16)) == 65472  # 10 bit scaled by 64
    assert saturation_level(np.array([3, 5], np.uint16)) == 65535


def test_a_synthetic_capture_is_registered_within_half_a_pixel(tmp_path, rng):
    scene = write_capture(tmp_path / "shot", rng)
    capture = load_capture(scene.paths[::-1])  # any order
    assert capture.names() == ["Blue", "Green", "Red", "NIR", "Red edge"] and capture.reference_band.name == "Green"
    registration = register_capture(capture, scale=1.0, keep_sampled=True)
    paths = {result.name: result.path for result in registration.results}
    assert paths == {"Blue": "parallax", "Green": "reference", "Red": "parallax", "NIR": "parallax",
                     "Red edge": "parallax"}
    for camera, result in zip(scene.cameras, registration.results):
        if result.search is not None:  # the range searched is the widened one (NEAR_FACTOR by default)
            assert result.search == search_range(result.parallax) != search_range(result.parallax, 1.0)
        if result.parallax is not None:  # the lens lies opposite its translation (X_band = X_ref + t)
            expected = -np.asarray(camera.translation[:2]) / np.hypot(*camera.translation[:2])
            assert result.parallax.baseline @ expected > np.cos(np.radians(2))
    for name, (errors, kept) in border_error(capture, registration, scene.truth).items():
        assert kept > 0.95, name
        assert np.mean(errors <= 0.5) > 0.98 and np.median(errors) < 0.25, name
    plane = register_capture(capture, plane_only=True, keep_sampled=True)
    assert {r.path for r in plane.results} == {"reference", "plane-only"}
    worse = border_error(capture, plane, scene.truth)
    assert all(np.mean(errors <= 0.5) < 0.9 for name, (errors, _) in worse.items() if name != "Green")


def test_a_far_capture_takes_the_cheap_path(tmp_path, rng):
    scene = write_capture(tmp_path / "far", rng, depth=300.0, hill=1.0)
    capture = load_capture(scene.paths)
    registration = register_capture(capture, keep_sampled=True)
    assert [r.path for r in registration.results] == ["plane", "reference", "plane", "plane", "plane"]
    for name, (errors, kept) in border_error(capture, registration, scene.truth).items():
        assert kept > 0.99 and np.percentile(errors, 99) < 0.2, name


def test_the_command_writes_the_cube_and_its_pictures(tmp_path, rng, capsys):
    scene = write_capture(tmp_path / "shot", rng, size=(320, 240), saturate=True)
    output, vis, ndvi, per_band = tmp_path / "IMG_0001.tif", tmp_path / "fc.png", tmp_path / "ndvi.png", tmp_path / "pb"
    code, _, err = run_cade(["register-capture", *scene.paths, "-o", output, "--vis", vis, "--ndvi", ndvi,
                             "--per-band", per_band], capsys)
    assert code == 0, err
    assert "5 bands onto Green" in err and "s per capture" in err
    with tifffile.TiffFile(output) as tiff:
        assert len(tiff.pages) == 1 and tiff.pages[0].samplesperpixel == 5  # one image of 5 samples (GDAL bands)
        description = json.loads(tiff.pages[0].description)
        assert [b["wavelength_nm"] for b in description["bands"]] == [475, 560, 668, 840, 717]
        cube = tiff.asarray()
    assert cube.dtype == np.float32 and cube.shape == (5, 240, 320)
    raw_green = tifffile.imread(scene.paths[1])
    saturated = raw_green == 65520
    assert np.array_equal(cube[1][~saturated], raw_green[~saturated].astype(np.float32))  # not resampled
    assert np.isposinf(cube[1][saturated]).all()
    assert np.isnan(cube[0]).any() and np.isfinite(cube[0]).mean() > 0.8  # borders not seen
    assert vis.stat().st_size > 0 and ndvi.stat().st_size > 0
    assert sorted(p.name for p in per_band.iterdir()) == [p.name for p in scene.paths]
    assert b"Camera:BandName>NIR<" in tifffile.TiffFile(per_band / "IMG_0001_4.tif").pages[0].tags[700].value

    code, _, err = run_cade(["register-capture", *scene.paths, "-o", tmp_path / "u16.tif", "--dtype", "uint16",
                             "--plane-only"], capsys)
    assert code == 0, err
    values, mask = tifffile.imread(tmp_path / "u16.tif"), tifffile.imread(tmp_path / "u16.valid.tif")
    assert values.dtype == np.uint16 and mask.shape == (5, 240, 320)
    assert np.array_equal(values[1], raw_green)  # the reference keeps its values, saturation included
    assert (values[0][mask[0] == 0] == 0).all() and values[0][mask[0] == 255].min() >= BLACK_LEVEL - 16


@pytest.mark.parametrize("tag, option", [("Camera:RigRelatives", "--rig"), ("Camera:BandName", "camera's own"),
                                         ("Camera:PerspectiveDistortion", "--rig")])
def test_a_missing_tag_is_one_line_and_nothing_is_written(tmp_path, rng, capsys, tag, option):
    scene = write_capture(tmp_path / "shot", rng, size=(64, 48), drop=("Red", tag))
    with pytest.raises(CadeError, match=tag):
        load_capture(scene.paths)
    output = tmp_path / "cube.tif"
    code, _, err = run_cade(["register-capture", *scene.paths, "-o", output], capsys)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and tag in lines[0] and option in lines[0] and "IMG_0001_3.tif" in lines[0]
    assert not output.exists() and not list(tmp_path.glob(".*tmp*"))


def test_bad_captures_are_refused(tmp_path, rng, capsys):
    scene = write_capture(tmp_path / "shot", rng, size=(64, 48))
    other = write_capture(tmp_path / "other", rng, size=(64, 48))
    with pytest.raises(CadeError, match="same band"):
        load_capture([scene.paths[0], other.paths[0], scene.paths[1]])
    with pytest.raises(CadeError, match="--reference"):
        load_capture(scene.paths, reference="Thermal")
    assert load_capture(scene.paths, reference="nir").reference_band.name == "NIR"
    copy = tmp_path / "copy.tif"
    shutil.copy(scene.paths[0], copy)
    code, _, err = run_cade(["register-capture", copy, "-o", tmp_path / "x.png"], capsys)
    assert code != 0 and len(err.strip().splitlines()) == 1
    before = scene.paths[0].read_bytes()
    code, _, err = run_cade(["register-capture", *scene.paths, "-o", tmp_path / "x.tif", "--per-band",
                             scene.paths[0].parent, "--plane-only"], capsys)
    assert code != 0 and "--per-band" in err and scene.paths[0].read_bytes() == before


def test_a_rig_file_supplies_what_the_files_lack(tmp_path, rng, capsys):
    scene = write_capture(tmp_path / "shot", rng, drop=("Red", "Camera:PerspectiveDistortion"))
    cameras = [{"name": c.name.replace(" ", "-"), "band": c.name, "image_size": [320, 240], "K": c.K.tolist(),
                "dist": c.opencv_dist.tolist(), "R": c.R.tolist(), "t": list(c.translation)} for c in scene.cameras]
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({"format": "cade-rig", "version": 1, "reference": "Green", "cameras": cameras}))
    from cade_cli.rigs.rig_file import load_rig

    capture = load_capture(scene.paths, rig=load_rig(rig))
    red = capture.bands[2]
    assert red.lens.k1 == scene.cameras[2].dist[0] and np.allclose(red.rotation, scene.cameras[2].R)
    code, _, err = run_cade(["register-capture", *scene.paths, "-o", tmp_path / "cube.tif", "--rig", rig,
                             "--plane-only"], capsys)
    assert code == 0, err
    assert tifffile.imread(tmp_path / "cube.tif").shape == (5, 240, 320)


def test_only_small_unmatched_areas_count_as_seen():
    from cade_cli.capture.register import small_holes

    trusted = np.ones((100, 100), bool)
    trusted[10:13, 10:13] = False  # 9 px: 0.09 % of the image
    trusted[50:90, 20:80] = False  # 2400 px: 24 %
    holes = small_holes(trusted, share=0.002)
    assert holes[10:13, 10:13].all() and not holes[50:90, 20:80].any() and not holes[trusted].any()


def _matched(low: float, high: float) -> Parallax:
    """A band whose sparse matches measured parallax ``low`` .. ``high`` px."""
    return Parallax(np.array([1.0, 0.0]), np.zeros(3), low, high, 1.0, 100)


def test_the_search_reaches_near_objects_the_matches_miss():
    bench = _matched(6.9, 11.6)  # IMG_0007's Red edge: the matches' range; a cable lies at 39-42 px
    assert search_range(bench, 1.0) == (2, 20)  # the matches' range widened by its margins alone
    assert search_range(bench) == search_range(bench, NEAR_FACTOR) == (2, 47)  # ceil(4 x 11.6)
    assert search_range(bench, 1.5) == (2, 20)  # 1.5 x 11.6 = 17.4 lies inside: never lowered
    assert search_range(_matched(50.0, 60.0)) == (46, NEAR_LIMIT)  # 4 x 60 = 240: capped
    assert search_range(_matched(160.0, 170.0)) == search_range(_matched(160.0, 170.0), 1.0) == (156, 180)


def test_near_defaults_to_near_factor_and_below_1_is_refused_in_one_line(tmp_path, rng, capsys):
    from cade_cli.cli.batch import batch
    from cade_cli.cli.capture import register_capture as command

    for function in (command, batch):
        assert inspect.signature(function).parameters["near"].default == NEAR_FACTOR
    scene = write_capture(tmp_path / "shot", rng, size=(64, 48))
    with pytest.raises(CadeError, match="at least 1"):
        register_capture(load_capture(scene.paths), near=0.5)
    output = tmp_path / "cube.tif"
    for value in ("0.5", "nan"):
        code, _, err = run_cade(["register-capture", *scene.paths, "-o", output, "--near", value], capsys)
        lines = err.strip().splitlines()
        assert code != 0 and len(lines) == 1 and ("--near" in lines[0] or "near factor" in lines[0]), err
        assert "Traceback" not in err and not output.exists()
