"""The files of one match, written together: the disparity (filled or not), its picture with a
colour bar (``--vis``), the validity mask and the confidence (:func:`write_match_outputs`, the
one writer ``cade disparity``, ``cade batch`` and rig pairs share).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.io.atomic import intended_path
from cade_cli.io.disparity import as_disparity, write_atomically, write_disparity, write_png, write_validity
from cade_cli.io.pictures import (
    INVALID_COLOUR, ROBUST_PERCENTILES, ColourBar, Swatch, colour_map, format_value, robust_range, scaled_picture,
)


def colorize_disparity(
    disparity: np.ndarray, *, vmin: float | None = None, vmax: float | None = None
) -> np.ndarray:
    """Colour a disparity map with the Turbo colormap, for looking at.

    Args:
        disparity: (H, W) pixels, NaN (any non-finite) = invalid.
        vmin, vmax: disparities mapped to the two ends of the colormap; values
            outside are clipped. Default: the finite minimum and maximum.

    Returns:
        (H, W, 3) uint8 in B, G, R order (ready for ``cv2.imwrite``); invalid pixels
        black. With an empty range (vmin == vmax) values above it get the high end's
        colour and the rest the low end's (a constant map is all low-end colour).

    Raises:
        CadeError: not 2-D, or ``vmax < vmin``.
    """
    values = as_disparity(disparity)
    low, high = _colour_range(values[np.isfinite(values)], vmin=vmin, vmax=vmax)
    return colour_map(values, colormap=cv2.COLORMAP_TURBO, low=low, high=high)


def disparity_picture(disparity: np.ndarray, *, value_range: tuple[float, float] | None = None,
                      invalid_label: str = "black = invalid / rejected") -> np.ndarray:
    """A disparity map for looking at: Turbo colours, invalid pixels black, and under it
    a colour bar in px with its range and a legend (:func:`cade_cli.io.pictures.with_legend`).

    Args:
        disparity: (H, W) pixels, NaN (any non-finite) = invalid.
        value_range: (min, max) px mapped to the ends of the colour bar, values beyond
            clipped to the end colours: the same range gives the same colour to the same
            disparity in every picture. Default: the 1st-99th percentile of the valid
            disparities (:func:`cade_cli.io.pictures.robust_range`), so a few outliers do
            not squeeze the rest into one colour.
        invalid_label: the legend of the black pixels (a ground truth's: no ground truth).

    Returns:
        (H + legend, max(W, 360), 3) uint8, B, G, R; the top-left (H, W) block is
        :func:`colorize_disparity` of the map with that range.
    """
    values = as_disparity(disparity)
    if value_range is None:
        low, high = robust_range(values)
        how = f"the {ROBUST_PERCENTILES[0]:g}-{ROBUST_PERCENTILES[1]:g} % range of the valid pixels"
    else:
        low, high = (float(bound) for bound in value_range)
        if high <= low:
            raise CadeError(f"a colour range must have min < max, got {low} : {high}")
        how = "a fixed range"
    shown = [format_value(bound, (high - low) / 10) for bound in (low, high)]  # a decimal more than the ticks
    caption = (f"disparity, px: colours span {shown[0]} to {shown[1]} ({how}); "
               "values beyond get the end colours")
    if not np.isfinite(values).any():
        caption = "disparity, px: no valid pixel"
    bar = ColourBar(cv2.COLORMAP_TURBO, low, high, caption)
    return scaled_picture(values, bar, swatches=[Swatch(INVALID_COLOUR, invalid_label)])


def write_visualization(path: Path, disparity: np.ndarray, *, value_range: tuple[float, float] | None = None) -> None:
    """Write :func:`disparity_picture` of ``disparity`` (with its colour bar) as a PNG, all-or-nothing.

    Raises:
        CadeError: ``path`` does not end in .png, plus :func:`disparity_picture`'s errors.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise CadeError(f"visualization {intended_path(path)} must be a .png file; change its extension to .png")
    picture = disparity_picture(disparity, value_range=value_range)
    write_atomically(path, lambda tmp: write_png(tmp, picture))


def _colour_range(valid_values: np.ndarray, *, vmin: float | None, vmax: float | None) -> tuple[float, float]:
    """The (low, high) disparities of the colormap ends."""
    if vmin is not None and vmax is not None and vmax < vmin:
        raise CadeError(f"vmax {vmax} is below vmin {vmin}; swap them")
    if valid_values.size == 0:
        return 0.0, 0.0
    low = float(valid_values.min()) if vmin is None else float(vmin)
    high = float(valid_values.max()) if vmax is None else float(vmax)
    if vmin is None:
        low = min(low, high)
    if vmax is None:
        high = max(high, low)
    return low, high


def write_match_outputs(files: dict[str, Path], *, dense: np.ndarray, disparity: np.ndarray, valid: np.ndarray,
                        confidence: np.ndarray | None, fill: str = "row",
                        vis_range: tuple[float, float] | None = None) -> None:
    """Write a match's outputs, each to ``files[role]`` when the role is there: ``disparity``
    (``dense`` for ``fill="row"``, else the unfilled ``disparity``, NaN where rejected),
    ``vis`` (of the unfilled map: rejected pixels black, colours over ``vis_range`` px,
    default the robust range of :func:`disparity_picture`), ``validity`` and ``confidence``
    (float32 TIFF). ``cade disparity``, ``--rig`` and ``cade batch`` all write through here."""
    write_disparity(files["disparity"], dense if fill == "row" else disparity)
    if "vis" in files:
        write_visualization(files["vis"], disparity, value_range=vis_range)
    if "validity" in files:
        write_validity(files["validity"], valid)
    if "confidence" in files:  # no NaN: 0 where rejected
        write_disparity(files["confidence"], confidence)
