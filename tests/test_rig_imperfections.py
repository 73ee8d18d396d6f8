"""The degradations of benchmarks/rig_imperfections.py do what its docstring says."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "rig_imperfections.py"
spec = importlib.util.spec_from_file_location("rig_imperfections", SCRIPT)
rig = importlib.util.module_from_spec(spec)
spec.loader.exec_module(rig)


@pytest.fixture
def band(rng) -> np.ndarray:
    return rng.random((40, 60)).astype(np.float32)


def test_vertical_shifts_move_rows_up(band):
    moved = rig.DEGRADATIONS["vshift-1"](band)
    assert np.allclose(moved[:-1], band[1:], atol=1e-6)  # row y shows row y + 1
    half = rig.DEGRADATIONS["vshift-0.5"](band)
    assert np.allclose(half[:-1], (band[:-1] + band[1:]) / 2, atol=1e-5)


def test_roll_turns_about_the_centre():
    rows = np.repeat(np.arange(40, dtype=np.float32)[:, None], 60, axis=1)  # value = row
    rolled = rig.DEGRADATIONS["roll-0.2"](rows)
    assert np.isclose(rolled[20, 30], 20.0, atol=1e-3)
    # 30 px either side of the centre the rows move by about 30 * tan(0.2 deg) = 0.1 px, oppositely
    left, right = rolled[20, 0] - 20.0, rolled[20, 59] - 20.0
    assert 0.08 < abs(left) < 0.12 and 0.08 < abs(right) < 0.12 and left * right < 0


def test_inversions_and_photometric_changes(band):
    half = rig.DEGRADATIONS["invert-half"](band)
    assert np.allclose(half[:, :30], band[:, :30]) and np.allclose(half[:, 30:], 1 - band[:, 30:])
    assert np.allclose(rig.DEGRADATIONS["invert"](band), 1 - band)
    vignetted = rig.DEGRADATIONS["vignette"](band)
    assert np.isclose(vignetted[20, 30], band[20, 30]) and np.isclose(vignetted[0, 0], 0.4 * band[0, 0])
    noisy = rig.DEGRADATIONS["noise-6"](band)
    assert np.array_equal(noisy, rig.DEGRADATIONS["noise-6"](band))  # seeded
    assert 4 / 255 < np.std(noisy - band) < 8 / 255


def test_unknown_degradation_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="unknown degradation"):
        rig.main(["--data-dir", str(tmp_path), "--degradations", "fog"])
