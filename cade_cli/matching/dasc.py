"""DASC: dense adaptive self-correlation descriptor and its matching cost.

Kim, Min, Ham, Ryu, Do & Sohn, "DASC: Dense Adaptive Self-Correlation Descriptor for
Multi-modal and Multi-spectral Correspondence", CVPR 2015 (journal version: "DASC:
Robust Dense Descriptor for Multi-modal and Multi-spectral Correspondence Estimation",
TPAMI 2017). A pixel is described by how its support window correlates with itself:
for each of K patch pairs (x + p_l, x + q_l) sampled in the window, the correlation
C_l(x) of the two 5x5 patches, weighted by an edge-aware kernel centred at x + p_l,
gives one entry ``exp(-(1 - C_l(x)) / sigma)``; the K entries are L2-normalised. Being
built from correlations of one image with itself, the descriptor does not change under
a gain and offset of the band, and it is largely unchanged by the nonlinear intensity
mappings between spectral bands that keep the local structure.

The adaptive correlation (the paper's eq. 3) is evaluated for all pixels at once with
the guided filter (He, Sun & Tang, ECCV 2010) of guide I as the edge-aware weighting,
the paper's constant-time variant ("DASC with GF" in the authors' code): with the
weighted means E[.] = GF_I(.) over the patch at x + p_l and J = I shifted by q_l - p_l,

    C_l(x + p_l) = (E[IJ] - E[I] E[J]) / sqrt((E[II] - E[I]^2) (E[JJ] - E[J]^2)).

Parameters and where they come from:

- patch 5x5 (guided-filter radius 2), epsilon 0.09, sigma 0.5, support window 31x31
  (offsets within +-15 px), K = 128 pairs, and the 7x7 Gaussian pre-blur (sigma 1 px)
  of an image in [0, 1]: the authors' MATLAB demo (``M_half = 15``, ``N_half = 2``,
  ``epsil = 0.09``, ``downSize = 1``, images ``/255`` and blurred by
  ``fspecial('gaussian', 7, 1)``) and the C++ ports of their MEX code (LITIV's
  ``features2d/DASC``, OpenCV contrib's port), which use ``exp(-(1 - C) / 0.5)``,
  128 dimensions and an L2 normalisation.
- The sampling pattern: the paper learns it on Middlebury (randomized receptive-field
  pooling with a discriminative criterion) and the authors ship it as
  ``rp1/rp2_Middlebury.mat``; that learned table is not reproduced here. Instead
  :data:`DASC_PATTERN` is a fixed seeded random pattern (:func:`dasc_sampling_pattern`,
  ``numpy.random.default_rng(2015)``): both points uniform over the 31x31 window, the
  two points of a pair distinct, no pair repeated. The ``dasc-sgm`` matcher uses a
  smaller 15x15 window (:data:`DASC_STEREO_PATTERN`, same seed and count).
- Intensity scale: epsilon is in the units of a [0, 1] image, so each band is first
  stretched over its own min..max to [0, 1] (for 8-bit images that is about the
  authors' ``/255``); this makes the descriptor exactly invariant to ``a * band + b``
  with a > 0.
- Where either weighted patch variance is below :data:`FLAT_VARIANCE` (a flat patch:
  no correlation is defined) the entry is 1, as in the C++ ports; correlations are
  clipped to [-1, 1] (the guided filter's weights can be slightly negative).
- Borders are replicated (the ports put zeros or leave entries at 0 outside the image).

:func:`~cade_cli.matching.reference.dasc_descriptor_reference` computes the same
descriptor pixel by pixel from the guided filter's explicit kernel weights.
"""

from __future__ import annotations

import cv2
import numpy as np

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.cost import CostVolume

SUPPORT_RADIUS = 15
"""Half side of the 31x31 support window the pattern's points lie in (authors' ``M_half``)."""
PATCH_RADIUS = 2
"""Half side of the 5x5 patches, the guided filter's radius (authors' ``N_half``)."""
EPSILON = 0.09
"""The guided filter's regulariser, in squared units of a [0, 1] image (authors' ``epsil``)."""
SIGMA = 0.5
"""Scale of ``exp(-(1 - C) / sigma)`` (the authors' code)."""
BLUR_SIGMA = 1.0
"""Pre-blur: 7x7 Gaussian, sigma 1 px (the authors' code)."""
FLAT_VARIANCE = 1e-6
"""A weighted patch variance below this (std 0.001 of the band's range) counts as flat."""
PATTERN_SEED = 2015


def dasc_sampling_pattern(count: int, *, radius: int = SUPPORT_RADIUS, rng: np.random.Generator) -> np.ndarray:
    """A random pattern of ``count`` distinct patch pairs in a (2 radius + 1)^2 window.

    Returns:
        (count, 4) int64 rows ``(py, px, qy, qx)``: the offsets (rows, columns, px) of the
        two patch centres from the described pixel, each uniform in [-radius, radius],
        p != q, no pair repeated (in either order).
    """
    if count < 1 or radius < 1:
        raise ValueError(f"a pattern needs count >= 1 and radius >= 1, got {count} and {radius}")
    side = 2 * radius + 1
    if count > side * side * (side * side - 1) // 2:
        raise ValueError(f"a {side}x{side} window has fewer than {count} distinct pairs")
    pairs: list[tuple[int, int, int, int]] = []
    seen: set[tuple[int, int, int, int]] = set()
    while len(pairs) < count:
        py, px, qy, qx = (int(v) for v in rng.integers(-radius, radius + 1, size=4))
        if (py, px) == (qy, qx) or (py, px, qy, qx) in seen:
            continue
        seen.update({(py, px, qy, qx), (qy, qx, py, px)})
        pairs.append((py, px, qy, qx))
    return np.array(pairs, np.int64)


DASC_PATTERN = dasc_sampling_pattern(128, rng=np.random.default_rng(PATTERN_SEED))
"""The default pattern: 128 pairs in the published 31x31 window (see the module docstring)."""

STEREO_SUPPORT_RADIUS = 7
DASC_STEREO_PATTERN = dasc_sampling_pattern(128, radius=STEREO_SUPPORT_RADIUS, rng=np.random.default_rng(PATTERN_SEED))
"""The pattern of the ``dasc-sgm`` matcher: 128 pairs in a 15x15 window, same seed. A
deviation from the paper's 31x31: under SGM the large window fattens depth edges and
blurs slanted surfaces (mean error 0.54 px against 0.30 px on the rendered 80x120
slanted-plane pair of tests/test_matchers.py) and it was less accurate on the train-real
scenes too (cs protocol, 4 scenes: EPE 4.59 against 4.24 px)."""


def dasc_prepare(image: np.ndarray, *, blur_sigma: float = BLUR_SIGMA) -> np.ndarray:
    """The band the descriptor reads: stretched over its own min..max to [0, 1] (a
    constant band becomes 0), then blurred by a 7x7 Gaussian of ``blur_sigma`` px
    (0: no blur), borders replicated. Returns (H, W) float32."""
    band = np.asarray(image, np.float64)
    low, high = float(band.min()), float(band.max())
    scale = 1.0 / (high - low) if high > low else 0.0
    stretched = ((band - low) * scale).astype(np.float32)
    if blur_sigma <= 0:
        return stretched
    return cv2.GaussianBlur(stretched, (7, 7), blur_sigma, borderType=cv2.BORDER_REPLICATE)


def dasc_descriptor(
    image: np.ndarray,
    *,
    pattern: np.ndarray = DASC_PATTERN,
    patch_radius: int = PATCH_RADIUS,
    epsilon: float = EPSILON,
    sigma: float = SIGMA,
    blur_sigma: float = BLUR_SIGMA,
) -> np.ndarray:
    """Dense DASC descriptor of every pixel (see the module docstring).

    Args:
        image: (H, W) band, any intensity units (stretched to [0, 1] first).
        pattern: (K, 4) integer patch-pair offsets ``(py, px, qy, qx)``, px.
        patch_radius: half side of the patches (the guided filter's box radius).
        epsilon: guided-filter regulariser, for a [0, 1] image.
        sigma: scale of ``exp(-(1 - C) / sigma)``.
        blur_sigma: Gaussian pre-blur, px (0: none).

    Returns:
        (H, W, K) float32 descriptors, each of unit L2 norm, entries in (0, 1].
    """
    guide = dasc_prepare(image, blur_sigma=blur_sigma)
    pattern = np.asarray(pattern, np.int64).reshape(-1, 4)
    height, width = guide.shape
    reach = int(np.abs(pattern).max(initial=0))
    padded = np.pad(guide, 2 * reach, mode="edge")
    window = (2 * patch_radius + 1,) * 2

    def box(x: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(x, cv2.CV_32F, window, normalize=True, borderType=cv2.BORDER_REPLICATE)

    mean_i = box(guide)
    inverse_variance = 1.0 / (box(guide * guide) - mean_i * mean_i + np.float32(epsilon))

    def guided(p: np.ndarray) -> np.ndarray:
        """He et al.'s guided filter of ``p`` with guide ``guide``: the weighted mean of
        ``p`` over the 5x5 patches, weights from the guide's local structure."""
        mean_p = box(p)
        a = (box(guide * p) - mean_i * mean_p) * inverse_variance
        b = mean_p - a * mean_i
        return box(a) * guide + box(b)

    e_i = guided(guide)
    var_i = guided(guide * guide) - e_i * e_i

    def shifted(x: np.ndarray, dy: int, dx: int, pad: int) -> np.ndarray:
        """``x(y + dy, x + dx)`` from ``x`` padded by ``pad`` (replicated borders)."""
        return x[pad + dy:pad + dy + height, pad + dx:pad + dx + width]

    descriptor = np.empty((len(pattern), height, width), np.float32)
    for l, (py, px, qy, qx) in enumerate(pattern):
        j = np.ascontiguousarray(shifted(padded, int(qy - py), int(qx - px), 2 * reach))
        e_j = guided(j)
        var_j = guided(j * j) - e_j * e_j
        covariance = guided(guide * j) - e_i * e_j
        flat = (var_i < FLAT_VARIANCE) | (var_j < FLAT_VARIANCE)
        correlation = covariance / np.sqrt(np.where(flat, 1.0, var_i * var_j))
        correlation = np.where(flat, np.float32(1.0), np.clip(correlation, -1.0, 1.0))
        # C was computed at the patch centre x + p; move it to the described pixel x.
        at_p = np.pad(correlation, reach, mode="edge")
        descriptor[l] = shifted(at_p, int(py), int(px), reach)
    np.exp((descriptor - np.float32(1.0)) / np.float32(sigma), out=descriptor)
    descriptor /= np.sqrt(np.einsum("khw,khw->hw", descriptor, descriptor))
    return np.ascontiguousarray(descriptor.transpose(1, 2, 0))


def dasc_cost(
    left: np.ndarray,
    right: np.ndarray,
    disparity_range: DisparityRange,
    *,
    pattern: np.ndarray = DASC_PATTERN,
) -> CostVolume:
    """DASC cost volume: ``1 - <d_left(y, x), d_right(y, x - d)>``.

    The descriptors have unit L2 norm and positive entries, so the cost is half the
    squared L2 distance between them, in [0, 1] (0: identical descriptors).
    Out-of-view entries cost 1.

    Returns:
        float32 (H, W, D) volume, lower is better.
    """
    left_descriptor = dasc_descriptor(left, pattern=pattern)
    right_descriptor = dasc_descriptor(right, pattern=pattern)
    return CostVolume(dasc_descriptor_cost(left_descriptor, right_descriptor, disparity_range), disparity_range)


PRODUCT_COLUMNS = (16, 128)
"""Bounds on the left columns per matrix product in :func:`dasc_descriptor_cost` (span + 1
within them). A product computes columns + span dot products per left pixel for the
span + 1 it keeps; narrower than 16 columns BLAS runs slowly, wider than 128 the waste
grows (fastest for ranges of 16 to 400 on 240x720 and 496x744 descriptors, 2 threads)."""
PRODUCT_BYTES = 2**20
"""Target size of one block of dot products, rows x columns x (columns + span) float32
(kept within a CPU's L2 cache for the copy of its band that follows)."""


def dasc_descriptor_cost(
    left_descriptor: np.ndarray, right_descriptor: np.ndarray, disparity_range: DisparityRange
) -> np.ndarray:
    """``1 - <left_descriptor(y, x), right_descriptor(y, x - d)>`` clipped to [0, 1], 1
    where x - d leaves the image: the volume of :func:`dasc_cost` from (H, W, K) descriptors.

    The dot products come from BLAS matrix products: for a block of rows and of left
    columns [x0, x1), the left descriptors (rows, x1 - x0, K) times the right descriptors
    of every column those pixels reach, (rows, K, x1 - x0 + span); the disparity band of
    that product is then copied into the volume. Temporaries are about
    :data:`PRODUCT_BYTES`, whatever the image size.

    Returns:
        float32 (H, W, D) volume, lower is better.
    """
    height, width, _ = left_descriptor.shape
    low, high, span = disparity_range.minimum, disparity_range.maximum, disparity_range.span
    volume = np.empty((height, width, disparity_range.count), np.float32)
    columns = min(max(span + 1, PRODUCT_COLUMNS[0]), PRODUCT_COLUMNS[1])
    rows = max(1, PRODUCT_BYTES // (4 * columns * (columns + span)))
    for x0 in range(0, width, columns):
        x1 = min(x0 + columns, width)
        # Left columns x0..x1 - 1 reach right columns first..x1 - 1 - low (x1 - x0 + span of
        # them); start..stop are those inside the image.
        first = x0 - high
        start = max(first, 0)
        stop = max(start, min(x1 - low, width))
        for y0 in range(0, height, rows):
            y1 = min(y0 + rows, height)
            products = np.matmul(left_descriptor[y0:y1, x0:x1], right_descriptor[y0:y1, start:stop].transpose(0, 2, 1))
            if (start, stop) != (first, x1 - low):  # columns outside the image: product 0, cost 1
                padded = np.zeros((y1 - y0, x1 - x0, x1 - x0 + span), np.float32)
                padded[:, :, start - first:stop - first] = products
                products = padded
            # products[y, i, j] pairs left x0 + i with right first + j = x0 + i - (high - (j - i)):
            # on the band j = i + m, m = 0..span is disparity high - m. A view of the band steps
            # one row and one column at a time (strides s1 + s2); reversed, it runs low..high.
            s0, s1, s2 = products.strides
            band = np.lib.stride_tricks.as_strided(products, (y1 - y0, x1 - x0, span + 1), (s0, s1 + s2, s2),
                                                   writeable=False)
            block = volume[y0:y1, x0:x1]
            np.subtract(np.float32(1.0), band[:, :, ::-1], out=block)
            np.clip(block, 0.0, 1.0, out=block)
    return volume
