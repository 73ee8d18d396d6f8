"""The radiance and reflectance options of ``cade register-capture`` (``--radiance``,
``--reflectance``, ``--panel``, ``--panel-corners``, ``--panel-albedo``): checked before any
work, turned into a :class:`~cade_cli.capture.radiometry.Radiometry`, and summarised in one
printed line (docs/drone.md, "Radiance and reflectance").
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

RadianceOption = Annotated[bool, typer.Option(
    "--radiance", help="Write radiance instead of raw values: each band converted by its camera's radiometric "
    "model (MicaSense: black level, vignetting, row gradient, exposure, gain, RadiometricCalibration, in "
    "W/m^2/sr/nm; Sequoia: its SensorModel and 2-D vignetting, in Parrot's relative units) before its one "
    "resampling. float32 only.")]
ReflectanceOption = Annotated[bool, typer.Option(
    "--reflectance", help="Write reflectance: pi * radiance / irradiance, the irradiance from the capture's own DLS "
    "tags, or from a panel shot (--panel). float32 only.")]
PanelOption = Annotated[Optional[list[Path]], typer.Option(
    "--panel", metavar="BAND_FILE", help="With --reflectance: the calibration panel shot's band files (one file: "
    "its siblings IMG_0000_*.tif are taken too). The grey square is taken from --panel-corners, else the camera's "
    "ReflectArea tag, else found from the panel's QR code.", exists=True, dir_okay=False, show_default=False)]
PanelCornersOption = Annotated[Optional[list[str]], typer.Option(
    "--panel-corners", metavar="X1,Y1,...", help="The grey square's corners in the panel shot, px: "
    "x1,y1,x2,y2,x3,y3,x4,y4 for every band, or BAND=x1,y1,... for one band (repeat the option).",
    show_default=False)]
PanelAlbedoOption = Annotated[Optional[str], typer.Option(
    "--panel-albedo", metavar="A1,A2,...", help="The panel's albedo per band as printed on it: 0.513,0.513,... in "
    "the capture's band order (rig index: Blue, Green, Red, NIR, Red edge for a RedEdge), or Blue=0.513,NIR=0.510 "
    "(percent accepted). Default: the camera's Albedo tag, else the line the panel's QR code carries.",
    show_default=False)]


def check_radiometry_options(*, radiance: bool, reflectance: bool, panel, panel_corners, panel_albedo,
                             dtype: str) -> None:
    """Refuse contradictory options before any work (one line, non-zero exit)."""
    from cade_cli.errors import CadeError

    if radiance and reflectance:
        raise CadeError("--radiance and --reflectance exclude each other; give one")
    if (radiance or reflectance) and dtype != "float32":
        raise CadeError(f"--{'radiance' if radiance else 'reflectance'} writes float32 values; leave out "
                        f"--dtype {dtype}")
    if panel and not reflectance:
        raise CadeError("--panel gives the irradiance of a reflectance; add --reflectance")
    if (panel_corners or panel_albedo) and not panel:
        raise CadeError("--panel-corners and --panel-albedo describe a panel shot; give it with --panel")


def _corners(options: list[str] | None) -> dict:
    from cade_cli.capture.panel import parse_corners

    found = {}
    for text in options or []:
        name, _, numbers = text.rpartition("=")
        found[name.strip() or "*"] = parse_corners(numbers)
    return found


def build_radiometry(capture, *, radiance: bool, reflectance: bool, panel: list[Path] | None,
                     panel_corners: list[str] | None, panel_albedo: str | None):
    """(the :class:`~cade_cli.capture.radiometry.Radiometry`, or None for raw values; the lines
    to print about it)."""
    from cade_cli.capture.irradiance import dls_irradiances
    from cade_cli.capture.panel import panel_files
    from cade_cli.capture.radiometry import Radiometry

    if not (radiance or reflectance):
        return None, []
    paths, names = [band.path for band in capture.bands], capture.names()
    if radiance:
        radiometry = Radiometry("radiance")
        return radiometry, [f"values: {radiometry.units(paths)}"]
    if not panel:
        irradiance = dls_irradiances(paths, names)
        radiometry = Radiometry("reflectance", tuple(irradiance), "DLS")
        listed = ", ".join(f"{name} {value:.4g}" for name, value in zip(names, irradiance))
        return radiometry, [f"values: reflectance; horizontal irradiance from the capture's DLS tags (W/m^2/nm): "
                            f"{listed}"]
    return panel_radiometry(panel_files(panel), paths, names, panel_corners=panel_corners, panel_albedo=panel_albedo)


def panel_radiometry(files: list[Path], paths: list[Path], names: list[str], *, panel_corners: list[str] | None,
                     panel_albedo: str | None):
    """(the reflectance :class:`~cade_cli.capture.radiometry.Radiometry` by the panel shot ``files``
    for the bands ``names`` whose files are ``paths``, the lines to print about it): the panel
    read and located once, whatever the number of captures it serves."""
    from cade_cli.capture.panel import panel_irradiances, parse_albedo
    from cade_cli.capture.radiometry import Radiometry, read_radiometric_model

    albedo = parse_albedo(panel_albedo, names) if panel_albedo else None
    units = [read_radiometric_model(path).units for path in paths]
    measures = panel_irradiances(files, names, corners=_corners(panel_corners), albedo=albedo, units=units)
    shot = files[0].stem.rpartition("_")[0] or files[0].stem
    radiometry = Radiometry("reflectance", tuple(m.irradiance for m in measures), f"panel {shot}")
    lines = [f"values: reflectance; irradiance from the panel shot {shot}:"]
    for m in measures:
        lines.append(f"  {m.band}: E {m.irradiance:.4g}, panel radiance {m.radiance:.4g} over {m.pixels} px "
                     f"(spread {100 * m.spread:.1f}%, {m.saturated} saturated; square from the {m.found_by}), albedo "
                     f"{m.albedo:.4f} ({m.albedo_from})")
    return radiometry, lines
