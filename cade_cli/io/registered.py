"""Writing a registration (a :class:`~cade_cli.registration.Registration`, or anything with its
three bands: :class:`RegisteredBands`) as one multi-band TIFF, and its picture."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Protocol

import numpy as np
import tifffile

from cade_cli.io.atomic import atomic_output


class RegisteredBands(Protocol):
    """What this module reads of a registration: :class:`cade_cli.registration.Registration` has
    it (io is below the registration, so it names the three bands instead of importing it)."""

    reference: np.ndarray
    """(H, W) float32 reference band."""
    registered: np.ndarray
    """(H, W) float32 moving band in reference coordinates, NaN where unknown."""
    valid: np.ndarray
    """(H, W) bool, True where the registration is trusted."""


BAND_ORDER: tuple[str, ...] = ("reference", "registered", "valid")


def write_registration(path: Path, registration: RegisteredBands) -> None:
    """Write ``registration`` to ``path`` atomically as a planar float32 TIFF.

    Bands, in order: the reference band, the registered (moving) band (NaN where unknown
    with ``fill="none"``), and validity (1.0 = trusted correspondence, 0.0 = occluded,
    rejected or out of view). The band names are stored as JSON in the description.
    """
    stack = np.stack(
        [registration.reference, registration.registered, registration.valid.astype(np.float32)]
    ).astype(np.float32)
    with atomic_output(Path(path)) as temporary:
        tifffile.imwrite(
            temporary, stack, photometric="minisblack", planarconfig="separate",
            description=json.dumps({"bands": list(BAND_ORDER)}), metadata=None,
        )


REGISTRATION_VIS_MODES: tuple[str, ...] = ("overlay", "checker")
"""What ``register --vis`` draws: the two bands as a false-colour ``overlay`` (the default)
or a ``checker``board of their tiles."""
NO_REGISTRATION_TINT = (255, 120, 0)
"""BGR mixed into the pixels without a valid registration (blue): an overlay pixel always
has as much red as blue, so a tinted one never looks like one."""
_TINT_WEIGHT = 0.55


def registration_picture(registration: RegisteredBands, *, mode: str = "overlay") -> np.ndarray:
    """The picture a person judges a registration by, with a legend drawn under it.

    Each band is histogram-equalised over the validly registered pixels (bands through different
    filters differ in brightness; equalised, a scene's structure gets the same greys in
    both where their brightness rises and falls together). ``overlay``: reference in magenta (red + blue),
    registered in green, so aligned structure is grey, and a misregistered edge shows a
    magenta and a green fringe. ``checker``: tiles of the reference and the registered
    band alternate; where they are aligned, edges run on across tile borders. Pixels
    without a valid registration (``registration.valid`` False) show the reference tinted
    blue, a colour no aligned or misaligned pixel takes.

    Returns:
        (H + legend, max(W, 360), 3) uint8, B, G, R (:func:`cade_cli.io.pictures.with_legend`).

    Raises:
        CadeError: an unknown ``mode``.
    """
    from cade_cli.errors import CadeError
    from cade_cli.io.pictures import Swatch, with_legend

    valid = np.asarray(registration.valid, bool)
    both = valid & np.isfinite(registration.registered) & np.isfinite(registration.reference)
    trusted = both if both.any() else np.isfinite(registration.reference)  # one set of pixels for both bands
    reference = _stretched(registration.reference, trusted)
    registered = _stretched(registration.registered, trusted)
    if mode == "overlay":
        picture = np.stack([reference, registered, reference], axis=-1)
        lines = ["reference in magenta, registered in green (each band histogram-equalised): aligned structure is "
                 "grey, a misregistered edge has a magenta and a green fringe"]
        swatches = [Swatch((255, 0, 255), "brighter in reference"), Swatch((0, 255, 0), "brighter in registered"),
                    Swatch((128, 128, 128), "equal")]
    elif mode == "checker":
        height, width = reference.shape
        tile = max(8, round(min(height, width) / 12))
        rows, columns = np.indices((height, width))
        shown = np.where((rows // tile + columns // tile) % 2 == 0, reference, registered)
        picture = np.repeat(shown[..., None], 3, axis=-1)
        lines = [f"checkerboard of reference and registered tiles, {tile} px (each band histogram-equalised): where "
                 "aligned, edges run on across tile borders"]
        swatches = []
    else:
        raise CadeError(f"unknown --vis-mode {mode!r}; choose {' or '.join(REGISTRATION_VIS_MODES)}")
    tint = np.array(NO_REGISTRATION_TINT, np.float32)
    picture[~valid] = (1 - _TINT_WEIGHT) * reference[~valid][:, None] + _TINT_WEIGHT * tint
    mid_grey = (1 - _TINT_WEIGHT) * 128 + _TINT_WEIGHT * tint
    swatches.append(Swatch(tuple(int(round(c)) for c in mid_grey), "no valid registration (occluded, rejected, "
                           "out of view)"))
    return with_legend(np.rint(np.clip(picture, 0, 255)).astype(np.uint8), lines=lines, swatches=swatches)


def _stretched(band: np.ndarray, trusted: np.ndarray) -> np.ndarray:
    """``band`` mapped to [0, 255] float32 by its distribution over the ``trusted`` pixels
    (histogram equalisation: a value's share of trusted values at or below it), so two bands
    of one scene through different filters get the same spread of grey; non-finite pixels 0."""
    values = np.asarray(band, np.float32)
    known = np.sort(values[trusted & np.isfinite(values)])
    if known.size == 0:
        return np.zeros(values.shape, np.float32)
    finite = np.isfinite(values)
    out = np.zeros(values.shape, np.float32)
    below = np.searchsorted(known, values[finite], side="left")
    at_or_below = np.searchsorted(known, values[finite], side="right")
    out[finite] = (below + at_or_below) * (0.5 * 255.0 / known.size)  # mid-rank: ties share one grey
    return out


def write_registration_picture(path: Path, registration: RegisteredBands, *, mode: str = "overlay") -> None:
    """Write :func:`registration_picture` as a PNG at ``path``, all-or-nothing.

    Raises:
        CadeError: an unknown ``mode``, or an OS error while writing.
    """
    import cv2

    picture = registration_picture(registration, mode=mode)
    ok, encoded = cv2.imencode(".png", picture)
    if not ok:
        raise ValueError(f"OpenCV could not encode a picture of shape {picture.shape} as PNG")
    with atomic_output(Path(path)) as temporary:
        temporary.write_bytes(encoded.tobytes())
