"""Cross-spectral training pairs made CADE's way (METHOD.md sections 2-3), and the two
ways the paper compares it with (section 6), for the training ablation.

A rendered RGB stereo pair becomes a cross-spectral one by synthesizing the 11 bands of
each view (the same coefficients for both views, so a band means the same "filter" in
both) and drawing the left and the right band independently; both then go through the
runtime's own :func:`~cade_cli.spectral.color_agnostic`. The training modes
(:data:`TRAINING_MODES`):

* ``cade``: as above (every shipped model);
* ``csdl``: the left and the right band drawn independently from the four weighted-sum
  bands only (:data:`CSDL_BANDS`), each with its own simulated sensor noise, no color
  agnostic transform (each band rescaled to [0, 1]: :func:`~cade_cli.spectral.normalised`);
* ``pristine``: ordinary stereo training: the same channel (R, G or B) on both sides, no
  transform (rescaled to [0, 1]).

All three draw their scenes (and so their per-view camera changes) from the same generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cade_cli.spectral import BAND_NAMES, network_input, normalised, synthesize_bands
from cade_cli.train.scenes import StereoScene


TRAINING_MODES: tuple[str, ...] = ("cade", "csdl", "pristine")
CSDL_BANDS: tuple[str, ...] = ("BG", "BR", "GR", "BGR")
"""The four weighted-sum bands of METHOD.md section 2, the only ones CSDL trains on."""
CSDL_NOISE = (0.0, 0.03)
"""Range of the standard deviation (of the band's [0, 1] scale) of the Gaussian noise CSDL
adds to each view of a pair independently."""
PRISTINE_BANDS: tuple[str, ...] = ("R", "G", "B")


def network_input_of(mode: str, chosen: str | None = None) -> str:
    """The card's ``input`` (:data:`~cade_cli.spectral.NETWORK_INPUTS`) of a network trained
    in ``mode``: ``chosen`` when given (``fit --network-input``; the ``cade`` mode only),
    else the mode's own."""
    if chosen:
        return chosen
    return "cade" if mode == "cade" else "normalised"


@dataclass(frozen=True)
class CadePair:
    """left, right: (H, W) float32 bands as the network takes them (color-agnostic, or for
    the ablation's other modes rescaled to [0, 1]); disparity, nonoccluded as in the scene."""

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonoccluded: np.ndarray
    bands: tuple[str, str]
    left_alt: np.ndarray | None = None
    """The left view in a second band (drawn with ``second_left``): the same points in
    another spectral mix, for the feature-consistency loss."""
    guides: np.ndarray | None = None
    """A real pair without ground truth (the self-supervised source, :mod:`~cade_cli.train.selfsup_pairs`):
    (4, H, W) left and right bands rescaled to about [0, 1] and where each was seen; its
    ``disparity`` is NaN throughout."""


def both_views_bands(scene: StereoScene, rng: np.random.Generator) -> tuple[dict, dict]:
    """The 11 bands of each view, synthesized with the same coefficients (one seed drawn from ``rng``)."""
    seed = int(rng.integers(2**63))
    return (synthesize_bands(scene.left, np.random.default_rng(seed)),
            synthesize_bands(scene.right, np.random.default_rng(seed)))


def cade_pair(scene: StereoScene, rng: np.random.Generator, kind: str = "cade", *,
              second_left: bool = False) -> CadePair:
    """Draw a left and a right band of ``scene`` independently and CADE-transform both
    (``kind``: the network input, ``cade`` or the ``cade-floor`` lever); with
    ``second_left`` also another band of the left view (``left_alt``; drawn after the
    others, so the pair itself is the one drawn without it)."""
    left_bands, right_bands = both_views_bands(scene, rng)
    left_name, right_name = (str(name) for name in rng.choice(BAND_NAMES, size=2))
    left_alt = None
    if second_left:
        alt_name = str(rng.choice([name for name in BAND_NAMES if name != left_name]))
        left_alt = network_input(left_bands[alt_name], kind)
    return CadePair(
        left=network_input(left_bands[left_name], kind),
        right=network_input(right_bands[right_name], kind),
        disparity=scene.disparity,
        nonoccluded=scene.nonoccluded,
        bands=(left_name, right_name),
        left_alt=left_alt,
    )


def training_pair(scene: StereoScene, rng: np.random.Generator, mode: str = "cade", kind: str | None = None, *,
                  second_left: bool = False) -> CadePair:
    """A pair of ``scene`` made in training ``mode`` (:data:`TRAINING_MODES`); ``cade`` is
    :func:`cade_pair` itself, drawing exactly the same random numbers (its transform
    ``kind`` may be chosen: :func:`network_input_of`; ``second_left``: the ``cade`` mode only)."""
    if mode == "cade":
        return cade_pair(scene, rng, network_input_of(mode, kind), second_left=second_left)
    if second_left:
        raise ValueError(f"a second left band is drawn in the cade training mode only, not {mode!r}")
    if kind:
        raise ValueError(f"a network input can be chosen in the cade training mode only, not {mode!r}")
    if mode not in TRAINING_MODES:
        raise ValueError(f"unknown training mode {mode!r}; choose one of {', '.join(TRAINING_MODES)}")
    left_bands, right_bands = both_views_bands(scene, rng)
    if mode == "pristine":
        left_name = right_name = str(rng.choice(PRISTINE_BANDS))
        left, right = left_bands[left_name], right_bands[right_name]
    else:
        left_name, right_name = (str(name) for name in rng.choice(CSDL_BANDS, size=2))
        left, right = (band + rng.normal(0.0, rng.uniform(*CSDL_NOISE), band.shape).astype(np.float32)
                       for band in (left_bands[left_name], right_bands[right_name]))
    return CadePair(left=normalised(left), right=normalised(right), disparity=scene.disparity,
                    nonoccluded=scene.nonoccluded, bands=(left_name, right_name))
