"""Rectify a rig's pair, and match it.

- :func:`stereo_rectification`: OpenCV's ``stereoRectify`` for the reference camera and
  one other, from the rig's calibration (cameras of different resolutions included).
- :func:`rectify_pair`: both images resampled into the rectified frame, where a scene
  point lies on the same row of both and ``I_left(y, x) ~ I_right(y, x - d)``, d >= 0.
- :func:`rig_disparity`: the pair rectified, self-checked (:mod:`cade_cli.rigs.self_check`:
  the vertical offset and roll rectification left, cancelled with ``--fix-vertical``),
  then the range and the matcher (whole or as tiles within a memory budget).

What the result becomes for the user (the original frame, depth, points, the rectified
images) is :mod:`cade_cli.rigs.outputs`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching import DisparityRange, DisparityResult, densify
from cade_cli.rigs.rig import Camera, Rectification, Rig
from cade_cli.rigs.self_check import VerticalMisalignment, align_vertically, measure_vertical_misalignment
from cade_cli.scale.memory import default_memory_limit
from cade_cli.scale.range import RangeEstimate, resolve_range
from cade_cli.scale.tiling import TilePlan, estimate_disparity_tiled
from cade_cli.stereo import DEFAULT_METHOD, DEFAULT_PREPROCESS


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
    memory_limit: int | None = None, on_range: Callable[[DisparityRange], None] | None = None,
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
            :func:`cade_cli.scale.memory.default_memory_limit`.
        on_range: called with the resolved range before matching (it may refuse it: an
            output that cannot hold it).

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
    if on_range is not None:
        on_range(searched)
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


