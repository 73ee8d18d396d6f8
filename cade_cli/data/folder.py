"""Any folder with ``left/``, ``right/`` and ``gt/`` holding one file per scene under one stem."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

from cade_cli.data.dataset import Dataset, Scene, make_scene
from cade_cli.errors import CadeError
from cade_cli.io.disparity import DISPARITY_SUFFIXES, read_disparity
from cade_cli.io.image_files import SUPPORTED_IMAGE_SUFFIXES


def _files_by_stem(folder: Path, suffixes: tuple[str, ...]) -> dict[str, Path]:
    files: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.is_file() and path.suffix.lower() in suffixes:
            if path.stem in files:
                raise CadeError(f"{files[path.stem]} and {path} share a name; keep one file per scene in {folder}")
            files[path.stem] = path
    return files


def _load_folder(name: str, left: Path, right: Path, gt: Path) -> Scene:
    return make_scene(name, left, right, read_disparity(gt), nonocc=None)


def _list_folder(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    if not all((folder / sub).is_dir() for sub in ("left", "right", "gt")):
        return {}
    left = _files_by_stem(folder / "left", SUPPORTED_IMAGE_SUFFIXES)
    right = _files_by_stem(folder / "right", SUPPORTED_IMAGE_SUFFIXES)
    gt = _files_by_stem(folder / "gt", DISPARITY_SUFFIXES)
    for sub, files in (("right", right), ("gt", gt)):
        missing = sorted(set(left) - set(files))
        if missing:
            raise CadeError(
                f"{folder / sub} has no file for {', '.join(missing)} (found in left/); add them or remove those"
            )
    return {stem: partial(_load_folder, stem, left[stem], right[stem], gt[stem]) for stem in left}


FOLDER = Dataset(
    "folder", "<root>/{left, right, gt}/ with one file per scene, same stem in each (gt: .pfm/.png/.tif/.npy)",
    (), _list_folder,
)
