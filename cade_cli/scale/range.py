"""The disparity search range of a pair, estimated from a coarse pyramid level (``--max-disp auto``).

A pair's range is found by matching it cheaply at low resolution and widening what was
found by a margin:

1. both bands are downscaled by :func:`coarse_factor` (a power of two that brings the
   width to at most :data:`COARSE_WIDTH` px; area averaging);
2. the coarse pair goes through :func:`cade_cli.stereo.estimate_disparity` with the
   ``census-sgm`` matcher on the colour-agnostic bands (``preprocess="cade"``), so bands seen
   through different filters, contrast inversions included, match as well as one band
   does; the search covers every disparity the image allows that the caller left open
   (up to half the width either way, or the bound the caller gave);
3. of the coarse estimates that passed the matcher's checks, the more confident half
   (peak-ratio confidence above its median; mismatches are mostly in the other half) is
   kept; its robust low and high percentiles (:data:`LOW_PERCENTILE`,
   :data:`HIGH_PERCENTILE`), scaled back to full resolution, are widened by a margin
   (:func:`cade_cli.matching.base.range_margin`) and rounded outwards.

The returned bounds are inclusive, like every range in the package, and fit the image
(:meth:`~cade_cli.matching.DisparityRange.check_for_width`). The coverage of the result
is measured on the benchmark sets by ``benchmarks/auto_range.py`` (docs/scale.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching import DisparityRange, DisparityResult
from cade_cli.matching.base import range_margin
from cade_cli.stereo import estimate_disparity

AUTO = "auto"
"""The value of ``--max-disp`` / ``--min-disp`` that asks for the estimated bound."""
COARSE_WIDTH = 256
"""The coarse level is the first power-of-two downscale at most this wide (px)."""
COARSE_METHOD = "census-sgm"
"""Matcher of the coarse level (on colour-agnostic bands): unlike OpenCV's SGBM it keeps
estimates near the left border however wide the search, so wide open ranges stay measurable."""
LOW_PERCENTILE = 0.2
HIGH_PERCENTILE = 99.8
"""Percentiles (%) of the confident coarse estimates taken as the scene's range before the
margin: robust to the few mismatches that survive the matcher's checks."""
CONFIDENT_QUANTILE = 0.5
"""Estimates whose confidence is below this quantile of the coarse confidences are left out."""
MIN_VALID_SHARE = 0.02
"""Fewer valid coarse estimates than this share of the coarse pixels: no estimate (an
empty, blank or unmatched pair), and the caller is asked for a range."""


@dataclass(frozen=True)
class RangeEstimate:
    """What :func:`estimate_range` found.

    Attributes:
        range: the inclusive search range, px of the input images.
        factor: downscale of the coarse level (1, 2, 4, ...).
        found: (low, high) percentiles of the coarse estimates, px of the input images.
        margin: px added below ``found[0]`` and above ``found[1]`` (where estimated).
        valid_share: share of the coarse pixels with an estimate, in [0, 1].
    """

    range: DisparityRange
    factor: int
    found: tuple[float, float]
    margin: float
    valid_share: float

    def describe(self, *, estimated: tuple[bool, bool]) -> str:
        """One line for the user: the range and how it was found."""
        bounds = " and ".join(name for name, chosen in zip(("--min-disp", "--max-disp"), estimated) if chosen)
        return (f"{bounds} auto: searching [{self.range.minimum}, {self.range.maximum}] px "
                f"({'a full-scale' if self.factor == 1 else f'a 1/{self.factor}-scale'} match found {self.found[0]:.1f}..{self.found[1]:.1f} px on "
                f"{100 * self.valid_share:.0f}% of the pixels, plus a {self.margin:.1f} px margin)")


def coarse_factor(width: int, *, coarse_width: int = COARSE_WIDTH) -> int:
    """Smallest power of two that brings ``width`` (px) to at most ``coarse_width``."""
    factor = 1
    while width / factor > coarse_width:
        factor *= 2
    return factor


@dataclass(frozen=True)
class CoarseMatch:
    """The coarse level's match (:func:`coarse_match`).

    Attributes:
        result: the coarse pair's :class:`~cade_cli.matching.DisparityResult`, px of the
            coarse level (multiply by ``scale`` for px of the input images).
        factor: downscale of the coarse level (1, 2, 4, ...).
        scale: input width / coarse width (``factor``, up to rounding).
    """

    result: DisparityResult
    factor: int
    scale: float


def coarse_match(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disp: int | None = None,
    max_disp: int | None = None,
) -> CoarseMatch:
    """Steps 1 and 2 of the estimate: the pair downscaled by :func:`coarse_factor` and
    matched by :data:`COARSE_METHOD` on colour-agnostic bands, over the bounds given (px of
    the input images; None: open on that side), the right band as it is and inverted (the
    polarity that matches more pixels wins).

    Raises:
        CadeError: bad shapes, a pair too small, or bounds that leave nothing to search.
    """
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    if left.ndim != 2 or left.shape != right.shape:
        raise CadeError(f"the range is estimated on two bands of one shape (H, W), got {left.shape} and "
                        f"{right.shape}; pick one band of each image")
    height, width = left.shape
    if width < 8 or height < 8:
        raise CadeError(f"a {width}x{height} pair is too small to estimate its disparity range; give --max-disp")
    factor = coarse_factor(width)
    coarse_size = (max(8, round(width / factor)), max(8, round(height / factor)))
    coarse_left, coarse_right = ((cv2.resize(band, coarse_size, interpolation=cv2.INTER_AREA) if factor > 1 else band)
                                 for band in (left, right))
    scale = width / coarse_size[0]
    reach = max(1, coarse_size[0] // 2)  # the widest search the coarse level makes on an open side
    low = -reach if min_disp is None else math.floor(min_disp / scale)
    high = reach if max_disp is None else math.ceil(max_disp / scale)
    low, high = max(low, -(coarse_size[0] - 1)), min(high, coarse_size[0] - 1)
    if high <= low:
        raise CadeError(f"--min-disp {min_disp} and --max-disp {max_disp} leave no range to search; "
                        "give a smaller --min-disp or a larger --max-disp")
    # The colour-agnostic transform absorbs any gain and offset between the bands but not a
    # contrast inversion (a material bright in one band and dark in the other): the right
    # band is matched as it is and inverted, and the polarity that matches more pixels wins.
    flipped = float(coarse_right.max()) + float(coarse_right.min()) - coarse_right
    result = max((estimate_disparity(coarse_left, band, method=COARSE_METHOD, min_disp=low, max_disp=high,
                                     preprocess="cade") for band in (coarse_right, flipped)),
                 key=lambda found: int(found.valid.sum()))
    return CoarseMatch(result, factor, scale)


def confident_bounds(found: np.ndarray, confidence: np.ndarray, scale: float) -> tuple[float, float]:
    """Step 3 before the margin: the robust (low, high) percentiles of the more confident half
    of coarse estimates ``found`` (px of the coarse level, with their ``confidence``), in px
    of the input images (times ``scale``)."""
    confident = found[confidence >= np.quantile(confidence, CONFIDENT_QUANTILE)]
    low, high = np.percentile(confident, [LOW_PERCENTILE, HIGH_PERCENTILE])
    return float(low) * scale, float(high) * scale


def estimate_range(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disp: int | None = None,
    max_disp: int | None = None,
) -> RangeEstimate:
    """Estimate the disparity range of a rectified pair from a coarse pyramid level.

    Args:
        left, right: (H, W) float bands of one rectified pair, any units; they may come
            from different spectral filters.
        min_disp, max_disp: bounds the caller fixed (px, inclusive); None: estimate it.
            With ``min_disp`` None the minimum may come out negative (pairs registered
            to a plane); with both None both are estimated.

    Returns:
        :class:`RangeEstimate`; its ``range`` keeps the given bounds as they are.

    Raises:
        CadeError: bad shapes, given bounds that leave nothing to search, or a pair with
            too few matchable pixels to estimate from (name the range instead).
    """
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    coarse = coarse_match(left, right, min_disp=min_disp, max_disp=max_disp)
    width = left.shape[1]
    factor, scale = coarse.factor, coarse.scale
    matched = coarse.result.valid & np.isfinite(coarse.result.disparity)
    found, confidence = coarse.result.disparity[matched], coarse.result.confidence[matched]
    valid_share = found.size / coarse.result.disparity.size
    if valid_share < MIN_VALID_SHARE or found.size < 16:
        raise CadeError(f"could not estimate the disparity range: only {100 * valid_share:.1f}% of the pair "
                        "matched at the coarse level (blank, unrelated or unrectified images?); give --max-disp "
                        "and --min-disp")
    found_low, found_high = confident_bounds(found, confidence, scale)
    margin = range_margin(found_low, found_high, factor)
    minimum = min_disp if min_disp is not None else max(-(width - 1), math.floor(found_low - margin))
    maximum = max_disp if max_disp is not None else min(width - 1, math.ceil(found_high + margin))
    if max_disp is None:  # an estimated bound gives way to a given one; the range may lie below zero
        maximum = max(maximum, minimum + 1)
    elif min_disp is None:
        minimum = min(minimum, maximum - 1)
    chosen = DisparityRange(int(minimum), int(maximum))
    chosen.check_for_width(width)
    return RangeEstimate(chosen, factor, (found_low, found_high), margin, valid_share)


def parse_bound(text: str | int, *, option: str, minimum: int | None = None) -> int | str:
    """A range bound as the user gave it: an integer (px) or ``"auto"``.

    Raises:
        CadeError: anything else, or an integer below ``minimum``; the message names ``option``.
    """
    value = str(text).strip()
    if value.lower() == AUTO:
        return AUTO
    try:
        number = int(value)
    except ValueError:
        raise CadeError(f"--{option} {value!r} is not a whole number of pixels or 'auto'") from None
    if minimum is not None and number < minimum:
        raise CadeError(f"--{option} {number} is below {minimum}; give at least {minimum} or 'auto'")
    return number


def check_bounds(low: int | str | None, high: int | str | None) -> None:
    """Refuse a range given in whole pixels that leaves nothing to search: ``high`` below ``low``
    (empty) or equal to it (one disparity: every pixel would get it, all "valid").
    ``"auto"`` or None bounds are checked once resolved (:meth:`DisparityRange.check_for_width`)."""
    if not (isinstance(low, int) and isinstance(high, int)):
        return
    if high < low:
        raise CadeError(f"--max-disp {high} is below --min-disp {low}; raise --max-disp or lower --min-disp")
    if high == low:
        raise CadeError(f"--min-disp {low} and --max-disp {high} leave one disparity to search; give a --max-disp "
                        f"above --min-disp (the scene's largest disparity, px) or a lower --min-disp")


def resolve_range(
    left: np.ndarray, right: np.ndarray, *, min_disp: int | str = 0, max_disp: int | str | None = None
) -> tuple[DisparityRange, RangeEstimate | None]:
    """The range to search on a pair, given bounds that may be ``"auto"``.

    Args:
        left, right: (H, W) bands of the pair.
        min_disp: px, or ``"auto"`` (estimated, may be negative).
        max_disp: px, ``"auto"`` (estimated), or None: the default
            (:func:`cade_cli.stereo.default_max_disparity`).

    Returns:
        (range, the estimate when a bound was ``auto``, else None). A given bound is kept
        as given; the range is not checked against the width here (the matcher does).
    """
    from cade_cli.stereo import default_max_disparity

    width = np.asarray(left).shape[-1]
    if max_disp is None:
        max_disp = default_max_disparity(width)
    if min_disp != AUTO and max_disp != AUTO:
        return DisparityRange(int(min_disp), int(max_disp)), None
    estimate = estimate_range(left, right, min_disp=None if min_disp == AUTO else int(min_disp),
                              max_disp=None if max_disp == AUTO else int(max_disp))
    return estimate.range, estimate
