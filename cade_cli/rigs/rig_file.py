"""The rig file: a rig (:mod:`cade_cli.rigs.rig`) as JSON.

A rig is a set of cameras, one of them the *reference*, each seeing one band. The file
is JSON, ``"format": "cade-rig"``, ``"version": 1`` (docs/rigs.md, "The rig file"):

- ``reference``: the name of the reference camera;
- ``cameras``: a list of cameras, each with ``name``, ``band`` (free text) and
  ``image_size`` ``[width, height]``, and either a full calibration, ``K`` (3x3, px),
  ``dist`` (OpenCV distortion coefficients) and the pose ``R`` (3x3), ``t`` (3, metres)
  of the camera relative to the reference camera (``X_cam = R X_ref + t``), or a
  plane registration, ``to_reference`` (``{"affine": 2x3}`` or ``{"homography": 3x3}``,
  this camera's pixels onto the reference image) and ``position`` ``[x, y]`` (metres,
  in the array plane, along the reference image's axes: x to the right, y down);
- ``calibration`` (optional): how the calibration was obtained (board, RMS, per-view
  errors, rejected views);
- ``rectification`` (optional): OpenCV's ``stereoRectify`` result for the reference and
  one other camera (``R1``, ``R2``, ``P1``, ``P2``, ``Q``, the rectified image size).

:func:`load_rig` accepts every version up to :data:`RIG_VERSION` and refuses newer ones;
every problem in a file is one :class:`CadeError` line naming the file and the key.
:func:`save_rig` writes atomically.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_output
from cade_cli.rigs.rig import Calibration, Camera, PLANE_MAPPINGS, PlaneMapping, Rectification, Rig


RIG_FORMAT = "cade-rig"
"""The value of a rig file's ``format`` key."""

RIG_VERSION = 1
"""The newest rig-file version this code reads and the one it writes."""


def load_rig(path: Path | str) -> Rig:
    """Read and check a rig file.

    Raises:
        CadeError: (one line, naming the file and the key) a missing or unreadable file,
            bad JSON, another format, a newer version than :data:`RIG_VERSION`, a missing
            key, a matrix of the wrong shape or with a non-finite value, a camera with
            neither a full calibration nor a plane registration, duplicate camera names,
            an unknown reference camera.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CadeError(f"rig file {path} does not exist; write one with `cade calibrate`") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or type(exc).__name__
        raise CadeError(f"cannot read rig file {path}: {reason}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CadeError(f"{path} is not valid JSON ({exc.msg} at line {exc.lineno}); is it a rig file?") from None
    return rig_from_dict(data, source=str(path))


def save_rig(rig: Rig, path: Path | str) -> None:
    """Write ``rig`` to ``path`` as a version-:data:`RIG_VERSION` rig file, atomically
    (an existing file is replaced only once the new one is complete)."""
    text = _dumps(rig_to_dict(rig)) + "\n"
    with atomic_output(Path(path)) as temporary:
        temporary.write_text(text, encoding="utf-8")


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """The JSON-ready dict of ``rig`` (what :func:`save_rig` writes)."""
    data: dict[str, Any] = {"format": RIG_FORMAT, "version": RIG_VERSION, "reference": rig.reference,
                            "cameras": [_camera_to_dict(camera) for camera in rig.cameras]}
    if rig.calibration is not None:
        c = rig.calibration
        data["calibration"] = {"board": c.board, "rms": float(c.rms), "camera_rms": {k: float(v) for k, v in c.camera_rms.items()},
                               "views": c.views, "rejected": c.rejected}
    if rig.rectification is not None:
        r = rig.rectification
        data["rectification"] = {"cameras": list(r.cameras), "image_size": list(r.image_size),
                                 **{key: _matrix(getattr(r, key)) for key in ("R1", "R2", "P1", "P2", "Q")}}
    return data


def rig_from_dict(data: Any, *, source: str = "rig") -> Rig:
    """Check ``data`` (a parsed rig file) and build the :class:`Rig`; ``source`` names it in errors."""
    reader = _Reader(source)
    if not isinstance(data, dict):
        reader.fail("", f"must be a JSON object, got {type(data).__name__}")
    fmt = data.get("format")
    if fmt != RIG_FORMAT:
        reader.fail("format", f"must be {RIG_FORMAT!r}, got {fmt!r}; is this a rig file?")
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        reader.fail("version", f"must be a positive integer, got {version!r}")
    if version > RIG_VERSION:
        raise CadeError(f"{source} is a {RIG_FORMAT} version {version} file; this cade reads versions up to "
                        f"{RIG_VERSION}: upgrade cade")
    cameras_data = reader.require(data, "cameras", list)
    if not cameras_data:
        reader.fail("cameras", "is empty; a rig needs at least one camera")
    cameras = tuple(_camera_from_dict(reader, item, f"cameras[{i}]") for i, item in enumerate(cameras_data))
    names = [camera.name for camera in cameras]
    for i, name in enumerate(names):
        if name in names[:i]:
            reader.fail(f"cameras[{i}].name", f"{name!r} is used twice; give each camera its own name")
    reference = reader.require(data, "reference", str)
    if reference not in names:
        reader.fail("reference", f"{reference!r} is not one of the cameras ({', '.join(names)})")
    calibration = None
    if data.get("calibration") is not None:
        calibration = _calibration_from_dict(reader, data["calibration"])
    rectification = None
    if data.get("rectification") is not None:
        rectification = _rectification_from_dict(reader, data["rectification"], names)
    return Rig(reference=reference, cameras=cameras, calibration=calibration, rectification=rectification)


class _Reader:
    """Typed access to a parsed rig file; every failure is one line naming file and key."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, problem: str) -> NoReturn:
        where = f"{self.source}: {key}" if key else self.source
        raise CadeError(f"{where} {problem}")

    def require(self, data: dict, key: str, kind: type | tuple[type, ...], *, prefix: str = "") -> Any:
        name = f"{prefix}.{key}" if prefix else key
        if key not in data:
            self.fail(name, "is missing")
        value = data[key]
        if not isinstance(value, kind) or isinstance(value, bool):
            expected = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
            self.fail(name, f"must be a {_JSON_NAMES.get(expected, expected)}, got {json.dumps(value)[:40]}")
        return value

    def array(self, value: Any, key: str, shape: tuple[int, ...] | None, *, what: str) -> np.ndarray:
        """``value`` as a finite float64 array of ``shape`` (None: any 1-D length >= 1)."""
        try:
            array = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(key, f"must be {what} of numbers, got {json.dumps(value)[:60]}")
        if (shape is not None and array.shape != shape) or (shape is None and (array.ndim != 1 or array.size == 0)):
            self.fail(key, f"must be {what}, got shape {list(array.shape)}")
        if not np.all(np.isfinite(array)):
            self.fail(key, f"has a non-finite value; every entry of {what} must be a finite number")
        return array

_JSON_NAMES = {"str": "string", "list": "list", "dict": "JSON object", "int": "integer", "float": "number",
               "int or float": "number"}


def _camera_from_dict(reader: _Reader, data: Any, key: str) -> Camera:
    if not isinstance(data, dict):
        reader.fail(key, f"must be a JSON object, got {json.dumps(data)[:40]}")
    name = reader.require(data, "name", str, prefix=key)
    if not name.strip():
        reader.fail(f"{key}.name", "is empty; give the camera a name")
    band = reader.require(data, "band", str, prefix=key)
    size = reader.require(data, "image_size", list, prefix=key)
    if len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size):
        reader.fail(f"{key}.image_size", f"must be [width, height], two positive integers, got {json.dumps(size)}")
    present = {k for k in ("K", "dist", "R", "t", "to_reference", "position") if data.get(k) is not None}
    K = reader.array(data["K"], f"{key}.K", (3, 3), what="a 3x3 matrix") if "K" in present else None
    dist = reader.array(data["dist"], f"{key}.dist", None, what="a list of distortion coefficients") if "dist" in present else None
    if dist is not None and dist.size not in (4, 5, 8, 12, 14):
        reader.fail(f"{key}.dist", f"must hold 4, 5, 8, 12 or 14 OpenCV distortion coefficients, got {dist.size}")
    R = reader.array(data["R"], f"{key}.R", (3, 3), what="a 3x3 rotation") if "R" in present else None
    if R is not None and not np.allclose(R @ R.T, np.eye(3), atol=1e-5):
        reader.fail(f"{key}.R", "is not a rotation matrix (R R^T != I)")
    t = reader.array(data["t"], f"{key}.t", (3,), what="a list of 3 numbers (metres)") if "t" in present else None
    if K is not None and (K[0, 0] <= 0 or K[1, 1] <= 0):
        reader.fail(f"{key}.K", "must have positive focal lengths K[0][0], K[1][1]")
    to_reference = None
    if "to_reference" in present:
        mapping = data["to_reference"]
        kinds = [k for k in PLANE_MAPPINGS if isinstance(mapping, dict) and k in mapping]
        if not isinstance(mapping, dict) or len(kinds) != 1 or len(mapping) != 1:
            reader.fail(f"{key}.to_reference", 'must be {"affine": 2x3} or {"homography": 3x3}')
        kind = kinds[0]
        shape = (2, 3) if kind == "affine" else (3, 3)
        matrix = reader.array(mapping[kind], f"{key}.to_reference.{kind}", shape, what=f"a {shape[0]}x{shape[1]} matrix")
        to_reference = PlaneMapping(kind, matrix)
    position = None
    if "position" in present:
        position = tuple(float(v) for v in reader.array(data["position"], f"{key}.position", (2,), what="[x, y] (metres)"))
    full, plane = {"K", "R", "t"} <= present, {"to_reference", "position"} <= present
    if not (full or plane):
        missing_full = sorted({"K", "R", "t"} - present)
        missing_plane = sorted({"to_reference", "position"} - present)
        reader.fail(key, f"({name}) needs K, R and t (missing {', '.join(missing_full)}) or to_reference and position "
                    f"(missing {', '.join(missing_plane)})")
    return Camera(name=name, band=band, image_size=(int(size[0]), int(size[1])), K=K, dist=dist, R=R, t=t,
                  to_reference=to_reference, position=position)


def _calibration_from_dict(reader: _Reader, data: Any) -> Calibration:
    if not isinstance(data, dict):
        reader.fail("calibration", "must be a JSON object")
    board = reader.require(data, "board", dict, prefix="calibration")
    rms = reader.require(data, "rms", (int, float), prefix="calibration")
    if not math.isfinite(rms) or rms < 0:
        reader.fail("calibration.rms", f"must be a finite number >= 0, got {rms}")
    camera_rms = data.get("camera_rms", {})
    if not isinstance(camera_rms, dict) or not all(isinstance(v, (int, float)) for v in camera_rms.values()):
        reader.fail("calibration.camera_rms", "must map camera names to numbers")
    views = data.get("views", [])
    rejected = data.get("rejected", [])
    for key, value in (("views", views), ("rejected", rejected)):
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            reader.fail(f"calibration.{key}", "must be a list of JSON objects")
    return Calibration(board=board, rms=float(rms), camera_rms={k: float(v) for k, v in camera_rms.items()},
                       views=views, rejected=rejected)


def _rectification_from_dict(reader: _Reader, data: Any, names: list[str]) -> Rectification:
    if not isinstance(data, dict):
        reader.fail("rectification", "must be a JSON object")
    pair = reader.require(data, "cameras", list, prefix="rectification")
    if len(pair) != 2 or not all(isinstance(n, str) and n in names for n in pair) or pair[0] == pair[1]:
        reader.fail("rectification.cameras", f"must name two different cameras of the rig, got {json.dumps(pair)}")
    size = reader.require(data, "image_size", list, prefix="rectification")
    if len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size):
        reader.fail("rectification.image_size", f"must be [width, height], two positive integers, got {json.dumps(size)}")
    shapes = {"R1": (3, 3), "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "Q": (4, 4)}
    matrices = {}
    for key, shape in shapes.items():
        if key not in data:
            reader.fail(f"rectification.{key}", "is missing")
        matrices[key] = reader.array(data[key], f"rectification.{key}", shape, what=f"a {shape[0]}x{shape[1]} matrix")
    return Rectification(cameras=(pair[0], pair[1]), image_size=(int(size[0]), int(size[1])), **matrices)


def _camera_to_dict(camera: Camera) -> dict[str, Any]:
    data: dict[str, Any] = {"name": camera.name, "band": camera.band, "image_size": list(camera.image_size)}
    for key in ("K", "dist", "R", "t"):
        value = getattr(camera, key)
        if value is not None:
            data[key] = _matrix(value)
    if camera.to_reference is not None:
        data["to_reference"] = {camera.to_reference.kind: _matrix(camera.to_reference.matrix)}
    if camera.position is not None:
        data["position"] = [float(v) for v in camera.position]
    return data


def _dumps(value: Any, indent: str = "") -> str:
    """JSON with two-space indentation, but a list of numbers on one line and a matrix one row a line."""
    inner = indent + "  "
    if isinstance(value, dict) and value:
        items = [f"{inner}{json.dumps(key)}: {_dumps(item, inner)}" for key, item in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    if isinstance(value, list) and value and not _flat(value):
        if all(isinstance(row, list) and _flat(row) for row in value):  # a matrix
            return "[\n" + ",\n".join(inner + json.dumps(row) for row in value) + "\n" + indent + "]"
        return "[\n" + ",\n".join(inner + _dumps(item, inner) for item in value) + "\n" + indent + "]"
    return json.dumps(value)


def _flat(values: list) -> bool:
    return all(isinstance(v, (int, float, str, bool)) or v is None for v in values)


def _matrix(array: np.ndarray) -> list:
    """A float array as nested lists of Python floats (JSON keeps all 17 digits)."""
    return np.asarray(array, np.float64).tolist()
