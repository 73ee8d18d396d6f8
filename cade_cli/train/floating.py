"""Floating objects over a real background: the training-data lever of Accuracy V (issue 51,
item 3) modelled on the procedural sets that float many textured objects in front of a
photograph (one built that way cut Middlebury errors by 28 % against standard synthetic data).

The background is a real image, never a procedural texture: a photo from the texture folders
(:meth:`~cade_cli.train.textures.TexturePool.photo`) or the left view of a real training scene
(:class:`~cade_cli.train.real.RealScenes`), mapped onto a slanted plane of its own at about its
own scale (a similarity of scale 0.6-1.4 and a small rotation), so it looks like the photograph
it is. In front of it float 10-40 objects of random outlines (:func:`~cade_cli.train.shapes.random_shape`,
4-30 % of the view's smaller side across), textures and slanted planes. Both views come from
the same layered renderer as :func:`~cade_cli.train.scenes.render_scene`
(:func:`~cade_cli.train.scenes.render_layers`), so occlusions and the ground truth are exact.
"""

from __future__ import annotations

import math

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.train.real import RealScenes
from cade_cli.train.scenes import (NO_MISALIGNMENT, Layer, Misalignment, Photometric, StereoScene, random_plane,
                                   render_layers, textured_surface, thin_layers)
from cade_cli.train.shapes import random_shape
from cade_cli.train.textures import TexturePool

FLOATING_OBJECTS = (10, 41)
"""Inclusive-exclusive range of the number of floating objects in a scene."""
FLOATING_SIZE = (0.04, 0.3)
"""Range (log-uniform) of a floating object's radius, as a share of the view's smaller side."""


def real_background(rng: np.random.Generator, textures: TexturePool, real: RealScenes | None) -> np.ndarray:
    """A (h, w, 3) float32 real image in [0, 1]: a texture photo or a real scene's left view
    (each half the time when both exist)."""
    sources = (["photo"] if textures.files else []) + (["real"] if real is not None and real.scenes else [])
    if not sources:
        raise CadeError("floating objects need a real background: texture images (--textures) or real scenes "
                        "(--real-dir)")
    if sources[int(rng.integers(len(sources)))] == "photo":
        return textures.photo(rng)
    return np.ascontiguousarray(real.scenes[int(rng.integers(len(real.scenes)))].left, dtype=np.float32)


def photo_mapping(rng: np.random.Generator, image: np.ndarray, height: int, width: int) -> np.ndarray:
    """2x3 map from view (x, y) into ``image`` (u, v): a similarity of scale 0.6-1.4 (less where the
    image is too small to cover the view) and up to 0.1 rad of rotation, placed inside the image
    where it fits (mirrored at its border where it does not)."""
    rows, cols = image.shape[:2]
    fits = 0.95 * min(cols / width, rows / height)
    scale = math.exp(rng.uniform(math.log(min(0.6, fits)), math.log(max(min(1.4, fits), min(0.6, fits)))))
    angle = rng.uniform(-0.1, 0.1)
    cos, sin = scale * math.cos(angle), scale * math.sin(angle)
    u0 = rng.uniform(0.0, max(0.0, cols - scale * width))
    v0 = rng.uniform(0.0, max(0.0, rows - scale * height))
    return np.array([[cos, -sin, u0], [sin, cos, v0]], np.float64)


def render_floating(
    rng: np.random.Generator,
    height: int,
    width: int,
    *,
    limit: float,
    textures: TexturePool,
    real: RealScenes | None = None,
    photometric: Photometric = Photometric(),
    misalignment: Misalignment = NO_MISALIGNMENT,
    thin: float = 0.0,
) -> StereoScene:
    """One stereo pair of floating objects over a real background, disparity in [0, limit).

    Args:
        textures: the objects' textures, and the background photos (its image files).
        real: real training scenes whose left views may serve as the background.
        photometric, misalignment: as :func:`~cade_cli.train.scenes.render_scene`.
        thin: share of the scenes with thin structures among the objects
            (:func:`~cade_cli.train.scenes.thin_layers`); no draw when 0.

    Raises:
        CadeError: neither texture photos nor real scenes to take the background from.
    """
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    background = real_background(rng, textures, real)
    background_high = limit * (0.5 if rng.random() < 0.7 else 0.95)
    layers = [Layer(random_plane(rng, height, width, 0.0, background_high), None, background,
                    photo_mapping(rng, background, height, width))]
    corners = layers[0].disparity(np.array([0.0, width, 0.0, width]), np.array([0.0, 0.0, height, height]))
    farthest_background = float(corners.min())
    for _ in range(int(rng.integers(*FLOATING_OBJECTS))):
        low = farthest_background if rng.random() < 0.8 else 0.0
        layers.append(Layer(random_plane(rng, height, width, low, limit * 0.995),
                            random_shape(rng, height, width, size=FLOATING_SIZE),
                            *textured_surface(rng, textures, height, width)))
    if thin > 0 and rng.random() < thin:
        layers += thin_layers(rng, height, width, far=farthest_background, limit=limit, textures=textures)
    return render_layers(rng, layers, photometric=photometric, misalignment=misalignment, x=x, y=y)
