"""``cade register-capture``: a drone multispectral capture (one band file per lens) registered
onto its reference band with parallax, as one cube TIFF (docs/drone.md).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli.cli.capture_radiometry import (PanelAlbedoOption, PanelCornersOption, PanelOption, RadianceOption,
                                             ReflectanceOption, build_radiometry, check_radiometry_options)
from cade_cli.cli.options import DEFAULT_METHOD, MethodOption, ModelOption, StepBar, check_output, print_note


def _describe(result) -> str:
    """One band's part of the summary line."""
    if result.path in ("reference", "plane-only", "rig"):
        return f"{result.name}: {result.path}"
    parallax = result.parallax
    direction = f"baseline ({parallax.baseline[0]:+.2f}, {parallax.baseline[1]:+.2f})"
    if result.path == "plane":
        return f"{result.name}: plane (parallax +/-{parallax.spread:.2f} px beyond the matches' noise)"
    return (f"{result.name}: {direction}, parallax {parallax.low:+.1f}..{parallax.high:+.1f} px, searched "
            f"[{result.search[0]}, {result.search[1]}]")


def register_capture(
    files: Annotated[list[Path], typer.Argument(metavar="BAND_FILE...", help="The band files of one capture, any "
                                                "order (e.g. IMG_0001_*.tif): the camera's own TIFFs, whose XMP "
                                                "says which band each is and how its lens sits.", exists=True,
                                                dir_okay=False, show_default=False)],
    output: Annotated[Path, typer.Option("--output", "-o", help="Cube: one TIFF image of N bands (GDAL and QGIS "
                                         "open N named bands) in the capture's band order, on the reference band's "
                                         "raw pixel grid; float32 raw values (bilinear), NaN where a band did not "
                                         "see the pixel (nodata), +inf where saturated; the reference file's EXIF, "
                                         "GPS and XMP carried over (docs/drone.md).", show_default=False)],
    reference: Annotated[Optional[str], typer.Option("--reference", help="Reference band's name (default: Green, "
                                                     "as the vendors).", show_default=False)] = None,
    bands: Annotated[Optional[str], typer.Option("--bands", help="The bands to keep, by name, separated by commas "
                                                 "(e.g. --bands 'Blue,Green,Red,NIR,Red edge' leaves an Altum's LWIR "
                                                 "out); default: every band given.", show_default=False)] = None,
    method: MethodOption = DEFAULT_METHOD,
    model: ModelOption = None,
    plane_only: Annotated[bool, typer.Option("--plane-only", help="One homography per band, fitted to sparse "
                                             "cross-spectral matches, no parallax (the vendors' model, for "
                                             "comparison).")] = False,
    rig_file: Annotated[Optional[Path], typer.Option("--rig", help="A calibrated rig file (docs/rigs.md) whose "
                                                     "cameras, named by band, give the lenses and rotations the "
                                                     "files lack.", exists=True, dir_okay=False,
                                                     show_default=False)] = None,
    dtype: Annotated[str, typer.Option("--dtype", help="float32, or uint16: the input's values rounded (0 where not "
                                       "seen, the sensor's maximum where saturated) with the validity in "
                                       "a mask beside it (-o IMG_0001.tif: IMG_0001.valid.tif, one uint8 page per "
                                       "band, 255 = seen).")
                     ] = "float32",
    per_band: Annotated[Optional[Path], typer.Option("--per-band", help="Also write one aligned single-band TIFF per "
                                                     "band into this folder, named and tagged as its source file.",
                                                     file_okay=False, show_default=False)] = None,
    vis: Annotated[Optional[Path], typer.Option("--vis", help="Also write a false-colour PNG: NIR, Red, Green as red, "
                                                "green, blue.", show_default=False)] = None,
    ndvi: Annotated[Optional[Path], typer.Option("--ndvi", help="Also write an NDVI PNG with its colour bar (of "
                                                 "raw signals above black level, or of --radiance / --reflectance; its "
                                                 "caption says which).", show_default=False)] = None,
    match_scale: Annotated[float, typer.Option("--match-scale", min=0.05, max=1.0, help="Dense matching at this "
                                               "fraction of the resolution (the disparity is brought back to full "
                                               "size).")] = 0.5,
    near: Annotated[float, typer.Option("--near", min=1.0, help="Each band's dense search reaches up to this many "
                                        "times the sparse matches' largest parallax (capped where the matcher would "
                                        "lose resolution), so that objects up to that many times nearer than the "
                                        "nearest match are found; 1: the matches' own range.")] = 4.0,
    radiance: RadianceOption = False,
    reflectance: ReflectanceOption = False,
    panel: PanelOption = None,
    panel_corners: PanelCornersOption = None,
    panel_albedo: PanelAlbedoOption = None,
) -> None:
    """Register the bands of one drone multispectral capture onto its reference band, parallax included."""
    from cade_cli.capture.cube import mask_path
    from cade_cli.capture.model import load_capture, parse_bands
    from cade_cli.capture.register import check_near, matching_scale, register_capture as register
    from cade_cli.matching import get_matcher
    from cade_cli.rigs.rig_file import load_rig

    _check_outputs(files, output, vis=vis, ndvi=ndvi, per_band=per_band, dtype=dtype)
    check_radiometry_options(radiance=radiance, reflectance=reflectance, panel=panel, panel_corners=panel_corners,
                             panel_albedo=panel_albedo, dtype=dtype)
    check_near(near)  # typer's min=1 lets nan through
    if not plane_only:
        get_matcher(method)  # refuse an unknown name before reading anything
    mask = mask_path(output) if dtype == "uint16" else None
    capture = load_capture(files, reference=reference, rig=None if rig_file is None else load_rig(rig_file),
                           bands=parse_bands(bands))
    radiometry, radiometry_lines = build_radiometry(capture, radiance=radiance, reflectance=reflectance, panel=panel,
                                                    panel_corners=panel_corners, panel_albedo=panel_albedo)
    scale = matching_scale(capture, match_scale)
    if scale < match_scale and not plane_only:
        print_note(f"matching at scale {scale:.2f} instead of {match_scale:g}: the bands are "
                   f"{capture.size[0]}x{capture.size[1]} (dense matching keeps to 1.5 MP per band)")
    with StepBar(len(capture.bands), "registering bands") as bar:
        registration = register(capture, plane_only=plane_only, method=method, scale=match_scale, model=model,
                                near=near, radiometry=radiometry,
                                on_band=lambda result: bar.advance(f"{result.name} done"))
    _print_notes(registration)
    _write_outputs(registration, output, mask=mask, per_band=per_band, vis=vis, ndvi=ndvi, dtype=dtype)
    _print_summary(registration, output, how='plane only' if plane_only else f'{method} at scale {scale:.2g}',
                   lines=radiometry_lines)


def _print_notes(registration) -> None:
    """The notes of a registered capture: bands left out or placed another way, second cameras' rotations."""
    from cade_cli.batch.captures import capture_notes

    capture = registration.capture
    for note in capture_notes(capture, {result.name: result.path for result in registration.results}):
        print_note(note)
    for name, angle in capture.linked:
        print_note(f"{name}: rotation against {capture.reference_band.name} measured from the images: {angle:.2f} deg"
                   if angle is not None else f"{name}: a second camera's reference band; the capture is too near to "
                   f"measure its rotation against the first camera (its bands "
                   f"{capture.first_camera_parallax:.1f} px from infinity): its tags' rotations kept, "
                   "the plane fit takes the rest")


def _check_outputs(files: list[Path], output: Path, *, vis: Path | None, ndvi: Path | None, per_band: Path | None,
                   dtype: str) -> None:
    """Refuse an unknown dtype and outputs that would overwrite the inputs, before any work."""
    from cade_cli.capture.cube import DTYPES
    from cade_cli.errors import CadeError

    if dtype not in DTYPES:
        raise CadeError(f"unknown --dtype {dtype!r}; choose one of {', '.join(DTYPES)}")
    check_output(output, suffixes=(".tif", ".tiff"), inputs=tuple(files))
    for picture in (vis, ndvi):
        if picture is not None:
            check_output(picture, suffixes=(".png",), inputs=tuple(files))
    if per_band is not None and any(path.resolve().parent == per_band.resolve() for path in files):
        raise CadeError(f"--per-band {per_band} holds the band files themselves, which it would overwrite; "
                        "give another folder")


def _print_summary(registration, output: Path, *, how: str, lines: list[str]) -> None:
    """The summary line of a registered capture, then ``lines`` (what its values are)."""
    capture = registration.capture
    width, height = capture.size
    seen = ", ".join(f"{band.name} {100 * valid.mean():.0f}%" for band, valid in zip(capture.bands, registration.valid))
    bands = "; ".join(_describe(result) for result in registration.results)
    print(f"{output}: {width}x{height}, {len(capture.bands)} bands onto {capture.reference_band.name} ({how}); "
          f"{bands}; seen: {seen}; {registration.seconds:.1f} s per capture", file=sys.stderr)
    for line in lines:
        print(line, file=sys.stderr)


def _write_outputs(registration, output: Path, *, mask: Path | None, per_band: Path | None, vis: Path | None,
                   ndvi: Path | None, dtype: str) -> None:
    """Every file of one registered capture, all at once or none (:mod:`cade_cli.io.atomic`)."""
    from cade_cli.capture.cube import write_registration
    from cade_cli.io.atomic import atomic_outputs

    with atomic_outputs([output, mask, vis, ndvi], folders=[per_band]) as staged:
        write_registration(registration, cube=staged[output], dtype=dtype,
                           **{name: None if path is None else staged[path]
                              for name, path in (("mask", mask), ("per_band", per_band), ("vis", vis), ("ndvi", ndvi))})
