"""The pictures of a benchmark run that the HTML report shows, made where the maps are.

A scene's maps exist only inside the worker that ran it, so the pictures are drawn there
and come back small: JPEG bytes (:data:`JPEG_QUALITY`), at most ``width`` px wide, per scene a
:class:`SceneAlbum` of the ground truth, the left and right bands of the task shown (the scene's
first task, or with ``every_task`` each task) and each of its scored maps with its error picture.
A disparity picture draws the matcher's rejected pixels black, as its legend says, though the
map scored is filled: the picture shows the map before the fill. Disparity pictures of one scene share the colour range
of its ground truth, so that methods compare at a glance
(:func:`cade_cli.io.match_outputs.disparity_picture`; errors:
:func:`cade_cli.evaluation.error_maps.error_picture`).

Pictures are downscaled before they are drawn: maps (disparity, ground truth) by nearest
neighbour, so that every pixel shown is a real value and pixels without ground truth stay
without; bands by area averaging. The scores are computed at full resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

from cade_cli.evaluation.error_maps import error_picture
from cade_cli.evaluation.protocols import get_protocol

if TYPE_CHECKING:
    from cade_cli.data import Scene
    from cade_cli.evaluation.records import Record

TILE_WIDTH = 360
"""Default width (px) of the report's pictures: two side by side fit a laptop screen, and a
map's legend (:data:`~cade_cli.io.pictures.MIN_WIDTH`) fits."""
JPEG_QUALITY = 80
"""JPEG quality of the report's pictures: a whole Middlebury 2014 run's page stays one file to mail."""
PICTURE_SETS = ("scene", "all")
"""What the report shows pictures of: one task per scene (its first), or every task."""


@dataclass
class SceneAlbum:
    """One scene's pictures for the HTML report, each a JPEG at most ``width`` px wide (a map
    with its legend at least :data:`~cade_cli.io.pictures.MIN_WIDTH`, for the text to fit).

    Attributes:
        scene: the scene's name.
        width: the largest picture width, px.
        value_range: (low, high) px, the colour range of every disparity picture of the
            scene: the range of its ground truth.
        ground_truth: the ground truth's disparity picture.
        bands: (protocol, task) -> (left band, right band) pictures, as matched.
        maps: (protocol, method, preprocess, degradation, task) -> (disparity picture,
            error picture) of the scored map (:func:`map_key` of its record).
        small_truth: the ground truth shrunk to ``width``, which every error picture is
            measured against (shrunk once per scene, not once per map).
        every_task: pictures of every task; False: of the first task added only (protocol,
            degradation, task: :attr:`shown_task`), the others' scores being in the tables.
    """

    scene: str
    width: int
    value_range: tuple[float, float]
    ground_truth: bytes
    bands: dict[tuple[str, str], tuple[bytes, bytes]] = field(default_factory=dict)
    maps: dict[tuple[str, str, str, str, str], tuple[bytes, bytes]] = field(default_factory=dict)
    small_truth: np.ndarray | None = field(default=None, repr=False, compare=False)
    every_task: bool = False
    shown_task: tuple[str, str, str] | None = None

    @classmethod
    def of(cls, scene: Scene, *, width: int = TILE_WIDTH, every_task: bool = False) -> SceneAlbum:
        """An album of ``scene`` holding its ground-truth picture, ready for :meth:`add`."""
        if width < 1:
            raise ValueError(f"a picture width must be >= 1 px, got {width}")
        from cade_cli.io.match_outputs import disparity_picture

        value_range = ground_truth_range(scene.disparity, max_disp=scene.max_disp)
        small_truth = shrink_map(scene.disparity, width)
        picture = disparity_picture(small_truth, value_range=value_range, invalid_label="black = no ground truth")
        return cls(scene.name, width, value_range, encode(picture), small_truth=small_truth, every_task=every_task)

    def add(self, record: Record, disparity: np.ndarray, scene: Scene, valid: np.ndarray | None = None) -> None:
        """Add the pictures of one scored map (``record``'s ``disparity`` of ``scene``, filled;
        ``valid``: where the matcher kept its estimate, the rest drawn black), and the bands of
        its task if the album has none yet; nothing for a task other than the one shown."""
        from cade_cli.io.match_outputs import disparity_picture

        task = (record.protocol, record.degradation, record.task)
        if not self.every_task and self.shown_task is not None and task != self.shown_task:
            return
        self.shown_task = self.shown_task or task
        band_key = (record.protocol, record.task)
        if band_key not in self.bands:
            left, right = task_images(record.protocol, record.task, scene.left, scene.right)
            self.bands[band_key] = (encode(band_picture(left, self.width)), encode(band_picture(right, self.width)))
        if self.small_truth is None:
            self.small_truth = shrink_map(scene.disparity, self.width)
        small = shrink_map(disparity, self.width)
        kept = small if valid is None else shrink_map(np.where(valid, disparity, np.nan), self.width)
        self.maps[map_key(record)] = (encode(disparity_picture(kept, value_range=self.value_range)),
                                      encode(error_picture(small, self.small_truth)))


def map_key(record: Record) -> tuple[str, str, str, str, str]:
    """Key of a record's pictures in :attr:`SceneAlbum.maps`."""
    return record.protocol, record.method, record.preprocess, record.degradation, record.task


def ground_truth_range(gt: np.ndarray, *, max_disp: int) -> tuple[float, float]:
    """(min, max) px of the finite ground truth; (0, ``max_disp``) when it has none or is flat."""
    finite = np.asarray(gt, np.float64)
    finite = finite[np.isfinite(finite)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    return (low, high) if high > low else (0.0, float(max(max_disp, 1)))


def task_images(protocol: str, task: str, left_rgb: np.ndarray, right_rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The left and right images a scored prediction of ``protocol`` comes from: the task's
    bands, or for a combined prediction (``RGB-median``) the colour views it combines."""
    for candidate in get_protocol(protocol).tasks:
        if candidate.name == task:
            return candidate.bands(left_rgb, right_rgb)
    return left_rgb, right_rgb


def band_picture(image: np.ndarray, width: int) -> np.ndarray:
    """A band ((H, W), [0, 1]) or colour view ((H, W, 3) R, G, B, [0, 1]) as an 8-bit picture
    at most ``width`` px wide (area averaging), its values as they are (no stretch): (h, w)
    grey for a band (a grey PNG is a third the size of a colour one), (h, w, 3) B, G, R for a view."""
    image = np.asarray(image, np.float32)
    scale = min(1.0, width / image.shape[1])
    if scale < 1.0:
        size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    eight_bit = np.rint(np.clip(np.nan_to_num(image), 0.0, 1.0) * 255.0).astype(np.uint8)
    return eight_bit if eight_bit.ndim == 2 else np.ascontiguousarray(eight_bit[:, :, ::-1])


def shrink_map(values: np.ndarray, width: int) -> np.ndarray:
    """An (H, W) map at most ``width`` px wide, by nearest neighbour (NaN stays NaN, no
    value is invented between two surfaces); a copy when it is narrow enough already."""
    values = np.asarray(values, np.float32)
    if values.shape[1] <= width:
        return values.copy()
    rows = np.minimum((np.arange(round(values.shape[0] * width / values.shape[1])) + 0.5)
                      * values.shape[1] / width, values.shape[0] - 1).astype(int)
    columns = np.minimum((np.arange(width) + 0.5) * values.shape[1] / width, values.shape[1] - 1).astype(int)
    return values[np.ix_(rows, columns)]


def encode(picture: np.ndarray) -> bytes:
    """``picture`` ((H, W) grey or (H, W, 3) B, G, R, uint8) encoded as JPEG (:data:`JPEG_QUALITY`,
    optimised Huffman tables): a quarter of the most compressed PNG's size for these pictures."""
    ok, encoded = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY, cv2.IMWRITE_JPEG_OPTIMIZE, 1])
    if not ok:
        raise ValueError(f"OpenCV could not encode a picture of shape {picture.shape} as JPEG")
    return encoded.tobytes()
