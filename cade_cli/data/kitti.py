"""KITTI stereo 2012 and scene flow 2015: ``training/<folder>/NNNNNN_10.png``.

The folder names, frame pattern and frame counts below are what both the readers and the
archive lists use.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

import numpy as np

from cade_cli.data.dataset import Dataset, DatasetSource, Scene, make_scene
from cade_cli.data.fetch import Archive, Expected
from cade_cli.io.disparity import read_disparity

HOST = "https://s3.eu-central-1.amazonaws.com/avg-kitti"

TRAINING = "training"
"""The split with GT, a subfolder of the official bundle."""

FRAMES = "*_10.png"
"""The frames with GT: the first of each pair of flow frames (``NNNNNN_10.png``)."""


def _load_kitti(folder: Path, stem: str, *, folders: tuple[str, str, str, str]) -> Scene:
    left, right, occ, noc = (folder / name for name in folders)
    disparity = read_disparity(occ / f"{stem}.png")
    nonocc = None
    if noc.is_dir():
        nonocc = np.isfinite(read_disparity(noc / f"{stem}.png")) & np.isfinite(disparity)
    return make_scene(stem, left / f"{stem}.png", right / f"{stem}.png", disparity, nonocc=nonocc)


def _list_kitti(folder: Path, resolution: str | None, *, folders: tuple[str, str, str, str]
                ) -> dict[str, Callable[[], Scene]]:
    """Frames ``<left>/NNNNNN_10.png`` (those with GT) in ``folder`` or ``folder/training``."""
    left, _, occ, _ = folders
    for base in (folder, folder / TRAINING):
        if (base / left).is_dir() and (base / occ).is_dir():
            return {png.stem: partial(_load_kitti, base, png.stem, folders=folders) for png in (base / left).glob(FRAMES)}
    return {}


def _bundle(filename: str, folders: tuple[str, ...], frames: int, resolution: str | None, scenes: Sequence[str]
            ) -> tuple[Archive, ...]:
    """One bundle with ``training/<folder>/NNNNNN_10.png`` for each of ``folders``."""
    expected = tuple(Expected(f"{TRAINING}/{folder}/{FRAMES}", frames) for folder in folders)
    return (Archive(url=f"{HOST}/{filename}", filename=filename, expected=expected,
                    strip=f"{filename.removesuffix('.zip')}/"),)


def _kitti(year: int, folders: tuple[str, str, str, str], *, bundle: str, frames: int, contents: str, page: str,
           size: str) -> Dataset:
    """``folders``: left view, right view, GT (all pixels), GT (non-occluded pixels)."""
    name, folder = f"kitti{year}", f"kitti/{year}"
    left, right, occ, noc = folders
    return Dataset(
        name, f"<root>[/{TRAINING}]/{{{left}, {right}, {occ}[, {noc}]}}/NNNNNN_10.png",
        (folder, name, bundle.removesuffix(".zip")), partial(_list_kitti, folders=folders),
        download=DatasetSource(
            name, folder, contents, page, f"{HOST}/{bundle}", {"": size}, partial(_bundle, bundle, folders, frames),
        ),
    )


KITTI2015 = _kitti(
    2015, ("image_2", "image_3", "disp_occ_0", "disp_noc_0"), bundle="data_scene_flow.zip", frames=200,
    contents="KITTI scene flow 2015: 200 training pairs with GT (image_2/3, disp_occ_0, disp_noc_0) and 200 test pairs",
    page="https://www.cvlibs.net/datasets/kitti/eval_scene_flow.php?benchmark=stereo", size="~1.7 GB",
)
KITTI2012 = _kitti(
    2012, ("colored_0", "colored_1", "disp_occ", "disp_noc"), bundle="data_stereo_flow.zip", frames=194,
    contents="KITTI stereo/flow 2012: 194 training pairs with GT (colored_0/1, disp_occ, disp_noc) and 195 test pairs",
    page="https://www.cvlibs.net/datasets/kitti/eval_stereo_flow.php?benchmark=stereo", size="~2 GB",
)
