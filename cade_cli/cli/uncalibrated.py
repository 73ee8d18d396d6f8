"""The route of a pair without a calibration: ``cade rectify --uncalibrated`` and ``--fix-vertical``
without ``--rig`` on ``disparity`` and ``register`` (the warp estimated from feature matches,
:mod:`cade_cli.rigs.uncalibrated`), and the small JSON beside the outputs that says what was done.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cade_cli.cli.options import check_output, print_note

WARP_SUFFIX = ".rectification.json"
"""The file beside an output that records the warp: ``OUTPUT`` + this suffix."""


def warp_record_path(output: Path) -> Path:
    """Where the warp of ``output`` is recorded: beside it, ``OUTPUT.rectification.json``."""
    return output.with_name(output.name + WARP_SUFFIX)


def check_warp_record(output: Path, inputs: tuple[Path, ...]) -> Path:
    """The warp record's path for ``output``, checked writable before any work."""
    path = warp_record_path(output)
    check_output(path, suffixes=(".json",), inputs=inputs)
    return path


def estimate_warp(left_image: np.ndarray, right_image: np.ndarray):
    """The :class:`~cade_cli.rigs.uncalibrated.PairRectification` of a pair (luminance of
    colour images), announced as a note; one-line :class:`CadeError` when the matches cannot support one."""
    from cade_cli.errors import CadeError
    from cade_cli.rigs.outputs import luminance_of
    from cade_cli.rigs.uncalibrated import estimate_pair_rectification

    if left_image.shape[:2] != right_image.shape[:2]:
        raise CadeError(f"the pair's images differ in size ({left_image.shape[1]}x{left_image.shape[0]} and "
                        f"{right_image.shape[1]}x{right_image.shape[0]}); uncalibrated rectification needs one size")
    found = estimate_pair_rectification(luminance_of(left_image), luminance_of(right_image))
    print_note(found.describe())
    return found


def fix_vertical_alone(output: Path, inputs: tuple[Path, ...], left_image: np.ndarray, right_image: np.ndarray):
    """``--fix-vertical`` without a rig (``cade disparity``, ``cade register``): the warp record's path
    for ``output``, checked writable, the warp estimated from the pair alone, and the pair rectified
    by it: returns (warp, record path, left image, right image)."""
    record = check_warp_record(output, inputs)
    found = estimate_warp(left_image, right_image)
    left_image, right_image = found.rectify(left_image, right_image)
    return found, record, left_image, right_image


def write_warp_record(path: Path, found, **extra) -> None:
    """Write the warp (:meth:`PairRectification.record`) and ``extra`` fields as JSON to ``path`` itself."""
    path.write_text(json.dumps({**found.record(), **extra}, indent=1) + "\n")


def registration_in_original_frame(found, result, reference: np.ndarray):
    """A registration done on the rectified pair, in the reference band's own view: the registered
    band, its validity and disparity resampled onto the original reference (the identity warp of
    the vertical model leaves them as they are); ``reference`` is that original band."""
    from dataclasses import replace

    registered, validity, disparity = found.to_original(result.registered, result.valid.astype(np.float32),
                                                       result.disparity)
    valid = np.nan_to_num(validity, nan=0.0) >= 0.999  # a pixel next to an invalid one is not trusted
    return replace(result, reference=np.asarray(reference, np.float32), registered=registered, valid=valid,
                   disparity=disparity)


def rectify_uncalibrated(left: Path, right: Path, output: tuple[Path, Path], epipolar: Path | None) -> None:
    """``cade rectify --uncalibrated LEFT RIGHT -o L R``: estimate the warp, write both rectified
    images, the epipolar picture if asked and ``L.rectification.json``, all or none."""
    import cv2

    from cade_cli.errors import CadeError
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.images import load_image
    from cade_cli.rigs.outputs import RECTIFIED_IMAGE_SUFFIXES, epipolar_picture, write_rectified_image

    for path in output:
        check_output(path, suffixes=RECTIFIED_IMAGE_SUFFIXES, inputs=(left, right))
    if output[0].resolve() == output[1].resolve():
        raise CadeError(f"-o names {output[0]} twice; give the rectified left and right images different names")
    if epipolar is not None:
        check_output(epipolar, suffixes=(".png",), inputs=(left, right))
    record = check_warp_record(output[0], (left, right))
    left_image, right_image = load_image(left), load_image(right)
    found = estimate_warp(left_image, right_image)
    left_rect, right_rect = found.rectify(left_image, right_image)
    with atomic_outputs([*output, epipolar, record]) as staged:
        write_rectified_image(staged[output[0]], left_rect)
        write_rectified_image(staged[output[1]], right_rect)
        if epipolar is not None:
            cv2.imwrite(str(staged[epipolar]), epipolar_picture(left_rect, right_rect))
        write_warp_record(staged[record], found, left=str(left), right=str(right))
    width, height = found.size
    print(f"{output[0]}, {output[1]}: {width}x{height}, uncalibrated {found.model} rectification, residual "
          f"{found.residual:.2f} px; the warp in {record}")
