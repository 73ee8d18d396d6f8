"""How the benchmark loop times a matcher call: warm-up runs, repeats, threads."""

from __future__ import annotations

import gc
import os
import time
from dataclasses import dataclass
from typing import Callable, TypeVar

T = TypeVar("T")

THREAD_VARIABLES: tuple[str, ...] = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                     "NUMEXPR_NUM_THREADS")
"""Environment variables that cap the native thread pools (onnxruntime reads OMP_NUM_THREADS
when a session is built; the BLAS libraries read theirs when NumPy is first imported)."""


@dataclass(frozen=True)
class Timing:
    """Timing options of the benchmark loop.

    Attributes:
        warmup: untimed calls before the timed ones (lazy initialisation: the cade
            matcher builds an onnxruntime session the first time a range needs it).
        repeat: timed calls; a record keeps their median, in seconds.
        threads: threads for OpenCV and the OpenMP / BLAS pools of each process that
            runs scenes (:func:`use_threads`); None leaves them as they are.
    """

    warmup: int = 0
    repeat: int = 1
    threads: int | None = None

    def __post_init__(self) -> None:
        from cade_cli.errors import CadeError

        if self.warmup < 0 or self.repeat < 1 or (self.threads is not None and self.threads < 1):
            raise CadeError(f"timing needs warmup >= 0, repeat >= 1 and threads >= 1 or None, got {self}")


def measure(call: Callable[[], T], *, warmup: int = 0, repeat: int = 1,
            prepare: Callable[[], None] | None = None) -> tuple[list[float], T]:
    """Run ``call`` ``warmup`` times untimed, then ``repeat`` times timed.

    The garbage collector is off during each timed call, so no collection lands inside it
    (a full collection before each call, as before, cost more than a small matcher call where
    many objects live: 0.1-0.5 s each in the test process). ``prepare``, when given, runs
    untimed before every call (warm-ups included).

    Returns:
        (seconds of each timed call with ``time.perf_counter``, the last call's result).
    """
    for _ in range(warmup):
        if prepare is not None:
            prepare()
        call()
    seconds = []
    for _ in range(repeat):
        if prepare is not None:
            prepare()
        collecting = gc.isenabled()
        gc.disable()
        try:
            start = time.perf_counter()
            result = call()
            seconds.append(time.perf_counter() - start)
        finally:
            if collecting:
                gc.enable()
    return seconds, result


def use_threads(threads: int | None) -> None:
    """Give this process ``threads`` threads: OpenCV's pool now, and the environment
    variables of :data:`THREAD_VARIABLES` for pools created later. To cap BLAS too, set
    them before NumPy is imported (the speed script does). None: change nothing."""
    if threads is None:
        return
    import cv2

    for name in THREAD_VARIABLES:
        os.environ[name] = str(threads)
    cv2.setNumThreads(threads)
