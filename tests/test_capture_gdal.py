"""register-capture's cube as GDAL (rasterio) opens it: N bands, named, with a nodata value, the
values cade computed; the uint16 cube and its mask; a --per-band file; and a flight's --per-band
files through `cade batch --captures`."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from capture_scenes import write_capture
from cli_runner import run_cade
from cade_cli.capture.cube import band_pages, write_cube, write_per_band
from cade_cli.capture.model import load_capture
from cade_cli.capture.register import register_capture

rasterio = pytest.importorskip("rasterio")
pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

NAMES = ("Blue", "Green", "Red", "NIR", "Red edge")


@pytest.fixture(scope="module")
def registered(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gdal")
    scene = write_capture(folder / "shot", np.random.default_rng(11), size=(96, 72), saturate=True)
    return folder, register_capture(load_capture(scene.paths), plane_only=True)


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal values, NaN where the other is NaN."""
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


def test_gdal_opens_the_float_cube_as_named_bands(registered, tmp_path):
    _, registration = registered
    path = tmp_path / "cube.tif"
    write_cube(path, registration)
    expected = np.stack(band_pages(registration, dtype="float32"))
    assert np.isnan(expected).any() and np.isposinf(expected).any()  # unseen and saturated pixels to carry
    with rasterio.open(path) as dataset:
        assert dataset.count == 5 and dataset.descriptions == NAMES
        assert np.isnan(dataset.nodata) and dataset.dtypes == ("float32",) * 5
        assert float(dataset.tags(4, "IMAGERY")["CENTRAL_WAVELENGTH_UM"]) == pytest.approx(0.840)
        values = dataset.read()
    assert same(values, expected)
    assert same(tifffile.imread(path), expected)  # the readers in the code base: (N, H, W) as before
    with tifffile.TiffFile(path) as tiff:
        assert json.loads(tiff.pages[0].description)["bands"][3]["name"] == "NIR"


def test_gdal_opens_the_uint16_cube_and_its_mask(registered, tmp_path):
    _, registration = registered
    path, mask = tmp_path / "cube.tif", tmp_path / "cube.valid.tif"
    write_cube(path, registration, dtype="uint16", mask=mask)
    with rasterio.open(path) as dataset:
        assert dataset.count == 5 and dataset.descriptions == NAMES and dataset.nodata == 0
        assert np.array_equal(dataset.read(), np.stack(band_pages(registration, dtype="uint16")))
    with rasterio.open(mask) as dataset:
        assert dataset.count == 5 and dataset.descriptions == tuple(f"seen: {name}" for name in NAMES)
        assert np.array_equal(dataset.read() > 0, np.stack(registration.valid))


def test_gdal_opens_a_per_band_file(registered, tmp_path):
    _, registration = registered
    written = write_per_band(tmp_path, registration)
    pages = band_pages(registration, dtype="float32")
    for name, path, page in zip(NAMES, written, pages):
        with rasterio.open(path) as dataset:
            assert dataset.count == 1 and dataset.descriptions == (name,) and np.isnan(dataset.nodata)
            assert same(dataset.read(1), page)


def test_a_flight_writes_its_per_band_files(tmp_path, capsys):
    flight, bands, out = tmp_path / "flight", tmp_path / "flight" / "aligned", tmp_path / "cubes"
    rng = np.random.default_rng(2)
    for name in ("IMG_0001", "IMG_0002"):
        write_capture(flight, rng, size=(64, 48), name=name, capture_id=name)
    arguments = ["batch", "--captures", flight, "-o", out, "--plane-only", "--per-band", bands]
    code, stdout, err = run_cade(arguments, capsys)
    assert code == 0 and "2 done" in stdout, err
    assert sorted(path.name for path in bands.iterdir()) == [f"IMG_000{c}_{k}.tif" for c in (1, 2) for k in range(1, 6)]
    with rasterio.open(bands / "IMG_0002_4.tif") as dataset:
        assert dataset.descriptions == ("NIR",)
    assert np.array_equal(tifffile.imread(bands / "IMG_0001_2.tif"), tifffile.imread(flight / "IMG_0001_2.tif"))
    record = json.loads((out / "IMG_0001.tif.cade.json").read_text())
    assert "per-band IMG_0001_3.tif" in record["outputs"]
    # the aligned files sit inside the flight folder: a rerun does not take them as captures, and resumes
    code, stdout, err = run_cade(arguments, capsys)
    assert code == 0 and "0 done, 2 already finished" in stdout, err
    (bands / "IMG_0002_5.tif").unlink()  # a per-band file gone: that capture is redone
    code, stdout, _ = run_cade(arguments, capsys)
    assert code == 0 and "1 done, 1 already finished" in stdout and (bands / "IMG_0002_5.tif").is_file()
    code, _, err = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only", "--per-band", flight], capsys)
    assert code != 0 and "--per-band" in err and len(err.strip().splitlines()) == 1
