"""Middlebury stereo: the 2005/2006 two-view sets, MiddEval3 (2014), and scenes in its file layout.

The folder and file names, sizes and scene lists below are what both the readers and
the archive lists use.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

import numpy as np

from cade_cli.data.dataset import Dataset, DatasetSource, Scene, grey_png, make_scene, nonoccluded_mask, subdirs_with
from cade_cli.data.fetch import Archive, Expected
from cade_cli.errors import CadeError
from cade_cli.io.disparity import read_disparity

HOST = "https://vision.middlebury.edu"

RESOLUTIONS: tuple[str, ...] = ("Q", "H", "F")
"""Quarter, half, full size, in order of preference when none is asked for (2005/2006: Q = ThirdSize)."""


def _braces(names: Sequence[str], separator: str = ", ") -> str:
    """``{a, b, c}``: alternatives in a layout or URL pattern."""
    return "{" + separator.join(names) + "}"


# --- 2005 / 2006: <Scene>/{view1,view5,disp1,disp5}.png ---------------------------------

TWO_VIEW_SIZES: dict[str, tuple[str, int, int, int]] = {
    "Q": ("ThirdSize", 3, 400, 500),
    "H": ("HalfSize", 2, 600, 750),
    "F": ("FullSize", 1, 1200, 1500),
}
"""Resolution -> (folder on the host, GT divisor, min width, max width) of the 2005/2006 image sizes."""

TWO_VIEW_FILES: tuple[str, str, str, str] = ("view1.png", "view5.png", "disp1.png", "disp5.png")
"""Left view, right view, left GT, right GT (8-bit, ``divisor * d``, 0 = unknown)."""

MIDDLEBURY05_SCENES: tuple[str, ...] = ("Art", "Books", "Dolls", "Laundry", "Moebius", "Reindeer")
"""The 2005 scenes with public GT; Computer, Drumsticks and Dwarves have none and are not fetched."""

MIDDLEBURY06_SCENES: tuple[str, ...] = (
    "Aloe", "Baby1", "Baby2", "Baby3", "Bowling1", "Bowling2", "Cloth1", "Cloth2", "Cloth3", "Cloth4",
    "Flowerpots", "Lampshade1", "Lampshade2", "Midd1", "Midd2", "Monopoly", "Plastic", "Rocks1", "Rocks2",
    "Wood1", "Wood2",
)


def _two_view_size(width: int, path: Path) -> tuple[str, int]:
    for size, divisor, low, high in TWO_VIEW_SIZES.values():
        if low <= width <= high:
            return size, divisor
    sizes = ", ".join(f"{size} {low}-{high}" for size, _, low, high in TWO_VIEW_SIZES.values())
    raise CadeError(f"{path} is {width} px wide, not a Middlebury 2005/2006 size ({sizes} px); use an unresized file")


def _load_two_view(folder: Path) -> Scene:
    left, right, left_gt_file, right_gt_file = (folder / name for name in TWO_VIEW_FILES)
    encoded_left = grey_png(left_gt_file, dtype=np.uint8)
    encoded_right = grey_png(right_gt_file, dtype=np.uint8)
    resolution, divisor = _two_view_size(encoded_left.shape[1], left_gt_file)
    left_gt, right_gt = (
        np.where(encoded > 0, encoded.astype(np.float32) / np.float32(divisor), np.float32(np.nan))
        for encoded in (encoded_left, encoded_right)
    )
    return make_scene(folder.name, left, right, left_gt, nonocc=nonoccluded_mask(left_gt, right_gt),
                      resolution=resolution)


def _list_two_view(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    return {sub.name: partial(_load_two_view, sub) for sub in subdirs_with(folder, TWO_VIEW_FILES[0])}


def _two_view_archives(year: int, resolution: str, scenes: Sequence[str]) -> tuple[Archive, ...]:
    """One ``<Scene>-2views.zip`` per scene: ``<Scene>/{view1,view5,disp1,disp5}.png``."""
    size = TWO_VIEW_SIZES[resolution][0]
    return tuple(
        Archive(
            url=f"{HOST}/stereo/data/scenes{year}/{size}/zip-2views/{scene}-2views.zip",
            filename=f"{scene}-2views-{size}.zip",
            expected=tuple(Expected(f"{scene}/{name}") for name in TWO_VIEW_FILES),
            strip=f"{scene}/",
            into=scene,
        )
        for scene in scenes
    )


def _two_view(year: int, scenes: tuple[str, ...], contents: str, sizes: dict[str, str]) -> Dataset:
    name, folder = f"middlebury{year % 100:02d}", f"middlebury{year}"
    return Dataset(
        name, f"<root>/<Scene>/{_braces(TWO_VIEW_FILES)}", (folder,), _list_two_view,
        download=DatasetSource(
            name, folder, contents, f"{HOST}/stereo/data/scenes{year}/",
            f"{HOST}/stereo/data/scenes{year}/{_braces([s for s, *_ in TWO_VIEW_SIZES.values()], ',')}"
            "/zip-2views/<Scene>-2views.zip",
            sizes, partial(_two_view_archives, year), RESOLUTIONS, scenes,
        ),
    )


MIDDLEBURY05 = _two_view(
    2005, MIDDLEBURY05_SCENES,
    f"2005 scenes with GT ({', '.join(MIDDLEBURY05_SCENES)}): view1/view5 + disp1/disp5, one zip per scene",
    {"Q": "~10 MB", "H": "~30 MB", "F": "~100 MB"},
)
MIDDLEBURY06 = _two_view(
    2006, MIDDLEBURY06_SCENES, "21 scenes from 2006: view1/view5 + disp1/disp5, one zip per scene",
    {"Q": "~25 MB", "H": "~80 MB", "F": "~300 MB"},
)


# --- 2014 (MiddEval3): training<Q|H|F>/<Scene>/... ---------------------------------------

IMAGE_FILES: tuple[str, str, str] = ("im0.png", "im1.png", "calib.txt")
"""Left view, right view, calibration of a MiddEval3 scene (in ``MiddEval3-data-<res>.zip``)."""

GT_FILES: tuple[str, str] = ("disp0GT.pfm", "mask0nocc.png")
"""Left GT (PFM, inf = unknown) and non-occluded mask (255) of a training scene (``MiddEval3-GT0-<res>.zip``)."""

MIDDLEBURY14_TRAINING: tuple[str, ...] = (
    "Adirondack", "ArtL", "Jadeplant", "Motorcycle", "MotorcycleE", "Piano", "PianoL", "Pipes",
    "Playroom", "Playtable", "PlaytableP", "Recycle", "Shelves", "Teddy", "Vintage",
)
"""The 15 MiddEval3 training scenes (the ones with public GT)."""


def _training(resolution: str) -> str:
    return f"training{resolution}"


def read_calib(path: Path) -> dict:
    """Parse a Middlebury ``calib.txt``: ``key=value`` lines; ``cam0=[a b c; d e f; g h i]``.

    Returns:
        {key: int, float, (3, 3) float64 array for bracketed matrices, or str}.
    """
    try:
        text = Path(path).read_text(encoding="ascii", errors="replace")
    except OSError as exc:
        raise CadeError(f"cannot read {path}: {exc.strerror or exc}; check that calib.txt exists") from exc
    calib: dict = {}
    for line in text.splitlines():
        key, sep, value = (part.strip() for part in line.partition("="))
        if not sep or not key:
            continue
        if value.startswith("["):
            rows = [row.split() for row in value.strip("[]").split(";")]
            calib[key] = np.array(rows, dtype=np.float64)
        elif re.fullmatch(r"[+-]?\d+", value):
            calib[key] = int(value)
        else:
            try:
                calib[key] = float(value)
            except ValueError:
                calib[key] = value
    if not isinstance(calib.get("ndisp"), int):
        raise CadeError(f"{path} has no integer ndisp=... line; use the dataset's original calib.txt")
    return calib


def _load_middlebury14(folder: Path, name: str, resolution: str, *, perfect: bool) -> Scene:
    left, right, calib_file = IMAGE_FILES
    gt_file, mask_file = GT_FILES
    calib = read_calib(folder / calib_file)
    disparity = read_disparity(folder / ("disp0.pfm" if perfect else gt_file))
    if not perfect:
        mask = grey_png(folder / mask_file, dtype=np.uint8)
        if mask.shape != disparity.shape:
            raise CadeError(f"{folder / mask_file} is {mask.shape}, GT is {disparity.shape}; use the scene's own mask")
        nonocc = (mask == 255) & np.isfinite(disparity)
    elif (folder / "disp1.pfm").is_file():
        nonocc = nonoccluded_mask(disparity, read_disparity(folder / "disp1.pfm"))
    else:
        nonocc = None
    return make_scene(
        name, folder / left, folder / right, disparity, nonocc=nonocc,
        max_disp=calib["ndisp"] - 1, resolution=resolution, metadata=calib,
    )


def _list_middlebury14(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    """trainingQ/H/F (first present, or the one asked for), else ``<Scene>-perfect`` (full size)."""
    resolution_of = {_training(r): r for r in RESOLUTIONS}
    if folder.name in resolution_of:
        found = resolution_of[folder.name]
        if resolution in (None, found):
            return {sub.name: partial(_load_middlebury14, sub, sub.name, found, perfect=False)
                    for sub in subdirs_with(folder, IMAGE_FILES[0])}
        return {}
    for candidate in RESOLUTIONS if resolution is None else (resolution,):
        training = folder / _training(candidate)
        if training.is_dir():
            scenes = _list_middlebury14(training, candidate)
            if scenes:
                return scenes
    if resolution not in (None, "F"):
        return {}
    names = {sub.name.removesuffix("-perfect"): sub
             for sub in subdirs_with(folder, IMAGE_FILES[0]) if sub.name.endswith("-perfect")}
    return {name: partial(_load_middlebury14, sub, name, "F", perfect=True) for name, sub in names.items()}


def _middlebury14_archives(resolution: str, scenes: Sequence[str]) -> tuple[Archive, ...]:
    """MiddEval3 images (training + test) and GT0 (left GT, non-occluded mask) of one resolution."""
    return tuple(
        Archive(
            url=f"{HOST}/stereo/submit3/zip/MiddEval3-{part}-{resolution}.zip",
            filename=f"MiddEval3-{part}-{resolution}.zip",
            expected=tuple(Expected(f"{_training(resolution)}/{scene}/{name}")
                           for scene in MIDDLEBURY14_TRAINING for name in names),
            strip="MiddEval3/",
        )
        for part, names in (("data", IMAGE_FILES), ("GT0", GT_FILES))
    )


_SCENE_FILES = _braces((*IMAGE_FILES[:2], *GT_FILES, IMAGE_FILES[2]))

MIDDLEBURY14 = Dataset(
    "middlebury14",
    f"<root>/{_training(_braces(RESOLUTIONS, ','))}/<Scene>/{_SCENE_FILES} "
    f"or <root>/<Scene>-perfect/{_braces((*IMAGE_FILES[:2], 'disp0.pfm', IMAGE_FILES[2]))}",
    ("middlebury2014", "MiddEval3"), _list_middlebury14, RESOLUTIONS,
    download=DatasetSource(
        "middlebury14", "middlebury2014",
        "MiddEval3 v3 images (15 training + 15 test pairs, calib.txt) and training GT0 (disp0GT.pfm, mask0nocc.png)",
        f"{HOST}/stereo/submit3/",
        f"{HOST}/stereo/submit3/zip/MiddEval3-{{data,GT0}}-{_braces(RESOLUTIONS, ',')}.zip",
        {"Q": "~60 MB", "H": "~200 MB", "F": "~750 MB"},
        _middlebury14_archives, RESOLUTIONS,
    ),
)


# --- scenes in the MiddEval3 file layout, any size (the real training scenes) -------------

def _list_middeval3_scenes(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    """Scene folders in the MiddEval3 file layout with no trainingQ/H/F level (any size)."""
    return {sub.name: partial(_load_middlebury14, sub, sub.name, "native", perfect=False)
            for sub in subdirs_with(folder, GT_FILES[0]) if (sub / IMAGE_FILES[0]).is_file()}


MIDDEVAL3 = Dataset(
    "middeval3", f"<root>/<Scene>/{_SCENE_FILES} (scenes of any size)", ("train-real",), _list_middeval3_scenes,
)
