"""Radiance, irradiance and reflectance of drone captures (cade_cli.capture.radiometry,
irradiance, sun, panel): each test builds its own truth — a radiance field through the camera's
forward model, the sun from published positions and closed forms, a panel drawn at a known
place — plus the real captures of ../shared/data when present."""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone

import cv2
import numpy as np
import pytest
import tifffile

from cli_runner import run_cade
from cade_cli.capture.irradiance import DLSReading, diffuser_transmission, horizontal_irradiance, read_dls
from cade_cli.capture.metadata import numbers, parse_xmp
from cade_cli.capture.panel import (PanelQR, albedo_from_qr, find_panel_qr, measure_panel, panel_irradiance,
                                    parse_albedo, parse_corners, region_stats, square_from_qr)
from cade_cli.capture.radiometry import (MicaSenseModel, Radiometry, SequoiaModel, radiance, raw_from_radiance,
                                         read_radiometric_model)
from cade_cli.capture.sun import sun_position
from cade_cli.errors import CadeError

SHAPE = (96, 128)
# a RedEdge-M Red band's tags (rededge-m-field), exposure and gain varied by the tests
RED = dict(black_level=4800.0, calibration=(0.0002687611, 9.757788e-08, -1.640921e-05),
           vignetting_centre=(639.3278, 480.3828),
           vignetting=(-0.0001110414, 1.386024e-06, -1.181262e-08, 3.447577e-11, -4.426178e-14, 2.036899e-17), bits=16)


def radiance_field(rng: np.random.Generator) -> np.ndarray:
    """A smooth positive radiance field, W/m^2/sr/nm."""
    coarse = rng.uniform(0.005, 0.03, size=(6, 8))
    return cv2.resize(coarse, SHAPE[::-1], interpolation=cv2.INTER_CUBIC).clip(0.004, None)


def scaled_red(scale: float) -> MicaSenseModel:
    """The Red model on a SHAPE image: the vignetting centre and radii scaled to it, so the
    corners are as dark as the real sensor's."""
    k = RED["vignetting"]
    return MicaSenseModel(RED["black_level"], 0.0010, 1.0, RED["calibration"],
                          (RED["vignetting_centre"][0] * scale, RED["vignetting_centre"][1] * scale),
                          tuple(c / scale ** (i + 1) for i, c in enumerate(k)), RED["bits"])


def test_micasense_radiance_inverts_the_forward_model(rng):
    truth = radiance_field(rng)
    model = scaled_red(SHAPE[1] / 1280)
    raw = raw_from_radiance(truth, model)
    assert raw.min() > model.black_level and raw.max() < 65520  # a real exposure: above black, unsaturated
    corner_falloff = raw_from_radiance(np.ones(SHAPE), model)
    assert corner_falloff[0, 0] < 0.8 * corner_falloff[SHAPE[0] // 2, SHAPE[1] // 2] + 0.2 * model.black_level
    np.testing.assert_allclose(radiance(raw, model), truth, rtol=1e-5)
    quantised = np.rint(raw / 16) * 16  # 12-bit data in 16 bits, as the camera stores it
    assert np.median(np.abs(radiance(quantised.astype(np.uint16), model) / truth - 1)) < 0.01


def test_exposure_and_gain_do_not_change_the_radiance(rng):
    """The same scene shot at other exposures and ISO gives the same radiance (and reflectance)."""
    truth = radiance_field(rng)
    base = scaled_red(SHAPE[1] / 1280)
    results = []
    for exposure, gain in ((0.0010, 1.0), (0.0018, 2.0), (0.0006, 4.0)):
        model = MicaSenseModel(base.black_level, exposure, gain, base.calibration, base.vignetting_centre,
                               base.vignetting, base.bits)
        raw = np.rint(raw_from_radiance(truth, model) / 16) * 16
        results.append(radiance(raw, model))
    raw_values = [raw_from_radiance(truth, MicaSenseModel(base.black_level, e, g, base.calibration,
                                                          base.vignetting_centre, base.vignetting, base.bits)).mean()
                  for e, g in ((0.0010, 1.0), (0.0018, 2.0))]
    assert raw_values[1] > 1.5 * raw_values[0]  # the raw values do differ
    for other in results[1:]:
        assert np.median(np.abs(other / results[0] - 1)) < 0.01


def test_below_black_level_is_zero_radiance():
    model = scaled_red(SHAPE[1] / 1280)
    raw = np.full(SHAPE, 4000, np.uint16)
    assert (radiance(raw, model) == 0).all()


def test_sequoia_radiance_inverts_its_sensor_model(rng):
    names = (0, 0, 1, 0, 2, 0, 0, 1, 0, 2, 1, 1)
    model = SequoiaModel((271665.8, 5008.3, 2581.1), 0.003, 621.0, 2.2,
                         (0.70, 0.35, -0.30, 0.30, -0.25, 0.12),
                         tuple((names[2 * i], names[2 * i + 1]) for i in range(6)))
    truth = radiance_field(rng) * 10
    raw = raw_from_radiance(truth, model)
    np.testing.assert_allclose(radiance(raw, model), truth, rtol=1e-5)


def test_radiometry_refuses_a_reflectance_without_irradiance():
    with pytest.raises(CadeError, match="irradiance"):
        Radiometry("reflectance")
    with pytest.raises(CadeError, match="radiance, reflectance"):
        Radiometry("brightness")


# ---------------------------------------------------------------- the sun

def test_sun_matches_the_published_spa_example():
    """NREL's SPA report (Reda & Andreas 2004), its worked example: 2003-10-17 12:30:30 local
    (UTC-7) at 39.742476 N, 105.1786 W: topocentric zenith 50.11162 deg, azimuth 194.34024 deg."""
    sun = sun_position(datetime(2003, 10, 17, 19, 30, 30, tzinfo=timezone.utc), 39.742476, -105.1786)
    assert abs((90 - sun.elevation) - 50.11162) < 0.05
    assert abs(sun.azimuth - 194.34024) < 0.05


def test_sun_at_solstice_noon_and_equinox_noon():
    # June solstice 2024 (June 20, 20:51 UTC); solar noon at Greenwich ~12:02 UTC: 90 - 40 + 23.44
    june = sun_position(datetime(2024, 6, 20, 12, 2), 40.0, 0.0)
    assert abs(june.elevation - (90 - 40 + 23.44)) < 0.05
    assert abs(june.azimuth - 180) < 1.0
    assert abs(june.declination - 23.44) < 0.01
    # March equinox 2024 (March 20, 03:06 UTC): at the equator the noon sun is overhead
    march = sun_position(datetime(2024, 3, 20, 12, 7, 30), 0.0, 0.0)
    assert march.elevation > 89.5
    # polar night: 80 N at the December solstice never sees the sun
    assert sun_position(datetime(2024, 12, 21, 12, 0), 80.0, 0.0).elevation < -10
    # the same instant at 90 E is 6 h later in solar time: the sun is lower in the afternoon
    assert sun_position(datetime(2024, 6, 20, 12, 0), 40.0, 90.0).azimuth > 180


# ---------------------------------------------------------------- the DLS

def test_a_level_dls_under_an_overhead_sun_reads_the_horizontal_irradiance_through_its_diffuser():
    """Sun at the zenith, sensor level: E_horizontal = reading / T(0), with T(0) the normal-incidence
    Fresnel transmission of the diffuser's two interfaces, 1 - ((n1 - n2) / (n1 + n2))^2 each."""
    indices = (1.000277, 1.6, 1.38)
    normal = math.prod(1 - ((a - b) / (a + b)) ** 2 for a, b in zip(indices, indices[1:]))
    assert diffuser_transmission(0.0) == pytest.approx(normal, rel=1e-9)
    noon = datetime(2024, 3, 20, 12, 7, 30, tzinfo=timezone.utc)
    reading = DLSReading(0.5, 0.0, 0.0, 0.0, False, (0.0, 0.0, 0.0), noon, 0.0, 0.0)
    assert horizontal_irradiance(reading) == pytest.approx(0.5 / normal, rel=2e-4)
    # a level sensor: the sun-sensor angle is the zenith angle, so E_horizontal = reading / T(zenith)
    afternoon = noon.replace(hour=17)
    zenith = math.radians(90 - sun_position(afternoon, 0.0, 0.0).elevation)
    low_sun = DLSReading(0.5, 0.0, 0.0, 0.0, False, (0.0, 0.0, 0.0), afternoon, 0.0, 0.0)
    assert horizontal_irradiance(low_sun) == pytest.approx(0.5 / diffuser_transmission(zenith), rel=1e-9)
    assert horizontal_irradiance(low_sun) > horizontal_irradiance(reading)  # the diffuser passes less at a slant


def test_dls2_horizontal_irradiance_is_taken_when_trusted():
    reading = DLSReading(0.47, 0.51, 0.93, 0.10, True, (0.0, 0.0, 0.0), None, None, None)
    assert horizontal_irradiance(reading) == 0.51
    with pytest.raises(CadeError, match="--panel"):
        horizontal_irradiance(DLSReading(0.47, 0.0, 0.0, 0.0, False, (0.0, 0.0, 0.0), None, None, None))


# ---------------------------------------------------------------- the panel

def panel_scene(rng: np.random.Generator, *, albedo: float, irradiance: float):
    """A radiance image of a RP04 panel: its QR code (90 mm) and, 145.8 mm to its left, a grey
    square of ``albedo`` under ``irradiance``; soil around. Returns (image, true square centre, px/mm)."""
    code = cv2.QRCodeEncoder.create().encode("RP04-1826246-SC_04005111000507")
    rows, cols = np.nonzero(code == 0)
    code = code[rows.min():rows.max() + 1, cols.min():cols.max() + 1]  # the modules alone, no quiet zone
    px_per_mm = 2.0
    side = int(round(90 * px_per_mm))
    module = cv2.resize(code, (side, side), interpolation=cv2.INTER_NEAREST).astype(np.float64) / 255
    image = rng.uniform(0.01, 0.02, size=(600, 800))
    qr_centre = np.array([560.0, 300.0])
    x0, y0 = (qr_centre - side / 2).astype(int)
    image[y0 - 40:y0 + side + 40, x0 - 40:x0 + side + 40] = 0.25  # the white card around the code
    image[y0:y0 + side, x0:x0 + side] = 0.01 + 0.24 * module
    centre = qr_centre + np.array([-145.8, 0.0]) * px_per_mm
    half = 50 * px_per_mm  # the grey square is 100 mm; the vendor measures its inner 50 mm
    image[int(centre[1] - half):int(centre[1] + half), int(centre[0] - half):int(centre[0] + half)] = \
        albedo * irradiance / math.pi
    return image, centre, px_per_mm


@pytest.mark.parametrize("turns", [0, 2])
def test_the_panel_square_is_found_from_its_qr_code(rng, turns):
    image, centre, px_per_mm = panel_scene(rng, albedo=0.51, irradiance=1.2)
    height, width = image.shape
    image = np.rot90(image, turns).copy()
    if turns == 2:
        centre = np.array([width - 1 - centre[0], height - 1 - centre[1]])
    qr = find_panel_qr(image)
    assert qr is not None and qr.serial == "RP04-1826246-SC" and qr.version == 4
    square = square_from_qr(qr, image)
    assert np.linalg.norm(square.mean(axis=0) - centre) < 4
    sides = np.linalg.norm(np.roll(square, -1, axis=0) - square, axis=1)
    np.testing.assert_allclose(sides, 50 * px_per_mm, rtol=0.05)


def test_the_reflectance_of_a_synthetic_panel_is_its_albedo(rng):
    albedo, irradiance = 0.513, 0.87
    image, _, _ = panel_scene(rng, albedo=albedo, irradiance=irradiance)
    qr = find_panel_qr(image)
    mean, std, count = region_stats(image, square_from_qr(qr, image))
    assert count > 2000 and std < 1e-9
    measured = panel_irradiance(mean, albedo)
    assert measured == pytest.approx(irradiance, rel=1e-9)
    reflectance = image * math.pi / measured
    assert float(np.median(reflectance[260:340, 228:308])) == pytest.approx(albedo, rel=1e-6)  # inside the square


def test_no_qr_code_is_none_and_a_square_off_the_image_is_refused(rng):
    assert find_panel_qr(rng.uniform(0, 1, size=(200, 300))) is None
    qr = PanelQR("RP04-1826246-SC", "RP04-1826246-SC", 4, np.array([[10.0, 10], [60, 10], [60, 60], [10, 60]]))
    with pytest.raises(CadeError, match="--panel-corners"):
        square_from_qr(qr, np.ones((80, 80)))


def test_albedo_options_and_the_qr_line():
    assert albedo_from_qr("RP04-1826246-SC_04005111000507", 475) == pytest.approx(0.5105)
    assert albedo_from_qr("RP02-1603036-SC", 475) is None
    names = ["Blue", "Green", "Red", "NIR", "Red edge"]
    assert parse_albedo("51.3,51.3,51.3,51.0,51.2", names)["NIR"] == pytest.approx(0.510)
    assert parse_albedo("nir=0.5, Red edge=0.52", names) == {"NIR": 0.5, "Red edge": 0.52}
    with pytest.raises(CadeError, match="5 bands"):
        parse_albedo("0.5,0.5", names)
    with pytest.raises(CadeError, match="Thermal"):
        parse_albedo("Thermal=0.5", names)
    assert parse_corners("1,2,3,4,5,6,7,8").shape == (4, 2)
    with pytest.raises(CadeError, match="--panel-corners"):
        parse_corners("1,2,3")


# ---------------------------------------------------------------- real captures

def field(shared_data, stem: str) -> list:
    folder = shared_data / "micasense" / "rededge-m-field"
    files = sorted(folder.glob(f"{stem}_*.tif"))
    if len(files) != 5:
        pytest.skip(f"{folder} lacks {stem}")
    return files


def reflect_area(path) -> np.ndarray:
    xmp = parse_xmp(tifffile.TiffFile(path).pages[0].tags[700].value)
    return np.array(numbers(xmp["Camera:ReflectArea"])).reshape(-1, 2), numbers(xmp["Camera:Albedo"])[0]


def test_radiance_of_a_real_capture_is_finite_and_positive_on_the_panel(shared_data):
    for path in field(shared_data, "IMG_0000"):
        image = radiance(tifffile.imread(path), read_radiometric_model(path))
        assert np.isfinite(image).all() and image.min() >= 0
        corners, _ = reflect_area(path)
        mean, std, count = region_stats(image, corners)
        assert count > 5000 and mean > 0.02 and std / mean < 0.05  # the panel: bright and uniform
        dls = read_dls(path)
        assert dls is not None and horizontal_irradiance(dls) > 0
        if "_2" not in path.stem:
            continue  # the panel's finders once, on Green
        by_tag, by_corners = measure_panel(path), measure_panel(path, corners=corners, albedo=0.5)
        assert by_tag.found_by == "camera ReflectArea tag" and by_corners.found_by == "--panel-corners"
        assert by_corners.radiance == by_tag.radiance and by_corners.irradiance == pytest.approx(np.pi * mean / 0.5)
        qr = find_panel_qr(tifffile.imread(path))  # the QR code's square: on the same grey, within 1 %
        assert qr is not None and qr.serial == "RP04-1826246-SC"
        assert region_stats(image, square_from_qr(qr, tifffile.imread(path)))[0] == pytest.approx(mean, rel=0.01)


def cube_band(path, index: int) -> np.ndarray:
    with tifffile.TiffFile(path) as tiff:
        if len(tiff.pages) > 1:
            return tiff.pages[index].asarray()
        data = tiff.pages[0].asarray()
        return data[index] if data.ndim == 3 and data.shape[0] < data.shape[-1] else data[..., index]


def test_register_capture_reflectance_from_its_own_panel_gives_the_albedo(shared_data, tmp_path, capsys):
    files = field(shared_data, "IMG_0000")
    output, ndvi = tmp_path / "panel.tif", tmp_path / "ndvi.png"
    code, _, err = run_cade(["register-capture", *files, "-o", output, "--plane-only", "--reflectance", "--panel",
                             files[0], "--ndvi", ndvi], capsys)
    assert code == 0, err
    assert "irradiance from the panel shot IMG_0000" in err
    with tifffile.TiffFile(output) as tiff:
        description = json.loads(tiff.pages[0].description)
    assert description["radiometry"]["quantity"] == "reflectance"
    assert description["radiometry"]["irradiance_source"] == "panel IMG_0000"
    green = cube_band(output, 1)  # the reference: not resampled
    assert green.dtype == np.float32
    corners, albedo = reflect_area(files[1])
    mean, _, _ = region_stats(green, corners)
    assert mean == pytest.approx(albedo, rel=1e-3)
    assert ndvi.exists()


def test_register_capture_refuses_radiometry_in_uint16_and_a_lone_panel(shared_data, tmp_path, capsys):
    files = field(shared_data, "IMG_0008")
    code, _, err = run_cade(["register-capture", *files, "-o", tmp_path / "c.tif", "--radiance", "--dtype", "uint16"],
                            capsys)
    assert code != 0 and "float32" in err and "Traceback" not in err
    code, _, err = run_cade(["register-capture", *files, "-o", tmp_path / "c.tif", "--panel", files[0]], capsys)
    assert code != 0 and "--reflectance" in err
    assert not (tmp_path / "c.tif").exists()
    sequoia = sorted((shared_data / "micasense" / "sequoia-tabletop").glob("*.TIF"))
    if sequoia:  # a MicaSense panel's irradiance is in other units than a Sequoia's radiance
        code, _, err = run_cade(["register-capture", *sequoia, "-o", tmp_path / "s.tif", "--reflectance", "--panel",
                                 shared_data / "micasense" / "rededge-m-field" / "IMG_0000_1.tif"], capsys)
        assert code != 0 and "same camera" in err


def test_a_dls2_capture_gives_its_trusted_horizontal_irradiance(shared_data):
    path = shared_data / "micasense" / "rededge-mx-dual" / "IMG_0000_7.tif"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    xmp = parse_xmp(tifffile.TiffFile(path).pages[0].tags[700].value)
    reading = read_dls(path)  # firmware v7.0.0-alpha1 >= 5.1.7: trusted; no scale tag: 0.01
    assert reading.horizontal_trusted
    assert horizontal_irradiance(reading) == pytest.approx(0.01 * numbers(xmp["DLS:HorizontalIrradiance"])[0])
