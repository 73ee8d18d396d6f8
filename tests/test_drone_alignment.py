"""benchmarks/drone_alignment.py on the real captures (../shared/data/micasense; skipped where
absent): it finds the four captures and their bands with the product's reader as the data's
README lists them; on the nearly planar field capture the lens rotations (the anchors' start,
on the product's frame and grid) line the bands up far better than the raw files do; every
method is scored on one grid, and on the windows every method could score."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from cade_cli.capture.alignment import alignment
from cade_cli.capture.anchors import register_anchor
from cade_cli.capture.model import load_capture

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "drone_alignment.py"


@pytest.fixture
def drone_alignment():
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        import drone_alignment
        yield drone_alignment
    finally:
        sys.path.remove(str(SCRIPT.parent))


@pytest.fixture
def micasense(shared_data) -> Path:
    folder = shared_data / "micasense"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    return folder


def test_the_captures_and_their_bands_are_found(drone_alignment, micasense):
    captures = drone_alignment.find_captures(micasense)
    first_delivery = {"rededge-m-bench/IMG_0001", "rededge-m-bench/IMG_0007", "rededge-m-field/IMG_0008",
                      "sequoia-tabletop/IMG_180413_080658_0000"}  # and the panel shots that came later
    assert first_delivery <= set(captures)
    rededge = ["Blue", "Green", "Red", "NIR", "Red edge"]  # RigCameraIndex order (README)
    for name, capture in captures.items():
        expected = (["Green", "Red", "Red edge", "NIR"] if name.startswith("sequoia") else
                    rededge + ["Blue-444", "Green-531", "Red-650", "Red edge-705", "Red edge-740"]
                    if name.startswith("rededge-mx-dual") else rededge)
        assert capture.names() == expected and capture.reference_band.name == "Green"
        assert [band.rig_index for band in capture.bands] == list(range(len(expected)))
        focal = [band.lens.focal for band in capture.bands]
        low, high = (1061, 1062) if name.startswith("sequoia") else (1440, 1460)
        assert all(low < f < high for f in focal)


def test_lens_rotations_line_up_the_field_capture(micasense):
    capture = load_capture(sorted((micasense / "rededge-m-field").glob("IMG_0008_*.tif")))
    rotated = register_anchor(capture, ecc=False)
    reference = rotated.bands["Green"]
    assert np.isfinite(reference).all()  # the reference band's raw grid: every pixel seen
    raw = tifffile.imread(capture.bands[2].path).astype(np.float32)  # Red: the largest raw offset (~40 px)
    before = alignment(reference, raw, search=48)
    after = alignment(reference, rotated.bands["Red"], search=48)
    assert before.median > 10 and after.median < 3 and after.windows > 50, (before, after)


def test_every_method_is_scored_on_one_grid_and_on_the_common_windows(drone_alignment, micasense):
    capture = load_capture(sorted((micasense / "rededge-m-field").glob("IMG_0008_*.tif")))
    results = {"unaligned": drone_alignment.Registered(
        {b.name: tifffile.imread(b.path).astype(np.float32) for b in capture.bands}, 0.0, 0.0),
        "rotations": drone_alignment.Registered(register_anchor(capture, ecc=False).bands, 0.0, 0.0)}
    scored = drone_alignment.score(capture, results)
    for band in ("Blue", "Red", "NIR", "Red edge"):
        own = {method: scored[method].own[band] for method in results}
        common = {method: scored[method].common[band] for method in results}
        assert len({a.windows for a in common.values()}) == 1  # the same windows for every method
        assert all(common[m].windows <= own[m].windows for m in results)
        assert common["rotations"].median < common["unaligned"].median


def test_a_folder_without_band_files_is_refused_in_one_line(tmp_path):
    done = subprocess.run([sys.executable, SCRIPT, "--data-dir", tmp_path], capture_output=True, text=True)
    assert done.returncode != 0 and done.stderr.strip().count("\n") == 0
    assert "no band files" in done.stderr
