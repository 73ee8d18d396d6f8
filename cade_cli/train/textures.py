"""Textures of the rendered scenes (:mod:`cade_cli.train.scenes`): natural images from folders,
loaded lazily, and procedural ones (multi-scale noise, stripes, gradients) drawn on demand."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError

TEXTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm")


class TexturePool:
    """Natural-image textures from folders (loaded lazily, kept in memory) plus
    procedural ones drawn on demand.

    Args:
        folders: directories searched recursively for images; may be empty.
        procedural_share: probability that :meth:`draw` returns a procedural texture
            even when image files exist.
    """

    def __init__(self, folders: list[Path] | tuple[Path, ...] = (), *, procedural_share: float = 0.4):
        self.files = sorted(
            path for folder in folders for path in Path(folder).rglob("*")
            if path.suffix.lower() in TEXTURE_SUFFIXES
        )
        for folder in folders:
            if not Path(folder).is_dir():
                raise CadeError(f"texture folder not found: {folder}")
        self.procedural_share = procedural_share if self.files else 1.0
        self._cache: dict[Path, np.ndarray] = {}

    def draw(self, rng: np.random.Generator, size: int = 384) -> np.ndarray:
        """A (h, w, 3) float32 RGB texture in [0, 1], at least ``size`` on its shorter side
        for procedural textures (image files are used at their own size)."""
        if rng.random() < self.procedural_share:
            return procedural_texture(rng, size)
        return self.photo(rng)

    def photo(self, rng: np.random.Generator) -> np.ndarray:
        """A (h, w, 3) float32 RGB image from the folders, in [0, 1], whole or (half the time) a
        random crop of 40-100 % of each side; the folders must hold images (:attr:`files`)."""
        if not self.files:
            raise CadeError("no texture images to draw a photo from; give --textures a folder of images")
        path = self.files[rng.integers(len(self.files))]
        if path not in self._cache:
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if image is None:
                raise CadeError(f"cannot read texture image {path}")
            self._cache[path] = image[..., ::-1].astype(np.float32) / 255.0
        texture = self._cache[path]
        if rng.random() < 0.5:  # a random crop keeps single objects from showing whole photos
            h, w = texture.shape[:2]
            ch, cw = int(h * rng.uniform(0.4, 1.0)), int(w * rng.uniform(0.4, 1.0))
            top, left = rng.integers(h - ch + 1), rng.integers(w - cw + 1)
            texture = texture[top:top + ch, left:left + cw]
        return np.ascontiguousarray(texture)


@functools.lru_cache(maxsize=4)
def _grid(size: int) -> np.ndarray:
    """(2, size, size) float32 row and column indices, made once per size (read-only)."""
    grid = np.mgrid[0:size, 0:size].astype(np.float32)
    grid.flags.writeable = False
    return grid


def procedural_texture(rng: np.random.Generator, size: int = 384) -> np.ndarray:
    """A (size, size, 3) float32 texture in [0, 1]: multi-scale noise, stripes, a smooth
    gradient, coloured patches or a checkerboard, with random colours."""
    kind = rng.choice(["noise", "stripes", "gradient", "patches", "checker"], p=[0.35, 0.15, 0.15, 0.25, 0.1])
    yy, xx = _grid(size)
    if kind == "noise":
        value = np.zeros((size, size), np.float32)
        for level in range(rng.integers(1, 5)):
            cells = int(rng.integers(4, max(5, size // (1 + 2 * level))))
            small = rng.random((cells, cells)).astype(np.float32)
            value += rng.uniform(0.2, 1.0) * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    elif kind == "stripes":
        angle, period = rng.uniform(0, math.pi), rng.uniform(3.0, 40.0)
        phase = (xx * math.cos(angle) + yy * math.sin(angle)) * (2 * math.pi / period)
        value = np.sin(phase)
        if rng.random() < 0.5:
            value = np.sign(value)
    elif kind == "gradient":
        angle = rng.uniform(0, 2 * math.pi)
        value = (xx * math.cos(angle) + yy * math.sin(angle)) / size
        value = value + 0.05 * rng.standard_normal((size, size)).astype(np.float32)
    elif kind == "patches":
        canvas = np.zeros((size, size, 3), np.float32)
        for _ in range(rng.integers(5, 60)):
            colour = tuple(float(c) for c in rng.random(3))
            centre = (int(rng.integers(size)), int(rng.integers(size)))
            if rng.random() < 0.5:
                cv2.circle(canvas, centre, int(rng.integers(3, size // 4)), colour, -1)
            else:
                corner = (centre[0] + int(rng.integers(-size // 4, size // 4)),
                          centre[1] + int(rng.integers(-size // 4, size // 4)))
                cv2.rectangle(canvas, centre, corner, colour, -1)
        return canvas
    else:
        period = rng.uniform(4.0, 48.0)
        value = ((np.floor(xx / period) + np.floor(yy / period)) % 2).astype(np.float32)
    value = (value - value.min()) / max(float(value.max() - value.min()), 1e-6)
    low, high = rng.random(3).astype(np.float32), rng.random(3).astype(np.float32)
    return _colourised(value, low, high)


def _colourised(value: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(h, w, 3) float32 ``low + value * (high - low)`` for a (h, w) ``value`` in [0, 1]: channel
    by channel on contiguous planes, then interleaved (the same float32 values as the broadcast,
    at a third of its time)."""
    value, step = np.asarray(value, np.float32), high - low
    return cv2.merge([value * step[channel] + low[channel] for channel in range(3)])
