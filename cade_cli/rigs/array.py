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
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import tifffile

from cade_cli.io.atomic import atomic_output
from cade_cli.errors import CadeError
from cade_cli.io.images import read_tiff_array
from cade_cli.io.image_files import check_input_file
from cade_cli.matching.disparity import densify, visible_in_right_view
from cade_cli.rigs.rig import Camera, PlaneMapping, Rig
from cade_cli.stereo import DEFAULT_METHOD, DEFAULT_PREPROCESS, estimate_disparity

CUBE_FORMAT = "cade-array-cube"
"""The ``format`` key of the JSON description a cube TIFF carries."""

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
class ArrayCamera:
    """A camera of an array, as the registration needs it.

    Attributes:
        name, band: from the rig.
        image_size: (width, height) of its images, px.
        baseline: (2,) float64 centre relative to the reference camera in the reference
            image's axes (x right, y down), metres; zero for the reference.
        homography: (3, 3) reference-plane px -> this camera's px (plane-registered
            rigs); None for a calibrated camera.
        K, dist, rotation, K_reference: for a calibrated camera: its intrinsics and
            distortion, the rotation ``R`` of the rig (reference -> camera) and the
            reference intrinsics the reference plane uses.
    """

    name: str
    band: str
    image_size: tuple[int, int]
    baseline: np.ndarray
    homography: np.ndarray | None = None
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    rotation: np.ndarray | None = None
    K_reference: np.ndarray | None = None

    def camera_pixels(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where reference-plane pixels (x, y) (float arrays, any equal shape) fall in this
        camera's image: two float32 arrays of the same shape (NaN behind the camera)."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        points = np.stack([x.ravel(), y.ravel(), np.ones(x.size)])
        if self.homography is not None:
            mapped = self.homography @ points
            with np.errstate(divide="ignore", invalid="ignore"):
                cx, cy = mapped[0] / mapped[2], mapped[1] / mapped[2]
        else:
            rays = self.rotation @ (np.linalg.inv(self.K_reference) @ points)
            behind = rays[2] <= 0
            projected, _ = cv2.projectPoints(rays.T.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, self.dist)
            cx, cy = projected[:, 0, 0].copy(), projected[:, 0, 1].copy()
            cx[behind] = cy[behind] = np.nan
        return cx.reshape(x.shape).astype(np.float32), cy.reshape(x.shape).astype(np.float32)


@dataclass(frozen=True)
class ArrayGeometry:
    """The reference camera, the other cameras (rig order), and the unit baseline (m)."""

    reference: ArrayCamera
    cameras: tuple[ArrayCamera, ...]
    unit: float

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the reference view: the cube's size."""
        return self.reference.image_size


def array_geometry(rig: Rig) -> ArrayGeometry:
    """The :class:`ArrayGeometry` of a rig of two or more cameras.

    Every camera is taken as plane-registered (``to_reference`` + ``position``) when all
    have that, else as calibrated (``K``, ``R``, ``t``) when all have that. A plane
    ``position`` [x, y] is read in the reference image's axes: x towards increasing
    column (image right), y towards increasing row (image down). A calibrated camera's
    baseline is its centre ``-R^T t`` in the reference camera's frame (x right, y down);
    its offset along the optical axis is ignored (an array is planar).

    Raises:
        CadeError: fewer than two cameras, cameras that are neither all plane-registered
            nor all calibrated, two cameras at the reference's position, a mapping that
            cannot be inverted.
    """
    if len(rig.cameras) < 2:
        raise CadeError(f"an array needs at least two cameras, the rig has {len(rig.cameras)}")
    plane = all(c.to_reference is not None and c.position is not None for c in rig.cameras)
    calibrated = all(c.calibrated for c in rig.cameras)
    if not (plane or calibrated):
        raise CadeError("the rig's cameras must all have to_reference and position (a plane-registered array) or "
                        "all have K, R and t (a calibrated one); complete the rig file")
    reference = rig.reference_camera
    if plane:
        origin = np.asarray(reference.position, np.float64)
        cameras = {c.name: _plane_camera(c, np.asarray(c.position, np.float64) - origin) for c in rig.cameras}
    else:
        K_reference = np.asarray(reference.K, np.float64)
        origin = _centre(reference)
        cameras = {c.name: _calibrated_camera(c, _centre(c) - origin, K_reference) for c in rig.cameras}
    others = tuple(cameras[c.name] for c in rig.cameras if c.name != rig.reference)
    lengths = [float(np.hypot(*camera.baseline)) for camera in others]
    for camera, length in zip(others, lengths):
        if length < 1e-9:
            raise CadeError(f"camera {camera.name} sits at the reference camera's position: no baseline to match "
                            "along; check its position (or t) in the rig")
    return ArrayGeometry(cameras[rig.reference], others, min(lengths))


def _plane_camera(camera: Camera, baseline: np.ndarray) -> ArrayCamera:
    mapping: PlaneMapping = camera.to_reference
    try:
        inverse = np.linalg.inv(mapping.homography)
    except np.linalg.LinAlgError:
        raise CadeError(f"camera {camera.name}: its to_reference {mapping.kind} cannot be inverted") from None
    return ArrayCamera(camera.name, camera.band, camera.image_size, baseline, homography=inverse)


def _centre(camera: Camera) -> np.ndarray:
    """(x, y) of the camera's centre in the reference frame, metres."""
    return (-np.asarray(camera.R).T @ np.asarray(camera.t, np.float64))[:2]


def _calibrated_camera(camera: Camera, baseline: np.ndarray, K_reference: np.ndarray) -> ArrayCamera:
    return ArrayCamera(camera.name, camera.band, camera.image_size, baseline, K=np.asarray(camera.K, np.float64),
                       dist=camera.distortion, rotation=np.asarray(camera.R, np.float64), K_reference=K_reference)


@dataclass(frozen=True)
class BaselineFrame:
    """A rotation of the reference view that turns one baseline direction into +x.

    Attributes:
        matrix: (2, 3) float64, reference px (x, y) -> frame px.
        size: (width, height) of the frame, large enough to hold the whole view.
        exact: True for multiples of 90 degrees (resampling is a copy).
    """

    matrix: np.ndarray
    size: tuple[int, int]
    exact: bool

    def to_frame(self, image: np.ndarray) -> np.ndarray:
        """``image`` (H, W) of the reference view, turned into the frame; what lies outside
        the view is filled by reflection (texture for the matcher, never scored)."""
        flags = cv2.INTER_NEAREST if self.exact else cv2.INTER_LINEAR
        return cv2.warpAffine(np.asarray(image, np.float32), self.matrix, self.size, flags=flags,
                              borderMode=cv2.BORDER_REFLECT)

    def from_frame(self, values: np.ndarray, valid: np.ndarray,
                   shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """A frame map (NaN where not ``valid``) back in the reference view of ``shape``:
        (values, valid), values averaged over valid neighbours only."""
        return _resample_masked(values, valid, shape, lambda image, flags: cv2.warpAffine(
            image, self.matrix, (shape[1], shape[0]), flags=flags | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT, borderValue=0), exact=self.exact)


def baseline_frame(direction: np.ndarray, shape: tuple[int, int]) -> BaselineFrame:
    """The :class:`BaselineFrame` turning ``direction`` (2,) (x right, y down) into +x for a
    view of ``shape`` (H, W)."""
    angle = math.atan2(float(direction[1]), float(direction[0]))
    cos, sin = math.cos(angle), math.sin(angle)
    quarter = abs(angle / (math.pi / 2) - round(angle / (math.pi / 2))) < 1e-9
    if quarter:
        cos, sin = float(round(cos)), float(round(sin))
    rotation = np.array([[cos, sin], [-sin, cos]])  # R(-angle): the direction -> (1, 0)
    height, width = shape
    corners = rotation @ np.array([[0, width - 1, 0, width - 1], [0, 0, height - 1, height - 1]], np.float64)
    low, high = corners.min(axis=1), corners.max(axis=1)
    if quarter:
        low, high = np.rint(low), np.rint(high)
    size = (int(math.ceil(high[0] - low[0])) + 1, int(math.ceil(high[1] - low[1])) + 1)
    return BaselineFrame(np.hstack([rotation, -low[:, None]]), size, quarter)


def _resample_masked(values, valid, shape, warp, *, exact: bool) -> tuple[np.ndarray, np.ndarray]:
    """Resample a map with holes: the interpolation only averages valid samples, and a
    pixel is valid where its nearest sample is."""
    valid = np.asarray(valid, bool) & np.isfinite(values)
    if exact:
        moved = warp(np.where(valid, values, 0).astype(np.float32), cv2.INTER_NEAREST)
        kept = warp(valid.astype(np.uint8), cv2.INTER_NEAREST).astype(bool)
        return np.where(kept, moved, np.float32(np.nan)).astype(np.float32), kept
    weighted = warp(np.where(valid, values, 0).astype(np.float32), cv2.INTER_LINEAR)
    weight = warp(valid.astype(np.float32), cv2.INTER_LINEAR)
    kept = warp(valid.astype(np.uint8), cv2.INTER_NEAREST).astype(bool) & (weight > 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = np.where(kept, weighted / weight, np.float32(np.nan))
    return moved.astype(np.float32), kept


def _resize_masked(values: np.ndarray, valid: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Bring a map with holes to ``shape`` (H, W); the values are not rescaled."""
    if values.shape == tuple(shape):
        return values, valid
    size = (shape[1], shape[0])
    return _resample_masked(values, valid, shape, lambda image, flags: cv2.resize(image, size, interpolation=flags),
                            exact=False)


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
    search: tuple[float, float] = DEFAULT_SEARCH,
    scale: float = 1.0,
    method: str = DEFAULT_METHOD,
    preprocess: str = DEFAULT_PREPROCESS,
    model: str | None = None,
) -> np.ndarray:
    """One camera's estimate of the reference view's disparity, px per unit baseline.

    Both views (the reference and the camera warped onto the reference plane, where
    ``inside``) are scaled by ``scale``, turned so that the camera's baseline is +x
    (:func:`baseline_frame`) and matched with :func:`~cade_cli.stereo.estimate_disparity`
    over ``search`` (px per unit baseline, times the baseline ratio: signed). The map is
    turned back, brought to full size and divided by the baseline ratio.

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
    low = math.floor(search[0] * ratio * scale)
    high = max(low + 1, math.ceil(search[1] * ratio * scale))
    result = estimate_disparity(frame.to_frame(reference_s), frame.to_frame(warped_s), method=method,
                                max_disp=high, min_disp=low, preprocess=preprocess, model=model)
    # An estimate at an end of the range is clipped there, not measured (flat sky, a range too small).
    measured = result.valid & (result.disparity > low + BOUND_MARGIN) & (result.disparity < high - BOUND_MARGIN)
    disparity, valid = frame.from_frame(result.disparity, measured, reference_s.shape)
    disparity, valid = _resize_masked(disparity, valid, shape)
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
    search: tuple[float, float] = DEFAULT_SEARCH,
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
            searches it times its baseline ratio.
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
    if not search[0] < search[1]:
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


@dataclass(frozen=True)
class ArrayCube:
    """A cube TIFF read back: the reference band, each registered band and its validity.

    Attributes:
        reference: (H, W) float32.
        registered, valid: per camera, (H, W) float32 and (H, W) bool.
        reference_name: the reference camera's name; cameras: the others' names;
        bands: the band name of the reference then of each camera (from the rig).
        description: the whole JSON description.
    """

    reference: np.ndarray
    registered: tuple[np.ndarray, ...]
    valid: tuple[np.ndarray, ...]
    reference_name: str
    cameras: tuple[str, ...]
    bands: tuple[str, ...]
    description: dict


def cube_band_names(registration: ArrayRegistration) -> list[str]:
    """Names of the cube's 2N + 1 bands: the reference's band, each camera's band, then
    ``valid:<band>`` per camera (a band name two cameras share gets ``@<camera>``)."""
    cameras = (registration.reference_camera, *registration.cameras)
    bands = [camera.band for camera in cameras]
    names = [band if bands.count(band) == 1 else f"{band}@{camera.name}" for band, camera in zip(bands, cameras)]
    return names + [f"valid:{name}" for name in names[1:]]


def array_cube(registration: ArrayRegistration, *, details: dict | None = None) -> ArrayCube:
    """The :class:`ArrayCube` of ``registration``: what :func:`write_array_cube` writes.

    The description holds ``format`` (:data:`CUBE_FORMAT`), ``bands`` (names,
    :func:`cube_band_names`), ``reference``, ``cameras``, ``band_of`` (camera -> band),
    ``disparity_unit_baseline_m`` and then ``details`` (method, range, ...).
    """
    names = cube_band_names(registration)
    description = {
        "format": CUBE_FORMAT, "version": 1, "bands": names,
        "reference": registration.reference_camera.name,
        "cameras": [camera.name for camera in registration.cameras],
        "band_of": {c.name: c.band for c in (registration.reference_camera, *registration.cameras)},
        "disparity_unit_baseline_m": registration.unit, **(details or {}),
    }
    return ArrayCube(registration.reference, registration.registered, registration.valid,
                     registration.reference_camera.name, tuple(description["cameras"]),
                     tuple(names[:1 + len(registration.cameras)]), description)


def write_array_cube(path: Path, cube: ArrayCube | ArrayRegistration, *, details: dict | None = None) -> None:
    """Write a cube (or the :func:`array_cube` of a registration, with ``details``) to
    ``path`` atomically as a planar float32 TIFF.

    Bands: the reference, each registered band (rig order), then one validity band per
    camera (1.0 = seen, 0.0 = outside its image, occluded or without a vote); the
    description is the cube's, as JSON.
    """
    if isinstance(cube, ArrayRegistration):
        cube = array_cube(cube, details=details)
    stack = np.stack([cube.reference, *cube.registered, *(v.astype(np.float32) for v in cube.valid)]).astype(np.float32)
    with atomic_output(Path(path)) as temporary:
        tifffile.imwrite(temporary, stack, photometric="minisblack", planarconfig="separate",
                         description=json.dumps(cube.description), metadata=None)


def read_array_cube(path: Path) -> ArrayCube:
    """Read a cube :func:`write_array_cube` wrote.

    Raises:
        CadeError: not a TIFF, or a TIFF without the cube's description or band count.
    """
    path = check_input_file(Path(path), suffixes=(".tif", ".tiff"))
    try:
        with tifffile.TiffFile(path) as tiff:
            text = tiff.pages[0].description
    except (tifffile.TiffFileError, OSError, ValueError) as exc:
        raise CadeError(f"cannot read {path} as a TIFF ({type(exc).__name__}); "
                        "give a cube `cade register-array` wrote") from None
    try:
        description = json.loads(text)
    except (json.JSONDecodeError, TypeError):
        description = None
    if not isinstance(description, dict) or description.get("format") != CUBE_FORMAT:
        raise CadeError(f"{path} is not an array cube (its TIFF description is not a {CUBE_FORMAT}); "
                        "give a cube `cade register-array` wrote")
    stack = read_tiff_array(path)
    cameras = tuple(description["cameras"])
    count = 1 + 2 * len(cameras)
    if stack.ndim != 3 or count not in (stack.shape[0], stack.shape[-1]):
        raise CadeError(f"{path} holds an array of shape {stack.shape}, not the {count} bands its description names")
    if stack.shape[0] != count:
        stack = np.moveaxis(stack, -1, 0)
    stack = stack.astype(np.float32)
    n = len(cameras)
    return ArrayCube(stack[0], tuple(stack[1:1 + n]), tuple(stack[1 + n:] > 0.5), description["reference"], cameras,
                     tuple(description["bands"][:1 + n]), description)


# --- judging a registration without ground truth --------------------------------------------------------------------

SCORE_WINDOW = 15
"""Side, px, of the windows :func:`gradient_correlation` correlates gradients in."""


def _gradients(band: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    band = np.asarray(band, np.float32)
    return cv2.Sobel(band, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(band, cv2.CV_32F, 0, 1, ksize=3)


def gradient_correlation(reference: np.ndarray, band: np.ndarray, valid: np.ndarray, *,
                         window: int = SCORE_WINDOW) -> float:
    """Mean local normalised gradient correlation of two registered bands, in [0, 1].

    In every ``window`` x ``window`` neighbourhood, ``|sum g_ref . g_band| / sqrt(sum
    |g_ref|^2 sum |g_band|^2)`` (3x3 Sobel gradients): 1 where the edges of both bands
    coincide, whatever their contrast or its sign (a filter may invert it), near 0 where
    they are displaced. Averaged over the pixels whose whole window is ``valid`` and has
    gradient in both bands (the 20 % least textured of those are left out: flat sky and
    walls carry no alignment information).

    Raises:
        CadeError: bands of different shapes or no pixel to score.
    """
    reference, band = np.asarray(reference, np.float32), np.asarray(band, np.float32)
    if reference.shape != band.shape or np.shape(valid) != reference.shape:
        raise CadeError(f"bands {reference.shape}, {band.shape} and mask {np.shape(valid)} differ in shape")
    usable = np.asarray(valid, bool) & np.isfinite(reference) & np.isfinite(band)
    rx, ry = _gradients(np.where(usable, reference, 0))
    bx, by = _gradients(np.where(usable, band, 0))
    box = lambda image: cv2.boxFilter(image, cv2.CV_32F, (window, window), normalize=False)  # noqa: E731
    cross = box(rx * bx + ry * by)
    energy = box(rx * rx + ry * ry) * box(bx * bx + by * by)
    whole = cv2.erode(usable.astype(np.uint8), np.ones((window + 2, window + 2), np.uint8),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    scored = whole & (energy > 0)
    if not scored.any():
        raise CadeError("no pixel to score: the bands share no valid, textured area")
    textured = energy[scored] >= np.quantile(energy[scored], 0.2)
    local = np.abs(cross[scored]) / np.sqrt(energy[scored])
    return float(local[textured].mean())


def mutual_information(reference: np.ndarray, band: np.ndarray, valid: np.ndarray, *, bins: int = 64) -> float:
    """Mutual information of two bands over ``valid`` pixels, bits (each band's values
    binned between its 0.5 and 99.5 percentiles)."""
    usable = np.asarray(valid, bool) & np.isfinite(reference) & np.isfinite(band)
    if not usable.any():
        raise CadeError("no pixel to score: the bands share no valid area")
    a, b = np.asarray(reference)[usable], np.asarray(band)[usable]
    edges = [np.linspace(*np.percentile(v, [0.5, 99.5]), bins + 1) for v in (a, b)]
    joint, _, _ = np.histogram2d(np.clip(a, edges[0][0], edges[0][-1]), np.clip(b, edges[1][0], edges[1][-1]),
                                 bins=edges)
    joint /= joint.sum()
    pa, pb = joint.sum(axis=1, keepdims=True), joint.sum(axis=0, keepdims=True)
    nonzero = joint > 0
    return float((joint[nonzero] * np.log2(joint[nonzero] / (pa @ pb)[nonzero])).sum())


@dataclass(frozen=True)
class AlignmentScore:
    """One camera of one cube scored against the reference band."""

    camera: str
    band: str
    gradient_correlation: float
    mutual_information: float
    scored_share: float


def score_cubes(cubes: Sequence[ArrayCube], *, window: int = SCORE_WINDOW) -> list[list[AlignmentScore]]:
    """Score each camera of each cube over the pixels valid in *every* cube, so that
    registrations of one array are compared on the same pixels.

    Returns:
        per cube, per camera: :class:`AlignmentScore`.

    Raises:
        CadeError: cubes of different cameras or sizes.
    """
    first = cubes[0]
    for cube in cubes[1:]:
        if cube.cameras != first.cameras or cube.reference.shape != first.reference.shape:
            raise CadeError("the cubes hold different cameras or sizes; score cubes of one array together")
    scores: list[list[AlignmentScore]] = [[] for _ in cubes]
    for i, camera in enumerate(first.cameras):
        common = np.logical_and.reduce([cube.valid[i] for cube in cubes])
        for cube, row in zip(cubes, scores):
            row.append(AlignmentScore(
                camera, cube.bands[1 + i],
                gradient_correlation(cube.reference, cube.registered[i], common, window=window),
                mutual_information(cube.reference, cube.registered[i], common), float(common.mean())))
    return scores


def false_colour(cube: ArrayCube, channels: Sequence[str]) -> np.ndarray:
    """An (H, W, 3) uint8 B, G, R picture of three bands of ``cube`` (red, green, blue in the
    order of ``channels``, camera names), each stretched between its 1st and 99th
    percentile; pixels invalid in a shown band are black. Misregistration shows as colour
    fringes along edges."""
    index = {cube.reference_name: None, **{name: i for i, name in enumerate(cube.cameras)}}
    planes = []
    shown = np.ones(cube.reference.shape, bool)
    for name in channels:
        if name not in index:
            raise CadeError(f"the cube has no camera {name!r}; its cameras are {', '.join(index)}")
        i = index[name]
        band = cube.reference if i is None else cube.registered[i]
        if i is not None:
            shown &= cube.valid[i]
        low, high = np.percentile(band[np.isfinite(band)], [1, 99])
        planes.append(np.clip((band - low) / max(high - low, 1e-6), 0, 1))
    picture = np.rint(np.stack(planes[::-1], axis=2) * 255).astype(np.uint8)
    picture[~shown] = 0
    return picture


# --- plane-registered rigs from point matches ----------------------------------------------------------------------


def plane_mapping_from_points(points: np.ndarray, reference_points: np.ndarray, *,
                              kind: str = "affine") -> tuple[PlaneMapping, float]:
    """Fit a camera's ``to_reference`` from matching points (N, 2) of that camera and of
    the reference (least squares over all points, N >= 3 for an affine, 4 for a homography).

    Returns:
        (the mapping, RMS residual in reference px).
    """
    points, reference_points = np.asarray(points, np.float64), np.asarray(reference_points, np.float64)
    if points.shape != reference_points.shape or points.ndim != 2 or points.shape[1] != 2:
        raise CadeError(f"point matches must be two (N, 2) arrays of one shape, got {points.shape} and "
                        f"{reference_points.shape}")
    needed = 3 if kind == "affine" else 4
    if len(points) < needed:
        raise CadeError(f"a {kind} needs at least {needed} point matches, got {len(points)}")
    ones = np.ones((len(points), 1))
    if kind == "affine":
        solution, *_ = np.linalg.lstsq(np.hstack([points, ones]), reference_points, rcond=None)
        matrix = solution.T
        mapped = points @ matrix[:, :2].T + matrix[:, 2]
    elif kind == "homography":
        matrix, _ = cv2.findHomography(points, reference_points, 0)
        if matrix is None:
            raise CadeError("the point matches do not determine a homography (collinear points?)")
        mapped = cv2.perspectiveTransform(points[:, None], matrix)[:, 0]
    else:
        raise CadeError(f"unknown mapping kind {kind!r}; choose affine or homography")
    rms = float(np.sqrt(np.mean(np.sum((mapped - reference_points) ** 2, axis=1))))
    return PlaneMapping(kind, matrix), rms
