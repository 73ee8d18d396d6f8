"""A flight folder's band files grouped into captures by the capture id in their metadata
(``MicaSense:CaptureId``, Parrot's ``Camera:CaptureUUID``), not by their names; which captures
are calibration-panel shots; a capture missing one of its camera's bands (the bands the
flight's other captures by the same camera body have, the rig indices its own bands refer to,
the bands of a known camera model); files cade wrote left out: the input of
``cade batch --captures`` (:mod:`cade_cli.batch.captures`).
"""

from __future__ import annotations

import collections
import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from cade_cli.capture.metadata import BandFile, CadeOutputFile, read_band_file
from cade_cli.errors import CadeError

BAND_SUFFIXES = (".tif", ".tiff")
CAMERA_BANDS = {
    "MicaSense RedEdge": {0: "Blue", 1: "Green", 2: "Red", 3: "NIR", 4: "Red edge"},
    "MicaSense RedEdge-M": {0: "Blue", 1: "Green", 2: "Red", 3: "NIR", 4: "Red edge"},
    "MicaSense RedEdge-MX": {0: "Blue", 1: "Green", 2: "Red", 3: "NIR", 4: "Red edge"},
    "MicaSense Altum": {0: "Blue", 1: "Green", 2: "Red", 3: "NIR", 4: "Red edge", 5: "LWIR"},
    "MicaSense RedEdge-P": {0: "Blue", 1: "Green", 2: "Red", 3: "NIR", 4: "Red edge", 5: "Panchro"},
    "Parrot Sequoia": {0: "Green", 1: "Red", 2: "Red edge", 3: "NIR"},
}
"""The bands (rig index -> name) every capture of a camera model has at least (EXIF ``Make
Model``): the RedEdge-M's and Sequoia's as their files here say; the Altum's and RedEdge-P's
sixth band as MicaSense documents it (docs/drone.md, "Other cameras"). A RedEdge-MX Dual
reports the model ``RedEdge-M``: its first camera's five bands."""


@dataclass(frozen=True)
class FlightCapture:
    """One capture of a flight.

    Attributes:
        name: the name most of its band files share before their band suffix (``IMG_0001``
            for ``IMG_0001_1.tif`` ..., ``IMG_180413_080658_0000`` for the Sequoia's
            ``..._GRE.TIF``), its first file's name where other captures share that name
            (DJI numbers every file: ``DJI_0011`` for ``DJI_0011.TIF`` .. ``DJI_0015.TIF``), or
            the capture id where no name holds a majority.
        folder: the folder of its files, relative to the flight folder.
        capture_id: from the metadata.
        paths: its band files.
        bands: their band names, in the order of ``paths``.
        panel: its files say it is a radiometric calibration target (``Camera:CalibrationPicture``
            1 or 2).
        problem: why it cannot be registered as it is (a band short of the flight's
            other captures), else None.
    """

    name: str
    folder: Path
    capture_id: str
    paths: tuple[Path, ...]
    bands: tuple[str, ...] = ()
    panel: bool = False
    problem: str | None = None

    def output(self, output_dir: Path) -> Path:
        """Its cube in ``output_dir``, mirroring the flight's subfolders: ``<folder>/<name>.tif``."""
        return output_dir / self.folder / f"{self.name}.tif"


def find_band_files(folder: Path) -> list[Path]:
    """Every TIFF under ``folder`` (any depth), sorted."""
    if not folder.is_dir():
        raise CadeError(f"{folder} is not a folder; give the flight's folder of band files")
    return sorted(path for path in folder.rglob("*") if path.suffix.lower() in BAND_SUFFIXES and path.is_file())


def capture_name(paths: list[Path]) -> str | None:
    """The name more than half of ``paths`` share once their band suffix (``_1``, ``_GRE``,
    the part after the last ``_`` or ``-``) is cut off; None when no name holds a majority."""
    stems = collections.Counter(re.sub(r"[_-][^_-]*$", "", path.stem) for path in paths)
    name, count = stems.most_common(1)[0]
    return name if name and 2 * count > len(paths) else None


def _index_names(bands: list[BandFile]) -> dict[int, str]:
    return {band.rig_index: band.name for band in bands}


def missing_bands(groups: dict[str, list[BandFile]]) -> dict[str, str]:
    """Capture id -> why it lacks a band (the bands named), for the captures that lack one:
    a rig index the flight's other captures by the same camera body (serial; the camera model
    where no serial is written) have, a rig index its own ``RigRelatives`` refer to, a gap in
    its rig indices, or a band its camera model always has (:data:`CAMERA_BANDS`)."""
    seen: dict[str, dict[int, str]] = defaultdict(dict)  # camera body -> the bands its captures have
    bodies = {}
    for capture_id, bands in groups.items():
        bodies[capture_id] = {band.serial or band.camera for band in bands}
        for body in bodies[capture_id]:
            seen[body].update(_index_names(bands))
    problems = {}
    for capture_id, bands in groups.items():
        own, camera = _index_names(bands), bands[0].camera
        expected: dict[int, str] = dict(CAMERA_BANDS.get(camera, {}))
        reasons = [f"a {camera} has {', '.join(expected.values())}"] if set(expected) - set(own) else []
        flight = {}
        for body in bodies[capture_id]:
            flight.update(seen[body])
        if set(flight) - set(own) - set(expected):
            reasons.append(f"the flight's other {camera} captures have {len(flight)} bands")
        expected.update(flight)
        referred = {band.rotation_reference for band in bands if band.rotation_reference is not None}
        gaps = set(range(min(own), max(own))) | referred
        if gaps - set(own) - set(expected):
            reasons.append("its bands' rig indices refer to it")
        missing = sorted((set(expected) | gaps) - set(own))
        if missing:
            names = [f"{expected[i]} (rig index {i})" if i in expected else f"rig index {i}" for i in missing]
            problems[capture_id] = (f"no {', '.join(names)} band file: {'; '.join(reasons) or 'the camera has it'} "
                                    "(a file unreadable or moved? see the notes)")
    return problems


def group_captures(folder: Path, *, skip: tuple[Path, ...] = ()) -> tuple[list[FlightCapture], list[str]]:
    """The captures of a flight folder, in the order of their first file, and a note for each
    TIFF that is not a band file (unreadable, no XMP band tags, no capture id; the files cade
    wrote, its cubes and per-band files, in one note).

    A capture missing one of its camera's bands (:func:`missing_bands`) gets a ``problem``
    naming the bands it lacks: its run fails alone.

    Args:
        folder: the flight folder (subfolders included).
        skip: files or folders to leave out (e.g. the output folder inside the flight folder).
    """
    groups: dict[str, list[BandFile]] = defaultdict(list)
    notes, written_by_cade = [], []
    for path in find_band_files(folder):
        if any(path.resolve().is_relative_to(other.resolve()) for other in skip):
            continue
        try:
            band = read_band_file(path, need_geometry=False, own_outputs=False)
        except CadeOutputFile:
            written_by_cade.append(path)
            continue
        except CadeError as error:
            reason = str(error).splitlines()[0].removeprefix(f"{path.name}: ").removeprefix(f"{path}: ")
            notes.append(f"{path.relative_to(folder)} skipped: {reason}")
            continue
        if not band.capture_id:
            notes.append(f"{path.relative_to(folder)} skipped: no capture id in its metadata")
            continue
        groups[band.capture_id].append(band)
    if written_by_cade:
        notes.append(f"{len(written_by_cade)} TIFF(s) written by cade (e.g. {written_by_cade[0].relative_to(folder)}) "
                     "left out: a flight's inputs are the camera's files")
    problems = missing_bands(groups)
    shared = collections.Counter((bands[0].path.parent, capture_name([band.path for band in bands]))
                                 for bands in groups.values())
    captures, names = [], set()
    for capture_id, bands in groups.items():
        paths = [band.path for band in bands]
        relative = paths[0].parent.relative_to(folder)
        common = capture_name(paths)
        name = common or capture_id
        if common and shared[(paths[0].parent, common)] > 1:  # DJI_0011..DJI_0015: the name is no capture's own
            name = min(paths).stem
        if (relative, name) in names:
            name = f"{name}_{capture_id}"
        names.add((relative, name))
        panel = any((band.calibration_picture or 0) > 0 for band in bands)
        captures.append(FlightCapture(name, relative, capture_id, tuple(paths), tuple(band.name for band in bands),
                                      panel, problems.get(capture_id)))
    return captures, notes
