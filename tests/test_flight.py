"""A flight never lies (cade batch --captures): a capture missing one of its camera's bands fails
alone, naming the band, and the summary says so; files cade wrote are never taken as inputs; a
rerun removes the side outputs of options no longer asked for; every bad TIFF is one line naming
it; --reference and --bands are checked once per flight; a note every capture shares is shown
once with a count. Synthetic far captures (the cheap plane path) of 96x72 px."""

from __future__ import annotations

import json
import math
import re
import shutil
import struct

import numpy as np
import pytest
import tifffile

from capture_scenes import BLACK_LEVEL, dji_like, write_capture, write_rig_capture
from cli_runner import run_cade
from cade_cli.capture.flight import group_captures

SIZE = (96, 72)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Three far captures (every band registered by its plane: a note each) written once."""
    folder = tmp_path_factory.mktemp("far") / "flight"
    rng = np.random.default_rng(21)
    for number in (1, 2, 3):
        write_capture(folder, rng, size=SIZE, name=f"IMG_000{number}", capture_id=f"C{number}", depth=300.0, hill=1.0)
    return folder


@pytest.fixture
def flight(rendered, tmp_path):
    folder = tmp_path / "flight"
    shutil.copytree(rendered, folder)
    return folder


def batch(folder, output, capsys, *options):
    return run_cade(["batch", "--captures", folder, "-o", output, *options], capsys)


def test_a_capture_missing_a_band_fails_alone_naming_it(flight, tmp_path, capsys):
    (flight / "IMG_0002_3.tif").unlink()  # Red
    code, stdout, err = batch(flight, tmp_path / "cubes", capsys, "--plane-only")
    assert code == 1 and "2 done, 0 already finished, 1 failed, of 3 captures" in stdout
    assert "warning: capture IMG_0002 failed: no Red (rig index 2) band file" in err
    assert sorted(p.name for p in (tmp_path / "cubes").glob("*.tif")) == ["IMG_0001.tif", "IMG_0003.tif"]
    # a flight of that one capture alone: its camera model's band set says what is missing
    alone = tmp_path / "alone"
    alone.mkdir()
    for path in flight.glob("IMG_0002_*.tif"):
        shutil.copy(path, alone)
    code, stdout, err = batch(alone, tmp_path / "alone-cubes", capsys, "--plane-only")
    assert code == 1 and "0 done, 0 already finished, 1 failed, of 1 captures" in stdout and "no Red" in err
    assert not list((tmp_path / "alone-cubes").glob("*.tif"))


def test_missing_bands_come_from_the_metadata_not_a_count(tmp_path):
    """A camera model cade has no table for: the other captures of the same body, and the rig
    indices a capture's own bands refer to, name what is missing."""
    rng = np.random.default_rng(4)
    for number in (1, 2, 3):
        write_capture(tmp_path, rng, size=(48, 36), name=f"IMG_000{number}", capture_id=f"C{number}")
    for path in tmp_path.glob("*.tif"):  # another model name: no table
        with tifffile.TiffFile(path, mode="r+b") as tiff:
            tiff.pages[0].tags[272].overwrite("RedEdge-Z")
    (tmp_path / "IMG_0001_5.tif").unlink()  # Red edge, the last rig index: only the other captures tell
    (tmp_path / "IMG_0003_4.tif").unlink()  # NIR, a gap in the rig indices
    captures = {capture.name: capture.problem for capture in group_captures(tmp_path)[0]}
    assert captures["IMG_0002"] is None
    assert captures["IMG_0001"].startswith("no Red edge (rig index 4) band file: the flight's other")
    assert captures["IMG_0003"].startswith("no NIR (rig index 3) band file")


def test_files_cade_wrote_are_never_inputs(flight, capsys):
    # the cubes, masks and per-band files of a first run inside the flight folder, and a
    # register-capture's per-band files there too: a second run groups only the camera's files
    code, _, err = batch(flight, flight / "cubes", capsys, "--plane-only", "--dtype", "uint16")
    assert code == 0, err
    code, _, err = run_cade(["register-capture", *sorted(flight.glob("IMG_0001_*.tif")), "-o", flight / "one.tif",
                             "--plane-only", "--per-band", flight / "aligned"], capsys)
    assert code == 0, err
    code, stdout, err = batch(flight, flight / "again", capsys, "--plane-only")
    assert code == 0 and "3 done, 0 already finished, 0 failed, of 3 captures" in stdout, err
    assert "TIFF(s) written by cade" in err and "left out" in err
    assert sorted(p.name for p in (flight / "again").glob("*.tif")) == ["IMG_0001.tif", "IMG_0002.tif",
                                                                      "IMG_0003.tif"]
    captures, _ = group_captures(flight)
    assert sorted(len(capture.paths) for capture in captures) == [5, 5, 5]


def test_a_rerun_removes_the_side_outputs_it_no_longer_writes(flight, tmp_path, capsys):
    out = tmp_path / "cubes"
    code, _, err = batch(flight, out, capsys, "--plane-only", "--dtype", "uint16", "--ndvi", "--vis")
    assert code == 0, err
    assert {p.name for p in out.iterdir() if p.name.startswith("IMG_0001")} == {
        "IMG_0001.tif", "IMG_0001.valid.tif", "IMG_0001_ndvi.png", "IMG_0001_vis.png", "IMG_0001.tif.cade.json"}
    (out / "keep_me.png").write_bytes(b"not cade's")
    code, stdout, err = batch(flight, out, capsys, "--plane-only")
    assert code == 0 and "3 done" in stdout, err
    assert {p.name for p in out.iterdir() if p.name.startswith("IMG_0001")} == {"IMG_0001.tif",
                                                                               "IMG_0001.tif.cade.json"}
    assert (out / "keep_me.png").read_bytes() == b"not cade's"
    assert not list(out.glob("*.valid.tif")) and not list(out.glob("*_vis.png")) and not list(out.glob("*_ndvi.png"))


def test_every_bad_tiff_is_one_line_naming_it(flight, tmp_path, capsys):
    source = (flight / "IMG_0001_1.tif").read_bytes()
    (flight / "cut.tif").write_bytes(source[:300])
    (flight / "text.tif").write_bytes(b"this is no TIFF at all")
    (flight / "beyond.tif").write_bytes(b"II*\x00" + struct.pack("<I", 10**6) + bytes(64))  # first IFD past the end
    tifffile.imwrite(flight / "plain.tif", np.zeros((8, 8), np.uint16))  # no XMP
    code, stdout, err = batch(flight, tmp_path / "cubes", capsys, "--plane-only")
    assert code == 0 and "3 done" in stdout, err
    lines = err.strip().splitlines()
    for name in ("cut.tif", "text.tif", "beyond.tif", "plain.tif"):
        assert len([line for line in lines if name in line]) == 1, (name, err)
    assert "tifffile" not in err.lower() and "warning:" not in err.lower() and "Traceback" not in err


def test_options_are_checked_once_per_flight(flight, tmp_path, capsys):
    for option, value, message in (("--reference", "Blu", "--reference 'Blu'"), ("--bands", "Green,Infrared",
                                                                                  "--bands 'Infrared'")):
        code, stdout, err = batch(flight, tmp_path / "cubes", capsys, "--plane-only", option, value)
        lines = err.strip().splitlines()
        assert code != 0 and len(lines) == 1 and message in lines[0], err
        assert "its bands: Blue, Green, Red, NIR, Red edge" in lines[0] and not stdout
        assert not list((tmp_path / "cubes").glob("*.tif"))
    code, stdout, err = batch(flight, tmp_path / "cubes", capsys, "--plane-only", "--bands", "Green,Red", "--ndvi")
    assert code != 0 and len(err.strip().splitlines()) == 1 and "--ndvi needs the NIR, Red bands" in err
    assert not list((tmp_path / "cubes").glob("*.tif"))
    code, stdout, err = batch(flight, tmp_path / "cubes", capsys, "--plane-only", "--bands", "Green,Red,NIR")
    assert code == 0 and "3 done" in stdout, err
    assert tifffile.imread(tmp_path / "cubes" / "IMG_0001.tif").shape[0] == 3
    assert err.count("Blue, Red edge: left out by --bands (3 of 3 captures") == 1


def test_a_changed_near_factor_redoes_the_flight_and_below_1_is_refused(flight, tmp_path, capsys):
    cubes = tmp_path / "cubes"
    code, stdout, err = batch(flight, cubes, capsys, "--near", "2")
    assert code == 0 and "3 done" in stdout, err
    assert json.loads((cubes / "IMG_0001.tif.cade.json").read_text())["options"]["near"] == 2.0
    code, stdout, err = batch(flight, cubes, capsys, "--near", "2")
    assert code == 0 and "0 done, 3 already finished" in stdout, err
    code, stdout, err = batch(flight, cubes, capsys)  # the default factor: another search, redone
    assert code == 0 and "3 done, 0 already finished" in stdout, err
    before = {path.name: path.read_bytes() for path in cubes.iterdir()}
    code, stdout, err = batch(flight, cubes, capsys, "--near", "0.5")
    lines = err.strip().splitlines()
    assert code != 0 and len(lines) == 1 and "--near" in lines[0] and not stdout, err
    assert {path.name: path.read_bytes() for path in cubes.iterdir()} == before


def test_a_note_every_capture_shares_is_shown_once_with_a_count(flight, tmp_path, capsys):
    code, stdout, err = batch(flight, tmp_path / "cubes", capsys)
    assert code == 0 and "3 done" in stdout, err
    notes = [line for line in err.splitlines() if "parallax below 0.3 px" in line]
    assert len(notes) == 1 and "(3 of 3 captures: IMG_0001, IMG_0002, IMG_0003)" in notes[0], err
    assert notes[0].startswith("note: Blue, Red, NIR, Red edge: parallax below 0.3 px")


def test_dji_captures_are_named_by_their_first_file(tmp_path):
    """DJI numbers every file (DJI_0011 .. DJI_0015 one capture, DJI_0021 .. the next): no shared
    name tells the captures apart, so each is named by its first file."""
    rng = np.random.default_rng(6)
    for first, uuid in ((11, "A"), (21, "B")):
        scene = write_rig_capture(tmp_path / "shots", rng, dji_like((48, 36)), style="p4m", capture_id=uuid,
                                  name=f"tmp{first}")
        for number, path in enumerate(scene.paths):
            path.rename(path.with_name(f"DJI_{first + number:04d}.TIF"))
    captures, notes = group_captures(tmp_path)
    assert not notes and sorted(c.name for c in captures) == ["DJI_0011", "DJI_0021"]
    assert all(c.problem is None and len(c.paths) == 5 for c in captures)


# ---------------------------------------------------------------- radiance and reflectance of a flight

CALIBRATION = (0.0002687611, 9.757788e-08, -1.640921e-05)  # a RedEdge-M Red band's (a1, a2, a3)
VIGNETTING = (-1.2e-3, 2.0e-5, 0.0, 0.0, 0.0, 0.0)  # k0..k5: the corners of 96x72 px about 6 % darker
SHOTS = {"IMG_0001": (0.0010, 100, 1.10), "IMG_0002": (0.0018, 400, 0.90), "IMG_0003": (0.0013, 200, 1.30)}
"""Capture -> (exposure s, ISO, DLS horizontal irradiance W/m^2/nm): other exposures and light each."""


def tag_radiometry(paths, *, exposure: float, iso: int, irradiance: float | None, flat: bool = False,
                   capture_id: str | None = None) -> None:
    """Rewrite the synthetic band files ``paths`` with MicaSense's radiometric tags (calibration,
    vignetting centre and polynomial, EXIF exposure and ISO) and, unless ``irradiance`` is None, a
    DLS 2 reading whose horizontal irradiance the firmware (v5.2.0 > 5.1.7) makes trusted;
    ``flat``: no vignetting, no row gradient (a panel shot whose square is uniform)."""
    from cade_cli.capture.exif import LONG, Entry, add_tags, rational_entry

    for path in paths:
        with tifffile.TiffFile(path) as tiff:
            raw, packet = tiff.pages[0].asarray(), tiff.pages[0].tags[700].value.decode()
        a1, a2, a3 = CALIBRATION
        fields = {"MicaSense:RadiometricCalibration": f"{a1!r}, {0.0 if flat else a2!r}, {0.0 if flat else a3!r}",
                  "Camera:VignettingCenter": f"{raw.shape[1] / 2}, {raw.shape[0] / 2}",
                  "Camera:VignettingPolynomial": ", ".join(repr(0.0 if flat else k) for k in VIGNETTING)}
        if irradiance is not None:
            fields.update({"DLS:HorizontalIrradiance": repr(irradiance), "DLS:DirectIrradiance": repr(0.8 * irradiance),
                           "DLS:ScatteredIrradiance": repr(0.2 * irradiance), "DLS:SpectralIrradiance":
                           repr(0.9 * irradiance), "DLS:IrradianceScaleToSIUnits": "1"})
        body = "".join(f"<{key}>{value}</{key}>" for key, value in fields.items())
        packet = packet.replace('xmlns:MicaSense=', 'xmlns:DLS="http://micasense.com/DLS/1.0/" xmlns:MicaSense=')
        packet = packet.replace("</rdf:Description>", body + "</rdf:Description>")
        if capture_id is not None:
            packet = re.sub(r"<MicaSense:CaptureId>[^<]*<", f"<MicaSense:CaptureId>{capture_id}<", packet)
        tags = [(700, "B", 0, packet.encode(), True), (271, "s", 0, "MicaSense", True),
                (272, "s", 0, "RedEdge-M", True),
                (37390, "2I", 1, (266666667, 1000000), True), (37392, "H", 1, 4, True),
                (50714, "H", 4, (BLACK_LEVEL,) * 4, True)]
        tifffile.imwrite(path, raw, photometric="minisblack", metadata=None, software="v5.2.0", extratags=tags)
        add_tags(path, exif=[rational_entry(33434, [exposure]), Entry(34867, LONG, (iso,))])


def expected_radiance(raw: np.ndarray, *, exposure: float, iso: int) -> np.ndarray:
    """MicaSense's model written out again here: (p - black) * V(r) * R(row) / (g t) * a1 / 2^16."""
    a1, a2, a3 = CALIBRATION
    rows, cols = np.mgrid[0:raw.shape[0], 0:raw.shape[1]].astype(np.float64)
    r = np.hypot(cols - raw.shape[1] / 2, rows - raw.shape[0] / 2)
    vignetting = 1 / (1 + sum(k * r ** (i + 1) for i, k in enumerate(VIGNETTING)))
    gradient = 1 / (1 + a2 * rows / exposure - a3 * rows)
    return np.maximum((raw - BLACK_LEVEL) * vignetting * gradient, 0) / (iso / 100 * exposure) * a1 / 2 ** 16


@pytest.fixture
def radiometric_flight(flight):
    for name, (exposure, iso, irradiance) in SHOTS.items():
        tag_radiometry(sorted(flight.glob(f"{name}_*.tif")), exposure=exposure, iso=iso, irradiance=irradiance)
    return flight


def test_a_flight_in_radiance_and_reflectance_gives_register_captures_values(radiometric_flight, tmp_path, capsys):
    flight, cubes = radiometric_flight, tmp_path / "cubes"
    code, stdout, err = batch(flight, cubes, capsys, "--plane-only", "--radiance")
    assert code == 0 and "3 done" in stdout, err
    assert err.count("values: radiance, W/m^2/sr/nm") == 1, err
    green = {name: tifffile.imread(flight / f"{name}_2.tif").astype(np.float64) for name in SHOTS}
    for name, (exposure, iso, _) in SHOTS.items():  # the reference band is not resampled: its radiance as it is
        np.testing.assert_allclose(tifffile.imread(cubes / f"{name}.tif")[1],
                                   expected_radiance(green[name], exposure=exposure, iso=iso), rtol=1e-5)
    code, _, err = run_cade(["register-capture", *sorted(flight.glob("IMG_0002_*.tif")), "-o", tmp_path / "one.tif",
                             "--plane-only", "--radiance"], capsys)
    assert code == 0, err
    np.testing.assert_array_equal(tifffile.imread(cubes / "IMG_0002.tif"), tifffile.imread(tmp_path / "one.tif"))
    code, stdout, _ = batch(flight, cubes, capsys, "--plane-only", "--radiance")
    assert "0 done, 3 already finished" in stdout
    # other radiometry is another fingerprint: every capture redone, each by its own DLS
    code, stdout, err = batch(flight, cubes, capsys, "--plane-only", "--reflectance")
    assert code == 0 and "3 done, 0 already finished" in stdout, err
    assert err.count("values: reflectance; horizontal irradiance from each capture's own DLS tags") == 1, err
    for name, (exposure, iso, irradiance) in SHOTS.items():
        np.testing.assert_allclose(tifffile.imread(cubes / f"{name}.tif")[1],
                                   math.pi * expected_radiance(green[name], exposure=exposure, iso=iso) / irradiance,
                                   rtol=1e-5)
        record = json.loads((cubes / f"{name}.tif.cade.json").read_text())
        assert record["options"]["radiometry"] == "reflectance" and "irradiance" not in record["options"]
        assert record["radiometry"]["irradiance_w_m2_nm"] == pytest.approx([irradiance] * 5)
    # a panel shot outside the flight, uniform: its irradiance pi * L / albedo serves every capture
    panel = write_capture(tmp_path / "panel", np.random.default_rng(3), size=SIZE, name="IMG_0100",
                          capture_id="PANEL").paths
    for path in panel:  # the panel fills the frame: 16000 above black level everywhere
        with tifffile.TiffFile(path) as tiff:
            packet = tiff.pages[0].tags[700].value
        tifffile.imwrite(path, np.full(SIZE[::-1], BLACK_LEVEL + 16000, np.uint16), photometric="minisblack",
                         metadata=None, extratags=[(700, "B", 0, packet, True)])
    tag_radiometry(panel, exposure=0.0005, iso=100, irradiance=None, flat=True)
    panel_radiance = 16000 / (1.0 * 0.0005) * CALIBRATION[0] / 2 ** 16
    code, stdout, err = batch(flight, cubes, capsys, "--plane-only", "--reflectance", "--panel", panel[0],
                              "--panel-corners", "20,20,60,20,60,50,20,50", "--panel-albedo", "0.5,0.5,0.5,0.5,0.5")
    assert code == 0 and "3 done, 0 already finished" in stdout, err
    assert err.count("values: reflectance; the irradiance of the panel IMG_0100 for every capture") == 1, err
    code, stdout, _ = batch(flight, cubes, capsys, "--plane-only", "--reflectance", "--panel", panel[0],
                            "--panel-corners", "20,20,60,20,60,50,20,50", "--panel-albedo", "0.5,0.5,0.5,0.5,0.5")
    assert "0 done, 3 already finished" in stdout  # the panel's irradiance, in the records, reads back equal
    for name, (exposure, iso, _) in SHOTS.items():
        np.testing.assert_allclose(tifffile.imread(cubes / f"{name}.tif")[1], 0.5 * expected_radiance(
            green[name], exposure=exposure, iso=iso) / panel_radiance, rtol=1e-5)


def test_bad_radiometry_options_fail_once_per_flight(flight, radiometric_flight_without_dls, tmp_path, capsys):
    for folder, options, message in (
            (flight, ["--radiance"], "no EXIF ExposureTime in its metadata"),
            (flight, ["--radiance", "--dtype", "uint16"], "--radiance writes float32 values"),
            (flight, ["--radiance", "--reflectance"], "exclude each other"),
            (flight, ["--panel-albedo", "0.5"], "add --reflectance"),
            (radiometric_flight_without_dls, ["--reflectance"], "no DLS irradiance in its tags"),
            (radiometric_flight_without_dls, ["--reflectance", "--panel", "IMG_0009"], "--panel IMG_0009")):
        code, stdout, err = batch(folder, tmp_path / "cubes", capsys, "--plane-only", *options)
        lines = err.strip().splitlines()
        assert code != 0 and len(lines) == 1 and message in lines[0], (options, err)
        assert "Traceback" not in err and not list((tmp_path / "cubes").glob("*.tif"))


@pytest.fixture
def radiometric_flight_without_dls(rendered, tmp_path):
    folder = tmp_path / "no-dls"
    shutil.copytree(rendered, folder)
    for name, (exposure, iso, _) in SHOTS.items():
        tag_radiometry(sorted(folder.glob(f"{name}_*.tif")), exposure=exposure, iso=iso, irradiance=None)
    return folder
