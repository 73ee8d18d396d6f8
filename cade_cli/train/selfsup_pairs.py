"""Real cross-spectral band pairs without ground truth, as a self-supervised training source
(issue 38 item 5): two bands of a multi-lens capture (``../shared/data/micasense``: the RedEdge-M
bench captures and the Sequoia tabletop, never ``msir-outdoor``) brought into one pinhole frame
(:mod:`cade_cli.capture`: undistortion, lens rotation, the parallax direction measured from
sparse cross-spectral matches) and resampled so that the parallax runs along +x: a rectified
stereo pair, ``left(x) ≈ right(x - d)`` with ``d >= 0``. Rectified once per band pair and cached
(npz), so training only crops them (:class:`SelfSupPairs`). Torch-free.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cade_cli.capture.model import Capture, band_pixels, load_capture
from cade_cli.capture.parallax import (MIN_MATCHES, Parallax, cross_spectral_matches, measure_parallax,
                                       plane_from_matches, refine_matches)
from cade_cli.capture.register import read_raw, sample_bilinear
from cade_cli.errors import CadeError
from cade_cli.spectral import network_input

MARGIN_PX = 2.0
"""The rectified pair's right view is shifted along x so that the matches' robust smallest
parallax (:attr:`Parallax.low`) becomes this many px: every disparity of the pair >= 0."""
SKIPPED_FOLDERS = ("msir-outdoor",)
"""Never rectified, whatever folder is given: the shipping rule's real check is scored on it."""
CACHE_VERSION = 1


@dataclass(frozen=True)
class RectifiedPair:
    """Two bands of one capture on a common grid whose parallax runs along +x.

    Attributes:
        left, right: (H, W) float32 signal (raw minus black level), NaN where the band did not see the pixel.
        bands: (left band name, right band name).
        capture: the capture's name (its first file's stem without the band suffix).
        baseline: (2,) the parallax direction in the capture's common frame (becomes +x).
        shift: px added to every disparity (``MARGIN_PX - low``).
        low, high: the matches' robust parallax extremes after the shift, px.
    """

    left: np.ndarray
    right: np.ndarray
    bands: tuple[str, str]
    capture: str
    baseline: np.ndarray
    shift: float
    low: float
    high: float


def rectified_grid(size: tuple[int, int], baseline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Common-frame coordinates (x, y), (H', W') float32 each, of the rectified grid: column X
    and row Y sit at ``origin + X·baseline + Y·normal`` (normal = baseline turned by +90°),
    the grid just covering the ``size`` = (width, height) frame."""
    width, height = size
    b = np.asarray(baseline, np.float64)
    n = np.array([-b[1], b[0]])
    corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], np.float64)
    along, across = corners @ b, corners @ n
    columns, rows = int(np.ceil(along.max() - along.min())) + 1, int(np.ceil(across.max() - across.min())) + 1
    X, Y = np.meshgrid(np.arange(columns, dtype=np.float64) + along.min(),
                       np.arange(rows, dtype=np.float64) + across.min())
    return (X * b[0] + Y * n[0]).astype(np.float32), (X * b[1] + Y * n[1]).astype(np.float32)


def measure_band(capture: Capture, signal: list[np.ndarray], index: int) -> Parallax | None:
    """The parallax of band ``index`` against the capture's reference (:func:`measure_parallax`
    on refined cross-spectral matches in the common frame); None when the matches are too few
    or the plane leaves no parallax (nothing to learn about depth there)."""
    width, height = capture.frame[1]
    x, y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    reference, _ = sample_bilinear(signal[capture.reference], *band_pixels(capture, capture.reference, x, y))
    rotated, _ = sample_bilinear(signal[index], *band_pixels(capture, index, x, y))
    points_reference, points_band = refine_matches(reference, rotated, *cross_spectral_matches(reference, rotated))
    if len(points_reference) < MIN_MATCHES:
        return None
    homography, _ = plane_from_matches(points_reference, points_band)
    parallax = measure_parallax(points_reference, points_band, homography)
    return None if parallax.negligible else parallax


def rectify(capture: Capture, signal: list[np.ndarray], index: int, parallax: Parallax, name: str) -> RectifiedPair:
    """The reference band (left) and band ``index`` (right) on the rectified grid of ``parallax``.

    The band sees the reference's pixel p at ``p + across(p)·normal - d·baseline`` (:class:`Parallax`);
    sampled at ``p + across·normal + shift·baseline`` it holds at p the point the reference has at
    ``p + (d + shift)·baseline``: along the grid's +x, ``left(X) = right(X - d - shift)``."""
    x, y = rectified_grid(capture.frame[1], parallax.baseline)
    shift = MARGIN_PX - parallax.low
    across = parallax.across_at(x, y)
    bx, by = (np.float32(value) for value in parallax.baseline)
    nx, ny = (np.float32(value) for value in parallax.normal)
    left, seen_left = sample_bilinear(signal[capture.reference], *band_pixels(capture, capture.reference, x, y))
    right, seen_right = sample_bilinear(signal[index], *band_pixels(capture, index, x + across * nx + shift * bx,
                                                                    y + across * ny + shift * by))
    rows, columns = np.nonzero(seen_left | seen_right)
    window = (slice(rows.min(), rows.max() + 1), slice(columns.min(), columns.max() + 1))
    nan = np.float32(np.nan)
    return RectifiedPair(
        left=np.where(seen_left, left, nan)[window], right=np.where(seen_right, right, nan)[window],
        bands=(capture.reference_band.name, capture.bands[index].name), capture=name,
        baseline=np.asarray(parallax.baseline, np.float64), shift=float(shift),
        low=MARGIN_PX, high=float(parallax.high + shift))


def capture_groups(folder: Path) -> dict[str, list[Path]]:
    """The captures under ``folder`` (any depth): band TIFFs grouped by their name without the
    band suffix (``IMG_0001_3.tif`` -> ``IMG_0001``); folders of :data:`SKIPPED_FOLDERS` left out."""
    groups: dict[str, list[Path]] = {}
    for path in sorted(Path(folder).rglob("*")):
        if path.suffix.lower() not in (".tif", ".tiff") or any(part in SKIPPED_FOLDERS for part in path.parts):
            continue
        groups.setdefault(str(path.parent / path.stem.rsplit("_", 1)[0]), []).append(path)
    return {key: paths for key, paths in groups.items() if len(paths) >= 2}


def rectified_pairs(paths: list[Path], name: str) -> list[RectifiedPair]:
    """Every pair of bands of one capture (the band of the lower rig index on the left: the
    other order is the mirror image, :meth:`SelfSupPairs.draw`) that shows parallax."""
    first = load_capture(paths)
    pairs = []
    for a, b in itertools.combinations(range(len(first.bands)), 2):
        capture = load_capture(paths, reference=first.bands[a].name)
        signal = [np.asarray(image, np.float32) - np.float32(band.black_level)
                  for image, band in zip(read_raw(capture), capture.bands)]
        index = next(i for i, band in enumerate(capture.bands) if band.name == first.bands[b].name)
        parallax = measure_band(capture, signal, index)
        if parallax is not None:
            pairs.append(rectify(capture, signal, index, parallax, name))
    return pairs


def build_cache(folder: Path, cache: Path, *, log=print) -> list[Path]:
    """Rectify every band pair of every capture under ``folder`` into ``cache`` (one npz per
    pair, written once: an existing file is kept); the npz paths."""
    cache = Path(cache)
    cache.mkdir(parents=True, exist_ok=True)
    groups = capture_groups(folder)
    if not groups:
        raise CadeError(f"no multi-band captures under {folder}; expected band TIFFs such as IMG_0001_1.tif")
    written = []
    for key, paths in groups.items():
        name = Path(key).relative_to(Path(folder)).as_posix().replace("/", "-")
        done = sorted(cache.glob(f"{name}--*.npz"))
        if done:
            written += done
            continue
        for pair in rectified_pairs(paths, name):
            target = cache / f"{name}--{pair.bands[0]}--{pair.bands[1]}.npz".replace(" ", "")
            partial = target.with_suffix(".partial.npz")
            np.savez(partial, left=pair.left, right=pair.right, bands=np.array(pair.bands), capture=pair.capture,
                     baseline=pair.baseline, shift=pair.shift, low=pair.low, high=pair.high, version=CACHE_VERSION)
            partial.replace(target)
            log(f"{target.name}: parallax {pair.low:.1f}..{pair.high:.1f} px, {pair.left.shape[1]}x{pair.left.shape[0]}")
            written.append(target)
    return written


GUIDE_PERCENTILES = (1.0, 99.0)
MIN_SEEN_SHARE = 0.97
"""A crop is kept when at least this share of its pixels is seen by both bands (else redrawn)."""
CROP_TRIES = 20


@dataclass(frozen=True)
class SelfSupCrop:
    """One crop of a rectified pair: the network's inputs (``left``, ``right``, as ``kind`` says)
    and the loss's: ``guides`` (4, H, W) float32 = left and right bands rescaled to about [0, 1]
    (percentiles of the crop), and where each was seen (1/0)."""

    left: np.ndarray
    right: np.ndarray
    guides: np.ndarray
    bands: tuple[str, str]


class SelfSupPairs:
    """The cached rectified pairs (:func:`build_cache`), loaded once, cropped at random."""

    def __init__(self, cache: Path):
        files = sorted(Path(cache).glob("*--*.npz"))
        if not files:
            raise CadeError(f"no rectified pairs in {cache}; build them first (fit --selfsup-dir)")
        self.pairs = []
        for path in files:
            with np.load(path) as data:
                self.pairs.append((data["left"].astype(np.float32), data["right"].astype(np.float32),
                                   tuple(str(band) for band in data["bands"])))

    def draw(self, rng: np.random.Generator, height: int, width: int, kind: str = "cade") -> SelfSupCrop:
        """A random (height, width) crop of a random pair, mostly seen by both bands; half the
        time mirrored left-right with the views swapped (the other band on the left, disparities
        still >= 0), half the time flipped upside down."""
        for _ in range(CROP_TRIES):
            left, right, bands = self.pairs[int(rng.integers(len(self.pairs)))]
            rows, columns = left.shape
            if rows < height or columns < width:
                continue
            top, start = int(rng.integers(rows - height + 1)), int(rng.integers(columns - width + 1))
            window = (slice(top, top + height), slice(start, start + width))
            crop_left, crop_right = left[window], right[window]
            seen_left, seen_right = np.isfinite(crop_left), np.isfinite(crop_right)
            if (seen_left & seen_right).mean() >= MIN_SEEN_SHARE:
                break
        else:
            raise CadeError(f"no {width}x{height} crop of the rectified pairs is seen by both bands")
        if rng.random() < 0.5:
            crop_left, crop_right = crop_right[:, ::-1], crop_left[:, ::-1]
            seen_left, seen_right = seen_right[:, ::-1], seen_left[:, ::-1]
            bands = bands[::-1]
        if rng.random() < 0.5:
            crop_left, crop_right, seen_left, seen_right = (a[::-1] for a in (crop_left, crop_right, seen_left,
                                                                              seen_right))
        views = [filled(view, seen) for view, seen in ((crop_left, seen_left), (crop_right, seen_right))]
        guides = np.stack([*(guide(view) for view in views), seen_left, seen_right]).astype(np.float32)
        return SelfSupCrop(left=network_input(views[0], kind), right=network_input(views[1], kind),
                           guides=np.ascontiguousarray(guides), bands=(str(bands[0]), str(bands[1])))


def filled(view: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """``view`` with its unseen pixels set to the median of the seen ones (float32, contiguous)."""
    value = np.float32(np.median(view[seen])) if seen.any() else np.float32(0)
    return np.ascontiguousarray(np.where(seen, view, value), dtype=np.float32)


def guide(view: np.ndarray) -> np.ndarray:
    """``view`` rescaled by its :data:`GUIDE_PERCENTILES` to about [0, 1] (clipped to [-0.5, 1.5])."""
    low, high = np.percentile(view, GUIDE_PERCENTILES)
    return np.clip((view - low) / max(float(high - low), 1e-6), -0.5, 1.5).astype(np.float32)
