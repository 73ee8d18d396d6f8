"""The files of a registered capture: the cube TIFF (one image of N samples, planar, that GDAL
opens as N bands: band names and the nodata value in GDAL's own tags, names and wavelengths in
its JSON description and XMP, the reference file's EXIF and GPS), the validity mask beside a
uint16 cube, aligned single-band TIFFs with each band's own metadata (``--per-band``), and the
pictures: false colour (NIR, Red, Green) and NDVI with a colour bar (docs/drone.md, "Metadata
the mapping tools read").
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import escape

import cv2
import numpy as np
import tifffile

from cade_cli.capture.exif import GEOMETRY_EXIF, Entry, SourceExif, add_tags, rational_entry, read_source_exif
from cade_cli.capture.radiometry import describe as describe_radiometry, values_label
from cade_cli.capture.register import CaptureRegistration, saturation_level
from cade_cli.capture.xmp import band_packet, cube_packet, one_band_properties
from cade_cli.errors import CadeError
from cade_cli.io.pictures import ColourBar, Swatch, scaled_picture, with_legend

DTYPES = ("float32", "uint16")
INTERPOLATION = "bilinear"
"""How a band's values are resampled (no overshoot: a registered value lies between the raw
values around it)."""
GDAL_METADATA, GDAL_NODATA = 42112, 42113
"""GDAL's private TIFF tags: its metadata XML (band descriptions, wavelengths) and the nodata value."""
SOFTWARE = "cade register-capture"


def mask_path(path: Path) -> Path:
    """The validity mask written beside a uint16 cube: ``IMG_0001.tif`` -> ``IMG_0001.valid.tif``."""
    return path.with_name(f"{path.stem}.valid{path.suffix}")


def _packet(path: Path) -> bytes:
    """The band file's XMP packet (TIFF tag 700), empty when it has none."""
    with tifffile.TiffFile(path) as tiff:
        tag = tiff.pages[0].tags.get(700)
        value = b"" if tag is None else tag.value
    return value if isinstance(value, bytes) else str(value).encode("utf-8")


def gdal_metadata(names: Sequence[str], wavelengths: Sequence[float | None] = (),
                  fwhms: Sequence[float | None] = ()) -> str:
    """GDAL's metadata XML (tag 42112): each sample's description (the band name), and its centre
    wavelength and width in GDAL's IMAGERY domain (micrometres) where known."""
    items = []
    for sample, name in enumerate(names):
        items.append(f'<Item name="DESCRIPTION" sample="{sample}" role="description">{escape(name)}</Item>')
        for key, values in (("CENTRAL_WAVELENGTH_UM", wavelengths), ("FWHM_UM", fwhms)):
            if sample < len(values) and values[sample] is not None:
                items.append(f'<Item name="{key}" sample="{sample}" domain="IMAGERY">{values[sample] / 1000:g}</Item>')
    return "<GDALMetadata>" + "".join(items) + "</GDALMetadata>"


def nodata_text(dtype: str) -> str:
    """GDAL's nodata value (tag 42113, ASCII) of a cube: NaN for float32, 0 for uint16 (not seen)."""
    return "nan" if dtype == "float32" else "0"


def _source_entries(source: SourceExif, *, geometry: SourceExif, black_levels: Sequence[float] | None = None,
                    converted: bool = False) -> dict:
    """``add_tags`` arguments carrying ``source``'s EXIF (``geometry``'s lens: FocalLength and
    FocalPlane resolution, the lens the pixels now have), GPS only with a fix; ``black_levels``:
    one BlackLevel per sample instead of the source's pattern; ``converted``: the values are
    radiance or reflectance, no BlackLevel."""
    main = dict(source.main)
    if converted:
        main.pop(50713, None)
        main.pop(50714, None)
    elif black_levels is not None:
        main[50713] = Entry(50713, 3, (1, 1))
        main[50714] = rational_entry(50714, black_levels)
    exif = dict(source.exif)
    for code in GEOMETRY_EXIF:
        if code in geometry.exif:
            exif[code] = geometry.exif[code]
        else:
            exif.pop(code, None)
    return {"main": list(main.values()), "exif": list(exif.values()),
            "gps": list(source.gps.values()) if source.has_fix() else []}


def _exposure(source: SourceExif) -> dict:
    """A band's exposure time (s) and ISO from its EXIF (None when absent)."""
    exposure = source.exif.get(33434)
    iso = source.exif.get(34867) or source.exif.get(34855)
    return {"exposure_s": exposure.numbers()[0] if exposure is not None else None,
            "iso": int(iso.numbers()[0]) if iso is not None else None}


def cube_description(registration: CaptureRegistration, *, dtype: str) -> dict:
    """The JSON the cube holds (ImageDescription): per band its name, wavelengths, source file,
    black level, saturation, how it was registered, exposure and ISO, and the XMP tags of that
    band alone (calibration, irradiance), which the cube's XMP cannot hold per band."""
    capture = registration.capture
    return {
        "bands": [{"name": band.name, "wavelength_nm": band.wavelength, "fwhm_nm": band.fwhm,
                   "rig_index": band.rig_index, "source": band.path.name, "black_level": band.black_level,
                   "saturation": saturation_level(raw), "registration": result.path,
                   **_exposure(read_source_exif(band.path)), "xmp": one_band_properties(_packet(band.path))}
                  for band, raw, result in zip(capture.bands, registration.raw, registration.results)],
        "reference": capture.reference_band.name,
        "grid": "the reference band's raw pixels: its lens (distortion included) describes every band",
        "values": (f"raw sensor values, {INTERPOLATION} interpolation; black level not subtracted"
                   if registration.radiometry is None else
                   f"{registration.radiometry.units([band.path for band in capture.bands])}, {INTERPOLATION} "
                   "interpolation (converted before the one resampling)"),
        "radiometry": describe_radiometry(registration.radiometry, [band.path for band in capture.bands]),
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


def _write_samples(path: Path, stack: np.ndarray, *, names: Sequence[str], description: str | None = None,
                   xmp: bytes | None = None, nodata: str | None = None, wavelengths: Sequence[float | None] = (),
                   fwhms: Sequence[float | None] = ()) -> None:
    """``stack`` ((N, H, W) or (H, W)) as one image of N samples, planar, black is zero, with
    GDAL's band descriptions (and ``nodata``), a classic TIFF (its EXIF is patched in after)."""
    extra = [(GDAL_METADATA, "s", 0, gdal_metadata(names, wavelengths, fwhms), True)]
    if nodata is not None:
        extra.append((GDAL_NODATA, "s", 0, nodata, True))
    if xmp is not None:
        extra.append((700, "B", len(xmp), xmp, True))
    tifffile.imwrite(path, stack, photometric="minisblack", planarconfig="separate" if stack.ndim == 3 else None,
                     description=description, metadata=None, software=SOFTWARE, extratags=extra, bigtiff=False)


def write_cube(path: Path, registration: CaptureRegistration, *, dtype: str = "float32",
               mask: Path | None = None) -> None:
    """Write the cube (and, for uint16, the validity ``mask``: one uint8 sample per band, 255 =
    seen) to ``path`` / ``mask`` (temporary paths the caller renames: :mod:`cade_cli.io.atomic`).

    The cube is one image of N samples (planar configuration separate), GDAL's tags naming each
    band and its nodata value (NaN, or 0 for uint16), the JSON :func:`cube_description`, the
    reference's XMP (:func:`~cade_cli.capture.xmp.cube_packet`) and its EXIF and GPS (no GPS
    without a fix), one BlackLevel per band.
    """
    capture = registration.capture
    reference = capture.reference_band
    names = capture.names()
    wavelengths, fwhms = [b.wavelength for b in capture.bands], [b.fwhm for b in capture.bands]
    source = read_source_exif(reference.path)
    xmp = cube_packet(_packet(reference.path), reference_index=reference.rig_index, names=names,
                      wavelengths=wavelengths, fwhms=fwhms, exif=source)
    _write_samples(path, np.stack(band_pages(registration, dtype=dtype)), names=names,
                   description=json.dumps(cube_description(registration, dtype=dtype)), xmp=xmp,
                   nodata=nodata_text(dtype), wavelengths=wavelengths, fwhms=fwhms)
    add_tags(path, **_source_entries(source, geometry=source, black_levels=[b.black_level for b in capture.bands],
                                     converted=getattr(registration, "radiometry", None) is not None))
    if mask is not None:
        _write_samples(mask, np.stack([valid.astype(np.uint8) * 255 for valid in registration.valid]),
                       names=[f"seen: {name}" for name in names])


def write_per_band(targets: Path | Sequence[Path], registration: CaptureRegistration, *,
                   dtype: str = "float32") -> list[Path]:
    """One aligned single-band TIFF per band: in the folder ``targets``, named as its source
    file, or at the paths ``targets`` (one per band, in the capture's band order). Each carries
    its band's XMP with the reference's lens and a zero rig rotation
    (:func:`~cade_cli.capture.xmp.band_packet`), its own EXIF (exposure, ISO, black level, time;
    GPS with a fix) with the reference's FocalLength and FocalPlane resolution, and GDAL's band
    description and nodata. Returns the paths."""
    capture = registration.capture
    reference = capture.reference_band
    if isinstance(targets, Path):
        targets = [targets / band.path.name for band in capture.bands]
    if len(targets) != len(capture.bands):
        raise ValueError(f"{len(targets)} per-band paths for {len(capture.bands)} bands")  # a caller's bug
    geometry = read_source_exif(reference.path)
    reference_packet = _packet(reference.path)
    converted = getattr(registration, "radiometry", None) is not None
    for band, page, target in zip(capture.bands, band_pages(registration, dtype=dtype), targets):
        source = read_source_exif(band.path)
        xmp = band_packet(_packet(band.path), reference_packet, reference_index=reference.rig_index, exif=source,
                          converted=converted)
        _write_samples(target, page, names=[band.name], xmp=xmp, nodata=nodata_text(dtype),
                       wavelengths=[band.wavelength], fwhms=[band.fwhm])
        add_tags(target, **_source_entries(source, geometry=geometry, converted=converted))
    return list(targets)


def _find(registration: CaptureRegistration, *names: str) -> int | None:
    wanted = [name.lower() for name in names]
    for index, band in enumerate(registration.capture.bands):
        if band.name.lower() in wanted:
            return index
    return None


def _signal(registration: CaptureRegistration, index: int) -> np.ndarray:
    """A band's values above its black level (radiance or reflectance as they are), NaN where
    not seen or saturated."""
    values = registration.bands[index]
    if registration.radiometry is None:
        values = values - np.float32(registration.capture.bands[index].black_level)
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
    return with_legend(picture, lines=[f"NIR, Red, Green as red, green, blue: {values_label(registration.radiometry)}"],
                       swatches=[Swatch((0, 0, 0), "band not seen or saturated")])


def ndvi_picture(registration: CaptureRegistration) -> np.ndarray:
    """The NDVI, (NIR - Red) / (NIR + Red) of the signals above black level (digital numbers,
    not reflectance), from -1 to 1 with its colour bar; black where either band is missing."""
    nir, red = _find(registration, "NIR"), _find(registration, "Red")
    if nir is None or red is None:
        raise CadeError(f"--ndvi needs NIR and Red bands; the capture has {', '.join(registration.capture.names())}")
    a, b = _signal(registration, nir), _signal(registration, red)
    with np.errstate(divide="ignore", invalid="ignore"):
        ndvi = np.where((a + b) > 0, (a - b) / (a + b), np.nan)
    bar = ColourBar(cv2.COLORMAP_TURBO, -1.0, 1.0, f"NDVI of {values_label(registration.radiometry)}")
    return scaled_picture(ndvi, bar, swatches=[Swatch((0, 0, 0), "band not seen or saturated")])


def write_registration(registration: CaptureRegistration, *, cube: Path, dtype: str = "float32",
                       mask: Path | None = None, per_band: Path | Sequence[Path] | None = None,
                       vis: Path | None = None, ndvi: Path | None = None) -> None:
    """Every file of one registered capture to the paths given (the stand-ins of
    :func:`cade_cli.io.atomic.atomic_outputs`, which the caller renames): the cube, the uint16
    cube's ``mask``, the ``per_band`` files (a folder, or one path per band: :func:`write_per_band`),
    the false-colour and NDVI pictures (None: not written)."""
    write_cube(cube, registration, dtype=dtype, mask=mask)
    if per_band is not None:
        write_per_band(per_band, registration, dtype=dtype)
    if vis is not None:
        cv2.imwrite(str(vis), false_colour_picture(registration))
    if ndvi is not None:
        cv2.imwrite(str(ndvi), ndvi_picture(registration))
