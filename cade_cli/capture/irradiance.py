"""The sunlight falling on the ground when a band was shot, from the capture's own
Downwelling Light Sensor (DLS) tags, as MicaSense's library computes it (micasense/imageprocessing,
MIT: ``image.py`` ``Image.__init__`` / ``compute_horizontal_irradiance_dls1/2``, ``dls.py``,
``metadata.py``):

- DLS 2 (``DLS:HorizontalIrradiance`` present and trusted for the firmware): that value;
  with direct and scattered parts but an untrusted horizontal value:
  ``direct * sin(solar elevation) + scattered``.
- DLS 1 (spectral irradiance only): the sensor's reading is divided by the Fresnel
  transmission of its diffuser at the sun-sensor angle, split into direct and diffuse light
  assuming a direct-to-diffuse ratio of 6 (clear sky), and the direct part is projected on the
  horizontal by the solar elevation; the sun's position comes from the capture's UTC time
  and GPS position (:mod:`cade_cli.capture.sun`), the sensor's pose from ``DLS:Yaw/Pitch/Roll``.

Irradiance in W/m^2/nm (the tags times ``IrradianceScaleToSIUnits``: 1 for DLS 1, 0.01 for a
DLS 2 that does not say).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from cade_cli.capture.metadata import numbers, parse_xmp, read_first_page_tags
from cade_cli.capture.sun import sun_position
from cade_cli.errors import CadeError

DIRECT_TO_DIFFUSE = 6.0
"""The vendor's clear-sky assumption for a DLS 1."""
DIFFUSER_INDICES = (1.000277, 1.6, 1.38)
"""Refractive indices the vendor's Fresnel model of the DLS diffuser crosses (air, polycarbonate, teflon)."""
TRUSTED_HORIZONTAL_FIRMWARE = {"Altum": (1, 2, 3), "RedEdge": (5, 1, 7), "RedEdge-M": (5, 1, 7)}
"""Firmware from which a camera's ``HorizontalIrradiance`` is right (RedEdge-P, Altum-PT: all)."""


@dataclass(frozen=True)
class DLSReading:
    """What a band file's DLS tags say.

    Attributes:
        spectral: the sensor's spectral irradiance, W/m^2/nm (not corrected for angles).
        horizontal, direct, scattered: DLS 2 values, W/m^2/nm (0 when absent).
        horizontal_trusted: the camera's horizontal value is right for its firmware.
        pose: the DLS's (yaw, pitch, roll), radians.
        time: UTC time of the capture (None when the file has none).
        latitude, longitude: degrees, north and east positive (None without a GPS fix).
    """

    spectral: float
    horizontal: float
    direct: float
    scattered: float
    horizontal_trusted: bool
    pose: tuple[float, float, float]
    time: datetime | None
    latitude: float | None
    longitude: float | None


def _value(xmp: dict, name: str) -> float:
    for prefix in ("DLS", "Camera"):
        if f"{prefix}:{name}" in xmp:
            try:
                return numbers(xmp[f"{prefix}:{name}"])[0]
            except (ValueError, IndexError):
                return 0.0
    return 0.0


def _degrees(value, reference: str) -> float | None:
    try:
        d, m, s = (value[i] / value[i + 1] for i in (0, 2, 4))
    except (TypeError, IndexError, ZeroDivisionError):
        return None
    sign = -1.0 if str(reference).strip().upper() in ("S", "W") else 1.0
    return sign * (d + m / 60 + s / 3600)


def _time(exif: dict) -> datetime | None:
    text = str(exif.get("DateTimeOriginal") or "").strip()
    try:
        when = datetime.strptime(text, "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return None
    subsec = str(exif.get("SubsecTimeOriginal") or exif.get("SubsecTime") or "0").strip().lstrip("-")
    try:
        when += timedelta(seconds=float(f"0.{subsec}"))
    except ValueError:
        pass
    return when.replace(tzinfo=timezone.utc)


def _version(text: str) -> tuple[int, ...]:
    """``"v7.0.0-alpha1"`` -> (7, 0, 0): the leading numbers of each dotted part, up to the first
    part that does not start with one."""
    parts = []
    for part in text.strip().lstrip("vV").split("."):
        match = re.match(r"\d+", part)
        if not match:
            break
        parts.append(int(match.group(0)))
        if match.end() < len(part):
            break
    return tuple(parts)


def read_dls(path: Path | str) -> DLSReading | None:
    """The DLS reading of a band file; None when the file has no DLS irradiance tags."""
    path = Path(path)
    tags, _ = read_first_page_tags(path)
    xmp = parse_xmp(tags.get(700, b""))
    present = any(key in xmp for key in ("Camera:Irradiance", "DLS:HorizontalIrradiance", "DLS:DirectIrradiance"))
    if not present:
        return None
    if "DLS:IrradianceScaleToSIUnits" in xmp or "Camera:IrradianceScaleToSIUnits" in xmp:
        scale = _value(xmp, "IrradianceScaleToSIUnits")
    elif "DLS:HorizontalIrradiance" in xmp:
        scale = 0.01
    else:
        scale = 1.0
    model = str(tags.get(272, "")).strip()
    firmware = _version(str(tags.get(305, "")))
    trusted = "DLS:HorizontalIrradiance" in xmp and (
        model in ("RedEdge-P", "Altum-PT") or
        (model in TRUSTED_HORIZONTAL_FIRMWARE and firmware >= TRUSTED_HORIZONTAL_FIRMWARE[model]))
    exif, gps = dict(tags.get(34665) or {}), dict(tags.get(34853) or {})
    latitude = _degrees(gps.get("GPSLatitude"), gps.get("GPSLatitudeRef", "N"))
    longitude = _degrees(gps.get("GPSLongitude"), gps.get("GPSLongitudeRef", "E"))
    pose = tuple(_value(xmp, name) if f"DLS:{name}" in xmp else 0.0 for name in ("Yaw", "Pitch", "Roll"))
    return DLSReading(_value(xmp, "SpectralIrradiance") * scale, _value(xmp, "HorizontalIrradiance") * scale,
                      _value(xmp, "DirectIrradiance") * scale, _value(xmp, "ScatteredIrradiance") * scale,
                      trusted, pose, _time(exif), latitude, longitude)


def fresnel_transmission(phi: float, n1: float, n2: float) -> float:
    """Unpolarised Fresnel transmission from index ``n1`` into ``n2`` at incidence ``phi`` (rad);
    0 where undefined (total reflection)."""
    f1 = math.cos(phi)
    inner = 1 - (n1 / n2 * math.sin(phi)) ** 2
    if inner < 0:
        return 0.0
    f2 = math.sqrt(inner)
    rs = ((n1 * f1 - n2 * f2) / (n1 * f1 + n2 * f2)) ** 2
    rp = ((n1 * f2 - n2 * f1) / (n1 * f2 + n2 * f1)) ** 2
    transmission = 1.0 - 0.5 * rs - 0.5 * rp
    return transmission if 0.0 <= transmission <= 1.0 else 0.0


def diffuser_transmission(phi: float) -> float:
    """The DLS diffuser's transmission at the sun-sensor angle ``phi`` (rad): the vendor's
    multilayer Fresnel model (``dls.fresnel``)."""
    transmission, angle = 1.0, phi
    for n1, n2 in zip(DIFFUSER_INDICES, DIFFUSER_INDICES[1:]):
        angle = math.asin(math.sin(angle) / n1)
        transmission *= fresnel_transmission(angle, n1, n2)
    return transmission


def sensor_normal(pose: tuple[float, float, float]) -> np.ndarray:
    """The DLS's up-facing normal (body ``(0, 0, -1)``) in North-East-Down for a (yaw, pitch,
    roll) pose in radians (``dls.get_orientation``)."""
    yaw, pitch, roll = pose
    c1, s1, c2, s2, c3, s3 = (math.cos(-yaw), math.sin(-yaw), math.cos(-pitch), math.sin(-pitch),
                              math.cos(-roll), math.sin(-roll))
    r_yaw = np.array([[c1, s1, 0], [-s1, c1, 0], [0, 0, 1]])
    r_pitch = np.array([[c2, 0, -s2], [0, 1, 0], [s2, 0, c2]])
    r_roll = np.array([[1, 0, 0], [0, c3, s3], [0, -s3, c3]])
    return r_yaw @ r_pitch @ r_roll @ np.array([0.0, 0.0, -1.0])


def sun_vector(elevation: float, azimuth: float) -> np.ndarray:
    """Unit vector towards the sun in North-East-Down; angles in radians."""
    return np.array([math.cos(azimuth) * math.cos(elevation), math.sin(azimuth) * math.cos(elevation),
                     -math.sin(elevation)])


def horizontal_irradiance(reading: DLSReading, *, name: str = "the band") -> float:
    """The irradiance on a horizontal surface, W/m^2/nm, from a band's DLS reading (module docstring).

    Raises:
        CadeError: a DLS 1 reading with no capture time or GPS position (the sun's position
            is unknown), or a non-positive result.
    """
    if reading.direct != 0 and reading.scattered != 0:
        if reading.horizontal_trusted:
            value = reading.horizontal
        else:
            elevation = _sun(reading, name)[0]
            value = reading.direct * math.sin(elevation) + reading.scattered
    else:
        elevation, azimuth = _sun(reading, name)
        angle = math.acos(max(-1.0, min(1.0, float(sun_vector(elevation, azimuth) @ sensor_normal(reading.pose)))))
        transmission = diffuser_transmission(angle)
        if transmission <= 0:
            raise CadeError(f"{name}: the sun is {math.degrees(angle):.0f} deg off the DLS's axis, beyond its "
                            "diffuser's model; give a panel shot with --panel")
        diffuse_share = 1.0 / DIRECT_TO_DIFFUSE
        direct = reading.spectral / transmission / (diffuse_share + math.cos(angle))
        value = direct * math.sin(elevation) + direct * diffuse_share
    if not value > 0:
        raise CadeError(f"{name}: the DLS tags give an irradiance of {value:g} W/m^2/nm; give a panel shot with "
                        "--panel")
    return float(value)


def _sun(reading: DLSReading, name: str) -> tuple[float, float]:
    """(elevation, azimuth) in radians of the sun at the reading's time and place."""
    if reading.time is None or reading.latitude is None or reading.longitude is None:
        raise CadeError(f"{name}: its DLS gives no horizontal irradiance and the file has no capture time or "
                        "GPS position to place the sun; give a panel shot with --panel")
    if reading.time.year < 1980:
        raise CadeError(f"{name}: its clock says {reading.time:%Y-%m-%d} (no GPS time), so the sun cannot be "
                        "placed; give a panel shot with --panel")
    sun = sun_position(reading.time, reading.latitude, reading.longitude)
    return math.radians(sun.elevation), math.radians(sun.azimuth) % (2 * math.pi)


def dls_irradiances(paths: list[Path], names: list[str]) -> list[float]:
    """The horizontal irradiance of each band of a capture from its own DLS tags, W/m^2/nm.

    Raises:
        CadeError: a band without DLS tags, or one whose irradiance cannot be computed, naming
            the band and suggesting ``--panel``.
    """
    values = []
    for path, name in zip(paths, names):
        reading = read_dls(path)
        if reading is None:
            raise CadeError(f"{Path(path).name} ({name}): no DLS irradiance in its tags (no light sensor); give a "
                            "panel shot with --panel")
        values.append(horizontal_irradiance(reading, name=f"{Path(path).name} ({name})"))
    return values
