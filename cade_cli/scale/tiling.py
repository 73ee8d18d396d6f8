"""Any image size in bounded memory: a pair matched as overlapping tiles (``--memory-limit``).

As Ames Stereo Pipeline's ``parallel_stereo`` and CNES CARS do, a pair too large for the
memory budget is cut into tiles of the left image, each matched on its own with its own
disparity range, seeded from a low-resolution pass over the whole pair:

1. **The coarse pass.** :func:`cade_cli.scale.range.coarse_match` matches the pair at a coarse
   pyramid level (the pass behind ``--max-disp auto``) over the range asked for.
2. **The layout.** Tiles are cores of the left image that cover it without overlap, a
   quadtree (step 4), or, when a core side is forced (``core``), a grid of square cores
   (the last row and column as large as the others, overlapping their neighbours' where
   the image does not divide evenly; there the later tile's values are kept). Each core is
   matched inside a window: the core plus a ``collar`` on every side (:func:`~cade_cli.scale.windows.method_collar`:
   wider for a learned method, whose network sees further), widened on the left by the
   tile's largest disparity (for a learned method the top level of its network's variant,
   :func:`~cade_cli.scale.windows.search_reach`) and on the right by its most negative one, so every pixel of
   the core finds its match (I_left(y, x) ~ I_right(y, x - d)) inside the window. Left and
   right are cropped to the same window, so disparities are unchanged; at an image border
   the window shifts inwards and keeps its width. For a learned method the window's first
   row and column are moved back to the network's sampling grid (:func:`~cade_cli.scale.windows.window_alignment`).
3. **The ranges.** A tile's range is :func:`cade_cli.scale.range.confident_bounds` of the coarse
   estimates over its core and collar, widened by :func:`cade_cli.matching.base.range_margin`, and
   kept within the range asked for; a tile with too few coarse estimates searches that
   whole range.
4. **The size.** Starting from the whole image, a core whose window does not fit the
   budget by :func:`~cade_cli.scale.memory.tile_memory_bytes` (the registry's
   :attr:`~cade_cli.matching.Matcher.volume_bytes` per pixel and disparity, plus
   :data:`~cade_cli.scale.memory.PIXEL_BYTES` per pixel, plus a learned method's network strip; after the
   process's base and the whole-image arrays, :data:`~cade_cli.scale.memory.IMAGE_BYTES` per pixel, are set
   aside) is cut in four, down to :data:`MIN_CORE`; its quarters get their own, narrower
   seeded ranges. Tiles stay large where the depth varies little, and only the cores
   that span a wide range pay for it (until 2026-11-23 one core side was chosen for the
   whole image, the one that the widest-ranged tile needed).
5. **The match and the stitch.** Each window goes through
   :func:`cade_cli.stereo.estimate_disparity` (the one matching path); the core's part of
   its disparity, validity and confidence is copied into the output, the collar dropped.

When the whole pair fits the budget, :func:`estimate_disparity_tiled` is exactly
:func:`~cade_cli.stereo.estimate_disparity`. Tiles differ from the untiled map where a
matcher's context (SGM paths, the network's receptive field, the LR check, the range)
reaches past a window, and for ``cade`` where its refinement's OpenCV SGBM (3-way mode)
restarts its top-down path: at the top of each of the 4 row stripes it cuts every image
into, so the untiled map's rows depend on the image's height, which no window reproduces;
``benchmarks/tiling.py`` measures it (docs/scale.md, "Tiling").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import NoReturn

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching import DisparityRange, DisparityResult, get_matcher
from cade_cli.matching.base import check_pair, range_margin
from cade_cli.scale.memory import BASE_BYTES, IMAGE_BYTES, tile_memory_bytes
from cade_cli.scale.range import coarse_match, confident_bounds
from cade_cli.scale.windows import method_collar, search_reach, window_alignment
from cade_cli.stereo import DEFAULT_METHOD, DEFAULT_PREPROCESS, MEMORY_LIMIT_BYTES, estimate_disparity

MIN_CORE = 32
"""No core is cut below this side, px."""
MIN_TILE_ESTIMATES = 16
"""A tile with fewer coarse estimates than this searches the whole range asked for."""


@dataclass(frozen=True)
class Tile:
    """One tile: the core it fills and the window it is matched in (rows and columns as
    half-open (start, stop) px of the left image), and the range it searches."""

    core_rows: tuple[int, int]
    core_columns: tuple[int, int]
    window_rows: tuple[int, int]
    window_columns: tuple[int, int]
    range: DisparityRange
    seeded: bool
    """True when the range came from the coarse pass, False when it is the whole range."""

    @property
    def side(self) -> int:
        """The core's longer side, px."""
        return max(self.core_rows[1] - self.core_rows[0], self.core_columns[1] - self.core_columns[0])

    @property
    def window_size(self) -> tuple[int, int]:
        """(width, height) of the window, px."""
        return (self.window_columns[1] - self.window_columns[0], self.window_rows[1] - self.window_rows[0])


@dataclass(frozen=True)
class TilePlan:
    """How a pair is matched: ``tiles`` empty when it is matched whole."""

    tiles: tuple[Tile, ...]
    core: int
    """The longest side of a core, px."""
    collar: int
    memory_limit: int
    peak_tile_bytes: int
    """The largest :func:`~cade_cli.scale.memory.tile_memory_bytes` of a tile (of the whole pair when untiled)."""

    @property
    def tiled(self) -> bool:
        return bool(self.tiles)

    def describe(self) -> str:
        """One line for the user."""
        if not self.tiled:
            return f"matched whole, within --memory-limit {self.memory_limit / 2**30:.1f} GB"
        seeded = sum(tile.seeded for tile in self.tiles)
        sides = [tile.side for tile in self.tiles]
        size = f"{max(sides)}" if min(sides) == max(sides) else f"{min(sides)}-{max(sides)}"
        return (f"the pair does not fit --memory-limit {self.memory_limit / 2**30:.1f} GB whole: matching it as "
                f"{len(self.tiles)} tiles of {size} px (+{self.collar} px collar; up to "
                f"{self.peak_tile_bytes / 2**30:.2f} GB each), {seeded} with a range seeded from a coarse pass")


def core_starts(length: int, core: int) -> list[int]:
    """Starts of cores ``core`` px long covering [0, ``length``); the last one ends at
    ``length`` (overlapping its neighbour when ``length`` is not a multiple)."""
    if core >= length:
        return [0]
    starts = list(range(0, length - core, core))
    return starts + [length - core]


def seeded_range(coarse, rows: tuple[int, int], columns: tuple[int, int], whole: DisparityRange) -> DisparityRange | None:
    """The range of the coarse estimates over ``rows`` x ``columns`` (px of the input images)
    plus the margin, within ``whole``; None when they are too few."""
    scale = coarse.scale
    result = coarse.result
    height, width = result.disparity.shape
    top, bottom = max(0, math.floor(rows[0] / scale) - 1), min(height, math.ceil(rows[1] / scale) + 1)
    left, right = max(0, math.floor(columns[0] / scale) - 1), min(width, math.ceil(columns[1] / scale) + 1)
    disparity = result.disparity[top:bottom, left:right]
    matched = result.valid[top:bottom, left:right] & np.isfinite(disparity)
    if matched.sum() < MIN_TILE_ESTIMATES:
        return None
    low, high = confident_bounds(disparity[matched], result.confidence[top:bottom, left:right][matched], scale)
    margin = range_margin(low, high, coarse.factor)
    minimum = min(whole.maximum - 1, max(whole.minimum, math.floor(low - margin)))
    maximum = max(minimum + 1, min(whole.maximum, math.ceil(high + margin)))
    return DisparityRange(minimum, maximum)


def make_tile(rows: tuple[int, int], columns: tuple[int, int], shape: tuple[int, int], chosen: DisparityRange,
              seeded: bool, collar: int, alignment: int = 1, searched: int | None = None) -> Tile:
    """The tile of a core: its window (collar, plus the range on the left and right; on the
    left up to ``searched``, :func:`~cade_cli.scale.windows.search_reach`, when the matcher looks further than the
    range's maximum; its first row and column moved back to multiples of ``alignment``,
    :func:`~cade_cli.scale.windows.window_alignment`) and the range, kept within what the window can hold."""
    height, width = shape
    left = max(chosen.maximum if searched is None else searched, 0)
    window_rows = (max(0, rows[0] - collar) // alignment * alignment, min(height, rows[1] + collar))
    # the core, the range on either side and the collars; shifted inwards at an image border,
    # so a window keeps its width (the matchers need columns beyond the widest disparity)
    need = columns[1] - columns[0] + left - min(chosen.minimum, 0) + 2 * collar
    start = max(0, min(columns[0] - left - collar, width - need))
    window_columns = (start // alignment * alignment, min(width, start + need))
    reach = window_columns[1] - window_columns[0] - 1  # |d| must stay below the window's width
    minimum, maximum = max(chosen.minimum, -reach), min(chosen.maximum, reach)
    maximum = max(maximum, 1, minimum + 1)
    return Tile(rows, columns, window_rows, window_columns, DisparityRange(minimum, maximum), seeded)


def seeded_tile(rows: tuple[int, int], columns: tuple[int, int], *, shape: tuple[int, int], whole: DisparityRange,
                coarse, collar: int, alignment: int, method: str, model: str | None) -> Tile:
    """The tile of a core (:func:`make_tile`), its range seeded from the ``coarse`` pass
    (:func:`seeded_range`; ``whole`` when there is none or it is too thin there)."""
    # Left of the range's maximum a pixel may have no match (x - d < 0), and its coarse
    # estimate is then a confident mistake; a core there also seeds from the columns up
    # to that maximum to its right, where every match exists (on 2026-11-23's 24 MP
    # pair two such cores got [0, 107] for a truth of 272..296 px).
    reach = collar + (max(whole.maximum, 0) if columns[0] < whole.maximum else 0)
    context = ((max(0, rows[0] - collar), rows[1] + collar), (max(0, columns[0] - collar), columns[1] + reach))
    seeded = None if coarse is None else seeded_range(coarse, *context, whole)
    chosen = seeded or whole
    return make_tile(rows, columns, shape, chosen, seeded is not None, collar, alignment,
                     search_reach(method, chosen, model))


def plan_tiles(
    left: np.ndarray,
    right: np.ndarray,
    *,
    method: str = DEFAULT_METHOD,
    min_disp: int = 0,
    max_disp: int,
    memory_limit: int,
    collar: int | None = None,
    core: int | None = None,
    seed: bool = True,
    model: str | None = None,
) -> TilePlan:
    """The tiles :func:`estimate_disparity_tiled` matches (none when the pair fits whole).

    Args:
        left, right: (H, W) bands of the pair.
        method: a registered matcher.
        min_disp, max_disp: the inclusive range asked for, px.
        memory_limit: budget, bytes, for the whole process.
        collar: px of context around each core; None: :func:`~cade_cli.scale.windows.method_collar`.
        core: force this core side (px) and tile even when the pair fits; None: the
            largest that fits the budget.
        seed: seed each tile's range from the coarse pass; False: every tile searches the
            whole range (to measure what the seams alone change).
        model: the network of a learned method (its widest variant enters the plan).

    Raises:
        CadeError: a budget too small for the smallest tiles (the message says how much
            they need), or a forced ``core`` whose tiles do not fit.
    """
    left, right = check_pair(left, right, min_size=get_matcher(method).min_size)
    height, width = left.shape
    whole = DisparityRange(int(min_disp), int(max_disp))
    whole.check_for_width(width)
    untiled = tile_memory_bytes(method, width, height, whole.count, model=model)
    volume_bytes = get_matcher(method).volume_bytes
    volume = volume_bytes * width * height * whole.count
    if core is None and BASE_BYTES + untiled <= memory_limit and volume <= MEMORY_LIMIT_BYTES:
        return TilePlan((), max(width, height), 0, memory_limit, untiled)
    budget = memory_limit - BASE_BYTES - IMAGE_BYTES * width * height
    collar = method_collar(method, model) if collar is None else collar
    alignment = window_alignment(method, whole.span, model)

    def refuse(needed: int, side: int) -> NoReturn:
        raise CadeError(
            f"a {width}x{height} pair over {whole.count} disparities does not fit --memory-limit "
            f"{memory_limit / 2**30:.2f} GB even as {side}x{side} px tiles (they need about "
            f"{(needed + BASE_BYTES + IMAGE_BYTES * width * height) / 2**30:.2f} GB); raise --memory-limit or "
            f"lower --max-disp")

    coarse = None  # none, or too small or too blank to seed: every tile searches the whole range
    if seed:
        try:
            coarse = coarse_match(left, right, min_disp=whole.minimum, max_disp=whole.maximum)
        except CadeError:
            pass

    tile_of = partial(seeded_tile, shape=(height, width), whole=whole, coarse=coarse, collar=collar,
                      alignment=alignment, method=method, model=model)

    def cost(tile: Tile) -> tuple[int, int]:
        """(planned bytes, cost-volume bytes) of matching ``tile``."""
        return (tile_memory_bytes(method, *tile.window_size, tile.range.count, model=model),
                volume_bytes * math.prod(tile.window_size) * tile.range.count)

    def fits(tile: Tile) -> bool:
        peak, volume = cost(tile)
        return peak <= budget and volume <= MEMORY_LIMIT_BYTES

    if core is not None:  # a forced core: a regular grid, or a refusal
        tiles = [tile_of((top, min(height, top + core)), (first, min(width, first + core)))
                 for top in core_starts(height, core) for first in core_starts(width, core)]
        if all(fits(tile) for tile in tiles):
            return TilePlan(tuple(tiles), core, collar, memory_limit, max(cost(tile)[0] for tile in tiles))
        refuse(max(cost(tile)[0] for tile in tiles), core)
    tiles = quadtree_tiles((height, width), tile_of, fits, lambda tile, side: refuse(cost(tile)[0], side))
    return TilePlan(tuple(tiles), max(tile.side for tile in tiles), collar, memory_limit, max(cost(tile)[0] for tile in tiles))


def quadtree_tiles(shape: tuple[int, int], tile_of: Callable[[tuple[int, int], tuple[int, int]], Tile],
                   fits: Callable[[Tile], bool], refuse: Callable[[Tile, int], NoReturn]) -> list[Tile]:
    """The tiles of a pair of ``shape`` (H, W), in row-major order of their cores. A quadtree: a
    core whose tile (``tile_of(rows, columns)``) does not fit is split in four (two when one side
    is already short), down to :data:`MIN_CORE`, where ``refuse(tile, side)`` is called; a tile's
    range is seeded from its own core, so where the scene's depth varies the tiles get smaller
    and their ranges narrower, and where it does not they stay large (less of each window is
    collar and range)."""
    height, width = shape
    tiles, pending = [], [((0, height), (0, width))]
    while pending:
        rows, columns = pending.pop()
        tile = tile_of(rows, columns)
        if fits(tile):
            tiles.append(tile)
            continue
        halves = [split_span(rows), split_span(columns)]
        if len(halves[0]) == len(halves[1]) == 1:
            refuse(tile, max(rows[1] - rows[0], columns[1] - columns[0]))
        pending += [(r, c) for r in halves[0] for c in halves[1]]
    tiles.sort(key=lambda tile: (tile.core_rows, tile.core_columns))
    return tiles


def split_span(span: tuple[int, int]) -> list[tuple[int, int]]:
    """``span`` (start, stop) cut in two near its middle (a multiple of 16 px from its start),
    or left whole when the halves would be shorter than :data:`MIN_CORE`."""
    start, stop = span
    if stop - start < 2 * MIN_CORE:
        return [span]
    middle = start + max(MIN_CORE, (stop - start) // 2 // 16 * 16)
    return [(start, middle), (middle, stop)]


def seam_distance(plan: TilePlan, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32: each pixel's distance (px) to the nearest seam of ``plan``, where the
    stitched map passes from one tile's values to another's (image borders are no seams;
    +inf everywhere when the pair was matched whole)."""
    import cv2

    if not plan.tiled:
        return np.full(shape, np.inf, np.float32)
    owner = np.zeros(shape, np.int32)
    for index, tile in enumerate(plan.tiles):
        owner[slice(*tile.core_rows), slice(*tile.core_columns)] = index
    seam = np.zeros(shape, bool)
    seam[:, 1:] |= owner[:, 1:] != owner[:, :-1]
    seam[1:, :] |= owner[1:, :] != owner[:-1, :]
    return cv2.distanceTransform((~seam).astype(np.uint8), cv2.DIST_L2, 3)


def estimate_disparity_tiled(
    left: np.ndarray,
    right: np.ndarray,
    *,
    method: str = DEFAULT_METHOD,
    min_disp: int = 0,
    max_disp: int,
    memory_limit: int,
    preprocess: str = DEFAULT_PREPROCESS,
    model: str | None = None,
    collar: int | None = None,
    core: int | None = None,
    seed: bool = True,
    plan: TilePlan | None = None,
    on_tile: Callable[[int, int], None] | None = None,
) -> tuple[DisparityResult, TilePlan]:
    """:func:`~cade_cli.stereo.estimate_disparity` within a memory budget: whole when the
    pair fits, else tile by tile (:func:`plan_tiles`) and stitched.

    Args:
        left, right: (H, W) float bands of one rectified pair.
        method, preprocess, model: as for :func:`~cade_cli.stereo.estimate_disparity`.
        min_disp, max_disp: the inclusive range, px.
        memory_limit: budget for the whole process, bytes.
        collar, core, seed: see :func:`plan_tiles`.
        plan: a plan made already by :func:`plan_tiles` for this pair (skips planning).
        on_tile: called as ``on_tile(done, total)`` after each tile of a tiled match (a
            progress bar); not called when the pair is matched whole.

    Returns:
        (the unfilled :class:`~cade_cli.matching.DisparityResult` of the whole left view,
        the plan followed).
    """
    if plan is None:
        plan = plan_tiles(left, right, method=method, min_disp=min_disp, max_disp=max_disp,
                          memory_limit=memory_limit, collar=collar, core=core, seed=seed, model=model)
    if not plan.tiled:
        result = estimate_disparity(left, right, method=method, min_disp=min_disp, max_disp=max_disp,
                                    preprocess=preprocess, model=model)
        return result, plan
    left, right = check_pair(left, right, min_size=get_matcher(method).min_size)
    disparity = np.full(left.shape, np.nan, np.float32)
    valid = np.zeros(left.shape, bool)
    confidence: np.ndarray | None = np.zeros(left.shape, np.float32)
    for done, tile in enumerate(plan.tiles, start=1):
        (top, bottom), (first, last) = tile.window_rows, tile.window_columns
        found = estimate_disparity(left[top:bottom, first:last], right[top:bottom, first:last], method=method,
                                   min_disp=tile.range.minimum, max_disp=tile.range.maximum,
                                   preprocess=preprocess, model=model)
        core = (slice(*tile.core_rows), slice(*tile.core_columns))
        inside = (slice(tile.core_rows[0] - top, tile.core_rows[1] - top),
                  slice(tile.core_columns[0] - first, tile.core_columns[1] - first))
        disparity[core], valid[core] = found.disparity[inside], found.valid[inside]
        if confidence is not None and found.confidence is not None:
            confidence[core] = found.confidence[inside]
        else:
            confidence = None
        if on_tile is not None:
            on_tile(done, len(plan.tiles))
    return DisparityResult(disparity, valid, confidence), plan


__all__ = ["TilePlan", "Tile", "estimate_disparity_tiled", "plan_tiles", "seam_distance"]
