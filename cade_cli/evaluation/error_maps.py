"""Pictures of a scored map's errors: |disparity - ground truth| in inferno colours with its
scale and legend (:func:`error_picture`), written beside the map by ``cade benchmark
--save-dir`` (:func:`save_maps`) and shown in its HTML report
(:mod:`cade_cli.evaluation.album`). One drawing for both, so they read the same.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cade_cli.io.atomic import atomic_output


ERROR_SCALE_PX = 8.0
"""The error at the top of the scale of ``*_error.png`` (px): larger errors share its colour."""
NO_GT_COLOUR = (80, 0, 0)
"""BGR of the pixels without ground truth in ``*_error.png``: dark blue (inferno has no blue)."""
NO_ESTIMATE_COLOUR = (160, 160, 160)
"""BGR of the pixels with ground truth but no estimate (NaN) in ``*_error.png``: grey."""


def error_picture(disparity: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """|disparity - gt| for looking at: 0 px black to >= :data:`ERROR_SCALE_PX` white-hot
    (inferno), pixels without GT dark blue, pixels with GT but no estimate grey; a scale
    bar in px of error and a legend of those colours drawn under it.

    Returns:
        (H + legend, max(W, 360), 3) uint8, B, G, R (:func:`cade_cli.io.pictures.with_legend`).
    """
    import cv2

    from cade_cli.io.pictures import ColourBar, Swatch, colour_map, with_legend

    error = np.abs(np.asarray(disparity, np.float64) - gt)
    colour = colour_map(error, colormap=cv2.COLORMAP_INFERNO, low=0.0, high=ERROR_SCALE_PX, missing=NO_ESTIMATE_COLOUR)
    no_gt = ~np.isfinite(gt)
    colour[no_gt] = NO_GT_COLOUR
    swatches = [Swatch(NO_GT_COLOUR, "no ground truth")]
    if (~np.isfinite(disparity) & ~no_gt).any():
        swatches.append(Swatch(NO_ESTIMATE_COLOUR, "no estimate"))
    bar = ColourBar(cv2.COLORMAP_INFERNO, 0.0, ERROR_SCALE_PX,
                    f"|disparity - ground truth|, px of error; {ERROR_SCALE_PX:g} px and more: the end colour")
    return with_legend(colour, bar=bar, swatches=swatches)


def save_maps(folder: Path, stem: str, disparity: np.ndarray, gt: np.ndarray) -> None:
    """Write ``<stem>.pfm`` (the disparity) and ``<stem>_error.png`` (:func:`error_picture`,
    with its scale and legend) into ``folder``."""
    import cv2

    from cade_cli.io.disparity import write_disparity

    folder.mkdir(parents=True, exist_ok=True)
    stem = stem.replace("/", "_").replace(">", "to")
    write_disparity(folder / f"{stem}.pfm", disparity)
    encoded = cv2.imencode(".png", error_picture(disparity, gt))[1]
    with atomic_output(folder / f"{stem}_error.png") as temporary:  # an OS error becomes a CadeError
        temporary.write_bytes(encoded.tobytes())
