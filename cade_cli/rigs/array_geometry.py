"""An array's geometry: where each camera sits relative to the reference (its baseline, in the
reference image's axes), how its pixels map onto the reference plane (a plane mapping, or
undistortion and rotation of a calibrated camera), the frame that turns a baseline into a
matcher's +x (:class:`BaselineFrame`) and the masked resampling it uses; the plane mapping
fitted to point pairs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.rigs.rig import Camera, PlaneMapping, Rig


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


def resize_masked(values: np.ndarray, valid: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Bring a map with holes to ``shape`` (H, W); the values are not rescaled."""
    if values.shape == tuple(shape):
        return values, valid
    size = (shape[1], shape[0])
    return _resample_masked(values, valid, shape, lambda image, flags: cv2.resize(image, size, interpolation=flags),
                            exact=False)


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
