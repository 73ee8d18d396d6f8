"""Rectification of one pair without a calibration: the warp estimated from cross-spectral feature matches.

Most users of two cameras have the pair and no calibration. :func:`estimate_pair_rectification`
finds the warp that puts a pair's scene points on the same rows from the pair alone:

1. SIFT features on each band's gradient image, matched mutually with the ratio test
   (:func:`cade_cli.matching.sparse.sparse_matches`: bands from different filters match);
   matches whose rows differ by more than :data:`MAX_VERTICAL_SHARE` of the width (at least
   :data:`MIN_MAX_VERTICAL_PX`) are not considered;
2. the **vertical model first**: a vertical offset plus a rotation of RIGHT about the image
   centre, the line most matches lie on found by a vote over rotations
   (:func:`cade_cli.pair_features.dominant_line`, a RANSAC-like consensus that cross-band
   outliers cannot steer), then refined robustly on the matches near it
   (:func:`cade_cli.rigs.self_check.fit_vertical_misalignment`, the rig self-check's fit).
   LEFT stays as it is; RIGHT is rotated and shifted;
3. a **full uncalibrated rectification** (a fundamental matrix by RANSAC,
   ``cv2.findFundamentalMat``, then ``cv2.stereoRectifyUncalibrated``: one homography per
   band) only where the matches support it and the vertical model does not explain them:
   at least :data:`MIN_PROJECTIVE_INLIERS` RANSAC inliers covering at least
   :data:`MIN_GRID_CELLS` of the 3 x 3 cells of LEFT, homographies that move no image corner
   by more than :data:`MAX_CORNER_SHIFT` of the diagonal, the vertical model's residual above
   :data:`VERTICAL_MODEL_GOOD_PX` and the projective one smaller by :data:`PROJECTIVE_GAIN_PX`.

The pair is refused (:class:`CadeError`, one line) when fewer than :data:`MIN_MATCHES` matches
agree, when the chosen model leaves a median residual above :data:`MAX_RESIDUAL_PX`, or when
the vertical model leaves 90 % of the matches within no less than :data:`MAX_SPREAD_PX` and
the matches support no full rectification.
Disparities found on the rectified pair are in rectified px; :meth:`PairRectification.original_maps`
resamples results back onto the original LEFT image (``--frame original``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.sparse import sparse_matches
from cade_cli.pair_features import dominant_line
from cade_cli.rigs.outputs import to_original_image
from cade_cli.rigs.self_check import MIN_CORRECTION_PX, fit_vertical_misalignment

MODELS = ("vertical", "projective")
"""The warps :func:`estimate_pair_rectification` chooses between."""
MAX_VERTICAL_SHARE = 0.05
"""Matches whose rows differ by more than this share of the width are not considered."""
MIN_MAX_VERTICAL_PX = 16.0
MIN_MATCHES = 20
"""The fewest matches a warp is estimated from."""
MAX_RESIDUAL_PX = 1.0
"""A warp that leaves its inliers' rows further apart than this (median, px) is refused."""
MAX_SPREAD_PX = 2.0
"""A vertical model that leaves the matches' rows further apart than this (90th percentile, px),
with no full rectification to take its place, is refused."""
VERTICAL_MODEL_GOOD_PX = 0.5
"""The vertical model is kept when it leaves the matches' rows at most this far apart (90th percentile, px)."""
PROJECTIVE_GAIN_PX = 0.1
"""The full rectification is chosen only when its 90th percentile is smaller than the vertical model's by this (px)."""
MIN_PROJECTIVE_INLIERS = 60
"""The fewest RANSAC inliers a fundamental matrix is trusted from."""
MIN_GRID_CELLS = 6
"""The fewest of LEFT's 3 x 3 cells the RANSAC inliers must reach (spread over the image)."""
MAX_CORNER_SHIFT = 0.1
"""The full rectification's homographies may move an image corner by at most this share of the diagonal."""


@dataclass(frozen=True)
class PairRectification:
    """The warp that rectifies one pair, and what it rests on.

    Attributes:
        model: ``vertical`` or ``projective`` (:data:`MODELS`).
        left_warp, right_warp: 3 x 3 homographies from each original image's pixels to the
            rectified frame (identity for LEFT under the vertical model).
        size: (width, height) of the pair, px.
        matches: feature matches considered; inliers: those the chosen model rests on.
        residual: median |row difference| of the inliers after the warp, px.
        offset, rotation: the vertical model's fit, whichever model is chosen: RIGHT's rows
            minus LEFT's at RIGHT's centre column (px; > 0: RIGHT shows things lower) and
            RIGHT's rotation against LEFT about its centre (degrees).
        reason: why this model was chosen, for the user.
    """

    model: str
    left_warp: np.ndarray
    right_warp: np.ndarray
    size: tuple[int, int]
    matches: int
    inliers: int
    residual: float
    offset: float
    rotation: float
    reason: str

    def warps(self) -> bool:
        """Whether the rectification changes either image (False: both warps are the identity)."""
        return not (np.allclose(self.left_warp, np.eye(3)) and np.allclose(self.right_warp, np.eye(3)))

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pair warped into the rectified frame (bicubic, borders replicated; (H, W) or (H, W, C))."""
        return _warp(left, self.left_warp, self.size), _warp(right, self.right_warp, self.size)

    def original_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """For each pixel of the ORIGINAL left image, its (x, y) in the rectified frame: the maps
        :func:`cade_cli.rigs.outputs.to_original_image` resamples rectified results with."""
        width, height = self.size
        y, x = np.mgrid[0:height, 0:width].astype(np.float32)
        points = cv2.perspectiveTransform(np.stack([x.ravel(), y.ravel()], axis=1).reshape(-1, 1, 2), self.left_warp)
        points = points.reshape(height, width, 2)
        return np.ascontiguousarray(points[..., 0]), np.ascontiguousarray(points[..., 1])

    def to_original(self, *images: np.ndarray | None) -> list[np.ndarray | None]:
        """Rectified-frame float images resampled onto the original LEFT image (bilinear; NaN
        outside the rectified view or next to NaN); None stays None; unchanged under an identity left warp."""
        if np.allclose(self.left_warp, np.eye(3)):
            return list(images)
        maps = self.original_maps()
        return [None if image is None else to_original_image(image, maps) for image in images]

    def record(self) -> dict:
        """JSON-ready: the model, both warps, the residual (px) and what the fit found."""
        return {"model": self.model, "left_warp": np.asarray(self.left_warp).tolist(),
                "right_warp": np.asarray(self.right_warp).tolist(), "size": list(self.size),
                "residual_vertical_px": self.residual, "inliers": self.inliers, "matches": self.matches,
                "vertical_offset_px": self.offset, "rotation_deg": self.rotation, "reason": self.reason}

    def describe(self) -> str:
        """One line: the model, the correction and the residual."""
        what = "full uncalibrated rectification (one homography per band)"
        if self.model == "vertical":
            done = "corrected" if self.warps() else "left as they are (too small to resample for)"
            what = f"vertical offset {self.offset:+.2f} px, rotation {self.rotation:+.2f} deg {done}"
        return (f"uncalibrated rectification: {what}; residual {self.residual:.2f} px (median over {self.inliers} "
                f"of {self.matches} feature matches)")


def match_in_original_frame(found: PairRectification, disparity: np.ndarray, valid: np.ndarray, dense: np.ndarray,
                            confidence: np.ndarray | None):
    """A match of the rectified pair on the original LEFT image (``--frame original``): (the
    unfilled map, NaN where rejected or outside the rectified view; its validity; the dense map;
    the confidence, 0 where invalid). Disparities stay in rectified px."""
    unfilled = np.where(valid, disparity, np.nan).astype(np.float32)
    unfilled, dense, confidence = found.to_original(unfilled, dense, confidence)
    valid = np.isfinite(unfilled)
    if confidence is not None:
        confidence = np.where(valid, np.nan_to_num(confidence, nan=0.0), 0.0).astype(np.float32)
    return unfilled, valid, dense, confidence


def _warp(image: np.ndarray, warp: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if np.allclose(warp, np.eye(3)):
        return image
    return cv2.warpPerspective(np.asarray(image, np.float32), np.asarray(warp, np.float64), size,
                               flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)


def vertical_warp(offset: float, roll: float, centre: tuple[float, float]) -> np.ndarray:
    """The homography taking RIGHT's pixels to the rectified frame under the vertical model: the
    inverse of the map :func:`cade_cli.rigs.self_check.correct_vertical_misalignment` samples with
    (rotation by ``roll``, radians, about ``centre``, then ``offset`` px down)."""
    cx, cy = centre
    c, s = math.cos(roll), math.sin(roll)
    forward = np.float64([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy + offset], [0, 0, 1]])
    return np.linalg.inv(forward)


def estimate_pair_rectification(left: np.ndarray, right: np.ndarray, *, features: int = 4000) -> PairRectification:
    """Estimate the warp that rectifies ``left``/``right`` (module docstring: the models and the criteria).

    Args:
        left, right: (H, W) float bands of one size, any range, possibly different spectral bands.
        features: the most SIFT features detected per band.

    Raises:
        CadeError: bands of different sizes, too few agreeing matches, or no warp that
            brings the matches within :data:`MAX_RESIDUAL_PX`.
    """
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    if left.ndim != 2 or left.shape != right.shape:
        raise CadeError(f"uncalibrated rectification needs two (H, W) bands of one size, got {left.shape} and "
                        f"{right.shape}")
    height, width = left.shape
    points_left, points_right = sparse_matches(left, right, detector="sift", features=features)
    dy = points_right[:, 1] - points_left[:, 1] if len(points_left) else np.zeros(0)
    keep = np.abs(dy) <= max(MAX_VERTICAL_SHARE * width, MIN_MAX_VERTICAL_PX)
    points_left, points_right, dy = points_left[keep], points_right[keep], dy[keep]
    # The rotation turns RIGHT about its centre: against RIGHT's columns, the row difference is
    # exactly offset + tan(roll) (x - cx) whatever the disparity (against LEFT's it is not).
    near = dominant_line(points_right[:, 0], dy, width=width, band=1.0)
    if near.sum() < MIN_MATCHES:
        raise _unsupported(f"only {int(near.sum())} feature matches agree on one row offset ({MIN_MATCHES} needed): "
                           "too little texture the bands share")
    try:
        fit, inliers = fit_vertical_misalignment(points_right[near, 0], dy[near], size=(width, height))
    except CadeError:  # too few inliers left by the robust fit
        raise _unsupported(f"the {int(near.sum())} matches near one row offset do not agree on a line") from None
    right_warp = vertical_warp(fit.offset, fit.roll, fit.centre)
    vertical = PairRectification(
        model="vertical", left_warp=np.eye(3), right_warp=right_warp, size=(width, height), matches=len(dy),
        inliers=fit.matches, residual=_row_residual(points_left[near][inliers], points_right[near][inliers],
                                                    np.eye(3), right_warp),
        offset=fit.offset, rotation=math.degrees(fit.roll), reason="")
    fundamental, agree = _fundamental(points_left, points_right)
    # The vertical model is judged on the matches the epipolar geometry agrees on (its own inliers
    # would flatter it), by their 90th percentile (a warp wrong at the edges shows there).
    judged = agree if agree is not None else np.flatnonzero(near)[inliers]
    spread = _row_residual(points_left[judged], points_right[judged], np.eye(3), right_warp, percentile=90)
    projective = None
    if spread > VERTICAL_MODEL_GOOD_PX and agree is not None:
        projective = _projective(points_left[agree], points_right[agree], fundamental, vertical)
    if projective is not None and _row_residual(points_left[agree], points_right[agree], projective.left_warp,
                                                projective.right_warp, percentile=90) <= spread - PROJECTIVE_GAIN_PX:
        chosen = _replace_reason(projective, f"the vertical offset and rotation leave {spread:.2f} px (90th "
                                 f"percentile); {projective.reason}")
    elif spread <= VERTICAL_MODEL_GOOD_PX:
        chosen = _replace_reason(vertical, f"the vertical offset and rotation leave {spread:.2f} px (90th percentile, "
                                 f"<= {VERTICAL_MODEL_GOOD_PX} px)")
    elif spread <= MAX_SPREAD_PX:
        chosen = _replace_reason(vertical, f"the vertical offset and rotation leave {spread:.2f} px (90th percentile) "
                                 "and the matches support no better full rectification")
    else:
        raise _unsupported(f"a vertical offset and rotation leave {spread:.1f} px between the rows of 90% of the "
                           f"matches (over {MAX_SPREAD_PX} px), and they support no full rectification (too few, or "
                           "clustered, or a far-reaching warp)")
    if chosen.model == "vertical" and fit.worst(width) < MIN_CORRECTION_PX:  # as the rig's --fix-vertical
        kept = np.flatnonzero(near)[inliers]
        chosen = replace(chosen, right_warp=np.eye(3), reason=f"{chosen.reason}; under {MIN_CORRECTION_PX} px across "
                         "the width, left as it is (resampling would soften the band more)",
                         residual=_row_residual(points_left[kept], points_right[kept], np.eye(3), np.eye(3)))
    if chosen.residual > MAX_RESIDUAL_PX:
        raise _unsupported(f"no warp brings the matches within {MAX_RESIDUAL_PX} px (best: {chosen.model} model, "
                           f"{chosen.residual:.2f} px)")
    return chosen


def _replace_reason(found: PairRectification, reason: str) -> PairRectification:
    return replace(found, reason=reason)


def _row_residual(points_left: np.ndarray, points_right: np.ndarray, left_warp: np.ndarray,
                  right_warp: np.ndarray, *, percentile: float = 50.0) -> float:
    """A percentile (default: the median) of the |row difference| (px) of matches once both are warped."""
    if not len(points_left):
        return math.inf
    warped_left = cv2.perspectiveTransform(points_left.reshape(-1, 1, 2), left_warp).reshape(-1, 2)
    warped_right = cv2.perspectiveTransform(points_right.reshape(-1, 1, 2), right_warp).reshape(-1, 2)
    return float(np.percentile(np.abs(warped_right[:, 1] - warped_left[:, 1]), percentile))


def _fundamental(points_left: np.ndarray, points_right: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A fundamental matrix by RANSAC (1 px) and the indices of its inliers; (None, None) with
    fewer than :data:`MIN_PROJECTIVE_INLIERS` matches, inliers, or no fit."""
    if len(points_left) < MIN_PROJECTIVE_INLIERS:
        return None, None
    fundamental, mask = cv2.findFundamentalMat(points_left, points_right, cv2.FM_RANSAC, 1.0, 0.999)
    if fundamental is None or fundamental.shape != (3, 3) or mask is None or mask.sum() < MIN_PROJECTIVE_INLIERS:
        return None, None
    return fundamental, np.flatnonzero(mask.ravel())


def _projective(points_left: np.ndarray, points_right: np.ndarray, fundamental: np.ndarray,
                vertical: PairRectification) -> PairRectification | None:
    """The full uncalibrated rectification from the fundamental matrix's inlier matches, or None
    where they do not support it (clustered in a few image cells, no rectification, a warp that
    moves a corner far)."""
    width, height = vertical.size
    cells = {(min(int(3 * x / width), 2), min(int(3 * y / height), 2)) for x, y in points_left}
    if len(cells) < MIN_GRID_CELLS:
        return None
    ok, left_warp, right_warp = cv2.stereoRectifyUncalibrated(points_left, points_right, fundamental, (width, height))
    if not ok:
        return None
    common = _closest_to_identity(left_warp, width, height)
    left_warp, right_warp = common @ left_warp, common @ right_warp
    right_warp = _keeping_disparities(points_left, points_right, left_warp, right_warp)
    corners = np.float64([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]]).reshape(-1, 1, 2)
    limit = MAX_CORNER_SHIFT * math.hypot(width, height)
    for warp in (left_warp, right_warp):
        moved = cv2.perspectiveTransform(corners, warp) - corners
        if not np.all(np.isfinite(moved)) or np.abs(moved).max() > limit:
            return None
    return PairRectification(
        model="projective", left_warp=left_warp, right_warp=right_warp, size=vertical.size, matches=vertical.matches,
        inliers=len(points_left), residual=_row_residual(points_left, points_right, left_warp, right_warp),
        offset=vertical.offset, rotation=vertical.rotation,
        reason=f"{len(points_left)} RANSAC inliers over {len(cells)} of 9 image cells support a full rectification")


def _closest_to_identity(left_warp: np.ndarray, width: int, height: int) -> np.ndarray:
    """The transform of both rectified images, ``x' = p x + q y + r``, ``y' = s y + t`` (rows stay
    rows, so the pair stays rectified), that brings ``left_warp``'s image of LEFT closest to LEFT
    itself (least squares on a 9 x 9 grid): ``cv2.stereoRectifyUncalibrated`` is free to scale,
    shear and move the rectified frame, which the user need not see."""
    y, x = np.mgrid[0:height:9j, 0:width:9j]
    grid = np.stack([x.ravel(), y.ravel()], axis=1)
    warped = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), left_warp).reshape(-1, 2)
    ones = np.ones(len(grid))
    (p, q, r), *_ = np.linalg.lstsq(np.stack([warped[:, 0], warped[:, 1], ones], axis=1), grid[:, 0], rcond=None)
    (s, t), *_ = np.linalg.lstsq(np.stack([warped[:, 1], ones], axis=1), grid[:, 1], rcond=None)
    return np.float64([[p, q, r], [0, s, t], [0, 0, 1]])


def _keeping_disparities(points_left: np.ndarray, points_right: np.ndarray, left_warp: np.ndarray,
                         right_warp: np.ndarray) -> np.ndarray:
    """``right_warp`` shifted along the rows so that the matches' median disparity ``x_left - x_right``
    is what it was before the warps (the range the user searches keeps its meaning)."""
    warped_left = cv2.perspectiveTransform(points_left.reshape(-1, 1, 2), left_warp).reshape(-1, 2)
    warped_right = cv2.perspectiveTransform(points_right.reshape(-1, 1, 2), right_warp).reshape(-1, 2)
    shift = float(np.median((points_left[:, 0] - points_right[:, 0]) - (warped_left[:, 0] - warped_right[:, 0])))
    return np.float64([[1, 0, -shift], [0, 1, 0], [0, 0, 1]]) @ right_warp


def _unsupported(why: str) -> CadeError:
    return CadeError(f"cannot rectify the pair without a calibration: {why}; calibrate the cameras (cade calibrate) "
                     "or give a pair with more shared texture")
