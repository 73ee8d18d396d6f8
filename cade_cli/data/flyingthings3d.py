"""FlyingThings3D (SceneFlow, synthetic): readable in its official layout, not downloadable."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

from cade_cli.data.dataset import Dataset, DatasetSource, Scene, make_scene
from cade_cli.io.disparity import read_disparity

PAGE = "https://lmb.informatik.uni-freiburg.de/resources/datasets/SceneFlowDatasets.en.html"

VIEWS, DISPARITY = "frames_cleanpass", "disparity"
"""``<VIEWS>/{TRAIN,TEST}/{A,B,C}/NNNN/{left,right}/NNNN.png`` and ``<DISPARITY>/.../left/NNNN.pfm``."""


def _load_flyingthings3d(folder: Path, name: str) -> Scene:
    split_letter_sequence, frame = name.rsplit("/", 1)
    views = folder / VIEWS / split_letter_sequence
    disparity = read_disparity(folder / DISPARITY / split_letter_sequence / "left" / f"{frame}.pfm")
    return make_scene(name, views / "left" / f"{frame}.png", views / "right" / f"{frame}.png", disparity, nonocc=None)


def _list_flyingthings3d(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    frames = folder / VIEWS
    if not frames.is_dir():
        return {}
    names = ("/".join((*png.relative_to(frames).parts[:3], png.stem)) for png in frames.glob("*/*/*/left/*.png"))
    return {name: partial(_load_flyingthings3d, folder, name) for name in names}


FLYINGTHINGS3D = Dataset(
    "flyingthings3d",
    f"<root>/{VIEWS}/{{TRAIN,TEST}}/{{A,B,C}}/NNNN/{{left,right}}/NNNN.png and <root>/{DISPARITY}/.../left/NNNN.pfm",
    ("flyingthings3d", "FlyingThings3D"), _list_flyingthings3d,
    download=DatasetSource(
        "flyingthings3d", "flyingthings3d",
        f"synthetic SceneFlow subset ({VIEWS} + {DISPARITY}); not downloadable with cade", PAGE, PAGE,
        {"": "hundreds of GB"},
        refusal=(
            "flyingthings3d is not downloadable with cade: its official archives are hundreds of GB "
            "(cleanpass images and disparity alone are well over 100 GB) and cannot be fetched piecemeal; "
            f"get them from {PAGE} and unpack into <DIR>/flyingthings3d"
        ),
    ),
)
