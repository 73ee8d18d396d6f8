"""Read and write disparity maps and validity masks (their pictures, and the writer of a
match's files: :mod:`cade_cli.io.match_outputs`).

In memory a disparity map is an (H, W) float32 array in pixels of its image, with NaN
marking invalid pixels. On disk each format uses its own marker (STYLE.md habit 7):

- ``.pfm``: float32, little-endian, rows bottom-to-top, ``inf`` = invalid.
- ``.tif`` / ``.tiff``: float32, NaN = invalid.
- ``.png``: uint16 ``round(d * 256)``, 0 = invalid (KITTI); only 0 <= d < 256.
- ``.npy``: float32, NaN = invalid.

A validity mask (:func:`write_validity`) is a separate file: PNG (uint8, 255 = valid,
0 = rejected) or TIFF (uint8, 1 / 0).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import tifffile

from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_output, intended_path
from cade_cli.io.images import read_tiff_array
from cade_cli.io.image_files import (
    MAX_IMAGE_SAMPLES, check_image_size, check_input_file, decode_with_cv2, one_line_message, read_bytes,
)

DISPARITY_SUFFIXES: tuple[str, ...] = (".pfm", ".tif", ".tiff", ".png", ".npy")
"""Extensions :func:`read_disparity` and :func:`write_disparity` handle (any case)."""

PNG_DISPARITY_SCALE = 256.0
"""16-bit PNG stores ``round(d * 256)`` (KITTI), so d in [0, 256) at 1/256 px steps."""

PNG_DISPARITY_LIMIT = 65536 / PNG_DISPARITY_SCALE
"""Disparities a 16-bit PNG holds lie in [0, this) px: 256."""

_PFM_HEADER_LIMIT = 256
"""Bytes searched for the three PFM header lines; longer headers are malformed."""


def write_disparity(path: Path, disparity: np.ndarray) -> None:
    """Write an (H, W) disparity map, the format chosen by ``path``'s extension.

    Written all-or-nothing through :func:`cade_cli.io.atomic.atomic_output`. NaN and
    ``±inf`` both count as invalid and are stored as the format's marker (the caller's
    array is not modified). In a PNG a valid value that would round to 0 (d < 1/512)
    is stored as 1 (d = 1/256) so that it stays valid, and values in
    [65535.5 / 256, 256) are stored as 65535.

    Args:
        path: output file ending in one of :data:`DISPARITY_SUFFIXES`.
        disparity: (H, W) real array, pixels, NaN = invalid.

    Raises:
        CadeError: unsupported extension, not 2-D, PNG with valid values outside
            [0, 256), missing output directory, or an OS error while writing.
    """
    path = Path(path)
    suffix = _disparity_suffix(path)
    values = as_disparity(disparity)
    if suffix == ".pfm":
        payload = np.where(np.isnan(values), np.float32(np.inf), values)
        write_atomically(path, lambda tmp: write_pfm(tmp, payload))
    elif suffix in (".tif", ".tiff"):
        write_atomically(path, lambda tmp: tifffile.imwrite(tmp, values, photometric="minisblack"))
    elif suffix == ".png":
        encoded = _encode_png_disparity(values, path)
        write_atomically(path, lambda tmp: write_png(tmp, encoded))
    elif suffix == ".npy":
        write_atomically(path, lambda tmp: _write_npy(tmp, values))
    else:
        raise AssertionError(f"unhandled disparity suffix {suffix}")


def check_disparity_range(path: Path, low: float, high: float) -> None:
    """Refuse, before any matching, an output that cannot hold disparities in [low, high] px.

    Only a 16-bit PNG is limited (0 <= d < :data:`PNG_DISPARITY_LIMIT`); a search range
    that reaches past it could give disparities the PNG cannot store, found only after
    the match. The other formats hold any float.

    Raises:
        CadeError: naming ``path``, the range and the fix (another format, or a smaller range).
    """
    path = Path(path)
    if path.suffix.lower() != ".png" or (low >= 0 and high < PNG_DISPARITY_LIMIT):
        return
    fix = "a --max-disp below 256" if low >= 0 else "a --min-disp of 0 or more"
    raise CadeError(
        f"{intended_path(path)} is a 16-bit PNG, which holds disparities 0 <= d < 256, but the search range is "
        f"[{low:g}, {high:g}] px; write a .pfm, .tif or .npy file instead, or give {fix}"
    )


def read_disparity(path: Path) -> np.ndarray:
    """Read a disparity map written by :func:`write_disparity` (or by a dataset).

    PFM ``inf`` (any non-finite), PNG 0 and TIFF/NPY NaN become NaN; PNG is uint16 / 256.

    Returns:
        (H, W) float32 disparity in pixels, NaN = invalid.

    Raises:
        CadeError: missing, unsupported, corrupt file, or content that is not one
            band of disparities (e.g. a 3-channel PFM or an 8-bit PNG).
    """
    path = check_input_file(path, suffixes=DISPARITY_SUFFIXES)
    suffix = path.suffix.lower()
    if suffix == ".pfm":
        values = read_pfm(path)
    elif suffix in (".tif", ".tiff"):
        values = _read_tiff_disparity(path)
    elif suffix == ".png":
        return _read_png_disparity(path)
    elif suffix == ".npy":
        values = _read_npy_disparity(path)
    else:
        raise AssertionError(f"unhandled disparity suffix {suffix}")
    if values.ndim != 2:
        raise CadeError(f"{path} holds an array of shape {values.shape}, not one (H, W) disparity map; save one band")
    return np.where(np.isfinite(values), values, np.float32(np.nan)).astype(np.float32)


def read_pfm(path: Path) -> np.ndarray:
    """Read a PFM file as stored: ``Pf`` -> (H, W), ``PF`` -> (H, W, 3) float32.

    Either byte order (negative scale = little-endian); rows are flipped from the
    file's bottom-to-top order to top-to-bottom. ``inf`` and NaN are kept as stored.

    Raises:
        CadeError: malformed header, or fewer data bytes than the header announces.
    """
    path = check_input_file(path, suffixes=(".pfm",))
    raw = read_bytes(path)
    channels, width, height, little_endian, start = _parse_pfm_header(raw, path)
    check_image_size(path, width, height)
    count = width * height * channels
    if len(raw) - start < 4 * count:
        raise CadeError(
            f"{path} is truncated: header announces {width}x{height}x{channels} floats "
            f"({4 * count} bytes) but {len(raw) - start} bytes follow; re-export it"
        )
    dtype = np.dtype("<f4" if little_endian else ">f4")
    data = np.frombuffer(raw, dtype=dtype, count=count, offset=start)
    shape = (height, width) if channels == 1 else (height, width, 3)
    return np.ascontiguousarray(data.reshape(shape)[::-1], dtype=np.float32)


def write_pfm(path: Path, array: np.ndarray) -> None:
    """Write (H, W) or (H, W, 3) values as PFM, non-atomically, values as given.

    Little-endian float32, scale -1.0, rows bottom-to-top (the PFM convention); no
    NaN/inf translation. :func:`write_disparity` is the safe entry point.
    """
    array = np.asarray(array)
    if array.ndim == 2:
        kind = "Pf"
    elif array.ndim == 3 and array.shape[2] == 3:
        kind = "PF"
    else:
        raise CadeError(f"PFM holds (H, W) or (H, W, 3) arrays, got shape {array.shape}")
    height, width = array.shape[:2]
    with open(path, "wb") as stream:
        stream.write(f"{kind}\n{width} {height}\n-1.0\n".encode("ascii"))
        stream.write(np.ascontiguousarray(array[::-1], dtype="<f4").tobytes())


VALIDITY_SUFFIXES: tuple[str, ...] = (".png", ".tif", ".tiff")
"""Extensions :func:`write_validity` and :func:`read_validity` handle (any case)."""


def write_validity(path: Path, valid: np.ndarray) -> None:
    """Write an (H, W) bool validity mask, all-or-nothing: PNG 255 / 0, TIFF uint8 1 / 0.

    Raises:
        CadeError: unsupported extension, not 2-D, or an OS error while writing.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    mask = np.asarray(valid, bool)
    if mask.ndim != 2:
        raise CadeError(f"a validity mask must have shape (H, W), got shape {mask.shape}")
    if suffix == ".png":
        write_atomically(path, lambda tmp: write_png(tmp, mask.astype(np.uint8) * np.uint8(255)))
    elif suffix in (".tif", ".tiff"):
        write_atomically(path, lambda tmp: tifffile.imwrite(tmp, mask.astype(np.uint8), photometric="minisblack"))
    else:
        raise CadeError(f"cannot write validity to {intended_path(path)}: unsupported extension {path.suffix or '(none)'}; "
                        f"use one of {', '.join(VALIDITY_SUFFIXES)}")


def read_validity(path: Path) -> np.ndarray:
    """Read a mask written by :func:`write_validity`: (H, W) bool, True where non-zero.

    Raises:
        CadeError: missing or unreadable file, unsupported extension, not one band.
    """
    path = check_input_file(Path(path), suffixes=VALIDITY_SUFFIXES)
    mask = decode_with_cv2(path) if path.suffix.lower() == ".png" else read_tiff_array(path)
    if mask.ndim != 2:
        raise CadeError(f"{path} has shape {mask.shape}; a validity mask is one band (255/1 = valid, 0 = rejected)")
    return mask != 0


def _disparity_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in DISPARITY_SUFFIXES:
        shown = path.suffix or "(none)"
        raise CadeError(
            f"cannot write disparity to {intended_path(path)}: unsupported extension {shown}; use one of {', '.join(DISPARITY_SUFFIXES)}"
        )
    return suffix


def as_disparity(disparity: np.ndarray) -> np.ndarray:
    """A float32 (H, W) copy with every non-finite value set to NaN."""
    array = np.asarray(disparity)
    if array.ndim != 2:
        raise CadeError(f"a disparity map must have shape (H, W), got shape {array.shape}; pass one band")
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise CadeError(f"a disparity map must hold real numbers, got dtype {array.dtype}")
    values = array.astype(np.float32)  # always a copy: the caller's array is never touched
    values[~np.isfinite(values)] = np.nan
    return values


def _encode_png_disparity(values: np.ndarray, path: Path) -> np.ndarray:
    """(H, W) uint16 ``round(d * 256)``, 0 where NaN; refuse d outside [0, 256)."""
    valid = ~np.isnan(values)
    if valid.any():
        low, high = float(values[valid].min()), float(values[valid].max())
        if low < 0 or high >= PNG_DISPARITY_LIMIT:
            raise CadeError(
                f"disparities in [{low:.3f}, {high:.3f}] do not fit a 16-bit PNG ({intended_path(path)}), which holds "
                "0 <= d < 256; save as .pfm, .tif or .npy instead"
            )
    encoded = np.zeros(values.shape, dtype=np.uint16)
    encoded[valid] = np.clip(np.rint(values[valid] * PNG_DISPARITY_SCALE), 1, 65535).astype(np.uint16)
    return encoded


def _read_png_disparity(path: Path) -> np.ndarray:
    encoded = decode_with_cv2(path)
    if encoded.dtype != np.uint16 or encoded.ndim != 2:
        channels = 1 if encoded.ndim == 2 else encoded.shape[2]
        raise CadeError(
            f"{path} is a {encoded.dtype} PNG with {channels} channel(s); disparity PNGs are 16-bit greyscale "
            "(d = value / 256, 0 = invalid); convert it or use .pfm"
        )
    disparity = encoded.astype(np.float32) / np.float32(PNG_DISPARITY_SCALE)
    disparity[encoded == 0] = np.nan
    return disparity


def _read_tiff_disparity(path: Path) -> np.ndarray:
    values = read_tiff_array(path)
    if not np.issubdtype(values.dtype, np.floating):
        raise CadeError(f"{path} stores {values.dtype} values; a disparity TIFF must be float32 (pixels, NaN = invalid)")
    return values.astype(np.float32)


def _read_npy_disparity(path: Path) -> np.ndarray:
    _check_npy_header(path)
    try:
        values = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises several types on corrupt files; none may escape
        raise CadeError(f"cannot read {path} as .npy: {one_line_message(exc)}; re-save it with numpy.save") from exc
    if not isinstance(values, np.ndarray) or not (
        np.issubdtype(values.dtype, np.floating) or np.issubdtype(values.dtype, np.integer)
    ):
        raise CadeError(f"{path} does not hold a numeric array; save a float32 (H, W) array with numpy.save")
    return values.astype(np.float32)


def _check_npy_header(path: Path) -> None:
    """Refuse, from its header alone, a .npy file that is not a numeric array of a readable size."""
    not_numeric = f"{path} does not hold a numeric array; save a float32 (H, W) array with numpy.save"
    try:
        with open(path, "rb") as stream:
            version = np.lib.format.read_magic(stream)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
            else:  # 3.0 only adds non-Latin-1 field names: a structured array, not a map
                raise CadeError(not_numeric)
    except CadeError:
        raise
    except Exception as exc:  # numpy raises several types on a malformed header; none may escape
        raise CadeError(f"cannot read {path} as .npy: {one_line_message(exc)}; re-save it with numpy.save") from exc
    if dtype.kind not in "biuf":
        raise CadeError(not_numeric)
    if len(shape) == 2:
        check_image_size(path, shape[1], shape[0])
    elif float(np.prod(shape, dtype=np.float64)) > MAX_IMAGE_SAMPLES:
        raise CadeError(f"{path} holds an array of shape {shape}, too large to be a disparity map; save one (H, W) band")


def _parse_pfm_header(raw: bytes, path: Path) -> tuple[int, int, int, bool, int]:
    """(channels, width, height, little_endian, data offset) from a PFM file's bytes.

    The header is four whitespace-separated tokens (``Pf``/``PF``, width, height, scale)
    followed by one whitespace character (``\\r\\n`` accepted).
    """
    tokens, end = _leading_tokens(raw[:_PFM_HEADER_LIMIT], count=4)
    bad = f"{path} is not a valid PFM file (expected header 'Pf' or 'PF', 'W H', scale); re-export it"
    if len(tokens) < 4 or tokens[0] not in (b"Pf", b"PF"):
        raise CadeError(bad)
    try:
        width, height, scale = int(tokens[1]), int(tokens[2]), float(tokens[3])
    except ValueError as exc:
        raise CadeError(bad) from exc
    if width <= 0 or height <= 0 or scale == 0.0 or not np.isfinite(scale):
        raise CadeError(bad)
    if raw[end : end + 2] == b"\r\n":
        end += 1
    channels = 1 if tokens[0] == b"Pf" else 3
    return channels, width, height, scale < 0, end + 1


def _leading_tokens(text: bytes, *, count: int) -> tuple[list[bytes], int]:
    """The first ``count`` whitespace-separated tokens of ``text`` and the index just after the last."""
    tokens: list[bytes] = []
    position = 0
    while len(tokens) < count:
        while position < len(text) and text[position : position + 1].isspace():
            position += 1
        start = position
        while position < len(text) and not text[position : position + 1].isspace():
            position += 1
        if start == position or position == len(text):
            break  # no token, or a token running into the end of the searched bytes
        tokens.append(text[start:position])
    return tokens, position


def write_png(path: Path, image: np.ndarray) -> None:
    """Encode ``image`` (uint8/uint16, grey or BGR) as PNG into ``path``."""
    ok, buffer = cv2.imencode(".png", image)
    if not ok:
        raise CadeError(f"OpenCV could not encode a {image.dtype} image of shape {image.shape} as PNG")
    Path(path).write_bytes(buffer.tobytes())


def _write_npy(path: Path, values: np.ndarray) -> None:
    with open(path, "wb") as stream:
        np.save(stream, values, allow_pickle=False)


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """Run ``write(temporary)`` inside :func:`atomic_output` (which turns OS errors into CadeError)."""
    with atomic_output(path) as temporary:
        write(temporary)


