"""Read images and pick the band to match on.

Everything comes back as float32: integer images scaled to [0, 1] by their dtype's
range, float TIFF data unchanged. Colour comes back in R, G, B(, A) order whatever the
decoder's habit. Any problem with a file is a :class:`CadeError` naming the file and
the fix; no decoder exception escapes and no decoder message is printed. A file whose
header announces more than :data:`MAX_IMAGE_PIXELS` is refused before it is decoded.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import stat
import struct
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import tifffile

from cade_cli.errors import CadeError

SUPPORTED_IMAGE_SUFFIXES: tuple[str, ...] = (
    ".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".pnm", ".tif", ".tiff",
)
"""Extensions :func:`load_image` reads (compared case-insensitively)."""

TIFF_SUFFIXES: tuple[str, ...] = (".tif", ".tiff")

LUMINANCE_WEIGHTS: tuple[float, float, float] = (0.299, 0.587, 0.114)
"""Rec. 601 weights of R, G, B for the luminance of a colour image."""

MAX_IMAGE_PIXELS = 2**28
"""The largest image read, in pixels per band: 268 million (16384 x 16384). A file whose
header announces more is refused before it is decoded (a "decompression bomb" is a few
bytes that would unpack to gigabytes); crop or downscale larger images."""

MAX_IMAGE_SAMPLES = 4 * MAX_IMAGE_PIXELS
"""The largest number of values (pixels x bands) read from one TIFF file."""

_INTEGER_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}
_FLOAT_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


def check_input_file(path: Path, *, suffixes: tuple[str, ...]) -> Path:
    """Return ``Path(path)`` if it is an existing, non-empty file with one of ``suffixes``.

    Raises:
        CadeError: missing file, a directory, an unsupported extension, or 0 bytes.
    """
    path = Path(path)
    try:
        status = path.stat()
    except OSError as exc:
        raise _inaccessible(path, exc) from exc
    if stat.S_ISDIR(status.st_mode):
        raise CadeError(f"{path} is a directory, not a file; give the path of a file inside it")
    if not stat.S_ISREG(status.st_mode):
        raise CadeError(f"{path} is not a regular file (a device, pipe or socket); give an image file")
    if path.suffix.lower() not in suffixes:
        shown = path.suffix or "(none)"
        raise CadeError(f"{path} has unsupported extension {shown}; use one of {', '.join(suffixes)}")
    if status.st_size == 0:
        raise CadeError(f"{path} is empty (0 bytes); re-export or re-download it")
    return path


def _inaccessible(path: Path, error: OSError) -> CadeError:
    """The CadeError for a path that cannot be looked up (``stat`` failed with ``error``)."""
    if error.errno == errno.ELOOP:
        return CadeError(f"{path} is a symbolic link that loops back on itself; point it at the real file")
    if error.errno == errno.ENOENT and path.is_symlink():
        return CadeError(f"{path} is a broken symbolic link (to {os.readlink(path)}, which does not exist); "
                         "fix the link or give the file itself")
    if error.errno == errno.ENOENT:
        return CadeError(f"{path} does not exist; check the path")
    if error.errno == errno.ENOTDIR:
        return CadeError(f"{path} does not exist (part of the path is a file, not a folder); check the path")
    if error.errno in (errno.EACCES, errno.EPERM):
        return CadeError(f"cannot open {path}: permission denied; check the permissions of the file and its folders")
    return CadeError(f"cannot open {path}: {error.strerror or type(error).__name__}; check the path")


def check_image_size(path: Path, width: int, height: int) -> None:
    """Refuse, before decoding, an image whose header announces no pixels or too many.

    Raises:
        CadeError: ``width`` or ``height`` below 1, or more than :data:`MAX_IMAGE_PIXELS`.
    """
    if width < 1 or height < 1:
        raise CadeError(f"{path} announces an empty {width}x{height} image; the file is corrupt, re-export it")
    if width * height > MAX_IMAGE_PIXELS:
        raise CadeError(
            f"{path} is too large: {width}x{height} pixels ({width * height / 1e6:.0f} MP), over the limit of "
            f"{MAX_IMAGE_PIXELS / 1e6:.0f} MP (16384x16384); crop or downscale it"
        )


def header_size(raw: bytes) -> tuple[int, int] | None:
    """(width, height) announced by the header of PNG, JPEG, BMP or PNM bytes; None if not found.

    Only the header is read, so the size of a file is known before it is decoded.
    """
    if raw[:8] == b"\x89PNG\r\n\x1a\n" and raw[12:16] == b"IHDR" and len(raw) >= 24:
        width, height = struct.unpack(">II", raw[16:24])
        return width, height
    if raw[:2] == b"\xff\xd8":
        return _jpeg_size(raw)
    if raw[:2] == b"BM" and len(raw) >= 26:
        if struct.unpack("<I", raw[14:18])[0] == 12:  # the old OS/2 header: 16-bit sizes
            width, height = struct.unpack("<HH", raw[18:22])
        else:
            width, height = struct.unpack("<ii", raw[18:26])
        return abs(width), abs(height)  # a negative height means top-down rows
    if len(raw) >= 2 and raw[:1] == b"P" and raw[1:2] in (b"1", b"2", b"3", b"4", b"5", b"6"):
        tokens = re.sub(rb"#[^\n]*", b" ", raw[2:1024]).split()[:2]
        if len(tokens) == 2 and tokens[0].isdigit() and tokens[1].isdigit():
            return int(tokens[0]), int(tokens[1])
    return None


def _jpeg_size(raw: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's first start-of-frame segment."""
    position = 2
    while position + 4 <= len(raw):
        if raw[position] != 0xFF:
            return None
        marker = raw[position + 1]
        if marker == 0xFF:  # fill byte
            position += 1
            continue
        if marker in (0x01, 0xD8) or 0xD0 <= marker <= 0xD7:  # segments without a length
            position += 2
            continue
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # SOFn, not DHT/JPG/DAC
            if position + 9 > len(raw):
                return None
            height, width = struct.unpack(">HH", raw[position + 5 : position + 9])
            return width, height
        position += 2 + int.from_bytes(raw[position + 2 : position + 4], "big")
    return None


def read_bytes(path: Path) -> bytes:
    """The content of ``path``; an ``OSError`` (permissions, I/O) becomes :class:`CadeError`."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise CadeError(f"cannot read {path}: {exc.strerror or exc}; check its permissions") from exc


def decode_with_cv2(path: Path) -> np.ndarray:
    """Decode ``path`` with ``cv2.imdecode(IMREAD_UNCHANGED)``, as stored.

    Returns:
        (H, W) or (H, W, C) array of the file's dtype; colour in cv2's B, G, R(, A) order.

    Raises:
        CadeError: the file is corrupt, truncated, or not in the format its name says.
    """
    raw = read_bytes(path)
    size = header_size(raw)
    if size is not None:
        check_image_size(path, *size)
    buffer = np.frombuffer(raw, dtype=np.uint8)
    with decoder_messages() as messages:
        try:
            image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            if "CV_IO_MAX_IMAGE" in str(exc):  # OpenCV's own size limit, for a header we did not parse
                raise CadeError(f"{path} is too large for the image decoder; crop or downscale it") from exc
            raise CadeError(f"cannot decode {path}: {one_line_message(exc)}; the file is corrupt, re-export it") from exc
    if image is None:
        raise CadeError(f"cannot decode {path} as {path.suffix} image{_reason(messages)}; the file is corrupt or "
                        "truncated, re-export it")
    return image


def _reason(messages: list[str]) -> str:
    """`` (the decoder's last message)`` on one line, or nothing."""
    return f" ({' '.join(messages[-1].split())})" if messages else ""


class _Collect(logging.Handler):
    """A logging handler that keeps each record's message in a list."""

    def __init__(self, lines: list[str]) -> None:
        super().__init__()
        self.lines = lines

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@contextmanager
def decoder_messages() -> Iterator[list[str]]:
    """Collect what decoders print meanwhile, instead of letting it reach the terminal.

    OpenCV's decoders write their own errors and warnings straight to file descriptor 2
    (``libpng error: ...``), around any Python handling, and tifffile logs a warning for
    each damaged tag; a user would see them before our one-line message. Inside the
    block, descriptor 2 points to a temporary file and the ``tifffile`` logger to a list;
    the yielded list receives their lines (for the error message, or to drop). Anything
    else written to descriptor 2 meanwhile (another thread) lands there too.
    """
    lines: list[str] = []
    logger = logging.getLogger("tifffile")
    handler, propagate = _Collect(lines), logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        with _descriptor_2_captured(lines):
            yield lines
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate


@contextmanager
def _descriptor_2_captured(lines: list[str]) -> Iterator[None]:
    """Point file descriptor 2 at a temporary file; append what was written to ``lines``."""
    try:
        saved = os.dup(2)
    except OSError:  # no descriptor 2 at all: nothing would be printed
        yield
        return
    try:
        with tempfile.TemporaryFile() as sink:
            if sys.stderr is not None:
                sys.stderr.flush()
            os.dup2(sink.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
                sink.seek(0)
                lines.extend(line for line in sink.read().decode("utf-8", "replace").splitlines() if line.strip())
    finally:
        os.close(saved)


def load_image(path: Path) -> np.ndarray:
    """Read an image file as float32.

    PNG, JPEG, BMP and PPM/PGM/PNM (8 and 16 bit) are decoded by OpenCV; TIFF by
    tifffile (uint8, uint16, float32 or float64; one band, several samples per pixel
    interleaved or planar, or several pages, which become bands in file order).

    Returns:
        (H, W) or (H, W, C) float32. uint8 data is divided by 255 and uint16 by 65535,
        giving [0, 1]; float TIFF data is kept as stored (any range, NaN included).
        Colour is in R, G, B(, A) order.

    Raises:
        CadeError: missing, unsupported, unreadable, corrupt or empty file, or a TIFF
            sample type other than uint8, uint16, float32, float64.
    """
    return _load(path)[0]


def read_band(path: Path, band: int | None = None) -> tuple[np.ndarray, str | None]:
    """Read one band of an image file, for matching.

    Args:
        path: image file, see :func:`load_image`.
        band: 0-based band index, or None. None is fine for a single-band file, and for
            a colour image (RGB, or RGBA whose alpha is dropped), which is converted to
            Rec. 601 luminance ``0.299 R + 0.587 G + 0.114 B``. Any other multi-band
            file (2 bands, more than 4, several TIFF pages, non-RGB samples) needs one.

    Returns:
        ``(image, note)``: (H, W) float32 band scaled as in :func:`load_image`, and a
        one-line note for the user when a conversion happened (luminance), else None.
        The caller may append how to choose a band (e.g. its ``--left-band`` option).

    Raises:
        CadeError: every :func:`load_image` error; a band index out of range; a
            multi-band, non-colour file without a band index.
    """
    image, is_colour = _load(path)
    count = 1 if image.ndim == 2 else image.shape[2]
    if band is not None:
        return _select_band(image, band, count=count, path=path), None
    if count == 1:
        return image if image.ndim == 2 else image[:, :, 0], None
    if is_colour:
        return luminance(image), _luminance_note(path, count)
    raise CadeError(
        f"{path} has {count} bands and is not an RGB colour image; choose one by its 0-based index (0-{count - 1})"
    )


def _select_band(image: np.ndarray, band: int, *, count: int, path: Path) -> np.ndarray:
    """Band ``band`` of an (H, W) or (H, W, C) image, as a contiguous (H, W) array."""
    if not 0 <= band < count:
        noun = "band" if count == 1 else "bands"
        raise CadeError(f"band {band} is out of range: {path} has {count} {noun} (0-{count - 1})")
    return image if image.ndim == 2 else np.ascontiguousarray(image[:, :, band])


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 601 luminance ``0.299 R + 0.587 G + 0.114 B`` of (H, W, 3+) RGB(A); (H, W) float32."""
    # A weighted sum, not np.tensordot: BLAS would leave its threads busy-waiting on the
    # cores the matcher needs next (cade_cli.matching.learned.correlation).
    rgb = np.asarray(rgb)
    red, green, blue = (rgb[:, :, channel].astype(np.float32) for channel in range(3))
    weight_red, weight_green, weight_blue = (np.float32(weight) for weight in LUMINANCE_WEIGHTS)
    return weight_red * red + weight_green * green + weight_blue * blue


def _luminance_note(path: Path, count: int) -> str:
    layout = "RGB" if count == 3 else "RGBA, alpha ignored"
    return f"{path} has {count} bands ({layout}); converted to luminance (0.299 R + 0.587 G + 0.114 B)"


def _load(path: Path) -> tuple[np.ndarray, bool]:
    """(float32 image as :func:`load_image` returns it, whether its bands are R, G, B(, A))."""
    path = check_input_file(path, suffixes=SUPPORTED_IMAGE_SUFFIXES)
    if path.suffix.lower() in TIFF_SUFFIXES:
        image, is_colour = _load_tiff(path)
    else:
        image, is_colour = _load_with_cv2(path)
    if image.size == 0:
        raise CadeError(f"{path} holds an empty image (shape {image.shape}); re-export it")
    return _to_float32(image, path), is_colour


def _load_with_cv2(path: Path) -> tuple[np.ndarray, bool]:
    """Decode a non-TIFF file; convert cv2's BGR(A) to RGB(A)."""
    image = decode_with_cv2(path)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] in (3, 4):
        order = [2, 1, 0, 3][: image.shape[2]]
        return image[:, :, order], True
    return image, False


def _load_tiff(path: Path) -> tuple[np.ndarray, bool]:
    """Read a TIFF as (H, W) or (H, W, C), raw dtype, and whether it is RGB(A) colour."""
    try:
        with decoder_messages() as messages, tifffile.TiffFile(path) as tif:
            if not tif.series:
                raise CadeError(f"{path} is a TIFF file with no images in it{_reason(messages)}; re-export it")
            first = tif.series[0]
            same = [s for s in tif.series[1:] if s.shape == first.shape and s.dtype == first.dtype]
            _check_tiff_size(path, first, count=1 + len(same))
            data = first.asarray()
            axes = first.axes
            photometric = tif.pages[0].photometric
            extra = [s.asarray() for s in same]
    except CadeError:
        raise
    except Exception as exc:  # tifffile raises many types on corrupt files; none may escape
        raise CadeError(f"cannot read {path} as TIFF: {one_line_message(exc)}; the file is corrupt, re-export it") from exc
    if photometric == tifffile.PHOTOMETRIC.PALETTE:
        raise CadeError(f"{path} is an indexed-colour (palette) TIFF; convert it to greyscale or RGB first")
    if data.size == 0:
        return data, False
    stacks = [_to_bands_last(d, axes, path) for d in [data, *extra]]
    image = stacks[0] if len(stacks) == 1 else np.dstack(stacks)
    squeezed_axes = "".join(a for a, n in zip(axes, data.shape) if n != 1 or a in "YX")
    is_colour = (
        not extra
        and photometric == tifffile.PHOTOMETRIC.RGB
        and squeezed_axes.replace("Y", "").replace("X", "") == "S"
        and image.ndim == 3
        and image.shape[2] in (3, 4)
    )
    return image, is_colour


def read_tiff_array(path: Path) -> np.ndarray:
    """The first image of a TIFF file, as stored (dtype and shape), size-checked first.

    Raises:
        CadeError: a file that is not a readable TIFF, has no image, or holds more than
            :data:`MAX_IMAGE_PIXELS` pixels or :data:`MAX_IMAGE_SAMPLES` values.
    """
    try:
        with decoder_messages() as messages, tifffile.TiffFile(path) as tif:
            if not tif.series:
                raise CadeError(f"{path} is a TIFF file with no images in it{_reason(messages)}; re-export it")
            _check_tiff_size(path, tif.series[0], count=1)
            return tif.series[0].asarray()
    except CadeError:
        raise
    except Exception as exc:  # tifffile raises many types on corrupt files; none may escape
        raise CadeError(f"cannot read {path} as TIFF: {one_line_message(exc)}; the file is corrupt, re-export it") from exc


def _check_tiff_size(path: Path, series: tifffile.TiffPageSeries, *, count: int) -> None:
    """Refuse ``count`` series like ``series`` whose size exceeds the limits, before reading them."""
    shape = dict(zip(series.axes, series.shape))
    if "X" in shape and "Y" in shape:
        check_image_size(path, shape["X"], shape["Y"])
    samples = count * int(np.prod(series.shape, dtype=np.float64))
    if samples > MAX_IMAGE_SAMPLES:
        raise CadeError(f"{path} is too large: {samples / 1e6:.0f} million values, over the limit of "
                        f"{MAX_IMAGE_SAMPLES / 1e6:.0f} million; crop it or keep fewer bands")


def _to_bands_last(data: np.ndarray, axes: str, path: Path) -> np.ndarray:
    """Reorder a tifffile series to (H, W) or (H, W, C); every non-Y/X axis becomes bands.

    Planar (``SYX``, ``CYX``), page stacks (``IYX``, ``QYX``, ``ZYX``...) and interleaved
    (``YXS``) layouts all end as bands-last; several non-spatial axes are flattened in
    file order.
    """
    if "Y" not in axes or "X" not in axes or len(axes) != data.ndim:
        raise CadeError(f"{path} has an unsupported TIFF layout (axes {axes!r}); save it as one image per file")
    others = [i for i, a in enumerate(axes) if a not in "YX"]
    moved = np.transpose(data, (axes.index("Y"), axes.index("X"), *others))
    height, width = moved.shape[:2]
    bands = int(np.prod(moved.shape[2:], dtype=np.int64))
    return moved.reshape(height, width) if bands == 1 else moved.reshape(height, width, bands)


def _to_float32(image: np.ndarray, path: Path) -> np.ndarray:
    """Integers scaled to [0, 1] by dtype range; float32/float64 kept as values."""
    if image.dtype in _INTEGER_SCALE:
        return image.astype(np.float32) / np.float32(_INTEGER_SCALE[image.dtype])
    if image.dtype in _FLOAT_DTYPES:
        return image.astype(np.float32)
    raise CadeError(
        f"{path} stores {image.dtype} samples; convert it to 8-bit, 16-bit or float32 (e.g. 16-bit PNG or float32 TIFF)"
    )


def one_line_message(exc: BaseException) -> str:
    """An exception's message on one line (decoder messages often span several)."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__
