"""Analytic object outlines for the rendered scenes (:mod:`cade_cli.train.scenes`): blobs,
rectangles, thin branches and lattices, each a function of (x, y) that can be evaluated at
any sub-pixel position."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

Shape = Callable[[np.ndarray, np.ndarray], np.ndarray]
MARGIN = 2.0
"""px added to a shape's reach before pixels beyond it are skipped (rounding at the edge)."""


def within(inside: Shape, cx: float, cy: float, reach: float) -> Shape:
    """``inside`` evaluated only in the box of the (H, W) grid that comes within ``reach`` px
    (a bound on the outline's extent, plus :data:`MARGIN`) of (``cx``, ``cy``) along both axes,
    and False beyond it: the same mask, without the trigonometry over the whole view for an
    object that covers a corner of it. Arrays that are not (H, W) grids are evaluated whole."""
    reach += MARGIN

    def bounded(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        if np.ndim(x) != 2:
            return inside(x, y)
        near = (np.abs(x - cx) < reach) & (np.abs(y - cy) < reach)
        rows, cols = np.flatnonzero(near.any(axis=1)), np.flatnonzero(near.any(axis=0))
        covered = np.zeros(np.shape(x), bool)
        if rows.size:
            box = np.s_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
            covered[box] = inside(x[box], y[box])
        return covered

    return bounded


def random_shape(rng: np.random.Generator, height: int, width: int, *,
                 size: tuple[float, float] = (0.04, 0.6)) -> Shape:
    """An analytic object outline, drawn from the kinds real scenes are made of:

    * a wobbly blob (polar radius with a few harmonics) or a rotated rectangle, between
      ``size[0]`` and ``size[1]`` of the image's smaller side across (4 % to 60 %; the same
      draws whatever ``size``);
    * a thin branch: a polyline of 1-4 segments, 1-8 px wide (stems, cables, chair legs);
    * a lattice: a rotated grid of thin bars (fences, frames, shelves) with holes that
      show what lies behind.
    """
    kind = rng.choice(["blob", "rectangle", "branch", "lattice"], p=[0.4, 0.25, 0.25, 0.1])
    cx, cy = rng.uniform(-0.1, 1.1) * width, rng.uniform(-0.1, 1.1) * height
    radius = math.exp(rng.uniform(math.log(size[0]), math.log(size[1]))) * min(height, width)
    angle = rng.uniform(0, 2 * math.pi)
    cos, sin = math.cos(angle), math.sin(angle)

    def frame(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (x - cx) * cos + (y - cy) * sin, (y - cy) * cos - (x - cx) * sin

    if kind == "blob":
        harmonics = [(k, rng.uniform(0, 0.35 / k), rng.uniform(0, 2 * math.pi)) for k in range(2, 6)]
        aspect = rng.uniform(0.5, 1.0)

        def blob(x: np.ndarray, y: np.ndarray) -> np.ndarray:
            u, v = frame(x, y)
            v = v / aspect
            theta = np.arctan2(v, u)
            rho = radius * (1 + sum(a * np.cos(k * theta + p) for k, a, p in harmonics))
            return u * u + v * v < rho * rho

        # rho <= radius (1 + sum of the harmonics' amplitudes); the aspect only shrinks the extent
        return within(blob, cx, cy, radius * (1 + sum(a for _, a, _ in harmonics)))
    if kind == "branch":
        half_width = rng.uniform(0.5, 4.0)
        points = [(cx, cy)]
        heading = angle
        for _ in range(rng.integers(1, 5)):
            heading += rng.uniform(-0.8, 0.8)
            length = rng.uniform(0.1, 0.5) * min(height, width)
            points.append((points[-1][0] + length * math.cos(heading), points[-1][1] + length * math.sin(heading)))
        segments = list(zip(points[:-1], points[1:]))

        def branch(x: np.ndarray, y: np.ndarray) -> np.ndarray:
            inside = np.zeros(x.shape, bool)
            for (x0, y0), (x1, y1) in segments:
                dx, dy = x1 - x0, y1 - y0
                t = np.clip(((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy + 1e-9), 0.0, 1.0)
                inside |= (x - x0 - t * dx) ** 2 + (y - y0 - t * dy) ** 2 < half_width * half_width
            return inside

        return within(branch, cx, cy, max(math.hypot(px - cx, py - cy) for px, py in points) + half_width)
    half_w, half_h = radius, radius * rng.uniform(0.2, 1.0)
    if kind == "lattice":
        period = rng.uniform(8.0, 40.0)
        bar = rng.uniform(1.5, 0.4 * period)

        def lattice(x: np.ndarray, y: np.ndarray) -> np.ndarray:
            u, v = frame(x, y)
            bars = (np.mod(u + half_w, period) < bar) | (np.mod(v + half_h, period) < bar)
            return (np.abs(u) < half_w) & (np.abs(v) < half_h) & bars

        return within(lattice, cx, cy, math.hypot(half_w, half_h))

    def rectangle(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u, v = frame(x, y)
        return (np.abs(u) < half_w) & (np.abs(v) < half_h)

    return within(rectangle, cx, cy, math.hypot(half_w, half_h))


THIN_KINDS = ("wire", "pole", "frond")


def thin_structure(rng: np.random.Generator, height: int, width: int) -> Shape:
    """A thin structure 1-6 px wide, as real scenes are full of and depth edges are made of:

    * ``wire``: a sagging curve (a quadratic Bezier) that crosses the whole view (cables,
      hoses, rails), sometimes two or three parallel ones (a power line);
    * ``pole``: a straight or once-bent bar, mostly near vertical, often reaching past an
      edge of the view (poles, posts, table legs);
    * ``frond``: a gently curved stem with 3-12 side branches, thinner than the stem (leaves,
      fronds, twigs).

    Every piece is a segment with its own half-width; a pixel is inside when it lies within
    that half-width of a segment (sub-pixel positions too, as for :func:`random_shape`)."""
    kind = rng.choice(THIN_KINDS, p=[0.4, 0.3, 0.3])
    side = min(height, width)
    half_width = rng.uniform(0.5, 3.0)  # 1-6 px wide
    segments: list[tuple[float, float, float, float, float]] = []  # x0, y0, x1, y1, half-width
    if kind == "wire":
        angle = rng.uniform(-0.6, 0.6) + (math.pi / 2 if rng.random() < 0.25 else 0.0)
        cx, cy = rng.uniform(0.1, 0.9) * width, rng.uniform(0.1, 0.9) * height
        reach = math.hypot(height, width) * 0.6  # both ends beyond the view
        cos, sin = math.cos(angle), math.sin(angle)
        sag = rng.uniform(-0.25, 0.25) * side
        spacing = rng.uniform(6.0, 30.0)
        for strand in range(int(rng.choice([1, 1, 1, 2, 3]))):
            offset = strand * spacing
            start = (cx - reach * cos - offset * sin, cy - reach * sin + offset * cos)
            end = (cx + reach * cos - offset * sin, cy + reach * sin + offset * cos)
            middle = ((start[0] + end[0]) / 2 - 2 * sag * sin, (start[1] + end[1]) / 2 + 2 * sag * cos)
            segments += _bezier(start, middle, end, half_width, pieces=16)
    elif kind == "pole":
        angle = math.pi / 2 + rng.uniform(-0.3, 0.3) if rng.random() < 0.7 else rng.uniform(0, math.pi)
        x, y = rng.uniform(0.0, 1.0) * width, rng.uniform(0.0, 1.0) * height
        for _ in range(int(rng.integers(1, 3))):
            length = rng.uniform(0.4, 1.2) * side
            x1, y1 = x + length * math.cos(angle), y + length * math.sin(angle)
            segments.append((x, y, x1, y1, half_width))
            x, y, angle = x1, y1, angle + rng.uniform(-1.2, 1.2)
    else:
        x, y = rng.uniform(0.0, 1.0) * width, rng.uniform(0.0, 1.0) * height
        heading, length = rng.uniform(0, 2 * math.pi), rng.uniform(0.3, 0.9) * side
        bend = rng.uniform(-0.5, 0.5)
        stem = [(x + length * t * math.cos(heading + bend * t), y + length * t * math.sin(heading + bend * t))
                for t in np.linspace(0.0, 1.0, 9)]
        segments += [(*a, *b, half_width) for a, b in zip(stem[:-1], stem[1:])]
        for _ in range(int(rng.integers(3, 13))):
            t = rng.uniform(0.1, 1.0)
            bx, by = x + length * t * math.cos(heading + bend * t), y + length * t * math.sin(heading + bend * t)
            branch = heading + bend * t + rng.choice([-1.0, 1.0]) * rng.uniform(0.4, 1.2)
            reach = rng.uniform(0.05, 0.3) * side
            segments.append((bx, by, bx + reach * math.cos(branch), by + reach * math.sin(branch),
                             max(0.5, half_width * rng.uniform(0.4, 1.0))))
    pieces = np.array(segments, np.float64)

    def thin(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        inside = np.zeros(np.shape(x), bool)
        for x0, y0, x1, y1, half in pieces:
            near = ((x > min(x0, x1) - half - 1) & (x < max(x0, x1) + half + 1)
                    & (y > min(y0, y1) - half - 1) & (y < max(y0, y1) + half + 1))
            if not near.any():
                continue
            px, py = x[near], y[near]
            dx, dy = x1 - x0, y1 - y0
            t = np.clip(((px - x0) * dx + (py - y0) * dy) / (dx * dx + dy * dy + 1e-9), 0.0, 1.0)
            inside[near] |= (px - x0 - t * dx) ** 2 + (py - y0 - t * dy) ** 2 < half * half
        return inside

    return thin


def _bezier(start: tuple[float, float], control: tuple[float, float], end: tuple[float, float], half_width: float,
            *, pieces: int) -> list[tuple[float, float, float, float, float]]:
    """A quadratic Bezier curve as ``pieces`` straight segments of ``half_width``."""
    t = np.linspace(0.0, 1.0, pieces + 1)[:, None]
    points = (1 - t) ** 2 * np.array(start) + 2 * (1 - t) * t * np.array(control) + t ** 2 * np.array(end)
    return [(*map(float, a), *map(float, b), half_width) for a, b in zip(points[:-1], points[1:])]
