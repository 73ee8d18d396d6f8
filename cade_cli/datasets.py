"""Readers for the benchmark datasets, one registry: name -> :class:`DatasetReader`.

Every reader takes the dataset's folder in its official layout, or a parent data folder
holding it under a usual name (``<root>/middlebury2005``, ``<root>/kitti/2015``...), and
yields :class:`Scene` objects one at a time. Each dataset's invalid-GT marker (0 in 8/16-bit
PNG, ``inf`` in PFM) becomes NaN here, once, and disparities are in pixels of the images
returned with them.

``max_disp`` (the search bound) is ``ndisp - 1`` from ``calib.txt`` for Middlebury 2014;
elsewhere it is derived from the GT: ``ceil(max finite GT)`` rounded up to a multiple of
8, at least 16 (:func:`max_disp_from_gt`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from cade_cli.disparity_io import DISPARITY_SUFFIXES, read_disparity
from cade_cli.errors import CadeError, lookup
from cade_cli.imageio import SUPPORTED_IMAGE_SUFFIXES, decode_with_cv2, load_image

LR_CONSISTENCY_TOLERANCE = 1.0
"""Max |d_left - d_right| (px) for a left pixel to count as non-occluded (Middlebury 2005/2006)."""

MIDDLEBURY_2VIEW_SIZES: tuple[tuple[str, int, int, int], ...] = (
    ("FullSize", 1, 1200, 1500),
    ("HalfSize", 2, 600, 750),
    ("ThirdSize", 3, 400, 500),
)
"""(resolution, divisor, min width, max width) of the Middlebury 2005/2006 image sizes."""

MIDDLEBURY14_RESOLUTIONS: tuple[str, ...] = ("Q", "H", "F")
"""MiddEval3 resolutions in order of preference when none is asked for."""


@dataclass(frozen=True, eq=False)
class Scene:
    """One stereo pair with ground truth.

    Attributes:
        name: scene name as :meth:`DatasetReader.scene_names` lists it.
        left, right: (H, W, 3) float32 RGB, [0, 1] for integer image files.
        disparity: (H, W) float32 left-view GT in pixels of these images, NaN = unknown.
        nonocc: (H, W) bool, True = non-occluded with GT; None where the dataset has no
            occlusion information.
        max_disp: search bound in pixels at this resolution (see the module docstring).
        resolution: e.g. ``"ThirdSize"``, ``"Q"``, ``"1242x375"``.
        metadata: extra values; Middlebury 2014 puts its ``calib.txt`` entries here
            (``ndisp``, ``vmin``, ``vmax``, ``doffs``, ``baseline``, ``cam0``...).
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonocc: np.ndarray | None
    max_disp: int
    resolution: str
    metadata: dict = field(default_factory=dict)


SceneLister = Callable[[Path, "str | None"], Mapping[str, Callable[[], Scene]]]


@dataclass(frozen=True)
class DatasetReader:
    """Find and read the scenes of one dataset.

    Attributes:
        name: registry key.
        layout: the expected layout, for error messages.
        subfolders: names under which a parent data folder may hold the dataset.
        list_scenes: ``(folder, resolution) -> {scene name: loader}``, empty when
            ``folder`` does not hold the layout; reads directory listings only.
        resolutions: values the ``resolution`` option accepts (empty: none).
    """

    name: str
    layout: str
    subfolders: tuple[str, ...]
    list_scenes: SceneLister
    resolutions: tuple[str, ...] = ()

    def scene_names(self, root: Path, *, resolution: str | None = None) -> list[str]:
        """Names of the scenes under ``root``, sorted; no image is read.

        Raises:
            CadeError: missing ``root``, nothing in the expected layout, a resolution
                this dataset does not offer.
        """
        return list(self._scenes(root, resolution))

    def __call__(
        self, root: Path, *, scenes: Sequence[str] | None = None, resolution: str | None = None
    ) -> Iterator[Scene]:
        """Scenes under ``root`` (all, or ``scenes`` in the order given), loaded one at a time.

        Folder and scene names are checked now; files are read as the iterator advances.

        Raises:
            CadeError: as :meth:`scene_names`, or an unknown name in ``scenes``.
        """
        found = self._scenes(root, resolution)
        names = list(found) if scenes is None else list(scenes)
        unknown = [name for name in names if name not in found]
        if unknown:
            raise CadeError(
                f"unknown {self.name} scene(s) {', '.join(unknown)} in {root}; available: {', '.join(found)}"
            )
        return (found[name]() for name in names)

    def _scenes(self, root: Path, resolution: str | None) -> Mapping[str, Callable[[], Scene]]:
        root = Path(root)
        if resolution is not None and resolution not in self.resolutions:
            fix = f"use one of {', '.join(self.resolutions)}" if self.resolutions else "drop the resolution option"
            raise CadeError(f"{self.name} has no resolution option {resolution!r}; {fix}")
        if not root.is_dir():
            raise CadeError(f"{self.name} data folder {root} does not exist or is not a folder; check --data-dir")
        candidates = [root, *(root / sub for sub in self.subfolders)]
        for folder in candidates:
            found = self.list_scenes(folder, resolution) if folder.is_dir() else {}
            if found:
                return dict(sorted(found.items()))
        at = f" at resolution {resolution}" if resolution else ""
        where = ", ".join(str(folder) for folder in candidates)
        raise CadeError(f"no {self.name} scenes{at} found in {where}; expected {self.layout}")


def max_disp_from_gt(disparity: np.ndarray) -> int:
    """Search bound from GT: ``ceil(max finite d)`` rounded up to a multiple of 8, at least 16."""
    finite = disparity[np.isfinite(disparity)]
    top = math.ceil(float(finite.max())) if finite.size else 0
    return max(16, -(-top // 8) * 8)


def nonoccluded_mask(
    left_disparity: np.ndarray, right_disparity: np.ndarray, *, tolerance: float = LR_CONSISTENCY_TOLERANCE
) -> np.ndarray:
    """Left pixels whose GT is confirmed by the right view's GT.

    Left pixel (y, x) with known d is non-occluded when ``x' = floor(x - d + 0.5)`` lies
    in the image, the right GT at (y, x') is known and ``|d - d_right(y, x')| <= tolerance``.

    Args:
        left_disparity, right_disparity: (H, W) float32 pixels, NaN = unknown.

    Returns:
        (H, W) bool.
    """
    if left_disparity.shape != right_disparity.shape:
        raise CadeError(
            f"left and right GT shapes differ ({left_disparity.shape} vs {right_disparity.shape}); "
            "use the two maps of one scene and resolution"
        )
    height, width = left_disparity.shape
    rows, cols = np.indices((height, width))
    known = np.isfinite(left_disparity)
    target = np.floor(cols[known] - left_disparity[known] + 0.5).astype(np.intp)
    inside = (target >= 0) & (target < width)
    mask = np.zeros((height, width), dtype=bool)
    d_left = left_disparity[known][inside]
    d_right = right_disparity[rows[known][inside], target[inside]]
    consistent = np.isfinite(d_right) & (np.abs(d_left - np.nan_to_num(d_right)) <= tolerance)
    mask[rows[known][inside], cols[known][inside]] = consistent
    return mask


def _rgb(path: Path) -> np.ndarray:
    """:func:`load_image` as (H, W, 3): grey stacked to 3 channels, alpha dropped."""
    image = load_image(path)
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2)
    if image.shape[2] in (3, 4):
        return np.ascontiguousarray(image[:, :, :3])
    raise CadeError(f"{path} has {image.shape[2]} bands; a stereo view must be grey, RGB or RGBA")


def _scene(name: str, left: Path, right: Path, disparity: np.ndarray, **fields) -> Scene:
    """A :class:`Scene` after checking that both views and the GT have one size."""
    left_image, right_image = _rgb(left), _rgb(right)
    shapes = {left_image.shape[:2], right_image.shape[:2], disparity.shape}
    if len(shapes) != 1:
        raise CadeError(
            f"scene {name}: left {left_image.shape[:2]}, right {right_image.shape[:2]} and GT {disparity.shape} "
            "sizes differ; use files of one resolution"
        )
    fields.setdefault("max_disp", max_disp_from_gt(disparity))
    return Scene(name=name, left=left_image, right=right_image, disparity=disparity, **fields)


def _grey_png(path: Path, *, dtype: type) -> np.ndarray:
    """A one-band PNG of ``dtype`` as stored (Middlebury disparities and masks)."""
    image = decode_with_cv2(path)
    if image.ndim != 2 or image.dtype != dtype:
        raise CadeError(f"{path} is not a one-band {np.dtype(dtype).name} PNG; use the dataset's original file")
    return image


def _subdirs_with(folder: Path, filename: str) -> list[Path]:
    return [sub for sub in folder.iterdir() if sub.is_dir() and (sub / filename).is_file()]


# --- Middlebury 2005 / 2006 -------------------------------------------------------------

def _middlebury_2view_resolution(width: int, path: Path) -> tuple[str, int]:
    for resolution, divisor, low, high in MIDDLEBURY_2VIEW_SIZES:
        if low <= width <= high:
            return resolution, divisor
    sizes = ", ".join(f"{name} {low}-{high}" for name, _, low, high in MIDDLEBURY_2VIEW_SIZES)
    raise CadeError(f"{path} is {width} px wide, not a Middlebury 2005/2006 size ({sizes} px); use an unresized file")


def _load_middlebury_2view(folder: Path) -> Scene:
    encoded_left = _grey_png(folder / "disp1.png", dtype=np.uint8)
    encoded_right = _grey_png(folder / "disp5.png", dtype=np.uint8)
    resolution, divisor = _middlebury_2view_resolution(encoded_left.shape[1], folder / "disp1.png")
    left_gt, right_gt = (
        np.where(encoded > 0, encoded.astype(np.float32) / np.float32(divisor), np.float32(np.nan))
        for encoded in (encoded_left, encoded_right)
    )
    return _scene(
        folder.name, folder / "view1.png", folder / "view5.png", left_gt,
        nonocc=nonoccluded_mask(left_gt, right_gt), resolution=resolution,
    )


def _list_middlebury_2view(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    return {sub.name: partial(_load_middlebury_2view, sub) for sub in _subdirs_with(folder, "view1.png")}


# --- Middlebury 2014 --------------------------------------------------------------------

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
    calib = read_calib(folder / "calib.txt")
    disparity = read_disparity(folder / ("disp0.pfm" if perfect else "disp0GT.pfm"))
    if not perfect:
        mask = _grey_png(folder / "mask0nocc.png", dtype=np.uint8)
        if mask.shape != disparity.shape:
            raise CadeError(
                f"{folder / 'mask0nocc.png'} is {mask.shape}, GT is {disparity.shape}; use the scene's own mask"
            )
        nonocc = (mask == 255) & np.isfinite(disparity)
    elif (folder / "disp1.pfm").is_file():
        nonocc = nonoccluded_mask(disparity, read_disparity(folder / "disp1.pfm"))
    else:
        nonocc = None
    return _scene(
        name, folder / "im0.png", folder / "im1.png", disparity, nonocc=nonocc,
        max_disp=calib["ndisp"] - 1, resolution=resolution, metadata=calib,
    )


def _list_middlebury14(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    """trainingQ/H/F (first present, or the one asked for), else ``<Scene>-perfect`` (full size)."""
    if folder.name in {f"training{r}" for r in MIDDLEBURY14_RESOLUTIONS}:
        found = folder.name[-1]
        if resolution in (None, found):
            return {sub.name: partial(_load_middlebury14, sub, sub.name, found, perfect=False)
                    for sub in _subdirs_with(folder, "im0.png")}
        return {}
    for candidate in MIDDLEBURY14_RESOLUTIONS if resolution is None else (resolution,):
        training = folder / f"training{candidate}"
        if training.is_dir():
            scenes = _list_middlebury14(training, candidate)
            if scenes:
                return scenes
    if resolution not in (None, "F"):
        return {}
    names = {sub.name.removesuffix("-perfect"): sub
             for sub in _subdirs_with(folder, "im0.png") if sub.name.endswith("-perfect")}
    return {name: partial(_load_middlebury14, sub, name, "F", perfect=True) for name, sub in names.items()}


# --- FlyingThings3D ---------------------------------------------------------------------

def _load_flyingthings3d(folder: Path, name: str) -> Scene:
    split_letter_sequence, frame = name.rsplit("/", 1)
    views = folder / "frames_cleanpass" / split_letter_sequence
    disparity = read_disparity(folder / "disparity" / split_letter_sequence / "left" / f"{frame}.pfm")
    return _scene(
        name, views / "left" / f"{frame}.png", views / "right" / f"{frame}.png", disparity,
        nonocc=None, resolution=f"{disparity.shape[1]}x{disparity.shape[0]}",
    )


def _list_flyingthings3d(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    frames = folder / "frames_cleanpass"
    if not frames.is_dir():
        return {}
    names = ("/".join((*png.relative_to(frames).parts[:3], png.stem)) for png in frames.glob("*/*/*/left/*.png"))
    return {name: partial(_load_flyingthings3d, folder, name) for name in names}


# --- KITTI 2012 / 2015 ------------------------------------------------------------------

def _load_kitti(folder: Path, stem: str, *, left: str, right: str, occ: str, noc: str) -> Scene:
    disparity = read_disparity(folder / occ / f"{stem}.png")
    nonocc = None
    if (folder / noc).is_dir():
        nonocc = np.isfinite(read_disparity(folder / noc / f"{stem}.png")) & np.isfinite(disparity)
    return _scene(
        stem, folder / left / f"{stem}.png", folder / right / f"{stem}.png", disparity,
        nonocc=nonocc, resolution=f"{disparity.shape[1]}x{disparity.shape[0]}",
    )


def _list_kitti(folder: Path, resolution: str | None, *, left: str, right: str, occ: str, noc: str
                ) -> dict[str, Callable[[], Scene]]:
    """Frames ``<left>/NNNNNN_10.png`` (those with GT) in ``folder`` or ``folder/training``."""
    for base in (folder, folder / "training"):
        if (base / left).is_dir() and (base / occ).is_dir():
            stems = (png.stem for png in (base / left).glob("*_10.png"))
            return {stem: partial(_load_kitti, base, stem, left=left, right=right, occ=occ, noc=noc) for stem in stems}
    return {}


# --- any folder with left/, right/, gt/ ---------------------------------------------------

def _files_by_stem(folder: Path, suffixes: tuple[str, ...]) -> dict[str, Path]:
    files: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.is_file() and path.suffix.lower() in suffixes:
            if path.stem in files:
                raise CadeError(f"{files[path.stem]} and {path} share a name; keep one file per scene in {folder}")
            files[path.stem] = path
    return files


def _load_folder(name: str, left: Path, right: Path, gt: Path) -> Scene:
    disparity = read_disparity(gt)
    return _scene(name, left, right, disparity, nonocc=None, resolution=f"{disparity.shape[1]}x{disparity.shape[0]}")


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


# --- registry ---------------------------------------------------------------------------

_MIDDLEBURY_2VIEW_LAYOUT = "<root>/<Scene>/{view1.png, view5.png, disp1.png, disp5.png}"

DATASETS: dict[str, DatasetReader] = {
    "middlebury05": DatasetReader(
        "middlebury05", _MIDDLEBURY_2VIEW_LAYOUT, ("middlebury2005",), _list_middlebury_2view),
    "middlebury06": DatasetReader(
        "middlebury06", _MIDDLEBURY_2VIEW_LAYOUT, ("middlebury2006",), _list_middlebury_2view),
    "middlebury14": DatasetReader(
        "middlebury14",
        "<root>/training{Q,H,F}/<Scene>/{im0.png, im1.png, disp0GT.pfm, mask0nocc.png, calib.txt} "
        "or <root>/<Scene>-perfect/{im0.png, im1.png, disp0.pfm, calib.txt}",
        ("middlebury2014", "MiddEval3"), _list_middlebury14, MIDDLEBURY14_RESOLUTIONS),
    "flyingthings3d": DatasetReader(
        "flyingthings3d",
        "<root>/frames_cleanpass/{TRAIN,TEST}/{A,B,C}/NNNN/{left,right}/NNNN.png "
        "and <root>/disparity/.../left/NNNN.pfm",
        ("flyingthings3d", "FlyingThings3D"), _list_flyingthings3d),
    "kitti2015": DatasetReader(
        "kitti2015", "<root>[/training]/{image_2, image_3, disp_occ_0[, disp_noc_0]}/NNNNNN_10.png",
        ("kitti/2015", "kitti2015", "data_scene_flow"),
        partial(_list_kitti, left="image_2", right="image_3", occ="disp_occ_0", noc="disp_noc_0")),
    "kitti2012": DatasetReader(
        "kitti2012", "<root>[/training]/{colored_0, colored_1, disp_occ[, disp_noc]}/NNNNNN_10.png",
        ("kitti/2012", "kitti2012", "data_stereo_flow"),
        partial(_list_kitti, left="colored_0", right="colored_1", occ="disp_occ", noc="disp_noc")),
    "folder": DatasetReader(
        "folder", "<root>/{left, right, gt}/ with one file per scene, same stem in each (gt: .pfm/.png/.tif/.npy)",
        (), _list_folder),
}
"""Dataset name -> reader."""


def get_dataset(name: str) -> DatasetReader:
    """The reader registered as ``name``.

    Raises:
        CadeError: unknown name; the message lists the choices.
    """
    return lookup(DATASETS, name, kind="dataset")
