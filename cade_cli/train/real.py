"""Real stereo scenes as a training source, beside the procedural generator.

A :class:`RealScenes` pool holds scenes with dense ground truth in the MiddEval3 file
layout (``../shared/data/train-real``: Middlebury 2001/2003/2006, never a reporting
scene). :meth:`RealScenes.draw` turns one of them into a :class:`StereoScene` of the
training size: a random zoom (disparity scaled with it), a random crop, an optional
vertical flip (rows of both views and the GT together, which keeps the epipolar
geometry), and the generator's own per-view camera model (:class:`Photometric`: gain,
gamma, blur, noise, 8-bit storage), so that the same :func:`~cade_cli.train.pairs.cade_pair`
turns it into a CADE pair exactly as it does a rendered scene.

A horizontal flip would need the right view's ground truth (the views swap roles), which
these scenes do not all carry, so it is not done.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.train.scenes import Photometric, StereoScene, camera


class RealScenes:
    """Real scenes loaded once and kept in memory (18 scenes of ~430x370: a few MB).

    Args:
        folder: a folder of scene folders in the MiddEval3 layout (``im0.png``,
            ``im1.png``, ``disp0GT.pfm``, ``mask0nocc.png``, ``calib.txt``).
        zoom: the range the scale factor is drawn from (log-uniformly); the crop must
            fit, so the lower end is raised where a scene is too small for it.
        hold_out: names of scenes in ``folder`` never drawn: kept out of training so that
            the learned chooser can be fitted on scenes the network has not memorised
            (``python -m cade_cli.train chooser --scenes``).
    """

    def __init__(self, folder: Path, *, zoom: tuple[float, float] = (0.8, 1.8), hold_out: Sequence[str] = ()):
        from cade_cli.data import get_dataset

        self.folder = Path(folder)
        self.zoom = zoom
        reader = get_dataset("middeval3")
        names, held = reader.scene_names(self.folder), set(hold_out)
        unknown = sorted(held - set(names))
        if unknown:
            raise CadeError(f"scenes to hold out are not in {folder}: {', '.join(unknown)}")
        kept = [name for name in names if name not in held]
        self.scenes = list(reader(self.folder, scenes=kept)) if kept else []
        if not self.scenes:
            raise CadeError(f"no real training scenes in {folder}; expected <scene>/im0.png, im1.png, disp0GT.pfm"
                            + (" (all held out)" if hold_out else ""))

    def draw(self, rng: np.random.Generator, height: int, width: int, *, limit: float,
             photometric: Photometric = Photometric()) -> StereoScene:
        """A (height, width) crop of a random scene at a random zoom, disparities below ``limit`` px
        (pixels above it are marked unknown: NaN), per-view photometric changes applied."""
        scene = self.scenes[int(rng.integers(len(self.scenes)))]
        rows, cols = scene.disparity.shape
        finite = scene.disparity[np.isfinite(scene.disparity)]
        top = float(finite.max()) if finite.size else 1.0
        smallest = max(height / rows, width / cols) * 1.001
        largest = max(smallest, min(self.zoom[1], 0.95 * limit / max(top, 1.0)))
        low = min(max(self.zoom[0], smallest), largest)
        scale = float(np.exp(rng.uniform(np.log(low), np.log(largest))))
        size = (max(width, round(cols * scale)), max(height, round(rows * scale)))
        interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
        left, right = (cv2.resize(view, size, interpolation=interpolation) for view in (scene.left, scene.right))
        sx = size[0] / cols
        disparity = cv2.resize(scene.disparity, size, interpolation=cv2.INTER_NEAREST) * np.float32(sx)
        nonocc = scene.nonocc if scene.nonocc is not None else np.isfinite(scene.disparity)
        nonocc = cv2.resize(nonocc.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
        top_row = int(rng.integers(size[1] - height + 1))
        left_col = int(rng.integers(size[0] - width + 1))
        window = (slice(top_row, top_row + height), slice(left_col, left_col + width))
        left, right, disparity, nonocc = (a[window] for a in (left, right, disparity, nonocc))
        if rng.random() < 0.5:
            left, right, disparity, nonocc = (a[::-1] for a in (left, right, disparity, nonocc))
        disparity = np.where(np.isfinite(disparity) & (disparity < limit), disparity, np.float32(np.nan))
        return StereoScene(
            left=camera(rng, np.ascontiguousarray(left, dtype=np.float32), photometric),
            right=camera(rng, np.ascontiguousarray(right, dtype=np.float32), photometric),
            disparity=np.ascontiguousarray(disparity, dtype=np.float32),
            nonoccluded=np.ascontiguousarray(nonocc & np.isfinite(disparity)),
        )
