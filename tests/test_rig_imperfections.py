"""The degradations (cade_cli.evaluation.degradations) do what their docstring says;
benchmarks/rig_imperfections.py refuses unknown ones."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from cade_cli.evaluation.degradations import DEGRADATIONS, degrade

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "rig_imperfections.py"


@pytest.fixture
def band(rng) -> np.ndarray:
    return rng.random((40, 60)).astype(np.float32)


def test_vertical_shifts_move_rows_up(band):
    moved = degrade(band, "vshift-1")
    assert np.allclose(moved[:-1], band[1:], atol=1e-6)  # row y shows row y + 1
    half = degrade(band, "vshift-0.5")
    assert np.allclose(half[:-1], (band[:-1] + band[1:]) / 2, atol=1e-5)


def test_roll_turns_about_the_centre():
    rows = np.repeat(np.arange(40, dtype=np.float32)[:, None], 60, axis=1)  # value = row
    rolled = degrade(rows, "roll-0.2")
    assert np.isclose(rolled[20, 30], 20.0, atol=1e-3)
    # 30 px either side of the centre the rows move by about 30 * tan(0.2 deg) = 0.1 px, oppositely
    left, right = rolled[20, 0] - 20.0, rolled[20, 59] - 20.0
    assert 0.08 < abs(left) < 0.12 and 0.08 < abs(right) < 0.12 and left * right < 0


def test_inversions_and_photometric_changes(band):
    half = degrade(band, "invert-half")
    assert np.allclose(half[:, :30], band[:, :30]) and np.allclose(half[:, 30:], 1 - band[:, 30:])
    assert np.allclose(degrade(band, "invert"), 1 - band)
    vignetted = degrade(band, "vignette")
    assert np.isclose(vignetted[20, 30], band[20, 30]) and np.isclose(vignetted[0, 0], 0.4 * band[0, 0])
    noisy = degrade(band, "noise-6")
    assert np.array_equal(noisy, degrade(band, "noise-6"))  # seeded
    assert not np.array_equal(noisy, degrade(band, "noise-6", seed=1))
    assert 4 / 255 < np.std(noisy - band) < 8 / 255


def test_every_degradation_keeps_shape_and_dtype_and_the_input(band):
    before = band.copy()
    for name in DEGRADATIONS:
        out = degrade(band, name)
        assert out.shape == band.shape and out.dtype == np.float32, name
    np.testing.assert_array_equal(band, before)
    np.testing.assert_array_equal(degrade(band, "none"), band)


def test_unknown_degradation_is_refused(tmp_path):
    spec = importlib.util.spec_from_file_location("rig_imperfections", SCRIPT)
    rig = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rig)
    with pytest.raises(SystemExit, match="unknown degradation 'fog'"):
        rig.main(["--data-dir", str(tmp_path), "--degradations", "fog"])
