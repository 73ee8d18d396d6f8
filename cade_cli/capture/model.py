"""A capture as a rig: its band files (any order) sorted by rig index, the reference band, the
common pinhole frame the bands are registered in, and where each frame's pixels fall in each
raw band image (undistortion and lens rotation, optionally a residual homography and a shift).
Bands may differ in size (a panchromatic band at twice the size, a 160x120 thermal band): each
band's lens maps rays to its own pixels; ``--bands`` chooses which bands a capture keeps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from cade_cli.capture.lens import BrownLens
from cade_cli.capture.metadata import RIG_OPTION, BandFile, read_band_file
from cade_cli.errors import CadeError

MAX_FRAME_GROWTH = 1.5
"""The common frame is at most this many times the raw image's width and height."""
DEFAULT_REFERENCE = "Green"
"""The vendors' reference band (MicaSense and Parrot align onto Green)."""


@dataclass(frozen=True)
class Capture:
    """The bands of one shot.

    Attributes:
        bands: one :class:`BandFile` per band, in rig-index order (the capture's band order).
        reference: index into ``bands`` of the reference band.
        left_out: the bands ``--bands`` left out, in rig-index order.
        linked: (band name, degrees) per second camera body's reference band: its rotation
            against the reference as measured from the images, None where the capture was too
            near to measure it (:func:`cade_cli.capture.cameras.link_cameras`).
        first_camera_parallax: the first camera's bands' displacement from infinity, px, that
            decided it (:func:`cade_cli.capture.cameras.first_camera_parallax`); None without
            a second camera.
    """

    bands: tuple[BandFile, ...]
    reference: int
    left_out: tuple[BandFile, ...] = ()
    linked: tuple[tuple[str, float | None], ...] = ()
    first_camera_parallax: float | None = None

    @property
    def reference_band(self) -> BandFile:
        return self.bands[self.reference]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the reference band (the output grid), px."""
        return self.reference_band.size

    @cached_property
    def frame(self) -> tuple[np.ndarray, tuple[int, int]]:
        """The common pinhole frame the bands are matched in: ((3, 3) intrinsics, (width, height)).

        The reference lens's focal length; the principal point and size such that the whole
        reference image, undistorted, fits (a fisheye's corners reach beyond the raw image's
        size), each side at most :data:`MAX_FRAME_GROWTH` times the raw image's.
        """
        lens = self.reference_band.lens
        width, height = self.size
        u = np.concatenate([np.arange(width), np.arange(width), np.zeros(height), np.full(height, width - 1)])
        v = np.concatenate([np.zeros(width), np.full(width, height - 1), np.arange(height), np.arange(height)])
        x, y = lens.rays(u.astype(np.float64), v.astype(np.float64))
        low = np.array([lens.focal * x.min(), lens.focal * y.min()])
        high = np.array([lens.focal * x.max(), lens.focal * y.max()])
        reach = MAX_FRAME_GROWTH * np.array([width, height]) / 2
        centre = np.array(lens.centre)
        low = np.maximum(np.floor(centre + low), centre - reach)
        high = np.minimum(np.ceil(centre + high), centre + reach)
        K = np.array([[lens.focal, 0, centre[0] - low[0]], [0, lens.focal, centre[1] - low[1]], [0, 0, 1]])
        return K, (int(high[0] - low[0]) + 1, int(high[1] - low[1]) + 1)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsics of the common pinhole :attr:`frame`."""
        return self.frame[0]

    def names(self) -> list[str]:
        return [band.name for band in self.bands]


def _from_rig(band: BandFile, rig) -> BandFile:
    """``band`` with the lens and rotation of the rig camera of the same band (or name)."""
    for camera in rig.cameras:
        if band.name.lower() in (camera.band.lower(), camera.name.lower()):
            if camera.K is None or camera.R is None:
                raise CadeError(f"camera {camera.name} of the rig has no K and R; give a calibrated rig with "
                                f"{RIG_OPTION}")
            dist = np.zeros(5)
            dist[:min(5, len(camera.distortion))] = camera.distortion[:5]
            K = camera.K
            lens = BrownLens(float((K[0, 0] + K[1, 1]) / 2), (float(K[0, 2]), float(K[1, 2])),
                             dist[0], dist[1], dist[4], dist[2], dist[3])
            return replace(band, lens=lens, rotation=np.asarray(camera.R, np.float64),
                           rotation_reference=None)  # the rig's rotations all refer to its reference
    raise CadeError(f"the rig has no camera for band {band.name!r} (its cameras: "
                    f"{', '.join(c.band for c in rig.cameras)}); name the camera's band {band.name!r} in the rig")


def parse_bands(text: str | None) -> tuple[str, ...] | None:
    """``--bands``'s value: band names separated by commas (``"Blue,Green,Red,NIR,Red edge"``,
    case-insensitive, spaces inside a name kept); None or empty: every band."""
    if text is None or not text.strip():
        return None
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    return names or None


def select_bands(bands: Sequence[BandFile], wanted: Sequence[str] | None) -> tuple[list[BandFile], list[BandFile]]:
    """(kept, left out): the bands named in ``wanted`` (case-insensitive), all when None.

    Raises:
        CadeError: a name that is no band's, naming the bands there are.
    """
    if not wanted:
        return list(bands), []
    names = {band.name.lower() for band in bands}
    unknown = [name for name in wanted if name.lower() not in names]
    if unknown:
        raise CadeError(f"--bands {unknown[0]!r}: the capture has no such band (its bands: "
                        f"{', '.join(band.name for band in bands)})")
    keep = {name.lower() for name in wanted}
    return ([band for band in bands if band.name.lower() in keep],
            [band for band in bands if band.name.lower() not in keep])


def load_capture(paths: Sequence[Path | str], *, reference: str | None = None, rig=None,
                 bands: Sequence[str] | None = None) -> Capture:
    """The :class:`Capture` of a shot's band files.

    Args:
        paths: the band files, any order (one per band).
        reference: the reference band's name (case-insensitive); None: Green.
        rig: a :class:`~cade_cli.rigs.rig.Rig` whose calibrated cameras (matched by band
            name) give the lenses and rotations instead of the files' metadata.
        bands: the band names to keep (``--bands``, :func:`parse_bands`); None: all.

    Raises:
        CadeError: fewer than two files (or bands kept), bands of different shots (capture
            ids), a band given twice, an unknown reference or band name, or metadata missing
            (one line naming it).
    """
    if len(paths) < 2:
        raise CadeError(f"a capture needs two band files or more, got {len(paths)}; give every band of the shot "
                        "(e.g. IMG_0001_*.tif)")
    found = sorted((read_band_file(path, need_geometry=rig is None) for path in paths),
                   key=lambda band: band.rig_index)
    kept, left_out = select_bands(found, bands)
    if len(kept) < 2:
        raise CadeError(f"--bands keeps {len(kept)} band ({', '.join(b.name for b in kept)}); a capture needs two "
                        "or more")
    bands = [_from_rig(band, rig) for band in kept] if rig is not None else kept
    ids = {band.capture_id for band in bands if band.capture_id}
    if len(ids) > 1:
        raise CadeError(f"the files come from {len(ids)} captures (capture ids {', '.join(sorted(ids))}); give the "
                        "band files of one shot")
    for first, second in zip(bands, bands[1:]):
        if first.rig_index == second.rig_index or first.name == second.name:
            raise CadeError(f"{first.path.name} and {second.path.name} are the same band ({first.name}, rig index "
                            f"{first.rig_index}); give each band once")
    wanted = (reference or DEFAULT_REFERENCE).lower()
    matches = [i for i, band in enumerate(bands) if band.name.lower() == wanted]
    if not matches:
        option = "--reference NAME" if reference is None else "--reference"
        raise CadeError(f"the capture has no band {reference or DEFAULT_REFERENCE!r} (its bands: "
                        f"{', '.join(b.name for b in bands)}); choose one with {option}")
    return Capture(tuple(bands), matches[0], tuple(left_out))


CHUNK_PIXELS = 1 << 20
"""Pixels mapped at a time (bounds the temporaries for 12 MP bands)."""


def band_pixels(capture: Capture, index: int, x: np.ndarray, y: np.ndarray,
                homography: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where common-frame pixels (x, y) fall in band ``index``'s raw image.

    The pixel becomes a ray of the reference camera (``K^-1``), optionally after the residual
    ``homography`` (common-frame px -> px of the band rotated into the reference, 3x3), is
    turned into the band's camera by its lens rotation and projected through its lens. In
    float32 (rays of unit depth: about 1e-4 px), :data:`CHUNK_PIXELS` at a time.

    Returns:
        (u, v) float32 arrays of the shape of ``x``; NaN behind the camera.
    """
    band = capture.bands[index]
    rotation = band.rotation @ capture.reference_band.rotation.T  # reference camera -> this band's
    to_rays = rotation @ np.linalg.inv(capture.K)
    if homography is not None:
        to_rays = to_rays @ homography
    to_rays = to_rays.astype(np.float32)
    x, y = np.asarray(x, np.float32), np.asarray(y, np.float32)
    u, v = np.empty(x.shape, np.float32), np.empty(x.shape, np.float32)
    flat_x, flat_y, flat_u, flat_v = x.reshape(-1), y.reshape(-1), u.reshape(-1), v.reshape(-1)
    for start in range(0, flat_x.size, CHUNK_PIXELS):
        part = slice(start, start + CHUNK_PIXELS)
        px, py = flat_x[part], flat_y[part]
        rx = to_rays[0, 0] * px + to_rays[0, 1] * py + to_rays[0, 2]
        ry = to_rays[1, 0] * px + to_rays[1, 1] * py + to_rays[1, 2]
        rz = to_rays[2, 0] * px + to_rays[2, 1] * py + to_rays[2, 2]
        behind = rz <= 1e-6
        rz[behind] = 1
        pu, pv = band.lens.pixels(rx / rz, ry / rz)
        pu[behind] = pv[behind] = np.nan
        flat_u[part], flat_v[part] = pu, pv
    return u, v


def reference_frame_pixels(capture: Capture, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Common-frame pixels (x, y) of the reference band's raw pixels (u, v): its undistortion."""
    x, y = capture.reference_band.lens.rays(np.asarray(u, np.float64), np.asarray(v, np.float64))
    K = capture.K
    return (K[0, 0] * x + K[0, 2]).astype(np.float32), (K[1, 1] * y + K[1, 2]).astype(np.float32)
