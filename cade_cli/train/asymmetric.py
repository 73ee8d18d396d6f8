"""Per-view asymmetric augmentation: one view of a pair through a camera the other did not
use (issue 51 item 3), beyond what the spectral mixes and :func:`~cade_cli.train.scenes.camera`
(each view's own gain, gamma, blur and noise from the same ranges) already vary.

Two cameras behind different filters differ in more than their band: optics (defocus,
vignetting), processing (tone curve, contrast) and storage (JPEG). :func:`one_view_changed`
applies a random subset of those to the left or the right view only; the ground truth and
the visibility mask do not change.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from cade_cli.train.scenes import StereoScene

EFFECTS = ("vignetting", "defocus", "gamma", "contrast", "blur", "noise", "jpeg")
"""The changes, in the order a camera applies them (optics, tone, sensor, storage)."""
EFFECT_SHARE = 0.4
"""Probability of each effect in a changed view (at least one is always applied)."""


def one_view_changed(scene: StereoScene, rng: np.random.Generator, share: float) -> StereoScene:
    """With probability ``share``, ``scene`` with its left or its right view (each half the time)
    changed by a random subset of :data:`EFFECTS` (no draw when ``share`` is 0):

    * vignetting: brightness falling to 50-80 % at the corners (radially, squared);
    * defocus: a pillbox blur of radius 1-2 px;
    * gamma: 0.6-1.6 (log-uniform);
    * contrast and brightness: (v - 0.5) * c + 0.5 + b, c in [0.6, 1.4], b in [-0.15, 0.15];
    * blur: a Gaussian of sigma 0.3-1.2 px;
    * noise: Gaussian, sigma 0.005-0.04;
    * jpeg: stored as JPEG of quality 15-80 (8x8 blocks, quantised frequencies).

    The view stays (H, W, 3) float32 in [0, 1]; ``disparity`` and ``nonoccluded`` are unchanged.
    """
    if share <= 0 or rng.random() >= share:
        return scene
    which = "left" if rng.random() < 0.5 else "right"
    chosen = rng.random(len(EFFECTS)) < EFFECT_SHARE
    if not chosen.any():
        chosen[int(rng.integers(len(EFFECTS)))] = True
    image = getattr(scene, which)
    for effect, on in zip(EFFECTS, chosen):
        if on:
            image = np.clip(_apply(effect, image, rng), 0.0, 1.0).astype(np.float32)
    return replace(scene, **{which: image})


def _apply(effect: str, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``image`` (float32 RGB in [0, 1]) with one of :data:`EFFECTS` drawn from ``rng``."""
    height, width = image.shape[:2]
    if effect == "vignetting":
        y, x = np.mgrid[0:height, 0:width].astype(np.float32)
        radius2 = ((x - width / 2) ** 2 + (y - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
        return image * (1.0 - np.float32(rng.uniform(0.2, 0.5)) * radius2)[..., None]
    if effect == "defocus":
        radius = rng.uniform(1.0, 2.0)
        size = 2 * int(np.ceil(radius)) + 1
        y, x = np.mgrid[0:size, 0:size] - size // 2
        disk = (x * x + y * y <= radius * radius).astype(np.float32)
        return cv2.filter2D(image, -1, disk / disk.sum(), borderType=cv2.BORDER_REFLECT_101)
    if effect == "gamma":
        return np.power(image, np.float32(np.exp(rng.uniform(np.log(0.6), np.log(1.6)))))
    if effect == "contrast":
        contrast, brightness = rng.uniform(0.6, 1.4), rng.uniform(-0.15, 0.15)
        return (image - 0.5) * np.float32(contrast) + np.float32(0.5 + brightness)
    if effect == "blur":
        return cv2.GaussianBlur(image, (0, 0), rng.uniform(0.3, 1.2))
    if effect == "noise":
        return image + np.float32(rng.uniform(0.005, 0.04)) * rng.standard_normal(image.shape).astype(np.float32)
    if effect == "jpeg":
        quality = int(rng.integers(15, 81))
        stored = np.rint(image[..., ::-1] * 255.0).astype(np.uint8)
        _, encoded = cv2.imencode(".jpg", stored, [cv2.IMWRITE_JPEG_QUALITY, quality])
        return cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255.0
    raise ValueError(f"unknown effect {effect!r}; choose one of {', '.join(EFFECTS)}")
