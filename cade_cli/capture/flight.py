"""A flight folder's band files grouped into captures by the capture id in their metadata
(``MicaSense:CaptureId``, Parrot's ``Camera:CaptureUUID``), not by their names: the input of
``cade register-flight``.
"""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from cade_cli.capture.metadata import read_band_file
from cade_cli.errors import CadeError

BAND_SUFFIXES = (".tif", ".tiff")


@dataclass(frozen=True)
class FlightCapture:
    """One capture of a flight.

    Attributes:
        name: the band files' common name (``IMG_0001`` for ``IMG_0001_1.tif`` ...), or the
            capture id where they share none.
        folder: the folder of its files, relative to the flight folder.
        capture_id: from the metadata.
        paths: its band files.
    """

    name: str
    folder: Path
    capture_id: str
    paths: tuple[Path, ...]

    def output(self, output_dir: Path) -> Path:
        """Its cube in ``output_dir``, mirroring the flight's subfolders: ``<folder>/<name>.tif``."""
        return output_dir / self.folder / f"{self.name}.tif"


def find_band_files(folder: Path) -> list[Path]:
    """Every TIFF under ``folder`` (any depth), sorted."""
    if not folder.is_dir():
        raise CadeError(f"{folder} is not a folder; give the flight's folder of band files")
    return sorted(path for path in folder.rglob("*") if path.suffix.lower() in BAND_SUFFIXES and path.is_file())


def _common_name(paths: list[Path]) -> str:
    return os.path.commonprefix([path.stem for path in paths]).rstrip("_-. ")


def group_captures(folder: Path, *, skip: tuple[Path, ...] = ()) -> tuple[list[FlightCapture], list[str]]:
    """The captures of a flight folder, in the order of their first file, and a note for each
    TIFF that is not a band file (no XMP band tags, no capture id).

    Args:
        folder: the flight folder (subfolders included).
        skip: files or folders to leave out (e.g. the output folder inside the flight folder).
    """
    groups: dict[str, list[Path]] = defaultdict(list)
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
        groups[band.capture_id].append(path)
    captures, names = [], set()
    for capture_id, paths in groups.items():
        relative = paths[0].parent.relative_to(folder)
        name = _common_name(paths) or capture_id
        if (relative, name) in names:
            name = f"{name}_{capture_id}"
        names.add((relative, name))
        captures.append(FlightCapture(name, relative, capture_id, tuple(paths)))
    return captures, notes
