"""What every matcher takes and returns, and the preprocessing they share."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.spectral import color_agnostic

Preprocess = Literal["auto", "none", "cade"]
PREPROCESS_CHOICES: tuple[str, ...] = ("auto", "none", "cade")
"""``cade``: color agnostic transform on both bands first; ``none``: bands as given;
``auto``: the matcher's own choice (:attr:`Matcher.best_preprocess`)."""


@dataclass(frozen=True)
class DisparityRange:
    """Inclusive integer search range: d in {minimum, ..., maximum}, in pixels.

    Disparity follows the data convention I_left(y, x) ~ I_right(y, x - d): positive
    for ordinary rectified pairs, of both signs for pairs pre-registered to a plane.
    """

    minimum: int
    maximum: int

    @property
    def count(self) -> int:
        return self.maximum - self.minimum + 1

    def check_for_width(self, width: int) -> None:
        """Raise :class:`CadeError` unless the range is usable on images ``width`` wide."""
        if self.maximum < self.minimum:
            raise CadeError(f"max disparity {self.maximum} is below min disparity {self.minimum}; raise --max-disp")
        if self.maximum <= 0:
            raise CadeError(f"max disparity must be > 0, got {self.maximum}")
        if self.maximum >= width or -self.minimum >= width:
            raise CadeError(
                f"disparity range [{self.minimum}, {self.maximum}] does not fit images {width} px wide; "
                f"keep |disparity| below the width"
            )


@dataclass(frozen=True)
class DisparityResult:
    """Output of a matcher for the left (reference) view.

    Attributes:
        disparity: (H, W) float32 in pixels of the input images, dense: pixels that
            failed validation are filled (from the background side along the row), so
            every value is finite.
        valid: (H, W) bool, False where the matcher rejected its own estimate
            (left-right inconsistency, outside the right view, ...).
    """

    disparity: np.ndarray
    valid: np.ndarray


Kernel = Callable[[np.ndarray, np.ndarray, DisparityRange], DisparityResult]


@dataclass(frozen=True)
class Matcher:
    """A named stereo matcher: preprocessing, checks, then its kernel.

    Calling it runs ``kernel(left, right, disparity_range)`` on the two bands, after
    the CADE transform when ``preprocess="cade"``.
    """

    name: str
    summary: str
    kernel: Kernel
    min_size: int = 3
    """Smallest image side the kernel can work with (its matching window)."""
    best_preprocess: str = "cade"
    """What ``preprocess="auto"`` means for this matcher: the more accurate of
    ``none`` / ``cade`` on the cross-spectral benchmark (benchmarks/cross_spectral.py)."""
    accepts_raw: bool = True
    """False for matchers that only work on color-agnostic bands (the CADE network)."""
    transforms_itself: bool = False
    """True for kernels that need the raw bands besides their CADE transform (the CADE
    network refines its estimate on the raw bands): they get the raw bands and apply the
    transform themselves where ``preprocess`` resolves to ``"cade"``."""
    volume_bytes: int = 20
    """Bytes the kernel holds per pixel and searched disparity (0: memory does not grow
    with the range); :func:`cade_cli.stereo.estimate_disparity` refuses requests beyond
    its limit."""

    def resolve_preprocess(self, preprocess: str) -> str:
        """``preprocess`` with ``"auto"`` replaced by this matcher's choice."""
        if preprocess not in PREPROCESS_CHOICES:
            raise CadeError(f"unknown preprocess {preprocess!r}; choose one of {', '.join(PREPROCESS_CHOICES)}")
        resolved = self.best_preprocess if preprocess == "auto" else preprocess
        if resolved == "none" and not self.accepts_raw:
            raise CadeError(f"method {self.name} works on color-agnostic bands only; use --preprocess cade or auto")
        return resolved

    def __call__(
        self,
        left: np.ndarray,
        right: np.ndarray,
        *,
        max_disp: int,
        min_disp: int = 0,
        preprocess: Preprocess = "auto",
    ) -> DisparityResult:
        """Disparity of ``left`` against ``right``.

        Args:
            left, right: (H, W) float bands of the same shape (any intensity units).
            max_disp, min_disp: inclusive search range in pixels.
            preprocess: ``"cade"`` (color agnostic transform on both bands), ``"none"``,
                or ``"auto"`` (:attr:`best_preprocess`).
        """
        left, right = check_pair(left, right, min_size=self.min_size)
        disparity_range = DisparityRange(int(min_disp), int(max_disp))
        disparity_range.check_for_width(left.shape[1])
        if self.resolve_preprocess(preprocess) == "cade" and not self.transforms_itself:
            left, right = color_agnostic(left), color_agnostic(right)
        return self.kernel(left, right, disparity_range)


def check_pair(left: np.ndarray, right: np.ndarray, *, min_size: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate a stereo pair of single bands and return them as float32."""
    left, right = np.asarray(left), np.asarray(right)
    for name, band in (("left", left), ("right", right)):
        if band.ndim != 2:
            raise CadeError(f"{name} image must be one band of shape (H, W), got shape {band.shape}; pick a band")
        if not np.isfinite(band).all():
            raise CadeError(f"{name} image contains NaN or infinite values")
    if left.shape != right.shape:
        raise CadeError(
            f"left and right images differ in size: {left.shape[1]}x{left.shape[0]} vs "
            f"{right.shape[1]}x{right.shape[0]}; rectify or crop them to the same size"
        )
    if min(left.shape) < min_size:
        raise CadeError(
            f"images {left.shape[1]}x{left.shape[0]} are smaller than the {min_size}x{min_size} matching window"
        )
    return left.astype(np.float32, copy=False), right.astype(np.float32, copy=False)
