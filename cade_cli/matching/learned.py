"""The learned CADE matcher: the shipped ONNX network run with onnxruntime.

The matcher gets the two raw bands. The network (trained by :mod:`cade_cli.train`,
never imported here) takes their CADE transforms (color-agnostic bands) whose sides are
multiples of its divisor and searches disparities 0 .. ``max_disp`` - 1. Its card lists
several exports of the same weights that differ only in ``max_disp`` (the trained range
and wider ones). Around it this module:

* pre-shifts the right band by the requested minimum disparity, so any range
  [min, max] (negative minimum included) becomes [0, max - min];
* runs the narrowest variant that searches that span at full resolution; when even
  the widest cannot, runs it on a downscaled pair (factor 2, 4, ...) and upsamples,
  rescaling disparity;
* pads to the divisor (replicating the border) and crops back;
* refines the network's estimate at full resolution (:func:`refine_semiglobal`):
  semi-global matching of the rank-transformed raw bands over the whole range, whose
  confident matches within 32 px of the network's disparity replace it, where the
  network sees the match;
* splits tall images into overlapping horizontal strips, so memory stays bounded
  (disparity is horizontal: a strip holds everything its rows need);
* marks as invalid the pixels the right view cannot see (a nearer surface hides them,
  or their match falls outside it; :func:`visible_in_right_view`) and fills them from
  the background side along the row, like the classical matchers.

The network's ``uncertainty`` output (spread of its disparity distribution) is not used
for validity: rejecting pixels above 3 px and filling them from the background replaced
many good estimates on thin and slanted structures (models/README.md, "Validity").
"""

from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cade_cli.checksum import file_sha256
from cade_cli.errors import CadeError
from cade_cli.matching.base import DisparityRange, DisparityResult
from cade_cli.matching.classical import opencv_sgbm_levels
from cade_cli.matching.cost import rank_transform
from cade_cli.matching.disparity import fill_invalid_along_rows, visible_in_right_view
from cade_cli.spectral import color_agnostic

MODEL_NAME = "cade-v4"
MODEL_DIR_ENV = "CADE_MODEL_DIR"
STRIP_PIXELS = 1_500_000
"""Largest padded strip (pixels) given to the network at once; bounds memory (the cost
volume grows with the variant's range: about 1 GB at 128 levels, 2.3 GB at 256)."""
STRIP_OVERLAP = 32
"""Rows shared by neighbouring strips; each keeps the half nearer its own centre."""
RANGE_MARGIN = 8
"""The network's top levels are kept free: spans up to ``max_disp - RANGE_MARGIN`` run at full size."""
ALLOW_SPINNING = "session.intra_op.allow_spinning"
"""onnxruntime's session option that lets its threads busy-wait for work after a run; off here."""


def model_dir() -> Path:
    """Where model files and cards are looked up: $CADE_MODEL_DIR, else the repo's models/."""
    configured = os.environ.get(MODEL_DIR_ENV)
    return Path(configured) if configured else Path(__file__).resolve().parents[2] / "models"


@dataclass(frozen=True)
class ModelVariant:
    """One ONNX export: the weights searching disparities 0 .. ``max_disp`` - 1."""

    path: Path
    sha256: str
    max_disp: int


@dataclass(frozen=True)
class ModelCard:
    variants: tuple[ModelVariant, ...]
    divisor: int

    @classmethod
    def load(cls, name: str = MODEL_NAME, folder: Path | None = None) -> "ModelCard":
        folder = model_dir() if folder is None else folder
        card_path = folder / f"{name}.json"
        if not card_path.is_file():
            raise CadeError(f"model card {card_path} not found; set {MODEL_DIR_ENV} to the folder holding {name}.onnx")
        try:
            card = json.loads(card_path.read_text())
            variants = tuple(ModelVariant(folder / v["file"], v["sha256"], int(v["max_disp"])) for v in card["variants"])
            if not variants:
                raise ValueError("no variants")
            return cls(variants, int(card["divisor"]))
        except (ValueError, KeyError, TypeError) as error:
            raise CadeError(f"model card {card_path} is malformed: {error}") from None

    def variant_for(self, span: int) -> tuple[ModelVariant, int]:
        """The variant and pyramid factor for a disparity ``span``: the least downscaling
        first, then the narrowest search (the fastest, and the range it was trained on)."""
        def factor(variant: ModelVariant) -> int:
            return pyramid_factor(span, variant.max_disp - RANGE_MARGIN)

        best = min(self.variants, key=lambda variant: (factor(variant), variant.max_disp))
        return best, factor(best)


@functools.lru_cache(maxsize=4)
def _session(path: Path, sha256: str):
    """One onnxruntime session per model file, built once after checking its sha256."""
    if not path.is_file():
        raise CadeError(f"model file {path} not found; set {MODEL_DIR_ENV} to the folder holding it")
    digest = file_sha256(path)
    if digest != sha256:
        raise CadeError(f"model file {path} has sha256 {digest[:12]}..., its card says {sha256[:12]}...; "
                        f"the file is damaged or not the one the card describes")
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.log_severity_level = 3
    options.intra_op_num_threads = int(os.environ.get("OMP_NUM_THREADS") or 0)  # 0: one per physical core
    # The matcher hands the cores to OpenCV (refinement) right after each run; spinning
    # onnxruntime threads would keep them busy-waiting meanwhile (models/README.md, session 9).
    options.add_session_config_entry(ALLOW_SPINNING, "0")
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def shift_right_view(right: np.ndarray, shift: int) -> np.ndarray:
    """``out(y, x) = right(y, x - shift)``, border columns replicated.

    Matching left against ``out`` finds d - shift where matching against ``right`` finds d."""
    if shift == 0:
        return right
    width = right.shape[1]
    columns = np.clip(np.arange(width) - shift, 0, width - 1)
    return np.ascontiguousarray(right[:, columns])


def pyramid_factor(span: int, searchable: int) -> int:
    """Smallest power of two that brings a disparity ``span`` within ``searchable``."""
    factor = 1
    while span / factor > searchable:
        factor *= 2
    return factor


def strips(height: int, width: int, *, max_pixels: int = STRIP_PIXELS, overlap: int = STRIP_OVERLAP,
           divisor: int = 8) -> list[tuple[int, int, int, int]]:
    """Row bands ``(start, stop, keep_start, keep_stop)`` covering ``height`` rows.

    Each band [start, stop) has at most ``max_pixels`` pixels (at least ``4 * overlap``
    rows); [keep_start, keep_stop) are the rows it contributes to the output. The kept
    rows tile [0, height) exactly."""
    rows = max(4 * overlap, (max_pixels // max(width, 1)) // divisor * divisor)
    if rows >= height:
        return [(0, height, 0, height)]
    step = rows - overlap
    bands, start = [], 0
    while True:
        stop = min(start + rows, height)
        start = max(0, stop - rows)
        keep_start = 0 if start == 0 else start + overlap // 2
        bands.append((start, stop, keep_start, stop))
        if stop == height:
            break
        start += step
    # Trim each band's kept rows where the next band starts keeping.
    return [(s, e, ks, bands[i + 1][2] if i + 1 < len(bands) else ke) for i, (s, e, ks, ke) in enumerate(bands)]


REFINE_AGREEMENT = 32
"""Largest difference (px) between the network's disparity and the semi-global match that
:func:`refine_semiglobal` still accepts; beyond it the network's value is kept."""
REFINE_RANK_WINDOW = 7
REFINE_BLOCK = 5
REFINE_P1, REFINE_P2 = 8, 64
"""SGBM smoothness penalties per pixel of the block (OpenCV's usual 8 and 32 x block area,
with a stiffer P2)."""
REFINE_UNIQUENESS = 10
"""SGBM rejects a match whose runner-up (beyond its neighbours) costs less than 10 % more."""
REFINE_SIGN_BLUR = 31
"""Side of the box blur applied to both bands before their correlation decides whether
one is the other's contrast-inverted version."""
REFINE_SIGN_STEP = 4
"""That correlation reads every 4th row and column of the blurred bands."""
REFINE_REGION = 127
"""Side (px) of the windows in which :func:`inverted_regions` correlates the bands."""
REFINE_REGION_CORRELATION = -0.4
"""A window whose correlation lies below this, against the image-wide relation, is inverted."""
REFINE_REGION_SHARE = 0.15
"""Inverted windows count only when they cover at least this share of the image."""
REFINE_REGION_EDGE = 63
"""Once regions count, each pixel is judged in windows of this side (px), by its sign."""


def correlation(left: np.ndarray, right: np.ndarray) -> float:
    """Pearson correlation of two images' pixels (0 where either is constant).

    Sums, not ``np.dot``: a BLAS call leaves OpenBLAS's threads busy-waiting for the next
    one, on the cores onnxruntime and OpenCV need next (models/README.md, session 9)."""
    left, right = (image.astype(np.float64).ravel() for image in (left, right))
    left, right = left - left.mean(), right - right.mean()
    norm = np.sqrt(np.sum(left * left) * np.sum(right * right))
    return float(np.sum(left * right) / norm) if norm > 0 else 0.0


def _sign_samples(left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 31x31-blurred bands on every ``REFINE_SIGN_STEP``-th row and column of the left
    view: the left band there, and the right band at the matches ``disparity`` gives."""
    step = np.s_[::REFINE_SIGN_STEP, ::REFINE_SIGN_STEP]
    height, width = left.shape
    rows, columns = np.mgrid[0:height:REFINE_SIGN_STEP, 0:width:REFINE_SIGN_STEP].astype(np.float32)
    blurred_left, blurred_right = (cv2.blur(band.astype(np.float32), (REFINE_SIGN_BLUR, REFINE_SIGN_BLUR))
                                   for band in (left, right))
    matched = cv2.remap(blurred_right, columns - np.rint(disparity[step]), rows,
                        cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    return blurred_left[step], matched


def windowed_correlation(first: np.ndarray, second: np.ndarray, side: int) -> np.ndarray:
    """Pearson correlation of two sample grids (every ``REFINE_SIGN_STEP``-th pixel) in
    windows of ``side`` image pixels around each sample."""
    window = (side // REFINE_SIGN_STEP) | 1

    def mean(image: np.ndarray) -> np.ndarray:
        return cv2.blur(image, (window, window), borderType=cv2.BORDER_REFLECT)

    first_mean, second_mean = mean(first), mean(second)
    covariance = mean(first * second) - first_mean * second_mean
    variances = (mean(first * first) - first_mean**2) * (mean(second * second) - second_mean**2)
    return covariance / np.sqrt(np.maximum(variances, np.float32(1e-12)))


def inverted_regions(left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """Left-view pixels where ``right`` is a contrast-inverted version of ``left``.

    First image-wide: a negative correlation of the 31x31-blurred bands along the matches
    ``disparity`` gives (judged on blurred bands, so the sign holds where ``disparity`` is
    many pixels off; every ``REFINE_SIGN_STEP``-th row and column is enough after that
    blur) flips every pixel. Then by region: the same samples are correlated in windows of
    ``REFINE_REGION`` px; where that correlation opposes the image-wide relation by more
    than ``REFINE_REGION_CORRELATION`` (e.g. vegetation, bright in NIR and dark in red,
    over part of the view) on at least ``REFINE_REGION_SHARE`` of the image, the pixels
    whose ``REFINE_REGION_EDGE``-px windows oppose it at all flip too. On the benchmark
    pairs (Middlebury, FlyingThings3D, KITTI) the strongly opposed windows cover at most
    about 10 %, so there only the image-wide relation counts.

    Returns:
        (H, W) bool.
    """
    height, width = left.shape
    blurred_left, matched = _sign_samples(left, right, disparity)
    inverted = correlation(blurred_left, matched) < 0
    sign = np.float32(-1 if inverted else 1)  # local correlations relative to the image-wide relation
    strongly_opposed = sign * windowed_correlation(blurred_left, matched, REFINE_REGION) < REFINE_REGION_CORRELATION
    if strongly_opposed.mean() < REFINE_REGION_SHARE:
        return np.full((height, width), inverted)
    opposed = sign * windowed_correlation(blurred_left, matched, REFINE_REGION_EDGE) < 0
    samples = (opposed ^ inverted).astype(np.uint8)
    return cv2.resize(samples, (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)


def refine_semiglobal(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, span: int, *,
                      agreement: float = REFINE_AGREEMENT) -> np.ndarray:
    """Correct the network's disparity by semi-global matching of the raw bands.

    The network works at 1/4 resolution on color-agnostic bands: robust across bands, but
    blurred at edges, in fine texture and on thin structures (branches, cables), which it
    can miss by tens of pixels. This step matches the full-resolution bands again, over
    the whole range, and lets the result overrule the network where it is trustworthy:

    1. both bands become rank images (:func:`~cade_cli.matching.cost.rank_transform`,
       7x7): they depend only on the order of intensities, so a gain, offset or gamma
       change between bands does not alter them, and fine texture is kept; where the
       bands are anti-correlated along the network's matches (:func:`inverted_regions`:
       over the whole image, as for a filter pair that inverts contrast, or over large
       regions of it), the left ranks are flipped (48 - rank). A smaller inverted patch
       is not flipped; there the ranks disagree and step 3 leaves most of it to the network;
    2. OpenCV's StereoSGBM (3-way mode, 5x5 blocks) searches
       disparities 0 .. ``span`` on that pair, with sub-pixel output;
    3. its value replaces the network's where SGBM accepted the match and it lies within
       ``agreement`` px of the network's; elsewhere the network's value is kept: SGBM
       rejects a match whose runner-up is within 10 % of the best cost, a speckle (a
       patch under 100 px that differs by more than 2 px from its surroundings), and a
       match outside the right image is refused too. Where the bands are unrelated (e.g.
       the R and G planes of random colour textures) the ranks disagree, and these
       rejections and the agreement bound leave the network in charge.

    Args:
        left, right: (H, W) float32 raw bands (any units; only their order matters).
        disparity: (H, W) float32 network disparity for ``left``, in pixels, in [0, span].
        span: largest disparity searched, px.
        agreement: largest accepted difference from ``disparity``, px.

    Returns:
        (H, W) float32 refined disparity.
    """
    if span < 1:
        raise ValueError(f"refinement needs a disparity span of at least 1 px, got {span}")
    width = left.shape[1]
    top = REFINE_RANK_WINDOW**2 - 1
    left_rank, right_rank = (rank_transform(band, window=REFINE_RANK_WINDOW) for band in (left, right))
    # The left ranks are flipped, where the regions are found. Flipping the right ones
    # instead is not bit-identical in OpenCV's SGBM but no more accurate (contrast inverted
    # everywhere: 5.87 px EPE against 5.86, models/README.md, session 11).
    inverted = inverted_regions(left, right, disparity)
    if inverted.any():
        left_rank = np.where(inverted, np.uint8(top) - left_rank, left_rank)
    # Ranks 0..48 spread over 0..240, so OpenCV's 8-bit cost keeps its resolution.
    scale = np.uint8(240 // top)
    left_rank, right_rank = left_rank * scale, right_rank * scale
    levels = opencv_sgbm_levels(span + 1)
    area = REFINE_BLOCK * REFINE_BLOCK
    # disp12MaxDiff asks for OpenCV's left-right check, but it changed no score and no
    # rejection count when tried off and at 0..2 px (models/README.md, session 10): no
    # left-right check is claimed for this step.
    matcher = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=levels, blockSize=REFINE_BLOCK, P1=REFINE_P1 * area, P2=REFINE_P2 * area,
        disp12MaxDiff=1, uniquenessRatio=REFINE_UNIQUENESS, speckleWindowSize=100, speckleRange=2,
        preFilterCap=15, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    # OpenCV leaves the first ``levels`` columns unmatched: pad, so that happens outside the image.
    left_rank, right_rank = (cv2.copyMakeBorder(image, 0, 0, levels, 0, cv2.BORDER_REPLICATE)
                             for image in (left_rank, right_rank))
    matched = matcher.compute(left_rank, right_rank)[:, levels:].astype(np.float32) / np.float32(16)
    inside = (matched >= 0) & (matched <= np.arange(width, dtype=np.float32)[None, :])  # rejects are -1
    accepted = inside & (np.abs(matched - disparity) <= agreement)
    return np.where(accepted, matched, disparity).astype(np.float32)


class CadeNetwork:
    """Kernel of the ``cade`` matcher (see the module docstring)."""

    def __init__(self, name: str = MODEL_NAME, *, refine: bool = True):
        self.name = name
        self.refine = refine

    def __call__(self, left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange) -> DisparityResult:
        """Disparity of the raw bands ``left`` against ``right`` (the network sees their
        CADE transform; the refinement matches the raw bands)."""
        card = ModelCard.load(self.name)
        variant, factor = card.variant_for(disparity_range.count - 1)
        session = _session(variant.path, variant.sha256)
        height, width = left.shape
        minimum = disparity_range.minimum
        right = shift_right_view(right, minimum)
        left_band, right_band = color_agnostic(left), color_agnostic(right)
        if factor > 1:
            size = (max(1, round(width / factor)), max(1, round(height / factor)))
            left_band, right_band = (cv2.resize(band, size, interpolation=cv2.INTER_AREA)
                                     for band in (left_band, right_band))
        network = self._run(session, card.divisor, left_band, right_band)
        if factor > 1:
            network = cv2.resize(network, (width, height), interpolation=cv2.INTER_LINEAR) * np.float32(
                width / left_band.shape[1])
        disparity = np.clip(network + minimum, minimum, disparity_range.maximum)
        # Visibility is judged on the network's surface: the refinement's per-pixel
        # corrections would scatter it. Occluded pixels have nothing to match: not refined.
        valid = visible_in_right_view(disparity)
        if self.refine:
            refined = refine_semiglobal(left, right, disparity - minimum, disparity_range.count - 1) + minimum
            disparity = np.clip(np.where(valid, refined, disparity), minimum, disparity_range.maximum)
        return DisparityResult(fill_invalid_along_rows(disparity, valid), valid)

    @staticmethod
    def _run(session, divisor: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """The network's disparity for a pair of any size: strips, padding, cropping."""
        height, width = left.shape
        disparity = np.empty((height, width), np.float32)
        padded_width = width + (-width % divisor)
        for start, stop, keep_start, keep_stop in strips(height, padded_width, divisor=divisor):
            rows = stop - start
            pad = ((0, -rows % divisor), (0, -width % divisor))
            inputs = {name: np.pad(band[start:stop], pad, mode="edge")[None, None].astype(np.float32, copy=False)
                      for name, band in (("left", left), ("right", right))}
            (out,) = session.run(["disparity"], inputs)
            disparity[keep_start:keep_stop] = out[0, 0, keep_start - start:keep_stop - start, :width]
        return disparity
