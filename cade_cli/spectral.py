"""The two CADE building blocks (Sippel et al., ICASSP 2024, METHOD.md sections 2-3).

- :func:`color_agnostic` removes absolute intensity and colour from a band, keeping
  only local structure. It runs on both views, in training and at inference.
- :func:`synthesize_bands` makes 11 single-channel "spectral bands" from one RGB
  image, so that ordinary RGB stereo data becomes cross-spectral training data.
"""

from __future__ import annotations

import cv2
import numpy as np

from cade_cli.errors import CadeError

BAND_NAMES: tuple[str, ...] = (
    "R", "G", "B", "BG", "BR", "GR", "BGR", "BnG", "GnR", "BuG", "GuR",
)
"""Names of the synthesized bands, in order. ``n`` stands for the paper's intersection
(∩, a scaled minimum) and ``u`` for its union (∪, a scaled maximum)."""

FLAT_TOLERANCE = 1e-6
"""A window counts as flat when its standard deviation is at most this fraction of the
image's dynamic range (max - min). Statistics are computed in float64 after removing
the image mean, so round-off leaves sigma around 1e-8 of the range on a constant
window; a single 16-bit step inside a 3x3 window gives about 5e-6. A threshold
relative to the range keeps the transform exactly invariant under x -> a*x + b."""


def color_agnostic(image: np.ndarray, *, window: int = 3, floor: float = 0.0) -> np.ndarray:
    """Color agnostic transform of one band (METHOD.md section 3).

    Steps: ``window`` x ``window`` median filter; local mean ``mu`` and population
    standard deviation ``sigma`` (divide by n, as the authors' reference code) over a
    ``window`` x ``window`` box; ``x_s = (x_f - mu) / sigma``;
    ``x_a = clip(0.5 + 0.5 * x_s, 0, 1)``; ``x_a = 0`` where the window is flat
    (see :data:`FLAT_TOLERANCE`). Borders are replicated, as in the authors' code.

    With ``floor`` > 0 (the ``cade-floor`` network input, not the paper's transform),
    ``sigma`` becomes ``sqrt(sigma^2 + floor^2)`` on the band scaled to a range of 1: a
    window whose contrast is far below ``floor`` (noise and 8-bit steps on a plain wall)
    stays near 0.5 instead of being stretched to full contrast, and no window is flat.
    Still invariant to ``a * image + b`` (the floor is relative to the band's range).

    Args:
        image: (H, W) array, any real dtype; intensity units do not matter because the
            result is invariant to ``a * image + b`` with ``a > 0``.
        window: odd window side in pixels, >= 3, used for the median and the statistics.
        floor: contrast floor, in units of the band's range (0: the paper's transform).

    Returns:
        (H, W) float32 array in [0, 1]. The input is not modified.
    """
    image = np.asarray(image)
    if image.ndim != 2:
        raise CadeError(f"color_agnostic expects one band of shape (H, W), got shape {image.shape}; pick a band first")
    if not isinstance(window, (int, np.integer)) or isinstance(window, bool) or window < 3 or window % 2 == 0:
        raise CadeError(f"window must be an odd integer >= 3, got {window}")
    if min(image.shape) < window:
        raise CadeError(f"image {image.shape[1]}x{image.shape[0]} is smaller than the {window}x{window} window")
    if not np.isfinite(image).all():
        raise CadeError("image contains NaN or infinite values; replace them before the transform")

    x = image.astype(np.float64)
    low, high = float(x.min()), float(x.max())
    dynamic_range = high - low
    if dynamic_range == 0.0:
        return np.zeros(image.shape, np.float32)
    # Centre and scale to [0, 1] first: the transform is invariant to this, and it
    # keeps the float32 median and the float64 statistics well-conditioned.
    x = (x - low) / dynamic_range

    filtered = median_filter(x.astype(np.float32), window).astype(np.float64)
    filtered -= filtered.mean()
    box = (window, window)
    mean = cv2.boxFilter(filtered, -1, box, normalize=True, borderType=cv2.BORDER_REPLICATE)
    mean_sq = cv2.boxFilter(filtered * filtered, -1, box, normalize=True, borderType=cv2.BORDER_REPLICATE)
    sigma = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))

    if floor > 0:
        sigma = np.sqrt(sigma * sigma + floor * floor)
    flat = sigma <= FLAT_TOLERANCE  # the image is already scaled to a range of 1
    standardized = (filtered - mean) / np.where(flat, 1.0, sigma)
    result = np.clip(0.5 + 0.5 * standardized, 0.0, 1.0)
    result[flat] = 0.0
    return result.astype(np.float32)


def median_filter(image: np.ndarray, window: int) -> np.ndarray:
    """``window`` x ``window`` median of a float32 (H, W) image with replicated borders.

    OpenCV's median handles float32 only for windows 3 and 5; larger windows fall back
    to a (slower) NumPy sliding-window median with the same border rule.
    """
    if window in (3, 5):
        return cv2.medianBlur(image, window)
    pad = window // 2
    padded = np.pad(image, pad, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, (window, window))
    return np.median(windows, axis=(-2, -1)).astype(np.float32)


def synthesize_bands(rgb: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Eleven synthetic spectral bands from one RGB image (METHOD.md section 2).

    Coefficients r0..r16 are drawn independently from Uniform(0, 1) on every call
    (sharing them between equations hurts, per the paper). A weighted mean whose
    weights sum to less than 1e-12 falls back to equal weights instead of dividing
    by (almost) zero.

    Args:
        rgb: (H, W, 3) float array in [0, 1], channels in R, G, B order (not OpenCV's BGR).
        rng: source of the random coefficients.

    Returns:
        dict mapping each name in :data:`BAND_NAMES` to an (H, W) float32 band in [0, 1].
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise CadeError(f"synthesize_bands expects an RGB image of shape (H, W, 3), got {rgb.shape}")
    red, green, blue = (rgb[..., channel].astype(np.float32) for channel in range(3))
    r = rng.uniform(0.0, 1.0, size=17)

    def weighted_mean(weights: np.ndarray, channels: tuple[np.ndarray, ...]) -> np.ndarray:
        total = float(weights.sum())
        if total < 1e-12:
            weights, total = np.ones_like(weights), float(len(weights))
        return sum(float(w) * c for w, c in zip(weights, channels)) / np.float32(total)

    bands = {
        "R": red,
        "G": green,
        "B": blue,
        "BG": weighted_mean(r[0:2], (blue, green)),
        "BR": weighted_mean(r[2:4], (blue, red)),
        "GR": weighted_mean(r[4:6], (green, red)),
        "BGR": weighted_mean(r[6:9], (blue, green, red)),
        "BnG": np.minimum(np.float32(r[9]) * blue, np.float32(r[10]) * green),
        "GnR": np.minimum(np.float32(r[11]) * green, np.float32(r[12]) * red),
        "BuG": np.maximum(np.float32(r[13]) * blue, np.float32(r[14]) * green),
        "GuR": np.maximum(np.float32(r[15]) * green, np.float32(r[16]) * red),
    }
    # float32 weighted means of saturated pixels can round to 1 + 1 ulp: keep [0, 1].
    return {name: np.clip(bands[name], 0.0, 1.0).astype(np.float32, copy=False) for name in BAND_NAMES}


NETWORK_INPUTS: tuple[str, ...] = ("cade", "normalised", "cade-floor")
"""What a network's card says its inputs are: the color agnostic transform of each band
(every shipped model), each band rescaled to [0, 1] by its own minimum and maximum (the
pristine and CSDL training modes of the training ablation, which see no transform), or
the color agnostic transform with a contrast floor (:data:`CONTRAST_FLOOR`; an Accuracy II
lever)."""
CONTRAST_FLOOR = 0.02
"""The ``cade-floor`` input's floor on the local standard deviation, in units of the band's
range: about 5 grey levels of a band spanning 255. Chosen a priori (8-bit steps and sensor
noise lie well below it, the texture the network matches mostly above it), not tuned."""


def normalised(image: np.ndarray) -> np.ndarray:
    """``image`` (H, W) rescaled to [0, 1] by its own minimum and maximum (float32; zeros
    where the image is constant). Invariant to ``a * image + b`` with ``a > 0`` globally,
    but unlike :func:`color_agnostic` not to a local or non-linear intensity change."""
    x = np.asarray(image, dtype=np.float64)
    if x.ndim != 2:
        raise CadeError(f"normalised expects one band of shape (H, W), got shape {x.shape}; pick a band first")
    low, high = float(x.min()), float(x.max())
    if high == low:
        return np.zeros(x.shape, np.float32)
    return ((x - low) / (high - low)).astype(np.float32)


def network_input(image: np.ndarray, kind: str = "cade") -> np.ndarray:
    """One band as a network of input ``kind`` (:data:`NETWORK_INPUTS`) takes it."""
    if kind == "cade":
        return color_agnostic(image)
    if kind == "normalised":
        return normalised(image)
    if kind == "cade-floor":
        return color_agnostic(image, floor=CONTRAST_FLOOR)
    raise CadeError(f"unknown network input {kind!r}; choose one of {', '.join(NETWORK_INPUTS)}")
