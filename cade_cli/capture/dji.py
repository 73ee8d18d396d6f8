"""What the band files of DJI's multispectral drones (P4 Multispectral, Mavic 3M) say about
themselves in their ``drone-dji`` XMP tags, as DJI's image processing guides document them:
the band (``BandName``, ``BandFreq``, ``SensorIndex``; the ``Camera:`` tags where present), the
lens (``DewarpData`` = ``"date;fx,fy,cx,cy,k1,k2,p1,p2,k3"``, its (cx, cy) an offset from
``CalibratedOpticalCenterX/Y``), how the band sits against the reference (the Mavic 3M's
``DewarpHMatrix``, the P4 Multispectral's ``RelativeOpticalCenterX/Y``, px relative to NIR), and
the radiometric tags (``Irradiance``, ``SensorGain``, ``SensorGainAdjustment``, ``ExposureTime``
in µs, ``VignettingData``, ``BlackCurrent``). Checked on files written from those documents,
not on files from the cameras (docs/drone.md, "Other cameras").
"""

from __future__ import annotations

import re

import numpy as np

from cade_cli.capture.lens import BrownLens

DJI = "drone-dji"
BANDS = {"blue": ("Blue", 450.0, 32.0, 1), "green": ("Green", 560.0, 32.0, 2), "red": ("Red", 650.0, 32.0, 3),
         "rededge": ("RedEdge", 730.0, 32.0, 4), "nir": ("NIR", 840.0, 52.0, 5)}
"""DJI's band names -> (name, centre nm, width nm, SensorIndex) of the P4 Multispectral (Blue 1 ..
NIR 5, its guide's ``Sensor index``); the Mavic 3M's NIR is centred at 860 nm (``BandFreq``
says so where written)."""
RADIOMETRY = {"Irradiance": "irradiance", "SensorGain": "sensor_gain", "SensorGainAdjustment": "gain_adjustment",
              "ExposureTime": "exposure_us", "BlackCurrent": "black_current"}


def is_dji(xmp: dict) -> bool:
    """Whether the packet carries DJI's drone tags."""
    return any(key.startswith(f"{DJI}:") for key in xmp)


def _value(xmp: dict, name: str) -> str | None:
    value = xmp.get(f"{DJI}:{name}")
    if isinstance(value, list):
        value = value[0] if value else None
    return None if value is None else str(value).strip()


def _floats(text: str | None) -> list[float]:
    return [float(part) for part in re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", text or "")]


def dji_band(xmp: dict) -> tuple[str, float, float | None, int] | None:
    """(name, centre wavelength nm, width nm, rig index) from ``BandName``, ``BandFreq``
    (``"840(+/-26)nm"``) and ``SensorIndex``; the table :data:`BANDS` fills the rest; None when
    the file names no band."""
    name = _value(xmp, "BandName")
    if not name:
        return None
    known = BANDS.get(re.sub(r"[^a-z]", "", name.lower()))
    frequency = _floats(_value(xmp, "BandFreq"))
    wavelength = frequency[0] if frequency else (known[1] if known else None)
    if wavelength is None:
        return None
    width = 2 * abs(frequency[1]) if len(frequency) > 1 else (known[2] if known else None)  # "840(+/-26)nm"
    index = _floats(_value(xmp, "SensorIndex"))
    rig_index = int(index[0]) if index else (known[3] if known else None)
    if rig_index is None:
        return None
    return name, wavelength, width, rig_index


def dji_lens(xmp: dict) -> BrownLens | None:
    """The band's lens from ``DewarpData`` and ``CalibratedOpticalCenterX/Y``: K = [[fx, 0,
    CenterX + cx], [0, fy, CenterY + cy], [0, 0, 1]], OpenCV's distortion (k1, k2, p1, p2, k3);
    None when either is missing."""
    dewarp = _value(xmp, "DewarpData")
    centre_x = _floats(_value(xmp, "CalibratedOpticalCenterX"))
    centre_y = _floats(_value(xmp, "CalibratedOpticalCenterY"))
    if not dewarp or not centre_x or not centre_y:
        return None
    values = _floats(dewarp.split(";", 1)[-1])
    if len(values) < 9:
        return None
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = values[:9]
    return BrownLens(fx, (centre_x[0] + cx, centre_y[0] + cy), k1, k2, k3, p1, p2, focal_y=fy)


def nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotation closest to ``matrix`` (3, 3) in the Frobenius sense (SVD)."""
    u, _, vt = np.linalg.svd(matrix / np.cbrt(np.linalg.det(matrix)))
    rotation = u @ vt
    return rotation if np.linalg.det(rotation) > 0 else u @ np.diag([1, 1, -1]) @ vt


def dji_rotation(xmp: dict, lens: BrownLens) -> np.ndarray | None:
    """The reference -> band rotation (``X_band = R @ X_reference``) the tags imply.

    ``DewarpHMatrix`` (Mavic 3M): a homography from the band's undistorted pixels to the
    reference's, taken as a rotation through the band's intrinsics (``K^-1 H K``, its nearest
    rotation; the scale and shear it may hold are left to the registration's plane fit).
    ``RelativeOpticalCenterX/Y`` (P4 Multispectral): a scene point at reference pixel p lies
    at band pixel p + (dx, dy), i.e. small rotations atan(dx / fx) about y and -atan(dy / fy)
    about x. None when the file has neither.
    """
    matrix = _floats(_value(xmp, "DewarpHMatrix"))
    K = lens.K
    if len(matrix) == 9:
        band_to_reference = nearest_rotation(np.linalg.inv(K) @ np.reshape(matrix, (3, 3)) @ K)
        return band_to_reference.T
    dx, dy = _floats(_value(xmp, "RelativeOpticalCenterX")), _floats(_value(xmp, "RelativeOpticalCenterY"))
    if not dx or not dy:
        return None
    about_y, about_x = np.arctan(dx[0] / lens.focal), -np.arctan(dy[0] / lens.fy)
    rx = np.array([[1, 0, 0], [0, np.cos(about_x), -np.sin(about_x)], [0, np.sin(about_x), np.cos(about_x)]])
    ry = np.array([[np.cos(about_y), 0, np.sin(about_y)], [0, 1, 0], [-np.sin(about_y), 0, np.cos(about_y)]])
    return rx @ ry


def dji_radiometry(xmp: dict) -> dict[str, float | list[float]]:
    """The radiometric tags present, by :data:`RADIOMETRY`'s names (``exposure_s`` converted from
    µs) plus ``vignetting`` (``VignettingData``'s six coefficients)."""
    found: dict[str, float | list[float]] = {}
    for tag, name in RADIOMETRY.items():
        values = _floats(_value(xmp, tag))
        if values:
            found[name] = values[0]
    if "exposure_us" in found:
        found["exposure_s"] = found.pop("exposure_us") / 1e6
    vignetting = _floats(_value(xmp, "VignettingData"))
    if vignetting:
        found["vignetting"] = vignetting
    return found
