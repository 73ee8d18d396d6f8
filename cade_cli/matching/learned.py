"""The learned CADE matcher: the shipped ONNX network run with onnxruntime.

The network (trained by :mod:`cade_cli.train`, never imported here) takes two
color-agnostic bands whose sides are multiples of its divisor and searches disparities
0 .. ``max_disp`` - 1. Its card lists several exports of the same weights that differ
only in ``max_disp`` (the trained range and wider ones). Around it this module:

* pre-shifts the right band by the requested minimum disparity, so any range
  [min, max] (negative minimum included) becomes [0, max - min];
* runs the narrowest variant that searches that span at full resolution; when even
  the widest cannot, runs it on a downscaled pair (factor 2, 4, ...) and upsamples,
  rescaling disparity;
* pads to the divisor (replicating the border) and crops back;
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
from cade_cli.matching.disparity import fill_invalid_along_rows, visible_in_right_view

MODEL_NAME = "cade-v4"
MODEL_DIR_ENV = "CADE_MODEL_DIR"
STRIP_PIXELS = 1_500_000
"""Largest padded strip (pixels) given to the network at once; bounds memory (the cost
volume grows with the variant's range: about 1 GB at 128 levels, 2.3 GB at 256)."""
STRIP_OVERLAP = 32
"""Rows shared by neighbouring strips; each keeps the half nearer its own centre."""
RANGE_MARGIN = 8
"""The network's top levels are kept free: spans up to ``max_disp - RANGE_MARGIN`` run at full size."""


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


SUBPIXEL_RADIUS = 2
SUBPIXEL_WINDOW = 5
SUBPIXEL_MIN_ZNCC = 0.5


def refine_subpixel(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, *,
                    radius: int = SUBPIXEL_RADIUS, window: int = SUBPIXEL_WINDOW,
                    min_zncc: float = SUBPIXEL_MIN_ZNCC) -> np.ndarray:
    """Sharpen the network's disparity with a local ZNCC search at full resolution.

    For each pixel, ZNCC over a ``window`` x ``window`` patch is evaluated at the integer
    disparities round(d) - radius .. round(d) + radius (the right band sampled per pixel,
    so the patch follows the network's surface); the best one, refined by a parabola
    through its neighbours, replaces d where it is an interior peak with ZNCC above
    ``min_zncc``. Elsewhere (flat or ambiguous patches) d is kept.

    Args:
        left, right: (H, W) float32 color-agnostic bands.
        disparity: (H, W) float32 network output for ``left``.
    """
    height, width = left.shape
    base = np.rint(disparity).astype(np.int32)
    landing = (np.arange(width, dtype=np.int32)[None, :] - base).astype(np.float32)
    rows = np.broadcast_to(np.arange(height, dtype=np.float32)[:, None], (height, width))
    size = (window, window)

    def box(image: np.ndarray) -> np.ndarray:
        return cv2.blur(image, size, borderType=cv2.BORDER_REFLECT)

    left_mean = box(left)
    left_var = box(left * left) - left_mean * left_mean
    scores = []
    for offset in range(-radius, radius + 1):
        # right(y, x - base - offset), border columns replicated (integer positions: exact)
        warped = cv2.remap(right, landing - offset, rows, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        warped_mean = box(warped)
        covariance = box(left * warped) - left_mean * warped_mean
        warped_var = box(warped * warped) - warped_mean * warped_mean
        scores.append(covariance / np.sqrt(np.maximum(left_var * warped_var, 1e-12)))
    # Per-pixel argmax (first maximum) and its neighbours, one plane at a time: on a
    # (2r+1, H, W) stack, axis-0 argmax and gathers cost more than all the ZNCC above.
    best, peak = np.zeros((height, width), np.int8), scores[0]
    for index in range(1, len(scores)):
        better = scores[index] > peak
        best, peak = np.where(better, np.int8(index), best), np.where(better, scores[index], peak)
    before, after = np.zeros_like(peak), np.zeros_like(peak)
    for index in range(1, 2 * radius):
        at = best == index
        before, after = np.where(at, scores[index - 1], before), np.where(at, scores[index + 1], after)
    interior = (best > 0) & (best < 2 * radius)
    curvature = before - 2 * peak + after
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(curvature < 0, 0.5 * (before - after) / curvature, 0.0)
    refined = base + (best - radius) + np.clip(delta, -0.5, 0.5)
    accept = interior & (peak >= min_zncc) & (left_var > 1e-6)
    return np.where(accept, refined, disparity).astype(np.float32)


class CadeNetwork:
    """Kernel of the ``cade`` matcher (see the module docstring)."""

    def __init__(self, name: str = MODEL_NAME, *, subpixel: bool = True):
        self.name = name
        self.subpixel = subpixel

    def __call__(self, left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange) -> DisparityResult:
        card = ModelCard.load(self.name)
        variant, factor = card.variant_for(disparity_range.count - 1)
        session = _session(variant.path, variant.sha256)
        height, width = left.shape
        right = shift_right_view(right, disparity_range.minimum)
        if factor > 1:
            size = (max(1, round(width / factor)), max(1, round(height / factor)))
            left_small, right_small = (cv2.resize(band, size, interpolation=cv2.INTER_AREA) for band in (left, right))
        else:
            left_small, right_small = left, right
        disparity = self._run(session, card.divisor, left_small, right_small)
        if self.subpixel:
            disparity = refine_subpixel(left_small, right_small, disparity)
        if factor > 1:
            disparity = cv2.resize(disparity, (width, height), interpolation=cv2.INTER_LINEAR) * np.float32(
                width / left_small.shape[1])
        disparity = np.clip(disparity + disparity_range.minimum, disparity_range.minimum, disparity_range.maximum)
        valid = visible_in_right_view(disparity)
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
