"""Camera arrays: N cameras registered onto the reference camera as one multi-band cube.

An array is a :class:`~cade_cli.rigs.rig.Rig` whose cameras all look the same way from
(nearly) one plane. Each camera is first brought onto the *reference plane*, the
reference camera's image:

- plane-registered rigs (``to_reference`` + ``position``, e.g. MSIR): its homography
  (an affine is one) maps the camera's pixels onto the reference image; what is left is
  the parallax of points off the plane that homography was fitted to;
- calibrated rigs (``K``, ``dist``, ``R``, ``t``): the camera is undistorted and rotated
  into the reference camera (the homography of the plane at infinity, ``K_ref R^T
  K^-1``); what is left is the parallax of points at finite depth.

Either way, a reference pixel p of a scene point sits in camera i's warped image at
``p - delta(p) * b_i / unit``: ``b_i`` is the camera's *baseline*, the position of its
centre relative to the reference's in the reference image's axes (x: towards
increasing column, y: towards increasing row, i.e. downwards; metres), ``unit`` the
length of the shortest baseline of the rig, and ``delta`` the one disparity of the
reference view in **pixels per unit baseline** (positive: nearer than the plane). For a
camera to the reference's right (b = (+B, 0)) this is the project's stereo convention
``I_left(x) ~ I_right(x - d)`` with ``d = delta * B / unit``.

:func:`register_array` estimates ``delta``: each camera is matched against the reference
along its own baseline (both images turned so that the baseline is the matcher's +x,
:class:`BaselineFrame`; a signed range), each estimate is divided by its baseline, and
the votes are fused by a median in which a camera that does not see a pixel (the
matcher rejected it, it falls out of that camera's view, a nearer surface hides it
there, or it disagrees with the others by more than a pixel) does not vote. Every band
is then resampled with that one geometry, and each gets a validity band.

The geometry is :mod:`cade_cli.rigs.array_geometry`, the cube written
:mod:`cade_cli.rigs.array_cube`, its scores without ground truth :mod:`cade_cli.rigs.array_score`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.disparity import densify, visible_in_right_view
from cade_cli.rigs.array_geometry import ArrayCamera, ArrayGeometry, baseline_frame, resize_masked
from cade_cli.scale.range import estimate_range
from cade_cli.stereo import DEFAULT_METHOD, DEFAULT_PREPROCESS, estimate_disparity


DEFAULT_SEARCH: tuple[float, float] = (-16.0, 16.0)
"""Signed search range, px per unit baseline: residual parallax after a plane
registration is small and has both signs (points before and behind the plane)."""

MIN_OVERLAP = 0.05
"""A camera whose warped image covers less than this share of the reference view is
refused: the rig's mapping or pose is wrong, or the image is another camera's."""

BOUND_MARGIN = 0.5
"""An estimate closer than this (px, at the matching resolution) to an end of its search
range does not vote: the matcher clipped it there."""

VOTE_TOLERANCE = 1.0
"""A vote further than this from the first median, in pixels of its own camera (at the
matching resolution), does not count."""


@dataclass(frozen=True)
class ArrayRegistration:
    """Every camera of an array in the reference view.

    Attributes:
        reference_camera: the reference's :class:`ArrayCamera`.
        cameras: the other cameras' :class:`ArrayCamera`, in rig order.
        reference: (H, W) float32 reference band (undistorted for a calibrated rig).
        registered: one (H, W) float32 band per camera, resampled with the fused geometry.
        valid: one (H, W) bool per camera: the sample fell inside that camera's image,
            the fused disparity had a vote there and no nearer surface hides the pixel
            from that camera.
        disparity: (H, W) float32 dense fused disparity, px per unit baseline.
        disparity_valid: (H, W) bool, where at least one camera voted.
        votes: one (H, W) float32 map per camera, its own estimate in px per unit
            baseline, NaN where it did not vote; empty when the parallax was not estimated.
        unit: the unit baseline, metres.
    """

    reference_camera: ArrayCamera
    cameras: tuple[ArrayCamera, ...]
    reference: np.ndarray
    registered: tuple[np.ndarray, ...]
    valid: tuple[np.ndarray, ...]
    disparity: np.ndarray
    disparity_valid: np.ndarray
    votes: tuple[np.ndarray, ...]
    unit: float


def check_array_images(geometry: ArrayGeometry, images: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The images, one per camera in the order ``(geometry.reference, *geometry.cameras)``,
    as float32 (H, W) bands.

    Raises:
        CadeError: a wrong number of images, an image that is not one band, or one of
            another size than its camera's ``image_size``.
    """
    cameras = (geometry.reference, *geometry.cameras)
    if len(images) != len(cameras):
        raise CadeError(f"the rig has {len(cameras)} cameras ({', '.join(c.name for c in cameras)}) but "
                        f"{len(images)} images were given; give one image per camera")
    bands = []
    for camera, image in zip(cameras, images):
        band = np.asarray(image, np.float32)
        if band.ndim != 2:
            raise CadeError(f"the image of camera {camera.name} has shape {band.shape}; give one band (H, W)")
        width, height = camera.image_size
        if band.shape != (height, width):
            raise CadeError(f"the image of camera {camera.name} is {band.shape[1]}x{band.shape[0]}, the rig says "
                            f"{width}x{height}; give that camera's image or fix image_size in the rig")
        bands.append(band)
    return bands


def _grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    height, width = shape
    return np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))


def _sample(image: np.ndarray, cx: np.ndarray, cy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of ``image`` at (cx, cy) (border replicated) and where they fell inside."""
    height, width = image.shape
    finite = np.isfinite(cx) & np.isfinite(cy)
    cx, cy = np.where(finite, cx, -1).astype(np.float32), np.where(finite, cy, -1).astype(np.float32)
    sampled = cv2.remap(image, cx, cy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = finite & (cx >= 0) & (cx <= width - 1) & (cy >= 0) & (cy <= height - 1)
    return sampled, inside


def warp_camera(image: np.ndarray, camera: ArrayCamera, shape: tuple[int, int], disparity: np.ndarray | None = None,
                *, unit: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``image`` of ``camera`` resampled into the reference view of ``shape`` (H, W).

    Each reference pixel p takes the camera's sample at the reference-plane point
    ``p - disparity(p) * baseline / unit`` (``disparity`` in px per unit baseline; None:
    the plane alone). Returns (band (H, W) float32, inside (H, W) bool).
    """
    x, y = _grid(shape)
    if disparity is not None:
        x = x - disparity * np.float32(camera.baseline[0] / unit)
        y = y - disparity * np.float32(camera.baseline[1] / unit)
    return _sample(image, *camera.camera_pixels(x, y))


def _visible(disparity: np.ndarray, camera: ArrayCamera, unit: float) -> np.ndarray:
    """Reference pixels no nearer surface hides from ``camera`` (dense ``disparity``, px per
    unit baseline), judged along its baseline (:func:`visible_in_right_view`)."""
    length = float(np.hypot(*camera.baseline))
    frame = baseline_frame(camera.baseline, disparity.shape)
    turned = frame.to_frame(disparity * np.float32(length / unit))
    seen = visible_in_right_view(turned, tolerance=1.0)
    # visible_in_right_view also drops what lands outside the (turned) frame: inside/outside
    # the camera's image is judged by the caller, so only the hiding counts here.
    landing = np.arange(turned.shape[1], dtype=np.float32)[None, :] - turned
    seen |= (landing < 0) | (landing > turned.shape[1] - 1)
    _, kept = frame.from_frame(np.ones(turned.shape, np.float32), seen, disparity.shape)
    return kept


def match_camera(
    reference: np.ndarray,
    warped: np.ndarray,
    inside: np.ndarray,
    camera: ArrayCamera,
    *,
    unit: float,
    search: tuple[float | None, float | None] = DEFAULT_SEARCH,
    scale: float = 1.0,
    method: str = DEFAULT_METHOD,
    preprocess: str = DEFAULT_PREPROCESS,
    model: str | None = None,
) -> np.ndarray:
    """One camera's estimate of the reference view's disparity, px per unit baseline.

    Both views (the reference and the camera warped onto the reference plane, where
    ``inside``) are scaled by ``scale``, turned so that the camera's baseline is +x
    (:func:`baseline_frame`) and matched with :func:`~cade_cli.stereo.estimate_disparity`
    over ``search`` (px per unit baseline, times the baseline ratio: signed; a None bound is
    estimated from a coarse match of this camera's pair, :func:`~cade_cli.scale.range.estimate_range`).
    The map is turned back, brought to full size and divided by the baseline ratio.

    Returns:
        (H, W) float32, NaN where the matcher rejected the pixel, its estimate lies within
        :data:`BOUND_MARGIN` of an end of the range, or its match falls outside the
        camera's view.
    """
    shape = reference.shape
    ratio = float(np.hypot(*camera.baseline)) / unit
    if scale != 1.0:
        small = (max(8, round(shape[1] * scale)), max(8, round(shape[0] * scale)))
        reference_s = cv2.resize(reference, small, interpolation=cv2.INTER_AREA)
        warped_s = cv2.resize(warped, small, interpolation=cv2.INTER_AREA)
    else:
        reference_s, warped_s = reference, warped
    frame = baseline_frame(camera.baseline, reference_s.shape)
    left, right = frame.to_frame(reference_s), frame.to_frame(warped_s)
    low = None if search[0] is None else math.floor(search[0] * ratio * scale)
    high = None if search[1] is None else math.ceil(search[1] * ratio * scale)
    if low is None or high is None:  # 'auto': this camera's own range, from a coarse match of its pair
        estimated = estimate_range(left, right, min_disp=low, max_disp=high).range
        low, high = estimated.minimum, estimated.maximum
    high = max(low + 1, high)
    result = estimate_disparity(left, right, method=method, max_disp=high, min_disp=low, preprocess=preprocess,
                                model=model)
    # An estimate at an end of the range is clipped there, not measured (flat sky, a range too small).
    measured = result.valid & (result.disparity > low + BOUND_MARGIN) & (result.disparity < high - BOUND_MARGIN)
    disparity, valid = frame.from_frame(result.disparity, measured, reference_s.shape)
    disparity, valid = resize_masked(disparity, valid, shape)
    vote = disparity / np.float32(ratio * (reference_s.shape[1] / shape[1]))
    x, y = _grid(shape)
    step = np.where(valid, vote, 0).astype(np.float32) / np.float32(unit)
    landing = cv2.remap(inside.astype(np.uint8), x - step * np.float32(camera.baseline[0]),
                        y - step * np.float32(camera.baseline[1]), cv2.INTER_NEAREST,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    return np.where(valid & landing, vote, np.float32(np.nan)).astype(np.float32)


def masked_median(votes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median over axis 0 of (N, H, W) ``votes``, ignoring NaN: ((H, W) float32 median, NaN
    where nothing voted; (H, W) int vote count). Even counts average the middle two."""
    count = np.isfinite(votes).sum(axis=0)
    ordered = np.sort(votes, axis=0)  # NaN last
    lower = np.take_along_axis(ordered, np.maximum(count - 1, 0)[None] // 2, axis=0)[0]
    upper = np.take_along_axis(ordered, (count // 2)[None], axis=0)[0] if len(votes) else lower
    upper = np.where(count % 2 == 0, upper, lower)
    median = np.where(count > 0, (lower + upper) / 2, np.nan)
    return median.astype(np.float32), count


def fuse_votes(votes: Sequence[np.ndarray], cameras: Sequence[ArrayCamera], *, unit: float,
               tolerance: float = VOTE_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """The robust fused disparity of the reference view from per-camera votes.

    A first median of the valid votes gives a dense geometry (rows filled from the
    background side, :func:`~cade_cli.matching.densify`). A vote then no longer counts
    where its camera cannot see the pixel in that geometry (a nearer surface hides it)
    or where it lies more than ``tolerance`` px *of its own camera* from the first
    median; the rest are fused by a second median (the first's value where no vote is
    left).

    Args:
        votes: per camera (H, W) float32, px per unit baseline, NaN = no vote.
        cameras: the cameras that cast them (their baselines scale the tolerance).

    Returns:
        ((H, W) float32 fused disparity, NaN where no camera voted; (H, W) int votes kept).
    """
    stack = np.stack([np.asarray(v, np.float32) for v in votes])
    first, count = masked_median(stack)
    dense = densify(first, count > 0)
    kept = stack.copy()
    for i, camera in enumerate(cameras):
        ratio = float(np.hypot(*camera.baseline)) / unit
        outlier = np.abs(stack[i] - first) * ratio > tolerance
        kept[i][outlier | ~_visible(dense, camera, unit)] = np.nan
    second, kept_count = masked_median(kept)
    fused = np.where(kept_count > 0, second, first)
    return fused.astype(np.float32), kept_count


def register_array(
    images: Sequence[np.ndarray],
    geometry: ArrayGeometry,
    *,
    parallax: bool = True,
    method: str = DEFAULT_METHOD,
    search: tuple[float | None, float | None] = DEFAULT_SEARCH,
    scale: float = 1.0,
    preprocess: str = DEFAULT_PREPROCESS,
    model: str | None = None,
    on_camera: Callable[[str], None] | None = None,
) -> ArrayRegistration:
    """Register every camera of an array onto its reference camera.

    Args:
        images: one (H, W) band per camera, in the order ``(geometry.reference,
            *geometry.cameras)``; each the size its camera's ``image_size`` says.
        geometry: :func:`array_geometry` of the rig.
        parallax: False registers on the plane alone (the rig's homographies, or the
            rotation for a calibrated rig): the plane-only baseline the parallax is judged
            against.
        method, preprocess, model: the matcher (:func:`~cade_cli.stereo.estimate_disparity`).
        search: (lowest, highest) disparity searched, px per unit baseline; each camera
            searches it times its baseline ratio. A None bound ('auto') is estimated for
            each camera from a coarse match of its pair (the camera's own range, px).
        scale: resolution of the matching, 0 < scale <= 1 (the disparity is brought back
            to full size and rescaled).
        on_camera: called with a camera's name once it is matched (a progress bar).

    Returns:
        :class:`ArrayRegistration`.

    Raises:
        CadeError: images that do not fit the rig (:func:`check_array_images`), a camera
            that sees less than :data:`MIN_OVERLAP` of the reference view, a bad range
            or scale.
    """
    if not 0 < scale <= 1:
        raise CadeError(f"the matching scale must be in (0, 1], got {scale}")
    if None not in search and not search[0] < search[1]:
        raise CadeError(f"the search range [{search[0]}, {search[1]}] is empty; give min < max")
    bands = check_array_images(geometry, images)
    width, height = geometry.size
    shape = (height, width)
    reference, _ = warp_camera(bands[0], geometry.reference, shape)
    warped = []
    for camera, band in zip(geometry.cameras, bands[1:]):
        on_plane, inside = warp_camera(band, camera, shape)
        if inside.mean() < MIN_OVERLAP:
            raise CadeError(f"camera {camera.name} sees {100 * inside.mean():.1f}% of the reference view once mapped "
                            f"onto it; check its to_reference (or pose) in the rig and that its image is the right one")
        warped.append((on_plane, inside))
    votes: list[np.ndarray] = []
    if parallax:
        for camera, (on_plane, inside) in zip(geometry.cameras, warped):
            votes.append(match_camera(reference, on_plane, inside, camera, unit=geometry.unit, search=search,
                                      scale=scale, method=method, preprocess=preprocess, model=model))
            if on_camera is not None:
                on_camera(camera.name)
        fused, count = fuse_votes(votes, geometry.cameras, unit=geometry.unit,
                                  tolerance=VOTE_TOLERANCE / scale)
        disparity_valid = count > 0
        disparity = densify(fused, disparity_valid)
    else:
        disparity_valid = np.ones(shape, bool)
        disparity = np.zeros(shape, np.float32)
    registered, valid = [], []
    for camera, band in zip(geometry.cameras, bands[1:]):
        resampled, inside = warp_camera(band, camera, shape, disparity if parallax else None, unit=geometry.unit)
        seen = _visible(disparity, camera, geometry.unit) if parallax else True
        registered.append(resampled)
        valid.append(inside & disparity_valid & seen)
        if on_camera is not None and not parallax:
            on_camera(camera.name)
    return ArrayRegistration(geometry.reference, geometry.cameras, reference, tuple(registered), tuple(valid),
                             disparity, disparity_valid, tuple(votes), geometry.unit)


# --- the cube file --------------------------------------------------------------------------------------------------


# --- judging a registration without ground truth --------------------------------------------------------------------


# --- plane-registered rigs from point matches ----------------------------------------------------------------------


