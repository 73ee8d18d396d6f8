"""Synthetic drone multispectral captures for the register-capture tests: five band cameras
with known rotations, baselines and Brown distortion looking down at a textured height map,
rendered with OpenCV's own lens model and written as band TIFFs carrying the XMP tags of a
MicaSense RedEdge (the true correspondence of every reference pixel kept for scoring).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import tifffile

PIXELS_PER_MM = 266.666667
BLACK_LEVEL = 4800


@dataclass(frozen=True)
class BandCamera:
    name: str
    wavelength: float
    index: int
    angles: tuple[float, float, float]  # RigRelatives, degrees
    translation: tuple[float, float, float]  # metres, X_band = R X_ref + t
    dist: tuple[float, float, float, float, float]  # k1, k2, k3, p1, p2 (the XMP order)
    focal: float
    centre: tuple[float, float]

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.focal, 0, self.centre[0]], [0, self.focal, self.centre[1]], [0, 0, 1]])

    @property
    def opencv_dist(self) -> np.ndarray:
        k1, k2, k3, p1, p2 = self.dist
        return np.array([k1, k2, p1, p2, k3])

    @property
    def R(self) -> np.ndarray:
        """Reference -> band rotation: the vendor builds Rx(a) Ry(b) Rz(c) for band -> reference."""
        a, b, c = np.radians(self.angles)
        rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
        rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
        return (rx @ ry @ rz).T


def rededge_like(size: tuple[int, int], *, baseline: float = 0.04) -> list[BandCamera]:
    """Five cameras in a RedEdge's order (Blue, Green, Red, NIR, Red edge), Green the reference."""
    width, height = size
    f = 1.25 * width
    cx, cy = width / 2, height / 2
    b = baseline
    return [
        BandCamera("Blue", 475, 0, (0.3, -0.2, 0.4), (b, 0, 0), (-0.10, 0.15, -0.05, 4e-4, -3e-4), f * 1.004,
                   (cx + 3, cy - 2)),
        BandCamera("Green", 560, 1, (0.0, 0.0, 0.0), (0, 0, 0), (-0.11, 0.18, -0.10, -2e-4, 5e-4), f, (cx, cy)),
        BandCamera("Red", 668, 2, (-0.25, 0.15, -0.3), (0, b, 0), (-0.09, 0.12, -0.02, 3e-4, 2e-4), f * 0.997,
                   (cx - 4, cy + 3)),
        BandCamera("NIR", 840, 3, (0.1, 0.3, 0.2), (b, b, 0), (-0.12, 0.20, -0.12, -3e-4, -1e-4), f * 1.002,
                   (cx + 2, cy + 4)),
        BandCamera("Red edge", 717, 4, (-0.2, -0.1, 0.1), (-b, 0, 0), (-0.10, 0.16, -0.06, 1e-4, 3e-4), f * 0.999,
                   (cx - 2, cy - 3)),
    ]


@dataclass(frozen=True)
class Terrain:
    """Depth below the reference camera (m) as a function of ground (X, Y): a plane at
    ``depth`` with a smooth hill ``hill`` m high; textured over ``extent`` m each way."""

    depth: float
    hill: float
    texture: np.ndarray

    @property
    def extent(self) -> float:
        return 0.9 * self.depth

    def z(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        sigma = 0.15 * self.depth
        return self.depth - self.hill * np.exp(-((x - 0.05 * self.depth) ** 2 + (y - 0.03 * self.depth) ** 2)
                                               / (2 * sigma**2))

    def shade(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        n = self.texture.shape[0]
        tx = ((x / self.extent + 1) / 2 * (n - 1)).astype(np.float32)
        ty = ((y / self.extent + 1) / 2 * (n - 1)).astype(np.float32)
        return cv2.remap(self.texture, tx, ty, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def make_terrain(rng: np.random.Generator, *, depth: float, hill: float, cells: int = 1024) -> Terrain:
    """A multi-scale random texture in [0, 1] on the ground."""
    texture = np.zeros((cells, cells), np.float32)
    for sigma, weight in ((1.2, 0.5), (4.0, 0.3), (16.0, 0.2)):
        layer = cv2.GaussianBlur(rng.random((cells, cells)).astype(np.float32), (0, 0), sigma)
        layer = (layer - layer.mean()) / (layer.std() + 1e-9)
        texture += weight * layer
    texture = (texture - texture.min()) / (texture.max() - texture.min())
    return Terrain(depth, hill, texture)


def surface_points(terrain: Terrain, camera: BandCamera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) ground points (reference axes) seen at band pixels (u, v) of ``camera``."""
    pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2).astype(np.float64)
    normalised = cv2.undistortPoints(pts, camera.K, camera.opencv_dist,
                                     criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10))
    rays = np.concatenate([normalised[:, 0, :], np.ones((len(pts), 1))], axis=1) @ camera.R  # R^T d, as rows
    centre = -camera.R.T @ np.asarray(camera.translation)
    s = (terrain.depth - centre[2]) / rays[:, 2]
    for _ in range(12):
        points = centre + s[:, None] * rays
        s = (terrain.z(points[:, 0], points[:, 1]) - centre[2]) / rays[:, 2]
    return centre + s[:, None] * rays


def project(camera: BandCamera, points: np.ndarray) -> np.ndarray:
    """(N, 2) band pixels of reference-axes points."""
    in_band = points @ camera.R.T + np.asarray(camera.translation)
    pixels, _ = cv2.projectPoints(in_band.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.K,
                                  camera.opencv_dist)
    return pixels[:, 0, :]


RESPONSES = {"Blue": lambda t: 0.2 + 0.5 * t**1.3, "Green": lambda t: 0.1 + 0.8 * t,
             "Red": lambda t: 0.15 + 0.6 * np.sqrt(t), "NIR": lambda t: 0.9 - 0.7 * t,
             "Red edge": lambda t: 0.3 + 0.4 * t}
"""Each band's response to the ground's texture (NIR inverted: a cross-spectral capture)."""


def xmp(camera: BandCamera, *, capture_id: str, drop: str | None = None, panel: bool = False) -> bytes:
    """An XMP packet in MicaSense's element form; ``drop``: a tag left out; ``panel``: tagged as a
    calibration target (``Camera:CalibrationPicture`` 2, as Pix4D documents it)."""
    f_mm = camera.focal / PIXELS_PER_MM
    cx, cy = (c / PIXELS_PER_MM for c in camera.centre)
    seq = "".join(f"<rdf:li>{value!r}</rdf:li>" for value in camera.dist)
    fields = {
        "Camera:BandName": camera.name, "Camera:CentralWavelength": f"{camera.wavelength:g}",
        "Camera:WavelengthFWHM": "10", "Camera:ModelType": "perspective",
        "Camera:PrincipalPoint": f"{cx!r},{cy!r}", "Camera:PerspectiveFocalLength": repr(f_mm),
        "Camera:PerspectiveFocalLengthUnits": "mm", "Camera:PerspectiveDistortion": f"<rdf:Seq>{seq}</rdf:Seq>",
        "Camera:RigRelatives": ", ".join(repr(a) for a in camera.angles), "Camera:RigCameraIndex": str(camera.index),
        "MicaSense:CaptureId": capture_id,
    }
    if panel:
        fields["Camera:CalibrationPicture"] = "2"
    body = "".join(f"<{key}>{value}</{key}>" for key, value in fields.items() if key != drop)
    return ('<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/">'
            '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about="" '
            'xmlns:Camera="http://pix4d.com/camera/1.0" xmlns:MicaSense="http://micasense.com/MicaSense/1.0/">'
            f'{body}</rdf:Description></rdf:RDF></x:xmpmeta><?xpacket end="w"?>').encode()


@dataclass(frozen=True)
class SyntheticCapture:
    paths: list[Path]
    cameras: list[BandCamera]
    truth: dict[str, tuple[np.ndarray, np.ndarray]]
    """Per band: (u, v) (H, W) where each reference raw pixel's ground point is in that band."""


def write_capture(folder: Path, rng: np.random.Generator, *, size: tuple[int, int] = (320, 240), depth: float = 1.5,
                  hill: float = 0.3, drop: tuple[str, str] | None = None, saturate: bool = False,
                  name: str = "IMG_0001", capture_id: str = "SYNTHETIC01", panel: bool = False) -> SyntheticCapture:
    """Render and write ``<name>_{1..5}.tif`` in ``folder``; ``drop`` = (band, tag) leaves a tag out;
    ``panel`` tags the files as a calibration panel shot."""
    folder.mkdir(parents=True, exist_ok=True)
    width, height = size
    terrain = make_terrain(rng, depth=depth, hill=hill)
    cameras = rededge_like(size, baseline=0.04)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    reference = cameras[1]
    ground = surface_points(terrain, reference, u, v)
    paths, truth = [], {}
    for number, camera in enumerate(cameras, start=1):
        points = surface_points(terrain, camera, u, v)
        shade = RESPONSES[camera.name](terrain.shade(points[:, 0].reshape(height, width),
                                                     points[:, 1].reshape(height, width)))
        noise = rng.normal(0, 0.002, shade.shape)
        raw = BLACK_LEVEL + 16 * np.rint(np.clip(shade + noise, 0, 1) * 3800)
        if saturate:
            raw[:20, :20] = 65520
        raw = raw.astype(np.uint16)
        truth[camera.name] = tuple(project(camera, ground).T.reshape(2, height, width))
        path = folder / f"{name}_{number}.tif"
        tags = [(700, "B", 0, xmp(camera, capture_id=capture_id, drop=drop[1] if drop and drop[0] == camera.name
                                   else None, panel=panel), True),
                (271, "s", 0, "MicaSense", True), (272, "s", 0, "RedEdge-M", True),
                (37390, "2I", 1, (266666667, 1000000), True), (37392, "H", 1, 4, True),
                (50714, "H", 4, (BLACK_LEVEL,) * 4, True)]
        tifffile.imwrite(path, raw, photometric="minisblack", metadata=None, extratags=tags)
        paths.append(path)
    return SyntheticCapture(paths, cameras, truth)
