"""The lens models of drone multispectral cameras, as their files describe them: Brown–Conrady
(MicaSense ``perspective``) and Parrot's fisheye polynomial (Sequoia ``fisheye``), each mapping
normalised pinhole rays to raw pixels and back; and the lens rotations (``RigRelatives``).

A ray is (X, Y, 1) in the camera's own axes (x right, y down, z forward); its *normalised
coordinates* are (X, Y). Every map works on float64 arrays of any equal shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class BrownLens:
    """A perspective lens with Brown–Conrady distortion (OpenCV's model).

    Attributes:
        focal: focal length, px (square pixels).
        centre: (cx, cy) principal point, px of the raw image.
        k1, k2, k3: radial coefficients; p1, p2: tangential (OpenCV's ``p1``, ``p2``).
        focal_y: the vertical focal length, px, where it differs from ``focal`` (DJI's
            ``DewarpData`` gives fx and fy); None: square pixels.
    """

    focal: float
    centre: tuple[float, float]
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    focal_y: float | None = None

    kind = "perspective"

    @property
    def fy(self) -> float:
        return self.focal if self.focal_y is None else self.focal_y

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix."""
        return np.array([[self.focal, 0, self.centre[0]], [0, self.fy, self.centre[1]], [0, 0, 1]], np.float64)

    @property
    def dist(self) -> np.ndarray:
        """OpenCV distortion coefficients (k1, k2, p1, p2, k3)."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3], np.float64)

    def pixels(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw pixels (u, v) of normalised coordinates (x, y)."""
        r2 = x * x + y * y
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * radial + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return self.focal * xd + self.centre[0], self.fy * yd + self.centre[1]

    def rays(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised coordinates (x, y) of raw pixels (u, v) (iterative inverse, to 1e-9)."""
        points = np.stack([np.ravel(u), np.ravel(v)], axis=1).reshape(-1, 1, 2).astype(np.float64)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9)
        undistorted = cv2.undistortPoints(points, self.K, self.dist, None, None, criteria=criteria)
        return undistorted[:, 0, 0].reshape(np.shape(u)), undistorted[:, 0, 1].reshape(np.shape(u))


@dataclass(frozen=True)
class FisheyeLens:
    """Parrot's fisheye model (Sequoia): for a ray (X, Y, 1), r = sqrt(X² + Y²),
    θ = (2/π)·atan(r), ρ = p0 + p1·θ + p2·θ² + p3·θ³ and the raw pixel is
    ``[C D; E F]·(ρ·X/r, ρ·Y/r) + (cx, cy)``.

    Attributes:
        focal: the pinhole focal length, px (EXIF FocalLength): only the scale of the
            pinhole frame the capture is registered in.
        centre: (cx, cy), px; polynomial: (p0, p1, p2, p3); affine: (C, D, E, F), px.
    """

    focal: float
    centre: tuple[float, float]
    polynomial: tuple[float, float, float, float]
    affine: tuple[float, float, float, float]

    kind = "fisheye"

    def pixels(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw pixels (u, v) of normalised coordinates (x, y)."""
        r = np.hypot(x, y)
        theta = (2 / np.pi) * np.arctan(r)
        p0, p1, p2, p3 = self.polynomial
        rho = p0 + theta * (p1 + theta * (p2 + theta * p3))
        scale = np.where(r > 1e-9, rho / np.maximum(r, 1e-9), p1 * 2 / np.pi)  # rho / r -> p1 (2/pi) at r = 0
        a, b = x * scale, y * scale
        c, d, e, f = self.affine
        return c * a + d * b + self.centre[0], e * a + f * b + self.centre[1]

    def rays(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised coordinates (x, y) of raw pixels (u, v) (Newton on θ)."""
        c, d, e, f = self.affine
        inverse = np.linalg.inv(np.array([[c, d], [e, f]], np.float64))
        du, dv = np.asarray(u, np.float64) - self.centre[0], np.asarray(v, np.float64) - self.centre[1]
        a, b = inverse[0, 0] * du + inverse[0, 1] * dv, inverse[1, 0] * du + inverse[1, 1] * dv
        rho = np.hypot(a, b)
        p0, p1, p2, p3 = self.polynomial
        theta = np.clip((rho - p0) / p1, 0, 0.999) if p1 else np.zeros_like(rho)
        for _ in range(20):
            value = p0 + theta * (p1 + theta * (p2 + theta * p3)) - rho
            slope = p1 + theta * (2 * p2 + 3 * p3 * theta)
            theta = np.clip(theta - value / np.where(np.abs(slope) > 1e-12, slope, 1e-12), 0, 0.999)
        r = np.tan(theta * np.pi / 2)
        scale = np.where(rho > 1e-12, r / np.maximum(rho, 1e-12), np.pi / 2 / p1 if p1 else 0.0)
        return a * scale, b * scale


Lens = BrownLens | FisheyeLens


def rig_relatives_rotation(angles_deg) -> np.ndarray:
    """The rotation of a band's camera from its ``RigRelatives`` angles (a, b, c), degrees:
    ``Rx(a) · Ry(b) · Rz(c)``, as the vendor's library builds it; (3, 3) float64."""
    a, b, c = np.radians(np.asarray(angles_deg, np.float64))
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz
