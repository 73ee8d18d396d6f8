"""Registering one band onto the reference view with a disparity map."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.disparity import densify
from cade_cli.stereo import DEFAULT_METHOD, DEFAULT_PREPROCESS, estimate_disparity

Fill = Literal["none", "row"]
FILL_CHOICES: tuple[str, ...] = ("none", "row")


@dataclass(frozen=True)
class Registration:
    """A moving band resampled into the reference view.

    Attributes:
        reference: (H, W) float32 reference band, as given.
        registered: (H, W) float32 moving band in reference coordinates; NaN where it is
            unknown and ``fill="none"``.
        valid: (H, W) bool, True where the disparity was trusted and the sample fell
            inside the moving image (False: occluded, rejected or out of view).
        disparity: (H, W) float32 dense disparity of the reference view used for the warp.
    """

    reference: np.ndarray
    registered: np.ndarray
    valid: np.ndarray
    disparity: np.ndarray


def warp_to_reference(moving: np.ndarray, disparity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``moving`` (the right view) at (y, x - d) for every reference pixel.

    Args:
        moving: (H, W) float band of the right view.
        disparity: (H, W) finite float disparity of the left (reference) view, px.

    Returns:
        (registered, inside): (H, W) float32 bilinear samples (border replicated) and a
        bool mask of samples that fell inside the moving image.
    """
    height, width = disparity.shape
    if moving.shape != disparity.shape:
        raise CadeError(f"moving band {moving.shape[::-1]} and disparity {disparity.shape[::-1]} differ in size")
    map_x = (np.arange(width, dtype=np.float32)[None, :] - disparity).astype(np.float32)
    map_y = np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)
    registered = cv2.remap(moving.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (map_x >= 0) & (map_x <= width - 1)
    return registered, inside


def check_given_disparity(disparity: np.ndarray, trusted: np.ndarray, *, name: str = "the disparity map") -> None:
    """Refuse a given map that cannot be a disparity of the pair it is to register.

    A disparity is a shift along the row, so every trusted value lies strictly between
    minus and plus the image width; a value beyond that (e.g. 1e30 used as a marker, or a
    map of another resolution or in other units) means the file is not this pair's map,
    and warping with it would silently produce nothing valid.

    Args:
        disparity: (H, W) float disparity, px; trusted: (H, W) bool, the pixels to use.
        name: how the message names the map (e.g. its file).

    Raises:
        CadeError: no trusted pixel, or trusted values with ``|d| >= W``.
    """
    if not trusted.any():
        raise CadeError(f"{name} has no valid pixel (all inf/NaN, 0 in a PNG, or rejected by the validity mask); "
                        "give a map with valid disparities")
    width = disparity.shape[1]
    values = disparity[trusted]
    beyond = np.abs(values) >= width
    if beyond.any():
        worst = float(values[np.argmax(np.abs(values))])
        raise CadeError(
            f"{name} holds {int(beyond.sum())} values at or beyond +/-{width} px (e.g. {worst:g}), the image width: "
            "not disparities of this pair in pixels; check its resolution and units, and mark unknown pixels as "
            "inf/NaN (0 in a PNG)"
        )


def register(
    moving: np.ndarray,
    reference: np.ndarray,
    *,
    disparity: np.ndarray | None = None,
    disparity_valid: np.ndarray | None = None,
    method: str = DEFAULT_METHOD,
    max_disp: int | None = None,
    min_disp: int = 0,
    preprocess: str = DEFAULT_PREPROCESS,
    fill: Fill = "row",
    model: str | None = None,
    disparity_name: str = "the disparity map",
) -> Registration:
    """Warp the moving (right) band into the reference (left) view.

    Args:
        moving, reference: (H, W) float bands of one rectified pair.
        disparity: (H, W) reference-view disparity in px, NaN where unknown; when None
            it is estimated with ``method`` / ``max_disp`` / ``min_disp`` / ``preprocess``
            (see :func:`cade_cli.estimate_disparity`).
        disparity_valid: (H, W) bool validity of a given ``disparity`` (e.g. the mask
            ``cade disparity --validity`` wrote); None trusts every finite pixel.
        fill: what pixels without a trusted correspondence get: ``"none"`` leaves NaN;
            ``"row"`` samples the moving band with the disparity filled from the
            background side along the row (occluded areas show the background).
        model: another network for the learned methods (:func:`cade_cli.estimate_disparity`).
        disparity_name: how error messages name a given ``disparity`` (e.g. its file).

    Returns:
        :class:`Registration`.

    Raises:
        CadeError: bands of different sizes or not (H, W); a given disparity of another
            size, without a trusted pixel, or not a disparity of this pair
            (:func:`check_given_disparity`).
    """
    if fill not in FILL_CHOICES:
        raise CadeError(f"unknown fill {fill!r}; choose one of {', '.join(FILL_CHOICES)}")
    moving = np.asarray(moving, np.float32)
    reference = np.asarray(reference, np.float32)
    for name, band in (("moving", moving), ("reference", reference)):
        if band.ndim != 2:
            raise CadeError(f"{name} image must be one band of shape (H, W), got shape {band.shape}; pick a band")
    if moving.shape != reference.shape:
        raise CadeError(
            f"moving and reference images differ in size: {moving.shape[1]}x{moving.shape[0]} vs "
            f"{reference.shape[1]}x{reference.shape[0]}; rectify or crop them to the same size"
        )
    if disparity is None:
        result = estimate_disparity(
            reference, moving, method=method, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess,
            model=model,
        )
        disparity, trusted = result.disparity, result.valid
    else:
        disparity = np.asarray(disparity, np.float32)
        if disparity.shape != reference.shape:
            raise CadeError(
                f"disparity map {disparity.shape[1]}x{disparity.shape[0]} does not match the images "
                f"{reference.shape[1]}x{reference.shape[0]}"
            )
        trusted = np.isfinite(disparity)
        if disparity_valid is not None:
            if np.shape(disparity_valid) != disparity.shape:
                raise CadeError(f"validity mask {np.shape(disparity_valid)[::-1]} and disparity map "
                                f"{disparity.shape[::-1]} differ in size; use the mask written with that map")
            trusted &= np.asarray(disparity_valid, bool)
        check_given_disparity(disparity, trusted, name=disparity_name)
    dense = densify(disparity, trusted)
    registered, inside = warp_to_reference(moving, dense)
    valid = trusted & inside
    if fill == "none":
        registered = np.where(valid, registered, np.float32(np.nan))
    return Registration(reference, registered.astype(np.float32), valid, dense)
