"""Every multi-lens camera (docs/drone.md, "Other cameras"): bands of other sizes (a
panchromatic band at twice the size, a 160x120 thermal band) registered onto the reference grid
with each band's own lens, or left out by --bands; DJI's drone-dji tags (P4 Multispectral,
Mavic 3M) read from files written with them; a RedEdge-MX Dual's second camera, whose
RigRelatives refer to its own Green-531, turned by the rotation measured from the images. Every
capture is rendered from a known rig over a far terrain: the true position of each reference
pixel in each band is known, so the registration's sampling maps are scored against it."""

from __future__ import annotations

import numpy as np
import pytest

from capture_scenes import DJI_NAMES, altum_like, dji_like, dual_like, write_rig_capture
from cli_runner import run_cade
from cade_cli.capture.lens import BrownLens
from cade_cli.capture.metadata import read_band_file
from cade_cli.capture.model import load_capture, parse_bands
from cade_cli.capture.register import register_capture
from cade_cli.errors import CadeError


def errors_in_band_pixels(capture, registration, truth, *, margin: int = 4):
    """Per band: the distances (in that band's own pixels) between where each valid output
    pixel was sampled and where its ground point truly is, on pixels whose truth lies inside."""
    found = {}
    for band, (u, v), valid in zip(capture.bands, registration.sampled, registration.valid):
        tu, tv = truth[band.name]
        width, height = band.size
        inside = (tu > margin) & (tu < width - 1 - margin) & (tv > margin) & (tv < height - 1 - margin)
        found[band.name] = (np.hypot(u - tu, v - tv)[valid & inside], (valid & inside).sum() / inside.sum())
    return found


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two rotations."""
    return float(np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1) / 2, -1, 1))))


@pytest.fixture(scope="module")
def altum(tmp_path_factory):
    """Green and Red at 512x384, a panchromatic band at 1024x768 and a thermal band at 160x120."""
    cameras = altum_like((512, 384))[1:]
    return write_rig_capture(tmp_path_factory.mktemp("altum"), np.random.default_rng(11), cameras)


def test_bands_of_other_sizes_are_registered_onto_the_reference_grid(altum):
    capture = load_capture(altum.paths)
    assert [(band.name, band.size) for band in capture.bands] == [
        ("Green", (512, 384)), ("Red", (512, 384)), ("Panchro", (1024, 768)), ("LWIR", (160, 120))]
    registration = register_capture(capture, keep_sampled=True)
    assert {r.name: r.path for r in registration.results} == {"Green": "reference", "Red": "plane",
                                                              "Panchro": "plane", "LWIR": "rig"}
    assert all(band.shape == (384, 512) for band in registration.bands)  # every band on the reference's grid
    for name, (errors, kept) in errors_in_band_pixels(capture, registration, altum.truth).items():
        # the known displacement (lens rotation, own principal point, distortion and scale) recovered
        assert kept > 0.99 and np.median(errors) < 0.15 and np.percentile(errors, 99) < 0.4, name
    pan = registration.sampled[2]  # a reference pixel samples the 2x band about 2 of its pixels apart
    assert 1.9 < np.median(np.diff(pan[0], axis=1)) < 2.1


def test_bands_leaves_a_band_out_with_a_note(altum, tmp_path, capsys):
    assert parse_bands(" Green, Red ,Panchro") == ("Green", "Red", "Panchro") and parse_bands("") is None
    capture = load_capture(altum.paths, bands=("green", "Red", "PANCHRO"))
    assert capture.names() == ["Green", "Red", "Panchro"] and [b.name for b in capture.left_out] == ["LWIR"]
    with pytest.raises(CadeError, match=r"--bands 'Thermal'.*its bands: Green, Red, Panchro, LWIR"):
        load_capture(altum.paths, bands=("Green", "Thermal"))
    with pytest.raises(CadeError, match="a capture needs two"):
        load_capture(altum.paths, bands=("Green",))
    code, _, err = run_cade(["register-capture", *altum.paths, "-o", tmp_path / "all.tif", "--plane-only"], capsys)
    assert code == 0 and "4 bands onto Green" in err and "LWIR: rig" in err, err
    assert "note: LWIR: too coarse to match" in err
    output = tmp_path / "cube.tif"
    code, _, err = run_cade(["register-capture", *altum.paths, "-o", output, "--plane-only", "--bands",
                             "Green,Red,Panchro"], capsys)
    assert code == 0, err
    assert "note: LWIR: left out by --bands" in err and "3 bands onto Green" in err
    code, _, err = run_cade(["register-capture", *altum.paths, "-o", tmp_path / "x.tif", "--bands", "Green,Blu"],
                            capsys)
    assert code != 0 and len(err.strip().splitlines()) == 1 and "--bands 'Blu'" in err
    assert not (tmp_path / "x.tif").exists()


@pytest.mark.parametrize("style", ["p4m", "m3m"])
def test_dji_tags_are_read_and_registered(tmp_path, style):
    cameras = dji_like((320, 240))
    scene = write_rig_capture(tmp_path / style, np.random.default_rng(5), cameras, style=style, capture_id="UUID7")
    bands = [read_band_file(path) for path in scene.paths]
    assert [(b.name, b.wavelength, b.fwhm, b.rig_index) for b in bands] == [
        ("Blue", 450, 32, 1), ("Green", 560, 32, 2), ("Red", 650, 32, 3), ("RedEdge", 730, 32, 4), ("NIR", 840, 52, 5)]
    nir = cameras[4]
    for band, camera in zip(bands, cameras):
        assert band.capture_id == "UUID7" and band.camera.startswith("DJI")
        assert isinstance(band.lens, BrownLens) and np.allclose(band.lens.K, camera.K)
        assert np.allclose([band.lens.k1, band.lens.k2, band.lens.k3, band.lens.p1, band.lens.p2], camera.dist)
        # the rotation against NIR (DJI's reference) as the tags give it
        assert rotation_angle(band.rotation @ bands[4].rotation.T, camera.R @ nir.R.T) < 0.01, band.name
        assert band.radiometry == {"irradiance": 1234.5, "sensor_gain": 1.5, "gain_adjustment": 1.002,
                                   "black_current": 4096.0, "exposure_s": 0.001,
                                   "vignetting": [0.000218, 1.2e-06, -2.8e-09, 5.1e-12, -4.1e-15, 1.3e-18]}
    capture = load_capture(scene.paths)
    assert capture.reference_band.name == "Green"
    registration = register_capture(capture, keep_sampled=True)
    truth = {DJI_NAMES[name][0]: where for name, where in scene.truth.items()}
    for name, (errors, kept) in errors_in_band_pixels(capture, registration, truth).items():
        assert kept > 0.99 and np.percentile(errors, 99) < 0.3, name


def test_the_dual_cameras_second_body_is_turned_by_its_measured_rotation(tmp_path):
    group = (0.6, -0.5, 0.9)
    cameras = dual_like((320, 240), group=group)
    scene = write_rig_capture(tmp_path / "dual", np.random.default_rng(8), cameras, model="RedEdge-M")
    capture = load_capture(scene.paths)
    assert len(capture.bands) == 10 and capture.bands[6].name == "Green-531"
    assert [b.rotation_reference for b in capture.bands] == [1] * 5 + [6] * 5
    # as read, Green-531's RigRelatives are 0, 0, 0: relative to itself, not to Green
    assert np.allclose(capture.bands[6].rotation, np.eye(3))
    registration = register_capture(capture, keep_sampled=True)
    linked = registration.capture.linked
    true_angle = rotation_angle(cameras[6].R, cameras[1].R)
    assert [name for name, _ in linked] == ["Green-531"] and abs(linked[0][1] - true_angle) < 0.05
    for band, camera in zip(registration.capture.bands, cameras):  # every band's rotation now against Green
        assert rotation_angle(band.rotation, camera.R) < 0.05, band.name
    for name, (errors, kept) in errors_in_band_pixels(registration.capture, registration, scene.truth).items():
        assert kept > 0.98 and np.percentile(errors, 99) < 0.3, name


def test_a_second_camera_without_its_reference_band_is_one_line(tmp_path):
    scene = write_rig_capture(tmp_path / "dual", np.random.default_rng(9), dual_like((96, 72)), model="RedEdge-M")
    capture = load_capture(scene.paths, bands=("Blue", "Green", "Red", "Blue-444", "Red-650"))
    with pytest.raises(CadeError, match="refer to rig camera 6, which is not in the capture"):
        register_capture(capture, plane_only=True)


def test_a_near_dual_capture_keeps_the_tags_rotations(tmp_path):
    """Near the ground the homography between the two bodies' reference bands holds their
    parallax too: no rotation is measured, the tags' are kept, and the capture says so."""
    from cade_cli.capture.cameras import first_camera_parallax, link_cameras
    from cade_cli.capture.register import read_raw

    scene = write_rig_capture(tmp_path / "near", np.random.default_rng(12), dual_like((240, 180)), depth=1.5,
                              hill=0.2, model="RedEdge-M")
    capture = load_capture(scene.paths)
    signal = [image.astype(np.float32) - np.float32(band.black_level) for image, band in zip(read_raw(capture),
                                                                                           capture.bands)]
    assert first_camera_parallax(capture, signal) > 5  # a 4 cm baseline at 1.5 m: about 8 px
    linked = link_cameras(capture, signal)
    assert linked.linked == (("Green-531", None),) and linked.first_camera_parallax > 5
    assert all(np.array_equal(a.rotation, b.rotation) for a, b in zip(linked.bands, capture.bands))
