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

With ``--match-evidence`` it also reads the right band's transform where each candidate puts the pixel's match, and
that times the left band's, both centred (:data:`MATCH_PLANES`): summed over a window, the second is the two bands'
local correlation at that candidate, the evidence the other planes lack (2026-12-07, docs/research/refinement.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.matching.chooser import FEATURES, Chooser, chooser_features, disputed, logistic
from cade_cli.matching.network import onnx_session, strips
from cade_cli.spectral import network_input

PLANES = (*FEATURES[:-1], "band")
"""The network's input planes, in order: the perceptron's features without its bias, then the left band's
colour-agnostic transform (``band``)."""
MATCH_PLANES = ("right_at_network", "right_at_candidate", "match_at_network", "match_at_candidate")
"""The matching evidence a chooser may also read, after :data:`PLANES`: the right band's colour-agnostic transform,
centred (``2 x - 1``, in -1 .. 1, as the transform's ``x_s`` clipped), sampled where the network's value and SGBM's
match put each pixel's match (0 outside the right view), then each times the left band's, centred alike: positive
where the two bands' contrast agrees, negative where it is inverted, near 0 on average where they are unrelated."""
MATCHING = PLANES + MATCH_PLANES
"""A chooser's planes with the matching evidence (``chooser --match-evidence``)."""
PLANE_SETS = (PLANES, MATCHING)
"""The input plane sets a network chooser may have (a card names its own)."""
KIND = "network"
"""A card's ``chooser.kind`` for this chooser (the perceptron's cards have none)."""
STRIP_PIXELS = 1_000_000
"""Largest strip (pixels) given to the network at once: its activations are 24 float32 planes of it."""
STRIP_OVERLAP = 96
"""Rows shared by neighbouring strips: each kept row sees half of them on its strip's side, at least the network's
reach (17 px, or 33 px with ``--context-dilations 1,2,4,8,16,1``), so that it sees all it would see in one run."""


def chooser_planes(left: np.ndarray, network: np.ndarray, uncertainty: np.ndarray, candidate: np.ndarray,
                   accepted: np.ndarray, right: np.ndarray | None = None, planes: tuple[str, ...] = PLANES
                   ) -> np.ndarray:
    """(len(planes), H, W) float32: the network's input (``planes``, one of :data:`PLANE_SETS`) for one pair; the
    arguments as :func:`~cade_cli.matching.chooser.chooser_features` takes them, and the right band where
    ``planes`` holds :data:`MATCH_PLANES`."""
    features = chooser_features(left, network, uncertainty, candidate, accepted)[..., :-1]
    band = network_input(np.asarray(left, np.float32), "cade")
    stack = [np.moveaxis(features, -1, 0), band[None]]
    if planes != PLANES:
        if right is None:
            raise ValueError("a chooser that reads the matching evidence needs the right band")
        other = 2 * network_input(np.asarray(right, np.float32), "cade") - 1
        at = [sampled_at(other, disparity) for disparity in (network, candidate)]
        stack += [np.stack(at), np.stack([(2 * band - 1) * sampled for sampled in at])]
    return np.concatenate(stack, axis=0).astype(np.float32)


def sampled_at(right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """(H, W) float32: ``right`` at (x - disparity, y), linearly interpolated; 0 where that lies outside the right
    view or the disparity is not finite."""
    height, width = right.shape
    shift = np.where(np.isfinite(disparity), disparity, np.float32(-1e6)).astype(np.float32)
    columns = np.arange(width, dtype=np.float32)[None, :] - shift
    rows = np.broadcast_to(np.arange(height, dtype=np.float32)[:, None], (height, width))
    return cv2.remap(np.asarray(right, np.float32), np.ascontiguousarray(columns), np.ascontiguousarray(rows),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


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
        if planes not in PLANE_SETS:
            raise ValueError(f"a network chooser's planes must be {list(PLANES)}, or those and "
                             f"{list(MATCH_PLANES)}; got {list(planes)}")
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
             accepted: np.ndarray, right: np.ndarray | None = None) -> np.ndarray:
        """(H, W) bool: where SGBM's accepted match replaces the network's value, as
        :meth:`~cade_cli.matching.chooser.Chooser.take` says (the agreeing matches, and the disputed pixels the
        network gives to SGBM). ``right``: the right band, which a chooser of :data:`MATCH_PLANES` reads."""
        taken = accepted.astype(bool).copy()
        asked = disputed(network, candidate, accepted)
        if asked.any():
            probability = self.probability(chooser_planes(left, network, uncertainty, candidate, accepted, right,
                                                          self.planes))
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
