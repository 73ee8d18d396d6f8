"""A learned choice between the network's disparity and the rank-SGBM match, per pixel.

:class:`~cade_cli.matching.refinement.RankSgbmRefinement` takes SGBM's match wherever SGBM
accepted it and it lies within a fixed 32 px of the network's value. :class:`Chooser`
replaces that rule by a small per-pixel perceptron over features both candidates give
(their difference, the network's uncertainty, how much the neighbourhood agrees, how
speckled each map is, how much texture the band has); it is fitted on real training
scenes by ``python -m cade_cli.train chooser`` (the Accuracy II lever; the model card in
docs/research/refinement.md records what it measured).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cade_cli.matching.side_by_side import side_by_side

FEATURES = (
    "difference", "signed_difference", "log_difference", "uncertainty", "accepted_share", "candidate_spread", "candidate_speckle",
    "network_spread", "texture", "agreement_near", "agreement_wide", "bias",
)
"""The per-pixel inputs of the chooser, in order (:func:`chooser_features`)."""
EDGE_FEATURES = ("network_jump", "network_side", "candidate_side")
"""Optional inputs (``train chooser --edge-features``, 2026-12-07): the network's local jump (its highest
minus its lowest value in a 9 x 9 window) and where the network's value and SGBM's match lie between those two
(0: the lower surface, 1: the higher), so that a choice at a depth edge can tell a match that took the
neighbouring surface. A card's chooser names its inputs; one without these computes what it did."""
WINDOW = 9
"""Side of the window of :data:`EDGE_FEATURES`' lowest and highest network values."""
AGREE = 1.0
"""Where SGBM's accepted match lies within this many px of the network's value, it is taken
without asking the chooser (the two agree; the match is the sharper, sub-pixel one): the
chooser decides only the disputed pixels, a third of the accepted ones on Middlebury."""


ROWS = 2048
"""The perceptron's products run on blocks of this many rows, the last one padded with zeros:
OpenCV's ``gemm`` rounds a row by where it lies in the block and how many rows follow it (on
an AMD EPYC VM, rows of a 10,000-row half came out otherwise than the same rows of the
20,001-row whole: docs/research/refinement.md, 2026-11-28), so a row's probability is reproducible only
at the same place in a block of the same size. :meth:`Chooser.take` splits its rows at a
multiple of this."""


def _aligned(rows: int, columns: int) -> np.ndarray:
    """A zeroed (rows, columns) float32 array whose data starts on a 64-byte boundary, so that
    every block's product reads its rows at the same alignment."""
    size = rows * columns
    buffer = np.zeros(size + 16, np.float32)
    start = (-buffer.ctypes.data % 64) // 4
    return buffer[start:start + size].reshape(rows, columns)


def logistic(logits: np.ndarray) -> np.ndarray:
    """float32 probability of each logit (clipped to +-30, where float32's exponential stays finite)."""
    return (1 / (1 + np.exp(-np.clip(logits, -30, 30)))).astype(np.float32)


def _box(image: np.ndarray, side: int) -> np.ndarray:
    return cv2.blur(image.astype(np.float32), (side, side), borderType=cv2.BORDER_REFLECT)


def _moments(image: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """The box means of ``image`` and of its square (the spread is taken per pixel later)."""
    image = image.astype(np.float32)
    return _box(image, side), _box(image * image, side)


def _spread(moments: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    mean, square = moments
    return np.sqrt(np.maximum(square - mean * mean, 0))


def disputed(network: np.ndarray, candidate: np.ndarray, accepted: np.ndarray) -> np.ndarray:
    """(H, W) bool: accepted matches more than :data:`AGREE` px from the network's value."""
    return accepted.astype(bool) & (np.abs(candidate - network) > AGREE)


def chooser_features(left: np.ndarray, network: np.ndarray, uncertainty: np.ndarray, candidate: np.ndarray,
                     accepted: np.ndarray, *, where: np.ndarray | None = None,
                     names: tuple[str, ...] = FEATURES) -> np.ndarray:
    """(H, W, len(names)) float32 features of each pixel (``names``: :data:`FEATURES`, the bias last,
    with :data:`EDGE_FEATURES` before it or not), or (N, len(names)) of the N pixels of the (H, W)
    bool mask ``where``.

    Neighbourhood statistics (box means, the median) need whole images; everything
    per-pixel after them is computed at the ``where`` pixels only (the same values, a third
    of the chooser's time on a Middlebury pair).

    Args:
        left: (H, W) raw left band, any units (only its local contrast relative to its
            image-wide spread is used).
        network, uncertainty: the network's (H, W) disparity and uncertainty, px.
        candidate, accepted: SGBM's (H, W) match (px) and where SGBM accepted it.
    """
    if where is None:
        def pick(image):
            return np.asarray(image)
    else:
        index = np.flatnonzero(where)

        def pick(image):
            return np.asarray(image).ravel()[index]
    accepted = accepted.astype(bool)

    def with_match():  # the statistics SGBM's match enters, beside the others (about half the work each)
        difference = np.where(accepted, np.abs(candidate - network), 0).astype(np.float32)
        agree = (accepted & (difference <= 3)).astype(np.float32)
        held = np.where(accepted, candidate, network).astype(np.float32)
        return (pick(difference), pick(held), pick(cv2.medianBlur(held, 5)), [pick(m) for m in _moments(held, 5)],
                pick(_box(agree, 9)), pick(_box(agree, 31)))

    def without_match():
        band = left.astype(np.float32)
        return (pick(_box(accepted, 9)), [pick(m) for m in _moments(network, 5)],
                [pick(m) for m in _moments(band, 7)], max(float(band.std()), 1e-6))

    ((picked_difference, picked_held, picked_median, held_moments, agree_near, agree_wide),
     (accepted_share, network_moments, band_moments, band_spread)) = side_by_side(with_match, without_match)
    planes = {
        "difference": np.minimum(picked_difference, 64) / 32,
        "signed_difference": np.clip(np.where(pick(accepted), pick(candidate) - pick(network), 0), -64, 64) / 32,
        "log_difference": np.log1p(picked_difference),
        "uncertainty": np.minimum(pick(uncertainty), 32) / 8,
        "accepted_share": accepted_share,
        "candidate_spread": np.minimum(_spread(held_moments), 32) / 8,
        "candidate_speckle": np.minimum(np.abs(picked_held - picked_median), 32) / 8,
        "network_spread": np.minimum(_spread(network_moments), 32) / 8,
        "texture": np.minimum(_spread(band_moments) / band_spread, 4),
        "agreement_near": agree_near,
        "agreement_wide": agree_wide,
        "bias": np.ones_like(picked_held),
    }
    if any(name in EDGE_FEATURES for name in names):
        kernel = np.ones((WINDOW, WINDOW), np.uint8)
        network32 = np.asarray(network, np.float32)
        low, high = pick(cv2.erode(network32, kernel)), pick(cv2.dilate(network32, kernel))
        jump = np.maximum(high - low, 1.0)  # a flat window: both sides read 0 .. 1 around its value
        planes.update(network_jump=np.minimum(high - low, 64) / 32,
                      network_side=np.clip((pick(network32) - low) / jump, 0, 1),
                      candidate_side=np.clip((np.where(pick(accepted), pick(candidate), pick(network32)) - low) / jump,
                                             -0.5, 1.5))
    return np.stack([np.asarray(planes[name], np.float32) for name in names], axis=-1)


@dataclass(frozen=True)
class Chooser:
    """A one-hidden-layer perceptron: P(SGBM's match is the better one) per pixel.

    Attributes:
        hidden: (len(features), n) weights of the hidden layer (its bias is the last feature).
        output: (n + 1,) weights of the output (last: bias).
        threshold: the match is taken where the probability exceeds this.
        features: its inputs, in order (:data:`FEATURES`, or with :data:`EDGE_FEATURES` before the bias).
    """

    hidden: np.ndarray
    output: np.ndarray
    threshold: float = 0.5
    features: tuple[str, ...] = FEATURES

    @classmethod
    def from_dict(cls, values: dict) -> "Chooser":
        features = tuple(values.get("features", FEATURES))
        unknown = set(features) - set(FEATURES) - set(EDGE_FEATURES)
        if unknown or features[-1] != "bias" or len(features) != len(values["hidden"]):
            raise ValueError(f"a chooser's features must be known ones, the bias last, one row of weights each; "
                             f"got {list(features)}")
        return cls(np.asarray(values["hidden"], np.float32), np.asarray(values["output"], np.float32),
                   float(values.get("threshold", 0.5)), features)

    def to_dict(self) -> dict:
        return {"features": list(self.features), "hidden": self.hidden.tolist(), "output": self.output.tolist(),
                "threshold": self.threshold}

    def probability(self, features: np.ndarray) -> np.ndarray:
        """float32 probability from features (..., F): one per pixel; each row's value depends
        only on the row and its place in its block of :data:`ROWS` rows.

        The products are OpenCV's ``gemm``, not NumPy's ``@``: a BLAS call leaves
        OpenBLAS's threads busy-waiting on the cores the next pair's network and SGBM need
        (:func:`cade_cli.matching.refinement.correlation` says the same)."""
        count = features.shape[-1]
        flat = features.reshape(-1, count)
        logits = np.empty(flat.shape[0], np.float32)
        block, hidden, out = _aligned(ROWS, count), _aligned(ROWS, self.hidden.shape[1]), _aligned(ROWS, 1)
        for start in range(0, flat.shape[0], ROWS):
            rows = flat[start:start + ROWS]
            block[:len(rows)], block[len(rows):] = rows, 0
            cv2.gemm(block, self.hidden, 1.0, None, 0.0, dst=hidden)
            np.maximum(hidden, 0, out=hidden)
            cv2.gemm(hidden, self.output[:-1, None], 1.0, None, 0.0, dst=out)
            logits[start:start + len(rows)] = out[:len(rows), 0]
        logits += self.output[-1]
        return logistic(logits).reshape(features.shape[:-1])

    @staticmethod
    def split(rows: int) -> int:
        """Where :meth:`take` cuts ``rows`` rows in two for its two threads: about halfway, at a
        multiple of :data:`ROWS`, so that both halves' blocks are the whole's."""
        return min(rows, -(-rows // (2 * ROWS)) * ROWS)

    def take(self, left: np.ndarray, network: np.ndarray, uncertainty: np.ndarray, candidate: np.ndarray,
             accepted: np.ndarray, right: np.ndarray | None = None) -> np.ndarray:
        """(H, W) bool: where SGBM's accepted match replaces the network's value: where
        the two agree, and at the :func:`disputed` pixels the chooser gives to SGBM. ``right`` is not read (the
        convolutional chooser's evidence may read it)."""
        taken = accepted.astype(bool).copy()
        asked = disputed(network, candidate, accepted)
        features = chooser_features(left, network, uncertainty, candidate, accepted, where=asked, names=self.features)
        half = self.split(len(features))  # each row's products are the same whichever half holds it
        taken[asked] = np.concatenate(side_by_side(lambda: self.probability(features[:half]),
                                                   lambda: self.probability(features[half:]))) > self.threshold
        return taken
