"""The paper's evaluation protocols (METHOD.md section 5): which bands are matched.

A protocol turns one RGB stereo pair into matching tasks on single bands:

* ``cs`` (cross-spectral): six tasks R>G, R>B, G>R, G>B, B>R, B>G (left band > right
  band), each scored on its own.
* ``rgb`` (mono-modal): R>R, G>G, B>B; their per-pixel median is the one prediction
  that is scored ("RGB-median"), the three per-channel maps are not.
* ``native``: the dataset's own pair, both views converted to grey (Rec. 601
  luminance 0.299 R + 0.587 G + 0.114 B), one task, scored.

Channel indices are 0, 1, 2 = R, G, B of (H, W, 3) images in R, G, B order
(:func:`cade_cli.io.images.load_image`). Every map a protocol returns has been through the
one fill stage, :func:`cade_cli.matching.disparity.densify`, here and nowhere else in
the evaluation.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Collection
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from cade_cli.errors import CadeError, lookup
from cade_cli.evaluation.timing import Timing, measure
from cade_cli.io.images import luminance
from cade_cli.matching.base import DisparityResult
from cade_cli.matching.disparity import densify

CHANNEL_NAMES: tuple[str, ...] = ("R", "G", "B")
"""Letter of each channel index of an RGB image."""

MEDIAN_NAME = "RGB-median"
"""Name of the combined, scored result of the ``rgb`` protocol."""


@dataclass(frozen=True)
class Task:
    """One matching task: which band of the left and of the right image to match.

    Attributes:
        name: e.g. ``"R>G"`` (left band > right band) or ``"grey"``.
        left_channel, right_channel: channel index 0..2 (R, G, B); None for grey tasks.
        grey: True when both views are converted to Rec. 601 luminance instead.
    """

    name: str
    left_channel: int | None
    right_channel: int | None
    grey: bool = False

    def bands(self, left_rgb: np.ndarray, right_rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The (H, W) float32 left and right bands this task matches (new contiguous arrays)."""
        if self.grey:
            return luminance(left_rgb), luminance(right_rgb)
        return (
            np.ascontiguousarray(left_rgb[:, :, self.left_channel], dtype=np.float32),
            np.ascontiguousarray(right_rgb[:, :, self.right_channel], dtype=np.float32),
        )


def _band_task(left: int, right: int) -> Task:
    return Task(f"{CHANNEL_NAMES[left]}>{CHANNEL_NAMES[right]}", left, right)


@dataclass(frozen=True)
class Protocol:
    """A named list of tasks and how their results become scored predictions.

    Attributes:
        combine: ``None``: every task's map is scored on its own; ``"median"``: the
            per-pixel median of all task maps is the single scored prediction.
    """

    name: str
    summary: str
    tasks: tuple[Task, ...]
    combine: str | None = None

    def select(self, names: Collection[str] | None) -> Protocol:
        """This protocol restricted to the tasks called ``names`` (None: all of them).

        Raises:
            CadeError: no task of this protocol is named, or only some tasks of a
                protocol that combines them.
        """
        if names is None:
            return self
        tasks = tuple(task for task in self.tasks if task.name in names)
        if not tasks:
            raise CadeError(f"none of the tasks {', '.join(names)} is part of protocol {self.name} "
                            f"({', '.join(t.name for t in self.tasks)}); drop the protocol or add one of its tasks")
        if self.combine is not None and len(tasks) != len(self.tasks):
            raise CadeError(f"protocol {self.name} combines all of {', '.join(t.name for t in self.tasks)}; "
                            f"select all of them or none")
        return replace(self, tasks=tasks)


PROTOCOLS: dict[str, Protocol] = {
    protocol.name: protocol
    for protocol in (
        Protocol(
            "cs",
            "cross-spectral: six tasks R>G, R>B, G>R, G>B, B>R, B>G, each scored",
            tuple(_band_task(left, right) for left in range(3) for right in range(3) if left != right),
        ),
        Protocol(
            "rgb",
            "mono-modal: R>R, G>G, B>B; their per-pixel median is scored",
            tuple(_band_task(channel, channel) for channel in range(3)),
            combine="median",
        ),
        Protocol(
            "native",
            "the dataset's own pair in grey (Rec. 601 luminance), one task",
            (Task("grey", None, None, grey=True),),
        ),
    )
}


def get_protocol(name: str) -> Protocol:
    """The protocol called ``name``; raises :class:`CadeError` listing the choices."""
    return lookup(PROTOCOLS, name, kind="protocol")


def median_combine(disparities: list[np.ndarray], valids: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel median of several dense disparity maps, and its validity.

    Args:
        disparities: N (H, W) float maps in pixels, dense (densified: the median is
            taken over all N values, filled ones included).
        valids: N (H, W) bool masks.

    Returns:
        ((H, W) float32 median, (H, W) bool): a pixel is valid when a strict majority of
        the maps are valid there (2 of 3) and the median is finite.
    """
    median = np.median(np.stack([np.asarray(d, np.float32) for d in disparities]), axis=0).astype(np.float32)
    votes = np.stack([np.asarray(v, bool) for v in valids]).sum(axis=0)
    return median, (2 * votes > len(valids)) & np.isfinite(median)


@dataclass(frozen=True)
class TaskResult:
    """Output of one task of a protocol (or of the ``rgb`` median).

    Attributes:
        name: task name (``"R>G"``, ``"grey"``) or ``"RGB-median"``.
        disparity: (H, W) float32 left-view disparity in pixels, dense: the matcher's map
            after :func:`~cade_cli.matching.disparity.densify` (the map that is scored).
        valid: (H, W) bool, where the matcher trusted its (finite) estimate, before the fill.
        seconds: wall time to produce this map (the median of the timed runs); for
            ``RGB-median`` the three matcher runs plus the median, so summing over all
            results double-counts ``rgb``.
        scored: True for the predictions the protocol scores (every ``cs`` task, the
            ``native`` task, only ``RGB-median`` for ``rgb``).
        confidence: (H, W) float32 in [0, 1], the matcher's confidence
            (:attr:`~cade_cli.matching.DisparityResult.confidence`), 0 where ``valid`` is
            False; for ``RGB-median`` the per-pixel median of the tasks' confidences. None
            when the matcher gives none.
    """

    name: str
    disparity: np.ndarray
    valid: np.ndarray
    seconds: float
    scored: bool
    confidence: np.ndarray | None = None


def _densified(name: str, disparity: np.ndarray, valid: np.ndarray, seconds: float, scored: bool,
               confidence: np.ndarray | None = None) -> TaskResult:
    """The one place where the evaluation fills a map (the confidence stays 0 where it is filled)."""
    valid = np.asarray(valid, bool) & np.isfinite(disparity)
    if confidence is not None:
        confidence = np.where(valid, np.asarray(confidence, np.float32), np.float32(0))
    return TaskResult(name, densify(disparity, valid), valid, seconds, scored, confidence)


MatcherFn = Callable[[np.ndarray, np.ndarray], DisparityResult]


def _check_rgb_pair(left_rgb: np.ndarray, right_rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    left_rgb, right_rgb = np.asarray(left_rgb), np.asarray(right_rgb)
    for side, image in (("left", left_rgb), ("right", right_rgb)):
        if image.ndim != 3 or image.shape[2] != 3:
            raise CadeError(
                f"{side} image must be RGB of shape (H, W, 3), got shape {image.shape}; "
                f"protocols split colour images into bands"
            )
    if left_rgb.shape != right_rgb.shape:
        raise CadeError(f"left and right images differ in shape: {left_rgb.shape} vs {right_rgb.shape}")
    return left_rgb, right_rgb


def run_protocol(
    protocol_name: str,
    matcher_fn: MatcherFn,
    left_rgb: np.ndarray,
    right_rgb: np.ndarray,
    *,
    tasks: Collection[str] | None = None,
    degrade: Callable[[np.ndarray], np.ndarray] | None = None,
    timing: Timing = Timing(),
    prepare: Callable[[np.ndarray, np.ndarray], None] | None = None,
    on_task: Callable[[str], None] | None = None,
) -> list[TaskResult]:
    """Run the tasks of a protocol on one RGB stereo pair.

    Args:
        protocol_name: a key of :data:`PROTOCOLS`.
        matcher_fn: ``matcher_fn(left_band, right_band) -> DisparityResult`` on (H, W)
            float32 bands, e.g. ``functools.partial(MATCHERS[name], max_disp=64)``; its
            disparity may be unfilled (NaN where invalid).
        left_rgb, right_rgb: (H, W, 3) images in R, G, B order, same shape.
        tasks: run only the tasks with these names (:meth:`Protocol.select`); None: all.
        degrade: applied to each task's RIGHT band before matching (an imperfect rig).
        timing: warm-up and timed runs of each matcher call (:func:`measure`).
        prepare: ``prepare(left_band, right_band)`` runs untimed before every matcher call.
        on_task: called with a task's name once it is matched (a progress bar).

    Returns:
        One :class:`TaskResult` per task, in the protocol's order; for a ``median``
        protocol (``rgb``) followed by ``RGB-median``, the only scored one.
    """
    protocol = get_protocol(protocol_name).select(tasks)
    left_rgb, right_rgb = _check_rgb_pair(left_rgb, right_rgb)
    scored_alone = protocol.combine is None
    results = []
    for task in protocol.tasks:
        left_band, right_band = task.bands(left_rgb, right_rgb)
        if degrade is not None:
            right_band = np.asarray(degrade(right_band), np.float32)
        seconds, output = measure(
            lambda: matcher_fn(left_band, right_band), warmup=timing.warmup, repeat=timing.repeat,
            prepare=None if prepare is None else lambda: prepare(left_band, right_band))
        if np.shape(output.disparity) != left_band.shape or np.shape(output.valid) != left_band.shape:
            raise CadeError(
                f"task {task.name}: matcher returned disparity {np.shape(output.disparity)} and valid "
                f"{np.shape(output.valid)} for bands of shape {left_band.shape}"
            )
        confidence = output.confidence
        if confidence is not None and np.shape(confidence) != left_band.shape:
            raise CadeError(f"task {task.name}: matcher returned confidence {np.shape(confidence)} for bands of "
                            f"shape {left_band.shape}")
        results.append(_densified(task.name, output.disparity, output.valid, statistics.median(seconds),
                                  scored_alone, confidence))
        if on_task is not None:
            on_task(task.name)
    if protocol.combine == "median":
        start = time.perf_counter()
        median, valid = median_combine([r.disparity for r in results], [r.valid for r in results])
        seconds = sum(r.seconds for r in results) + time.perf_counter() - start
        confidences = [r.confidence for r in results]
        confidence = None if any(c is None for c in confidences) else np.median(np.stack(confidences), axis=0)
        results.append(_densified(MEDIAN_NAME, median, valid, seconds, scored=True, confidence=confidence))
    elif protocol.combine is not None:
        raise CadeError(f"protocol {protocol.name!r} has unknown combine {protocol.combine!r}")
    return results
