"""A flight folder as capture jobs (``cade batch --captures``): its captures found
(:func:`find_captures`), the options checked once for the whole flight, one
:class:`~cade_cli.batch.captures.CaptureJob` per capture with calibration panels set aside, and
where each capture's ``--per-band`` files go.
"""

from __future__ import annotations

from pathlib import Path

from cade_cli.batch.captures import CaptureJob, CaptureOptions
from cade_cli.batch.radiometry import check_flight_radiometry
from cade_cli.capture.flight import group_captures
from cade_cli.errors import CadeError


def check_flight_options(captures, options: CaptureOptions) -> None:
    """Refuse once, before any capture runs, a ``--reference`` or ``--bands`` name that no
    capture of the flight has, naming the bands there are, and ``--vis`` / ``--ndvi`` when the
    bands they need are in no capture (or left out by ``--bands``)."""
    there = {}
    for capture in captures:
        for name in capture.bands:
            there.setdefault(name.lower(), name)
    listing = ", ".join(there.values())
    wanted = [("--reference", options.reference)] if options.reference else []
    wanted += [("--bands", name) for name in options.bands or ()]
    for option, name in wanted:
        if name.lower() not in there:
            raise CadeError(f"{option} {name!r}: no capture of the flight has that band (its bands: {listing})")
    kept = {name.lower() for name in options.bands} if options.bands else set(there)
    for option, needs in (("--vis", ("NIR", "Red", "Green")), ("--ndvi", ("NIR", "Red"))):
        lacking = [name for name in needs if name.lower() not in kept]
        if getattr(options, option[2:]) and lacking:
            raise CadeError(f"{option} needs the {', '.join(needs)} bands; the flight's captures (with --bands) "
                            f"have no {', '.join(lacking)}: drop {option} or keep those bands")


def find_captures(folder: Path, output_dir: Path, *, per_band: Path | None = None) -> tuple[list, list[str]]:
    """The captures of a flight folder (:func:`cade_cli.capture.flight.group_captures`: grouped by
    capture id; the output folders left out) and the notes to show (files that are not band files).

    Raises:
        CadeError: no capture in the folder, or a ``per_band`` folder where the aligned files
            (named as the band files) would replace them.
    """
    if per_band is not None and folder.resolve().is_relative_to(per_band.resolve()):
        raise CadeError(f"--per-band {per_band} holds the flight's band files, which the aligned files (named as "
                        "them) would replace; give a folder beside the flight or inside it")
    captures, notes = group_captures(folder, skip=(output_dir,) if per_band is None else (output_dir, per_band))
    if not captures:
        raise CadeError(f"no capture found in {folder}: no TIFF there carries a band name and a capture id in its XMP")
    return captures, notes


def flight_jobs(captures: list, output_dir: Path, options: CaptureOptions, *, skip_panels: bool = False,
                panels: tuple[str, ...] = (), per_band: Path | None = None) -> tuple[list[CaptureJob], list[str]]:
    """The jobs of a flight's captures (:func:`find_captures`; ``<output_dir>/<subfolder>/<name>.tif``
    each) and the notes to show (panels skipped or kept), the options checked once for the flight.

    A capture is a calibration panel when its files say so (``Camera:CalibrationPicture`` 1 or
    2: the Sequoia, and any camera following Pix4D's tags) or when ``panels`` names it (by
    name, capture id or one of its band files: MicaSense RedEdge files carry no such tag). With
    ``skip_panels`` the panels get no job. ``per_band``: a folder for every capture's aligned
    single-band files (``--per-band``), mirroring the flight's subfolders and named as the
    source files.

    Raises:
        CadeError: an option no capture can honour (:func:`check_flight_options`,
            :func:`~cade_cli.batch.radiometry.check_flight_radiometry`), a name in ``panels``
            that is no capture's nor a file.
    """
    check_flight_options(captures, options)
    check_flight_radiometry(captures, options)
    known = {capture.name for capture in captures} | {capture.capture_id for capture in captures}
    unknown = [name for name in panels if name not in known and not Path(name).is_file()]
    if unknown:
        raise CadeError(f"--panel {unknown[0]} names no capture of the flight nor a file; its captures are "
                        f"{', '.join(capture.name for capture in captures[:5])}{' ...' if len(captures) > 5 else ''}")
    panel_paths = {Path(name).resolve() for name in panels if name not in known}
    jobs, notes = [], []
    for capture in captures:
        named = (capture.name in panels or capture.capture_id in panels
                 or any(path.resolve() in panel_paths for path in capture.paths))
        if capture.panel or named:
            why = "tagged Camera:CalibrationPicture" if capture.panel else "named by --panel"
            if skip_panels:
                notes.append(f"{capture.name}: a calibration panel shot ({why}): skipped (--skip-panels)")
                continue
            notes.append(f"{capture.name}: a calibration panel shot ({why}), registered; --skip-panels leaves it out")
        jobs.append(CaptureJob(capture.name, capture.paths, capture.output(output_dir), options, capture.problem,
                               per_band_files(capture, per_band, options.bands)))
    return jobs, notes


def per_band_files(capture, folder: Path | None, bands: tuple[str, ...] | None) -> tuple[Path, ...]:
    """The ``--per-band`` files of a :class:`~cade_cli.capture.flight.FlightCapture` in ``folder``
    (none when None): ``<folder>/<its subfolder>/<source name>`` for each band ``bands`` keeps.

    Raises:
        CadeError: a file that would replace one of the capture's band files.
    """
    if folder is None:
        return ()
    keep = None if not bands else {name.lower() for name in bands}
    targets = tuple(folder / capture.folder / path.name for path, name in zip(capture.paths, capture.bands)
                    if keep is None or name.lower() in keep)
    for target in targets:
        if any(target.resolve() == path.resolve() for path in capture.paths):
            raise CadeError(f"--per-band {folder} would write over the band file {target}; give another folder")
    return targets
