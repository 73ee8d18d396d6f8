"""benchmarks/edge_headroom.py: its candidates hold both surfaces of a depth edge, its oracle puts a
shifted edge back where the ground truth has it, its local correlation finds a texture's shift (and is
blind to inverted contrast, which is why it picks badly between bands), and its consistency pick undoes
a fattened edge on the side the right view sees."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import edge_headroom  # noqa: E402
from synthetic import smooth_texture  # noqa: E402

FAR, NEAR = 10.0, 20.0


def step_scene(shape=(40, 100), first=40, last=60):
    """True left map: FAR everywhere, NEAR on columns [first, last) (a near bar)."""
    truth = np.full(shape, FAR, np.float32)
    truth[:, first:last] = NEAR
    return truth


def test_candidates_are_the_two_surfaces_near_an_edge_only():
    truth = step_scene()
    rows, columns, options = edge_headroom.candidates(truth, 4)
    assert set(np.unique(columns)) == set(range(36, 44)) | set(range(56, 64))
    np.testing.assert_array_equal(options[:, 1], FAR)
    np.testing.assert_array_equal(options[:, 2], NEAR)
    np.testing.assert_array_equal(options[:, 0], truth[rows, columns])


@pytest.mark.parametrize("radius", [2, 4])
def test_the_oracle_puts_a_fattened_edge_back_and_keeps_unknown_pixels(radius):
    truth = step_scene()
    fattened = truth.copy()
    fattened[:, 60:60 + radius] = NEAR  # the near bar spreads over the far surface, as far as the window reaches
    gt = truth.copy()
    gt[:5] = np.nan
    fixed = edge_headroom.oracle(fattened, gt, radius)
    np.testing.assert_array_equal(fixed[5:], truth[5:])
    np.testing.assert_array_equal(fixed[:5], fattened[:5])


def test_window_correlation_finds_a_shift_and_reads_inverted_contrast_as_a_mismatch():
    rng = np.random.default_rng(3)
    scene = smooth_texture(rng, (60, 140), 1.5).astype(np.float32)
    left, right = scene[:, 20:120], scene[:, 32:132]  # right(x - 12) = left(x): disparity 12
    left, right = edge_headroom.stretched(left), edge_headroom.stretched(right)
    guide = edge_headroom.guide_band(left).astype(np.float32)
    rows, columns = np.mgrid[10:50, 30:90]
    rows, columns = rows.ravel(), columns.ravel()
    at = {d: edge_headroom.window_correlation(left, right, guide, rows, columns, np.full(rows.size, d, np.float32))
          for d in (12.0, 7.0, 17.0)}
    assert np.median(at[12.0]) > 0.99
    assert np.median(at[7.0]) < 0.7 and np.median(at[17.0]) < 0.7
    inverted = edge_headroom.window_correlation(left, 255.0 - right, guide, rows, columns, np.full(rows.size, 12.0))
    assert np.median(inverted) < -0.99


def test_the_consistency_pick_undoes_fattening_the_right_view_sees():
    truth = step_scene()
    fattened = truth.copy()
    fattened[:, 60:63] = NEAR
    right_view = np.full(truth.shape, FAR, np.float32)
    right_view[:, 40 - int(NEAR):60 - int(NEAR)] = NEAR  # the bar seen from the right: 20 px further left
    picked = edge_headroom.consistency_pick(fattened, right_view, 4)
    np.testing.assert_array_equal(picked, truth)
