"""Where the sun is: elevation and azimuth for a UTC time and a place, by NOAA's solar
calculator (the low-precision Meeus formulas NOAA's spreadsheet uses; within about 0.01 deg
for years 1900-2100), with NOAA's atmospheric refraction correction. Used for the
horizontal irradiance of a version-1 DLS (:mod:`cade_cli.capture.irradiance`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timezone

UNIX_EPOCH_JULIAN_DAY = 2440587.5
J2000 = 2451545.0


@dataclass(frozen=True)
class SunPosition:
    """The sun seen from a place.

    Attributes:
        elevation: above the horizon, degrees, refraction included (90 = overhead).
        azimuth: clockwise from true north, degrees in [0, 360).
        declination: degrees; equation_of_time: minutes.
    """

    elevation: float
    azimuth: float
    declination: float
    equation_of_time: float


def julian_day(when: datetime) -> float:
    """Julian day of a time; a naive ``when`` is taken as UTC."""
    if when.tzinfo is None:
        when = when.replace(tzinfo=timezone.utc)
    return when.timestamp() / 86400.0 + UNIX_EPOCH_JULIAN_DAY


def refraction(elevation: float) -> float:
    """NOAA's approximation of atmospheric refraction, degrees, at a true elevation in degrees."""
    if elevation > 85.0:
        return 0.0
    t = math.tan(math.radians(elevation))
    if elevation > 5.0:
        arcsec = 58.1 / t - 0.07 / t ** 3 + 0.000086 / t ** 5
    elif elevation > -0.575:
        e = elevation
        arcsec = 1735.0 + e * (-518.2 + e * (103.4 + e * (-12.79 + e * 0.711)))
    else:
        arcsec = -20.772 / t
    return arcsec / 3600.0


def sun_position(when: datetime, latitude: float, longitude: float, *, refract: bool = True) -> SunPosition:
    """The sun's position at ``when`` (UTC; naive is UTC) from ``latitude``, ``longitude``
    (degrees, north and east positive).

    Raises:
        ValueError: a latitude outside [-90, 90] or longitude outside [-180, 360].
    """
    if not -90.0 <= latitude <= 90.0 or not -180.0 <= longitude <= 360.0:
        raise ValueError(f"latitude {latitude} / longitude {longitude} out of range (degrees, N and E positive)")
    jd = julian_day(when)
    t = (jd - J2000) / 36525.0
    mean_longitude = (280.46646 + t * (36000.76983 + t * 0.0003032)) % 360.0
    anomaly = 357.52911 + t * (35999.05029 - 0.0001537 * t)
    eccentricity = 0.016708634 - t * (0.000042037 + 0.0000001267 * t)
    m = math.radians(anomaly)
    centre = (math.sin(m) * (1.914602 - t * (0.004817 + 0.000014 * t)) + math.sin(2 * m) * (0.019993 - 0.000101 * t)
              + math.sin(3 * m) * 0.000289)
    omega = math.radians(125.04 - 1934.136 * t)
    apparent = math.radians(mean_longitude + centre - 0.00569 - 0.00478 * math.sin(omega))
    obliquity0 = 23.0 + (26.0 + (21.448 - t * (46.815 + t * (0.00059 - t * 0.001813))) / 60.0) / 60.0
    obliquity = math.radians(obliquity0 + 0.00256 * math.cos(omega))
    declination = math.asin(math.sin(obliquity) * math.sin(apparent))
    y = math.tan(obliquity / 2) ** 2
    l0 = math.radians(mean_longitude)
    equation = 4 * math.degrees(y * math.sin(2 * l0) - 2 * eccentricity * math.sin(m)
                                + 4 * eccentricity * y * math.sin(m) * math.cos(2 * l0)
                                - 0.5 * y * y * math.sin(4 * l0) - 1.25 * eccentricity ** 2 * math.sin(2 * m))
    minutes = ((jd + 0.5) % 1.0) * 1440.0  # minutes since UTC midnight
    solar_time = (minutes + equation + 4.0 * longitude) % 1440.0
    hour_angle = solar_time / 4.0 - 180.0
    lat, dec, ha = math.radians(latitude), declination, math.radians(hour_angle)
    cos_zenith = math.sin(lat) * math.sin(dec) + math.cos(lat) * math.cos(dec) * math.cos(ha)
    zenith = math.acos(max(-1.0, min(1.0, cos_zenith)))
    elevation = 90.0 - math.degrees(zenith)
    denominator = math.cos(lat) * math.sin(zenith)
    if abs(denominator) < 1e-12:
        azimuth = 180.0 if latitude > math.degrees(dec) else 0.0
    else:
        cos_az = max(-1.0, min(1.0, (math.sin(lat) * math.cos(zenith) - math.sin(dec)) / denominator))
        angle = math.degrees(math.acos(cos_az))
        azimuth = (angle + 180.0) % 360.0 if hour_angle > 0 else (540.0 - angle) % 360.0
    if refract:
        elevation += refraction(elevation)
    return SunPosition(elevation, azimuth, math.degrees(declination), equation)
