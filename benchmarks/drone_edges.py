"""Edge crops for benchmarks/drone_alignment.py (``--edge-crops``): where a capture's registration
is worst on the reference band's strong edges, the reference band beside each compared method's
registered band as a false-colour overlay, so the methods' residual misregistration shows as
colour fringes side by side.

The rule that picks the places (:func:`pick_edge_windows`), deterministic:
  1. the windows are the residual measure's own (cade_cli.capture.alignment.window_shifts: 64 px
     on a 64 px grid, the same for every method and band);
  2. a window has strong edges where the mean of the reference band's gradient image
     (cade_cli.capture.homography.gradient_magnitude) over it is at least the
     :data:`EDGE_QUANTILE` quantile of all the windows' means;
  3. among those, over every registered band, each (band, window) is ranked by the largest
     residual shift any compared method leaves there (windows no method could score are left
     out); ties go to the band listed first, then the smaller row, then the smaller column;
  4. the crops are taken down that ranking, skipping a window whose crop would overlap one
     already taken (centres closer than the crop's side on both axes), until ``count`` are taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cade_cli.capture.alignment import WINDOW, WindowShifts
from cade_cli.capture.homography import gradient_magnitude

EDGE_CROP = 176
"""Side, px, of an edge crop (full resolution, one panel)."""
EDGE_QUANTILE = 0.5
"""A window has strong edges where its mean reference gradient reaches this quantile of the
windows' means (the upper half)."""
LEVELS = 16
"""Grey levels kept per channel in the pictures: fringes stay visible and a picture stays near
50 KB (six bench crops with 32 levels: 485 KB; with 16: 318 KB)."""
LABEL = 14
"""Height, px, of the strip above each panel that names it."""


@dataclass(frozen=True)
class EdgePlace:
    """One picked crop: the band, the window's centre (row, column, reference px), the window's
    mean reference gradient, and each method's residual shift there (px, NaN: not scored)."""

    band: str
    row: int
    column: int
    edge: float
    residuals: dict[str, float]


def window_edge_strength(reference: np.ndarray, centres: np.ndarray, *, window: int = WINDOW) -> np.ndarray:
    """(N,) mean of the reference's gradient image over each ``window`` px window centred at
    ``centres`` ((N, 2) row, column, as :class:`WindowShifts` gives them)."""
    integral = cv2.integral(gradient_magnitude(reference).astype(np.float64))
    height, width = reference.shape
    tops = np.clip(np.rint(centres[:, 0] - (window - 1) / 2.0).astype(int), 0, height - window)
    lefts = np.clip(np.rint(centres[:, 1] - (window - 1) / 2.0).astype(int), 0, width - window)
    sums = (integral[tops + window, lefts + window] - integral[tops, lefts + window]
            - integral[tops + window, lefts] + integral[tops, lefts])
    return sums / float(window * window)


def pick_edge_windows(edge: np.ndarray, shifts: dict[str, dict[str, WindowShifts]], *, count: int,
                      crop: int = EDGE_CROP, quantile: float = EDGE_QUANTILE) -> list[EdgePlace]:
    """The ``count`` places of the module's rule.

    Args:
        edge: (N,) the windows' mean reference gradient (:func:`window_edge_strength`).
        shifts: band -> method -> :class:`WindowShifts` on those N windows (every method's the
            same grid); the bands in the order ties are broken.
        count: how many places at most.
        crop: side of a crop, px: picked centres are at least this far apart on one axis.
        quantile: of ``edge``, the least a window needs.
    """
    strong = edge >= np.quantile(edge, quantile)
    candidates = []  # (residual, band order, row, column, band)
    for order, (band, per_method) in enumerate(shifts.items()):
        magnitudes = np.stack([found.magnitudes for found in per_method.values()])
        scored = np.isfinite(magnitudes).any(axis=0)
        worst = np.where(scored, np.nanmax(np.where(np.isfinite(magnitudes), magnitudes, -np.inf), axis=0), np.nan)
        centres = next(iter(per_method.values())).centres
        for k in np.flatnonzero(strong & scored):
            candidates.append((-float(worst[k]), order, float(centres[k, 0]), float(centres[k, 1]), band, k))
    candidates.sort(key=lambda c: c[:4])
    picked: list[EdgePlace] = []
    for _, _, row, column, band, k in candidates:
        if len(picked) == count:
            break
        if any(abs(row - p.row) < crop and abs(column - p.column) < crop for p in picked):
            continue
        picked.append(EdgePlace(band, int(round(row)), int(round(column)), float(edge[k]),
                                {method: float(found.magnitudes[k]) for method, found in shifts[band].items()}))
    return picked


def _stretched(image: np.ndarray) -> np.ndarray:
    finite = np.isfinite(image)
    low, high = np.percentile(image[finite], [1, 99]) if finite.any() else (0.0, 1.0)
    return np.where(finite, np.clip((image - low) / max(high - low, 1e-6), 0, 1), 0)


def _labelled(panel: np.ndarray, text: str) -> np.ndarray:
    strip = np.zeros((LABEL, panel.shape[1], 3), np.uint8)
    cv2.putText(strip, text, (3, LABEL - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (255, 255, 255), 1, cv2.LINE_AA)
    return np.vstack([strip, panel])


def edge_picture(reference: np.ndarray, bands: dict[str, np.ndarray], place: EdgePlace, overlay, *,
                 crop: int = EDGE_CROP) -> np.ndarray:
    """BGR uint8: the reference band's crop in grey, then ``overlay(reference, band)`` of each
    method's band (``bands``: method -> its registered band), side by side, each under its label
    (with its residual there), quantised to :data:`LEVELS` levels."""
    height, width = reference.shape
    top = int(np.clip(place.row - crop // 2, 0, height - crop))
    left = int(np.clip(place.column - crop // 2, 0, width - crop))
    window = (slice(top, top + crop), slice(left, left + crop))
    grey = (_stretched(reference[window]) * 255).astype(np.uint8)
    panels = [_labelled(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), "reference")]
    for method, band in bands.items():
        residual = place.residuals.get(method, float("nan"))
        shown = method.removeprefix("cade:") + (f" {residual:.1f}px" if np.isfinite(residual) else " n/a")
        panels.append(_labelled(overlay(reference[window], band[window]), shown))
    gap = np.full((crop + LABEL, 2, 3), 255, np.uint8)
    picture = np.hstack([part for panel in panels for part in (panel, gap)][:-1])
    step = 256 // LEVELS
    return (picture // step * step + step // 2 * (picture > 0)).astype(np.uint8)


def write_edge_crops(folder: Path, name: str, reference: np.ndarray, registered: dict[str, dict[str, np.ndarray]],
                     shifts: dict[str, dict[str, WindowShifts]], overlay, *,
                     count: int) -> list[tuple[Path, EdgePlace]]:
    """:func:`pick_edge_windows`' ``count`` places of one capture, each as
    ``<capture>-edges-<k>-<band>.png`` (:func:`edge_picture`); ``registered``: method -> band ->
    image; ``shifts``: band -> method -> its residual shifts."""
    if not shifts:
        return []
    centres = next(iter(next(iter(shifts.values())).values())).centres
    places = pick_edge_windows(window_edge_strength(reference, centres), shifts, count=count)
    written = []
    for k, place in enumerate(places, 1):
        bands = {method: images[place.band] for method, images in registered.items() if place.band in images}
        path = folder / f"{name.replace('/', '-')}-edges-{k}-{place.band.replace(' ', '')}.png"
        cv2.imwrite(str(path), edge_picture(reference, bands, place, overlay), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        written.append((path, place))
    return written


def same_registration(registered: dict[str, dict[str, np.ndarray]]) -> bool:
    """Whether every method (method -> band -> image) registered every band to the same values
    (NaN equal to NaN): a capture whose crops would show nothing to compare."""
    first, *others = registered.values()
    return all(other.keys() == first.keys() and all(np.array_equal(other[band], first[band], equal_nan=True)
                                                    for band in first) for other in others)


def edge_table(crops: dict[str, list[tuple[Path, EdgePlace]] | None], methods: list[str]) -> str:
    """Markdown: a row per edge crop: its file, place, reference edge strength and each method's
    residual shift there (px, n/a: the window was not scored); a capture of None (every method
    registered it alike, :func:`same_registration`) has one row that says so."""
    header = ["capture", "crop", "band", "centre (row, column)", "edge", *[f"{m} px" for m in methods]]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for capture, written in crops.items():
        if written is None:
            lines.append("| " + " | ".join([capture, "none: every method registered it alike", "", "", "",
                                            *[""] * len(methods)]) + " |")
        for path, place in written or []:
            residuals = [f"{place.residuals[m]:.2f}" if np.isfinite(place.residuals.get(m, np.nan)) else "n/a"
                         for m in methods]
            lines.append("| " + " | ".join([capture, path.name, place.band, f"({place.row}, {place.column})",
                                            f"{place.edge:.3f}", *residuals]) + " |")
    return "\n".join(lines)
