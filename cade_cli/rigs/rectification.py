"""Rectify a rig's pair, check what rectification left, and turn disparity into depth.

- :func:`stereo_rectification`: OpenCV's ``stereoRectify`` for the reference camera and
  one other, from the rig's calibration (cameras of different resolutions included).
- :func:`rectify_pair`: both images resampled into the rectified frame, where a scene
  point lies on the same row of both and ``I_left(y, x) ~ I_right(y, x - d)``, d >= 0.
- :func:`measure_vertical_misalignment` / :func:`correct_vertical_misalignment` /
  :func:`align_vertically`: the self-check. Sparse features on gradient magnitude (the
  same for a band and its inverse, and similar across bands) are matched, and a vertical
  offset plus a roll about the image centre are fitted to their row differences by a
  robust least squares; the right image can then be resampled to cancel them.
- :func:`rig_disparity`: all of the above, then the range and the matcher (whole or as
  tiles within a memory budget), on a rig's pair.
- :func:`in_frame`, :func:`rectified_points`, :func:`write_ply`: results on the rectified
  or the original reference image, metric depth and a point cloud.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching import DisparityRange, DisparityResult, densify
from cade_cli.rigs.rig import Camera, Rectification, Rig
from cade_cli.scale.range import RangeEstimate, resolve_range
from cade_cli.stereo import DEFAULT_METHOD, DEFAULT_PREPROCESS
from cade_cli.scale.tiling import TilePlan, default_memory_limit, estimate_disparity_tiled

VERTICAL_TOLERANCE_PX = 0.5
"""Residual vertical misalignment above which the self-check warns."""

MIN_SELF_CHECK_MATCHES = 12
"""The fewest feature matches the self-check fits a vertical offset to."""

MIN_ROLL_MATCHES = 40
"""The fewest feature matches the self-check also fits a roll to; with fewer, the roll
is taken as 0 (a roll fitted to a few matches can be off by tenths of a degree)."""

MIN_CORRECTION_PX = 0.25
"""The smallest misalignment (px, anywhere across the width) :func:`align_vertically` corrects."""


def stereo_rectification(rig: Rig, other: str | None = None) -> Rectification:
    """Rectification of the rig's reference camera (left) with camera ``other`` (right).

    Uses ``cv2.stereoRectify`` with zero disparity at infinity and ``alpha = 0`` (the
    rectified images show valid pixels only), at the reference camera's image size. A
    camera of another resolution is handled by giving OpenCV its intrinsics rescaled to
    that size; :func:`rectify_maps` samples it at its own resolution.

    Args:
        other: a camera name; default the first camera after the reference.

    Raises:
        CadeError: a camera without K, R and t; a vertical rig (cameras one above the
            other); cameras whose rectified views do not overlap.
    """
    reference = rig.reference_camera
    if other is None:
        other = next((c.name for c in rig.cameras if c.name != rig.reference), None)
        if other is None:
            raise CadeError("the rig has a single camera; rectification needs two")
    second = rig.camera(other)
    if other == rig.reference:
        raise CadeError(f"cannot rectify camera {other} with itself; name another camera of the rig")
    for camera in (reference, second):
        if not camera.calibrated:
            raise CadeError(f"camera {camera.name} has no K, R and t in the rig file, so it cannot be rectified; "
                            "calibrate it with `cade calibrate` (plane-registered cameras are matched unrectified)")
    size = reference.image_size
    K1, K2 = reference.K, _scaled_intrinsics(second, size)
    # The pose of the other camera relative to the reference, in the reference's own pose frame.
    R, t = _relative_pose(reference, second)
    if float(np.linalg.norm(t)) == 0.0:
        raise CadeError(f"cameras {reference.name} and {other} are at the same place (t = 0): there is no baseline")
    R1, R2, P1, P2, Q, roi1, roi2 = cv2.stereoRectify(
        K1, reference.distortion, K2, second.distortion, size, R, t.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    if P2[1, 3] != 0:
        raise CadeError(f"cameras {reference.name} and {other} are one above the other (the baseline is mostly "
                        "vertical); cade matches along rows: rotate both images by 90 degrees and calibrate again")
    if min(roi1[2], roi1[3], roi2[2], roi2[3]) <= 0 or not np.all(np.isfinite(Q)):
        raise CadeError(f"cameras {reference.name} and {other} do not overlap once rectified; check the rig file's "
                        "R and t (do they face the same way?)")
    return Rectification(cameras=(reference.name, other), image_size=size, R1=R1, R2=R2, P1=P1, P2=P2, Q=Q)


def _relative_pose(reference: Camera, second: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with X_second = R X_reference + t, from the poses both hold relative to the rig's reference."""
    R = second.R @ reference.R.T
    return R, second.t - R @ reference.t


def _scaled_intrinsics(camera: Camera, size: tuple[int, int]) -> np.ndarray:
    """``camera.K`` as it would be for images of ``size`` (width, height)."""
    scale = np.diag([size[0] / camera.image_size[0], size[1] / camera.image_size[1], 1.0])
    return scale @ camera.K


def rectification_of(rig: Rig, other: str | None = None) -> Rectification:
    """The rig's stored rectification when it is for ``other`` (or ``other`` is None), otherwise
    one computed by :func:`stereo_rectification`."""
    stored = rig.rectification
    if stored is not None and stored.cameras[0] == rig.reference and other in (None, stored.cameras[1]):
        return stored
    return stereo_rectification(rig, other)


@dataclass(frozen=True)
class RectifyMaps:
    """``cv2.remap`` maps into the rectified frame: for each rectified pixel, where to
    sample the original left (reference) and right image. Each map is (H, W) float32,
    (H, W) = the rectified size."""

    left_x: np.ndarray
    left_y: np.ndarray
    right_x: np.ndarray
    right_y: np.ndarray


def rectify_maps(rig: Rig, rectification: Rectification) -> RectifyMaps:
    """The remap tables of ``rectification`` (``cv2.initUndistortRectifyMap`` for each camera)."""
    left, right = (rig.camera(name) for name in rectification.cameras)
    size = rectification.image_size
    left_x, left_y = cv2.initUndistortRectifyMap(left.K, left.distortion, rectification.R1, rectification.P1, size,
                                                 cv2.CV_32FC1)
    right_x, right_y = cv2.initUndistortRectifyMap(right.K, right.distortion, rectification.R2, rectification.P2,
                                                   size, cv2.CV_32FC1)
    return RectifyMaps(left_x, left_y, right_x, right_y)


def check_image_size(rig: Rig, name: str, image: np.ndarray, *, path: object = None) -> None:
    """CadeError unless ``image`` (H, W[, C]) has the size the rig records for camera ``name``."""
    width, height = rig.camera(name).image_size
    if image.shape[:2] != (height, width):
        shown = f"{path} is" if path is not None else f"the {name} image is"
        raise CadeError(f"{shown} {image.shape[1]}x{image.shape[0]} but the rig's camera {name} takes "
                        f"{width}x{height} images; give that camera's picture, or calibrate at this size")


def rectify_pair(rig: Rig, left: np.ndarray, right: np.ndarray, *, rectification: Rectification | None = None,
                 maps: RectifyMaps | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``left`` (reference camera) and ``right`` resampled into the rectified frame.

    Args:
        left, right: (H, W) or (H, W, C) images of the two cameras of ``rectification``,
            each at the size the rig records for it (they may differ).
        rectification: default :func:`rectification_of` the rig.

    Returns:
        The rectified (H', W'[, C]) float32 images, bilinear; pixels with no source are 0.

    Raises:
        CadeError: an image whose size is not its camera's.
    """
    rectification = rectification_of(rig) if rectification is None else rectification
    for name, image in zip(rectification.cameras, (left, right)):
        check_image_size(rig, name, image)
    maps = rectify_maps(rig, rectification) if maps is None else maps
    return (_remap(left, maps.left_x, maps.left_y), _remap(right, maps.right_x, maps.right_y))


def _remap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, *, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    return cv2.remap(np.asarray(image, np.float32), map_x, map_y, interpolation, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=0)


def needs_mirroring(rectification: Rectification) -> bool:
    """True when the second camera is LEFT of the reference in the rectified frame.

    cade's matchers search ``I_left(y, x) ~ I_right(y, x - d)`` with d >= 0, which holds
    when the reference is the left camera. Otherwise the two rectified images are
    mirrored (left-right) before matching and the disparity mirrored back.
    """
    return float(rectification.P2[0, 3]) > 0


def rectified_points(disparity: np.ndarray, rectification: Rectification) -> np.ndarray:
    """(H, W, 3) float32 3-D point of each rectified reference pixel, metres, in the
    rectified reference camera's frame (``cv2.reprojectImageTo3D`` with ``Q``); NaN where
    the disparity is NaN or <= 0."""
    disparity = np.asarray(disparity, np.float32)
    usable = np.isfinite(disparity) & (disparity > 0)
    sign = -1.0 if needs_mirroring(rectification) else 1.0  # Q's disparity is x_left - x_right in the rectified frame
    points = cv2.reprojectImageTo3D((sign * np.where(usable, disparity, 1.0)).astype(np.float32), rectification.Q)
    points[~usable] = np.nan
    return points


def to_original_frame(points: np.ndarray, rectification: Rectification) -> np.ndarray:
    """(…, 3) points of the rectified reference frame in the reference camera's own frame
    (rotated by ``R1^T``)."""
    return (points.reshape(-1, 3) @ np.asarray(rectification.R1, np.float64)).reshape(points.shape).astype(np.float32)


def original_to_rectified_maps(rig: Rig, rectification: Rectification) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel of the ORIGINAL reference image, its (x, y) in the rectified frame:
    two (H, W) float32 maps, for ``cv2.remap`` of a rectified-frame image back onto the
    original reference image (``cv2.undistortPoints`` with ``R1``, ``P1``)."""
    camera = rig.camera(rectification.cameras[0])
    width, height = camera.image_size
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    pixels = np.stack([x.ravel(), y.ravel()], axis=1).reshape(-1, 1, 2)
    rectified = cv2.undistortPoints(pixels, camera.K, camera.distortion, R=rectification.R1, P=rectification.P1)
    rectified = rectified.reshape(height, width, 2)
    return rectified[..., 0].astype(np.float32), rectified[..., 1].astype(np.float32)


def to_original_image(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """A rectified-frame (H', W'[, C]) float image resampled onto the original reference image
    (bilinear; NaN where the rectified frame has no pixel or a NaN neighbour)."""
    return cv2.remap(np.asarray(image, np.float32), maps[0], maps[1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))


def write_ply(path: Path, points: np.ndarray, colours: np.ndarray) -> int:
    """Write finite points as a binary little-endian PLY (x, y, z float32; red, green, blue uint8).

    Args:
        points: (H, W, 3) or (N, 3) float, metres; rows with a NaN are left out.
        colours: (H, W) or (N,) grey values in [0, 1], or (…, 3) RGB in [0, 1].

    Returns:
        The number of points written.
    """
    xyz = np.asarray(points, np.float32).reshape(-1, 3)
    colour = np.asarray(colours, np.float32)
    if colour.size == 3 * len(xyz) and colour.shape[-1] == 3:
        colour = colour.reshape(-1, 3)  # RGB
    else:
        colour = np.repeat(colour.reshape(-1, 1), 3, axis=1)  # grey
    keep = np.all(np.isfinite(xyz), axis=1)
    vertex = np.zeros(int(keep.sum()), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                              ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = xyz[keep, i]
    rgb = np.round(np.clip(np.nan_to_num(colour[keep]), 0, 1) * 255).astype(np.uint8)
    for i, name in enumerate(("red", "green", "blue")):
        vertex[name] = rgb[:, i]
    header = ("ply\nformat binary_little_endian 1.0\ncomment cade point cloud, metres, reference camera frame\n"
              f"element vertex {len(vertex)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    with open(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(vertex.tobytes())
    return len(vertex)


@dataclass(frozen=True)
class VerticalMisalignment:
    """What is left of a pair's rectification error, as right-image row minus left-image row
    of the same scene point: ``dy(x) = offset + tan(roll) * (x - cx)``.

    Attributes:
        offset: vertical offset at the image centre, px (> 0: the right image shows things lower).
        roll: rotation of the right image against the left about the image centre, radians.
        residual: median |dy| of the matches after the fit, px (how well the model explains them).
        matches: number of inlier matches the fit rests on.
        centre: (cx, cy) the roll turns about, px.
    """

    offset: float
    roll: float
    residual: float
    matches: int
    centre: tuple[float, float]

    def worst(self, width: int) -> float:
        """The largest |dy| over the image width, px (the offset plus the roll at the far edge)."""
        half = width / 2
        return max(abs(self.offset + math.tan(self.roll) * dx) for dx in (-half, half))


def gradient_image(band: np.ndarray) -> np.ndarray:
    """(H, W) uint8 gradient magnitude of a band (Gaussian sigma 1, Sobel), divided by its
    local mean (31x31 box) and scaled: the same for a band and its inverse, and similar
    across bands that see the same edges with different contrasts."""
    values = np.asarray(band, np.float32)
    smooth = cv2.GaussianBlur(values, (0, 0), 1.0)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.sqrt(gx * gx + gy * gy)
    local = cv2.blur(magnitude, (31, 31)) + 1e-3 * float(magnitude.max() + 1e-12)
    normalised = magnitude / local
    return np.clip(normalised * 64, 0, 255).astype(np.uint8)


FEATURE_DETECTORS = ("sift", "orb")
"""Detectors :func:`sparse_matches` offers: ``sift`` (precise, the rig self-check's) and
``orb`` (about ten times cheaper, the pair check's: :mod:`cade_cli.pair_check`)."""


def sparse_matches(left: np.ndarray, right: np.ndarray, *, detector: str = "sift", features: int = 4000,
                   max_vertical: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sparse feature matches between two bands that may come from different filters.

    Features are detected on :func:`gradient_image` of each band (so a contrast inversion
    or a different response of the filters matters little) and matched mutually, with
    Lowe's ratio test (0.8): :func:`gradient_matches`.

    Args:
        left, right: (H, W) float bands, any range; sizes may differ.
        detector: ``sift`` (float descriptors, L2) or ``orb`` (binary, Hamming, one
            scale: the two views of a pair share their scale), :data:`FEATURE_DETECTORS`.
        features: the most features detected per band.
        max_vertical: only features whose rows differ by at most this many px are
            candidates (and compete in the ratio test); None: any two.

    Returns:
        (points_left, points_right): (N, 2) float64 (x, y) px of the N matches, in the
        pixels of each band; N may be 0.
    """
    return gradient_matches(gradient_image(left), gradient_image(right), detector=detector, features=features,
                            max_vertical=max_vertical)


ORB_FAST_THRESHOLD = 5
"""FAST threshold of the ``orb`` detector (grey levels of :func:`gradient_image`)."""


def gradient_matches(left: np.ndarray, right: np.ndarray, *, detector: str = "sift", features: int = 4000,
                     max_vertical: float | None = None, max_horizontal: float | None = None,
                     fast_threshold: int = ORB_FAST_THRESHOLD, patch_size: int = 31) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sparse_matches` of two :func:`gradient_image` results (uint8, (H, W)).

    ``fast_threshold`` and ``patch_size`` (px, odd) tune the ``orb`` detector: a higher
    threshold and a smaller patch are cheaper and suit small images. With
    ``max_vertical``, the distances are computed only between the allowed pairs
    (``cv2.batchDistance`` with a mask), which is several times cheaper than all of them;
    ``max_horizontal`` (px, with ``max_vertical`` only) also keeps apart the features whose
    columns differ by more (fewer wrong candidates: more matches pass the ratio test).
    """
    if detector == "sift":
        finder, norm = cv2.SIFT_create(nfeatures=features, contrastThreshold=0.02), cv2.NORM_L2
    elif detector == "orb":
        finder, norm = cv2.ORB_create(nfeatures=features, nlevels=1, fastThreshold=fast_threshold,
                                      edgeThreshold=patch_size, patchSize=patch_size), cv2.NORM_HAMMING
    else:
        raise ValueError(f"unknown detector {detector!r}; expected one of {FEATURE_DETECTORS}")
    key_left, desc_left = finder.detectAndCompute(left, None)
    key_right, desc_right = finder.detectAndCompute(right, None)
    if desc_left is None or desc_right is None or len(key_left) < 2 or len(key_right) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    points_left, points_right = (np.float64([key.pt for key in keys]).reshape(-1, 2) for keys in (key_left, key_right))
    if max_vertical is None:
        matcher = cv2.BFMatcher(norm)
        forward = matcher.knnMatch(desc_left, desc_right, k=2)
        backward = {m[0].queryIdx: m[0].trainIdx for m in matcher.knnMatch(desc_right, desc_left, k=1) if m}
        pairs = [(m[0].queryIdx, m[0].trainIdx) for m in forward
                 if len(m) == 2 and m[0].distance < 0.8 * m[1].distance and backward.get(m[0].trainIdx) == m[0].queryIdx]
        if not pairs:
            return np.zeros((0, 2)), np.zeros((0, 2))
        first, second = np.array(pairs).T
        return points_left[first], points_right[second]
    rows_left = np.empty((len(points_left), len(points_right)), np.float32)
    rows_left[:] = points_left[:, 1:2]
    allowed = cv2.inRange(rows_left - np.float32(points_right[:, 1]), -max_vertical, max_vertical)  # 255: a candidate
    if max_horizontal is not None:
        rows_left[:] = points_left[:, :1]  # now columns
        allowed &= cv2.inRange(rows_left - np.float32(points_right[:, 0]), -max_horizontal, max_horizontal)
    dtype = cv2.CV_32S if norm == cv2.NORM_HAMMING else cv2.CV_32F
    distance, nearest = cv2.batchDistance(desc_left, desc_right, dtype, normType=norm, K=2, mask=allowed)
    _, back = cv2.batchDistance(desc_right, desc_left, dtype, normType=norm, K=1, mask=np.ascontiguousarray(allowed.T))
    best, back = nearest[:, 0], back[:, 0]
    keep = ((nearest[:, 1] >= 0) & (best >= 0)
            & (distance[:, 0].astype(np.float64) < 0.8 * distance[:, 1].astype(np.float64)))
    keep[keep] = back[best[keep]] == np.flatnonzero(keep)
    return points_left[keep], points_right[best[keep]]


def fit_vertical_misalignment(x: np.ndarray, dy: np.ndarray, *, size: tuple[int, int], min_band: float = 0.25,
                              min_roll_matches: int = MIN_ROLL_MATCHES) -> tuple[VerticalMisalignment, np.ndarray]:
    """Fit ``dy = offset + tan(roll) (x - cx)`` to matches, robustly.

    Least squares, repeated on the matches within 3 robust standard deviations (at
    least ``min_band`` px) of the previous fit, starting from those within 3 of the median
    (at least 0.5 px). With fewer than ``min_roll_matches`` matches only the offset is
    fitted (roll 0).

    Args:
        x: (N,) column of each match in the left band, px.
        dy: (N,) right-band row minus left-band row of each match, px.
        size: (width, height) of the band, px (the roll turns about its centre).
        min_band: the narrowest inlier band, px (the precision of the match positions).
        min_roll_matches: the fewest matches the roll is fitted from.

    Returns:
        (the fit, (N,) bool inlier mask).

    Raises:
        CadeError: fewer than :data:`MIN_SELF_CHECK_MATCHES` matches, or inliers.
    """
    x, dy = np.asarray(x, np.float64), np.asarray(dy, np.float64)
    if len(dy) < MIN_SELF_CHECK_MATCHES:
        raise _too_few_matches(len(dy))
    width, height = size
    centre = ((width - 1) / 2, (height - 1) / 2)
    design = np.stack([np.ones_like(x), x - centre[0]], axis=1)
    if len(dy) < min_roll_matches:
        design[:, 1] = 0  # offset only; lstsq gives the roll term 0
    inliers = np.abs(dy - np.median(dy)) <= max(3 * 1.4826 * np.median(np.abs(dy - np.median(dy))), 0.5)
    for _ in range(5):
        if inliers.sum() < MIN_SELF_CHECK_MATCHES:
            raise _too_few_matches(int(inliers.sum()))
        coefficients, *_ = np.linalg.lstsq(design[inliers], dy[inliers], rcond=None)
        residual = dy - design @ coefficients
        spread = 1.4826 * float(np.median(np.abs(residual[inliers])))
        inliers = np.abs(residual) <= max(3 * spread, min_band)
    offset, slope = (float(v) for v in coefficients)
    found = VerticalMisalignment(offset=offset, roll=math.atan(slope),
                                 residual=float(np.median(np.abs(residual[inliers]))) if inliers.any() else 0.0,
                                 matches=int(inliers.sum()), centre=centre)
    return found, inliers


def measure_vertical_misalignment(left: np.ndarray, right: np.ndarray, *, max_vertical: float = 8.0,
                                  max_disp: float | None = None, mirrored: bool = False) -> VerticalMisalignment:
    """Fit a vertical offset and roll to sparse matches between a rectified pair.

    SIFT features on :func:`gradient_image` of each band are matched (ratio test 0.8,
    mutual; :func:`sparse_matches`), kept where the row difference is within
    ``max_vertical`` px and the disparity ``x_left - x_right`` within [-8, ``max_disp`` + 8]
    px, and ``dy = offset + tan(roll) (x - cx)`` is fitted (:func:`fit_vertical_misalignment`).

    Args:
        left, right: (H, W) float bands of one rectified pair, same size, any range.
        max_vertical: the largest row difference considered, px.
        max_disp: the largest disparity considered, px (default: the image width).
        mirrored: the ``right`` camera is the one on the left (:func:`needs_mirroring`):
            its matches lie at x_right = x_left + d, so the disparity is ``x_right - x_left``.

    Raises:
        CadeError: images of different sizes, or fewer than :data:`MIN_SELF_CHECK_MATCHES`
            matches (too little texture shared by the bands).
    """
    left, right = np.asarray(left, np.float32), np.asarray(right, np.float32)
    if left.shape != right.shape or left.ndim != 2:
        raise CadeError(f"the self-check needs two (H, W) bands of one size, got {left.shape} and {right.shape}")
    height, width = left.shape
    max_disp = float(width) if max_disp is None else float(max_disp)
    points_left, points_right = sparse_matches(left, right, detector="sift", features=4000)
    if not len(points_left):
        raise _too_few_matches(0)
    dy = points_right[:, 1] - points_left[:, 1]
    dx = (points_left[:, 0] - points_right[:, 0]) * (-1.0 if mirrored else 1.0)
    keep = (np.abs(dy) <= max_vertical) & (dx >= -8) & (dx <= max_disp + 8)
    found, _ = fit_vertical_misalignment(points_left[keep, 0], dy[keep], size=(width, height))
    return found


def _too_few_matches(count: int) -> CadeError:
    return CadeError(f"the rectification self-check found only {count} feature matches between the rectified images "
                     f"({MIN_SELF_CHECK_MATCHES} needed): too little shared texture; drop --fix-vertical")


def correct_vertical_misalignment(right: np.ndarray, misalignment: VerticalMisalignment) -> np.ndarray:
    """``right`` resampled so that the fitted offset and roll vanish: output pixel (x, y)
    takes ``right`` at the roll-rotated, offset position of (x, y) (bicubic, which softens
    the band less than bilinear; borders replicated). Works on (H, W) or (H, W, C) float images."""
    cx, cy = misalignment.centre
    c, s = math.cos(misalignment.roll), math.sin(misalignment.roll)
    # Where left pixel p = (x, y) lies in the right image: rotation about the centre, then the offset.
    forward = np.float64([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy + misalignment.offset]])
    height, width = right.shape[:2]
    return cv2.warpAffine(np.asarray(right, np.float32), forward, (width, height),
                          flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)


def align_vertically(left: np.ndarray, right: np.ndarray, *, max_disp: float | None = None,
                     min_correction: float = MIN_CORRECTION_PX, mirrored: bool = False) -> tuple[np.ndarray, VerticalMisalignment, bool]:
    """The self-check and its correction, as ``--fix-vertical`` and the rig benchmark run it.

    Measures the misalignment (:func:`measure_vertical_misalignment`) and, when it
    reaches ``min_correction`` px somewhere across the width, resamples ``right`` to
    cancel it (:func:`correct_vertical_misalignment`); a smaller one is left alone, since
    resampling softens the band more than such a residual costs the matcher.

    Returns:
        (``right``, corrected or as given; the misalignment measured; whether it was corrected).

    Raises:
        CadeError: too few matches to measure (:func:`measure_vertical_misalignment`).
    """
    found = measure_vertical_misalignment(left, right, max_disp=max_disp, mirrored=mirrored)
    if found.worst(right.shape[1]) < min_correction:
        return right, found, False
    return correct_vertical_misalignment(right, found), found, True


@dataclass(frozen=True)
class RigDisparity:
    """Disparity of a rig's pair, in the rectified reference frame.

    Attributes:
        result: the matcher's unfilled map (NaN where invalid), validity and confidence;
            disparity d >= 0 px of the rectified frame, the other camera's view of
            reference pixel (y, x) lying at (y, x - d) when it is the right camera and
            at (y, x + d) when it is the left one (:func:`needs_mirroring`).
        dense: the map filled by :func:`~cade_cli.matching.densify` (filled in the frame
            it was matched in, so from the background side).
        left, right: the rectified reference and other band (``right`` after the
            vertical correction when one was applied).
        rectification: the rectification used.
        misalignment: the self-check's measurement on the rectified pair, before any
            correction; None when it could not run (``self_check_problem`` says why).
        corrected: True when ``right`` was corrected for ``misalignment`` (``fix_vertical``
            and a misalignment of at least :data:`MIN_CORRECTION_PX`).
        range: the inclusive range searched, px of the rectified frame (``auto`` bounds resolved).
        range_estimate: how an ``auto`` bound was estimated (:func:`cade_cli.scale.range.estimate_range`), else None.
        plan: how the rectified pair was matched: whole, or as tiles within the memory
            limit (:func:`cade_cli.scale.tiling.plan_tiles`).
    """

    result: DisparityResult
    dense: np.ndarray
    left: np.ndarray
    right: np.ndarray
    rectification: Rectification
    misalignment: VerticalMisalignment | None
    self_check_problem: str | None
    corrected: bool
    range: DisparityRange
    range_estimate: RangeEstimate | None
    plan: TilePlan


def rig_disparity(
    rig: Rig, left: np.ndarray, right: np.ndarray, *, other: str | None = None, fix_vertical: bool = False,
    self_check: bool = True, method: str = DEFAULT_METHOD, max_disp: int | str | None = None,
    min_disp: int | str = 0, preprocess: str = DEFAULT_PREPROCESS, model: str | None = None,
    memory_limit: int | None = None,
) -> RigDisparity:
    """Rectify a rig's pair, check it, and match it as ``cade disparity`` matches a pair:
    the range resolved (:func:`cade_cli.scale.range.resolve_range`), then
    :func:`cade_cli.scale.tiling.estimate_disparity_tiled` (whole when it fits the memory limit,
    else as tiles).

    The range is resolved on the rectified bands as the matcher takes them (after the
    vertical correction; mirrored when the other camera is the left one), so an ``auto``
    bound is in the same rectified px, d >= 0 towards the near side, as a given one.

    Args:
        rig: the rig; ``left`` is its reference camera's image and ``right`` camera
            ``other``'s (default: the camera of the rig's rectification, else the first
            other camera). Each must have its camera's image size; they may differ.
        left, right: (H, W) float bands.
        fix_vertical: correct the measured vertical offset and roll before matching
            (:func:`align_vertically`); the self-check must then succeed.
        self_check: measure the vertical misalignment of the rectified pair.
        method, preprocess, model: as for :func:`~cade_cli.stereo.estimate_disparity`.
        min_disp, max_disp: the range, px of the rectified frame, each a whole number or
            ``"auto"`` (estimated on the rectified pair); ``max_disp=None``: a quarter of
            the rectified width. The self-check considers matches up to ``max_disp``
            (the image width while it is ``auto`` or None, since it runs first).
        memory_limit: budget for the whole process, bytes, as ``--memory-limit``; None:
            :func:`cade_cli.scale.tiling.default_memory_limit`.

    Raises:
        CadeError: a bad rig or image size (:func:`rectify_pair`), too few self-check
            matches with ``fix_vertical``, a range that cannot be estimated, or what the
            matcher or the tiling refuses.
    """
    other = other if other is not None or rig.rectification is None else rig.rectification.cameras[1]
    rectification = rectification_of(rig, other)
    left_rect, right_rect = rectify_pair(rig, left, right, rectification=rectification)
    check_max = max_disp if isinstance(max_disp, int) else None
    flip = needs_mirroring(rectification)
    misalignment, problem, corrected = None, None, False
    if fix_vertical:
        right_rect, misalignment, corrected = align_vertically(left_rect, right_rect, max_disp=check_max, mirrored=flip)
    elif self_check:
        try:
            misalignment = measure_vertical_misalignment(left_rect, right_rect, max_disp=check_max, mirrored=flip)
        except CadeError as error:
            problem = str(error).split(";")[0]
    matched_left, matched_right = (np.ascontiguousarray(band[:, ::-1]) if flip else band
                                   for band in (left_rect, right_rect))
    searched, estimate = resolve_range(matched_left, matched_right, min_disp=min_disp, max_disp=max_disp)
    budget = default_memory_limit() if memory_limit is None else memory_limit
    result, plan = estimate_disparity_tiled(matched_left, matched_right, method=method, min_disp=searched.minimum,
                                            max_disp=searched.maximum, preprocess=preprocess, model=model,
                                            memory_limit=budget)
    dense = densify(result.disparity, result.valid)
    if flip:
        result = DisparityResult(**{field.name: _unflip(getattr(result, field.name))
                                    for field in dataclasses.fields(result)})
        dense = _unflip(dense)
    return RigDisparity(result=result, dense=dense, left=left_rect, right=right_rect, rectification=rectification,
                        misalignment=misalignment, self_check_problem=problem, corrected=corrected, range=searched,
                        range_estimate=estimate, plan=plan)


def _unflip(value):
    return np.ascontiguousarray(value[:, ::-1]) if isinstance(value, np.ndarray) and value.ndim >= 2 else value


RECTIFIED_IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
"""What :func:`write_rectified_image` writes: 8-bit PNG, or float32 TIFF (values kept)."""


def write_rectified_image(path: Path, image: np.ndarray) -> None:
    """Write a rectified (H, W) or (H, W, 3) RGB float image: a PNG as 8 bits ([0, 1] -> 0-255,
    clipped), a TIFF as float32 as it is. Writes ``path`` itself (stage it for atomicity)."""
    path = Path(path)
    values = np.asarray(image, np.float32)
    if path.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        tifffile.imwrite(path, values, photometric="rgb" if values.ndim == 3 else "minisblack")
        return
    if path.suffix.lower() != ".png":
        raise CadeError(f"cannot write {path}: use .png (8 bits) or .tif (float32)")
    scaled = np.round(np.clip(np.nan_to_num(values), 0, 1) * 255).astype(np.uint8)
    if scaled.ndim == 3:
        scaled = cv2.cvtColor(scaled, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), scaled):
        raise CadeError(f"could not write {path}")


def epipolar_picture(left: np.ndarray, right: np.ndarray, *, spacing: int = 32) -> np.ndarray:
    """(H, 2W, 3) uint8 BGR picture: the rectified pair side by side, with a horizontal line
    every ``spacing`` px across both (a scene point should sit on the same line in each)."""
    def as_bgr(image):
        scaled = np.round(np.clip(np.nan_to_num(np.asarray(image, np.float32)), 0, 1) * 255).astype(np.uint8)
        return cv2.cvtColor(scaled, cv2.COLOR_GRAY2BGR if scaled.ndim == 2 else cv2.COLOR_RGB2BGR)

    left_bgr, right_bgr = as_bgr(left), as_bgr(right)
    height = max(left_bgr.shape[0], right_bgr.shape[0])
    canvas = np.zeros((height, left_bgr.shape[1] + right_bgr.shape[1], 3), np.uint8)
    canvas[:left_bgr.shape[0], :left_bgr.shape[1]] = left_bgr
    canvas[:right_bgr.shape[0], left_bgr.shape[1]:] = right_bgr
    colours = ((0, 255, 0), (0, 160, 255), (255, 80, 255))
    for i, y in enumerate(range(spacing // 2, height, spacing)):
        cv2.line(canvas, (0, y), (canvas.shape[1] - 1, y), colours[i % len(colours)], 1, cv2.LINE_AA)
    return canvas


def luminance_of(image: np.ndarray) -> np.ndarray:
    """An (H, W) band of an (H, W) or (H, W, C) image: itself, or the Rec. 601 luminance of RGB(A)."""
    image = np.asarray(image, np.float32)
    if image.ndim == 2:
        return image
    if image.shape[2] >= 3:
        return (0.299 * image[..., 0] + 0.587 * image[..., 1] + 0.114 * image[..., 2]).astype(np.float32)
    return image[..., 0]


FRAMES = ("rectified", "original")
"""Where :func:`in_frame` puts results: the rectified reference image, or the original one."""


@dataclass(frozen=True)
class FramedDisparity:
    """A :class:`RigDisparity` in one frame (:data:`FRAMES`).

    Attributes:
        disparity: (H, W) float32 unfilled disparity, px of the RECTIFIED frame (so that
            depth = f B / d holds), NaN where invalid or outside the rectified view.
        dense: the filled map in that frame (NaN only outside the rectified view).
        valid: (H, W) bool, where ``disparity`` is finite.
        confidence: (H, W) float32 in [0, 1] (0 where invalid), or None.
        depth: (H, W) float32 depth of ``dense`` (or of ``disparity`` with ``fill=False``)
            along the frame's optical axis, metres, NaN where unknown.
        points: (N, 3) float32 3-D points of the valid rectified pixels in the reference
            camera's own frame, metres; colours: (N,) their reference band values.
    """

    disparity: np.ndarray
    dense: np.ndarray
    valid: np.ndarray
    confidence: np.ndarray | None
    depth: np.ndarray
    points: np.ndarray
    colours: np.ndarray


def in_frame(found: RigDisparity, rig: Rig, *, frame: str = "rectified", fill: bool = True) -> FramedDisparity:
    """``found`` in the rectified reference frame, or resampled (bilinear) onto the original
    reference image (``frame="original"``: ``cv2.undistortPoints`` with R1, P1 gives each
    original pixel's place in the rectified frame). Depth and points use the dense map
    when ``fill``, else only the valid pixels."""
    if frame not in FRAMES:
        raise CadeError(f"unknown frame {frame!r}; choose rectified or original")
    rectification = found.rectification
    chosen = found.dense if fill else found.result.disparity
    rectified_xyz = rectified_points(chosen, rectification)
    camera_xyz = to_original_frame(rectified_xyz, rectification)
    keep = np.all(np.isfinite(camera_xyz), axis=2)
    points, colours = camera_xyz[keep], np.asarray(found.left, np.float32)[keep]
    if found.left.ndim == 3:
        colours = luminance_of(found.left)[keep]
    confidence = found.result.confidence
    if frame == "rectified":
        return FramedDisparity(disparity=found.result.disparity, dense=found.dense, valid=found.result.valid,
                               confidence=confidence, depth=rectified_xyz[..., 2], points=points, colours=colours)
    maps = original_to_rectified_maps(rig, rectification)
    disparity = to_original_image(found.result.disparity, maps)
    dense = to_original_image(found.dense, maps)
    depth = to_original_image(camera_xyz[..., 2], maps)
    if confidence is not None:
        confidence = np.nan_to_num(to_original_image(confidence, maps), nan=0.0)
        confidence[~np.isfinite(disparity)] = 0
    return FramedDisparity(disparity=disparity, dense=dense, valid=np.isfinite(disparity), confidence=confidence,
                           depth=depth, points=points, colours=colours)
