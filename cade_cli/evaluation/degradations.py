"""What an imperfect multispectral rig does to a band, one way at a time.

Benchmark pairs are rectified to a fraction of a pixel and their bands come from one
sensor. Two cameras behind different filters are not: rectification leaves a vertical
offset or a slight roll, one band is softer (NIR focuses behind visible light) or
noisier, lenses vignette, and some materials reverse their contrast between bands
(vegetation is dark in red, bright in NIR). The benchmark loop applies one of these to
the RIGHT band of every task (``degradations=`` of
:func:`cade_cli.evaluation.loop.run_benchmark`):

    none          the band as it is
    vshift-0.5    rows moved by 0.5 px (bilinear), a typical residual after calibration
    vshift-1      rows moved by 1 px
    roll-0.2      rotated by 0.2 degrees about the image centre
    blur-1.5      Gaussian blur, sigma 1.5 px
    noise-6       Gaussian noise, sigma 6/255 of the band's [0, 1] range
    vignette      brightness falling to 40 % in the corners
    invert-half   contrast inverted in the right half of the image only
    invert        contrast inverted everywhere

Each is ``degradation(band, rng) -> band`` on an (H, W) float32 band in [0, 1]; only
``noise-6`` draws from ``rng``.

The counter-measure to the first three is :class:`VerticallyCorrected`: a matcher that runs
the rectification self-check (:func:`cade_cli.rigs.self_check.align_vertically`) on each pair and
matches the corrected right band, as ``cade disparity --rig --fix-vertical`` does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import cv2
import numpy as np

from cade_cli.errors import CadeError, lookup
from cade_cli.rigs.self_check import align_vertically

Degradation = Callable[[np.ndarray, np.random.Generator], np.ndarray]


def vertical_shift(band: np.ndarray, rows: float) -> np.ndarray:
    """Content moves up by ``rows``: output row y shows input row y + rows (bilinear)."""
    height, width = band.shape
    shift = np.float32([[1, 0, 0], [0, 1, rows]])
    return cv2.warpAffine(band, shift, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def roll(band: np.ndarray, degrees: float) -> np.ndarray:
    """Rotated by ``degrees`` about the image centre (bilinear, borders replicated)."""
    height, width = band.shape
    rotation = cv2.getRotationMatrix2D((width / 2, height / 2), degrees, 1.0)
    return cv2.warpAffine(band, rotation, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def vignette(band: np.ndarray) -> np.ndarray:
    """Brightness times 1 - 0.6 r^2, r = distance from the centre / half-diagonal (0.4 in the corners)."""
    height, width = band.shape
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    radius2 = ((x - width / 2) ** 2 + (y - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
    return band * (1 - 0.6 * radius2)


def invert_right_half(band: np.ndarray) -> np.ndarray:
    """Contrast inverted (1 - band) in columns from W // 2 on."""
    right_half = np.arange(band.shape[1])[None, :] >= band.shape[1] // 2
    return np.where(right_half, 1 - band, band)


DEGRADATIONS: dict[str, Degradation] = {
    "none": lambda band, rng: band,
    "vshift-0.5": lambda band, rng: vertical_shift(band, 0.5),
    "vshift-1": lambda band, rng: vertical_shift(band, 1.0),
    "roll-0.2": lambda band, rng: roll(band, 0.2),
    "blur-1.5": lambda band, rng: cv2.GaussianBlur(band, (0, 0), 1.5),
    "noise-6": lambda band, rng: band + rng.normal(0, 6 / 255, band.shape).astype(np.float32),
    "vignette": lambda band, rng: vignette(band),
    "invert-half": lambda band, rng: invert_right_half(band),
    "invert": lambda band, rng: 1 - band,
}
"""Name -> degradation of a right band (see the module docstring)."""


def get_degradation(name: str) -> Degradation:
    """The degradation called ``name``; raises :class:`CadeError` listing the choices."""
    return lookup(DEGRADATIONS, name, kind="degradation")


def degrade(band: np.ndarray, name: str, *, seed: int = 0) -> np.ndarray:
    """``band`` degraded the ``name`` way, as float32; the noise is drawn from
    ``np.random.default_rng(seed)``, so every band of a run gets the same draw."""
    return np.asarray(get_degradation(name)(band, np.random.default_rng(seed)), np.float32)


@dataclass(frozen=True)
class VerticallyCorrected:
    """``matcher`` behind the rectification self-check: each call first measures the
    vertical offset and roll between the bands and, when they reach
    :data:`~cade_cli.rigs.self_check.MIN_CORRECTION_PX`, resamples the right band to cancel
    them (:func:`~cade_cli.rigs.self_check.align_vertically`, disparities up to the call's
    ``max_disp``), then matches. A pair with too few feature matches is matched as it is. Every other attribute is the
    wrapped matcher's (its name, preprocessing, volume), so the benchmark loop treats it
    as that matcher; its time includes the self-check."""

    matcher: Any

    def __call__(self, left: np.ndarray, right: np.ndarray, **options: Any) -> Any:
        try:
            right, _, _ = align_vertically(left, right, max_disp=options.get("max_disp"))
        except CadeError:  # too little shared texture to measure: matched as it is
            pass
        return self.matcher(left, right, **options)

    def __getattr__(self, name: str) -> Any:
        if name == "matcher":  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.matcher, name)
