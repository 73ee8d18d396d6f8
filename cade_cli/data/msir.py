"""MSIR outdoor, a real 3x3 multispectral camera array, as a benchmark of visible/near-infrared
pairs scored against a pseudo ground truth built from its visible/visible pairs (docs/msir-outdoor.md).

Cameras 0-2 (the top row) behave as near-infrared, 3-8 as visible (NOTES.md of the data
folder). Each task pairs a visible camera (left, the reference) with the near-infrared camera
straight above it: 3>0, 4>1, 5>2 (40 mm) and 6>0, 7>1, 8>2 (80 mm). Per task:

1. every camera is put on the reference's façade plane: its affine from the 8 hand-picked
   façade points (``calibration/corners.npy``) onto Cam-4, composed with the inverse of the
   reference's (:func:`~cade_cli.rigs.array_pseudo_gt.rereferenced`);
2. both views are turned by a multiple of 90 degrees (a copy) so that the baseline is +x:
   ``I_left(y, x) ~ I_right(y, x - d)``, d > 0 nearer than the plane;
3. the right view is shifted by a whole number of pixels (the left view cropped to match)
   so that every pseudo-ground-truth disparity is >= 1 px: the plane-relative parallax is a
   few px and negative behind the façade (the forest).

The pseudo ground truth of a reference is :func:`~cade_cli.rigs.array_pseudo_gt.pseudo_ground_truth`
from its visible neighbours along axis-aligned baselines (:func:`partners_of`), scaled to the
task's baseline. It is deterministic and takes a minute or two of matching, so it is cached
(:func:`cache_folder`, keyed by the data files' sizes and times and the code's sources); the
cache is never needed for a correct result. The data has no licence: it cannot be downloaded.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from cade_cli.data.dataset import Dataset, DatasetSource, Scene, max_disp_from_gt
from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_output
from cade_cli.io.images import load_image
from cade_cli.matching.disparity import densify, visible_in_right_view
from cade_cli.rigs.array import warp_camera
from cade_cli.rigs.array_geometry import BaselineFrame, array_geometry, baseline_frame, plane_mapping_from_points
from cade_cli.rigs.array_pseudo_gt import AGREEMENT_TOLERANCE, PSEUDO_GT_METHODS, pseudo_ground_truth, rereferenced
from cade_cli.rigs.rig import Camera, PlaneMapping, Rig

NAME = "msir-outdoor"
PAGE = "https://github.com/FAU-LMS/MSIR"
LAYOUT = "<root>/scene/Cam-0.png .. Cam-8.png, <root>/calibration/corners.npy, <root>/camera_array.json"
CALIBRATION_REFERENCE = 4
"""The camera the corners' affines map onto (Cam-4, the centre)."""

NEAR_INFRARED: tuple[int, ...] = (0, 1, 2)
TASKS: tuple[tuple[int, int], ...] = ((3, 0), (4, 1), (5, 2), (6, 0), (7, 1), (8, 2))
"""(visible left camera, near-infrared right camera): every pair on a vertical baseline."""

SHIFT_MARGIN = 1
"""Px left between the lowest pseudo-ground-truth disparity and 0 after the shift."""

CACHE_ENV = "CADE_CACHE_DIR"
"""Environment variable naming the cache folder (default: ``$XDG_CACHE_HOME/cade`` or ``~/.cache/cade``)."""

KEY_SOURCES: tuple[str, ...] = (
    "data/msir.py", "rigs/array_pseudo_gt.py", "rigs/array.py", "rigs/array_geometry.py", "matching/classical.py",
    "matching/sgm.py", "matching/cost.py", "matching/disparity.py", "matching/__init__.py",
)
"""The code (paths in the package) whose sources key the cache: a change to any of them rebuilds it."""

Window = tuple[int, int, int, int]
"""(top, left, height, width) of the reference view, px."""


def msir_rig(folder: Path) -> tuple[Rig, list[float]]:
    """The plane-registered rig of an MSIR scene folder (reference Cam-4), and each camera's affine RMS (px).

    Bands are named ``cam0`` .. ``cam8`` (the data set documents none). Each camera's
    ``to_reference`` is the least-squares affine from its 8 façade points onto Cam-4's;
    positions come from ``camera_array.json`` (mm, X = +40 image right, Y = +40 the top row),
    in the rig's image axes: [X, -Y] / 1000 m.
    """
    try:
        layout = json.loads((folder / "camera_array.json").read_text())
        corners = np.load(folder / "calibration" / "corners.npy")
    except (OSError, ValueError) as error:
        raise CadeError(f"cannot read the MSIR layout in {folder}: {error}; expected {LAYOUT}") from None
    if corners.ndim != 3 or corners.shape[0] != 9 or corners.shape[2] != 2:
        raise CadeError(f"{folder / 'calibration' / 'corners.npy'} holds shape {corners.shape}, not (9, N, 2) "
                        "points per camera; use the data set's file")
    cameras, residuals = [], []
    for index in range(len(corners)):
        mapping, rms = plane_mapping_from_points(corners[index], corners[CALIBRATION_REFERENCE])
        if index == CALIBRATION_REFERENCE:
            mapping = PlaneMapping("affine", np.array([[1.0, 0, 0], [0, 1.0, 0]]))  # exactly the identity
        try:
            entry = layout[f"Camera {index}"]
            size = (int(entry["image_width"]), int(entry["image_height"]))
            position = (float(entry["X"]), float(entry["Y"]))
        except (KeyError, TypeError, ValueError):
            raise CadeError(f"{folder / 'camera_array.json'} has no complete 'Camera {index}' (image_width, "
                            "image_height, X, Y); use the data set's file") from None
        cameras.append(Camera(name=f"Cam-{index}", band=f"cam{index}", image_size=size, to_reference=mapping,
                              position=(position[0] / 1000.0, -position[1] / 1000.0)))
        residuals.append(rms)
    return Rig(reference=f"Cam-{CALIBRATION_REFERENCE}", cameras=tuple(cameras)), residuals


def partners_of(rig: Rig, reference: int) -> tuple[int, ...]:
    """The visible cameras on an axis-aligned baseline from ``reference`` (rig order)."""
    origin = np.asarray(rig.camera(f"Cam-{reference}").position)
    chosen = []
    for index, camera in enumerate(rig.cameras):
        offset = np.asarray(camera.position) - origin
        if index != reference and index not in NEAR_INFRARED and np.count_nonzero(np.abs(offset) > 1e-9) == 1:
            chosen.append(index)
    return tuple(chosen)


def task_name(left: int, right: int) -> str:
    return f"cam{left}-cam{right}"


def read_camera(folder: Path, index: int) -> np.ndarray:
    """Camera ``index``'s image as (H, W) float32 in [0, 1]."""
    image = load_image(folder / "scene" / f"Cam-{index}.png")
    if image.ndim != 2:
        raise CadeError(f"{folder / 'scene' / f'Cam-{index}.png'} is not one band; use the data set's file")
    return image


def _windowed(rig: Rig, window: Window | None) -> Rig:
    """The rig whose reference view is ``window`` of the reference image (the others' mappings shifted)."""
    if window is None:
        return rig
    top, left = window[0], window[1]
    shift = np.array([[1.0, 0, -left], [0, 1.0, -top], [0, 0, 1.0]])
    cameras = tuple(camera if camera.name == rig.reference else dataclasses.replace(
        camera, to_reference=PlaneMapping("homography", shift @ camera.to_reference.homography))
        for camera in rig.cameras)
    return dataclasses.replace(rig, cameras=cameras)


def _crop(image: np.ndarray, window: Window | None) -> np.ndarray:
    if window is None:
        return image
    top, left, height, width = window
    return image[top:top + height, left:left + width]


def cache_folder() -> Path:
    """Where pseudo ground truths are cached: ``$CADE_CACHE_DIR``, else the user cache folder."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "cade"


def _cache_key(folder: Path, reference: int, partners: tuple[int, ...]) -> str:
    files = [folder / "camera_array.json", folder / "calibration" / "corners.npy",
             *(folder / "scene" / f"Cam-{i}.png" for i in range(9))]
    stats = [(path.name, path.stat().st_size, path.stat().st_mtime_ns) for path in files if path.is_file()]
    package = Path(__file__).resolve().parents[1]
    sources = [hashlib.sha256((package / name).read_bytes()).hexdigest() for name in KEY_SOURCES]
    key = {"sources": sources, "files": stats, "reference": reference, "partners": partners,
           "methods": PSEUDO_GT_METHODS, "tolerance": AGREEMENT_TOLERANCE}
    return hashlib.sha256(json.dumps(key).encode()).hexdigest()[:20]


def reference_truth(folder: Path, reference: int, *, partners: tuple[int, ...] | None = None,
                    window: Window | None = None, cache: bool = True) -> tuple[np.ndarray, float]:
    """The pseudo ground truth of camera ``reference``'s view (or ``window`` of it).

    Returns:
        ((H, W) float32 disparity in px per unit baseline, NaN where none; the unit, m).
        Read from the cache when ``cache`` and a full view's entry is there; a cache that
        cannot be read or written is ignored.
    """
    rig = rereferenced(msir_rig(folder)[0], f"Cam-{reference}")
    partners = partners_of(rig, reference) if partners is None else tuple(partners)
    unit = array_geometry(rig).unit
    path = None
    if cache and window is None:
        path = cache_folder() / NAME / f"pseudo-gt-cam{reference}-{_cache_key(folder, reference, partners)}.npy"
        width, height = rig.reference_camera.image_size
        try:
            cached = np.load(path, allow_pickle=False)
            if cached.shape == (height, width):
                return cached.astype(np.float32), unit
        except (OSError, ValueError, EOFError):
            pass  # missing or unreadable: built again
    images = {f"Cam-{i}": read_camera(folder, i) for i in partners}
    images[f"Cam-{reference}"] = _crop(read_camera(folder, reference), window)
    truth = pseudo_ground_truth(_windowed(rig, window), images, [f"Cam-{i}" for i in partners])
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_output(path) as staged:
                np.save(staged, truth.disparity)
        except (OSError, CadeError):
            pass  # the cache is a convenience, never a requirement
    return truth.disparity, truth.unit


@dataclass(frozen=True)
class TaskFrame:
    """A pair of the array turned so that its baseline is +x (before the shift).

    Attributes:
        left: (H', W') the left camera's band; right: the right camera's band on the
            left's façade plane, turned alike; inside: (H', W') where the right band's
            samples fell inside its image.
        frame: the turn (from the left view of (H, W)); ratio: baseline / unit baseline.
    """

    left: np.ndarray
    right: np.ndarray
    inside: np.ndarray
    frame: BaselineFrame
    ratio: float


def task_frame(folder: Path, left: int, right: int, *, window: Window | None = None) -> TaskFrame:
    """Cameras ``left`` and ``right`` (any two on an axis-aligned baseline) turned into a stereo pair.

    Raises:
        CadeError: a baseline that is not along an image axis.
    """
    rig = _windowed(rereferenced(msir_rig(folder)[0], f"Cam-{left}"), window)
    geometry = array_geometry(rig)
    camera = next(c for c in geometry.cameras if c.name == f"Cam-{right}")
    reference = _crop(read_camera(folder, left), window)
    warped, inside = warp_camera(read_camera(folder, right), camera, reference.shape)
    frame = baseline_frame(camera.baseline, reference.shape)
    if not frame.exact:
        raise CadeError(f"Cam-{left} and Cam-{right} are not on one row or column of the array; pick such a pair")
    return TaskFrame(frame.to_frame(reference), frame.to_frame(warped), frame.to_frame(inside.astype(np.float32)) > 0.5,
                     frame, float(np.hypot(*camera.baseline)) / geometry.unit)


def shift_for(disparity: np.ndarray) -> int:
    """Whole px that bring the lowest finite ``disparity`` to :data:`SHIFT_MARGIN` or more."""
    finite = disparity[np.isfinite(disparity)]
    lowest = float(finite.min()) if finite.size else 0.0
    return max(0, math.ceil(SHIFT_MARGIN - lowest))


def shifted_pair(pair: TaskFrame, disparity: np.ndarray, shift: int) -> tuple[np.ndarray, ...]:
    """(left, right, disparity + shift, nonocc) once the right band is shifted by ``shift`` px
    (``right'(x) = right(x + shift)``; both cropped to W' - shift columns). ``nonocc``: the
    disparity's pixels that the right view sees (no nearer surface hides them, their match
    lands inside its image)."""
    width = pair.left.shape[1] - shift
    left, right = pair.left[:, :width], pair.right[:, shift:]
    truth = (disparity[:, :width] + np.float32(shift)).astype(np.float32)
    known = np.isfinite(truth)
    seen = visible_in_right_view(densify(truth, known))
    rows, columns = np.indices(truth.shape)
    landing = np.clip(np.rint(columns - np.nan_to_num(truth)), 0, width - 1).astype(np.intp)
    nonocc = known & seen & pair.inside[:, shift:][rows, landing]
    return np.ascontiguousarray(left), np.ascontiguousarray(right), truth, nonocc


def _grey_rgb(band: np.ndarray) -> np.ndarray:
    return np.repeat(band[:, :, None], 3, axis=2)


def load_task(folder: Path, left: int, right: int, *, cache: bool = True) -> Scene:
    """The scene of task ``left`` > ``right``: grey views stacked to 3 channels (the ``native``
    protocol matches them), the pseudo ground truth, the non-occluded share of it."""
    truth, _ = reference_truth(folder, left, cache=cache)
    pair = task_frame(folder, left, right)
    turned = pair.frame.to_frame(truth * np.float32(pair.ratio))
    shift = shift_for(turned)
    left_band, right_band, disparity, nonocc = shifted_pair(pair, turned, shift)
    rig = msir_rig(folder)[0]
    metadata = {"baseline_mm": round(1000 * pair.ratio * array_geometry(rig).unit), "shift": shift,
                "coverage": float(np.isfinite(disparity).mean()), "tolerance_per_unit": AGREEMENT_TOLERANCE,
                "partners": [f"Cam-{i}" for i in partners_of(rereferenced(rig, f"Cam-{left}"), left)]}
    return Scene(task_name(left, right), _grey_rgb(left_band), _grey_rgb(right_band), disparity, nonocc,
                 max_disp_from_gt(disparity), f"{disparity.shape[1]}x{disparity.shape[0]}", metadata)


def _list_msir(folder: Path, resolution: str | None) -> dict[str, Callable[[], Scene]]:
    if not ((folder / "calibration" / "corners.npy").is_file() and (folder / "camera_array.json").is_file()
            and all((folder / "scene" / f"Cam-{i}.png").is_file() for i in range(9))):
        return {}
    return {task_name(left, right): partial(load_task, folder, left, right) for left, right in TASKS}


MSIR_OUTDOOR = Dataset(
    NAME, LAYOUT, (NAME, "msir/outdoor"), _list_msir, grey=True,
    download=DatasetSource(
        NAME, NAME, "MSIR outdoor: one real 3x3 multispectral array capture (9 x 1600x1200 uint16); no GT", PAGE, PAGE,
        {"": "19 MB"},
        refusal=(f"{NAME} is not downloadable with cade: its repository ({PAGE}) carries no licence, so it may "
                 "not be redistributed or fetched on a user's behalf; copy data/outdoor/{scene,calibration} and "
                 f"data/camera_array.json from it yourself into <DIR>/{NAME}"),
    ),
)
