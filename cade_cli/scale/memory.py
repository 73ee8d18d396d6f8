"""The memory plan: what matching a pair takes (per pixel, per network level), what the machine
has (``MemAvailable``), the default budget, and ``--memory-limit`` as a user writes it. Tiling
(:mod:`cade_cli.scale.tiling`) cuts a pair to fit it; ``cade batch`` caps its workers with it.
"""

from __future__ import annotations

import functools
import re

from cade_cli.errors import CadeError
from cade_cli.matching import get_matcher
from cade_cli.matching.learned import LearnedPipeline
from cade_cli.matching.network import STRIP_PIXELS, UPSCALED


PIXEL_BYTES = 200
"""Per pixel of a matched pair: the bands, their transforms, the map, confidence, the
temporaries of the stages and, for the CADE network, its strips' share (docs/scale.md,
"Jobs and memory": the plan sits just above measured peaks of ``cade``)."""

BASE_BYTES = 250 * 2**20
"""Resident memory of a process before its first pair: Python, NumPy, OpenCV, onnxruntime."""

IMAGE_BYTES = 24
"""Per pixel of the whole pair while it is tiled: both bands (float32), the stitched
disparity, confidence and validity, and the dense copy the command writes."""

NETWORK_LEVEL_BYTES = 6
"""For the learned methods, bytes the network holds per pixel of a strip and level of its
variant (about 1 GB at 128 levels and 2.3 GB at 256 on a full strip of
:data:`~cade_cli.matching.network.STRIP_PIXELS`, :mod:`cade_cli.matching.network`)."""

ENLARGED_PIXEL_BYTES = 32
"""For a card with a second-scale pass (``upscaled-x1.5``, ``upscaled-x2``:
:mod:`cade_cli.matching.augmentation`), bytes per pixel of the enlarged pair: its two raw bands, their
network input and the pass's two outputs (float32), and the resize's temporaries."""

MEMORY_SHARE = 0.5
"""Default budget: this share of the memory available (``MemAvailable``)."""

_UNITS = {"": 1, "B": 1, "K": 2**10, "KB": 2**10, "KIB": 2**10, "M": 2**20, "MB": 2**20, "MIB": 2**20,
          "G": 2**30, "GB": 2**30, "GIB": 2**30, "T": 2**40, "TB": 2**40, "TIB": 2**40}


def parse_memory(text: str) -> int:
    """A memory size as a user writes it (``4GB``, ``512MB``, ``1.5G``, ``2GiB``; 1 GB = 2**30
    bytes) in bytes.

    Raises:
        CadeError: anything else, or a size of zero.
    """
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([A-Za-z]*)\s*", str(text))
    unit = match.group(2).upper() if match else None
    if match is None or unit not in _UNITS:
        raise CadeError(f"--memory-limit {text!r} is not a memory size; write it like 4GB or 512MB")
    size = int(float(match.group(1)) * _UNITS[unit])
    if size <= 0:
        raise CadeError(f"--memory-limit {text!r} is zero; give a positive size like 4GB")
    return size


def available_memory_bytes() -> int:
    """Memory available to new processes (``MemAvailable`` of /proc/meminfo, else the
    physical memory)."""
    import os

    try:
        with open("/proc/meminfo") as stream:
            for line in stream:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def default_memory_limit() -> int:
    """The budget when none is given: :data:`MEMORY_SHARE` of the available memory, bytes."""
    return int(MEMORY_SHARE * available_memory_bytes())


def matching_memory_bytes(method: str, width: int, height: int, disparities: int) -> int:
    """Planned memory (bytes) of matching one ``width`` x ``height`` pair over
    ``disparities`` levels with ``method``, beyond the process's base: :data:`PIXEL_BYTES`
    per pixel plus the matcher's cost volume (:attr:`~cade_cli.matching.Matcher.volume_bytes`
    per pixel and disparity; 0 for the learned methods, whose strips bound it)."""
    pixels = width * height
    return int(PIXEL_BYTES * pixels + get_matcher(method).volume_bytes * pixels * disparities)


@functools.lru_cache(maxsize=8)
def learned_kernel(method: str, model: str | None = None) -> LearnedPipeline | None:
    """``method``'s :class:`~cade_cli.matching.learned.LearnedPipeline` (with ``model``'s
    network), None for a classical matcher."""
    kernel = get_matcher(method, model=model).kernel
    return kernel if isinstance(kernel, LearnedPipeline) else None


def widest_network_levels(method: str, model: str | None = None) -> int:
    """Levels of the widest variant of ``method``'s network (0 for a classical matcher)."""
    kernel = learned_kernel(method, model)
    return 0 if kernel is None else max(variant.levels for variant in kernel.network.card().variants)


def enlarged_area(method: str, model: str | None = None) -> float:
    """Area of ``method``'s largest second-scale pass against the pair's (2.25 for ``upscaled-x1.5``), 0
    without one (a classical matcher, a card without such a ``test_time_augmentation`` entry)."""
    kernel = learned_kernel(method, model)
    if kernel is None:
        return 0.0
    return max((UPSCALED[name] for name in kernel.network.card().test_time if name in UPSCALED), default=0.0) ** 2


def tile_memory_bytes(method: str, width: int, height: int, disparities: int, *, model: str | None = None) -> int:
    """What a ``width`` x ``height`` window (or the whole pair) is planned to take when tiling:
    :func:`matching_memory_bytes`, plus for a learned method its network's largest strip
    (:data:`NETWORK_LEVEL_BYTES` per pixel, up to
    :data:`~cade_cli.matching.network.STRIP_PIXELS`, and level of the widest variant): on
    a large window the strip, not the pixels, dominates), plus the pair enlarged for a second-scale
    pass (:data:`ENLARGED_PIXEL_BYTES` per enlarged pixel; the pass's strips are the same size)."""
    strip = min(width * height, STRIP_PIXELS)
    return int(matching_memory_bytes(method, width, height, disparities)
               + NETWORK_LEVEL_BYTES * strip * widest_network_levels(method, model)
               + ENLARGED_PIXEL_BYTES * width * height * enlarged_area(method, model))
