"""Cross-spectral training pairs made CADE's way (METHOD.md sections 2-3).

A rendered RGB stereo pair becomes a cross-spectral one by synthesizing the 11 bands of
each view (the same coefficients for both views, so a band means the same "filter" in
both) and drawing the left and the right band independently; both then go through the
runtime's own :func:`~cade_cli.spectral.color_agnostic`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cade_cli.spectral import BAND_NAMES, color_agnostic, synthesize_bands
from cade_cli.train.scenes import StereoScene


@dataclass(frozen=True)
class CadePair:
    """left, right: (H, W) float32 color-agnostic bands; disparity, nonoccluded as in the scene."""

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonoccluded: np.ndarray
    bands: tuple[str, str]


def cade_pair(scene: StereoScene, rng: np.random.Generator) -> CadePair:
    """Draw a left and a right band of ``scene`` independently and CADE-transform both."""
    seed = int(rng.integers(2**63))
    left_bands = synthesize_bands(scene.left, np.random.default_rng(seed))
    right_bands = synthesize_bands(scene.right, np.random.default_rng(seed))
    left_name, right_name = (str(name) for name in rng.choice(BAND_NAMES, size=2))
    return CadePair(
        left=color_agnostic(left_bands[left_name]),
        right=color_agnostic(right_bands[right_name]),
        disparity=scene.disparity,
        nonoccluded=scene.nonoccluded,
        bands=(left_name, right_name),
    )
