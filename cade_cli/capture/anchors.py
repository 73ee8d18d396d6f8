"""The anchors that ``register-capture`` is measured against, on the product's own frame and
output grid: every band undistorted and turned by its lens rotation into the common pinhole
frame (:func:`~cade_cli.capture.model.band_pixels`), then either left there (lens rotations
only) or fitted by one ECC homography on gradient images (the vendor's method,
:func:`~cade_cli.capture.homography.ecc_homography`), and resampled once, bilinearly, from its
raw file onto the reference band's raw pixel grid, NaN where it was not seen: the grid and
values ``register-capture``'s cube has, so the two are scored on the same windows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cade_cli.capture.homography import ecc_homography, feature_homography
from cade_cli.capture.model import Capture, band_pixels, reference_frame_pixels
from cade_cli.capture.parallax import plane_homography
from cade_cli.capture.register import read_raw, sample_bilinear
from cade_cli.errors import CadeError


@dataclass
class AnchorResult:
    """One anchor's registered capture.

    Attributes:
        bands: band name -> (H, W) float32 on the reference band's raw grid (raw values,
            bilinear), NaN where not seen; the reference band is its raw values.
        homographies: band name -> (3, 3) common-frame px of the reference -> of the band
            (rotation removed).
        starts: band name -> where ECC started: ``"rotations"``, ``"features"`` or ``"plane"``.
        failures: band name -> why the band could not be registered (left out of ``bands``).
    """

    bands: dict[str, np.ndarray]
    homographies: dict[str, np.ndarray] = field(default_factory=dict)
    starts: dict[str, str] = field(default_factory=dict)
    failures: dict[str, str] = field(default_factory=dict)


def common_frame(capture: Capture, raw: list[np.ndarray]) -> list[np.ndarray]:
    """Each band's signal (raw less black level) in the common pinhole frame, NaN outside it."""
    width, height = capture.frame[1]
    x, y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    frames = []
    for index, band in enumerate(capture.bands):
        signal = np.asarray(raw[index], np.float32) - np.float32(band.black_level)
        values, inside = sample_bilinear(signal, *band_pixels(capture, index, x, y))
        frames.append(np.where(inside, values, np.float32(np.nan)))
    return frames


def on_reference_grid(capture: Capture, raw: list[np.ndarray], index: int,
                      homography: np.ndarray | None) -> np.ndarray:
    """Band ``index``'s raw values on the reference band's raw grid through ``homography``
    (common-frame px of the reference -> of the band; None: the lens rotation alone), NaN
    where the sample falls outside the band's image."""
    raw_x, raw_y = np.meshgrid(*(np.arange(n, dtype=np.float32) for n in capture.size))
    px, py = reference_frame_pixels(capture, raw_x, raw_y)
    values, inside = sample_bilinear(raw[index], *band_pixels(capture, index, px, py, homography))
    return np.where(inside, values, np.float32(np.nan)).astype(np.float32)


def ecc_from_rotations_or_features(reference: np.ndarray, band: np.ndarray) -> tuple[np.ndarray, str]:
    """ECC homography (band px -> reference px, common frame) started from the lens rotations
    (identity in the common frame); where that fails, from a feature-match homography (SIFT,
    as OpenDroneMap starts); where that fails too, from register-capture's own sparse
    cross-spectral plane (:func:`~cade_cli.capture.parallax.plane_homography`). Returns it and
    where it started: ``"rotations"``, ``"features"`` or ``"plane"``.

    Raises:
        CadeError: every start fails (the reasons in one line).
    """
    reasons = []
    for start in ("rotations", "features", "plane"):
        try:
            if start == "rotations":
                return ecc_homography(reference, band), start
            if start == "features":
                init, _ = feature_homography(reference, band)
            else:
                init = np.linalg.inv(plane_homography(np.nan_to_num(reference), np.nan_to_num(band)))
            return ecc_homography(reference, band, init=init), start
        except CadeError as error:
            reasons.append(f"from the {start}: {error}")
    raise CadeError("; ".join(reasons))


def register_anchor(capture: Capture, *, ecc: bool, raw: list[np.ndarray] | None = None) -> AnchorResult:
    """Every band of ``capture`` on the reference band's raw grid by its lens rotation alone
    (``ecc`` False) or by the ECC homography in the common frame (``ecc`` True)."""
    raw = read_raw(capture) if raw is None else raw
    ref = capture.reference
    result = AnchorResult({capture.bands[ref].name: np.asarray(raw[ref], np.float32)})
    frames = common_frame(capture, raw) if ecc else None
    for index, band in enumerate(capture.bands):
        if index == ref:
            continue
        homography = np.eye(3)
        if ecc:
            try:
                to_reference, result.starts[band.name] = ecc_from_rotations_or_features(frames[ref], frames[index])
            except CadeError as error:
                result.failures[band.name] = f"failed: {error}"
                continue
            homography = np.linalg.inv(to_reference)
            homography /= homography[2, 2]
        result.homographies[band.name] = homography
        result.bands[band.name] = on_reference_grid(capture, raw, index, homography)
    return result
