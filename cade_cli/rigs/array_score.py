"""How well an array's bands line up with its reference band, with no ground truth (``cade
array-score``): per camera, the correlation of gradient orientations and the mutual information
of each band with the reference, in windows, before and after a registration.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.rigs.array_cube import ArrayCube


SCORE_WINDOW = 15
"""Side, px, of the windows :func:`gradient_correlation` correlates gradients in."""


def _gradients(band: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    band = np.asarray(band, np.float32)
    return cv2.Sobel(band, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(band, cv2.CV_32F, 0, 1, ksize=3)


def gradient_correlation(reference: np.ndarray, band: np.ndarray, valid: np.ndarray, *,
                         window: int = SCORE_WINDOW) -> float:
    """Mean local normalised gradient correlation of two registered bands, in [0, 1].

    In every ``window`` x ``window`` neighbourhood, ``|sum g_ref . g_band| / sqrt(sum
    |g_ref|^2 sum |g_band|^2)`` (3x3 Sobel gradients): 1 where the edges of both bands
    coincide, whatever their contrast or its sign (a filter may invert it), near 0 where
    they are displaced. Averaged over the pixels whose whole window is ``valid`` and has
    gradient in both bands (the 20 % least textured of those are left out: flat sky and
    walls carry no alignment information).

    Raises:
        CadeError: bands of different shapes or no pixel to score.
    """
    reference, band = np.asarray(reference, np.float32), np.asarray(band, np.float32)
    if reference.shape != band.shape or np.shape(valid) != reference.shape:
        raise CadeError(f"bands {reference.shape}, {band.shape} and mask {np.shape(valid)} differ in shape")
    usable = np.asarray(valid, bool) & np.isfinite(reference) & np.isfinite(band)
    rx, ry = _gradients(np.where(usable, reference, 0))
    bx, by = _gradients(np.where(usable, band, 0))
    box = lambda image: cv2.boxFilter(image, cv2.CV_32F, (window, window), normalize=False)  # noqa: E731
    cross = box(rx * bx + ry * by)
    energy = box(rx * rx + ry * ry) * box(bx * bx + by * by)
    whole = cv2.erode(usable.astype(np.uint8), np.ones((window + 2, window + 2), np.uint8),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    scored = whole & (energy > 0)
    if not scored.any():
        raise CadeError("no pixel to score: the bands share no valid, textured area")
    textured = energy[scored] >= np.quantile(energy[scored], 0.2)
    local = np.abs(cross[scored]) / np.sqrt(energy[scored])
    return float(local[textured].mean())


def mutual_information(reference: np.ndarray, band: np.ndarray, valid: np.ndarray, *, bins: int = 64) -> float:
    """Mutual information of two bands over ``valid`` pixels, bits (each band's values
    binned between its 0.5 and 99.5 percentiles)."""
    usable = np.asarray(valid, bool) & np.isfinite(reference) & np.isfinite(band)
    if not usable.any():
        raise CadeError("no pixel to score: the bands share no valid area")
    a, b = np.asarray(reference)[usable], np.asarray(band)[usable]
    edges = [np.linspace(*np.percentile(v, [0.5, 99.5]), bins + 1) for v in (a, b)]
    joint, _, _ = np.histogram2d(np.clip(a, edges[0][0], edges[0][-1]), np.clip(b, edges[1][0], edges[1][-1]),
                                 bins=edges)
    joint /= joint.sum()
    pa, pb = joint.sum(axis=1, keepdims=True), joint.sum(axis=0, keepdims=True)
    nonzero = joint > 0
    return float((joint[nonzero] * np.log2(joint[nonzero] / (pa @ pb)[nonzero])).sum())


@dataclass(frozen=True)
class AlignmentScore:
    """One camera of one cube scored against the reference band."""

    camera: str
    band: str
    gradient_correlation: float
    mutual_information: float
    scored_share: float


SAME_SCENE_CORRELATION = 0.9
"""Two cubes of one capture share their reference band (the reference camera's picture): a
normalised correlation of the two below this means two scenes (or captures), not comparable."""


def check_same_capture(cubes: Sequence[ArrayCube], names: Sequence[str]) -> None:
    """Refuse cubes that are not registrations of one capture of one array: another size,
    other bands or cameras, or a reference band that differs (:data:`SAME_SCENE_CORRELATION`).

    Raises:
        CadeError: naming the two cubes (``names``) and what differs, in one line.
    """
    first = cubes[0]
    height, width = first.reference.shape
    for cube, name in zip(cubes[1:], names[1:]):
        other = f"{name} and {names[0]}"
        if cube.reference.shape != first.reference.shape:
            raise CadeError(f"{other} differ in size ({cube.reference.shape[1]}x{cube.reference.shape[0]} vs "
                            f"{width}x{height}); score cubes of one array together")
        if len(cube.bands) != len(first.bands) or cube.cameras != first.cameras:
            raise CadeError(f"{other} hold other bands ({len(cube.bands)}: {', '.join(cube.cameras)} vs "
                            f"{len(first.bands)}: {', '.join(first.cameras)}); score cubes of one array together")
        both = np.isfinite(cube.reference) & np.isfinite(first.reference)
        correlation = float(np.corrcoef(cube.reference[both], first.reference[both])[0, 1]) if both.any() else 0.0
        if not correlation >= SAME_SCENE_CORRELATION:  # NaN (a constant band) is refused too
            raise CadeError(f"{other} have different reference bands (correlation {correlation:.2f}, below "
                            f"{SAME_SCENE_CORRELATION}): two scenes or captures; score registrations of one capture "
                            "together")


def score_cubes(cubes: Sequence[ArrayCube], *, window: int = SCORE_WINDOW,
                names: Sequence[str] | None = None) -> list[list[AlignmentScore]]:
    """Score each camera of each cube over the pixels valid in *every* cube, so that
    registrations of one array are compared on the same pixels.

    Args:
        names: what to call the cubes in messages (their files); default cube 1, cube 2, ...

    Returns:
        per cube, per camera: :class:`AlignmentScore`.

    Raises:
        CadeError: cubes that are not of one capture of one array (:func:`check_same_capture`).
    """
    first = cubes[0]
    check_same_capture(cubes, names or [f"cube {k}" for k in range(1, len(cubes) + 1)])
    scores: list[list[AlignmentScore]] = [[] for _ in cubes]
    for i, camera in enumerate(first.cameras):
        common = np.logical_and.reduce([cube.valid[i] for cube in cubes])
        for cube, row in zip(cubes, scores):
            row.append(AlignmentScore(
                camera, cube.bands[1 + i],
                gradient_correlation(cube.reference, cube.registered[i], common, window=window),
                mutual_information(cube.reference, cube.registered[i], common), float(common.mean())))
    return scores
