"""benchmarks/cade_errors.py: its regions are the ones ``cade benchmark`` scores, and its error
classes say which stage made each gross error (a replacement that broke a right network value is
counted as such; a kept network value where SGBM rejected the match is counted apart)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import cade_errors  # noqa: E402

from cade_cli.data.dataset import Scene  # noqa: E402


def bar_scene(nonocc: bool = True) -> Scene:
    """A 40 x 100 scene: disparity 10, and 20 on columns 40..59; the 10 px left of the bar occluded."""
    truth = np.full((40, 100), 10.0, np.float32)
    truth[:, 40:60] = 20.0
    visible = np.ones(truth.shape, bool)
    visible[:, 30:40] = False
    band = np.zeros((40, 100, 3), np.float32)
    return Scene("bar", band, band, truth, visible if nonocc else None, 32, "test")


def test_the_edge_region_is_the_visible_band_along_the_jumps():
    scene = bar_scene()
    edge = cade_errors.scored_region(scene, "edge")
    assert edge[:, 60:64].all() and edge[:, 56:60].all()  # both sides of the bar's right jump
    assert not edge[:, 30:40].any()  # occluded: not an edge pixel
    assert not edge[:, 70:].any() and not edge[:, :25].any()
    assert cade_errors.scored_region(scene, "nonocc").sum() == 40 * 90
    assert cade_errors.scored_region(scene, "all").all()
    with pytest.raises(SystemExit, match="no nonocc"):
        cade_errors.scored_region(bar_scene(nonocc=False), "nonocc")


def test_each_gross_error_is_put_in_the_class_of_the_stage_that_made_it():
    truth = np.full((1, 4), 10.0, np.float32)
    network = np.array([[10.0, 20.0, 20.0, 20.0]], np.float32)  # right, then wrong three times
    candidate = np.array([[20.0, 20.0, 10.0, 90.0]], np.float32)
    accepted = np.array([[True, True, False, True]])
    near = accepted & (np.abs(candidate - network) <= 32)
    maps = {"network": network, "candidate": candidate, "accepted": accepted, "near": near,
            "sgbm": np.where(accepted, candidate, network), "cade": np.where(near, candidate, network)}
    row = cade_errors.analyse(maps, truth, np.ones(truth.shape, bool))
    # pixel 0 broke a right value, pixel 1 replaced a wrong one wrongly, pixel 2 kept (rejected), pixel 3 kept (far)
    assert row["refined-wrong"] == 50.0 and row["broke"] == 25.0
    assert row["kept-rejected"] == 25.0 and row["kept-far"] == 25.0 and row["far-right"] == 0.0
    assert row["cade_bmp3"] == 100.0 and row["oracle_bmp3"] == 75.0
