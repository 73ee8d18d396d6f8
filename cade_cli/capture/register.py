"""A capture's bands registered onto its reference band, parallax included: each band is brought
into the reference's pinhole frame (undistorted, lens rotation applied), fitted to it by a plane
homography from sparse cross-spectral matches, and, where the matches show parallax, matched
densely along its baseline (:func:`~cade_cli.rigs.array.match_camera`, the cross-spectral
matchers) and resampled through that disparity. Every band ends on the reference band's raw
pixel grid (the reference is not resampled), its raw values changed only by bilinear
interpolation.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import tifffile

from cade_cli.capture.cameras import link_cameras
from cade_cli.capture.homography import ecc_homography
from cade_cli.capture.metadata import quiet_tifffile
from cade_cli.capture.model import Capture, band_pixels, reference_frame_pixels
from cade_cli.capture.parallax import (Parallax, band_features, cross_spectral_matches, measure_parallax,
                                       plane_from_matches, plane_homography, refine_matches)
from cade_cli.capture.radiometry import Radiometry
from cade_cli.errors import CadeError
from cade_cli.matching.disparity import densify
from cade_cli.rigs.array import fuse_votes, match_camera
from cade_cli.rigs.array_geometry import ArrayCamera
from cade_cli.stereo import DEFAULT_METHOD

MAX_MATCH_PIXELS = 1_500_000
"""The dense matching runs on at most this many pixels per band (a 12 MP band at 0.35 instead of
0.5): memory and time stay those of a 1.2 MP capture's order."""
DEFAULT_MATCH_SCALE = 0.5
"""Dense matching at half resolution by default: a 1.2 MP capture's four pairs in seconds on two
cores (docs/drone.md); the disparity is brought back to full size."""
RANGE_MARGIN_SHARE = (0.25, 1.0)
RANGE_MARGIN_PX = (4, 8)
"""The disparity range searched: the matches' robust extremes widened by these shares of their
span, and by at least these many px, below and above: more above, as the sparse matches miss
small near surfaces more often than far ones (nothing lies beyond infinity, d = 0)."""
NEAR_FACTOR = 4.0
"""The top of each band's search is raised to at least this many times the matches' highest
parallax (:func:`search_range`): the nearest point may be about this many times closer than the
nearest match (IMG_0007's Red edge: matches at 6.9-11.6 px, a cable over the bench at 39-42 px,
docs/drone.md, "Near objects the matches miss")."""
NEAR_LIMIT = 160
"""px of the full-size band: the widening by :data:`NEAR_FACTOR` never raises the top beyond
this, so it never makes the matcher downscale the pair. The network of the default method
searches a span (max - min, px of the pair it is given: the band at the matching scale) at full
resolution up to its widest variant's levels less
:data:`~cade_cli.matching.network.RANGE_MARGIN` (cade-v13: 192 - 8 = 184 px); beyond that it
matches the pair downscaled by 2, 4 ... (:func:`~cade_cli.matching.network.choose_variant`,
:func:`~cade_cli.matching.network.pyramid_factor`). 160 px is 80 px at the default match scale
0.5, and stays within 184 px even at --match-scale 1 with the search's bottom down to -24 px.
(The classical matchers do not downscale; their cost volume grows with the span.)"""


@dataclass(frozen=True)
class BandResult:
    """How one band was registered.

    Attributes:
        name: band name.
        path: ``"reference"``, ``"plane-only"``, ``"plane"`` (the parallax was below the cheap
            path's threshold), ``"parallax"`` or ``"rig"`` (a band over :data:`COARSE_BAND` times
            coarser than the reference, e.g. a thermal band: placed by its lens and rotation
            alone, no matching).
        homography: (3, 3) common-frame px of the reference -> of the band (rotation removed):
            the plane the ``plane-only`` and ``plane`` paths use.
        parallax: what the matches showed (None for the reference and ``--plane-only``).
        search: (min, max) disparity searched, px (None without the dense step).
        matches: sparse matches used.
    """

    name: str
    path: str
    homography: np.ndarray
    parallax: Parallax | None
    search: tuple[int, int] | None
    matches: int


@dataclass(frozen=True)
class CaptureRegistration:
    """A registered capture, on the reference band's raw pixel grid.

    Attributes:
        capture: the :class:`~cade_cli.capture.model.Capture`.
        raw: one (H, W) array per band as read (uint16 for the cameras' files).
        bands: one (H, W) float32 per band: its raw values, bilinearly resampled; NaN where
            the band did not see the pixel.
        valid: one (H, W) bool per band: False where the sample fell outside the band's image,
            or (parallax bands) where the matcher found no trusted disparity (left-right check,
            occlusion, flat area).
        saturated: one (H, W) bool per band: the sample touches a raw pixel at the sensor's
            maximum (:func:`saturation_level`).
        results: one :class:`BandResult` per band.
        sampled: one ((H, W) float32 u, v) per band: where each output pixel was sampled in the
            band's raw image (the reference's own grid for the reference); None per band
            unless asked for (``keep_sampled``).
        seconds: wall time of the registration.
    """

    capture: Capture
    raw: tuple[np.ndarray, ...]
    bands: tuple[np.ndarray, ...]
    valid: tuple[np.ndarray, ...]
    saturated: tuple[np.ndarray, ...]
    results: tuple[BandResult, ...]
    sampled: tuple[tuple[np.ndarray, np.ndarray] | None, ...]
    seconds: float
    radiometry: Radiometry | None = None
    """None: ``bands`` hold raw values; else what each band was converted to (radiance or
    reflectance, :mod:`cade_cli.capture.radiometry`) before its one resampling."""


def saturation_level(raw: np.ndarray) -> int:
    """The largest value an integer band can hold: for data scaled up to 16 bit (every value
    a multiple of 2^k, e.g. 12-bit RedEdge x16, 10-bit Sequoia x64), the type's maximum
    rounded down to that step (65520, 65472); the type's maximum otherwise."""
    if not np.issubdtype(raw.dtype, np.integer):
        return int(np.iinfo(np.uint16).max) if raw.max() > 1 else 1
    top = int(np.iinfo(raw.dtype).max)
    bits = int(np.bitwise_or.reduce(raw.ravel()))
    step = bits & -bits if bits else 1
    return top + 1 - step if step > 1 else top


def read_raw(capture: Capture) -> list[np.ndarray]:
    """Each band's pixels as stored, (H, W)."""
    raw = []
    for band in capture.bands:
        try:
            with quiet_tifffile():
                image = tifffile.imread(band.path, key=0)
        except (OSError, tifffile.TiffFileError, ValueError, IndexError) as error:
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise CadeError(f"{band.path}: cannot read its pixels ({reason})") from None
        if image.shape != (band.size[1], band.size[0]):
            raise CadeError(f"{band.path.name} holds {image.shape} pixels, its tags say {band.size[::-1]}")
        raw.append(image)
    return raw


def sample_bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of ``image`` at (u, v) and where they fell inside it."""
    height, width = image.shape
    finite = np.isfinite(u) & np.isfinite(v)
    u, v = np.where(finite, u, -1).astype(np.float32), np.where(finite, v, -1).astype(np.float32)
    sampled = cv2.remap(np.asarray(image, np.float32), u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = finite & (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)
    return sampled, inside


def _search(parallax: Parallax) -> tuple[int, int]:
    span = parallax.high - parallax.low
    below, above = (max(px, share * span) for px, share in zip(RANGE_MARGIN_PX, RANGE_MARGIN_SHARE))
    return math.floor(parallax.low - below), math.ceil(parallax.high + above)


def check_near(near: float) -> None:
    """Refuse a ``near`` factor (:func:`search_range`) below 1 or not finite."""
    if not (math.isfinite(near) and near >= 1):
        raise CadeError(f"the near factor must be at least 1 (1: the matches' own range), got {near:g}")


def search_range(parallax: Parallax, near: float = NEAR_FACTOR) -> tuple[int, int]:
    """(min, max) disparity a band's dense matching searches, px of the full-size band: the
    matches' robust extremes widened by :data:`RANGE_MARGIN_SHARE` / :data:`RANGE_MARGIN_PX`,
    its top then raised to ``near`` x ``parallax.high`` (at most :data:`NEAR_LIMIT` px; never
    lowered). ``near`` >= 1; 1 keeps the matches' widened range."""
    low, high = _search(parallax)
    return low, max(high, min(math.ceil(near * parallax.high), NEAR_LIMIT))


SMALL_HOLE_SHARE = 0.002
"""Unmatched areas smaller than this share of the image each (the matcher's checks reject
patches of weak texture even on a flat field) that no nearer surface hides take the filled
disparity (from the background side) and count as seen; larger ones stay unseen."""


def small_holes(trusted: np.ndarray, *, share: float = SMALL_HOLE_SHARE) -> np.ndarray:
    """(H, W) bool: the connected areas of ``~trusted`` smaller than ``share`` of the image."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats((~trusted).astype(np.uint8), connectivity=8)
    small = stats[:, cv2.CC_STAT_AREA] < share * trusted.size
    small[0] = False  # label 0: the trusted pixels
    return small[labels]


def _dense_disparity(reference: np.ndarray, warped: np.ndarray, inside: np.ndarray, name: str,
                     parallax: Parallax, search: tuple[int, int], *, method: str, scale: float,
                     model: str | None) -> tuple[np.ndarray, np.ndarray]:
    """The reference view's disparity along the band's baseline (px, dense) and where the band
    saw the pixel: the matcher's checks passed and no nearer surface hides it from the band,
    or a small unmatched area (:func:`small_holes`) that no nearer surface hides."""
    camera = ArrayCamera(name, name, (reference.shape[1], reference.shape[0]), parallax.baseline)
    vote = match_camera(reference, warped, inside, camera, unit=1.0, search=search, method=method, scale=scale,
                        model=model)
    fused, count = fuse_votes([vote], [camera], unit=1.0, tolerance=1.0 / scale)
    trusted = count > 0
    if not trusted.any():
        return np.zeros(reference.shape, np.float32), trusted
    dense = densify(fused, trusted)
    _, visible = fuse_votes([dense], [camera], unit=1.0, tolerance=1.0 / scale)
    return dense, trusted | (small_holes(trusted) & (visible > 0))


PLANE_ECC_ITERATIONS = 10
"""ECC iterations that refine the cheap path's plane (full size only, from the sparse matches'
plane): on the nearly planar field capture, 10 took each band's residual shift from 0.08-0.13 px
to 0.07-0.11 px (the vendor's ECC from the lens rotations: 0.07-0.11) in about 1 s CPU; 30 did
no better (docs/drone.md)."""


def refined_plane(reference: np.ndarray, band: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """``homography`` (common-frame px of the reference -> of the band, from sparse matches)
    refined by ECC on the two bands' gradient images (:func:`~cade_cli.capture.homography.ecc_homography`,
    full size, :data:`PLANE_ECC_ITERATIONS`); ``homography`` itself where ECC fails. NaN: not seen."""
    try:
        to_reference = ecc_homography(reference, band, init=np.linalg.inv(homography), levels=1,
                                      iterations=PLANE_ECC_ITERATIONS)
    except CadeError:
        return homography
    refined = np.linalg.inv(to_reference)
    return refined / refined[2, 2]


COARSE_BAND = 3.0
"""A band whose focal length (px) is this many times shorter than the reference's (a 160x120
thermal band beside 1.2-3 MP bands) is not matched: upsampled onto the reference's grid it
holds too little detail, and other light, for cross-spectral features; its lens and rotation
place it (its parallax is below its own pixel at any height a flight is flown)."""


def coarse(capture: Capture, index: int) -> bool:
    """Whether band ``index`` is :data:`COARSE_BAND` times coarser than the reference."""
    return capture.bands[index].lens.focal * COARSE_BAND < capture.reference_band.lens.focal


def _band_geometry(capture, index, raw_band, reference, reference_features, grid, *, reference_seen, plane_only,
                   method, scale, model, near) -> tuple[BandResult, np.ndarray | None, np.ndarray | None]:
    """One band's :class:`BandResult` and, for the parallax path, its dense disparity and trust
    in the common frame."""
    name = capture.bands[index].name
    if coarse(capture, index):
        return BandResult(name, "rig", np.eye(3), None, None, 0), None, None
    x, y = grid
    rotated, seen = sample_bilinear(raw_band, *band_pixels(capture, index, x, y))
    if plane_only:
        homography = plane_homography(reference, rotated)
        return BandResult(name, "plane-only", homography, None, None, 0), None, None
    points_reference, points_band = refine_matches(reference, rotated, *cross_spectral_matches(reference_features,
                                                                                               rotated))
    homography, _ = plane_from_matches(points_reference, points_band)
    parallax = measure_parallax(points_reference, points_band, homography)
    if parallax.negligible:
        homography = refined_plane(np.where(reference_seen, reference, np.float32(np.nan)),
                                   np.where(seen, rotated, np.float32(np.nan)), homography)
        return BandResult(name, "plane", homography, parallax, None, len(points_reference)), None, None
    across = parallax.across_at(x, y)
    warped, inside = sample_bilinear(raw_band, *band_pixels(capture, index, x + across * np.float32(parallax.normal[0]),
                                                     y + across * np.float32(parallax.normal[1])))
    search = search_range(parallax, near)
    disparity, trusted = _dense_disparity(reference, warped, inside, name, parallax, search, method=method,
                                          scale=scale, model=model)
    return BandResult(name, "parallax", homography, parallax, search, len(points_reference)), disparity, trusted


def matching_scale(capture: Capture, scale: float) -> float:
    """``scale``, lowered so the matched band has at most :data:`MAX_MATCH_PIXELS`."""
    width, height = capture.frame[1]
    return min(scale, math.sqrt(MAX_MATCH_PIXELS / (width * height)))


def register_capture(capture: Capture, *, plane_only: bool = False, method: str = DEFAULT_METHOD,
                     scale: float = DEFAULT_MATCH_SCALE, model: str | None = None, near: float = NEAR_FACTOR,
                     keep_sampled: bool = False, radiometry: Radiometry | None = None,
                     on_band: Callable[[BandResult], None] | None = None) -> CaptureRegistration:
    """Register every band of ``capture`` onto its reference band.

    Args:
        capture: :func:`~cade_cli.capture.model.load_capture`.
        plane_only: one homography per band (:func:`~cade_cli.capture.parallax.plane_homography`),
            no parallax: the anchors' model, for comparison.
        method: the dense matcher (:data:`cade_cli.matching.MATCHERS`).
        scale: resolution of the dense matching, 0 < scale <= 1 (the disparity is brought back
            to full size); lowered for bands over :data:`MAX_MATCH_PIXELS` (:func:`matching_scale`).
        model: another network for the learned methods (:func:`~cade_cli.stereo.estimate_disparity`).
        near: each parallax band's search reaches up to this many times the matches' highest
            parallax (:func:`search_range`, at most :data:`NEAR_LIMIT` px), >= 1.
        keep_sampled: keep where each output pixel was sampled in each band
            (:attr:`CaptureRegistration.sampled`; two float32 maps per band).
        on_band: called with each band's :class:`BandResult` once it is done (progress).
        radiometry: convert each band's raw image to radiance or reflectance by its camera's
            model before its one resampling (the matching still uses the raw signals); None
            keeps the raw values.

    Returns:
        :class:`CaptureRegistration`.
    """
    if not 0 < scale <= 1:
        raise CadeError(f"the matching scale must be in (0, 1], got {scale}")
    check_near(near)
    start = time.perf_counter()
    raw = read_raw(capture)
    width, height = capture.frame[1]
    scale = matching_scale(capture, scale)
    x, y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    ref_index = capture.reference
    signal = [np.asarray(image, np.float32) - np.float32(band.black_level) for image, band in zip(raw, capture.bands)]
    capture = link_cameras(capture, signal)  # a second camera body's rotation, measured (RedEdge-MX Dual)
    reference, reference_seen = sample_bilinear(signal[ref_index], *band_pixels(capture, ref_index, x, y))
    reference_features = band_features(reference)
    values_of = raw if radiometry is None else radiometry.convert(raw, [band.path for band in capture.bands])
    raw_x, raw_y = np.meshgrid(*(np.arange(n, dtype=np.float32) for n in capture.size))
    px, py = reference_frame_pixels(capture, raw_x, raw_y)  # the output grid (reference raw px) in the common frame
    bands, valid, saturated, results, sampled = [], [], [], [], []
    for index, band in enumerate(capture.bands):
        level = saturation_level(raw[index])
        if index == ref_index:
            result = BandResult(band.name, "reference", np.eye(3), None, None, 0)
            bands.append(values_of[index].astype(np.float32))
            valid.append(np.ones(raw[index].shape, bool))
            saturated.append(raw[index] >= level)
            sampled.append((raw_x, raw_y) if keep_sampled else None)
        else:
            result, disparity, trusted = _band_geometry(capture, index, signal[index], reference, reference_features,
                                                        (x, y), reference_seen=reference_seen,
                                                        plane_only=plane_only, method=method, scale=scale, model=model,
                                                        near=near)
            if disparity is None:
                u, v = band_pixels(capture, index, px, py, result.homography)
                seen = np.ones(px.shape, bool)
            else:
                d, in_frame = sample_bilinear(disparity, px, py)
                seen = in_frame & (cv2.remap(trusted.astype(np.uint8), px, py, cv2.INTER_NEAREST) > 0)
                parallax = result.parallax
                shift = parallax.across_at(px, py)
                u, v = band_pixels(capture, index,
                                   px + shift * np.float32(parallax.normal[0]) - d * np.float32(parallax.baseline[0]),
                                   py + shift * np.float32(parallax.normal[1]) - d * np.float32(parallax.baseline[1]))
            values, inside = sample_bilinear(values_of[index], u, v)
            touched, _ = sample_bilinear((raw[index] >= level).astype(np.float32), u, v)
            bands.append(values)
            valid.append(inside & seen)
            saturated.append(touched > 0)
            sampled.append((u, v) if keep_sampled else None)
        results.append(result)
        if on_band is not None:
            on_band(result)
    bands = [np.where(ok, values, np.float32(np.nan)).astype(np.float32) for values, ok in zip(bands, valid)]
    return CaptureRegistration(capture, tuple(raw), tuple(bands), tuple(valid), tuple(saturated), tuple(results),
                               tuple(sampled), time.perf_counter() - start, radiometry)
