"""A band's raw pixels as radiance, by the camera's own radiometric model, read from its tags.

MicaSense (RedEdge, RedEdge-M/MX, Altum; as ``micasense/image.py`` ``Image.radiance()`` of
micasense/imageprocessing, MIT, computes it)::

    V(x, y) = 1 / (1 + k0 r + k1 r^2 + ... + k5 r^6),  r = |(x, y) - VignettingCenter|
    R(y)    = 1 / (1 + a2 y / t - a3 y)                  (row gradient / readout; y = row)
    L       = max(V R (p - BlackLevel), 0) / (g t) * a1 / 2^BitsPerSample

with ``p`` the stored value, ``BlackLevel`` the mean of EXIF/DNG tag 50714 (not the dark-row
values), ``t`` the exposure time (s), ``g = ISOSpeed / 100``, ``(a1, a2, a3)`` the
``MicaSense:RadiometricCalibration`` tag: radiance in W/m^2/sr/nm.

Parrot Sequoia (application note SEQ-AN-01)::

    V(x, y) = sum_i c_i (x / W)^m_i (y / H)^n_i     (VignettingPolynomial2D, ...2DName)
    L       = f^2 (p / V - B) / (A t g + C)          (SensorModel A, B, C; f the f-number,
                                                       g the ISO)

in Parrot's own relative units (proportional to radiance; not W/m^2/sr/nm): a reflectance
from it needs a panel shot of the same camera.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cade_cli.capture.metadata import numbers, parse_xmp, read_first_page_tags
from cade_cli.errors import CadeError

RADIANCE_UNITS = "W/m^2/sr/nm"
SEQUOIA_UNITS = "Parrot Sequoia relative radiance units (SEQ-AN-01; proportional to radiance, not W/m^2/sr/nm)"
LEGACY_EXPOSURE = (1.0 / 6329.0, 0.000274)
"""Some old RedEdge firmware wrote 1/6329 s for an exposure of 0.274 ms (the vendor corrects it)."""


@dataclass(frozen=True)
class MicaSenseModel:
    """MicaSense's per-band radiometric model (see the module docstring).

    Attributes:
        black_level: raw units; exposure: s; gain: ISO / 100; calibration: (a1, a2, a3);
        vignetting_centre: (x, y) px; vignetting: the 6 polynomial coefficients k0..k5 (r in
        px); bits: BitsPerSample (2^bits is the full scale).
    """

    black_level: float
    exposure: float
    gain: float
    calibration: tuple[float, float, float]
    vignetting_centre: tuple[float, float]
    vignetting: tuple[float, ...]
    bits: int

    units = RADIANCE_UNITS


@dataclass(frozen=True)
class SequoiaModel:
    """Parrot Sequoia's sensor model (see the module docstring).

    Attributes:
        sensor: SensorModel (A, B, C); exposure: s; iso: ISO; f_number: the lens's f-number;
        vignetting: the 2-D polynomial's coefficients; exponents: (x power, y power) per
        coefficient.
    """

    sensor: tuple[float, float, float]
    exposure: float
    iso: float
    f_number: float
    vignetting: tuple[float, ...]
    exponents: tuple[tuple[int, int], ...]

    units = SEQUOIA_UNITS


RadiometricModel = MicaSenseModel | SequoiaModel


def _rational(value) -> float | None:
    if value is None:
        return None
    if isinstance(value, tuple):
        return value[0] / value[1] if len(value) >= 2 and value[1] else None
    return float(value)


def read_radiometric_model(path: Path | str) -> RadiometricModel:
    """The radiometric model a band file's tags describe.

    Raises:
        CadeError: not a readable TIFF, or a tag the model needs is missing (one line naming it).
    """
    path = Path(path)
    tags, _ = read_first_page_tags(path)
    xmp = parse_xmp(tags.get(700, b""))
    exif = dict(tags.get(34665) or {})
    model = str(tags.get(272, "")).strip()

    def missing(field: str) -> CadeError:
        return CadeError(f"{path.name}: no {field} in its metadata, so its radiance cannot be computed; "
                         "give the camera's own files, or leave out --radiance/--reflectance")

    exposure = _rational(exif.get("ExposureTime"))
    if not exposure:
        raise missing("EXIF ExposureTime")
    if "Camera:SensorModel" in xmp:
        sensor = numbers(xmp["Camera:SensorModel"])
        iso = exif.get("ISOSpeedRatings") or exif.get("ISOSpeed")
        f_number = _rational(exif.get("FNumber"))
        if len(sensor) < 3:
            raise missing("Camera:SensorModel (3 numbers A, B, C)")
        if not iso or not f_number:
            raise missing("EXIF ISOSpeedRatings or FNumber")
        coefficients = numbers(xmp.get("Camera:VignettingPolynomial2D", ""))
        powers = [int(v) for v in numbers(xmp.get("Camera:VignettingPolynomial2DName", ""))]
        if not coefficients or len(powers) != 2 * len(coefficients):
            raise missing("Camera:VignettingPolynomial2D with its ...2DName exponents")
        exponents = tuple((powers[2 * i], powers[2 * i + 1]) for i in range(len(coefficients)))
        return SequoiaModel(tuple(sensor[:3]), exposure, float(iso[0] if isinstance(iso, tuple) else iso),
                            f_number, tuple(coefficients), exponents)
    if "MicaSense:RadiometricCalibration" not in xmp:
        raise missing("MicaSense:RadiometricCalibration or Camera:SensorModel")
    calibration = numbers(xmp["MicaSense:RadiometricCalibration"])
    iso = exif.get("ISOSpeed") or exif.get("ISOSpeedRatings")
    if not iso:
        raise missing("EXIF ISOSpeed")
    centre = numbers(xmp.get("Camera:VignettingCenter", ""))
    polynomial = numbers(xmp.get("Camera:VignettingPolynomial", ""))
    if len(calibration) < 3 or len(centre) < 2 or not polynomial:
        raise missing("RadiometricCalibration (3), VignettingCenter (2) and VignettingPolynomial")
    if model != "Altum" and abs(exposure - LEGACY_EXPOSURE[0]) < 1e-6:
        exposure = LEGACY_EXPOSURE[1]
    black = tags.get(50714)
    bits = tags.get(258, 16)
    return MicaSenseModel(float(np.mean(black)) if black is not None else 0.0, exposure,
                          float(iso[0] if isinstance(iso, tuple) else iso) / 100.0, tuple(calibration[:3]),
                          (centre[0], centre[1]), tuple(polynomial), int(bits[0] if isinstance(bits, tuple) else bits))


def vignetting_correction(model: RadiometricModel, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float64 factor a raw signal is multiplied by to undo the lens's vignetting
    (MicaSense: 1 / radial polynomial; Sequoia: 1 / 2-D polynomial)."""
    height, width = shape
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    if isinstance(model, MicaSenseModel):
        r = np.hypot(x - model.vignetting_centre[0], y - model.vignetting_centre[1])
        polynomial = np.polyval(list(reversed(model.vignetting)) + [1.0], r)
        return 1.0 / polynomial
    falloff = np.zeros(shape)
    xv, yv = x / width, y / height
    for coefficient, (ex, ey) in zip(model.vignetting, model.exponents):
        falloff += coefficient * xv ** ex * yv ** ey
    return 1.0 / falloff


def radiance(raw: np.ndarray, model: RadiometricModel) -> np.ndarray:
    """(H, W) float32 radiance of a band's raw (H, W) values by ``model`` (units: ``model.units``).

    MicaSense: negative signals (below the black level) become 0, as the vendor's library."""
    raw = np.asarray(raw, np.float64)
    if raw.ndim != 2:
        raise CadeError(f"a band's raw image must be (H, W), got shape {raw.shape}")
    correction = vignetting_correction(model, raw.shape)
    if isinstance(model, MicaSenseModel):
        a1, a2, a3 = model.calibration
        rows = np.arange(raw.shape[0], dtype=np.float64)[:, None]
        readout = 1.0 / (1.0 + a2 * rows / model.exposure - a3 * rows)
        signal = np.maximum(correction * readout * (raw - model.black_level), 0.0)
        return (signal / (model.gain * model.exposure) * a1 / float(2 ** model.bits)).astype(np.float32)
    a, b, c = model.sensor
    return (model.f_number ** 2 * (raw * correction - b) / (a * model.exposure * model.iso + c)).astype(np.float32)


def raw_from_radiance(radiance_image: np.ndarray, model: RadiometricModel) -> np.ndarray:
    """The forward model: the (H, W) float64 raw values a band records for a radiance field
    (no quantisation, no clipping); :func:`radiance` inverts it where the signal is positive."""
    radiance_image = np.asarray(radiance_image, np.float64)
    correction = vignetting_correction(model, radiance_image.shape)
    if isinstance(model, MicaSenseModel):
        a1, a2, a3 = model.calibration
        rows = np.arange(radiance_image.shape[0], dtype=np.float64)[:, None]
        readout = 1.0 / (1.0 + a2 * rows / model.exposure - a3 * rows)
        signal = radiance_image * model.gain * model.exposure * float(2 ** model.bits) / a1
        return signal / (correction * readout) + model.black_level
    a, b, c = model.sensor
    return (radiance_image * (a * model.exposure * model.iso + c) / model.f_number ** 2 + b) / correction


QUANTITIES = ("radiance", "reflectance")


@dataclass(frozen=True)
class Radiometry:
    """What a registration's values are converted to before the one resampling.

    Attributes:
        quantity: ``"radiance"`` or ``"reflectance"`` (``pi * L / E``, unitless, 1 = a white
            Lambertian surface).
        irradiance: per band, in the capture's band order, the irradiance E (W/m^2/nm for
            MicaSense; the camera's relative units for a Sequoia panel), reflectance only.
        source: where E came from, e.g. ``"DLS"`` or ``"panel IMG_0000"``.
    """

    quantity: str
    irradiance: tuple[float, ...] | None = None
    source: str | None = None

    def __post_init__(self) -> None:
        if self.quantity not in QUANTITIES:
            raise CadeError(f"unknown radiometric quantity {self.quantity!r}; choose one of {', '.join(QUANTITIES)}")
        if self.quantity == "reflectance" and not self.irradiance:
            raise CadeError("a reflectance needs the irradiance of every band (DLS tags or a panel shot)")

    def convert(self, raw: list[np.ndarray], paths: list[Path]) -> list[np.ndarray]:
        """Each band's (H, W) raw image as float32 radiance or reflectance, by its file's model."""
        if self.irradiance is not None and len(self.irradiance) != len(raw):
            raise CadeError(f"{len(self.irradiance)} irradiance values for {len(raw)} bands")
        converted = []
        for index, (image, path) in enumerate(zip(raw, paths)):
            values = radiance(image, read_radiometric_model(path))
            if self.quantity == "reflectance":
                values = (values * np.float32(np.pi / self.irradiance[index])).astype(np.float32)
            converted.append(values)
        return converted

    def units(self, paths: list[Path]) -> str:
        """The converted values' units, for the cube's description and the pictures."""
        if self.quantity == "reflectance":
            return "reflectance (unitless, pi * radiance / irradiance)"
        kinds = {read_radiometric_model(path).units for path in paths}
        return f"radiance, {' / '.join(sorted(kinds))}"


def values_label(radiometry: Radiometry | None) -> str:
    """What a picture computed from a registration's bands shows: ``"raw signals above black
    level (not radiance or reflectance)"``, ``"radiance"`` or ``"reflectance (DLS irradiance)"``."""
    if radiometry is None:
        return "raw signals above black level (not radiance or reflectance)"
    if radiometry.quantity == "reflectance":
        return f"reflectance ({radiometry.source or 'given'} irradiance)"
    return "radiance"


def describe(radiometry: Radiometry | None, paths: list[Path]) -> dict | None:
    """The cube description's ``radiometry`` entry: quantity, units, irradiance per band and
    its source; None for raw values."""
    if radiometry is None:
        return None
    units = ("1 (unitless)" if radiometry.quantity == "reflectance"
             else " / ".join(sorted({read_radiometric_model(path).units for path in paths})))
    return {"quantity": radiometry.quantity, "units": units,
            "irradiance_w_m2_nm": None if radiometry.irradiance is None else [float(v) for v in radiometry.irradiance],
            "irradiance_source": radiometry.source,
            "model": "MicaSense imageprocessing Image.radiance() / Parrot SEQ-AN-01 (cade_cli/capture/radiometry.py)"}
