"""Pictures for people: a map in false colour, with its scale bar and legend drawn into the image.

Every picture ``cade`` writes for looking at (``--vis`` of a disparity, the benchmark's
error maps, ``register --vis``) goes through :func:`with_legend`, which appends a white
panel under the picture: a colour bar with its values and caption, then one swatch per
colour that means something else (black = invalid, ...). Drawn with OpenCV only; text is
ASCII (OpenCV's Hershey fonts have no other glyphs).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.errors import CadeError

INVALID_COLOUR: tuple[int, int, int] = (0, 0, 0)
"""BGR of the pixels a map has no value for (invalid, rejected): black, which no colormap
used here starts with (Turbo's low end is dark blue)."""
PANEL_COLOUR = (255, 255, 255)
TEXT_COLOUR = (40, 40, 40)
MIN_WIDTH = 360
"""Narrower pictures get a wider panel (the map is padded on the right), so the text fits."""
ROBUST_PERCENTILES: tuple[float, float] = (1.0, 99.0)
"""Default colour range of a map: these percentiles of its valid values, so that a few
outliers (a 107 px mismatch, a sky at 0 px) do not squeeze the rest into one colour."""
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class ColourBar:
    """The colour bar of a picture: ``colormap`` (a ``cv2.COLORMAP_*``) runs from ``low``
    to ``high`` (the map's units); ``caption`` says what and which units, under the bar."""

    colormap: int
    low: float
    high: float
    caption: str


@dataclass(frozen=True)
class Swatch:
    """A legend entry: a square of ``colour`` (B, G, R) and what it means."""

    colour: tuple[int, int, int]
    label: str


def robust_range(values: np.ndarray, *, percentiles: tuple[float, float] = ROBUST_PERCENTILES) -> tuple[float, float]:
    """The (low, high) percentiles of the finite ``values``; (0, 0) when there is none."""
    finite = np.asarray(values, np.float64)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return 0.0, 0.0
    low, high = np.percentile(finite, percentiles)
    return float(low), float(high)


def parse_value_range(text: str, *, option: str = "--vis-range") -> tuple[float, float]:
    """``MIN:MAX`` (two finite numbers, MIN < MAX; either may be negative) as (min, max).

    Raises:
        CadeError: anything else, naming ``option`` and an example.
    """
    parts = str(text).split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        low, high = float(parts[0]), float(parts[1])
    except ValueError:
        raise CadeError(f"{option} must be MIN:MAX, two numbers like 0:80, got {text!r}") from None
    if not (np.isfinite(low) and np.isfinite(high)):
        raise CadeError(f"{option} must be two finite numbers like 0:80, got {text!r}")
    if low >= high:
        raise CadeError(f"{option} {text}: MIN must be below MAX, like 0:80")
    return low, high


def colour_map(values: np.ndarray, *, colormap: int, low: float, high: float,
               missing: tuple[int, int, int] = INVALID_COLOUR) -> np.ndarray:
    """Colour an (H, W) map: ``low`` gets the colormap's first colour, ``high`` its last,
    values beyond are clipped to the end colours, non-finite values get ``missing``.

    With an empty range (``low == high``) values above it get the high end's colour and
    the rest the low end's. Returns (H, W, 3) uint8, B, G, R (ready for ``cv2.imwrite``).
    """
    values = np.asarray(values)
    valid = np.isfinite(values)
    span = high - low
    scaled = np.zeros(values.shape, dtype=np.float64)
    if span > 0:
        scaled[valid] = np.clip((values[valid] - low) / span, 0.0, 1.0)
    else:
        scaled[valid] = values[valid] > low
    coloured = cv2.applyColorMap(np.rint(scaled * 255.0).astype(np.uint8), colormap)
    coloured[~valid] = missing
    return coloured


def format_value(value: float, span: float) -> str:
    """``value`` with the decimals that tell apart the quarters of a range of ``span``."""
    span = abs(span)
    decimals = 0 if span >= 40 else 1 if span >= 4 or span == 0 else 2 if span >= 0.4 else 3
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text  # no "-0.0"


def nice_ticks(low: float, high: float, *, count: int = 6) -> list[tuple[float, str]]:
    """Round values from ``low`` to ``high``, steps of 1, 2, 2.5 or 5 times a power of ten
    and at most ``count`` steps, with their labels; just ``low`` for an empty range."""
    span = high - low
    if not span > 0:
        return [(low, format_value(low, 0.0))]
    raw = span / max(count, 1)
    power = int(np.floor(np.log10(raw)))
    magnitude = 10.0 ** power
    multiple = next(m for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * magnitude >= raw * (1 - 1e-9))
    step = multiple * magnitude
    decimals = max(0, -power + (1 if multiple == 2.5 else 0))
    first = np.ceil(low / step - 1e-9) * step
    values = first + step * np.arange(int(np.floor((high - first) / step + 1e-9)) + 1)
    labels = [f"{value:.{decimals}f}" for value in values]
    return [(float(value), label[1:] if label.startswith("-") and float(label) == 0 else label)
            for value, label in zip(values, labels)]


def with_legend(picture: np.ndarray, *, bar: ColourBar | None = None, swatches: Sequence[Swatch] = (),
                lines: Sequence[str] = ()) -> np.ndarray:
    """``picture`` with a legend panel appended below it (a new array; ``picture`` is kept).

    The panel holds, in order: the colour ``bar`` (its ramp, five values under it and its
    caption), the ``lines`` of text, and the ``swatches``. It is as wide as the picture,
    or :data:`MIN_WIDTH` (the picture is then padded on the right); text sizes follow the
    width, and text too long for one line is wrapped between words.

    Args:
        picture: (H, W, 3) uint8, B, G, R.

    Returns:
        (H + panel, max(W, MIN_WIDTH), 3) uint8; ``result[:H, :W]`` equals ``picture``.
    """
    picture = np.asarray(picture)
    if picture.ndim != 3 or picture.shape[2] != 3 or picture.dtype != np.uint8:
        raise ValueError(f"a picture must be (H, W, 3) uint8, got {picture.dtype} of shape {picture.shape}")
    height, width = picture.shape[:2]
    canvas_width = max(width, MIN_WIDTH)
    style = _Style.for_width(canvas_width)
    panel = _Panel(canvas_width, style)
    if bar is not None:
        panel.colour_bar(bar)
    for line in lines:
        panel.text(line)
    if swatches:
        panel.swatches(swatches)
    drawn = panel.render()
    out = np.full((height + drawn.shape[0], canvas_width, 3), PANEL_COLOUR, np.uint8)
    out[:height, :width] = picture
    out[height:] = drawn
    return out


def scaled_picture(values: np.ndarray, bar: ColourBar, *, swatches: Sequence[Swatch] = (),
                   missing: tuple[int, int, int] = INVALID_COLOUR) -> np.ndarray:
    """An (H, W) map coloured by ``bar`` (:func:`colour_map`) with the bar and ``swatches``
    drawn under it (:func:`with_legend`)."""
    coloured = colour_map(values, colormap=bar.colormap, low=bar.low, high=bar.high, missing=missing)
    return with_legend(coloured, bar=bar, swatches=swatches)


# ---------------------------------------------------------------- drawing


@dataclass(frozen=True)
class _Style:
    scale: float      # font scale
    thickness: int    # text stroke, px
    unit: int         # bar height and line spacing unit, px

    @classmethod
    def for_width(cls, width: int) -> "_Style":
        scale = float(np.clip(width / 1400.0, 0.45, 2.0))
        return cls(scale=scale, thickness=1 if scale < 1.0 else 2, unit=int(round(22 * scale)))

    def size(self, text: str) -> tuple[int, int, int]:
        (w, h), baseline = cv2.getTextSize(text, _FONT, self.scale, self.thickness)
        return w, h, baseline


class _Panel:
    """Rows of drawing commands stacked top to bottom, rendered onto one white strip."""

    def __init__(self, width: int, style: _Style) -> None:
        self.width, self.style = width, style
        self.margin = max(6, style.unit // 2)
        self.y = self.margin
        self.ops: list = []

    def _put(self, text: str, x: int, baseline_y: int) -> None:
        self.ops.append(lambda image: cv2.putText(image, text, (x, baseline_y), _FONT, self.style.scale, TEXT_COLOUR,
                                                  self.style.thickness, cv2.LINE_AA))

    def text(self, line: str) -> None:
        for piece in self._wrap(line, self.width - 2 * self.margin):
            _, h, baseline = self.style.size(piece)
            self._put(piece, self.margin, self.y + h)
            self.y += h + baseline + self.margin // 2

    def _wrap(self, line: str, room: int) -> list[str]:
        """``line`` cut into pieces of at most ``room`` px, between words, after a "; " where one fits."""
        pieces, current = [], ""
        for clause in line.split("; "):
            if current and self.style.size(f"{current}; {clause}")[0] <= room:
                current = f"{current}; {clause}"
                continue
            if current:
                pieces.append(current + ";")
                current = ""
            for word in clause.split(" "):
                candidate = f"{current} {word}" if current else word
                if current and self.style.size(candidate)[0] > room:
                    pieces.append(current)
                    current = word
                else:
                    current = candidate
        pieces.append(current)
        return pieces

    def colour_bar(self, bar: ColourBar) -> None:
        left, right = self.margin, self.width - self.margin
        top, bottom = self.y, self.y + self.style.unit
        ramp = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None, :], bar.colormap)  # (1, 256, 3)
        strip = cv2.resize(ramp, (right - left, bottom - top), interpolation=cv2.INTER_NEAREST)

        def draw_ramp(image: np.ndarray) -> None:
            image[top:bottom, left:right] = strip
            cv2.rectangle(image, (left - 1, top - 1), (right, bottom), TEXT_COLOUR, 1)

        self.ops.append(draw_ramp)
        tick = max(3, self.style.unit // 4)
        ticks = nice_ticks(bar.low, bar.high)
        if sum(self.style.size(label)[0] for _, label in ticks) * 1.5 > right - left:  # crowded
            ticks = nice_ticks(bar.low, bar.high, count=2)
        label_height = max(self.style.size(label)[1] for _, label in ticks)
        span = bar.high - bar.low
        drawn_until = left - self.margin  # right end of the last label, so that none overlap
        for value, label in ticks:
            x = int(round(left + (value - bar.low) / span * (right - left - 1))) if span > 0 else left
            w = self.style.size(label)[0]
            start = min(max(x - w // 2, left), right - w)
            if start < drawn_until + self.margin:
                continue
            drawn_until = start + w
            self.ops.append(lambda image, x=x: cv2.line(image, (x, bottom), (x, bottom + tick), TEXT_COLOUR, 1))
            self._put(label, start, bottom + tick + 2 + label_height)
        self.y = bottom + tick + 2 + label_height + self.margin
        self.text(bar.caption)

    def swatches(self, swatches: Sequence[Swatch]) -> None:
        _, h, baseline = self.style.size("Ag")
        side = h + baseline
        x, room = self.margin, self.width - self.margin
        for swatch in swatches:
            w = self.style.size(swatch.label)[0]
            needed = side + self.margin // 2 + w
            if x > self.margin and x + needed > room:  # next line
                x, self.y = self.margin, self.y + side + self.margin // 2
            top, origin = self.y, x

            def draw_square(image: np.ndarray, top=top, origin=origin, colour=swatch.colour) -> None:
                cv2.rectangle(image, (origin, top), (origin + side, top + side), colour, -1)
                cv2.rectangle(image, (origin, top), (origin + side, top + side), (150, 150, 150), 1)

            self.ops.append(draw_square)
            self._put(swatch.label, origin + side + self.margin // 2, top + h)
            x += needed + 2 * self.margin
        self.y += side + self.margin // 2

    def render(self) -> np.ndarray:
        image = np.full((self.y + self.margin // 2, self.width, 3), PANEL_COLOUR, np.uint8)
        for op in self.ops:
            op(image)
        return image
