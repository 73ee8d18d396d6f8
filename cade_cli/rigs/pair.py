"""One pair of a rig, matched and written: the code path ``cade disparity --rig`` and ``cade batch --rig`` share.

LEFT is the image of the rig's reference camera, RIGHT that of another camera
(:func:`rig_pair_rectification` picks it and its rectification). :func:`check_rig_pair`
refuses images of the wrong size, :func:`match_rig_pair` rectifies, self-checks and
matches the pair (:func:`cade_cli.rigs.rectification.rig_disparity`: an ``auto`` range estimated
on the rectified bands, the pair matched whole or as tiles within the memory limit, as
``cade disparity`` matches a pair without a rig) and puts the result in the frame asked
for (:func:`cade_cli.rigs.outputs.in_frame`), and :func:`write_rig_outputs` writes the
outputs asked for. The commands only add their own messages around these.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching import DisparityRange
from cade_cli.rigs.outputs import FramedDisparity, in_frame
from cade_cli.rigs.rectification import RigDisparity, check_image_size, rectification_of, rig_disparity
from cade_cli.rigs.rig import Rectification, Rig

RIG_OUTPUT_ROLES = ("disparity", "vis", "validity", "confidence", "depth", "points")
"""What :func:`write_rig_outputs` can write: the disparity, and the side outputs of ``cade disparity --rig``."""


def rig_pair_rectification(rig: Rig, camera: str | None = None) -> tuple[str | None, Rectification]:
    """(the other camera, the rectification) of a pair whose RIGHT image is camera ``camera``'s.

    ``camera`` None: the other camera of the rig's stored rectification, else (none stored)
    the first other camera.

    Raises:
        CadeError: an unknown camera, or one the rig cannot rectify with its reference.
    """
    other = camera if camera is not None or rig.rectification is None else rig.rectification.cameras[1]
    return other, rectification_of(rig, other)


def check_rig_pair(rig: Rig, rectification: Rectification, left: np.ndarray, right: np.ndarray, *,
                   paths: tuple[object, object] = (None, None)) -> None:
    """CadeError unless ``left`` and ``right`` have the sizes the rig records for the two
    cameras of ``rectification`` (``paths`` name the files in the message)."""
    for name, image, path in zip(rectification.cameras, (left, right), paths):
        check_image_size(rig, name, image, path=path)


def match_rig_pair(
    rig: Rig, left: np.ndarray, right: np.ndarray, *, other: str | None, frame: str, fill: str, fix_vertical: bool,
    method: str, min_disp: int | str, max_disp: int | str | None, preprocess: str, model: str | None,
    memory_limit: int | None, on_range: Callable[[DisparityRange], None] | None = None,
) -> tuple[RigDisparity, FramedDisparity]:
    """Rectify, self-check and match a rig's pair, and put the result in ``frame``.

    Args:
        rig, other: the rig and the camera of ``right`` (:func:`rig_pair_rectification`).
        left, right: (H, W) float bands of the reference camera and of ``other``.
        frame: ``rectified`` or ``original`` (:data:`cade_cli.rigs.outputs.FRAMES`).
        fill: ``row`` (depth and points from the filled map) or ``none``.
        fix_vertical, method, min_disp, max_disp, preprocess, model, memory_limit: as for
            :func:`~cade_cli.rigs.rectification.rig_disparity`: the range in rectified px, a
            bound ``auto`` estimated on the rectified pair; the pair matched whole when it
            fits ``memory_limit`` (bytes; None: the default), else as tiles.
        on_range: called with the resolved range before matching (it may refuse it).

    Returns:
        (the match in the rectified frame, with the self-check's finding, the range
        searched and the tile plan; the outputs in ``frame``).
    """
    found = rig_disparity(rig, left, right, other=other, fix_vertical=fix_vertical, method=method,
                          max_disp=max_disp, min_disp=min_disp, preprocess=preprocess, model=model,
                          memory_limit=memory_limit, on_range=on_range)
    return found, in_frame(found, rig, frame=frame, fill=fill == "row")


def write_rig_outputs(paths: Mapping[str, Path | None], framed: FramedDisparity, *, fill: str,
                      method: str, vis_range: tuple[float, float] | None = None) -> int | None:
    """Write the outputs of a rig's pair to ``paths`` (role -> file, :data:`RIG_OUTPUT_ROLES`;
    a role missing or None is not written), as ``cade disparity --rig`` writes them.

    ``disparity``: the map (filled unless ``fill`` is ``none``); ``vis``: the colourised
    unfilled disparity (px, with its colour bar; ``vis_range`` (min, max) px fixes its
    colours, :func:`~cade_cli.io.match_outputs.disparity_picture`); ``validity``: the mask;
    ``confidence``: float32 TIFF; ``depth``: float32 TIFF, metres, NaN where unknown;
    ``points``: binary PLY.

    Returns:
        The number of points written, or None when no ``points`` were asked for.

    Raises:
        CadeError: a confidence asked of a method that gives none (nothing is written).
    """
    from cade_cli.io.disparity import write_disparity
    from cade_cli.io.match_outputs import write_match_outputs
    from cade_cli.rigs.outputs import write_ply

    unknown = set(paths) - set(RIG_OUTPUT_ROLES)
    if unknown:
        raise ValueError(f"unknown output roles {sorted(unknown)}; expected some of {RIG_OUTPUT_ROLES}")
    wanted = {role: path for role, path in paths.items() if path is not None}
    if "confidence" in wanted and framed.confidence is None:
        raise CadeError(f"method {method} gives no confidence; drop --confidence")
    write_match_outputs(wanted, dense=framed.dense, disparity=framed.disparity, valid=framed.valid,
                        confidence=framed.confidence, fill=fill, vis_range=vis_range)
    if "depth" in wanted:
        write_disparity(wanted["depth"], framed.depth)  # float32 TIFF, NaN where unknown
    if "points" in wanted:
        return write_ply(wanted["points"], framed.points, framed.colours)
    return None
