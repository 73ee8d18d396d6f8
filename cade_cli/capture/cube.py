"""The files of a registered capture: the multi-page cube TIFF (one page per band, in the
capture's band order; band names and wavelengths in its tags; the reference file's XMP and
camera tags carried over, its EXIF GPS and time added to the XMP), the validity mask beside a
uint16 cube, aligned single-band TIFFs with each file's own metadata (``--per-band``), and the
pictures: false colour (NIR, Red, Green) and NDVI with a colour bar.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import tifffile

from cade_cli.capture.register import CaptureRegistration, saturation_level
from cade_cli.errors import CadeError
from cade_cli.io.pictures import ColourBar, Swatch, scaled_picture, with_legend

DTYPES = ("float32", "uint16")
INTERPOLATION = "bilinear"
"""How a band's values are resampled (no overshoot: a registered value lies between the raw
values around it)."""


def mask_path(path: Path) -> Path:
    """The validity mask written beside a uint16 cube: ``IMG_0001.tif`` -> ``IMG_0001.valid.tif``."""
    return path.with_name(f"{path.stem}.valid{path.suffix}")


def _source_tags(path: Path) -> tuple[dict[int, object], dict, dict]:
    """(plain TIFF tags, EXIF dict, GPS dict) of a band file."""
    with tifffile.TiffFile(path) as tiff:
        tags = {tag.code: tag.value for tag in tiff.pages[0].tags.values()}
    return tags, dict(tags.get(34665) or {}), dict(tags.get(34853) or {})


def _degrees(value, reference: str) -> str | None:
    """EXIF (deg, min, sec) rationals -> XMP ``DD,MM.mmmmR``; None for an unset position."""
    try:
        d, m, s = (value[i] / value[i + 1] for i in (0, 2, 4))
    except (TypeError, IndexError, ZeroDivisionError):
        return None
    return f"{int(d)},{m + s / 60 + (d - int(d)) * 60:.6f}{reference}"


def xmp_packet(path: Path) -> bytes:
    """The band file's XMP packet with its EXIF GPS position and capture time added
    (``exif:GPSLatitude`` ...) so that tools reading the XMP find them in a cube whose
    EXIF block is not copied; the packet as it is when it has none of them."""
    tags, exif, gps = _source_tags(path)
    packet = tags.get(700, b"")
    packet = packet.decode("utf-8", "replace") if isinstance(packet, bytes) else str(packet)
    fields = {}
    latitude = _degrees(gps.get("GPSLatitude"), gps.get("GPSLatitudeRef", "N"))
    longitude = _degrees(gps.get("GPSLongitude"), gps.get("GPSLongitudeRef", "E"))
    if latitude and longitude:
        fields["exif:GPSLatitude"], fields["exif:GPSLongitude"] = latitude, longitude
        altitude = gps.get("GPSAltitude")
        if isinstance(altitude, tuple) and altitude[1]:
            fields["exif:GPSAltitude"] = f"{altitude[0]}/{altitude[1]}"
            fields["exif:GPSAltitudeRef"] = str(int(gps.get("GPSAltitudeRef", 0)))
    if exif.get("DateTimeOriginal"):
        date, _, clock = str(exif["DateTimeOriginal"]).partition(" ")
        fields["exif:DateTimeOriginal"] = f"{date.replace(':', '-')}T{clock}"
    end = packet.find("</rdf:RDF>")
    if not fields or end < 0:
        return packet.encode("utf-8")
    attributes = " ".join(f'{key}="{value}"' for key, value in fields.items())
    description = (f'<rdf:Description rdf:about="" xmlns:exif="http://ns.adobe.com/exif/1.0/" {attributes}/>\n')
    return (packet[:end] + description + packet[end:]).encode("utf-8")


def _source_metadata(path: Path, page_name: str) -> dict:
    """``tifffile`` write arguments carrying a band file's metadata onto a page named
    ``page_name``: its XMP (:func:`xmp_packet`), Make, Model and DateTime."""
    tags, _, _ = _source_tags(path)
    extra = [(285, "s", 0, page_name, True), (700, "B", 0, xmp_packet(path), True)]
    for code in (271, 272):
        if tags.get(code):
            extra.append((code, "s", 0, str(tags[code]), True))
    return {"extratags": extra, "datetime": str(tags[306]) if tags.get(306) else None,
            "software": "cade register-capture", "photometric": "minisblack", "metadata": None}


def cube_description(registration: CaptureRegistration, *, dtype: str) -> dict:
    """The JSON the cube's first page holds (ImageDescription)."""
    capture = registration.capture
    return {
        "bands": [{"name": band.name, "wavelength_nm": band.wavelength, "fwhm_nm": band.fwhm,
                   "rig_index": band.rig_index, "source": band.path.name, "black_level": band.black_level,
                   "saturation": saturation_level(raw), "registration": result.path}
                  for band, raw, result in zip(capture.bands, registration.raw, registration.results)],
        "reference": capture.reference_band.name,
        "grid": "the reference band's raw pixels (its lens and metadata still apply)",
        "values": f"raw sensor values, {INTERPOLATION} interpolation; black level not subtracted",
        "not_seen": "NaN" if dtype == "float32" else "0, and 0 in the .valid mask",
        "saturated": "+inf" if dtype == "float32" else "the band's saturation value",
        "capture_id": capture.reference_band.capture_id,
    }


def band_pages(registration: CaptureRegistration, *, dtype: str) -> list[np.ndarray]:
    """One (H, W) page per band: float32 (NaN not seen, +inf saturated) or uint16 (the raw
    values rounded, 0 not seen, the saturation value where saturated)."""
    if dtype not in DTYPES:
        raise CadeError(f"unknown --dtype {dtype!r}; choose one of {', '.join(DTYPES)}")
    pages = []
    for values, valid, saturated, raw in zip(registration.bands, registration.valid, registration.saturated,
                                             registration.raw):
        if dtype == "float32":
            pages.append(np.where(valid & saturated, np.float32(np.inf), values).astype(np.float32))
        else:
            rounded = np.rint(np.clip(np.nan_to_num(values), 0, 65535)).astype(np.uint16)
            rounded[saturated] = saturation_level(raw)
            rounded[~valid] = 0
            pages.append(rounded)
    return pages


def write_cube(path: Path, registration: CaptureRegistration, *, dtype: str = "float32",
               mask: Path | None = None) -> None:
    """Write the cube (and, for uint16, the validity ``mask``: one uint8 page per band, 255 =
    seen) to ``path`` / ``mask`` (temporary paths the caller renames: :mod:`cade_cli.io.atomic`)."""
    capture = registration.capture
    reference = capture.reference_band.path
    description = json.dumps(cube_description(registration, dtype=dtype))
    with tifffile.TiffWriter(path) as writer:
        for index, (band, page) in enumerate(zip(capture.bands, band_pages(registration, dtype=dtype))):
            writer.write(page, description=description if index == 0 else None,
                         **_source_metadata(reference, band.name))
    if mask is not None:
        with tifffile.TiffWriter(mask) as writer:
            for band, valid in zip(capture.bands, registration.valid):
                writer.write(valid.astype(np.uint8) * 255, photometric="minisblack", metadata=None,
                             extratags=[(285, "s", 0, band.name, True)])


def write_per_band(folder: Path, registration: CaptureRegistration, *, dtype: str = "float32") -> list[Path]:
    """One aligned single-band TIFF per band in ``folder``, named as its source file and
    carrying that file's XMP (plus GPS and time) and camera tags. Returns the paths."""
    written = []
    for band, page in zip(registration.capture.bands, band_pages(registration, dtype=dtype)):
        target = folder / band.path.name
        tifffile.imwrite(target, page, **_source_metadata(band.path, band.name))
        written.append(target)
    return written


def _find(registration: CaptureRegistration, *names: str) -> int | None:
    wanted = [name.lower() for name in names]
    for index, band in enumerate(registration.capture.bands):
        if band.name.lower() in wanted:
            return index
    return None


def _signal(registration: CaptureRegistration, index: int) -> np.ndarray:
    """A band's values above its black level, NaN where not seen or saturated."""
    values = registration.bands[index] - np.float32(registration.capture.bands[index].black_level)
    return np.where(registration.saturated[index], np.float32(np.nan), values)


def false_colour_picture(registration: CaptureRegistration) -> np.ndarray:
    """(H, W, 3) uint8 BGR: NIR as red, Red as green, Green as blue, each stretched between its
    1st and 99th percentile; black where a band did not see the pixel or is saturated."""
    order = [_find(registration, "NIR"), _find(registration, "Red"), _find(registration, "Green")]
    if None in order:
        raise CadeError(f"--vis needs NIR, Red and Green bands; the capture has "
                        f"{', '.join(registration.capture.names())}")
    planes = []
    for index in order:
        signal = _signal(registration, index)
        low, high = np.nanpercentile(signal, [1, 99])
        planes.append(np.clip((signal - low) / max(high - low, 1e-6), 0, 1))
    stacked = np.stack(planes[::-1], axis=2)
    picture = np.rint(np.nan_to_num(stacked) * 255).astype(np.uint8)
    picture[~np.isfinite(stacked).all(axis=2)] = 0
    return with_legend(picture, swatches=[Swatch((0, 0, 0), "band not seen or saturated")])


def ndvi_picture(registration: CaptureRegistration) -> np.ndarray:
    """The NDVI, (NIR - Red) / (NIR + Red) of the signals above black level (digital numbers,
    not reflectance), from -1 to 1 with its colour bar; black where either band is missing."""
    nir, red = _find(registration, "NIR"), _find(registration, "Red")
    if nir is None or red is None:
        raise CadeError(f"--ndvi needs NIR and Red bands; the capture has {', '.join(registration.capture.names())}")
    a, b = _signal(registration, nir), _signal(registration, red)
    with np.errstate(divide="ignore", invalid="ignore"):
        ndvi = np.where((a + b) > 0, (a - b) / (a + b), np.nan)
    bar = ColourBar(cv2.COLORMAP_TURBO, -1.0, 1.0, "NDVI of raw signals above black level (not reflectance)")
    return scaled_picture(ndvi, bar, swatches=[Swatch((0, 0, 0), "band not seen or saturated")])


def write_registration(registration: CaptureRegistration, *, cube: Path, dtype: str = "float32",
                       mask: Path | None = None, per_band: Path | None = None, vis: Path | None = None,
                       ndvi: Path | None = None) -> None:
    """Every file of one registered capture to the paths given (the stand-ins of
    :func:`cade_cli.io.atomic.atomic_outputs`, which the caller renames): the cube, the uint16
    cube's ``mask``, the ``per_band`` folder's files, the false-colour and NDVI pictures
    (None: not written)."""
    write_cube(cube, registration, dtype=dtype, mask=mask)
    if per_band is not None:
        write_per_band(per_band, registration, dtype=dtype)
    if vis is not None:
        cv2.imwrite(str(vis), false_colour_picture(registration))
    if ndvi is not None:
        cv2.imwrite(str(ndvi), ndvi_picture(registration))
