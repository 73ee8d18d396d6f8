"""Artificial stereo scenes with exact disparity, in the spirit of FlyingThings3D.

A scene is a stack of layers: a slanted background plane covering the whole view, a
ground below a horizon in some scenes (:func:`ground_layer`), and a few objects in front.
Each layer has an affine disparity d(x, y) = a + b x + c y (a slanted plane), a shape
(analytic, so it can be evaluated at any sub-pixel position: :mod:`cade_cli.train.shapes`)
and a texture mapped into left-view coordinates with a random similarity transform.

The left view samples every layer at its own pixel; the right view maps each right
pixel back to the left-view position that projects onto it, x = (x_r + a + c y)/(1 - b),
and samples the layer there. In both views the layer with the largest disparity (the
nearest surface) wins, so occlusions are physically right. Both views resample the
textures at non-integer positions (scale and rotation), so neither is softer than the
other. No torch here: this module is plain NumPy/OpenCV and is tested like the runtime.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from cade_cli.train.shapes import Shape, random_shape, thin_structure
from cade_cli.train.textures import TexturePool


@dataclass(frozen=True)
class StereoScene:
    """One rendered pair.

    Attributes:
        left, right: (H, W, 3) float32 RGB in [0, 1].
        disparity: (H, W) float32, left view, pixels; I_left(y, x) ~ I_right(y, x - d).
        nonoccluded: (H, W) bool, True where the left pixel's surface point is visible in
            the right view (same layer wins there and it lies inside the image).
    """

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonoccluded: np.ndarray


@dataclass(frozen=True)
class Photometric:
    """Per-view camera differences applied after rendering (to each view independently)."""

    gain: tuple[float, float] = (0.6, 1.4)
    gamma: tuple[float, float] = (0.7, 1.4)
    blur_sigma: tuple[float, float] = (0.0, 1.0)
    noise_sigma: tuple[float, float] = (0.0, 0.03)
    quantized_share: float = 0.8
    """Probability that a view is stored with 8 bits, as real camera images are: in dark
    and flat regions the CADE transform then sees a few grey levels, not smooth noise."""


@dataclass(frozen=True)
class Misalignment:
    """Residual vertical misalignment of the right view, as an imperfectly rectified rig
    (two cameras behind different filters, calibrated once) leaves it.

    A misaligned pair's right view shows, at pixel (x, y), the scene row
    y + offset + roll * (x - W/2) + zoom * (y - H/2) of the left view's coordinates, with
    each term drawn uniformly from [-bound, bound]. Only rows move: the ground-truth
    (horizontal) disparity of the left view stays exact, and the right view is rendered
    at those rows, not resampled, so it is as sharp as the left.
    """

    share: float = 0.0
    """Probability that a pair is misaligned at all (0: every pair perfectly rectified)."""
    offset: float = 1.0
    """Largest vertical offset, px."""
    roll: float = 0.002
    """Largest change of the offset per column (a roll of about 0.1 degrees)."""
    zoom: float = 0.002
    """Largest change of the offset per row (focal lengths 0.2 % apart)."""

    def rows(self, rng: np.random.Generator, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Left-view rows the right view shows at (x, y); ``y`` itself when not misaligned."""
        if self.share <= 0 or rng.random() >= self.share:  # no draw when off: v4's scenes unchanged
            return y
        height, width = y.shape
        offset, roll, zoom = rng.uniform(-1.0, 1.0, size=3) * (self.offset, self.roll, self.zoom)
        return (y + offset + roll * (x - width / 2) + zoom * (y - height / 2)).astype(np.float32)


NO_MISALIGNMENT = Misalignment()


def erased(scene: StereoScene, rng: np.random.Generator, share: float) -> StereoScene:
    """With probability ``share``, 1 or 2 rectangles (20-100 px a side) of the right view
    painted in that view's mean colour: left pixels whose match falls there must be found
    from their context, as behind an occluder (RAFT-Stereo's "eraser"; no draw when
    ``share`` is 0). The ground truth is unchanged; those pixels are no longer
    ``nonoccluded``."""
    if share <= 0 or rng.random() >= share:
        return scene
    right, nonoccluded = scene.right.copy(), scene.nonoccluded.copy()
    height, width = right.shape[:2]
    mean = right.reshape(-1, 3).mean(axis=0)
    y, x = np.mgrid[0:height, 0:width]
    lands = np.rint(x - np.nan_to_num(scene.disparity, nan=-1e6))  # the right column each left pixel matches
    for _ in range(int(rng.integers(1, 3))):
        h, w = (int(rng.integers(20, 101)) for _ in range(2))
        top, left = int(rng.integers(max(1, height - h + 1))), int(rng.integers(max(1, width - w + 1)))
        right[top:top + h, left:left + w] = mean
        nonoccluded &= ~((y >= top) & (y < top + h) & (lands >= left) & (lands < left + w))
    return replace(scene, right=right, nonoccluded=nonoccluded)


NO_PHOTOMETRIC = Photometric((1.0, 1.0), (1.0, 1.0), (0.0, 0.0), (0.0, 0.0), 0.0)


@dataclass(frozen=True)
class Layer:
    plane: tuple[float, float, float]  # d = a + b x + c y
    shape: Shape | None                # None: covers everything (background)
    texture: np.ndarray                # (h, w, 3)
    mapping: np.ndarray                # 2x3 affine, left-view (x, y) -> texture (u, v)

    def disparity(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        a, b, c = self.plane
        return a + b * x + c * y

    def source_column(self, right_x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Left-view column whose surface point lands on right column ``right_x``."""
        a, b, c = self.plane
        return (right_x + a + c * y) / (1.0 - b)

    def covers(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.ones(x.shape, bool) if self.shape is None else self.shape(x, y)

    def colour(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        (m00, m01, m02), (m10, m11, m12) = self.mapping
        u = (m00 * x + m01 * y + m02).astype(np.float32)
        v = (m10 * x + m11 * y + m12).astype(np.float32)
        return cv2.remap(self.texture, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)


def random_plane(rng: np.random.Generator, height: int, width: int, low: float,
                 high: float) -> tuple[float, float, float]:
    """A plane whose disparity over the whole view stays inside [low, high]."""
    slope_scale = rng.choice([0.0, 0.02, 0.1, 0.3], p=[0.25, 0.3, 0.3, 0.15])
    b, c = rng.uniform(-slope_scale, slope_scale, size=2)
    span = abs(b) * width + abs(c) * height
    if span > 0.8 * (high - low):  # too steep for the range: flatten it
        shrink = 0.8 * (high - low) / span
        b, c, span = b * shrink, c * shrink, span * shrink
    centre = rng.uniform(low + span / 2, high - span / 2)
    a = centre - b * width / 2 - c * height / 2
    return float(a), float(b), float(c)


def _mapping(rng: np.random.Generator, texture: np.ndarray, height: int, width: int) -> np.ndarray:
    """Similarity transform from view coordinates into the texture (random scale, rotation, shift)."""
    scale = math.exp(rng.uniform(math.log(0.35), math.log(1.6)))
    angle = rng.uniform(0, 2 * math.pi) if rng.random() < 0.5 else rng.uniform(-0.2, 0.2)
    cos, sin = scale * math.cos(angle), scale * math.sin(angle)
    th, tw = texture.shape[:2]
    return np.array([[cos, -sin, rng.uniform(0, tw)], [sin, cos, rng.uniform(0, th)]], np.float64)


def _composite(layers: list[Layer], columns: list[np.ndarray], y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z-buffer: for each pixel the covering layer with the largest disparity.

    ``columns[i]`` is where layer i is sampled (left-view x). Returns the image, the
    winning layer's disparity and the winning layer's index."""
    best = np.full(y.shape, -np.inf, np.float32)
    index = np.zeros(y.shape, np.int16)
    for i, (layer, x) in enumerate(zip(layers, columns)):
        d = layer.disparity(x, y).astype(np.float32)
        wins = layer.covers(x, y) & (d > best)
        best = np.where(wins, d, best)
        index[wins] = i
    image = np.zeros(y.shape + (3,), np.float32)
    for i, (layer, x) in enumerate(zip(layers, columns)):
        where = index == i
        rows, cols = np.flatnonzero(where.any(axis=1)), np.flatnonzero(where.any(axis=0))
        if rows.size:  # texture only the box the layer shows in (remap reads each pixel alone: same values)
            box = np.s_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
            np.copyto(image[box], layer.colour(x[box], y[box]), where=where[box][..., None])
    return image, best, index


def render_scene(
    rng: np.random.Generator,
    height: int,
    width: int,
    *,
    limit: float,
    textures: TexturePool,
    objects: tuple[int, int] = (3, 15),
    photometric: Photometric = Photometric(),
    misalignment: Misalignment = NO_MISALIGNMENT,
    ground: float = 0.0,
    shadows: float = 0.0,
    thin: float = 0.0,
) -> StereoScene:
    """Render one stereo pair with disparity in [0, limit).

    Args:
        height, width: size of each view.
        limit: exclusive upper bound of every disparity in the scene, px.
        textures: where layer textures come from.
        objects: inclusive-exclusive range for the number of objects before the background.
        photometric: ranges of the per-view gain (per channel), gamma, blur and noise.
        misalignment: residual vertical misalignment of the right view (none by default).
            A misaligned pair's ``nonoccluded`` compares layers across that offset, so
            it may be off by the offset (about a pixel) along occlusion boundaries.
        ground: share of the scenes with a ground (:func:`ground_layer`) under the objects;
            no random draw when 0, so earlier runs' scenes are unchanged.
        shadows: share of the background and ground surfaces (the wide ones a shade falls
            across; objects keep their textures) with shadows cast on them
            (:func:`cast_shadow`); no random draw when 0, as for ``ground``.
        thin: share of the scenes with thin structures in front (:func:`thin_layers`); no
            random draw when 0, as for ``ground``.
    """
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    # Background mostly far (small disparity), sometimes anywhere; objects anywhere above 0.
    background_high = limit * (0.5 if rng.random() < 0.7 else 0.95)
    layers = [Layer(random_plane(rng, height, width, 0.0, background_high), None,
                    *textured_surface(rng, textures, height, width, shadows=shadows))]
    corners = layers[0].disparity(np.array([0.0, width, 0.0, width]), np.array([0.0, 0.0, height, height]))
    farthest_background = float(corners.min())
    if ground > 0 and rng.random() < ground:
        layers.append(ground_layer(rng, height, width, near=farthest_background, limit=limit, textures=textures,
                                   shadows=shadows))
    for _ in range(rng.integers(*objects)):
        low = farthest_background if rng.random() < 0.8 else 0.0
        layers.append(Layer(random_plane(rng, height, width, low, limit * 0.995),
                            random_shape(rng, height, width), *textured_surface(rng, textures, height, width)))
    if thin > 0 and rng.random() < thin:  # no draw when off: earlier runs' scenes unchanged
        layers += thin_layers(rng, height, width, far=farthest_background, limit=limit, textures=textures)
    return render_layers(rng, layers, photometric=photometric, misalignment=misalignment, x=x, y=y)


def render_layers(rng: np.random.Generator, layers: list[Layer], *, photometric: Photometric,
                  misalignment: Misalignment, x: np.ndarray, y: np.ndarray) -> StereoScene:
    """Both views of ``layers`` (the nearest covering layer wins in each), the left view's
    disparity and where it is seen in the right view, then each view through :func:`camera`.
    ``x``, ``y``: the (H, W) float32 column and row grids of the left view."""
    height, width = y.shape
    left, disparity, left_index = _composite(layers, [x] * len(layers), y)
    right_rows = misalignment.rows(rng, x, y)
    right, _, right_index = _composite(layers, [layer.source_column(x, right_rows) for layer in layers], right_rows)

    right_x = np.rint(x - disparity).astype(np.int64)
    inside = (right_x >= 0) & (right_x < width)
    rows = np.arange(height)[:, None].repeat(width, 1)
    seen = np.zeros((height, width), bool)
    seen[inside] = right_index[rows[inside], right_x[inside]] == left_index[inside]
    return StereoScene(
        left=camera(rng, left, photometric),
        right=camera(rng, right, photometric),
        disparity=disparity.astype(np.float32),
        nonoccluded=seen,
    )


def thin_layers(rng: np.random.Generator, height: int, width: int, *, far: float, limit: float,
                textures: TexturePool) -> list[Layer]:
    """1-6 thin structures (:func:`~cade_cli.train.shapes.thin_structure`: wires, poles, fronds),
    each a layer with its own plane between 15 % of the way from ``far`` (the background's
    farthest disparity) to ``limit`` and ``limit``: well in front of the background, so
    every one of them makes two depth edges a few px apart."""
    layers = []
    for _ in range(int(rng.integers(1, 7))):
        low = far + 0.15 * (limit - far)
        layers.append(Layer(random_plane(rng, height, width, low, limit * 0.995), thin_structure(rng, height, width),
                            *textured_surface(rng, textures, height, width)))
    return layers


def ground_layer(rng: np.random.Generator, height: int, width: int, *, near: float, limit: float,
                 textures: TexturePool, shadows: float = 0.0) -> Layer:
    """A ground seen from a camera above it (a road, a floor, a field): covering the view below a
    horizon row (anywhere from 10 % to 60 % down the view, tilted by up to 2 %), its disparity
    ``near`` px at the horizon and rising linearly to 40-99 % of ``limit`` at the nearest bottom
    corner: one plane steeper in y than most of the background's, under everything in front."""
    horizon = rng.uniform(0.1, 0.6) * height
    tilt = rng.uniform(-0.02, 0.02)  # rows per column: a camera rolled a little
    bottom = max(near + 1.0, rng.uniform(0.4, 0.99) * limit)
    c = (bottom - near) / (height - horizon + abs(tilt) * width / 2)  # the nearest bottom corner reaches ``bottom``
    a, b = near - c * (horizon - tilt * width / 2), -c * tilt
    return Layer((float(a), float(b), float(c)),
                 lambda x, y: y >= horizon + tilt * (x - width / 2),
                 *textured_surface(rng, textures, height, width, shadows=shadows))


def textured_surface(rng: np.random.Generator, textures: TexturePool, height: int, width: int, *,
              shadows: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    texture = textures.draw(rng)
    kind = rng.random()
    if kind < 0.1:  # nearly textureless surfaces exist too
        mean = texture.mean(axis=(0, 1), keepdims=True)
        texture = (mean + rng.uniform(0.02, 0.15) * (texture - mean)).astype(np.float32)
    elif kind < 0.2:  # and dark ones (black cloth, shadows): after noise and 8 bits, little signal is left
        texture = (rng.uniform(0.01, 0.1) * texture).astype(np.float32)
    if shadows > 0 and rng.random() < shadows:  # no draw when off: earlier runs' scenes unchanged
        texture = cast_shadow(rng, texture)
    return texture, _mapping(rng, texture, height, width)


def cast_shadow(rng: np.random.Generator, texture: np.ndarray) -> np.ndarray:
    """``texture`` with shadows cast on it: trees' or buildings' shade on a sunlit road or wall.

    Part of the surface (20-70 %, in blobs drawn from smooth noise of 3-24 cells across, so from
    a few large shadows to dappled foliage shade) keeps 3-30 % of its light; the edge is sharp
    or soft (a blur of up to 15 % of a cell). The shade lies on the texture, so both views
    see it on the same surface points, as with a real cast shadow: inside it the texture's
    contrast drops with its light, and after noise and 8 bits little is left to match, while the
    shadow's edge is a strong feature both views share.
    """
    height, width = texture.shape[:2]
    cells = int(rng.integers(3, 25))
    field = cv2.resize(rng.standard_normal((cells, cells)).astype(np.float32), (width, height),
                       interpolation=cv2.INTER_CUBIC)
    shaded = (field < np.quantile(field, rng.uniform(0.2, 0.7))).astype(np.float32)
    softness = rng.uniform(0.0, 0.15) * max(height, width) / cells  # a penumbra narrower than a blob
    if softness > 0.5:
        shaded = cv2.GaussianBlur(shaded, (0, 0), softness)
    light = np.float32(rng.uniform(0.03, 0.3))
    return (texture * (1 - (1 - light) * shaded)[..., None]).astype(np.float32)


def camera(rng: np.random.Generator, image: np.ndarray, photometric: Photometric) -> np.ndarray:
    """One view as a camera behind its own filter stores it: (H, W, 3) float32 in [0, 1],
    with a per-channel gain, a gamma, blur, noise and (sometimes) 8-bit quantisation drawn
    from ``photometric``."""
    gain = rng.uniform(*photometric.gain, size=3).astype(np.float32)
    gamma = rng.uniform(*photometric.gamma)
    sigma = rng.uniform(*photometric.blur_sigma)
    noise = rng.uniform(*photometric.noise_sigma)
    out = np.clip(image * gain, 0.0, 1.0)
    np.power(out, np.float32(gamma), out=out)
    if sigma > 0.05:
        out = cv2.GaussianBlur(out, (0, 0), sigma)
    if noise > 0:
        drawn = rng.standard_normal(out.shape).astype(np.float32)
        drawn *= np.float32(noise)  # noise * drawn: a float32 array times a Python float stays float32
        out += drawn
    np.clip(out, 0.0, 1.0, out=out)
    if rng.random() < photometric.quantized_share:
        out *= np.float32(255.0)
        np.rint(out, out=out)
        out /= np.float32(255.0)
    return out
