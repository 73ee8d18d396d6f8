"""A rig: which cameras it has, how they are calibrated and how to rectify them.

A rig is a set of cameras, one of them the *reference*, each seeing one band: each camera
has either a full calibration (intrinsics, distortion and its pose relative to the
reference camera) or a plane registration onto the reference image (camera arrays). Its
file, JSON, is read and written by :mod:`cade_cli.rigs.rig_file` (docs/rigs.md, "The rig
file").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cade_cli.errors import CadeError


PLANE_MAPPINGS = ("affine", "homography")
"""The kinds of ``to_reference`` mapping: a 2x3 affine or a 3x3 homography."""


@dataclass(frozen=True)
class PlaneMapping:
    """A camera's pixels mapped onto the reference image (a plane-registered array).

    Attributes:
        kind: ``"affine"`` (``matrix`` 2x3) or ``"homography"`` (``matrix`` 3x3); both
            map (x, y) of this camera to (x, y) of the reference image.
        matrix: float64, (2, 3) or (3, 3).
    """

    kind: str
    matrix: np.ndarray

    @property
    def homography(self) -> np.ndarray:
        """The mapping as a (3, 3) float64 homography."""
        if self.kind == "affine":
            return np.vstack([self.matrix, [0.0, 0.0, 1.0]])
        return np.array(self.matrix, np.float64)


@dataclass(frozen=True)
class Camera:
    """One camera of a rig.

    Attributes:
        name: unique within the rig.
        band: what the camera sees, free text (``"bp400"``, ``"nir"``, ``"rgb"``).
        image_size: (width, height) of its images, px.
        K: (3, 3) intrinsic matrix, px; None without a full calibration.
        dist: OpenCV distortion coefficients (k1, k2, p1, p2[, k3, ...]), float64 (N,).
        R, t: pose relative to the reference camera, ``X_cam = R @ X_ref + t``: (3, 3)
            rotation and (3,) translation in metres (identity and zero for the reference).
        to_reference: plane registration onto the reference image, for arrays without a
            full calibration.
        position: (x, y) position in the array plane, metres, along the reference image's
            axes (x to the right, y down), with ``to_reference``.
    """

    name: str
    band: str
    image_size: tuple[int, int]
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    to_reference: PlaneMapping | None = None
    position: tuple[float, float] | None = None

    @property
    def calibrated(self) -> bool:
        """True when the camera has intrinsics and a pose (K, R, t)."""
        return self.K is not None and self.R is not None and self.t is not None

    @property
    def distortion(self) -> np.ndarray:
        """``dist`` as float64, zeros (no distortion) when it is not given."""
        return np.zeros(5) if self.dist is None else np.asarray(self.dist, np.float64)


@dataclass(frozen=True)
class Calibration:
    """How a rig was calibrated (informative; nothing downstream depends on it).

    Attributes:
        board: the target, e.g. ``{"type": "chessboard", "inner_corners": [9, 6],
            "square": 0.025}`` or ``{"type": "charuco", "squares": [11, 8], "square":
            0.03, "marker": 0.022, "dictionary": "DICT_5X5_100"}``.
        rms: RMS reprojection error of the final stereo calibration, px (with more than two
            cameras, the largest over the pairs of the reference with another camera).
        camera_rms: camera name -> RMS of its own (intrinsic) calibration, px.
        views: one entry per view used: ``{"files": {camera: path}, "errors": {camera: px}}``.
        rejected: one entry per view left out: ``{"files": {camera: path}, "reason": text}``.
    """

    board: dict[str, Any]
    rms: float
    camera_rms: dict[str, float] = field(default_factory=dict)
    views: list[dict[str, Any]] = field(default_factory=list)
    rejected: list[dict[str, Any]] = field(default_factory=list)


@dataclass(frozen=True)
class Rectification:
    """OpenCV ``stereoRectify`` output for the reference camera and one other.

    Attributes:
        cameras: (reference name, other name): the rectified left and right view.
        image_size: (width, height) of the rectified images, px.
        R1, R2: (3, 3) rectifying rotations of the two cameras.
        P1, P2: (3, 4) projections in the rectified frame (``P2[0, 3] = -f * baseline``
            when the baseline is horizontal).
        Q: (4, 4) disparity-to-depth matrix (``cv2.reprojectImageTo3D``).
    """

    cameras: tuple[str, str]
    image_size: tuple[int, int]
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray

    @property
    def focal(self) -> float:
        """Focal length of the rectified pair, px."""
        return float(self.P1[0, 0])

    @property
    def baseline(self) -> float:
        """Distance between the two rectified optical centres, metres (positive)."""
        return float(abs(self.P2[0, 3] / self.P2[0, 0])) if self.P2[0, 3] != 0 else float(abs(self.P2[1, 3] / self.P2[1, 1]))


@dataclass(frozen=True)
class Rig:
    """A rig: its cameras, the reference among them, and optionally how they were
    calibrated and how the reference pair is rectified."""

    reference: str
    cameras: tuple[Camera, ...]
    calibration: Calibration | None = None
    rectification: Rectification | None = None

    def camera(self, name: str) -> Camera:
        """The camera called ``name``; CadeError listing the rig's cameras otherwise."""
        for camera in self.cameras:
            if camera.name == name:
                return camera
        raise CadeError(f"the rig has no camera {name!r}; its cameras are {', '.join(c.name for c in self.cameras)}")

    @property
    def reference_camera(self) -> Camera:
        return self.camera(self.reference)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(camera.name for camera in self.cameras)


