"""The network stage of the CADE matcher: the shipped ONNX network run with onnxruntime.

The network (trained by :mod:`cade_cli.train`, never imported here) takes the CADE
transforms (color-agnostic bands) of the two views, with sides that are multiples of its
divisor, and searches disparities 0 .. ``levels`` - 1 of the variant it was exported
with (:mod:`cade_cli.model_card`). Around it :class:`NetworkStage`:

* pre-shifts the right band by the requested minimum disparity, so any range
  [min, max] (negative minimum included) becomes [0, max - min];
* runs the narrowest variant that searches that span at full resolution; when even the
  widest cannot, runs it on a downscaled pair (factor 2, 4, ...) and upsamples,
  rescaling disparity (:func:`pyramid_factor`);
* pads to the divisor (replicating the border, :func:`pad_to_divisor`) and crops back;
* splits tall images into overlapping horizontal strips (:func:`strips`), so memory
  stays bounded (disparity is horizontal: a strip holds everything its rows need).

The network's ``uncertainty`` output (spread of its disparity distribution, px) is not used
for validity: rejecting pixels above 3 px and filling them from the background replaced
many good estimates on thin and slanted structures (docs/research/refinement.md, 2026-11-22). It
feeds the matcher's confidence instead (:func:`~cade_cli.matching.confidence.network_confidence`);
:meth:`NetworkStage.estimate` returns it beside the disparity, resampled like it.

A card may ask for extra passes fused with the plain one (its ``test_time_augmentation``: the pair
upside down, enlarged, or mirrored for a left-right check; :mod:`cade_cli.matching.augmentation`).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.io.checksum import file_sha256
from cade_cli.matching import augmentation
from cade_cli.matching.augmentation import FUSE_AGREEMENT_PX, NetworkOutput, fuse_estimates  # noqa: F401 (re-exported)
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.side_by_side import side_by_side
from cade_cli.model_card import DEFAULT_MODEL, MODEL_DIR_ENV, ModelCard, ModelVariant, read_card
from cade_cli.spectral import network_input

STRIP_PIXELS = 1_500_000
"""Largest padded strip (pixels) given to the network at once; bounds memory (the cost
volume grows with the variant's levels: about 1 GB at 128, 2.3 GB at 256)."""
STRIP_OVERLAP = 32
"""Rows shared by neighbouring strips; each keeps the half nearer its own centre."""
RANGE_MARGIN = 8
"""A variant's top levels are kept free: spans (max - min) up to ``levels - RANGE_MARGIN`` px
run at full size."""
OUTPUT_NAMES = ("disparity", "uncertainty")
"""The ONNX outputs read, in the order of :class:`NetworkOutput`'s fields."""
UPSCALED = {"upscaled-x1.5": 1.5, "upscaled-x2": 2.0}
"""The second-scale entries of a card's ``test_time_augmentation``: how much each enlarges the raw bands."""
ALLOW_SPINNING = "session.intra_op.allow_spinning"
"""onnxruntime's session option that lets its threads busy-wait for work after a run; off here."""


def searchable_span(variant: ModelVariant) -> int:
    """Largest disparity span (max - min, px) the variant searches at full resolution."""
    return variant.levels - RANGE_MARGIN


def pyramid_factor(span: int, searchable: int) -> int:
    """Smallest power of two that brings a disparity ``span`` (px) within ``searchable`` (px)."""
    factor = 1
    while span / factor > searchable:
        factor *= 2
    return factor


def choose_variant(card: ModelCard, span: int) -> tuple[ModelVariant, int]:
    """The variant and pyramid factor for a disparity ``span`` (max - min, px): the least
    downscaling first, then the narrowest search (the fastest, and the range it was trained on)."""
    def factor(variant: ModelVariant) -> int:
        return pyramid_factor(span, searchable_span(variant))

    best = min(card.variants, key=lambda variant: (factor(variant), variant.levels))
    return best, factor(best)


def onnx_session(path: Path, sha256: str):
    """One onnxruntime session per model file and thread count ($OMP_NUM_THREADS as it is now:
    :func:`cade_cli.evaluation.timing.use_threads` sets it for pools created later), built once
    after checking its sha256. The count is part of the key because it is part of the output: the
    fast design's maps (cade-v12, cade-v13) move slightly (far below 0.01 px) between one and two
    threads on small inputs (cade-v11's do not), so a session kept from before a change of threads
    would score otherwise than a new one."""
    return _onnx_session(path, sha256, int(os.environ.get("OMP_NUM_THREADS") or 0))


@functools.lru_cache(maxsize=4)
def _onnx_session(path: Path, sha256: str, threads: int):
    """:func:`onnx_session`'s session with ``threads`` intra-op threads (0: one per physical core)."""
    if not path.is_file():
        raise CadeError(f"model file {path} not found; set {MODEL_DIR_ENV} to the folder holding it")
    digest = file_sha256(path)
    if digest != sha256:
        raise CadeError(f"model file {path} has sha256 {digest[:12]}..., its card says {sha256[:12]}...; "
                        f"the file is damaged or not the one the card describes")
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.log_severity_level = 3
    options.intra_op_num_threads = threads
    # The matcher hands the cores to OpenCV (refinement) right after each run; spinning
    # onnxruntime threads would keep them busy-waiting meanwhile (docs/research/speed.md, 2026-11-22).
    options.add_session_config_entry(ALLOW_SPINNING, "0")
    # No arena: it keeps the peak of every input shape it has seen, so tiles of many shapes
    # (cade_cli.scale.tiling) grew the process past its budget (docs/scale.md, "Tiling"); the
    # run time of a pair is the same without it.
    options.enable_cpu_mem_arena = False
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def shift_right_view(right: np.ndarray, shift: int) -> np.ndarray:
    """``out(y, x) = right(y, x - shift)``, border columns replicated.

    Matching left against ``out`` finds d - shift where matching against ``right`` finds d."""
    if shift == 0:
        return right
    width = right.shape[1]
    columns = np.clip(np.arange(width) - shift, 0, width - 1)
    return np.ascontiguousarray(right[:, columns])


def pad_to_divisor(band: np.ndarray, divisor: int) -> tuple[np.ndarray, tuple[int, int]]:
    """``band`` (H, W) padded at the bottom and right, edges replicated, to multiples of
    ``divisor``; returns the padded float32 array and (H, W) to crop back to. The runtime
    and the training validation both pad with this."""
    height, width = band.shape
    padded = np.pad(band, ((0, -height % divisor), (0, -width % divisor)), mode="edge")
    return padded.astype(np.float32, copy=False), (height, width)


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


def run_network_outputs(session, divisor: int, left: np.ndarray, right: np.ndarray) -> NetworkOutput:
    """The network's disparity (px, 0 .. levels - 1) and uncertainty (px) for
    color-agnostic bands of any size: strips, padding, cropping. Asking for both outputs
    leaves the disparity bit-identical to asking for it alone."""
    height, width = left.shape
    outputs = NetworkOutput(np.empty((height, width), np.float32), np.empty((height, width), np.float32))
    padded_width = width + (-width % divisor)
    for start, stop, keep_start, keep_stop in strips(height, padded_width, max_pixels=STRIP_PIXELS, divisor=divisor):
        inputs = {name: pad_to_divisor(band[start:stop], divisor)[0][None, None]
                  for name, band in (("left", left), ("right", right))}
        for kept, out in zip(outputs, session.run(list(OUTPUT_NAMES), inputs)):
            kept[keep_start:keep_stop] = out[0, 0, keep_start - start:keep_stop - start, :width]
    return outputs


def run_network(session, divisor: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The network's (H, W) float32 disparity (px, 0 .. levels - 1) for color-agnostic
    bands of any size (:func:`run_network_outputs` without the uncertainty)."""
    return run_network_outputs(session, divisor, left, right).disparity


@dataclass(frozen=True)
class NetworkStage:
    """Raw bands and a range -> the network's disparity of the left view at full resolution.

    Attributes:
        model: a card name in :func:`cade_cli.model_card.model_dir` (``cade-v4``) or the
            path of a card (``.json``), whose variants lie beside it.
    """

    model: str = DEFAULT_MODEL

    def card(self) -> ModelCard:
        """The model's card."""
        return read_card(self.model)

    def __call__(self, left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange) -> np.ndarray:
        """(H, W) float32 disparity in px, clipped to ``disparity_range``, of the raw bands
        ``left`` against ``right`` (the network sees their CADE transforms, or for a card
        whose ``input`` is ``normalised`` the bands rescaled to [0, 1])."""
        return self.estimate(left, right, disparity_range).disparity

    def estimate(self, left: np.ndarray, right: np.ndarray, disparity_range: DisparityRange) -> NetworkOutput:
        """The disparity of :meth:`__call__` and the network's uncertainty (px of the input
        images: on a pyramid level it is upsampled and rescaled like the disparity)."""
        card = read_card(self.model)
        variant, factor = choose_variant(card, disparity_range.span)
        session = onnx_session(variant.path, variant.sha256)
        height, width = left.shape
        minimum = disparity_range.minimum
        raw = (left, shift_right_view(right, minimum))
        left_band, right_band = side_by_side(lambda: network_input(raw[0], card.input),
                                             lambda: network_input(raw[1], card.input))
        if factor > 1:
            size = (max(1, round(width / factor)), max(1, round(height / factor)))
            left_band, right_band = (cv2.resize(band, size, interpolation=cv2.INTER_AREA)
                                     for band in (left_band, right_band))
        run = functools.partial(run_network_outputs, session, card.divisor)
        output = run(left_band, right_band)
        for name in card.test_time:
            output = self._augment(name, output, run, card, (left_band, right_band), raw,
                                   second_span=disparity_range.span * left_band.shape[1] / width,
                                   searchable=searchable_span(variant))
        network, uncertainty = output
        if factor > 1:
            scale = np.float32(width / left_band.shape[1])
            network, uncertainty = (cv2.resize(band, (width, height), interpolation=cv2.INTER_LINEAR) * scale
                                    for band in (network, uncertainty))
        return NetworkOutput(np.clip(network + minimum, minimum, disparity_range.maximum), uncertainty)

    @staticmethod
    def _augment(name: str, output: NetworkOutput, run, card: ModelCard, bands: tuple[np.ndarray, np.ndarray],
                 raw: tuple[np.ndarray, np.ndarray], *, second_span: float, searchable: int) -> NetworkOutput:
        """``output`` (the network's on the level's ``bands``) fused with the extra pass ``name`` of the
        card's ``test_time_augmentation`` (:mod:`cade_cli.matching.augmentation`); ``raw``: the full-size
        raw bands (the right one pre-shifted), ``second_span``: the range's span on the level, px."""
        if name == "vertical-flip":
            return fuse_estimates(output, augmentation.flipped_pass(run, *bands))
        if name == "mirrored":
            return augmentation.left_right_fuse(output, augmentation.mirrored_pass(run, *bands))
        factor = augmentation.second_scale(UPSCALED[name], second_span, searchable)
        if factor is None:
            return output
        size = (bands[0].shape[1], bands[0].shape[0])
        second = augmentation.upscaled_pass(run, functools.partial(network_input, kind=card.input), *raw, size, factor)
        return fuse_estimates(output, second)
