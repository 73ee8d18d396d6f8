"""The radiance or reflectance of a flight's captures (``cade batch --captures --radiance`` /
``--reflectance``, docs/drone.md, "A whole flight"): the options checked once per flight on its
first whole capture, the panel shot a ``--panel`` value names, each capture's
:class:`~cade_cli.capture.radiometry.Radiometry`, and the flight's one ``values:`` line.

A reflectance's irradiance is either each capture's own DLS reading, or the panel shot's,
measured once and used for every capture of the flight (MicaSense's own flight workflow): right
only for captures under the panel shot's light.
"""

from __future__ import annotations

from pathlib import Path

from cade_cli.capture.irradiance import dls_irradiances
from cade_cli.capture.panel import panel_files
from cade_cli.capture.radiometry import QUANTITIES, Radiometry, read_radiometric_model
from cade_cli.errors import CadeError


def kept_bands(paths, names, bands: tuple[str, ...] | None) -> tuple[list[Path], list[str]]:
    """(band files, band names) of a capture that ``bands`` (``--bands``; None: all) keeps."""
    keep = None if not bands else {name.lower() for name in bands}
    kept = [(Path(path), name) for path, name in zip(paths, names) if keep is None or name.lower() in keep]
    return [path for path, _ in kept], [name for _, name in kept]


def first_whole_capture(captures):
    """The flight's first capture that is neither a panel shot nor short of a band (else its first)."""
    whole = [capture for capture in captures if capture.problem is None and not capture.panel]
    return (whole or list(captures))[0]


def panel_shot_files(value: str, captures) -> list[Path]:
    """The band files of the panel shot ``value`` names: a capture of the flight (by name or
    capture id) or a band file (its siblings ``<name>_*.tif`` taken too).

    Raises:
        CadeError: neither.
    """
    for capture in captures:
        if value in (capture.name, capture.capture_id):
            return list(capture.paths)
    if Path(value).is_file():
        return panel_files([Path(value)])
    raise CadeError(f"--panel {value}: no capture of the flight has that name or capture id, and it is no file")


def check_flight_radiometry(captures, options) -> None:
    """Refuse once, before any capture runs, radiometry the flight's first whole capture cannot
    give: a band file without its camera's radiometric tags, no DLS reading for a reflectance
    without a panel, or a band the panel shot's irradiance lacks.

    ``options``: a :class:`~cade_cli.batch.captures.CaptureOptions` (``radiometry``, ``irradiance``,
    ``bands``).
    """
    if options.radiometry is None or not captures:
        return
    capture = first_whole_capture(captures)
    paths, names = kept_bands(capture.paths, capture.bands, options.bands)
    for path in paths:
        read_radiometric_model(path)
    if options.radiometry == "reflectance" and options.irradiance is None:
        dls_irradiances(paths, names)
    elif options.irradiance is not None:
        lacking = [name for name in names if name.lower() not in {key.lower() for key in options.irradiance}]
        if lacking:
            raise CadeError(f"the panel shot has no {', '.join(lacking)} band (it has "
                            f"{', '.join(options.irradiance)}); give a panel shot of the flight's camera")


def capture_radiometry(options, paths: list[Path], names: list[str]) -> Radiometry | None:
    """The conversion of one capture's bands (``paths``, ``names``: its bands kept, in its order):
    None for raw values; radiance; reflectance by the irradiance of its own DLS tags, or of the
    flight's panel shot (``options.irradiance``, band name -> E).

    Raises:
        CadeError: no DLS reading in a band (the capture fails alone).
    """
    if options.radiometry is None:
        return None
    if options.radiometry == "radiance":
        return Radiometry("radiance")
    if options.irradiance is None:
        return Radiometry("reflectance", tuple(dls_irradiances(paths, names)), "DLS")
    by_name = {key.lower(): value for key, value in options.irradiance.items()}
    missing = [name for name in names if name.lower() not in by_name]
    if missing:
        raise CadeError(f"the panel shot has no {', '.join(missing)} band; give a panel shot of this camera")
    return Radiometry("reflectance", tuple(by_name[name.lower()] for name in names), options.irradiance_source)


def values_note(options, captures) -> str | None:
    """The flight's one line on what its cubes' values are (None: raw values)."""
    if options.radiometry is None:
        return None
    if options.radiometry == "radiance":
        capture = first_whole_capture(captures)
        paths, _ = kept_bands(capture.paths, capture.bands, options.bands)
        return f"values: {Radiometry('radiance').units(paths)}, every capture"
    if options.irradiance is None:
        return ("values: reflectance; horizontal irradiance from each capture's own DLS tags (W/m^2/nm, in each "
                "capture's record and cube description)")
    return (f"values: reflectance; the irradiance of the {options.irradiance_source} for every capture of the "
            "flight (right only for captures under the panel shot's light)")


def check_quantity(radiometry: str | None, dtype: str, irradiance) -> None:
    """Refuse an unknown quantity, converted values in uint16, a panel's irradiance without a reflectance."""
    if radiometry is not None and radiometry not in QUANTITIES:
        raise CadeError(f"unknown radiometric quantity {radiometry!r}; choose one of {', '.join(QUANTITIES)}")
    if radiometry is not None and dtype != "float32":
        raise CadeError(f"--{radiometry} writes float32 values; leave out --dtype {dtype}")
    if irradiance is not None and radiometry != "reflectance":
        raise CadeError("a panel's irradiance gives a reflectance; add --reflectance")
