"""The metadata mapping tools read, in register-capture's cube and --per-band files: the source's
EXIF and GPS read back equal by exifread (OpenDroneMap's reader) and exiftool (skipped when not
installed), no GPS without a fix, each file's own band XMP with the geometry of the pixels as
written, and the per-band files read back as a capture."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tifffile

from capture_scenes import write_capture
from cli_runner import run_cade
from cade_cli.capture.cube import write_cube, write_per_band
from cade_cli.capture.exif import Entry, add_tags, ascii_entry, rational_entry, read_source_exif
from cade_cli.capture.metadata import numbers, parse_xmp, read_band_file
from cade_cli.capture.model import load_capture
from cade_cli.capture.register import BandResult, CaptureRegistration, read_raw

exifread = pytest.importorskip("exifread")

LATITUDE, LONGITUDE, ALTITUDE = (10, 1, 30, 1, 334285, 10000), (84, 1, 20, 1, 360700, 10000), (112665, 1000)
EXPOSURES = {1: (1, 694), 2: (1, 860), 3: (1, 549), 4: (1, 653), 5: (1, 1000)}
"""Per file number: a different exposure time for each band (the cube carries the reference's)."""


def add_source_exif(paths: list[Path], *, gps: str = "fix") -> None:
    """Give a synthetic capture's band files the EXIF a MicaSense camera writes: exposure, ISO,
    times, lens, serial, orientation, and a GPS IFD (``fix``: a position; ``zero``: 0, 0 as a bench
    camera without a fix writes; ``void``: GPSStatus V as the Sequoia; ``none``: no GPS IFD)."""
    for number, path in enumerate(paths, start=1):
        exif = [rational_entry(33434, [EXPOSURES[number][0] / EXPOSURES[number][1]]),
                Entry(34867, 4, (200 * number,)), Entry(34864, 3, (3,)), Entry(36864, 7, b"0230"),
                ascii_entry(36867, "2021:08:27 19:35:07"), ascii_entry(37520, "651740578"),
                Entry(37386, 5, (11, 2)), Entry(41486, 5, (266666667, 1000000)),
                Entry(41487, 5, (266666667, 1000000)), Entry(41488, 3, (4,)), ascii_entry(42033, "RM01-1824146-SC")]
        position = {"fix": [Entry(2, 5, LATITUDE), Entry(4, 5, LONGITUDE), Entry(6, 5, ALTITUDE)],
                    "zero": [Entry(2, 5, (0, 1, 0, 1, 0, 1)), Entry(4, 5, (0, 1, 0, 1, 0, 1)), Entry(6, 5, (0, 1))],
                    "void": [ascii_entry(9, "V")], "none": []}[gps]
        refs = [Entry(0, 1, b"\x02\x02\x00\x00"), ascii_entry(1, "N"), ascii_entry(3, "W"), Entry(5, 1, b"\x00")]
        add_tags(path, main=[Entry(274, 3, (1,)), ascii_entry(306, "2021:08:27 19:35:07")], exif=exif,
                 gps=refs + position if position else [])


def tags_of(path: Path) -> dict[str, str]:
    with open(path, "rb") as handle:
        return {key: str(value) for key, value in exifread.process_file(handle, details=False).items()
                if not key.startswith(("JPEGThumbnail", "Thumbnail"))}


CARRIED = ["GPS GPSLatitude", "GPS GPSLatitudeRef", "GPS GPSLongitude", "GPS GPSLongitudeRef", "GPS GPSAltitude",
           "GPS GPSAltitudeRef", "EXIF DateTimeOriginal", "EXIF FocalLength", "EXIF ExposureTime", "EXIF ISOSpeed",
           "EXIF FocalPlaneXResolution", "EXIF FocalPlaneYResolution", "EXIF FocalPlaneResolutionUnit",
           "EXIF BodySerialNumber", "Image Make", "Image Model", "Image Orientation", "EXIF SubSecTime"]


def xmp_of(path: Path) -> dict:
    with tifffile.TiffFile(path) as tiff:
        return parse_xmp(tiff.pages[0].tags[700].value)


def identity_registration(capture) -> CaptureRegistration:
    """A registration that leaves every band as read (for the metadata alone: the files are
    written as register-capture writes them)."""
    raw = tuple(read_raw(capture))
    bands = tuple(image.astype(np.float32) for image in raw)
    return CaptureRegistration(capture=capture, raw=raw, bands=bands,
                               valid=tuple(np.ones(b.shape, bool) for b in bands),
                               saturated=tuple(np.zeros(b.shape, bool) for b in bands),
                               results=tuple(BandResult(b.name, "reference", np.eye(3), None, None, 0)
                                             for b in capture.bands),
                               sampled=(None,) * len(bands), seconds=0.0)


def test_written_ifds_read_back_with_exifread_and_tifffile(tmp_path):
    for big in (False, True):
        path = tmp_path / f"big{big}.tif"
        pixels = np.arange(3 * 20 * 30, dtype=np.float32).reshape(3, 20, 30)
        tifffile.imwrite(path, pixels, photometric="minisblack", planarconfig="separate", metadata=None, bigtiff=big)
        add_tags(path, main=[ascii_entry(271, "MicaSense"), Entry(50714, 3, (4800,) * 4)],
                 exif=[rational_entry(33434, [1 / 694]), ascii_entry(42033, "RM01")],
                 gps=[ascii_entry(1, "N"), Entry(2, 5, LATITUDE), Entry(4, 5, LONGITUDE)])
        with tifffile.TiffFile(path) as tiff:
            page = tiff.pages[0]
            assert np.array_equal(page.asarray(), pixels) and page.tags[271].value == "MicaSense"
            assert page.tags[50714].value == (4800,) * 4
            assert page.tags[34665].value["ExposureTime"] == (1, 694)
            assert page.tags[34665].value["BodySerialNumber"] == "RM01"
            assert page.tags[34853].value["GPSLatitude"] == LATITUDE
        source = read_source_exif(path)
        assert source.exif[33434].value == (1, 694) and source.has_fix()
        if not big:  # exifread reads classic TIFF only
            tags = tags_of(path)
            assert tags["EXIF ExposureTime"] == "1/694" and tags["GPS GPSLatitude"] == "[10, 30, 66857/2000]"
            assert tags["Image Make"] == "MicaSense" and tags["EXIF BodySerialNumber"] == "RM01"


def test_no_fix_is_read_as_none():
    zero, void = (0, 1, 0, 1, 0, 1), [ascii_entry(9, "V"), Entry(2, 5, LATITUDE), Entry(4, 5, LONGITUDE)]
    from cade_cli.capture.exif import SourceExif

    assert not SourceExif({}, {}, {2: Entry(2, 5, zero), 4: Entry(4, 5, zero)}).has_fix()
    assert not SourceExif({}, {}, {entry.code: entry for entry in void}).has_fix()
    assert not SourceExif({}, {}, {}).has_fix()
    assert SourceExif({}, {}, {2: Entry(2, 5, LATITUDE), 4: Entry(4, 5, LONGITUDE)}).has_fix()


@pytest.fixture
def fixed_capture(tmp_path, rng):
    scene = write_capture(tmp_path / "shot", rng, size=(64, 48))
    add_source_exif(scene.paths)
    return scene


def test_cube_and_per_band_files_carry_the_source_exif(fixed_capture, tmp_path, capsys):
    paths = fixed_capture.paths
    out, bands = tmp_path / "cube.tif", tmp_path / "bands"
    code, _, err = run_cade(["register-capture", *paths, "-o", out, "--per-band", bands, "--plane-only"], capsys)
    assert code == 0, err
    green = tags_of(paths[1])
    assert green["GPS GPSLatitude"] == "[10, 30, 66857/2000]" and green["EXIF ExposureTime"] == "1/860"
    cube = tags_of(out)
    for key in CARRIED:
        assert cube.get(key) == green[key], key  # the reference's
    assert cube["EXIF SubSecTimeOriginal"] == "651740578"  # MicaSense's SubSecTime, of DateTimeOriginal
    for number, path in enumerate(paths, start=1):
        written, source = tags_of(bands / path.name), tags_of(path)
        for key in CARRIED:
            assert written.get(key) == source[key], (path.name, key)
        assert written["EXIF ExposureTime"] == f"{EXPOSURES[number][0]}/{EXPOSURES[number][1]}"
        assert written["EXIF ISOSpeed"] == str(200 * number)
    with tifffile.TiffFile(out) as tiff:  # one BlackLevel per band (DNG: repeat 1x1, one value per sample)
        assert tiff.pages[0].tags[50714].value == (4800, 1) * 5 and tiff.pages[0].tags[50713].value == (1, 1)
    if shutil.which("exiftool") is None:
        pytest.skip("exiftool is not installed (apt-get install libimage-exiftool-perl)")
    for path in (out, bands / paths[3].name):
        shown = subprocess.run(["exiftool", "-n", "-s", "-GPSLatitude", "-GPSLongitude", "-GPSAltitude",
                                "-DateTimeOriginal", "-FocalLength", "-ExposureTime", "-SerialNumber",
                                "-FocalPlaneXResolution", "-BlackLevel", str(path)], capture_output=True, text=True,
                               check=True).stdout
        fields = dict(line.split(":", 1) for line in shown.splitlines())
        fields = {key.strip(): value.strip() for key, value in fields.items()}
        assert float(fields["GPSLatitude"]) == pytest.approx(10 + 30 / 60 + 33.4285 / 3600, abs=1e-7)
        assert float(fields["GPSLongitude"]) == pytest.approx(-(84 + 20 / 60 + 36.07 / 3600), abs=1e-7)
        assert float(fields["GPSAltitude"]) == pytest.approx(112.665)
        assert fields["DateTimeOriginal"] == "2021:08:27 19:35:07" and float(fields["FocalLength"]) == 5.5
        assert fields["SerialNumber"] == "RM01-1824146-SC"
        assert float(fields["FocalPlaneXResolution"]) == pytest.approx(266.666667)
        assert float(fields["ExposureTime"]) == pytest.approx(1 / 860 if path == out else 1 / 653)
        assert fields["BlackLevel"].split()[0] == "4800"


@pytest.mark.parametrize("gps", ["zero", "void", "none"])
def test_no_gps_is_written_without_a_fix(tmp_path, rng, gps):
    scene = write_capture(tmp_path / "shot", rng, size=(48, 32))
    add_source_exif(scene.paths, gps=gps)
    capture = load_capture(scene.paths)
    registration = identity_registration(capture)
    write_cube(tmp_path / "cube.tif", registration)
    written = write_per_band(tmp_path, registration)
    for path in (tmp_path / "cube.tif", *written):
        tags = tags_of(path)
        assert not [key for key in tags if key.startswith("GPS")], path.name
        assert tags["EXIF DateTimeOriginal"] == "2021:08:27 19:35:07"  # the rest is carried
        with tifffile.TiffFile(path) as tiff:
            assert 34853 not in tiff.pages[0].tags
            assert b"GPSLatitude" not in tiff.pages[0].tags[700].value


def test_each_file_carries_its_own_band_and_the_geometry_of_its_pixels(fixed_capture, tmp_path):
    capture = load_capture(fixed_capture.paths, reference="NIR")
    registration = identity_registration(capture)
    write_cube(tmp_path / "cube.tif", registration)
    (tmp_path / "bands").mkdir()
    written = write_per_band(tmp_path / "bands", registration)
    nir = xmp_of(fixed_capture.paths[3])
    for band, path in zip(capture.bands, written):
        xmp = xmp_of(path)
        source = xmp_of(band.path)
        assert xmp["Camera:BandName"] == band.name and xmp["Camera:CentralWavelength"] == source[
            "Camera:CentralWavelength"]
        assert xmp["Camera:RigCameraIndex"] == source["Camera:RigCameraIndex"]
        assert xmp["MicaSense:CaptureId"] == "SYNTHETIC01"
        assert xmp["Camera:ModelType"] == "perspective"
        for name in ("Camera:PrincipalPoint", "Camera:PerspectiveFocalLength", "Camera:PerspectiveDistortion"):
            assert numbers(xmp[name]) == numbers(nir[name]), name  # the reference's lens: the pixels lie on its grid
        assert numbers(xmp["Camera:RigRelatives"]) == [0, 0, 0]
        assert xmp["Camera:RigRelativesReferenceRigCameraIndex"] == "3"
        assert xmp["http://ns.adobe.com/exif/1.0/:GPSLatitude"] == "10,30.557142N"  # the fix, in the XMP too
    with tifffile.TiffFile(tmp_path / "cube.tif") as tiff:
        xmp = parse_xmp(tiff.pages[0].tags[700].value)
    assert xmp["Camera:BandName"] == ["Blue", "Green", "Red", "NIR", "Red edge"]
    assert numbers(xmp["Camera:CentralWavelength"]) == [475, 560, 668, 840, 717]
    assert numbers(xmp["Camera:PrincipalPoint"]) == numbers(nir["Camera:PrincipalPoint"])
    assert "Camera:RigCameraIndex" not in xmp


def test_per_band_files_read_back_as_a_capture(fixed_capture, tmp_path, capsys):
    bands = tmp_path / "bands"
    code, _, err = run_cade(["register-capture", *fixed_capture.paths, "-o", tmp_path / "cube.tif", "--per-band",
                             bands, "--plane-only"], capsys)
    assert code == 0, err
    again = load_capture(sorted(bands.glob("*.tif")))
    reference = load_capture(fixed_capture.paths).reference_band
    assert again.names() == ["Blue", "Green", "Red", "NIR", "Red edge"]
    for band in again.bands:
        assert band.lens == reference.lens and np.allclose(band.rotation, np.eye(3))
        assert band.black_level == 4800 and band.capture_id == "SYNTHETIC01"
    code, _, err = run_cade(["register-capture", *sorted(bands.glob("*.tif")), "-o", tmp_path / "again.tif",
                             "--plane-only"], capsys)
    assert code == 0, err


MICASENSE_FIELD = ("rededge-m-field", "IMG_0008")
SEQUOIA = ("sequoia-tabletop", "IMG_180413_080658_0000")


def real_capture(shared_data, folder: str, name: str) -> list[Path]:
    paths = sorted((shared_data / "micasense" / folder).glob(f"{name}_*"))
    if not paths:
        pytest.skip(f"{shared_data / 'micasense' / folder} not found")
    return paths


def test_the_field_capture_keeps_its_gps_and_time(shared_data, tmp_path):
    capture = load_capture(real_capture(shared_data, *MICASENSE_FIELD))
    registration = identity_registration(capture)
    write_cube(tmp_path / "cube.tif", registration)
    written = write_per_band(tmp_path, registration)
    green, nir = tags_of(capture.reference_band.path), tags_of(capture.bands[3].path)
    assert green["GPS GPSLatitudeRef"] == "N" and green["GPS GPSLongitudeRef"] == "W"
    for path, source in ((tmp_path / "cube.tif", green), (written[3], nir)):
        tags = tags_of(path)
        for key in ("GPS GPSLatitude", "GPS GPSLongitude", "GPS GPSAltitude", "EXIF DateTimeOriginal",
                    "EXIF FocalLength", "EXIF ExposureTime", "EXIF ISOSpeed", "EXIF BodySerialNumber",
                    "EXIF SubSecTime", "Image Make", "Image Model", "EXIF FocalPlaneXResolution"):
            assert tags[key] == source[key], (path.name, key)
    xmp = xmp_of(written[3])
    source = xmp_of(capture.bands[3].path)
    for name in ("MicaSense:RadiometricCalibration", "Camera:VignettingPolynomial", "Camera:Irradiance",
                 "DLS:SpectralIrradiance", "MicaSense:DarkRowValue"):
        assert xmp[name] == source[name], name  # NIR's own
    (tmp_path / "converted").mkdir()
    converted = write_per_band(tmp_path / "converted", replace(registration, radiometry="radiance"))  # as radiance
    xmp = xmp_of(converted[3])
    assert xmp["Camera:Irradiance"] == source["Camera:Irradiance"]
    assert not {"MicaSense:RadiometricCalibration", "Camera:VignettingCenter", "Camera:VignettingPolynomial",
                "MicaSense:DarkRowValue"} & set(xmp)  # applied already: no tool may apply them again
    with tifffile.TiffFile(converted[3]) as tiff:
        assert 50714 not in tiff.pages[0].tags


def test_the_sequoia_keeps_its_orientation_and_claims_no_fix(shared_data, tmp_path):
    capture = load_capture(real_capture(shared_data, *SEQUOIA))
    registration = identity_registration(capture)
    write_cube(tmp_path / "cube.tif", registration)
    written = write_per_band(tmp_path, registration)
    for path in (tmp_path / "cube.tif", *written):
        tags = tags_of(path)
        assert tags["Image Orientation"] == "Rotated 180" and not [key for key in tags if key.startswith("GPS")]
    again = load_capture(written)
    for band in again.bands:  # the reference's fisheye lens and no rotation, read back
        assert band.lens == capture.reference_band.lens and np.allclose(band.rotation, np.eye(3))
    assert read_band_file(written[2]).name == "Red edge"
