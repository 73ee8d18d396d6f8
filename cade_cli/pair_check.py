"""A cheap test of a pair before it is matched: rectified, in order, and inside the range searched?

Every matcher assumes a rectified pair, LEFT the reference, and a search range that holds
the scene's disparities. When one of these fails, the matchers still return a map that
looks plausible (a pair shifted 6 px vertically keeps most pixels "valid") but is wrong.
:func:`check_pair` tests the three assumptions on sparse feature matches, before matching:

1. both bands are downscaled by :func:`check_factor` (area averaging, width kept at least
   :data:`CHECK_WIDTH` px), turned into colour-agnostic gradient images
   (:func:`gradient_band`: bands from different filters match, contrast inversions
   included), and described by upright ORB features (:func:`describe_band`: FAST corners
   ranked by Harris response, :func:`feature_count` of them, one per
   :data:`AREA_PER_FEATURE` px of the pair, so that the work follows the image area as the
   matchers' does; the binary pattern is not steered by each corner's orientation, which
   between spectral bands is unstable); features within :func:`max_horizontal` columns and
   :data:`MAX_VERTICAL_SHARE` rows of each other compete (:func:`match_features`), and the
   row of each match is refined to a fraction of a pixel (:func:`subpixel_row_shift`, on
   the same gradient images);
2. the row difference of the matches is fitted as a vertical offset plus a rotation about
   the image centre: the line (offset, rotation) that most matches lie on is found by a
   vote over rotations of up to :data:`MAX_ROTATION_DEG` (:func:`dominant_line`: cross-band
   matches hold many wrong ones, spread over every row difference), then refined on the
   matches near it by the rig self-check's robust fit
   (:func:`cade_cli.rigs.self_check.fit_vertical_misalignment`); the matches it keeps are
   the pair's trusted matches;
3. their horizontal offsets ``x_left - x_right`` are disparities (px): mostly negative
   with a non-negative range means LEFT and RIGHT are swapped; mostly outside the range
   searched means the range misses the scene, and a range that holds them is suggested.

The check only reads the pair: it never changes a disparity, and its result does not depend
on the thread count (with two OpenCV threads or more the two bands are described side by
side). Its cost follows the image area: about 5 ms for a small pair such as ArtL, 347 x 277,
about 8-9 ms for a Q-size Middlebury pair, 4-6 % of the fastest matcher's (sgbm) time on
those but about 20 % on ArtL (``benchmarks/pair_check.py``, docs/pair-check.md, which also
counts its false alarms on every rectified Middlebury, KITTI and FlyingThings3D pair of the
data folder). A pair with too little texture shared by the bands gives too few matches to
judge: the check is then inconclusive and finds no problem.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.base import range_margin
from cade_cli.pair_features import band_features, dominant_line, feature_count, match_features, max_horizontal, subpixel_row_shift
from cade_cli.rigs.self_check import fit_vertical_misalignment

CHECK_WIDTH = 320
"""The pair is downscaled by powers of two while it stays at least this wide (px)."""
MAX_VERTICAL_SHARE = 0.05
"""Matches whose rows differ by more than this share of the width (at least
:data:`MIN_MAX_VERTICAL_PX`) are not considered: room for a 2 degree rotation plus an offset."""
MIN_MAX_VERTICAL_PX = 16.0
MIN_MATCHES = 20
"""Fewer trusted matches than this: the check is inconclusive (repetitive texture can put a
handful of wrong matches on one wrong row)."""
MIN_ROLL_MATCHES = 20
"""The rotation is fitted from at least this many matches (below: the offset only)."""
LINE_BAND_PX = 1.0
"""Matches within this many px of the line voted for are refined; the fit keeps those within
3 robust standard deviations of its line, at least half of this."""
VERTICAL_TOLERANCE_PX = 1.5
"""A vertical misalignment reaching this many px somewhere across the width is reported.
Matchers search along rows: beyond about a pixel their error grows quickly."""
ROTATION_PRECISION_DEG = 0.4
"""The check's rotations are this precise (spurious rotations of up to 0.32 degrees on the
rectified benchmark pairs, docs/pair-check.md): the misalignment judged is that of the
rotation shrunk towards 0 by this much."""
SWAPPED_SHARE = 0.5
"""More than this share of the trusted matches with a negative disparity, while the range
searched is non-negative: LEFT and RIGHT are swapped."""
RANGE_MISS_SHARE = 0.5
"""More than this share of the trusted matches outside the range searched: the range misses the scene."""
DISPARITY_TOLERANCE_PX = 2.0
"""Slack (px of the check's scale) on the range bounds: the matches' positions are that coarse."""
RANGE_PERCENTILES = (2.0, 98.0)
"""Percentiles (%) of the trusted matches' disparities taken as the scene's range before the margin."""
PROBLEMS = ("swapped", "vertical", "range")
"""What :attr:`PairCheck.problems` may name, in the order they are reported."""


@dataclass(frozen=True)
class PairCheck:
    """What :func:`check_pair` found.

    Attributes:
        matches: trusted matches (consistent with the vertical fit); fewer than the fit
            needs: the check is inconclusive (:attr:`conclusive`) and finds no problem.
        vertical_offset: right-image row minus left-image row of one scene point at the
            image centre, px (> 0: RIGHT shows things lower); None when inconclusive.
        rotation: rotation of RIGHT against LEFT about the image centre, degrees; None
            when inconclusive.
        vertical_worst: the largest |row difference| across the width, px: the offset
            plus, at the far edge, the rotation less :data:`ROTATION_PRECISION_DEG`; None
            when inconclusive.
        disparity: (low, high) robust percentiles (:data:`RANGE_PERCENTILES`) of the
            trusted matches' disparities ``x_left - x_right``, px; None when inconclusive.
        negative_share: share of the trusted matches with a disparity below
            ``-tolerance``, in [0, 1].
        outside_share: share of the trusted matches outside ``searched`` widened by the
            tolerance, in [0, 1].
        searched: the inclusive range checked against, px.
        suggested: a range holding the trusted matches, px (their percentiles widened by
            :func:`cade_cli.matching.base.range_margin`); None when inconclusive.
        factor: the downscale the pair was matched at (1, 2, 4, ...).
        problems: what is wrong, a subset of :data:`PROBLEMS` in that order; empty: nothing found.
    """

    matches: int
    vertical_offset: float | None
    rotation: float | None
    vertical_worst: float | None
    disparity: tuple[float, float] | None
    negative_share: float
    outside_share: float
    searched: tuple[int, int]
    suggested: tuple[int, int] | None
    factor: int
    problems: tuple[str, ...]

    @property
    def conclusive(self) -> bool:
        """Whether there were enough matches to judge the pair."""
        return self.vertical_offset is not None

    def describe(self, *, swap_fix: str = "give the reference (left) image first") -> str:
        """One line for the user: what is wrong, the numbers measured, and the fix; "" when nothing is.
        ``swap_fix``: how the command that reports it undoes a swapped pair."""
        findings = []
        if "swapped" in self.problems:
            findings.append(f"{100 * self.negative_share:.0f}% of the {self.matches} feature matches have a negative "
                            f"disparity ({self.disparity[0]:+.1f}..{self.disparity[1]:+.1f} px): LEFT and RIGHT look "
                            f"swapped; {swap_fix}")
        if "vertical" in self.problems:
            findings.append(f"the pair is not rectified: vertical offset {self.vertical_offset:+.2f} px, rotation "
                            f"{self.rotation:+.2f} deg (up to {self.vertical_worst:.1f} px across the width, "
                            f"{VERTICAL_TOLERANCE_PX} px tolerated); rectify it (--fix-vertical, or cade rectify "
                            "--uncalibrated, or with a calibrated rig --rig RIG.json)")
        if "range" in self.problems:
            low, high = self.suggested
            findings.append(f"{100 * self.outside_share:.0f}% of the {self.matches} feature matches lie outside the "
                            f"searched range [{self.searched[0]}, {self.searched[1]}] px (they span "
                            f"{self.disparity[0]:.1f}..{self.disparity[1]:.1f} px); search --min-disp {low} "
                            f"--max-disp {high}, or --max-disp auto")
        return "pair check: " + "; ".join(findings) if findings else ""

    def summary(self) -> str:
        """A few words for a summary line: the vertical offset measured."""
        if not self.conclusive:
            return f"vertical offset unmeasured ({self.matches} feature matches)"
        return f"vertical offset {self.vertical_offset:+.2f} px"

    def record(self) -> dict:
        """JSON-ready fields for a record (px and degrees, shares in [0, 1])."""
        return {"vertical_offset_px": self.vertical_offset, "rotation_deg": self.rotation,
                "vertical_worst_px": self.vertical_worst, "matches": self.matches,
                "disparity_px": None if self.disparity is None else list(self.disparity),
                "negative_share": self.negative_share, "outside_share": self.outside_share,
                "problems": list(self.problems)}


def check_factor(width: int, *, check_width: int = CHECK_WIDTH) -> int:
    """The largest power of two that keeps ``width`` (px) divided by it at least ``check_width``."""
    factor = 1
    while width / (2 * factor) >= check_width:
        factor *= 2
    return factor


def check_pair(left: np.ndarray, right: np.ndarray, *, min_disp: int = 0, max_disp: int) -> PairCheck:
    """Test a pair before matching it: vertical alignment, order, and the range searched.

    Args:
        left, right: (H, W) float bands of the pair as they will be matched, any range;
            they may come from different spectral filters.
        min_disp, max_disp: the inclusive range that will be searched, px.

    Returns:
        :class:`PairCheck`. Its ``problems`` name what was found; an inconclusive check
        (too few matches) finds nothing.

    Raises:
        CadeError: bands of different shapes, or not (H, W).
    """
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    if left.ndim != 2 or left.shape != right.shape:
        raise CadeError(f"the pair check needs two (H, W) bands of one size, got {left.shape} and {right.shape}")
    height, width = left.shape
    factor = check_factor(width)
    if factor > 1:
        size = (max(8, round(width / factor)), max(8, round(height / factor)))
        left, right = (cv2.resize(band, size, interpolation=cv2.INTER_AREA) for band in (left, right))
    scale_x, scale_y = width / left.shape[1], height / left.shape[0]
    max_vertical = max(MAX_VERTICAL_SHARE * width, MIN_MAX_VERTICAL_PX)
    features = feature_count(width, height)
    (points_left, desc_left), (points_right, desc_right), (gradient_left, gradient_right) = band_features(
        left, right, features=features)
    points_left, points_right = match_features(points_left, desc_left, points_right, desc_right,
                                               max_vertical=max_vertical / scale_y,
                                               max_horizontal=max_horizontal(width, min_disp, max_disp) / scale_x)
    row_shift = subpixel_row_shift(gradient_left, gradient_right, points_left, points_right)
    points_left, points_right = points_left * (scale_x, scale_y), points_right * (scale_x, scale_y)
    dy = points_right[:, 1] + row_shift * scale_y - points_left[:, 1]
    disparities = points_left[:, 0] - points_right[:, 0]
    searched = (int(min_disp), int(max_disp))
    near = dominant_line(points_left[:, 0], dy, width=width, band=LINE_BAND_PX)
    try:
        found, inliers = fit_vertical_misalignment(points_left[near, 0], dy[near], size=(width, height),
                                                   min_band=LINE_BAND_PX / 2, min_roll_matches=MIN_ROLL_MATCHES)
        if found.matches < MIN_MATCHES:
            raise CadeError("too few matches")
    except CadeError:  # too few matches: nothing to judge
        return PairCheck(int(near.sum()), None, None, None, None, 0.0, 0.0, searched, None, factor, ())
    trusted = disparities[near][inliers]
    tolerance = DISPARITY_TOLERANCE_PX * scale_x
    negative_share = float(np.mean(trusted < -tolerance))
    outside_share = float(np.mean((trusted < min_disp - tolerance) | (trusted > max_disp + tolerance)))
    low, high = (float(v) for v in np.percentile(trusted, RANGE_PERCENTILES))
    margin = range_margin(low, high, factor)
    suggested = (max(0, math.floor(low - margin)) if low >= 0 else math.floor(low - margin),
                 max(1, math.ceil(high + margin)))
    rotation = math.degrees(found.roll)
    beyond_precision = math.copysign(max(abs(rotation) - ROTATION_PRECISION_DEG, 0.0), rotation)
    worst = max(abs(found.offset + math.tan(math.radians(beyond_precision)) * dx) for dx in (-width / 2, width / 2))
    swapped = min_disp >= 0 and negative_share > SWAPPED_SHARE
    problems = tuple(name for name, found_it in (("swapped", swapped), ("vertical", worst >= VERTICAL_TOLERANCE_PX),
                                                 ("range", not swapped and outside_share > RANGE_MISS_SHARE))
                     if found_it)
    return PairCheck(matches=found.matches, vertical_offset=found.offset, rotation=rotation,
                     vertical_worst=worst, disparity=(low, high), negative_share=negative_share,
                     outside_share=outside_share, searched=searched, suggested=suggested, factor=factor,
                     problems=problems)


