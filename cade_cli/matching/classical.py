"""Classical matchers: own Census/ZNCC/DASC + SGM pipelines, and OpenCV's StereoSGBM."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Callable

import cv2
import numpy as np

from cade_cli.matching.base import DisparityRange, DisparityResult, preprocessed
from cade_cli.matching.confidence import neighbourhood_confidence, peak_ratio_confidence
from cade_cli.matching.cost import CostVolume, census_cost, quantize, zncc_cost
from cade_cli.matching.dasc import DASC_STEREO_PATTERN, dasc_cost
from cade_cli.matching.disparity import (
    best_level,
    fill_invalid_along_rows,
    left_right_check,
    right_view_cost,
    winner_takes_all,
)
from cade_cli.matching.sgm import sgm_aggregate

CostFunction = Callable[[np.ndarray, np.ndarray, DisparityRange], CostVolume]


@dataclass(frozen=True)
class SgmPipeline:
    """cost -> 8-path SGM -> WTA + parabola -> left-right check -> median (of the
    row-filled map, kept at the valid pixels); the result is unfilled (NaN where invalid).
    Its confidence is the peak ratio of the aggregated cost at the winner
    (:func:`~cade_cli.matching.confidence.peak_ratio_confidence`), 0 where invalid.

    Attributes:
        cost: builds the (H, W, D) lower-is-better volume.
        p1, p2: SGM penalties in the cost's units (after quantization, if any).
        quantize_scale: when set, float costs are turned into uint8 levels
            (``rint(cost * scale)``) so SGM runs in fast exact integer arithmetic.
        lr_tolerance: max |d_left - d_right| in px for a pixel to stay valid.
        median: side of the median filter applied to the filled map (1 = off); it
            removes isolated outliers that survive the left-right check.
        confidence: compute the confidence (False: ``DisparityResult.confidence`` is
            None; the disparity and validity are the same either way).
    """

    cost: CostFunction
    p1: float
    p2: float
    quantize_scale: float | None = None
    lr_tolerance: float = 1.0
    median: int = 3
    confidence: bool = True

    def __call__(self, left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange, *,
                 preprocess: str = "none") -> DisparityResult:
        left, right = preprocessed(left, right, preprocess)
        cost = self.cost(left, right, disparity_range)
        if self.quantize_scale is not None:
            cost = quantize(cost, scale=self.quantize_scale)
        aggregated = sgm_aggregate(cost, p1=self.p1, p2=self.p2)
        best = best_level(aggregated) if self.confidence else None
        left_disparity = winner_takes_all(aggregated, best=best)
        right_disparity = winner_takes_all(right_view_cost(aggregated))
        valid = left_right_check(left_disparity, right_disparity, tolerance=self.lr_tolerance)
        confidence = None if best is None else peak_ratio_confidence(aggregated, best, valid)
        if self.median > 1:  # the median needs a dense map; its values are kept where valid
            left_disparity = cv2.medianBlur(fill_invalid_along_rows(left_disparity, valid), self.median)
        return DisparityResult(np.where(valid, left_disparity, np.float32(np.nan)), valid, confidence)


# Census costs are bit counts (0..48 for 7x7); ZNCC costs (0..2) are quantized x32.
census_sgm = SgmPipeline(cost=partial(census_cost, window=7), p1=7, p2=72)
zncc_sgm = SgmPipeline(cost=partial(zncc_cost, window=5), quantize_scale=32, p1=3, p2=32)
# DASC costs (1 - descriptor dot product, 0..1) are quantized x64: a wrong match then
# costs about 22 levels (median on a train-real scene), close to Census's 24 of 48, so
# the penalties follow Census's (p1 4..10, p2 40..100 changed the train-real EPE by < 1 %).
# The pattern spans 15x15, not the paper's 31x31 (see DASC_STEREO_PATTERN).
dasc_sgm = SgmPipeline(cost=partial(dasc_cost, pattern=DASC_STEREO_PATTERN), quantize_scale=64, p1=7, p2=72)


@dataclass(frozen=True)
class OpenCvSgbm:
    """OpenCV StereoSGBM (Birchfield-Tomasi cost, 5 or 8 paths), the mono-modal reference.

    Bands are stretched to uint8 over their own min..max. OpenCV needs a disparity count
    divisible by 16, so it searches a slightly wider range; estimates outside the
    requested range and OpenCV's own rejects are marked invalid (NaN). OpenCV gives no
    costs (and its left-right check is already part of the validity): the confidence is
    graded from the map itself (:func:`~cade_cli.matching.confidence.neighbourhood_confidence`);
    ``confidence=False`` leaves it None.
    """

    block_size: int = 5
    uniqueness_ratio: int = 10
    full_dp: bool = True
    confidence: bool = True

    def __call__(self, left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange, *,
                 preprocess: str = "none") -> DisparityResult:
        left, right = preprocessed(left, right, preprocess)
        matcher = sgbm_matcher(disparity_range.minimum, disparity_range.count, block=self.block_size,
                               p1=8, p2=32, uniqueness=self.uniqueness_ratio, prefilter_cap=63,
                               mode=cv2.STEREO_SGBM_MODE_HH if self.full_dp else cv2.STEREO_SGBM_MODE_SGBM)
        raw = matcher.compute(to_uint8(left), to_uint8(right)).astype(np.float32) / 16.0
        valid = (raw >= disparity_range.minimum) & (raw <= disparity_range.maximum)
        confidence = neighbourhood_confidence(raw, valid) if self.confidence else None
        return DisparityResult(np.where(valid, raw, np.float32(np.nan)), valid, confidence)


def sgbm_matcher(minimum: int, count: int, *, block: int, p1: int, p2: int, uniqueness: int, prefilter_cap: int,
                 mode: int) -> cv2.StereoSGBM:
    """OpenCV's StereoSGBM over disparities ``minimum`` .. ``minimum + count - 1`` (widened
    to :func:`opencv_sgbm_levels`), penalties ``p1``/``p2`` per pixel of the ``block`` x
    ``block`` window, ``disp12MaxDiff`` 1, speckle filter (100 px, 2 px). The one builder
    behind the ``sgbm`` matcher and the CADE matcher's refinement."""
    area = block * block
    return cv2.StereoSGBM_create(
        minDisparity=minimum, numDisparities=opencv_sgbm_levels(count), blockSize=block, P1=p1 * area,
        P2=p2 * area, disp12MaxDiff=1, uniquenessRatio=uniqueness, speckleWindowSize=100, speckleRange=2,
        preFilterCap=prefilter_cap, mode=mode)


def opencv_sgbm_levels(count: int) -> int:
    """The disparity count OpenCV's StereoSGBM searches for ``count`` levels: the next
    multiple of 16 (its requirement)."""
    return -(-count // 16) * 16


def to_uint8(band: np.ndarray) -> np.ndarray:
    """Stretch a float band over its own min..max to uint8 (constant bands become 0)."""
    low, high = float(band.min()), float(band.max())
    scale = 255.0 / (high - low) if high > low else 0.0
    return np.clip(np.rint((band - low) * scale), 0, 255).astype(np.uint8)
