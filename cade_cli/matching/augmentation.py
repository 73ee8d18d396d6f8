"""Test-time augmentation of the network stage: extra network passes over a transformed pair, fused
with the plain pass (a card's ``test_time_augmentation``, :data:`cade_cli.model_card.TEST_TIME_AUGMENTATIONS`).

* ``vertical-flip``: the pair upside down (same rows, same disparities, other context above and below);
  fused by :func:`fuse_estimates`.
* ``upscaled-x1.5``, ``upscaled-x2``: the raw bands enlarged (bicubic) before their network input is
  computed, so the network's quarter-resolution cost volume sees finer detail (thin structures, sub-pixel
  slopes); its disparity, shrunk back (area mean) and divided by the factor, is fused by
  :func:`fuse_estimates`. The factor is lowered to what the variant searches (:func:`second_scale`) and the
  pass skipped when that leaves almost nothing (wide ranges).
* ``mirrored``: the right view's disparity (the pair mirrored left-right and swapped, so the network
  searches the same direction), sampled where each left pixel lands in the right view: a left-right
  consistency check. Where the two agree their inverse-variance mean, elsewhere (occlusions, the left
  view's border, mismatches) the plain pass (:func:`left_right_fuse`).

The functions work on one pyramid level's bands, before the minimum disparity is added back.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import cv2
import numpy as np


class NetworkOutput(NamedTuple):
    """The network's two (H, W) float32 outputs for the left view, px: ``disparity`` and
    ``uncertainty`` (standard deviation of its soft-argmin distribution, >= 0)."""

    disparity: np.ndarray
    uncertainty: np.ndarray


NetworkPass = Callable[[np.ndarray, np.ndarray], NetworkOutput]
"""One network run: (left, right) network-input bands -> its output for the left one."""

FUSE_AGREEMENT_PX = 1.0
"""Two passes' disparities within this many px (plus their uncertainties) are one surface and
are averaged; farther apart they are two guesses, and the more certain one is kept."""
UPSCALE_INTERPOLATION = cv2.INTER_CUBIC
"""How a raw band is enlarged for the second scale: bicubic keeps edges sharper than bilinear."""
SMALLEST_SECOND_SCALE = 1.2
"""A second-scale pass whose factor the searchable span lowers below this is skipped: it would cost a
pass and see almost the same detail."""


def _agreement(first: NetworkOutput, second: NetworkOutput) -> tuple[np.ndarray, NetworkOutput]:
    """Where two estimates agree (within :data:`FUSE_AGREEMENT_PX` plus the larger uncertainty), and
    their inverse-variance weighted means (of the uncertainties too, with the same weights, so the
    uncertainty keeps the scale the card's chooser was fitted on)."""
    d1, u1, d2, u2 = first.disparity, first.uncertainty, second.disparity, second.uncertainty
    w1, w2 = (1.0 / (np.square(u) + np.float32(0.25)) for u in (u1, u2))
    agree = np.abs(d1 - d2) <= FUSE_AGREEMENT_PX + np.maximum(u1, u2)
    return agree, NetworkOutput((w1 * d1 + w2 * d2) / (w1 + w2), (w1 * u1 + w2 * u2) / (w1 + w2))


def fuse_estimates(first: NetworkOutput, second: NetworkOutput) -> NetworkOutput:
    """One estimate of two network passes over the same pair: where they agree the inverse-variance
    weighted mean (:func:`_agreement`); elsewhere the pass with the lower uncertainty."""
    agree, mean = _agreement(first, second)
    first_surer = first.uncertainty <= second.uncertainty
    disparity = np.where(agree, mean.disparity, np.where(first_surer, first.disparity, second.disparity))
    uncertainty = np.where(agree, mean.uncertainty, np.where(first_surer, first.uncertainty, second.uncertainty))
    return NetworkOutput(disparity.astype(np.float32), uncertainty.astype(np.float32))


def flipped_pass(run: NetworkPass, left: np.ndarray, right: np.ndarray) -> NetworkOutput:
    """The pass over the pair upside down, turned back."""
    flipped = run(left[::-1].copy(), right[::-1].copy())
    return NetworkOutput(flipped.disparity[::-1], flipped.uncertainty[::-1])


def second_scale(wanted: float, span: float, searchable: int) -> float | None:
    """The enlargement of a second-scale pass: ``wanted``, lowered so that the enlarged ``span`` (px of
    the level's bands) stays within ``searchable``; None when that is below :data:`SMALLEST_SECOND_SCALE`."""
    factor = min(wanted, searchable / max(span, 1e-6))
    return factor if factor >= SMALLEST_SECOND_SCALE else None


def upscaled_pass(run: NetworkPass, to_input: Callable[[np.ndarray], np.ndarray], left: np.ndarray,
                  right: np.ndarray, size: tuple[int, int], factor: float) -> NetworkOutput:
    """The pass over the raw bands ``left``, ``right`` resized to ``factor`` x ``size`` ((width, height)
    of the level's bands: bicubic when that enlarges them, by area when a pyramid level leaves it below
    their size), its network input made by ``to_input``; the output shrunk back to ``size``
    (area mean) and divided by the true enlargement of the width."""
    width, height = size
    large = (max(1, round(width * factor)), max(1, round(height * factor)))
    # On a pyramid level the "enlarged" pair may still be smaller than the raw one: shrink it by area then.
    interpolation = UPSCALE_INTERPOLATION if large[0] > left.shape[1] else cv2.INTER_AREA
    bands = [to_input(cv2.resize(np.asarray(band, np.float32), large, interpolation=interpolation))
             for band in (left, right)]
    output = run(*bands)
    scale = np.float32(large[0] / width)
    return NetworkOutput(*(cv2.resize(band, size, interpolation=cv2.INTER_AREA) / scale for band in output))


def mirrored_pass(run: NetworkPass, left: np.ndarray, right: np.ndarray) -> NetworkOutput:
    """The right view's disparity and uncertainty: the network on (mirrored right, mirrored left), whose
    matches lie at the same positive disparities, mirrored back."""
    mirrored = run(right[:, ::-1].copy(), left[:, ::-1].copy())
    return NetworkOutput(mirrored.disparity[:, ::-1], mirrored.uncertainty[:, ::-1])


def warp_to_left(right_view: NetworkOutput, left_disparity: np.ndarray) -> tuple[NetworkOutput, np.ndarray]:
    """The right view's output sampled (bilinear) where each left pixel lands in the right view,
    x - ``left_disparity``; and the mask of left pixels that land inside it."""
    height, width = left_disparity.shape
    map_x = (np.arange(width, dtype=np.float32)[None, :] - left_disparity).astype(np.float32)
    map_y = np.broadcast_to(np.arange(height, dtype=np.float32)[:, None], (height, width)).astype(np.float32)
    warped = NetworkOutput(*(cv2.remap(np.ascontiguousarray(band, np.float32), map_x, map_y, cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_REPLICATE) for band in right_view))
    return warped, (map_x >= 0) & (map_x <= width - 1)


def left_right_fuse(plain: NetworkOutput, right_view: NetworkOutput) -> NetworkOutput:
    """The left view's estimate checked against the right view's: where the right view's disparity at the
    matching pixel agrees (:func:`_agreement`), the inverse-variance mean of the two; elsewhere (the left
    view's occlusions, pixels that leave the right view, mismatches) the plain pass as it is."""
    warped, inside = warp_to_left(right_view, plain.disparity)
    agree, mean = _agreement(plain, warped)
    agree &= inside
    return NetworkOutput(np.where(agree, mean.disparity, plain.disparity).astype(np.float32),
                         np.where(agree, mean.uncertainty, plain.uncertainty).astype(np.float32))
