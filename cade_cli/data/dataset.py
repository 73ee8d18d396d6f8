"""What a dataset entry is: how to find and read its scenes, and where it comes from.

A :class:`Dataset` takes the dataset's folder in its official layout, or a parent data
folder holding it under a usual name (``<root>/middlebury2005``, ``<root>/kitti/2015``...),
and yields :class:`Scene` objects one at a time. Each dataset's invalid-GT marker (0 in
8/16-bit PNG, ``inf`` in PFM) becomes NaN where its file is read, once, and disparities
are in pixels of the images returned with them. Its optional :class:`DatasetSource` says
which archives hold it; the family modules build both halves from one set of layout
constants, so that a download lands where the reader looks.

``max_disp`` (the search bound) is ``ndisp - 1`` from ``calib.txt`` for Middlebury 2014;
elsewhere it is derived from the GT: ``ceil(max finite GT)`` rounded up to a multiple of
8, at least 16 (:func:`max_disp_from_gt`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cade_cli.data.fetch import Archive
from cade_cli.errors import CadeError
from cade_cli.io.image_files import decode_with_cv2
from cade_cli.io.images import load_image

LR_CONSISTENCY_TOLERANCE = 1.0
"""Max |d_left - d_right| (px) for a left pixel to count as non-occluded (Middlebury 2005/2006)."""


@dataclass(frozen=True, eq=False)
class Scene:
    """One stereo pair with ground truth.

    Attributes:
        name: scene name as :meth:`Dataset.scene_names` lists it.
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
ArchiveBuilder = Callable[[str | None, Sequence[str]], tuple[Archive, ...]]


@dataclass(frozen=True)
class DatasetSource:
    """Where one dataset comes from and where it goes.

    Attributes:
        name: the dataset's registry key.
        folder: subfolder of the download target, the first one its reader looks in.
        contents: what a download holds, one line.
        page: the dataset's official page.
        source: the archive URL(s), braces for the variants.
        sizes: approximate download size per resolution (key ``""`` without resolutions).
        build: ``(resolution, scenes) -> archives``; None for a refused dataset.
        resolutions: accepted ``resolution`` values, the default (smallest) first; empty: none.
        scenes: the scenes that come as separate archives (empty: one bundle).
        refusal: why this dataset cannot be downloaded here (None: it can).
    """

    name: str
    folder: str
    contents: str
    page: str
    source: str
    sizes: dict[str, str]
    build: ArchiveBuilder | None = None
    resolutions: tuple[str, ...] = ()
    scenes: tuple[str, ...] = ()
    refusal: str | None = None

    @property
    def default_resolution(self) -> str | None:
        return self.resolutions[0] if self.resolutions else None

    def archives(self, resolution: str | None = None, scenes: Sequence[str] | None = None) -> tuple[Archive, ...]:
        """The archives for ``resolution`` (default: :attr:`default_resolution`) and ``scenes`` (default: all).

        Raises:
            CadeError: a refused dataset, a resolution or scene this source does not offer.
        """
        if self.refusal is not None or self.build is None:
            raise CadeError(self.refusal or f"{self.name} cannot be downloaded by cade; see {self.page}")
        if resolution is None:
            resolution = self.default_resolution
        elif not self.resolutions:
            raise CadeError(f"{self.name} comes in one resolution only; drop --resolution")
        elif resolution not in self.resolutions:
            raise CadeError(f"{self.name} has no resolution {resolution!r}; use one of {', '.join(self.resolutions)}")
        if scenes is None:
            chosen: tuple[str, ...] = self.scenes
        elif not self.scenes:
            raise CadeError(f"{self.name} comes as one archive holding every scene; do not pick scenes")
        else:
            chosen = tuple(dict.fromkeys(scenes))
            unknown = [scene for scene in chosen if scene not in self.scenes]
            if unknown or not chosen:
                raise CadeError(
                    f"{self.name} has no downloadable scene(s) {', '.join(unknown) or '(none given)'}; "
                    f"choose from {', '.join(self.scenes)}"
                )
        return self.build(resolution, chosen)


@dataclass(frozen=True)
class Dataset:
    """Find and read the scenes of one dataset; say where it comes from.

    Attributes:
        name: registry key.
        layout: the expected layout, for error messages.
        subfolders: names under which a parent data folder may hold the dataset.
        list_scenes: ``(folder, resolution) -> {scene name: loader}``, empty when
            ``folder`` does not hold the layout; reads directory listings only.
        resolutions: values the ``resolution`` option accepts (empty: none).
        download: where the official archives come from (they land in ``subfolders[0]``);
            None for layouts that are not one published dataset (``folder``, ``middeval3``).
        grey: its scenes are one band per view, already of two spectral bands (stacked to
            3 equal channels in :class:`Scene`): only the ``native`` protocol applies.
    """

    name: str
    layout: str
    subfolders: tuple[str, ...]
    list_scenes: SceneLister
    resolutions: tuple[str, ...] = ()
    download: DatasetSource | None = None
    grey: bool = False

    @property
    def default_protocols(self) -> tuple[str, ...]:
        """The evaluation protocols a benchmark runs when none is named: the paper's two
        (``cs``, ``rgb``) on colour pairs, ``native`` on :attr:`grey` ones."""
        return ("native",) if self.grey else ("cs", "rgb")

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


def make_scene(name: str, left: Path, right: Path, disparity: np.ndarray, **fields) -> Scene:
    """A :class:`Scene` after checking that both views and the GT have one size.

    ``fields``: the other :class:`Scene` attributes; ``max_disp`` defaults to
    :func:`max_disp_from_gt`, ``resolution`` to ``"<W>x<H>"``.
    """
    left_image, right_image = _rgb(left), _rgb(right)
    shapes = {left_image.shape[:2], right_image.shape[:2], disparity.shape}
    if len(shapes) != 1:
        raise CadeError(
            f"scene {name}: left {left_image.shape[:2]}, right {right_image.shape[:2]} and GT {disparity.shape} "
            "sizes differ; use files of one resolution"
        )
    fields.setdefault("max_disp", max_disp_from_gt(disparity))
    fields.setdefault("resolution", f"{disparity.shape[1]}x{disparity.shape[0]}")
    return Scene(name=name, left=left_image, right=right_image, disparity=disparity, **fields)


def grey_png(path: Path, *, dtype: type) -> np.ndarray:
    """A one-band PNG of ``dtype`` as stored (Middlebury disparities and masks)."""
    image = decode_with_cv2(path)
    if image.ndim != 2 or image.dtype != dtype:
        raise CadeError(f"{path} is not a one-band {np.dtype(dtype).name} PNG; use the dataset's original file")
    return image


def subdirs_with(folder: Path, filename: str) -> list[Path]:
    """Subfolders of ``folder`` that hold a file ``filename``."""
    return [sub for sub in folder.iterdir() if sub.is_dir() and (sub / filename).is_file()]
