"""Two calls side by side on OpenCV's threads, and the CADE matcher's stages that use it: the
same results, bit for bit, on one thread or two."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

from cade_cli.matching.chooser import FEATURES, ROWS, Chooser, chooser_features, disputed
from cade_cli.matching.cost import rank_transform
from cade_cli.matching.refinement import RankSgbmRefinement
from cade_cli.matching.side_by_side import side_by_side


@pytest.fixture
def opencv_threads():
    """Set OpenCV's thread count for one test, restored after it."""
    before = cv2.getNumThreads()
    yield cv2.setNumThreads
    cv2.setNumThreads(before)


@pytest.mark.parametrize("threads, apart", [(1, False), (2, True)])
def test_second_call_runs_on_another_thread_only_with_two_threads(opencv_threads, threads, apart):
    opencv_threads(threads)
    first, second = side_by_side(lambda: ("first", threading.get_ident()), lambda: ("second", threading.get_ident()))
    assert first[0] == "first" and second[0] == "second"
    assert first[1] == threading.get_ident()
    assert (second[1] != first[1]) == apart


def test_a_failing_first_call_still_waits_for_the_second(opencv_threads):
    opencv_threads(2)
    finished = threading.Event()

    def fail():
        raise ValueError("first failed")

    def slow():
        finished.wait(0.2)
        finished.set()
        return 1

    with pytest.raises(ValueError, match="first failed"):
        side_by_side(fail, slow)
    assert finished.is_set()


def disputed_pair(seed: int, shape=(96, 128)):
    rng = np.random.default_rng(seed)
    network = rng.uniform(0, 40, shape).astype(np.float32)
    candidate = (network + rng.normal(0, 8, shape)).astype(np.float32)
    return (rng.random(shape).astype(np.float32), network, rng.uniform(0, 5, shape).astype(np.float32),
            candidate, rng.random(shape) < 0.7)


def test_the_chooser_decides_the_same_on_one_thread_or_two(opencv_threads):
    left, network, uncertainty, candidate, accepted = disputed_pair(3)
    rng = np.random.default_rng(4)
    chooser = Chooser(rng.normal(size=(len(FEATURES), 32)).astype(np.float32), rng.normal(size=33).astype(np.float32))
    results = {}
    for threads in (1, 2):
        opencv_threads(threads)
        asked = disputed(network, candidate, accepted)
        results[threads] = (chooser_features(left, network, uncertainty, candidate, accepted, where=asked),
                            chooser.take(left, network, uncertainty, candidate, accepted))
    np.testing.assert_array_equal(results[1][0], results[2][0])
    np.testing.assert_array_equal(results[1][1], results[2][1])
    assert 0 < results[2][1].sum() < accepted.sum()  # the chooser took some disputed matches, not all


@pytest.mark.parametrize("rows", [20_001, 4_097, 2_048, 5])
def test_the_probability_of_each_row_does_not_depend_on_the_others(rows):
    """``Chooser.take`` splits the disputed pixels in two halves (at a multiple of ``ROWS``, where
    ``Chooser.split`` says): each row's probability must be the one the whole batch gives it, and
    the perceptron's (float64, by NumPy) within float32 rounding."""
    rng = np.random.default_rng(5)
    chooser = Chooser(rng.normal(size=(len(FEATURES), 32)).astype(np.float32), rng.normal(size=33).astype(np.float32))
    features = rng.normal(size=(rows, len(FEATURES))).astype(np.float32)
    whole = chooser.probability(features)
    cut = Chooser.split(rows)
    assert cut % ROWS == 0 or cut == rows
    assert abs(cut - rows / 2) <= ROWS
    halves = np.concatenate([chooser.probability(features[:cut]), chooser.probability(features[cut:])])
    np.testing.assert_array_equal(whole, halves)
    hidden = np.maximum(features.astype(np.float64) @ chooser.hidden, 0)
    expected = 1 / (1 + np.exp(-(hidden @ chooser.output[:-1] + chooser.output[-1])))
    np.testing.assert_allclose(whole, expected, atol=1e-5)


def test_the_refinements_ranks_are_each_bands_own(opencv_threads, monkeypatch):
    """The two rank transforms run side by side: each band must get its own ranks back."""
    rng = np.random.default_rng(6)
    left = cv2.GaussianBlur(rng.random((64, 96)).astype(np.float32), (0, 0), 2)
    right = np.roll(left, -3, axis=1) + rng.normal(0, 0.01, left.shape).astype(np.float32)  # 3 px, not inverted
    seen = []
    monkeypatch.setattr("cade_cli.matching.refinement.sgbm_matcher", lambda *args, **kwargs: _Spy(seen))
    opencv_threads(2)
    RankSgbmRefinement().candidate(left, right, np.full_like(left, 3), 16)
    assert not np.array_equal(rank_transform(left), rank_transform(right))
    scale = np.uint8(240 // 48)
    np.testing.assert_array_equal(seen[0][:, 32:], rank_transform(left) * scale)
    np.testing.assert_array_equal(seen[1][:, 32:], rank_transform(right) * scale)


class _Spy:
    """An SGBM stand-in that records the images it is given and accepts nothing."""

    def __init__(self, seen: list):
        self.seen = seen

    def getNumDisparities(self) -> int:  # noqa: N802 (OpenCV's name)
        return 32

    def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        self.seen += [left, right]
        return np.full(left.shape, -16, np.int16)
