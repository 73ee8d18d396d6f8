"""Calibrate a rig from pictures of a board: detection across bands, OpenCV calibration.

A rig's cameras look through different filters, so one board can be bright in one band,
dark in another, low in contrast or partly hidden in a third. :func:`~cade_cli.rigs.boards.detect_board`
therefore normalises each picture first (a percentile stretch, then CLAHE) and tries
it both as it is and inverted; chessboard corners are refined with ``cornerSubPix``.
ChArUco boards (``cv2.aruco``) also work when only part of the board is seen, since
each corner carries its id.

:func:`calibrate_rig` then calibrates every camera on its own (``cv2.calibrateCamera``),
leaves out views whose error is far above the others and calibrates again, and finally
puts every camera relative to the reference (``cv2.stereoCalibrate`` with the intrinsics
fixed, the same outlier rule) and rectifies the reference with the first other camera
(``cv2.stereoRectify``). Views are paired across cameras by the last number in their file
names (``left07.png`` with ``right07.png``); when a name has none, by sorted order.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.io.images import read_band
from cade_cli.rigs.boards import Board, Detection, MIN_CHARUCO_CORNERS, detect_board, spec, suggest_board
from cade_cli.rigs.rectification import stereo_rectification
from cade_cli.rigs.rig import Calibration, Camera, Rig


MIN_VIEWS = 3
"""The fewest views a camera (and a camera pair) is calibrated from."""

PLAUSIBLE_SQUARE_M = 0.5
PLAUSIBLE_BASELINE_M = 5.0
"""Board squares and baselines above these (metres) are warned about: a unit mistake (mm)?"""

OUTLIER_FACTOR = 3.0
OUTLIER_FLOOR_PX = 0.5
"""A view is an outlier when its reprojection error exceeds both OUTLIER_FACTOR x the
median view's and OUTLIER_FLOOR_PX (so that a set of excellent views loses none)."""


@dataclass(frozen=True)
class CameraImages:
    """The calibration pictures of one camera: its name, band and image files."""

    name: str
    band: str
    files: tuple[Path, ...]


def view_key(path: Path) -> str | None:
    """The last run of digits in a file's stem (``left07.png`` -> ``"07"``), None without one."""
    numbers = re.findall(r"\d+", Path(path).stem)
    return numbers[-1] if numbers else None


def pair_views(cameras: Sequence[CameraImages]) -> list[tuple[str, dict[str, Path]]]:
    """Views as ``(key, {camera: file})``, paired by the number in the file names (a
    camera may miss a view) or, when a name has no number, by sorted order.

    Raises:
        CadeError: two files of one camera with the same number; without numbers,
            cameras with different counts of files.
    """
    keyed = all(view_key(path) is not None for camera in cameras for path in camera.files)
    views: dict[str, dict[str, Path]] = {}
    if keyed:
        for camera in cameras:
            for path in sorted(camera.files):
                key = str(int(view_key(path)))
                if key in views and camera.name in views[key]:
                    raise CadeError(f"camera {camera.name}: {views[key][camera.name]} and {path} both have number "
                                    f"{key}; views are paired by the number in the file name, give each view its own")
                views.setdefault(key, {})[camera.name] = path
        return sorted(views.items(), key=lambda item: int(item[0]))
    counts = {camera.name: len(camera.files) for camera in cameras}
    if len(set(counts.values())) != 1:
        shown = ", ".join(f"{name} {count}" for name, count in counts.items())
        raise CadeError(f"file names without numbers are paired by sorted order, but the cameras have different "
                        f"numbers of files ({shown}); number the views (left01, right01, ...) or give equal counts")
    ordered = {camera.name: sorted(camera.files) for camera in cameras}
    return [(str(i + 1), {name: files[i] for name, files in ordered.items()}) for i in range(len(cameras[0].files))]


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate_rig` found.

    Attributes:
        rig: the calibrated rig (with ``calibration`` and ``rectification`` filled in).
        views: (view key, {camera: file}) of every view, as paired.
        detections: camera -> view key -> the board found (None: not found), for pictures.
        left_out: camera -> view key -> ``"outlier"`` for the views of a camera that its
            own calibration left out (and so every pair with it).
        notes: one line per view left out, saying why.
    """

    rig: Rig
    views: list[tuple[str, dict[str, Path]]]
    detections: dict[str, dict[str, Detection | None]]
    left_out: dict[str, dict[str, str]]
    notes: list[str]


def calibrate_rig(cameras: Sequence[CameraImages], board: Board, *, reference: str | None = None) -> CalibrationResult:
    """Calibrate two or more cameras from pictures of ``board``.

    Each camera is calibrated on its own (``cv2.calibrateCamera``), views whose error
    is an outlier (over :data:`OUTLIER_FACTOR` x the median and :data:`OUTLIER_FLOOR_PX`)
    are left out and it is calibrated again; then every other camera is placed relative
    to the reference (``cv2.stereoCalibrate``, intrinsics fixed, same outlier rule), and
    the reference is rectified with the first other camera.

    Args:
        cameras: each camera's name, band and pictures; the first is the reference unless
            ``reference`` names another. Pictures of one camera must share one size.
        board: the target (:func:`parse_board`); translations come out in its unit (metres).

    Raises:
        CadeError: fewer than two cameras, duplicate names, unreadable pictures, pictures
            of one camera with different sizes, fewer than :data:`MIN_VIEWS` usable views
            for a camera or a camera pair, a calibration OpenCV cannot solve.
    """
    names, reference = _camera_names(cameras, reference)
    views = pair_views(cameras)
    notes: list[str] = []
    rejected: dict[str, dict] = {}  # view key -> why it was (partly) left out
    left_out: dict[str, dict[str, str]] = {name: {} for name in names}  # camera -> view key -> "outlier"
    detections, sizes = _detect_boards(views, board, names, notes, rejected)
    files_of = dict(views)
    intrinsics: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
    for name in names:
        keys = [key for key, _ in views if detections[name].get(key) is not None]
        if len(keys) < MIN_VIEWS:  # the board is mostly not found: the wrong --board?
            raise _too_few(f"camera {name}", len(keys), _board_hint(board, name, views, detections, notes))
        K, dist, rms, kept = _calibrate_camera(name, keys, detections[name], board, sizes[name], files_of, notes,
                                               rejected)
        intrinsics[name] = (K, dist, rms)
        for key in set(keys) - set(kept):
            left_out[name][key] = "outlier"  # an outlier view is not used in any pair either
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {reference: (np.eye(3), np.zeros(3))}
    view_errors: dict[str, dict[str, float]] = {}
    pair_rms: list[float] = []
    for name in names:
        if name == reference:
            continue
        R, t, rms, errors = _calibrate_pair(reference, name, views, detections, left_out, board, intrinsics,
                                            sizes[reference], files_of, notes, rejected)
        poses[name] = (R, t)
        pair_rms.append(rms)
        for key, (error_ref, error_other) in errors.items():
            view_errors.setdefault(key, {})[reference] = error_ref
            view_errors[key][name] = error_other
    rig_cameras = tuple(
        Camera(name=camera.name, band=camera.band, image_size=sizes[camera.name], K=intrinsics[camera.name][0],
               dist=intrinsics[camera.name][1], R=poses[camera.name][0], t=poses[camera.name][1])
        for camera in cameras)
    other = next(name for name in names if name != reference)
    calibration = Calibration(
        board=board.to_dict(), rms=float(max(pair_rms)), camera_rms={name: intrinsics[name][2] for name in names},
        views=[{"view": key, "files": {n: str(p) for n, p in files_of[key].items()}, "errors": errors}
               for key, errors in sorted(view_errors.items(), key=lambda item: int(item[0]) if item[0].isdigit() else item[0])],
        rejected=[{"view": key, "files": {n: str(p) for n, p in files_of[key].items()}, "reason": entry["reason"]}
                  for key, entry in rejected.items()],
    )
    unrectified = Rig(reference=reference, cameras=rig_cameras, calibration=calibration)
    rig = Rig(reference=reference, cameras=rig_cameras, calibration=calibration,
              rectification=stereo_rectification(unrectified, other))
    return CalibrationResult(rig=rig, views=views, detections=detections, left_out=left_out, notes=notes)


def _camera_names(cameras: Sequence[CameraImages], reference: str | None) -> tuple[list[str], str]:
    """The cameras' names and the reference's (the first camera's unless given), refusing
    fewer than two cameras, a name given twice, an unknown reference or a camera without pictures."""
    if len(cameras) < 2:
        raise CadeError("calibration needs two or more cameras; give --camera NAME:BAND:PATTERN for each")
    names = [camera.name for camera in cameras]
    if len(set(names)) != len(names):
        raise CadeError(f"camera names must differ, got {', '.join(names)}")
    reference = names[0] if reference is None else reference
    if reference not in names:
        raise CadeError(f"reference camera {reference!r} is not one of {', '.join(names)}")
    for camera in cameras:
        if not camera.files:
            raise CadeError(f"camera {camera.name} has no pictures; check its file pattern")
    return names, reference


def _detect_boards(views: list[tuple[str, dict[str, Path]]], board: Board, names: list[str], notes: list[str],
                   rejected: dict[str, dict]) -> tuple[dict[str, dict[str, Detection | None]], dict[str, tuple[int, int]]]:
    """The board found in every picture (camera -> view key -> detection, None where it was
    not: noted, and the view recorded in ``rejected``) and each camera's image size (one per camera)."""
    detections: dict[str, dict[str, Detection | None]] = {name: {} for name in names}
    sizes: dict[str, tuple[int, int]] = {}
    for key, files in views:
        for name, path in files.items():
            band, _ = read_band(path)
            size = (band.shape[1], band.shape[0])
            if sizes.setdefault(name, size) != size:
                raise CadeError(f"{path} is {size[0]}x{size[1]} but camera {name}'s other pictures are "
                                f"{sizes[name][0]}x{sizes[name][1]}; one camera, one image size")
            detections[name][key] = detect_board(band, board)
            if detections[name][key] is None:
                notes.append(f"view {key}: board not found in {path}; left out for camera {name}")
                rejected.setdefault(key, {"reason": notes[-1]})
    return detections, sizes


def _object_image_points(detection: Detection, board: Board, ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Board (N, 1, 3) and image (N, 1, 2) float32 points of ``detection`` (only ``ids`` if given, in that order)."""
    if ids is None:
        ids = detection.ids
    order = {int(i): n for n, i in enumerate(detection.ids)}
    rows = [order[int(i)] for i in ids]
    return (board.corners[np.asarray(ids, int)].reshape(-1, 1, 3),
            detection.points[rows].reshape(-1, 1, 2).astype(np.float32))


def _outliers(errors: dict[str, float]) -> list[str]:
    median = float(np.median(list(errors.values())))
    limit = max(OUTLIER_FACTOR * median, OUTLIER_FLOOR_PX)
    return [key for key, error in errors.items() if error > limit]


def _too_few(what: str, count: int, notes: list[str]) -> CadeError:
    hint = "; ".join(notes[-3:]) if notes else "check the board size and the pictures"
    return CadeError(f"{what}: only {count} usable view(s), {MIN_VIEWS} needed ({hint})")


def _board_hint(board: Board, name: str, views, detections, notes: list[str]) -> list[str]:
    """Why camera ``name`` has too few views when its board is mostly not found: its last note,
    the board searched, and a nearby size found in its first picture without it (:func:`suggest_board`)."""
    pictures = [(key, files[name]) for key, files in views if name in files]
    missed = [path for key, path in pictures if detections[name].get(key) is None]
    hint = (f"{spec(board)} found in {len(pictures) - len(missed)} of {len(pictures)} pictures; check that --board "
            "counts what it should")
    suggested = suggest_board(read_band(missed[0])[0], board) if missed else None
    if suggested is not None:
        hint += f"; {spec(suggested)} is found in {missed[0]}: try --board {spec(suggested).split()[0]}"
    return [note for note in notes if note.endswith(f"for camera {name}")][-1:] + [hint]


def widest_baseline(rig) -> float:
    """The longest camera translation from the rig's origin camera, in the rig's unit (what
    :func:`implausible_scale` checks: a scale error shows most on the widest pair)."""
    return max(float(np.linalg.norm(camera.t)) for camera in rig.cameras)


def implausible_scale(square: float, baseline: float) -> str | None:
    """A warning when the square side or the baseline (both metres) look like another unit
    (above :data:`PLAUSIBLE_SQUARE_M` or :data:`PLAUSIBLE_BASELINE_M`: millimetres given as
    metres?); None when both are plausible."""
    if square <= PLAUSIBLE_SQUARE_M and baseline <= PLAUSIBLE_BASELINE_M:
        return None
    what = f"--square {square:g} m" if square > PLAUSIBLE_SQUARE_M else f"a baseline of {baseline:.4g} m"
    return (f"{what} is implausible for a calibration rig: --square takes metres (25 mm is --square 0.025); "
            "every translation and depth comes out in its unit")


def _calibrate_camera(name, keys, detections, board, size, files_of, notes, rejected):
    """K, dist, RMS and the kept view keys of one camera: calibrate, drop outlier views, calibrate again."""
    kept = list(keys)
    for attempt in range(2):
        if len(kept) < MIN_VIEWS:
            raise _too_few(f"camera {name}", len(kept), notes)
        points = [_object_image_points(detections[key], board) for key in kept]
        flags = 0
        if board.kind == "charuco" or len(kept) < 6:
            flags |= cv2.CALIB_FIX_K3  # partial or few views cannot pin down the sixth-order term
        try:
            rms, K, dist, _, _, _, _, per_view = cv2.calibrateCameraExtended(
                [p[0] for p in points], [p[1] for p in points], size, None, None, flags=flags)
        except cv2.error as exc:
            raise CadeError(f"camera {name}: OpenCV could not calibrate from {len(kept)} views ({_cv_reason(exc)}); "
                            "add views with the board at different angles") from None
        errors = {key: float(e) for key, e in zip(kept, np.asarray(per_view).reshape(-1))}
        outliers = _outliers(errors) if attempt == 0 else []
        if not outliers:
            return K, dist.reshape(-1), float(rms), kept
        median = float(np.median(list(errors.values())))
        for key in outliers:
            path = files_of[key][name]
            notes.append(f"view {key}: {path} reprojects with {errors[key]:.2f} px, over {OUTLIER_FACTOR:g}x the "
                         f"median {median:.2f} px; left out for camera {name}")
            rejected.setdefault(key, {"reason": notes[-1]})
        kept = [key for key in kept if key not in outliers]
    raise AssertionError("unreachable")


def _common_points(key, reference, other, detections, board):
    """Board and image points of the corners both cameras saw in view ``key``, None if too few."""
    first, second = detections[reference].get(key), detections[other].get(key)
    if first is None or second is None:
        return None
    if board.kind == "chessboard":
        second = _agree_with(first, second, board)
        ids = first.ids
    else:
        ids = np.intersect1d(first.ids, second.ids)
        if len(ids) < MIN_CHARUCO_CORNERS:
            return None
    objects, image_first = _object_image_points(first, board, ids)
    _, image_second = _object_image_points(second, board, ids)
    return objects, image_first, image_second


def _agree_with(first: Detection, second: Detection, board: Board) -> Detection:
    """``second``'s chessboard corners in the order that matches ``first``'s.

    OpenCV orders a chessboard's corners by its colours, and a 9x6 board inverted looks
    like the board turned by 180 degrees, so a band that shows it inverted numbers the
    corners the other way round. Cameras of a rig are mounted nearly parallel: the board's
    first-to-last corner direction must point the same way in both pictures.
    """
    direction_first = first.points[-1] - first.points[0]
    direction_second = second.points[-1] - second.points[0]
    if float(direction_first @ direction_second) >= 0:
        return second
    return Detection(second.points[::-1].copy(), second.ids, second.inverted)


def _calibrate_pair(reference, other, views, detections, left_out, board, intrinsics, size, files_of, notes, rejected):
    """R, t, RMS and per-view errors of camera ``other`` relative to ``reference`` (intrinsics fixed)."""
    usable = {name: {key: d for key, d in detections[name].items() if key not in left_out[name]}
              for name in (reference, other)}
    kept = [key for key, _ in views if _common_points(key, reference, other, usable, board) is not None]
    K1, d1, _ = intrinsics[reference]
    K2, d2, _ = intrinsics[other]
    for attempt in range(2):
        if len(kept) < MIN_VIEWS:
            raise _too_few(f"cameras {reference} and {other} together", len(kept), notes)
        points = [_common_points(key, reference, other, usable, board) for key in kept]
        try:
            result = cv2.stereoCalibrateExtended(
                [p[0] for p in points], [p[1] for p in points], [p[2] for p in points], K1, d1, K2, d2, size,
                None, None, flags=cv2.CALIB_FIX_INTRINSIC,
                criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-6))
        except cv2.error as exc:
            raise CadeError(f"cameras {reference} and {other}: OpenCV could not calibrate the pair "
                            f"({_cv_reason(exc)}); do both cameras see the board in the same views?") from None
        rms, R, T, per_view = result[0], result[5], result[6], np.asarray(result[11]).reshape(-1, 2)
        errors = {key: (float(a), float(b)) for key, (a, b) in zip(kept, per_view)}
        combined = {key: float(np.hypot(a, b) / np.sqrt(2)) for key, (a, b) in errors.items()}
        outliers = _outliers(combined) if attempt == 0 else []
        if not outliers:
            return R, T.reshape(-1), float(rms), errors
        median = float(np.median(list(combined.values())))
        for key in outliers:
            files = files_of[key]
            notes.append(f"view {key}: {files[reference]} / {files[other]} reproject with {combined[key]:.2f} px as "
                         f"a pair, over {OUTLIER_FACTOR:g}x the median {median:.2f} px; left out")
            rejected.setdefault(key, {"reason": notes[-1]})
        kept = [key for key in kept if key not in outliers]
    raise AssertionError("unreachable")


def _cv_reason(error: cv2.error) -> str:
    text = str(error).strip().splitlines()
    return (text[-1] if text else "error").strip()[:120]
