"""Two independent calls on two cores: the matchers' one-core stages (NumPy and OpenCV
element-wise work, which releases the GIL) run side by side where OpenCV may use two threads.

The CADE matcher's network and SGBM use every thread they are given; its other stages (the
bands' transforms, their rank transforms, the chooser's features) each ran on one core while
the other waited (docs/research/speed.md, 2026-11-27). Splitting such a stage into two independent
halves and running them here gives the same results, bit for bit, in about half the time.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import cv2

A = TypeVar("A")
B = TypeVar("B")

_POOL: ThreadPoolExecutor | None = None


def side_by_side(first: Callable[[], A], second: Callable[[], B]) -> tuple[A, B]:
    """``(first(), second())``: ``second`` on a worker thread while this thread runs ``first``,
    when OpenCV is allowed two threads or more (``cv2.getNumThreads``, which the benchmark
    loop's and the CLI's thread setting fix); else one after the other.

    ``second`` must not call :func:`side_by_side` itself (the workers never wait on each other,
    so callers on several threads cannot deadlock)."""
    global _POOL
    if cv2.getNumThreads() < 2:
        return first(), second()
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="cade-side-by-side")
    pending = _POOL.submit(second)
    try:
        result = first()
    finally:
        later = pending.result()
    return result, later
