"""A calibration panel in a band image: where its grey square is, its albedo, and the
irradiance its radiance implies (``E = pi * L_panel / albedo``), as MicaSense's library does it
(micasense/imageprocessing, MIT: ``panel.py``): the square is found from the panel's QR code
at the panel version's known offset (the four orientations of the code tried, the one with
the most uniform square kept), or taken from the camera's own ``Camera:ReflectArea`` tag
(a panel shot the camera recognised), or given as corners.

The albedo: given per band, else the camera's ``Camera:Albedo`` tag, else the linear model a
version >= 4 panel's QR text carries (``RPvv-nnnnnnn-SC_wwwwrrrWWWWRRR``: reflectance ``rrr/1000``
at ``wwww`` nm and ``RRR/1000`` at ``WWWW`` nm). The albedo table printed on the panel is the
panel's calibration; the tag and the QR model are a two-point line through it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from pathlib import Path

import cv2
import numpy as np
import tifffile

from cade_cli.capture.metadata import numbers, parse_xmp, text_of
from cade_cli.capture.radiometry import radiance, read_radiometric_model
from cade_cli.capture.register import saturation_level
from cade_cli.errors import CadeError

SERIAL = re.compile(r"RP(\d{2})-(\d{7})-\D{2}")
PANEL_GEOMETRY = {  # version range: (QR half side p, square side s, square centre T from the QR centre), mm
    (0, 3): (42.0, 76.2, (-143.2, 0.0)),
    (3, 6): (45.0, 50.0, (-145.8, 0.0)),
    (6, 100): (41.0, 50.0, (0.0, -130.84)),
}
"""The vendor's panel layouts: the QR code's half side and the measured square's side and
centre in the QR code's own frame, mm (``panel.Panel.panel_corners``)."""


@dataclass(frozen=True)
class PanelQR:
    """A decoded panel QR code.

    Attributes:
        text: its text, e.g. ``RP04-1826246-SC_04005111000507``; serial: ``RP04-1826246-SC``;
        version: the panel version (04); corners: (4, 2) float64 corners, px (x, y), in the
        order OpenCV reports them.
    """

    text: str
    serial: str
    version: int
    corners: np.ndarray


def to_gray8(image: np.ndarray) -> np.ndarray:
    """A band image as 8-bit grey for the QR detector: its 0.5th to 99.5th percentile stretched."""
    values = np.asarray(image, np.float64)
    finite = np.isfinite(values)
    if not finite.any():
        return np.zeros(values.shape, np.uint8)
    low, high = np.percentile(values[finite], [0.5, 99.5])
    scaled = (np.where(finite, values, low) - low) / max(high - low, 1e-12)
    return np.rint(np.clip(scaled, 0, 1) * 255).astype(np.uint8)


def find_panel_qr(image: np.ndarray) -> PanelQR | None:
    """The panel QR code in a band image (OpenCV's QR detector); None when none is read or its
    text is not a panel serial."""
    gray = to_gray8(image)
    detector = cv2.QRCodeDetector()
    for candidate in (gray, cv2.resize(gray, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)):
        factor = candidate.shape[0] / gray.shape[0]
        try:
            text, points, _ = detector.detectAndDecode(candidate)
        except cv2.error:
            continue
        match = SERIAL.search(text or "")
        if points is not None and match:
            return PanelQR(text, match.group(0), int(match.group(1)), points.reshape(-1, 2).astype(np.float64) / factor)
    return None


def region_mask(shape: tuple[int, int], corners: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels inside a polygon of (N, 2) corners (x, y), px."""
    mask = np.zeros(shape, np.uint8)
    cv2.fillPoly(mask, [np.rint(np.asarray(corners, np.float64)).astype(np.int32).reshape(-1, 1, 2)], 1)
    return mask.astype(bool)


def region_stats(image: np.ndarray, corners: np.ndarray) -> tuple[float, float, int]:
    """(mean, standard deviation, pixels) of the finite values of ``image`` inside the polygon."""
    values = np.asarray(image, np.float64)[region_mask(np.shape(image), corners)]
    values = values[np.isfinite(values)]
    if values.size == 0:
        return math.nan, math.nan, 0
    return float(values.mean()), float(values.std()), int(values.size)


def _geometry(version: int) -> tuple[float, float, tuple[float, float]]:
    for (low, high), geometry in PANEL_GEOMETRY.items():
        if low <= version < high:
            return geometry
    raise CadeError(f"unknown panel version {version}; give the square's corners with --panel-corners")


def square_from_qr(qr: PanelQR, image: np.ndarray) -> np.ndarray:
    """(4, 2) corners of the panel's grey square from its QR code: the vendor's layout mapped
    by the homography of the code's corners, in each of the code's four orientations; the
    orientation whose square lies in the image and is most uniform (least std / mean) wins.

    Raises:
        CadeError: no orientation puts the square inside the image.
    """
    half_qr, side, (tx, ty) = _geometry(qr.version)
    square = (np.array([[-side, side], [side, side], [side, -side], [-side, -side]]) * 0.5
              + np.array([tx, ty])).astype(np.float32)
    code = np.array([[-half_qr, half_qr], [half_qr, half_qr], [half_qr, -half_qr], [-half_qr, -half_qr]],
                    np.float32)
    height, width = np.shape(image)
    best, best_cost = None, math.inf
    for rotation in range(4):
        warp = cv2.getPerspectiveTransform(np.roll(code, rotation, axis=0), qr.corners.astype(np.float32))
        corners = cv2.perspectiveTransform(square[None], warp)[0].astype(np.float64)
        if (corners < 0).any() or (corners[:, 0] >= width).any() or (corners[:, 1] >= height).any():
            continue
        mean, std, count = region_stats(image, corners)
        if count and mean > 0 and std / mean < best_cost:
            best, best_cost = corners, std / mean
    if best is None:
        raise CadeError(f"the panel {qr.serial}'s grey square falls outside the image; give its corners with "
                        "--panel-corners")
    return best


def albedo_from_qr(text: str, wavelength: float) -> float | None:
    """The albedo at ``wavelength`` nm by the two-point line a version >= 4 panel's QR text
    carries; None for older panels or a text without it."""
    match = SERIAL.search(text)
    if not match or int(match.group(1)) < 4:
        return None
    tail = re.search(r"_(\d{4})(\d{3})(\d{4})(\d{3})\s*$", text)
    if not tail:
        return None
    low_nm, low_r, high_nm, high_r = (float(value) for value in tail.groups())
    if high_nm == low_nm:
        return low_r / 1000
    return (low_r + (high_r - low_r) * (wavelength - low_nm) / (high_nm - low_nm)) / 1000


def panel_irradiance(panel_radiance: float, albedo: float) -> float:
    """The irradiance on a Lambertian panel of ``albedo`` whose mean radiance is ``panel_radiance``."""
    if not 0 < albedo <= 1:
        raise CadeError(f"a panel albedo must be in (0, 1], got {albedo:g}")
    return math.pi * panel_radiance / albedo


def parse_corners(text: str) -> np.ndarray:
    """``x1,y1,x2,y2,...`` (at least 3 points) -> (N, 2) float64.

    Raises:
        CadeError: not an even count of at least 6 numbers.
    """
    try:
        values = [float(part) for part in text.replace(";", ",").split(",") if part.strip()]
    except ValueError:
        values = []
    if len(values) < 6 or len(values) % 2:
        raise CadeError(f"--panel-corners wants x1,y1,x2,y2,x3,y3[,x4,y4] in pixels of the panel shot, got {text!r}")
    return np.array(values, np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class PanelMeasure:
    """The panel as one band of a panel shot sees it.

    Attributes:
        band: band name; wavelength: nm.
        corners: (N, 2) corners of the measured square in the band's raw image, px (x, y).
        found_by: ``"--panel-corners"``, ``"camera ReflectArea tag"`` or ``"QR code"``.
        radiance: mean radiance over the square (the band's radiometric units); spread: its
            standard deviation over the mean; pixels: pixels averaged; saturated: saturated
            pixels inside the square.
        albedo: the panel's reflectance in this band; albedo_from: where it came from.
        irradiance: ``pi * radiance / albedo``.
        units: the radiometric units of ``radiance`` (the camera's model).
    """

    band: str
    wavelength: float
    corners: np.ndarray
    found_by: str
    radiance: float
    spread: float
    pixels: int
    saturated: int
    albedo: float
    albedo_from: str
    irradiance: float
    units: str


def _tags(path: Path) -> tuple[dict, np.ndarray]:
    try:
        with tifffile.TiffFile(path) as tiff:
            page = tiff.pages[0]
            return parse_xmp(page.tags[700].value if 700 in page.tags else b""), page.asarray()
    except (OSError, tifffile.TiffFileError, IndexError, ValueError) as error:
        raise CadeError(f"{path}: cannot read it as a TIFF ({error})") from None


def measure_panel(path, *, corners: np.ndarray | None = None, albedo: float | None = None) -> PanelMeasure:
    """The panel in one band file of a panel shot (module docstring for the order of sources).

    Raises:
        CadeError: the square is not found (no tag, no readable QR code) or no albedo is known,
            in one line naming the option that supplies it.
    """
    path = Path(path)
    xmp, raw = _tags(path)
    band = text_of(xmp.get("Camera:BandName", "")).strip() or path.stem
    wavelength = numbers(xmp["Camera:CentralWavelength"])[0] if "Camera:CentralWavelength" in xmp else math.nan
    model = read_radiometric_model(path)
    image = radiance(raw, model)
    qr = None
    if corners is not None:
        found_by = "--panel-corners"
    elif "Camera:ReflectArea" in xmp and len(numbers(xmp["Camera:ReflectArea"])) >= 6:
        corners, found_by = np.array(numbers(xmp["Camera:ReflectArea"]), np.float64).reshape(-1, 2), \
            "camera ReflectArea tag"
    else:
        qr = find_panel_qr(raw)
        if qr is None:
            raise CadeError(f"{path.name}: no panel QR code found in the {band} band and no Camera:ReflectArea tag; "
                            "give the grey square's corners with --panel-corners x1,y1,...")
        corners, found_by = square_from_qr(qr, raw), "QR code"
    mean, std, count = region_stats(image, corners)
    if count == 0 or not mean > 0:
        raise CadeError(f"{path.name}: the panel square at {corners.round().astype(int).tolist()} holds no "
                        "positive radiance; check --panel-corners")
    saturated = int((raw[region_mask(raw.shape, corners)] >= saturation_level(raw)).sum())
    if albedo is not None:
        albedo_from = "--panel-albedo"
    elif "Camera:Albedo" in xmp:
        albedo, albedo_from = numbers(xmp["Camera:Albedo"])[0], "camera Albedo tag"
    else:
        qr = qr or find_panel_qr(raw)
        albedo = albedo_from_qr(qr.text, wavelength) if qr is not None else None
        albedo_from = "QR code line"
        if albedo is None:
            raise CadeError(f"{path.name}: the panel's albedo in {band} is not in its tags or QR code; give the "
                            "values printed on the panel with --panel-albedo")
    return PanelMeasure(band, wavelength, np.asarray(corners, np.float64), found_by, mean, std / mean, count,
                        saturated, float(albedo), albedo_from, panel_irradiance(mean, float(albedo)), model.units)


def parse_albedo(text: str, names: list[str]) -> dict[str, float]:
    """``--panel-albedo``: ``0.51,0.51,...`` in the panel shot's band order, or
    ``Blue=0.513,NIR=0.510`` by band name -> {band name: albedo}; values over 1 are percent.

    Raises:
        CadeError: a count that is not the band count, an unknown band name, or a non-number.
    """
    def number(value: str) -> float:
        try:
            return float(value)
        except ValueError:
            raise CadeError(f"--panel-albedo wants numbers, got {value!r} in {text!r}") from None

    parts = [part.strip() for part in text.split(",") if part.strip()]
    found: dict[str, float] = {}
    if parts and all("=" in part for part in parts):
        lower = {name.lower(): name for name in names}
        for part in parts:
            key, value = (side.strip() for side in part.split("=", 1))
            if key.lower() not in lower:
                raise CadeError(f"--panel-albedo names band {key!r}; the capture has {', '.join(names)}")
            found[lower[key.lower()]] = number(value)
    elif len(parts) == len(names):
        found = {name: number(value) for name, value in zip(names, parts)}
    else:
        raise CadeError(f"--panel-albedo gives {len(parts)} values for {len(names)} bands ({', '.join(names)}); "
                        "give one per band in that order, or NAME=VALUE pairs")
    return {name: value / 100 if value > 1 else value for name, value in found.items()}


def panel_files(paths: list[Path]) -> list[Path]:
    """The band files of a panel shot: ``paths`` as given, or, for one file, it and its siblings
    (same folder, same name up to the last ``_``, same extension: ``IMG_0000_1.tif`` ->
    ``IMG_0000_*.tif``)."""
    paths = [Path(path) for path in paths]
    if len(paths) != 1:
        return paths
    only = paths[0]
    stem, _, _ = only.stem.rpartition("_")
    if not stem:
        return paths
    siblings = sorted(path for path in only.parent.glob(f"{stem}_*{only.suffix}")
                      if path.stem.rpartition("_")[0] == stem)
    return siblings or paths


def panel_irradiances(paths: list[Path], names: list[str], *, corners: dict[str, np.ndarray] | None = None,
                      albedo: dict[str, float] | None = None, units: list[str] | None = None) -> list[PanelMeasure]:
    """The panel as each band of a capture (``names``, its band order) sees it in the panel
    shot ``paths`` (:func:`panel_files`), matched by band name.

    Args:
        corners: per band name (or ``"*"`` for all), the square's corners in the panel shot, px.
        albedo: per band name, the panel's albedo (:func:`parse_albedo`).
        units: per band, the capture's radiometric units: a panel shot whose camera model
            gives other units (a MicaSense panel for a Sequoia capture) is refused.

    Raises:
        CadeError: a band of the capture missing from the panel shot, a panel shot of a camera
            with other radiometric units, or the panel not found.
    """
    by_name: dict[str, Path] = {}
    for path in panel_files(paths):
        xmp, _ = _tags(path)
        by_name[text_of(xmp.get("Camera:BandName", "")).strip().lower()] = path
    corners, albedo = corners or {}, {key.lower(): value for key, value in (albedo or {}).items()}
    measures = []
    for name in names:
        path = by_name.get(name.lower())
        if path is None:
            raise CadeError(f"the panel shot has no {name} band (it has {', '.join(sorted(by_name)) or 'none'}); "
                            "give all of its band files with --panel")
        square = corners.get(name, corners.get(name.lower(), corners.get("*")))
        measure = measure_panel(path, corners=square, albedo=albedo.get(name.lower()))
        if units is not None and measure.units != units[len(measures)]:
            raise CadeError(f"the panel shot's {name} band is in {measure.units}, the capture's in "
                            f"{units[len(measures)]}: give a panel shot of the same camera")
        measures.append(measure)
    return measures
