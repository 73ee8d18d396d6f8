"""Image files before decoding, and decoding without noise: a file checked (exists, readable, a
file, a supported extension), its size read from the header and refused above
:data:`MAX_IMAGE_PIXELS` before it is decoded, bytes decoded by OpenCV with its messages
captured into the error instead of printed.
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

from cade_cli.errors import CadeError


SUPPORTED_IMAGE_SUFFIXES: tuple[str, ...] = (
    ".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".pnm", ".tif", ".tiff",
)
"""Extensions :func:`load_image` reads (compared case-insensitively)."""

MAX_IMAGE_PIXELS = 2**28
"""The largest image read, in pixels per band: 268 million (16384 x 16384). A file whose
header announces more is refused before it is decoded (a "decompression bomb" is a few
bytes that would unpack to gigabytes); crop or downscale larger images."""

MAX_IMAGE_SAMPLES = 4 * MAX_IMAGE_PIXELS
"""The largest number of values (pixels x bands) read from one TIFF file."""


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
        raise CadeError(f"cannot decode {path} as {path.suffix} image{last_decoder_message(messages)}; the file is corrupt or "
                        "truncated, re-export it")
    return image


def last_decoder_message(messages: list[str]) -> str:
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


def one_line_message(exc: BaseException) -> str:
    """An exception's message on one line (decoder messages often span several)."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__
