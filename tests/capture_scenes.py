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


# --- Other cameras (docs/drone.md, "Other cameras"): bands of other sizes (an Altum's or
# RedEdge-P's panchromatic and thermal bands), a RedEdge-MX Dual's second camera, DJI's tags.


def _rotation(angles) -> np.ndarray:
    a, b, c = np.radians(angles)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz


@dataclass(frozen=True)
class RigBand(BandCamera):
    """A band camera with its own image ``size`` and pixel pitch (``per_mm``, px/mm), whose
    written ``RigRelatives`` (``angles``) may refer to another camera body's reference band
    (``group_index``), itself turned by ``group`` (degrees, Rx Ry Rz, band -> rig reference)
    against the rig reference: the true rotation is ``group`` then ``angles``."""

    size: tuple[int, int] = (320, 240)
    per_mm: float = PIXELS_PER_MM
    group: tuple[float, float, float] = (0.0, 0.0, 0.0)
    group_index: int | None = None

    @property
    def R(self) -> np.ndarray:
        return (_rotation(self.group) @ _rotation(self.angles)).T


def altum_like(size: tuple[int, int], *, pan_scale: float = 2.0,
               thermal: tuple[int, int] = (160, 120)) -> list[RigBand]:
    """Blue, Green, Red (an Altum's first bands, ``size``), a panchromatic band at ``pan_scale``
    times their size and a thermal band of ``thermal`` px, each with its own lens and pitch."""
    width, height = size
    f = 1.25 * width
    base = rededge_like(size, baseline=0.04)[:3]
    bands = [RigBand(c.name, c.wavelength, c.index, c.angles, c.translation, c.dist, c.focal, c.centre, size=size)
             for c in base]
    pw, ph = round(width * pan_scale), round(height * pan_scale)
    bands.append(RigBand("Panchro", 634.5, 3, (0.2, 0.25, -0.35), (0.03, -0.02, 0), (-0.08, 0.1, -0.02, 2e-4, -1e-4),
                         f * pan_scale * 1.003, (pw / 2 + 5, ph / 2 - 4), size=(pw, ph),
                         per_mm=PIXELS_PER_MM * pan_scale))
    tw, th = thermal
    scale = tw / width
    bands.append(RigBand("LWIR", 11000, 4, (-0.4, 0.3, 0.25), (-0.03, 0.02, 0), (0.0, 0.0, 0.0, 0.0, 0.0),
                         f * scale * 0.98, (tw / 2 + 0.7, th / 2 - 0.4), size=(tw, th), per_mm=PIXELS_PER_MM * scale))
    return bands


def dual_like(size: tuple[int, int], *, group: tuple[float, float, float] = (0.6, -0.5, 0.9)) -> list[RigBand]:
    """A RedEdge-MX Dual: the five RedEdge bands, then Blue-444 .. Red edge-740 (rig indices 5-9)
    whose RigRelatives refer to Green-531 (index 6), that camera body turned by ``group``
    against Green and 6 cm away."""
    first = [RigBand(c.name, c.wavelength, c.index, c.angles, c.translation, c.dist, c.focal, c.centre, size=size,
                     group_index=1) for c in rededge_like(size, baseline=0.04)]
    second = []
    for band, (name, wavelength) in zip(rededge_like(size, baseline=0.04),
                                        (("Blue-444", 444), ("Green-531", 531), ("Red-650", 650),
                                         ("Red edge-705", 705), ("Red edge-740", 740))):
        angles = (0.0, 0.0, 0.0) if name == "Green-531" else tuple(-a for a in band.angles)
        translation = tuple(t + o for t, o in zip(band.translation, (0.0, 0.06, 0.0)))
        second.append(RigBand(name, wavelength, band.index + 5, angles, translation, band.dist, band.focal * 1.001,
                              band.centre, size=size, group=group, group_index=6))
    return first + second


def _response(name: str):
    known = RESPONSES.get(name) or RESPONSES.get(name.split("-")[0])
    return known or (lambda t: 0.15 + 0.7 * t)


def micasense_xmp(camera: RigBand, *, capture_id: str) -> bytes:
    """MicaSense's element-form tags of ``camera`` (its own pitch; the RigRelatives reference)."""
    f_mm = camera.focal / camera.per_mm
    cx, cy = (c / camera.per_mm for c in camera.centre)
    seq = "".join(f"<rdf:li>{value!r}</rdf:li>" for value in camera.dist)
    fields = {"Camera:BandName": camera.name, "Camera:CentralWavelength": f"{camera.wavelength:g}",
              "Camera:WavelengthFWHM": "10", "Camera:ModelType": "perspective",
              "Camera:PrincipalPoint": f"{cx!r},{cy!r}", "Camera:PerspectiveFocalLength": repr(f_mm),
              "Camera:PerspectiveFocalLengthUnits": "mm", "Camera:PerspectiveDistortion": f"<rdf:Seq>{seq}</rdf:Seq>",
              "Camera:RigRelatives": ", ".join(repr(a) for a in camera.angles),
              "Camera:RigCameraIndex": str(camera.index), "MicaSense:CaptureId": capture_id}
    if camera.group_index is not None:
        fields["Camera:RigRelativesReferenceRigCameraIndex"] = str(camera.group_index)
    body = "".join(f"<{key}>{value}</{key}>" for key, value in fields.items())
    return ('<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/">'
            '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about="" '
            'xmlns:Camera="http://pix4d.com/camera/1.0" xmlns:MicaSense="http://micasense.com/MicaSense/1.0/">'
            f'{body}</rdf:Description></rdf:RDF></x:xmpmeta><?xpacket end="w"?>').encode()


DJI_NAMES = {"Blue": ("Blue", 450, 16, 1), "Green": ("Green", 560, 16, 2), "Red": ("Red", 650, 16, 3),
             "Red edge": ("RedEdge", 730, 16, 4), "NIR": ("NIR", 840, 26, 5)}
"""The synthetic RedEdge-like bands under DJI's names, BandFreq and SensorIndex (P4 Multispectral)."""


def dji_xmp(camera: RigBand, *, capture_id: str, style: str, reference: RigBand) -> bytes:
    """DJI's attribute-form ``drone-dji`` tags of ``camera``: DewarpData (its (cx, cy) an offset
    from CalibratedOpticalCenterX/Y, the image centre), and either the P4 Multispectral's
    RelativeOpticalCenterX/Y (``style`` "p4m": where the reference's centre ray falls in the
    band, relative to it) or the Mavic 3M's DewarpHMatrix (``"m3m"``: the band's undistorted
    pixels -> the reference's, through the band's intrinsics)."""
    name, centre_nm, half_width, index = DJI_NAMES[camera.name]
    width, height = camera.size
    k1, k2, k3, p1, p2 = camera.dist
    cx, cy = camera.centre[0] - width / 2, camera.centre[1] - height / 2
    fields = {"BandName": name, "BandFreq": f"{centre_nm}(+/-{half_width})nm", "SensorIndex": str(index),
              "CaptureUUID": capture_id, "CalibratedOpticalCenterX": f"{width / 2:g}",
              "CalibratedOpticalCenterY": f"{height / 2:g}", "CalibratedFocalLength": f"{camera.focal:.4f}",
              "DewarpData": "2020-08-07;" + ",".join(repr(float(v)) for v in (camera.focal, camera.focal, cx, cy, k1,
                                                                              k2, p1, p2, k3)),
              "Irradiance": "1234.5", "SensorGain": "1.5", "SensorGainAdjustment": "1.002", "ExposureTime": "1000",
              "VignettingData": "0.000218, 1.2e-06, -2.8e-09, 5.1e-12, -4.1e-15, 1.3e-18", "BlackCurrent": "4096"}
    R = camera.R @ reference.R.T  # reference camera -> this band's
    if style == "p4m":
        ray = R @ np.array([0.0, 0.0, 1.0])
        fields["RelativeOpticalCenterX"] = repr(float(camera.focal * ray[0] / ray[2]))
        fields["RelativeOpticalCenterY"] = repr(float(camera.focal * ray[1] / ray[2]))
    else:
        K = np.array([[camera.focal, 0, camera.centre[0]], [0, camera.focal, camera.centre[1]], [0, 0, 1]])
        H = K @ R.T @ np.linalg.inv(K)
        fields["DewarpHMatrix"] = ",".join(repr(float(v)) for v in (H / H[2, 2]).ravel())
    attributes = " ".join(f'drone-dji:{key}="{value}"' for key, value in fields.items())
    return ('<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/">'
            '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about="" '
            f'xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" {attributes}/></rdf:RDF></x:xmpmeta>'
            '<?xpacket end="w"?>').encode()


def dji_like(size: tuple[int, int]) -> list[RigBand]:
    """Five P4 Multispectral-like bands in DJI's order (Blue, Green, Red, Red edge, NIR; no roll
    between lenses: RelativeOpticalCenter holds a shift only), each with its own principal
    point and distortion."""
    return [RigBand(c.name, c.wavelength, c.index, (c.angles[0], c.angles[1], 0.0), c.translation, c.dist, c.focal,
                    c.centre, size=size) for c in (rededge_like(size, baseline=0.04)[i] for i in (0, 1, 2, 4, 3))]


def _ground_xy(terrain: Terrain, camera: RigBand, *, step: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Ground (X, Y) (H, W) float32 seen at every pixel of ``camera``: exact on every ``step``-th
    pixel, bilinear between (the far terrain's map is smooth; rendering stays fast)."""
    width, height = camera.size
    cu, cv = np.arange(0, width + step, step, dtype=np.float64), np.arange(0, height + step, step, dtype=np.float64)
    gu, gv = np.meshgrid(cu, cv)
    points = surface_points(terrain, camera, gu, gv)
    at_u, at_v = np.meshgrid(np.arange(width, dtype=np.float32) / step, np.arange(height, dtype=np.float32) / step)
    return tuple(cv2.remap(points[:, k].reshape(gu.shape).astype(np.float32), at_u, at_v, cv2.INTER_LINEAR)
                 for k in (0, 1))


def write_rig_capture(folder: Path, rng: np.random.Generator, cameras: list[RigBand], *, depth: float = 300.0,
                      hill: float = 1.0, name: str = "IMG_0001", capture_id: str = "RIG01", style: str = "micasense",
                      reference: str = "Green", make: str = "MicaSense", model: str = "Altum") -> SyntheticCapture:
    """Render ``cameras`` (each at its own size) over one terrain and write ``<name>_<k>.tif``
    (k = 1.. in the cameras' order) with MicaSense's tags (``style`` "micasense") or DJI's
    ("p4m", "m3m"); the truth maps are on the ``reference`` band's grid."""
    folder.mkdir(parents=True, exist_ok=True)
    terrain = make_terrain(rng, depth=depth, hill=hill)
    ref = next(camera for camera in cameras if camera.name == reference)
    rw, rh = ref.size
    u, v = np.meshgrid(np.arange(rw, dtype=np.float64), np.arange(rh, dtype=np.float64))
    ground = surface_points(terrain, ref, u, v)
    paths, truth = [], {}
    for number, camera in enumerate(cameras, start=1):
        width, height = camera.size
        shade = _response(camera.name)(terrain.shade(*_ground_xy(terrain, camera)))
        raw = (BLACK_LEVEL + 16 * np.rint(np.clip(shade + rng.normal(0, 0.002, shade.shape), 0, 1) * 3800))
        truth[camera.name] = tuple(project(camera, ground).T.reshape(2, rh, rw))
        path = folder / f"{name}_{number}.tif"
        if style == "micasense":
            packet = micasense_xmp(camera, capture_id=capture_id)
            tags = [(271, "s", 0, make, True), (272, "s", 0, model, True),
                    (37390, "2I", 1, (round(camera.per_mm * 1e6), 1000000), True), (37392, "H", 1, 4, True)]
        else:
            nir = next(other for other in cameras if other.name == "NIR")  # DJI aligns onto NIR
            packet = dji_xmp(camera, capture_id=capture_id, style=style, reference=nir)
            tags = [(271, "s", 0, "DJI", True), (272, "s", 0, "FC6360" if style == "p4m" else "M3M", True)]
        tags += [(700, "B", 0, packet, True), (50714, "H", 4, (BLACK_LEVEL,) * 4, True)]
        tifffile.imwrite(path, raw.astype(np.uint16), photometric="minisblack", metadata=None, extratags=tags)
        paths.append(path)
    return SyntheticCapture(paths, list(cameras), truth)
