"""What every matcher takes and returns, and the preprocessing they share."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.spectral import color_agnostic

Preprocess = Literal["auto", "none", "cade"]
PREPROCESS_CHOICES: tuple[str, ...] = ("auto", "none", "cade")
"""``cade``: the color agnostic transform (:func:`~cade_cli.spectral.color_agnostic`) on
both bands first; ``none``: bands as given; ``auto``: the matcher's own choice (the first
of :attr:`Matcher.preprocessing`)."""


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
        """Number of disparities searched."""
        return self.maximum - self.minimum + 1

    @property
    def span(self) -> int:
        """``maximum - minimum``, px."""
        return self.maximum - self.minimum

    def check_for_width(self, width: int) -> None:
        """Raise :class:`CadeError` unless the range is usable on images ``width`` wide."""
        if self.maximum < self.minimum:
            raise CadeError(f"max disparity {self.maximum} is below min disparity {self.minimum}; raise --max-disp "
                           "or lower --min-disp")
        if self.maximum == self.minimum:
            raise CadeError(f"disparity range [{self.minimum}, {self.maximum}] holds one value; give a --max-disp "
                           "above --min-disp")
        if self.maximum >= width or -self.minimum >= width:
            raise CadeError(
                f"disparity range [{self.minimum}, {self.maximum}] does not fit images {width} px wide; "
                f"keep |disparity| below the width"
            )


MARGIN_SHARE = 0.15
"""The margin added on each side of a range found at a coarse level: this share of the found span..."""
MARGIN_COARSE_PX = 2
"""...but at least this many coarse pixels (the coarse level's own uncertainty)."""


def range_margin(low: float, high: float, factor: int) -> float:
    """Margin (px) added to each side of the found range [low, high] (px) of a 1/``factor`` level:
    ``--max-disp auto`` (:mod:`cade_cli.scale.range`), the tiles' own ranges and the pair check's
    suggested range widen what they found by it."""
    return max(MARGIN_SHARE * (high - low), MARGIN_COARSE_PX * factor)


@dataclass(frozen=True)
class DisparityResult:
    """Output of a matcher for the left (reference) view.

    Attributes:
        disparity: (H, W) float32 in pixels of the input images, unfilled: NaN where
            ``valid`` is False (:func:`~cade_cli.matching.disparity.densify` is the one
            fill stage).
        valid: (H, W) bool, False where the matcher rejected its own estimate
            (left-right inconsistency, outside the right view, ...).
        confidence: (H, W) float32 in [0, 1], how far the matcher trusts each valid
            estimate (higher = more likely right; 0 exactly where ``valid`` is False), for
            masking what it is unsure of: keep ``confidence >= t``. Each matcher documents
            what it measures (:mod:`cade_cli.matching.confidence`); its values rank pixels
            within a map and are not calibrated probabilities. None when the kernel gives none.
    """

    disparity: np.ndarray
    valid: np.ndarray
    confidence: np.ndarray | None = None


Kernel = Callable[..., DisparityResult]
"""``kernel(left, right, disparity_range, *, preprocess) -> DisparityResult`` on (H, W)
float32 raw bands; ``preprocess`` is one of the matcher's :attr:`Matcher.preprocessing`."""


@dataclass(frozen=True)
class Matcher:
    """A named stereo matcher: input checks, then its kernel (a pipeline of stages).

    Calling it resolves ``preprocess`` and runs ``kernel(left, right, disparity_range,
    preprocess=...)``; each kernel applies its preprocessing stage itself
    (:func:`preprocessed`), so the CADE pipeline can give the network the transformed
    bands and its refinement the raw ones.
    """

    name: str
    summary: str
    kernel: Kernel
    min_size: int = 3
    """Smallest image side the kernel can work with (its matching window)."""
    preprocessing: tuple[str, ...] = ("cade", "none")
    """The ``preprocess`` values this matcher accepts; ``"auto"`` means the first, its more
    accurate one on the cross-spectral benchmark (benchmarks/cross_spectral.py)."""
    volume_bytes: int = 20
    """Bytes the kernel holds per pixel and searched disparity (0: memory does not grow
    with the range); :func:`cade_cli.stereo.estimate_disparity` refuses requests beyond
    its limit."""

    def resolve_preprocess(self, preprocess: str) -> str:
        """``preprocess`` with ``"auto"`` replaced by this matcher's choice."""
        if preprocess not in PREPROCESS_CHOICES:
            raise CadeError(f"unknown preprocess {preprocess!r}; choose one of {', '.join(PREPROCESS_CHOICES)}")
        resolved = self.preprocessing[0] if preprocess == "auto" else preprocess
        if resolved not in self.preprocessing:
            why = " (that input transform is part of its network, trained on such bands)" if len(
                self.preprocessing) == 1 else ""
            raise CadeError(f"method {self.name} takes --preprocess {' or '.join(self.preprocessing)} (or auto), "
                            f"not {resolved}{why}")
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
                or ``"auto"`` (the first of :attr:`preprocessing`).

        Returns:
            the unfilled :class:`DisparityResult` (NaN where invalid).
        """
        left, right = check_pair(left, right, min_size=self.min_size)
        disparity_range = DisparityRange(int(min_disp), int(max_disp))
        disparity_range.check_for_width(left.shape[1])
        return self.kernel(left, right, disparity_range, preprocess=self.resolve_preprocess(preprocess))


def preprocessed(left: np.ndarray, right: np.ndarray, preprocess: str) -> tuple[np.ndarray, np.ndarray]:
    """The preprocessing stage of the classical pipelines: both bands through
    :func:`~cade_cli.spectral.color_agnostic` for ``"cade"``, as given for ``"none"``."""
    if preprocess == "cade":
        return color_agnostic(left), color_agnostic(right)
    if preprocess == "none":
        return left, right
    raise CadeError(f"unknown preprocess {preprocess!r}; choose cade or none")


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
