"""Calibration boards and finding them: a chessboard or ChArUco board as ``--board`` names it
(:func:`parse_board`), its corners detected in a picture (normalised, as is and inverted, refined to
sub-pixel: :func:`detect_board`), and the picture of a detection (``calibrate --vis``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError


BOARD_KINDS = ("chessboard", "charuco")

CHARUCO_DICTIONARIES = tuple(name for name in dir(cv2.aruco) if name.startswith("DICT_"))
"""Names of the ArUco dictionaries a ChArUco board may use (``DICT_5X5_100``, ...)."""

MIN_CHARUCO_CORNERS = 6
"""The fewest ChArUco corners a view must show (and two cameras share) to be used."""


@dataclass(frozen=True)
class Board:
    """A calibration target.

    Attributes:
        kind: ``"chessboard"`` or ``"charuco"``.
        columns, rows: chessboard: inner corners along x and y (OpenCV's pattern size,
            9x6 for a board of 10x7 squares); ChArUco: squares along x and y.
        square: side of a square, metres (the unit of every translation that follows).
        marker: ChArUco only: side of a marker, metres.
        dictionary: ChArUco only: the ArUco dictionary, e.g. ``"DICT_5X5_100"``.
    """

    kind: str
    columns: int
    rows: int
    square: float
    marker: float | None = None
    dictionary: str | None = None

    @property
    def corners(self) -> np.ndarray:
        """(N, 3) float32 board coordinates of every corner, metres (z = 0), in id order."""
        if self.kind == "charuco":
            return np.asarray(self.charuco.getChessboardCorners(), np.float32).reshape(-1, 3)
        grid = np.mgrid[0:self.columns, 0:self.rows].T.reshape(-1, 2).astype(np.float32)
        return np.hstack([grid * self.square, np.zeros((len(grid), 1), np.float32)])

    @property
    def charuco(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV ChArUco board (ChArUco boards only)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.columns, self.rows), self.square, self.marker, dictionary)

    def to_dict(self) -> dict:
        """The ``calibration.board`` entry of a rig file."""
        if self.kind == "chessboard":
            return {"type": "chessboard", "inner_corners": [self.columns, self.rows], "square": self.square}
        return {"type": "charuco", "squares": [self.columns, self.rows], "square": self.square,
                "marker": self.marker, "dictionary": self.dictionary}


def parse_board(spec: str, *, square: float, marker: float | None = None, dictionary: str = "DICT_5X5_100") -> Board:
    """The board ``spec`` names: ``chessboard:COLSxROWS`` (inner corners) or
    ``charuco:COLSxROWS`` (squares), with the square (and marker) side in metres.

    Raises:
        CadeError: a malformed spec, a non-positive size, a marker not smaller than the
            square, an unknown dictionary.
    """
    match = re.fullmatch(r"(chessboard|charuco):(\d+)x(\d+)", spec.strip().lower())
    if match is None:
        raise CadeError(f"board {spec!r} not understood; write chessboard:COLSxROWS (inner corners, e.g. "
                        "chessboard:9x6) or charuco:COLSxROWS (squares, e.g. charuco:11x8)")
    kind, columns, rows = match[1], int(match[2]), int(match[3])
    if not square > 0:
        raise CadeError(f"--square must be the side of a board square in metres (> 0), got {square}")
    if kind == "chessboard":
        if columns < 3 or rows < 3:
            raise CadeError(f"a chessboard needs at least 3x3 inner corners, got {columns}x{rows}")
        if columns == rows:
            raise CadeError(f"a {columns}x{rows} chessboard looks the same turned by 90 degrees, so its corners cannot be "
                            "told apart between cameras; use a board with different numbers of rows and columns")
        return Board("chessboard", columns, rows, float(square))
    if columns < 3 or rows < 3:
        raise CadeError(f"a ChArUco board needs at least 3x3 squares, got {columns}x{rows}")
    marker = 0.75 * square if marker is None else marker
    if not 0 < marker < square:
        raise CadeError(f"--marker must be smaller than --square (both in metres), got {marker} and {square}")
    dictionary = dictionary.upper()
    if dictionary not in CHARUCO_DICTIONARIES:
        raise CadeError(f"unknown ArUco dictionary {dictionary!r}; choose e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250")
    return Board("charuco", columns, rows, float(square), float(marker), dictionary)


@dataclass(frozen=True)
class Detection:
    """The board found in one picture.

    Attributes:
        points: (N, 2) float32 corner positions, px (x, y).
        ids: (N,) int corner ids: rows of :attr:`Board.corners`.
        inverted: True when the board was found in the inverted picture.
    """

    points: np.ndarray
    ids: np.ndarray
    inverted: bool


def normalise_for_detection(band: np.ndarray) -> np.ndarray:
    """(H, W) uint8 picture for board detection: the 0.5-99.5 percentile range
    stretched to 0-255, then CLAHE (clip 2, 8x8 tiles), so that a dim, low-contrast or
    unevenly lit board in any band shows full-contrast corners."""
    values = np.asarray(band, np.float32)
    finite = values[np.isfinite(values)]
    low, high = (np.percentile(finite, (0.5, 99.5)) if finite.size else (0.0, 1.0))
    scaled = np.clip((np.nan_to_num(values, nan=low) - low) / max(float(high - low), 1e-12), 0, 1)
    image = np.round(scaled * 255).astype(np.uint8)
    return cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8)).apply(image)


def detect_board(band: np.ndarray, board: Board) -> Detection | None:
    """Find ``board`` in an (H, W) band of any range; None where it is not found.

    The band is normalised (:func:`normalise_for_detection`) and tried as it is and
    inverted. A chessboard must be seen whole; its corners come back in OpenCV's order
    (which may be turned by 180 degrees: :func:`calibrate_rig` makes the cameras agree).
    A ChArUco board may be seen in part: the view with the most corners (at least
    :data:`MIN_CHARUCO_CORNERS`) is kept.
    """
    image = normalise_for_detection(band)
    found: list[Detection] = []
    for inverted in (False, True):
        candidate = 255 - image if inverted else image
        detection = _detect_chessboard(candidate, board) if board.kind == "chessboard" else _detect_charuco(candidate, board)
        if detection is not None:
            found.append(Detection(detection[0], detection[1], inverted))
            if board.kind == "chessboard" or len(detection[1]) == len(board.corners):
                break
    return max(found, key=lambda d: len(d.ids)) if found else None


def spec(board: Board) -> str:
    """``board`` as ``--board`` names it, with what its numbers count: ``chessboard:9x6 (inner corners)``."""
    counted = "inner corners" if board.kind == "chessboard" else "squares"
    return f"{board.kind}:{board.columns}x{board.rows} ({counted})"


def suggest_board(band: np.ndarray, board: Board) -> Board | None:
    """A chessboard of a nearby size found in ``band`` where ``board`` is not: transposed, one
    corner more or fewer along either side, or squares counted instead of inner corners (one
    fewer each way). OpenCV's fast check only, both polarities: cheap on a picture without
    such a board. None when none is found (or ``board`` is a ChArUco board)."""
    if board.kind != "chessboard":
        return None
    columns, rows = board.columns, board.rows
    sizes = [(rows, columns), (columns - 1, rows - 1), (columns + 1, rows + 1), (columns - 1, rows),
             (columns + 1, rows), (columns, rows - 1), (columns, rows + 1)]
    image = normalise_for_detection(band)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    for size in sizes:
        if min(size) >= 3 and size[0] != size[1] and any(
                cv2.findChessboardCorners(candidate, size, flags=flags)[0] for candidate in (image, 255 - image)):
            return Board("chessboard", size[0], size[1], board.square)
    return None


def _detect_chessboard(image: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    size = (board.columns, board.rows)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCorners(image, size, flags=flags)
    if ok:
        grid = corners.reshape(board.rows, board.columns, 2)
        spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(), np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
        half = int(np.clip(spacing * 0.4, 2, 11))
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
        corners = cv2.cornerSubPix(image, corners, (half, half), (-1, -1), criteria)
    else:
        ok, corners = cv2.findChessboardCornersSB(image, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE)
        if not ok:
            return None
    return corners.reshape(-1, 2).astype(np.float32), np.arange(board.columns * board.rows)


def _detect_charuco(image: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    detector = cv2.aruco.CharucoDetector(board.charuco)
    corners, ids, _, _ = detector.detectBoard(image)
    if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
        return None
    return corners.reshape(-1, 2).astype(np.float32), ids.reshape(-1).astype(int)


def draw_detection(band: np.ndarray, board: Board, detection: Detection | None, *, left_out: bool = False) -> np.ndarray:
    """(H, W, 3) uint8 BGR picture of the normalised band (what the detector saw) with the
    corners found drawn on it; a red frame where the board was not found, an orange one
    where it was found but the view was left out (``left_out``)."""
    image = cv2.cvtColor(normalise_for_detection(band), cv2.COLOR_GRAY2BGR)
    thickness = max(3, image.shape[1] // 200)
    if detection is None:
        cv2.rectangle(image, (0, 0), (image.shape[1] - 1, image.shape[0] - 1), (0, 0, 255), thickness)
        return image
    if board.kind == "chessboard":
        cv2.drawChessboardCorners(image, (board.columns, board.rows), detection.points.reshape(-1, 1, 2), True)
    else:
        cv2.aruco.drawDetectedCornersCharuco(image, detection.points.reshape(-1, 1, 2),
                                             detection.ids.reshape(-1, 1).astype(np.int32), (0, 255, 0))
    if left_out:
        cv2.rectangle(image, (0, 0), (image.shape[1] - 1, image.shape[0] - 1), (0, 165, 255), thickness)
    return image
