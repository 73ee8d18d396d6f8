"""benchmarks/drone_alignment.py on the real captures (../shared/data/micasense; skipped where
absent): its private metadata reader finds the four captures and their bands as the data's
README lists them, and on the nearly planar field capture the lens rotations it reads line
the bands up far better than the raw files do."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cade_cli.capture.alignment import alignment
from cade_cli.capture.homography import warp_band

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
    assert sorted(captures) == ["rededge-m-bench/IMG_0001", "rededge-m-bench/IMG_0007", "rededge-m-field/IMG_0008",
                                "sequoia-tabletop/IMG_180413_080658_0000"]
    for name, bands in captures.items():
        expected = ["Green", "Red", "Red edge", "NIR"] if name.startswith("sequoia") else \
            ["Blue", "Green", "Red", "NIR", "Red edge"]  # RigCameraIndex order (README)
        assert [band.name for band in bands] == expected
        assert [band.index for band in bands] == list(range(len(expected)))
        focal = [band.camera[0, 0] for band in bands]
        assert all(1061 < f < 1062 for f in focal) if name.startswith("sequoia") else all(1440 < f < 1457 for f in focal)
        for band in bands:
            assert np.allclose(band.rotation @ band.rotation.T, np.eye(3))


def test_lens_rotations_line_up_the_field_capture(drone_alignment, micasense):
    bands = drone_alignment.find_captures(micasense / "rededge-m-field")["rededge-m-field/IMG_0008"]
    reference = bands[1]
    flat_reference, reference_camera = drone_alignment.undistorted(reference)
    assert np.isnan(flat_reference[0, 0]) and np.isfinite(flat_reference[480, 640])  # alpha = 1: black corners
    for band in (bands[2],):  # Red: the largest raw offset (~40 px)
        image, camera = drone_alignment.undistorted(band)
        homography = drone_alignment.rotation_homography(band, camera, reference, reference_camera)
        raw = alignment(reference.image, band.image, search=48)
        rotated = alignment(flat_reference, warp_band(image, homography, image.shape[::-1]), search=48)
        assert raw.median > 10 and rotated.median < 3 and rotated.windows > 50, (band.name, raw, rotated)


def test_a_folder_without_band_files_is_refused_in_one_line(tmp_path):
    done = subprocess.run([sys.executable, SCRIPT, "--data-dir", tmp_path], capture_output=True, text=True)
    assert done.returncode != 0 and done.stderr.strip().count("\n") == 0
    assert "no band files" in done.stderr
