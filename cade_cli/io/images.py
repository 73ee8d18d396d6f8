"""Read images and pick the band to match on.

Everything comes back as float32: integer images scaled to [0, 1] by their dtype's
range, float TIFF data unchanged. Colour comes back in R, G, B(, A) order whatever the
decoder's habit. Any problem with a file is a :class:`CadeError` naming the file and
the fix; no decoder exception escapes and no decoder message is printed. A file whose
header announces more than :data:`~cade_cli.io.image_files.MAX_IMAGE_PIXELS` is refused before it is
decoded (:mod:`cade_cli.io.image_files`: the checks and the decoder).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tifffile

from cade_cli.errors import CadeError
from cade_cli.io.image_files import (
    MAX_IMAGE_SAMPLES, SUPPORTED_IMAGE_SUFFIXES, check_image_size, check_input_file, decode_with_cv2, decoder_messages,
    last_decoder_message, one_line_message,
)


TIFF_SUFFIXES: tuple[str, ...] = (".tif", ".tiff")

LUMINANCE_WEIGHTS: tuple[float, float, float] = (0.299, 0.587, 0.114)
"""Rec. 601 weights of R, G, B for the luminance of a colour image."""


_INTEGER_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}
_FLOAT_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


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
                raise CadeError(f"{path} is a TIFF file with no images in it{last_decoder_message(messages)}; re-export it")
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
                raise CadeError(f"{path} is a TIFF file with no images in it{last_decoder_message(messages)}; re-export it")
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


