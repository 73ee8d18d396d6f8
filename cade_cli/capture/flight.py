"""A flight folder's band files grouped into captures by the capture id in their metadata
(``MicaSense:CaptureId``, Parrot's ``Camera:CaptureUUID``), not by their names; which captures
are calibration-panel shots; a capture missing a band the flight's others have: the input of
``cade batch --captures`` (:mod:`cade_cli.scale.batch_captures`).
"""

from __future__ import annotations

import collections
import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from cade_cli.capture.metadata import BandFile, read_band_file
from cade_cli.errors import CadeError

BAND_SUFFIXES = (".tif", ".tiff")


@dataclass(frozen=True)
class FlightCapture:
    """One capture of a flight.

    Attributes:
        name: the name most of its band files share before their band suffix (``IMG_0001``
            for ``IMG_0001_1.tif`` ..., ``IMG_180413_080658_0000`` for the Sequoia's
            ``..._GRE.TIF``), or the capture id where no name holds a majority.
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


def group_captures(folder: Path, *, skip: tuple[Path, ...] = ()) -> tuple[list[FlightCapture], list[str]]:
    """The captures of a flight folder, in the order of their first file, and a note for each
    TIFF that is not a band file (unreadable, no XMP band tags, no capture id).

    A capture with fewer bands than the flight's other captures by the same camera (the most
    common set of band names) gets a ``problem`` naming the bands it lacks: its run fails alone.

    Args:
        folder: the flight folder (subfolders included).
        skip: files or folders to leave out (e.g. the output folder inside the flight folder).
    """
    groups: dict[str, list[BandFile]] = defaultdict(list)
    notes = []
    for path in find_band_files(folder):
        if any(path.resolve().is_relative_to(other.resolve()) for other in skip):
            continue
        try:
            band = read_band_file(path, need_geometry=False)
        except CadeError as error:
            notes.append(f"{path.relative_to(folder)} skipped: {error}")
            continue
        if not band.capture_id:
            notes.append(f"{path.relative_to(folder)} skipped: no capture id in its metadata")
            continue
        groups[band.capture_id].append(band)
    usual: dict[str, collections.Counter] = defaultdict(collections.Counter)  # per camera (make and model)
    for bands in groups.values():
        usual[bands[0].camera][frozenset(band.name for band in bands)] += 1
    captures, names = [], set()
    for capture_id, bands in groups.items():
        paths = [band.path for band in bands]
        relative = paths[0].parent.relative_to(folder)
        name = capture_name(paths) or capture_id
        if (relative, name) in names:
            name = f"{name}_{capture_id}"
        names.add((relative, name))
        usual_bands = usual[bands[0].camera].most_common(1)[0][0]
        missing = sorted(usual_bands - {band.name for band in bands})
        problem = (f"no {', '.join(missing)} band file: the flight's other {bands[0].camera} captures have "
                   f"{len(usual_bands)} bands (a file unreadable or moved? see the notes)") if missing else None
        panel = any((band.calibration_picture or 0) > 0 for band in bands)
        captures.append(FlightCapture(name, relative, capture_id, tuple(paths), tuple(band.name for band in bands),
                                      panel, problem))
    return captures, notes
