"""The no-ground-truth alignment measure (cade_cli/capture/alignment.py): bands shifted by known
amounts in known places must report those shifts there, identical bands nothing, and windows
without texture or without a registered value must not be scored."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cade_cli.capture.alignment import alignment, coverage, summarise, window_shifts
from cade_cli.errors import CadeError
from synthetic import smooth_texture

SHAPE = (256, 448)
HALF = 256
"""The column where the shifted left half meets the unshifted right half: a window edge of the
default grid (64 px windows from the image's corner)."""
WINDOW = 64


def inside(centres: np.ndarray, shift: tuple[float, float], slack: float = 0.5) -> np.ndarray:
    """Whether each window's match (the window moved by ``shift``) lies inside the image, bar
    ``slack`` px."""
    top, left = centres[:, 0] - (WINDOW - 1) / 2 + shift[1], centres[:, 1] - (WINDOW - 1) / 2 + shift[0]
    return ((top >= -slack) & (left >= -slack) & (top + WINDOW <= SHAPE[0] + slack)
            & (left + WINDOW <= SHAPE[1] + slack))


def shifted(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``image``'s content moved by (dx, dy) px (cubic resampling, reflected borders)."""
    cols, rows = np.meshgrid(np.arange(image.shape[1], dtype=np.float32), np.arange(image.shape[0], dtype=np.float32))
    return cv2.remap(image, cols - np.float32(dx), rows - np.float32(dy), cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_REFLECT)


@pytest.fixture
def reference(rng) -> np.ndarray:
    return smooth_texture(rng, SHAPE, sigma=2.0)


@pytest.mark.parametrize("shift", [(0.4, 0.0), (2.3, -0.6), (-7.5, 3.25)])
def test_a_half_shifted_band_reports_its_shift_in_that_half_only(reference, shift):
    band = 1.0 - 0.8 * shifted(reference, *shift) ** 2  # another band: inverted, non-linear response
    band[:, HALF:] = 1.0 - 0.8 * reference[:, HALF:] ** 2
    found = window_shifts(reference, band)
    left = found.centres[:, 1] < HALF
    scored = np.isfinite(found.shifts).all(axis=1)
    assert scored[~left].all() and scored[left & inside(found.centres, shift)].all()
    assert not scored[left & ~inside(found.centres, shift, slack=1.0)].any()  # a match outside the band: not scored
    assert (left & scored).sum() >= 8 and (~left).sum() >= 8
    assert np.abs(found.shifts[left & scored] - shift).max() < 0.15
    assert np.abs(found.shifts[~left]).max() < 0.1
    summary = summarise(found, 1.0)
    assert summary.windows == scored.sum()
    assert summary.share_over_1px == pytest.approx((left & scored).sum() / scored.sum() if np.hypot(*shift) > 1 else 0)


def test_identical_bands_give_no_shift(reference):
    result = alignment(reference, reference)
    assert result.windows > 0 and result.median < 0.01 and result.p90 < 0.01
    assert result.share_over_1px == 0 and result.coverage == 1.0 and result.beyond == 0


def test_a_textureless_window_is_not_scored(reference):
    flat = reference.copy()
    flat[64:128, 192:256] = 0.5  # exactly one window of the grid
    found = window_shifts(flat, shifted(flat, 1.0, 0.0))
    centre = (found.centres[:, 0] == 95.5) & (found.centres[:, 1] == 223.5)
    assert centre.sum() == 1
    assert np.isnan(found.shifts[centre]).all()
    others = ~centre & inside(found.centres, (1.0, 0.0))
    assert np.isfinite(found.shifts[others]).all()
    assert np.abs(found.shifts[others] - (1.0, 0.0)).max() < 0.15


def test_the_unseen_is_not_scored_and_lowers_the_coverage(reference):
    band = reference.copy()
    band[:, :SHAPE[1] // 4] = np.nan
    result = alignment(reference, band)
    assert result.coverage == pytest.approx(0.75)
    found = window_shifts(reference, band)
    near = found.centres[:, 1] - (WINDOW - 1) / 2 < SHAPE[1] // 4  # the match would hold a NaN
    assert np.isnan(found.shifts[near]).all() and np.isfinite(found.shifts[~near]).all()
    assert result.windows == (~near).sum()


def test_a_shift_beyond_the_search_is_kept_as_a_lower_bound(reference):
    found = window_shifts(reference, shifted(reference, 8.6, 0.0), search=8, window=48)
    scored = np.isfinite(found.shifts).all(axis=1)
    assert scored.sum() > len(scored) // 2 and found.beyond[scored].all()
    assert np.all(found.magnitudes[scored] >= 8)
    assert summarise(found, 1.0).share_over_1px == 1.0


def test_unrelated_bands_score_no_window_and_say_so(rng, reference):
    result = alignment(reference, rng.random(SHAPE).astype(np.float32))
    assert result.windows <= 2  # noise correlates with the texture nowhere, bar chance
    empty = alignment(np.full(SHAPE, 0.5, np.float32), np.full(SHAPE, 0.5, np.float32))
    assert empty.windows == 0 and np.isnan(empty.median)


def test_bad_inputs_are_refused_in_one_line(reference):
    with pytest.raises(CadeError, match="one size"):
        window_shifts(reference, reference[:, :-1])
    with pytest.raises(CadeError, match="does not fit"):
        window_shifts(reference[:40, :40], reference[:40, :40])
    with pytest.raises(CadeError, match="no valid pixel"):
        coverage(np.full(SHAPE, np.nan), reference)
