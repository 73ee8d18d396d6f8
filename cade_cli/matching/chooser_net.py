"""A learned choice with context: a small convolutional network decides, per pixel, between the network's disparity
and the rank-SGBM match (Accuracy V, docs/research/refinement.md, 2026-12-07, "a chooser that sees around the pixel").

:class:`~cade_cli.matching.chooser.Chooser` weighs each pixel's features alone. At a depth edge the right candidate
depends on where the pixel lies relative to the image's edge and to the two maps' jumps around it, which a
per-pixel perceptron sees only through a few box statistics. :class:`ChooserNet` reads the same feature planes over
the whole image (:func:`~cade_cli.matching.chooser.chooser_features`, without the bias) and the left band's
colour-agnostic transform, and gives P(SGBM's match is the better one) per pixel from a few dilated 3 x 3
convolutions (about 35 px of context). It is an ONNX file beside the model's card, pinned by its sha256 there
(``chooser: {"kind": "network", "file", "sha256", "planes", "threshold"}``), fitted by
``python -m cade_cli.train chooser --context`` on the real training scenes and run with onnxruntime.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.chooser import FEATURES, Chooser, chooser_features, disputed, logistic
from cade_cli.matching.network import onnx_session, strips
from cade_cli.spectral import network_input

PLANES = (*FEATURES[:-1], "band")
"""The network's input planes, in order: the perceptron's features without its bias, then the left band's
colour-agnostic transform (``band``)."""
KIND = "network"
"""A card's ``chooser.kind`` for this chooser (the perceptron's cards have none)."""
STRIP_PIXELS = 1_000_000
"""Largest strip (pixels) given to the network at once: its activations are 24 float32 planes of it."""
STRIP_OVERLAP = 96
"""Rows shared by neighbouring strips: each kept row sees half of them on its strip's side, at least the network's
reach (17 px, or 33 px with ``--context-dilations 1,2,4,8,16,1``), so that it sees all it would see in one run."""


def chooser_planes(left: np.ndarray, network: np.ndarray, uncertainty: np.ndarray, candidate: np.ndarray,
                   accepted: np.ndarray) -> np.ndarray:
    """(len(PLANES), H, W) float32: the network's input (:data:`PLANES`) for one pair; the arguments as
    :func:`~cade_cli.matching.chooser.chooser_features` takes them."""
    features = chooser_features(left, network, uncertainty, candidate, accepted)[..., :-1]
    band = network_input(np.asarray(left, np.float32), "cade")
    return np.concatenate([np.moveaxis(features, -1, 0), band[None]], axis=0).astype(np.float32)


@dataclass(frozen=True)
class ChooserNet:
    """The convolutional chooser: ``path`` (its ONNX file, input ``planes`` (1, P, H, W), output ``logit``
    (1, 1, H, W)), pinned by ``sha256``; SGBM's match is taken where the probability exceeds ``threshold``."""

    path: Path
    sha256: str
    threshold: float = 0.5
    planes: tuple[str, ...] = PLANES

    @classmethod
    def from_dict(cls, values: dict, folder: Path) -> "ChooserNet":
        """The chooser a card describes; ``folder``: where the card (and so the file) lies."""
        planes = tuple(values.get("planes", PLANES))
        if planes != PLANES:
            raise ValueError(f"a network chooser's planes must be {list(PLANES)}; got {list(planes)}")
        return cls(folder / values["file"], str(values["sha256"]), float(values.get("threshold", 0.5)), planes)

    def to_dict(self) -> dict:
        return {"kind": KIND, "file": self.path.name, "sha256": self.sha256, "planes": list(self.planes),
                "threshold": self.threshold}

    def probability(self, planes: np.ndarray) -> np.ndarray:
        """(H, W) float32 probability from :func:`chooser_planes`' (P, H, W), in row strips (each run on
        :data:`STRIP_OVERLAP` more rows than it keeps, so the strips add up to one run's result)."""
        session = onnx_session(self.path, self.sha256)
        _, height, width = planes.shape
        logits = np.empty((height, width), np.float32)
        for start, stop, keep_start, keep_stop in strips(height, width, max_pixels=STRIP_PIXELS,
                                                         overlap=STRIP_OVERLAP, divisor=1):
            (out,) = session.run(["logit"], {"planes": np.ascontiguousarray(planes[None, :, start:stop])})
            logits[keep_start:keep_stop] = out[0, 0, keep_start - start:keep_stop - start]
        return logistic(logits)

    def take(self, left: np.ndarray, network: np.ndarray, uncertainty: np.ndarray, candidate: np.ndarray,
             accepted: np.ndarray) -> np.ndarray:
        """(H, W) bool: where SGBM's accepted match replaces the network's value, as
        :meth:`~cade_cli.matching.chooser.Chooser.take` says (the agreeing matches, and the disputed pixels the
        network gives to SGBM)."""
        taken = accepted.astype(bool).copy()
        asked = disputed(network, candidate, accepted)
        if asked.any():
            probability = self.probability(chooser_planes(left, network, uncertainty, candidate, accepted))
            taken[asked] = probability[asked] > self.threshold
        return taken


def load_chooser(values: dict, folder: Path) -> Chooser | ChooserNet:
    """The chooser a card's ``chooser`` object describes: the perceptron (no ``kind``, or ``perceptron``) or
    :class:`ChooserNet` (``kind`` ``network``, its file in ``folder``, where the card lies).

    Raises:
        CadeError: an unknown kind or malformed weights (one line naming the fix)."""
    kind = values.get("kind", "perceptron")
    try:
        if kind == "perceptron":
            return Chooser.from_dict(values)
        if kind == KIND:
            return ChooserNet.from_dict(values, folder)
        raise ValueError(f"kind {kind!r} is not one of perceptron, {KIND}")
    except (ValueError, KeyError, TypeError) as error:
        raise CadeError(f"the model card's chooser is malformed ({error}); refit it with "
                        f"python -m cade_cli.train chooser --write-card") from None
