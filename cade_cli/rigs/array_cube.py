"""The cube an array registration writes: a planar float32 TIFF with the reference, every
registered band and their validity bands, described by a JSON tag (band names, cameras, the
geometry), read back by ``cade array-score``; and its false-colour picture.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tifffile

from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_output
from cade_cli.io.image_files import check_input_file
from cade_cli.io.images import read_tiff_array
from cade_cli.rigs.array import ArrayRegistration


CUBE_FORMAT = "cade-array-cube"
"""The ``format`` key of the JSON description a cube TIFF carries."""


@dataclass(frozen=True)
class ArrayCube:
    """A cube TIFF read back: the reference band, each registered band and its validity.

    Attributes:
        reference: (H, W) float32.
        registered, valid: per camera, (H, W) float32 and (H, W) bool.
        reference_name: the reference camera's name; cameras: the others' names;
        bands: the band name of the reference then of each camera (from the rig).
        description: the whole JSON description.
    """

    reference: np.ndarray
    registered: tuple[np.ndarray, ...]
    valid: tuple[np.ndarray, ...]
    reference_name: str
    cameras: tuple[str, ...]
    bands: tuple[str, ...]
    description: dict


def cube_band_names(registration: ArrayRegistration) -> list[str]:
    """Names of the cube's 2N + 1 bands: the reference's band, each camera's band, then
    ``valid:<band>`` per camera (a band name two cameras share gets ``@<camera>``)."""
    cameras = (registration.reference_camera, *registration.cameras)
    bands = [camera.band for camera in cameras]
    names = [band if bands.count(band) == 1 else f"{band}@{camera.name}" for band, camera in zip(bands, cameras)]
    return names + [f"valid:{name}" for name in names[1:]]


def array_cube(registration: ArrayRegistration, *, details: dict | None = None) -> ArrayCube:
    """The :class:`ArrayCube` of ``registration``: what :func:`write_array_cube` writes.

    The description holds ``format`` (:data:`CUBE_FORMAT`), ``bands`` (names,
    :func:`cube_band_names`), ``reference``, ``cameras``, ``band_of`` (camera -> band),
    ``disparity_unit_baseline_m`` and then ``details`` (method, range, ...).
    """
    names = cube_band_names(registration)
    description = {
        "format": CUBE_FORMAT, "version": 1, "bands": names,
        "reference": registration.reference_camera.name,
        "cameras": [camera.name for camera in registration.cameras],
        "band_of": {c.name: c.band for c in (registration.reference_camera, *registration.cameras)},
        "disparity_unit_baseline_m": registration.unit, **(details or {}),
    }
    return ArrayCube(registration.reference, registration.registered, registration.valid,
                     registration.reference_camera.name, tuple(description["cameras"]),
                     tuple(names[:1 + len(registration.cameras)]), description)


def write_array_cube(path: Path, cube: ArrayCube | ArrayRegistration, *, details: dict | None = None) -> None:
    """Write a cube (or the :func:`array_cube` of a registration, with ``details``) to
    ``path`` atomically as a planar float32 TIFF.

    Bands: the reference, each registered band (rig order), then one validity band per
    camera (1.0 = seen, 0.0 = outside its image, occluded or without a vote); the
    description is the cube's, as JSON.
    """
    if isinstance(cube, ArrayRegistration):
        cube = array_cube(cube, details=details)
    stack = np.stack([cube.reference, *cube.registered, *(v.astype(np.float32) for v in cube.valid)]).astype(np.float32)
    with atomic_output(Path(path)) as temporary:
        tifffile.imwrite(temporary, stack, photometric="minisblack", planarconfig="separate",
                         description=json.dumps(cube.description), metadata=None)


def read_array_cube(path: Path) -> ArrayCube:
    """Read a cube :func:`write_array_cube` wrote.

    Raises:
        CadeError: not a TIFF, or a TIFF without the cube's description or band count.
    """
    path = check_input_file(Path(path), suffixes=(".tif", ".tiff"))
    try:
        with tifffile.TiffFile(path) as tiff:
            text = tiff.pages[0].description
    except (tifffile.TiffFileError, OSError, ValueError) as exc:
        raise CadeError(f"cannot read {path} as a TIFF ({type(exc).__name__}); "
                        "give a cube `cade register-array` wrote") from None
    try:
        description = json.loads(text)
    except (json.JSONDecodeError, TypeError):
        description = None
    if not isinstance(description, dict) or description.get("format") != CUBE_FORMAT:
        raise CadeError(f"{path} is not an array cube (its TIFF description is not a {CUBE_FORMAT}); "
                        "give a cube `cade register-array` wrote")
    stack = read_tiff_array(path)
    cameras = tuple(description["cameras"])
    count = 1 + 2 * len(cameras)
    if stack.ndim != 3 or count not in (stack.shape[0], stack.shape[-1]):
        raise CadeError(f"{path} holds an array of shape {stack.shape}, not the {count} bands its description names")
    if stack.shape[0] != count:
        stack = np.moveaxis(stack, -1, 0)
    stack = stack.astype(np.float32)
    n = len(cameras)
    return ArrayCube(stack[0], tuple(stack[1:1 + n]), tuple(stack[1 + n:] > 0.5), description["reference"], cameras,
                     tuple(description["bands"][:1 + n]), description)


def false_colour(cube: ArrayCube, channels: Sequence[str]) -> np.ndarray:
    """An (H, W, 3) uint8 B, G, R picture of three bands of ``cube`` (red, green, blue in the
    order of ``channels``, camera names), each stretched between its 1st and 99th
    percentile; pixels invalid in a shown band are black. Misregistration shows as colour
    fringes along edges."""
    index = {cube.reference_name: None, **{name: i for i, name in enumerate(cube.cameras)}}
    planes = []
    shown = np.ones(cube.reference.shape, bool)
    for name in channels:
        if name not in index:
            raise CadeError(f"the cube has no camera {name!r}; its cameras are {', '.join(index)}")
        i = index[name]
        band = cube.reference if i is None else cube.registered[i]
        if i is not None:
            shown &= cube.valid[i]
        low, high = np.percentile(band[np.isfinite(band)], [1, 99])
        planes.append(np.clip((band - low) / max(high - low, 1e-6), 0, 1))
    picture = np.rint(np.stack(planes[::-1], axis=2) * 255).astype(np.uint8)
    picture[~shown] = 0
    return picture
