"""Rigs of more than one camera body: the RedEdge-MX Dual's second camera gives its bands'
``RigRelatives`` relative to its own reference band (``RigRelativesReferenceRigCameraIndex`` = 6,
Green-531), and no tag says how that band sits against the rig's reference (Green). The
rotation is measured from the images: the second camera's reference band, brought into the
capture's reference frame, matched to the capture's reference (sparse cross-spectral matches,
one RANSAC homography), and the rotation nearest that homography taken through the frame's
intrinsics. Only on a far capture: on a near one the homography also holds the parallax between
the two bodies (a shift no single capture tells from a rotation), and a rotation that holds it
leaves the parallax step without its zero at infinity (on the Dual's panel shot the second
camera's bands then ended 0.65-0.76 px off at the median instead of 0.28-0.31, docs/drone.md).
A capture is far when the first camera's own bands, turned by their tags' rotations, lie within
:data:`FAR_PARALLAX` of the reference; a near one keeps the tags' rotations (the second camera
parallel to the reference), as before, and says so.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from cade_cli.capture.dji import nearest_rotation
from cade_cli.capture.model import Capture, band_pixels
from cade_cli.capture.parallax import cross_spectral_matches, plane_from_matches, refine_matches
from cade_cli.errors import CadeError

FAR_PARALLAX = 1.0
"""A capture is far enough to measure a second camera's rotation when the median displacement of
the first camera's bands against the reference, once turned by their tags' rotations, is below
this many px (its parallax from infinity; a 4 cm baseline at 60 m and more with a RedEdge's
1450 px focal length)."""


def camera_groups(capture: Capture) -> dict[int, list[int]]:
    """Rig index of each rotation reference -> indices into ``capture.bands`` of the bands whose
    ``RigRelatives`` refer to it (bands without the tag: their own group of the rig reference,
    keyed -1)."""
    groups: dict[int, list[int]] = {}
    for index, band in enumerate(capture.bands):
        key = -1 if band.rotation_reference is None else band.rotation_reference
        groups.setdefault(key, []).append(index)
    return groups


def second_cameras(capture: Capture) -> dict[int, list[int]]:
    """The groups of :func:`camera_groups` other than the capture reference's own."""
    groups = camera_groups(capture)
    own = capture.reference_band.rotation_reference
    return {key: members for key, members in groups.items() if key != (-1 if own is None else own)}


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at (u, v); NaN outside it."""
    height, width = image.shape
    finite = np.isfinite(u) & np.isfinite(v)
    u, v = np.where(finite, u, -1).astype(np.float32), np.where(finite, v, -1).astype(np.float32)
    sampled = cv2.remap(np.asarray(image, np.float32), u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = finite & (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)
    return np.where(inside, sampled, np.float32(np.nan))


def _matches(capture: Capture, signal: list[np.ndarray], index: int) -> tuple[np.ndarray, np.ndarray]:
    """Sparse matches (common-frame px of the reference, of band ``index``) between the two
    bands turned by their tags' rotations."""
    _, (width, height) = capture.frame
    x, y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    reference = _sample(signal[capture.reference], *band_pixels(capture, capture.reference, x, y))
    band = _sample(signal[index], *band_pixels(capture, index, x, y))
    return refine_matches(reference, band, *cross_spectral_matches(reference, band))


def measured_rotation(capture: Capture, signal: list[np.ndarray], index: int) -> np.ndarray | None:
    """The correction C (3, 3) of band ``index``'s rotation against the capture's reference as
    the images show it: with R0 the rotation its tags give (reference camera -> its camera), the
    true one is R0 @ C. None when the two bands give too few matches."""
    homography, inliers = plane_from_matches(*_matches(capture, signal, index))
    if not inliers.any():
        return None
    K = capture.K
    return nearest_rotation(np.linalg.inv(K) @ homography @ K)


def first_camera_parallax(capture: Capture, signal: list[np.ndarray]) -> float:
    """The median displacement, px, between the reference and the other bands of its own camera
    once turned by their tags' rotations (the largest over those bands): 0 on a far capture,
    tens of px near. inf when no such band gives matches."""
    own = camera_groups(capture)[-1 if capture.reference_band.rotation_reference is None
                                 else capture.reference_band.rotation_reference]
    found = []
    for index in own:
        if index == capture.reference:
            continue
        points_reference, points_band = _matches(capture, signal, index)
        if len(points_reference):
            found.append(float(np.median(np.hypot(*(points_band - points_reference).T))))
    return max(found) if found else float("inf")


def link_cameras(capture: Capture, signal: list[np.ndarray]) -> Capture:
    """``capture`` with each second camera's bands turned by the rotation measured between its
    reference band and the capture's reference (:func:`measured_rotation`) when the capture is
    far (:func:`first_camera_parallax` below :data:`FAR_PARALLAX`); ``linked`` names each
    second camera's reference band with the angle, degrees, or None where it was not measured
    (a near capture: the tags' rotations kept). ``capture`` itself when it has one camera.

    Args:
        capture: :func:`~cade_cli.capture.model.load_capture`.
        signal: one (H, W) float32 image per band (the raw values above black level).

    Raises:
        CadeError: a second camera whose reference band is not in the capture (left out by
            ``--bands`` or missing), so its bands' rotations refer to nothing.
    """
    groups = second_cameras(capture)
    if not groups:
        return capture
    bands, linked = list(capture.bands), []
    reference_rotation = capture.reference_band.rotation
    far, parallax = None, None
    for key, members in groups.items():
        heads = [i for i in members if capture.bands[i].rig_index == key]
        if not heads:
            names = ", ".join(capture.bands[i].name for i in members)
            raise CadeError(f"{names}: their RigRelatives refer to rig camera {key}, which is not in the capture; "
                            "give its band file (or keep it in --bands)")
        head = capture.bands[heads[0]]
        if far is None:
            parallax = first_camera_parallax(capture, signal)
            far = parallax < FAR_PARALLAX
        correction = measured_rotation(capture, signal, heads[0]) if far else None
        if correction is None:
            linked.append((head.name, None))
            continue
        old = head.rotation
        initial = old @ reference_rotation.T  # reference camera -> the head's camera, as the tags say
        new = initial @ correction @ reference_rotation
        for i in members:
            bands[i] = replace(capture.bands[i], rotation=capture.bands[i].rotation @ old.T @ new)
        angle = np.degrees(np.arccos(np.clip((np.trace(new @ reference_rotation.T) - 1) / 2, -1, 1)))
        linked.append((head.name, float(angle)))
    return replace(capture, bands=tuple(bands), linked=tuple(linked), first_camera_parallax=parallax)
