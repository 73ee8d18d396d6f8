"""The refinement stage of the CADE matcher: semi-global matching of the raw bands' ranks.

The network works at 1/4 resolution on color-agnostic bands: robust across bands, but
blurred at edges, in fine texture and on thin structures (branches, cables), which it can
miss by tens of pixels. :class:`RankSgbmRefinement` matches the full-resolution bands
again, over the whole range, with OpenCV's SGBM (built by the same
:func:`~cade_cli.matching.classical.sgbm_matcher` as the ``sgbm`` matcher) on their rank
transforms, and lets the result overrule the network where it is trustworthy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.classical import opencv_sgbm_levels, sgbm_matcher
from cade_cli.matching.cost import rank_transform
from cade_cli.matching.network import shift_right_view
from cade_cli.matching.side_by_side import side_by_side

Choice = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""``choose(network, match, accepted, right) -> taken``: which accepted matches replace the
network's value, instead of the ``agreement`` rule (all (H, W); the disparities may be
shifted by the range's minimum, and ``right``, the raw right band SGBM matched, with them)."""

SIGN_BLUR = 31
"""Side of the box blur applied to both bands before their correlation decides whether
one is the other's contrast-inverted version."""
SIGN_STEP = 4
"""That correlation reads every 4th row and column of the blurred bands."""
REGION_SIDE = 127
"""Side (px) of the windows in which :func:`inverted_regions` correlates the bands."""
REGION_CORRELATION = -0.4
"""A window whose correlation lies below this, against the image-wide relation, is inverted."""
REGION_SHARE = 0.15
"""Inverted windows count only when they cover at least this share of the image."""
REGION_EDGE = 63
"""Once regions count, each pixel is judged in windows of this side (px), by its sign."""


def correlation(left: np.ndarray, right: np.ndarray) -> float:
    """Pearson correlation of two images' pixels (0 where either is constant).

    Sums, not ``np.dot``: a BLAS call leaves OpenBLAS's threads busy-waiting for the next
    one, on the cores onnxruntime and OpenCV need next (docs/research/speed.md, 2026-11-22)."""
    left, right = (image.astype(np.float64).ravel() for image in (left, right))
    left, right = left - left.mean(), right - right.mean()
    norm = np.sqrt(np.sum(left * left) * np.sum(right * right))
    return float(np.sum(left * right) / norm) if norm > 0 else 0.0


def _sign_samples(left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 31x31-blurred bands on every ``SIGN_STEP``-th row and column of the left
    view: the left band there, and the right band at the matches ``disparity`` gives."""
    step = np.s_[::SIGN_STEP, ::SIGN_STEP]
    height, width = left.shape
    rows, columns = np.mgrid[0:height:SIGN_STEP, 0:width:SIGN_STEP].astype(np.float32)
    blurred_left, blurred_right = (cv2.blur(band.astype(np.float32), (SIGN_BLUR, SIGN_BLUR))
                                   for band in (left, right))
    matched = cv2.remap(blurred_right, columns - np.rint(disparity[step]), rows,
                        cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    return blurred_left[step], matched


def windowed_correlation(first: np.ndarray, second: np.ndarray, side: int) -> np.ndarray:
    """Pearson correlation of two sample grids (every ``SIGN_STEP``-th pixel) in
    windows of ``side`` image pixels around each sample."""
    window = (side // SIGN_STEP) | 1

    def mean(image: np.ndarray) -> np.ndarray:
        return cv2.blur(image, (window, window), borderType=cv2.BORDER_REFLECT)

    first_mean, second_mean = mean(first), mean(second)
    covariance = mean(first * second) - first_mean * second_mean
    variances = (mean(first * first) - first_mean**2) * (mean(second * second) - second_mean**2)
    return covariance / np.sqrt(np.maximum(variances, np.float32(1e-12)))


def inverted_regions(left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """Left-view pixels where ``right`` is a contrast-inverted version of ``left``.

    First image-wide: a negative correlation of the 31x31-blurred bands along the matches
    ``disparity`` gives (judged on blurred bands, so the sign holds where ``disparity`` is
    many pixels off; every ``SIGN_STEP``-th row and column is enough after that
    blur) flips every pixel. Then by region: the same samples are correlated in windows of
    ``REGION_SIDE`` px; where that correlation opposes the image-wide relation by more
    than ``REGION_CORRELATION`` (e.g. vegetation, bright in NIR and dark in red,
    over part of the view) on at least ``REGION_SHARE`` of the image, the pixels
    whose ``REGION_EDGE``-px windows oppose it at all flip too. On the benchmark
    pairs (Middlebury, FlyingThings3D, KITTI) the strongly opposed windows cover at most
    about 10 %, so there only the image-wide relation counts.

    Returns:
        (H, W) bool.
    """
    height, width = left.shape
    blurred_left, matched = _sign_samples(left, right, disparity)
    inverted = correlation(blurred_left, matched) < 0
    sign = np.float32(-1 if inverted else 1)  # local correlations relative to the image-wide relation
    strongly_opposed = sign * windowed_correlation(blurred_left, matched, REGION_SIDE) < REGION_CORRELATION
    if strongly_opposed.mean() < REGION_SHARE:
        return np.full((height, width), inverted)
    opposed = sign * windowed_correlation(blurred_left, matched, REGION_EDGE) < 0
    samples = (opposed ^ inverted).astype(np.uint8)
    return cv2.resize(samples, (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)


@dataclass(frozen=True)
class RankSgbmRefinement:
    """Correct the network's disparity by semi-global matching of the raw bands:

    1. both bands become rank images (:func:`~cade_cli.matching.cost.rank_transform`,
       ``rank_window`` x ``rank_window``): they depend only on the order of intensities, so
       a gain, offset or gamma change between bands does not alter them, and fine texture
       is kept; where the bands are anti-correlated along the network's matches
       (:func:`inverted_regions`: over the whole image, as for a filter pair that inverts
       contrast, or over large regions of it), the left ranks are flipped (48 - rank). A
       smaller inverted patch is not flipped; there the ranks disagree and step 3 leaves
       most of it to the network;
    2. OpenCV's StereoSGBM (3-way mode, ``block`` x ``block`` blocks) searches the whole
       range on that pair, with sub-pixel output;
    3. its value replaces the network's where SGBM accepted the match and it lies within
       ``agreement`` px of the network's; elsewhere the network's value is kept: SGBM
       rejects a match whose runner-up is within ``uniqueness`` % of the best cost, a
       speckle (a patch under 100 px that differs by more than 2 px from its
       surroundings), and a match outside the right image is refused too. Where the bands
       are unrelated (e.g. the R and G planes of random colour textures) the ranks
       disagree, and these rejections and the agreement bound leave the network in charge.

    Attributes:
        agreement: largest accepted difference (px) between the network and the match.
        rank_window: side of the rank transform's window.
        block, p1, p2: SGBM block side and smoothness penalties per pixel of the block
            (OpenCV's usual 8 and 32, with a stiffer P2).
        uniqueness: SGBM's uniqueness ratio, %.
        network_range: None searches the whole range in step 2; a margin (px) searches only
            the network's own range (:meth:`searched_range`) widened by it on each side.
        half_size: where step 2 rejects a match (no unique minimum: weak texture, such as a
            road in shade), a second SGBM of the ranks of the bands shrunk to half size
            (:meth:`half_size_candidate`) offers its accepted match instead; from there on
            it is treated as SGBM's match.
    """

    agreement: float = 32
    rank_window: int = 7
    block: int = 5
    p1: int = 8
    p2: int = 64
    uniqueness: int = 10
    network_range: int | None = None
    half_size: bool = False

    def __call__(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                 disparity_range: DisparityRange) -> np.ndarray:
        """Refined (H, W) float32 disparity, px, of the raw bands ``left`` / ``right`` (any
        units; only their order matters) from the network's ``disparity`` (px, within
        ``disparity_range``); a non-zero minimum is handled by shifting the right band."""
        return self.refine(left, right, disparity, disparity_range)[0]

    def refine(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
               disparity_range: DisparityRange, *, choose: Choice | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`__call__`'s refined disparity and the (H, W) bool mask of the pixels where
        it is SGBM's match (accepted, and within ``agreement`` px of ``disparity`` or where
        ``choose`` says so); elsewhere it is ``disparity`` itself."""
        searched = self.searched_range(disparity, disparity_range)
        minimum = searched.minimum
        refined, taken = self.refine_span(left, shift_right_view(right, minimum), disparity - minimum, searched.span,
                                          choose=choose)
        refined = refined + minimum if minimum else refined
        if searched != disparity_range:  # where the network lies outside the search, SGBM had no say
            outside = (disparity < searched.minimum) | (disparity > searched.maximum)
            refined, taken = np.where(outside, disparity, refined).astype(np.float32), taken & ~outside
        return refined, taken

    def searched_range(self, disparity: np.ndarray, disparity_range: DisparityRange) -> DisparityRange:
        """The disparities SGBM searches: ``disparity_range``, or with :attr:`network_range` set the
        network's own range (its 0.5 and 99.5 percentiles over every 4th row and column, widened by
        that margin, then by OpenCV's rounding of the count up to a multiple of 16, both sides
        alike) within ``disparity_range``."""
        if self.network_range is None:
            return disparity_range
        low, high = np.percentile(disparity[::4, ::4], (0.5, 99.5))
        low = max(disparity_range.minimum, int(np.floor(low)) - self.network_range)
        high = min(disparity_range.maximum, max(int(np.ceil(high)) + self.network_range, low + 1))
        slack = opencv_sgbm_levels(high - low + 1) - (high - low + 1)  # searched anyway: centred
        low = max(disparity_range.minimum, low - slack // 2)
        high = min(disparity_range.maximum, low + opencv_sgbm_levels(high - low + 1) - 1)
        return DisparityRange(low, high)

    def refine_span(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                    span: int, *, choose: Choice | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The refinement over disparities 0 .. ``span`` px (``disparity`` in that range, or near it),
        and where it took SGBM's match (as :meth:`refine`)."""
        if span < 1:  # a single disparity: nothing to choose between
            return np.asarray(disparity, np.float32), np.zeros(np.shape(disparity), bool)
        matched, accepted = self.candidate(left, right, disparity, span)
        if choose is None:
            accepted &= np.abs(matched - disparity) <= self.agreement
        else:
            accepted &= choose(disparity, matched, accepted, right)
        return np.where(accepted, matched, disparity).astype(np.float32), accepted

    def candidate(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                  span: int) -> tuple[np.ndarray, np.ndarray]:
        """Steps 1-2: SGBM's (H, W) float32 match of the rank images over 0 .. ``span`` px
        (``span`` >= 1), and where SGBM accepted it and it lies inside the right image (the
        agreement with ``disparity`` is not applied here); with :attr:`half_size`, its
        rejected pixels filled where the half-size match was accepted."""
        matched, accepted = self.full_size_candidate(left, right, disparity, span)
        if not self.half_size:
            return matched, accepted
        half, half_accepted = self.half_size_candidate(left, right, disparity, span)
        filled = half_accepted & ~accepted
        return np.where(filled, half, matched).astype(np.float32), accepted | filled

    def half_size_candidate(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                            span: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`full_size_candidate` of the bands and ``disparity`` shrunk to half size (area
        means; disparities halved, ``span`` too, rounded up), enlarged back to (H, W): the match
        bilinearly (the network's value stands in for rejected pixels there, so that none
        enters an accepted pixel's value), rescaled to full-size px; where it was accepted, by
        nearest neighbour, and only where it stays inside the right image. A quarter of the
        pixels and half the disparities: about an eighth of the full-size SGBM's work."""
        height, width = left.shape
        size = ((width + 1) // 2, (height + 1) // 2)
        left_half, right_half, disparity_half = (cv2.resize(np.asarray(image, np.float32), size,
                                                            interpolation=cv2.INTER_AREA)
                                                 for image in (left, right, disparity))
        scale = np.float32(width / size[0])
        disparity_half /= scale
        matched, accepted = self.full_size_candidate(left_half, right_half, disparity_half,
                                                     max(1, int(np.ceil(span / scale))))
        matched = np.where(accepted, matched, disparity_half).astype(np.float32)
        matched = cv2.resize(matched, (width, height), interpolation=cv2.INTER_LINEAR) * scale
        accepted = cv2.resize(accepted.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
        accepted &= matched <= np.arange(width, dtype=np.float32)[None, :]
        return matched, accepted

    def full_size_candidate(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                            span: int) -> tuple[np.ndarray, np.ndarray]:
        """Steps 1-2 on the bands as given: SGBM's match of their rank images over 0 ..
        ``span`` px and where SGBM accepted it inside the right image."""
        width = left.shape[1]
        top = self.rank_window**2 - 1
        left_rank, right_rank = side_by_side(lambda: rank_transform(left, window=self.rank_window),
                                             lambda: rank_transform(right, window=self.rank_window))
        # The left ranks are flipped, where the regions are found. Flipping the right ones
        # instead is not bit-identical in OpenCV's SGBM but no more accurate (contrast inverted
        # everywhere: 5.87 px EPE against 5.86, docs/research/refinement.md, 2026-11-22).
        inverted = inverted_regions(left, right, disparity)
        if inverted.any():
            left_rank = np.where(inverted, np.uint8(top) - left_rank, left_rank)
        # Ranks 0..48 spread over 0..240, so OpenCV's 8-bit cost keeps its resolution.
        scale = np.uint8(240 // top)
        left_rank, right_rank = left_rank * scale, right_rank * scale
        # disp12MaxDiff asks for OpenCV's left-right check, but it changed no score and no
        # rejection count when tried off and at 0..2 px (docs/research/refinement.md, 2026-11-22): no
        # left-right check is claimed for this step.
        matcher = sgbm_matcher(0, span + 1, block=self.block, p1=self.p1, p2=self.p2, uniqueness=self.uniqueness,
                               prefilter_cap=15, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
        levels = matcher.getNumDisparities()
        # OpenCV leaves the first ``levels`` columns unmatched: pad, so that happens outside the image.
        left_rank, right_rank = (cv2.copyMakeBorder(image, 0, 0, levels, 0, cv2.BORDER_REPLICATE)
                                 for image in (left_rank, right_rank))
        matched = matcher.compute(left_rank, right_rank)[:, levels:].astype(np.float32) / np.float32(16)
        accepted = (matched >= 0) & (matched <= np.arange(width, dtype=np.float32)[None, :])  # rejects are -1
        return matched, accepted
