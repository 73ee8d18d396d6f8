"""What a drone multispectral band file says about itself: its XMP packet (TIFF tag 700, the
Pix4D ``Camera:`` namespace, MicaSense's and Parrot's own) and EXIF, read with tifffile into a
:class:`BandFile`: band name and centre wavelength, rig index, capture id, lens model and
rotation, black level; DJI's ``drone-dji`` tags through :mod:`cade_cli.capture.dji`. A missing
tag is a :class:`~cade_cli.errors.CadeError` naming the field and the option that supplies it
(docs/drone.md). Files cade wrote (TIFF ``Software`` tag starting ``cade``) can be refused
(:class:`CadeOutputFile`), so that a flight never takes its own outputs as inputs.
"""

from __future__ import annotations

import contextlib
import logging
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tifffile

from cade_cli.capture.dji import dji_band, dji_lens, dji_radiometry, dji_rotation, is_dji
from cade_cli.capture.lens import BrownLens, FisheyeLens, Lens, rig_relatives_rotation
from cade_cli.errors import CadeError

NAMESPACES = {"http://pix4d.com/camera/": "Camera", "http://micasense.com/MicaSense/": "MicaSense",
              "http://micasense.com/DLS/": "DLS", "http://www.parrot.com/": "Parrot",
              "http://www.dji.com/drone-dji/": "drone-dji"}
"""Namespace URI prefixes and the prefix names tags are read under (Parrot and MicaSense
differ by a trailing slash and version: only the start is compared)."""

RDF = "{http://www.w3.org/1999/02/22-rdf-syntax-ns#}"
RIG_OPTION = "--rig rig.json"
"""The option that supplies a camera's geometry when its files do not."""
CADE_SOFTWARE = "cade"
"""The start of the TIFF ``Software`` tag (305) of every file cade writes (the cube writer's
``cade register-capture``): how a flight tells its own outputs from a camera's files."""


class CadeOutputFile(CadeError):
    """A TIFF cade wrote, refused where only a camera's own files are wanted."""


@contextlib.contextmanager
def quiet_tifffile():
    """tifffile's own log messages (e.g. ``invalid offset to first page`` for a file cut short)
    held back while a file is read: the reader's one line says what is wrong instead."""
    logger = logging.getLogger("tifffile")
    disabled, logger.disabled = logger.disabled, True
    try:
        yield
    finally:
        logger.disabled = disabled


def _prefix(uri: str) -> str:
    for start, name in NAMESPACES.items():
        if uri.startswith(start):
            return name
    return uri


def _key(tag: str) -> str:
    """``{uri}Local`` -> ``Prefix:Local``."""
    if tag.startswith("{"):
        uri, local = tag[1:].split("}", 1)
        return f"{_prefix(uri)}:{local}"
    return tag


def parse_xmp(packet: bytes | str) -> dict[str, str | list[str]]:
    """The properties of an XMP packet: ``{"Camera:BandName": "Red", ...}``; a property given
    as an ``rdf:Seq``/``Bag``/``Alt`` is its list of items; both the element form (MicaSense)
    and the attribute form (Parrot) are read. An unreadable packet gives {}."""
    text = packet.decode("utf-8", "replace") if isinstance(packet, bytes) else packet
    start, end = text.find("<x:xmpmeta"), text.rfind("</x:xmpmeta>")
    if start < 0 or end < 0:
        return {}
    try:
        root = ElementTree.fromstring(text[start:end + len("</x:xmpmeta>")])
    except ElementTree.ParseError:
        return {}
    found: dict[str, str | list[str]] = {}
    for description in root.iter(f"{RDF}Description"):
        for name, value in description.attrib.items():
            if not name.startswith(RDF):
                found[_key(name)] = value
        for child in description:
            items = [item.text or "" for item in child.iter(f"{RDF}li")]
            found[_key(child.tag)] = items if items else (child.text or "").strip()
    return found


def numbers(value: str | list[str]) -> list[float]:
    """The numbers of a property: ``"1, 2, 3"``, ``["1", "2"]`` or ``["1,2,3"]`` -> [1.0, 2.0, 3.0]."""
    text = ",".join(value) if isinstance(value, list) else value
    return [float(part) for part in text.replace(",", " ").split()]


def text_of(value: str | list[str]) -> str:
    """A one-item ``rdf:Seq`` (Parrot) or plain text (MicaSense) as text."""
    return (value[0] if value else "") if isinstance(value, list) else value


@dataclass(frozen=True)
class BandFile:
    """One band file of a capture, as its metadata describes it.

    Attributes:
        path: the file.
        name: band name (``Camera:BandName``), e.g. ``"Green"``, ``"NIR"``.
        wavelength: centre wavelength, nm; fwhm: its width, nm (None when not given).
        rig_index: ``Camera:RigCameraIndex`` (the capture's band order).
        capture_id: ``MicaSense:CaptureId`` or Parrot's ``Camera:CaptureUUID``; None when absent.
        camera: ``Make Model`` from the TIFF tags.
        size: (width, height), px.
        lens: its lens model; None when the file has none (``--rig``).
        rotation: (3, 3) rotation of this camera relative to the rig reference (Green),
            ``X_band = rotation @ X_reference``; None when the file gives none.
        black_level: mean of the DNG ``BlackLevel`` values (tag 50714), raw units; 0 when absent.
        calibration_picture: ``Camera:CalibrationPicture`` (Pix4D's tag, written by the
            Sequoia): 0 an ordinary shot, 1 or 2 a radiometric calibration target (a panel);
            None when absent (MicaSense RedEdge files do not carry it).
        rotation_reference: ``Camera:RigRelativesReferenceRigCameraIndex``, the rig index
            ``RigRelatives`` are relative to (the RedEdge-MX Dual's second camera: 6,
            Green-531); None when absent (the rig reference).
        serial: the camera body's serial (EXIF BodySerialNumber), None when absent.
        software: the TIFF Software tag ("" when absent).
        radiometry: DJI's radiometric tags (:func:`cade_cli.capture.dji.dji_radiometry`), {}
            for other cameras.
    """

    path: Path
    name: str
    wavelength: float
    fwhm: float | None
    rig_index: int
    capture_id: str | None
    camera: str
    size: tuple[int, int]
    lens: Lens | None
    rotation: np.ndarray | None
    black_level: float
    calibration_picture: int | None = None
    rotation_reference: int | None = None
    serial: str | None = None
    software: str = ""
    radiometry: dict = field(default_factory=dict, compare=False)


class _Fields:
    """Reads one file's required properties; a missing one is one line naming it."""

    def __init__(self, path: Path, xmp: dict, exif: dict) -> None:
        self.path, self.xmp, self.exif = path, xmp, exif

    def missing(self, field: str, supply: str) -> CadeError:
        return CadeError(f"{self.path.name}: no {field} in its metadata; {supply}")

    def text(self, field: str, supply: str) -> str:
        if field not in self.xmp or not text_of(self.xmp[field]).strip():
            raise self.missing(field, supply)
        return text_of(self.xmp[field]).strip()

    def numbers(self, field: str, count: int, supply: str) -> list[float]:
        if field not in self.xmp:
            raise self.missing(field, supply)
        try:
            values = numbers(self.xmp[field])
        except ValueError:
            values = []
        if len(values) < count:
            raise CadeError(f"{self.path.name}: {field} should hold {count} numbers, it holds "
                            f"{self.xmp[field]!r}; {supply}")
        return values[:count]

    def pixel_pitch(self) -> float:
        """Pixels per mm from EXIF (or TIFF/EP) FocalPlaneXResolution (unit 4 = mm, 3 = cm)."""
        value, unit = self.exif.get("FocalPlaneXResolution"), self.exif.get("FocalPlaneResolutionUnit", 4)
        if not value or unit not in (3, 4):
            raise self.missing("EXIF FocalPlaneXResolution (in mm or cm)", f"give the lenses with {RIG_OPTION}")
        resolution = value[0] / value[1] if isinstance(value, tuple) else float(value)
        return resolution if unit == 4 else resolution / 10


def _lens(fields: _Fields) -> Lens:
    supply = f"give the lenses with {RIG_OPTION}"
    model = fields.text("Camera:ModelType", supply).lower()
    per_mm = fields.pixel_pitch()
    cx, cy = (value * per_mm for value in fields.numbers("Camera:PrincipalPoint", 2, supply))
    if model == "perspective":
        focal = fields.numbers("Camera:PerspectiveFocalLength", 1, supply)[0]
        units = text_of(fields.xmp.get("Camera:PerspectiveFocalLengthUnits", "mm")).strip().lower()
        focal_px = focal * per_mm if units == "mm" else focal
        k1, k2, k3, p1, p2 = fields.numbers("Camera:PerspectiveDistortion", 5, supply)
        return BrownLens(focal_px, (cx, cy), k1, k2, k3, p1, p2)
    if model == "fisheye":
        focal = fields.exif.get("FocalLength")
        if not focal:
            raise fields.missing("EXIF FocalLength", supply)
        focal_mm = focal[0] / focal[1] if isinstance(focal, tuple) else float(focal)
        polynomial = fields.numbers("Camera:FisheyePolynomial", 4, supply)
        affine = fields.numbers("Camera:FisheyeAffineMatrix", 4, supply)
        return FisheyeLens(focal_mm * per_mm, (cx, cy), tuple(polynomial), tuple(affine))
    raise CadeError(f"{fields.path.name}: unknown Camera:ModelType {model!r} (known: perspective, fisheye); "
                    f"{supply}")


def _rotation(fields: _Fields, rig_index: int) -> np.ndarray | None:
    """The lens rotation; Parrot leaves ``RigRelatives`` out for its reference (index 0)."""
    if "Camera:RigRelatives" not in fields.xmp:
        return np.eye(3) if fields.exif.get("_make") == "Parrot" and rig_index == 0 else None
    angles = fields.numbers("Camera:RigRelatives", 3, f"give the rotations with {RIG_OPTION}")
    return rig_relatives_rotation(angles).T  # the vendor maps band rays to reference rays with R


def _band(fields: _Fields) -> tuple[str, float, float | None, int]:
    """(name, centre wavelength, width, rig index) from the ``Camera:`` tags, or DJI's."""
    xmp = fields.xmp
    if "Camera:BandName" not in xmp and is_dji(xmp):
        band = dji_band(xmp)
        if band is None:
            raise fields.missing("drone-dji:BandName (or BandFreq, SensorIndex)", "give the camera's own files")
        return band
    name = fields.text("Camera:BandName", "give the camera's own files (the band name is in their XMP)")
    wavelength = fields.numbers("Camera:CentralWavelength", 1, "give the camera's own files")[0]
    fwhm = numbers(xmp["Camera:WavelengthFWHM"])[0] if "Camera:WavelengthFWHM" in xmp else None
    rig_index = int(fields.numbers("Camera:RigCameraIndex", 1, f"give the bands' order with {RIG_OPTION}")[0])
    return name, wavelength, fwhm, rig_index


def _geometry(fields: _Fields, rig_index: int) -> tuple[Lens, np.ndarray | None]:
    """The lens and rotation: the ``Camera:`` tags, or DJI's ``DewarpData`` and alignment tags."""
    xmp = fields.xmp
    if "Camera:ModelType" not in xmp and is_dji(xmp):
        lens = dji_lens(xmp)
        if lens is None:
            raise fields.missing("drone-dji:DewarpData and CalibratedOpticalCenterX/Y",
                                 f"give the lenses with {RIG_OPTION}")
        return lens, _rotation(fields, rig_index) if "Camera:RigRelatives" in xmp else dji_rotation(xmp, lens)
    return _lens(fields), _rotation(fields, rig_index)


def read_first_page_tags(path: Path) -> tuple[dict[int, object], tuple[int, ...]]:
    """(tags of the first page, its shape); one line naming the file when it is no readable
    TIFF (tifffile's own messages held back)."""
    try:
        with quiet_tifffile(), tifffile.TiffFile(path) as tiff:
            page = tiff.pages[0] if len(tiff.pages) else None
            found = None if page is None else ({tag.code: tag.value for tag in page.tags.values()}, tuple(page.shape))
    except (OSError, tifffile.TiffFileError, IndexError, ValueError, KeyError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise CadeError(f"{path.name}: cannot read it as a TIFF ({reason}); give the camera's band files") from None
    if found is None:
        raise CadeError(f"{path.name}: a TIFF with no image in it (cut short?); give the camera's band files")
    return found


def read_band_file(path: Path | str, *, need_geometry: bool = True, own_outputs: bool = True) -> BandFile:
    """The :class:`BandFile` of one band TIFF.

    Args:
        path: a single-band TIFF written by the camera.
        need_geometry: False reads the lens and rotation only when present (``--rig``
            supplies the rest); True requires them.
        own_outputs: False refuses a file cade wrote (:class:`CadeOutputFile`: its Software
            tag starts with :data:`CADE_SOFTWARE`) before anything else is read.

    Raises:
        CadeError: not a readable TIFF, not one band, or a required property missing,
            in one line naming the property and the option that supplies it.
    """
    path = Path(path)
    tags, shape = read_first_page_tags(path)
    software = str(tags.get(305, "")).strip()
    if not own_outputs and software.lower().startswith(CADE_SOFTWARE):
        raise CadeOutputFile(f"{path.name}: written by cade (Software {software!r}), not a camera's band file")
    if len(shape) != 2:
        raise CadeError(f"{path.name} has shape {shape}; a band file holds one band (H, W)")
    xmp = parse_xmp(tags.get(700, b""))
    if not xmp:
        raise CadeError(f"{path.name}: no XMP packet (TIFF tag 700) with the camera's band tags; "
                        f"give the camera's own files, or the geometry with {RIG_OPTION} and the files' band tags")
    exif = dict(tags.get(34665) or {})
    for code, name in ((37390, "FocalPlaneXResolution"), (37392, "FocalPlaneResolutionUnit"), (37386, "FocalLength")):
        if name not in exif and code in tags:  # TIFF/EP keeps them in the image's own tags
            exif[name] = tags[code]
    exif["_make"] = str(tags.get(271, "")).strip()
    fields = _Fields(path, xmp, exif)
    name, wavelength, fwhm, rig_index = _band(fields)
    capture_id = xmp.get("MicaSense:CaptureId") or xmp.get("Camera:CaptureUUID") or xmp.get("drone-dji:CaptureUUID")
    if need_geometry:
        lens, rotation = _geometry(fields, rig_index)
    else:  # --rig supplies them: what the file has is not needed
        try:
            lens, rotation = _geometry(fields, rig_index)
        except CadeError:
            lens = rotation = None
    if rotation is None and need_geometry:
        raise fields.missing("Camera:RigRelatives", f"give the lens rotations with {RIG_OPTION}")
    black = tags.get(50714)
    black_level = float(np.mean(black)) if black is not None else 0.0
    camera = f"{str(tags.get(271, '')).strip()} {str(tags.get(272, '')).strip()}".strip()
    calibration = text_of(xmp.get("Camera:CalibrationPicture", "")).strip()
    reference = text_of(xmp.get("Camera:RigRelativesReferenceRigCameraIndex", "")).strip()
    serial = exif.get("BodySerialNumber") or tags.get(42033) or text_of(xmp.get("Camera:BodySerialNumber", ""))
    return BandFile(path, name, wavelength, fwhm, rig_index, text_of(capture_id) if capture_id else None,
                    camera, (int(shape[1]), int(shape[0])), lens, rotation, black_level,
                    int(calibration) if calibration.isdigit() else None,
                    int(reference) if reference.lstrip("-").isdigit() else None,
                    str(serial).strip() or None, software, dji_radiometry(xmp) if is_dji(xmp) else {})
