"""Protocols: task lists and subsets, the bands handed to the matcher (degraded right
bands), the one fill stage, the RGB median, scoring."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.evaluation import protocols
from cade_cli.evaluation.metrics import score
from cade_cli.evaluation.protocols import (
    MEDIAN_NAME,
    PROTOCOLS,
    get_protocol,
    luminance,
    median_combine,
    run_protocol,
)
from cade_cli.evaluation.timing import Timing
from cade_cli.matching import DisparityResult
from cade_cli.matching.disparity import densify

SHAPE = (6, 9)


def _pair(rng):
    """Left/right RGB whose channels are told apart by their offset (c and 10 + c)."""
    noise = rng.random((2, *SHAPE, 3)).astype(np.float32) * 0.1
    offsets = np.arange(3, dtype=np.float32)
    return offsets + noise[0], 10 + offsets + noise[1]


class RecordingMatcher:
    """Fake matcher: remembers its bands and returns a fixed map."""

    def __init__(self, disparity=None):
        self.calls = []
        self.disparity = disparity

    def __call__(self, left, right):
        self.calls.append((left.copy(), right.copy()))
        disparity = np.zeros(left.shape, np.float32) if self.disparity is None else self.disparity
        return DisparityResult(disparity.copy(), np.ones(left.shape, bool))


def test_task_lists_are_stable():
    cs = get_protocol("cs").tasks
    assert [t.name for t in cs] == ["R>G", "R>B", "G>R", "G>B", "B>R", "B>G"]
    assert [(t.left_channel, t.right_channel) for t in cs] == [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]
    assert not any(t.grey for t in cs)
    rgb = get_protocol("rgb")
    assert [t.name for t in rgb.tasks] == ["R>R", "G>G", "B>B"]
    assert [(t.left_channel, t.right_channel) for t in rgb.tasks] == [(0, 0), (1, 1), (2, 2)]
    assert rgb.combine == "median"
    (native,) = get_protocol("native").tasks
    assert native.grey and native.left_channel is None and native.right_channel is None
    assert list(PROTOCOLS) == ["cs", "rgb", "native"]


def test_unknown_protocol_lists_choices():
    with pytest.raises(CadeError, match="cs, rgb, native"):
        get_protocol("mono")


@pytest.mark.parametrize("name", ["cs", "rgb"])
def test_matcher_gets_the_tasks_bands(rng, name):
    left_rgb, right_rgb = _pair(rng)
    matcher = RecordingMatcher()
    run_protocol(name, matcher, left_rgb, right_rgb)
    tasks = get_protocol(name).tasks
    assert len(matcher.calls) == len(tasks)
    for task, (left, right) in zip(tasks, matcher.calls):
        assert left.shape == SHAPE and left.dtype == np.float32 and left.flags.c_contiguous
        np.testing.assert_array_equal(left, left_rgb[:, :, task.left_channel])
        np.testing.assert_array_equal(right, right_rgb[:, :, task.right_channel])


def test_luminance_weights():
    for channel, weight in enumerate((0.299, 0.587, 0.114)):
        rgb = np.zeros((2, 2, 3), np.float32)
        rgb[:, :, channel] = 1.0
        np.testing.assert_allclose(luminance(rgb), weight, rtol=1e-6)


def test_luminance_of_integer_images_is_float32():
    rgba = np.array([[[255, 0, 0, 7], [10, 20, 30, 255]]], np.uint8)
    grey = luminance(rgba)
    assert grey.dtype == np.float32 and grey.shape == (1, 2)
    np.testing.assert_allclose(grey, [[0.299 * 255, 0.299 * 10 + 0.587 * 20 + 0.114 * 30]], rtol=1e-6)


def test_native_matches_grey(rng):
    left_rgb, right_rgb = _pair(rng)
    matcher = RecordingMatcher()
    (result,) = run_protocol("native", matcher, left_rgb, right_rgb)
    (left, right), = matcher.calls
    expected_left = 0.299 * left_rgb[..., 0] + 0.587 * left_rgb[..., 1] + 0.114 * left_rgb[..., 2]
    expected_right = 0.299 * right_rgb[..., 0] + 0.587 * right_rgb[..., 1] + 0.114 * right_rgb[..., 2]
    np.testing.assert_allclose(left, expected_left, rtol=1e-6)
    np.testing.assert_allclose(right, expected_right, rtol=1e-6)
    assert result.name == "grey" and result.scored


def test_median_combine_by_hand():
    maps = [np.array([[1.0, 5.0]]), np.array([[2.0, 4.0]]), np.array([[9.0, 3.0]])]
    valids = [np.array([[True, True]]), np.array([[True, False]]), np.array([[False, False]])]
    median, valid = median_combine(maps, valids)
    np.testing.assert_array_equal(median, [[2.0, 4.0]])
    np.testing.assert_array_equal(valid, [[True, False]])  # 2 of 3 valid; 1 of 3 is not


def test_rgb_protocol_scores_only_the_median(rng):
    left_rgb, right_rgb = _pair(rng)
    per_channel = {0: 1.0, 1: 9.0, 2: 2.0}  # R>R says 1, G>G says 9, B>B says 2

    def matcher(left, right):
        channel = int(round(float(left.mean())))  # left channel c has values c + [0, 0.1)
        return DisparityResult(np.full(left.shape, per_channel[channel], np.float32), np.ones(left.shape, bool))

    results = run_protocol("rgb", matcher, left_rgb, right_rgb)
    assert [r.name for r in results] == ["R>R", "G>G", "B>B", MEDIAN_NAME]
    assert [r.scored for r in results] == [False, False, False, True]
    np.testing.assert_array_equal(results[-1].disparity, np.full(SHAPE, 2.0))
    assert results[-1].valid.all()
    assert results[-1].seconds >= sum(r.seconds for r in results[:3])


@pytest.mark.parametrize("name", list(PROTOCOLS))
def test_exact_matcher_scores_zero_under_every_protocol(rng, name):
    left_rgb, right_rgb = _pair(rng)
    gt = rng.uniform(0, 20, SHAPE).astype(np.float32)
    gt[0, :3] = np.nan  # unknown GT
    matcher = RecordingMatcher(np.nan_to_num(gt, nan=0.0))
    results = run_protocol(name, matcher, left_rgb, right_rgb)
    scored = [r for r in results if r.scored]
    assert len(scored) == {"cs": 6, "rgb": 1, "native": 1}[name]
    for result in scored:
        metrics = score(result.disparity, gt, nonocc=np.ones(SHAPE, bool), pred_valid=result.valid)
        assert all(value == 0.0 for value in metrics.values()), (result.name, metrics)


def test_bad_images_raise():
    with pytest.raises(CadeError, match=r"\(H, W, 3\)"):
        run_protocol("cs", RecordingMatcher(), np.zeros(SHAPE), np.zeros(SHAPE))
    with pytest.raises(CadeError, match="differ"):
        run_protocol("cs", RecordingMatcher(), np.zeros((*SHAPE, 3)), np.zeros((6, 8, 3)))


def test_task_subset_runs_only_those_tasks_in_protocol_order(rng):
    left_rgb, right_rgb = _pair(rng)
    matcher = RecordingMatcher()
    results = run_protocol("cs", matcher, left_rgb, right_rgb, tasks=["G>B", "R>B"])
    assert [r.name for r in results] == ["R>B", "G>B"]
    assert len(matcher.calls) == 2
    np.testing.assert_array_equal(matcher.calls[0][0], left_rgb[:, :, 0])
    np.testing.assert_array_equal(matcher.calls[0][1], right_rgb[:, :, 2])


def test_task_subsets_that_break_a_protocol_are_refused():
    with pytest.raises(CadeError, match="none of the tasks R>G"):
        get_protocol("rgb").select(["R>G"])
    with pytest.raises(CadeError, match="combines all of R>R, G>G, B>B"):
        get_protocol("rgb").select(["R>R", "G>G"])
    assert get_protocol("rgb").select(None) is get_protocol("rgb")


def test_degradation_applies_to_the_right_band_only(rng):
    left_rgb, right_rgb = _pair(rng)
    matcher = RecordingMatcher()
    run_protocol("cs", matcher, left_rgb, right_rgb, tasks=["R>B"], degrade=lambda band: -band)
    ((left, right),) = matcher.calls
    np.testing.assert_array_equal(left, left_rgb[:, :, 0])
    np.testing.assert_array_equal(right, -right_rgb[:, :, 2])


def test_every_returned_map_is_the_matchers_map_densified(rng):
    """The protocols are where the evaluation fills (matching.disparity.densify), once per map."""
    left_rgb, right_rgb = _pair(rng)
    raw = rng.uniform(0, 20, SHAPE).astype(np.float32)
    valid = rng.random(SHAPE) < 0.6
    unfilled = np.where(valid, raw, np.float32(np.nan))

    def matcher(left, right):
        return DisparityResult(unfilled.copy(), valid.copy())

    (result,) = run_protocol("native", matcher, left_rgb, right_rgb)
    np.testing.assert_array_equal(result.disparity, densify(unfilled, valid))
    np.testing.assert_array_equal(result.valid, valid)
    assert np.isfinite(result.disparity).all()


def test_rgb_median_combines_the_densified_maps_and_is_densified_again(rng, monkeypatch):
    left_rgb, right_rgb = _pair(rng)
    row = np.array([[np.nan, 4.0, np.nan, 8.0]], np.float32)  # unfilled: 4 4 4 8 once filled
    maps = {0: row, 1: np.full((1, 4), 6.0, np.float32), 2: np.full((1, 4), 5.0, np.float32)}
    valids = {0: np.isfinite(row), 1: np.array([[False, True, True, True]]), 2: np.array([[False, True, True, True]])}

    def matcher(left, right):
        channel = int(round(float(left.mean())))
        return DisparityResult(maps[channel].copy(), valids[channel].copy())

    calls = []

    def counting_densify(disparity, valid):
        calls.append(1)
        return densify(disparity, valid)

    monkeypatch.setattr(protocols, "densify", counting_densify)
    left_rgb, right_rgb = left_rgb[:1, :4], right_rgb[:1, :4]
    *tasks, combined = run_protocol("rgb", matcher, left_rgb, right_rgb)
    assert len(calls) == 4  # three task maps, then the median
    np.testing.assert_array_equal(tasks[0].disparity, [[4, 4, 4, 8]])
    # medians of (4, 6, 5), (4, 6, 5), (4, 6, 5), (8, 6, 5); the first pixel has 0 of 3 valid votes
    np.testing.assert_array_equal(combined.valid, [[False, True, True, True]])
    np.testing.assert_array_equal(combined.disparity, [[5, 5, 5, 6]])


def test_timing_repeats_the_matcher_and_keeps_the_median(rng):
    left_rgb, right_rgb = _pair(rng)
    matcher = RecordingMatcher()
    prepared = []
    (result,) = run_protocol("native", matcher, left_rgb, right_rgb, timing=Timing(warmup=2, repeat=3),
                             prepare=lambda left, right: prepared.append(left.shape))
    assert len(matcher.calls) == 5 and len(prepared) == 5
    assert result.seconds >= 0
