"""Rendered pairs for the chooser's fit (``python -m cade_cli.train chooser --synthetic N``, 2026-12-07).

The chooser learns from the network's and SGBM's errors. On the 18 real training scenes those errors are too few and
too mild: the network trained on those very scenes (``fit --real-share``), so it rarely misses there, and a chooser
fitted on them sees few of the misses it must catch on scenes the network never saw. A freshly rendered pair is one
the network has never seen, with exact truth at every pixel, and there is no end of them. :func:`cache_synthetic`
renders them with the training campaign's scene generator and levers (procedural and floating scenes, thin
structures, grounds, shadows, one view changed, a misaligned right view) and stores the candidates of each exactly as
:func:`~cade_cli.train.chooser.cache_candidates` stores a real scene's task (both call
:func:`~cade_cli.train.chooser.task_candidates`), so the fit reads both alike.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cade_cli.spectral import BAND_NAMES
from cade_cli.train.chooser import candidate_stages, save_atomically, task_candidates

SIZE = (384, 448)
"""(height, width) of a rendered pair: about a real training scene's size (~370 x 430)."""
LEVELS = 128
"""The scenes' disparities lie below this many px (times a per-scene share, :data:`LEVERS` ``scene_range``)."""
LEVERS = {"misaligned": 0.3, "scene_range": 0.25, "ground": 0.3, "shadows": 0.3, "thin": 0.3, "floating": 0.5,
          "asymmetric": 0.3}
"""The scene generator's levers (:func:`~cade_cli.train.batches.generated_scene`), as the training campaign
draws them (``runs/campaign-2026-12-07-extended/config.json``)."""
MARGIN = 1.15
"""The searched range is the pair's largest disparity times this (and 4 px more), as a dataset's stated range
(a Middlebury scene's ``ndisp``) lies a little above its largest disparity."""
PREFIX = "synthetic"
"""The task name of a rendered pair in its cache (:func:`~cade_cli.train.chooser.tasks_of` reads it)."""


def rendered_bands(rng: np.random.Generator, pool, real, size: tuple[int, int] = SIZE, levels: int = LEVELS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, str]]:
    """(left band, right band, truth, (left band name, right band name)) of one freshly rendered scene (textures
    from the :class:`~cade_cli.train.textures.TexturePool` ``pool``, floating objects' backgrounds also from the
    :class:`~cade_cli.train.real.RealScenes` ``real`` or None): two of its eleven bands (METHOD.md section 2, the
    same mix in both views) drawn independently, on the 0-255 scale of an 8-bit camera, as float32."""
    from cade_cli.train.batches import generated_scene
    from cade_cli.train.pairs import both_views_bands

    scene = generated_scene(rng, pool, *size, levels, real=real, **LEVERS)
    left_bands, right_bands = both_views_bands(scene, rng)
    names = tuple(str(name) for name in rng.choice(BAND_NAMES, size=2))
    left, right = (np.clip(bands[name], 0, 1).astype(np.float32) * 255 for bands, name in
                   zip((left_bands, right_bands), names))
    return left, right, scene.disparity.astype(np.float32), names


def cache_rendered(out: Path, stem: str, store, *, count: int, seed: int, textures: Path, real_dir: Path | None = None,
                   size: tuple[int, int] = SIZE, levels: int = LEVELS) -> list[Path]:
    """``count`` npz files ``out/STEM-SEED-IIII.npz``, each one rendered pair (:func:`rendered_bands`) stored as
    ``store(left, right, truth, span)`` returns it (a dict of arrays; ``span``: the px searched, the truth's largest
    disparity times :data:`MARGIN` and 4 px more). Pair ``i`` comes from its own stream (``seed``, ``i``), so a cache
    grows or resumes without changing its other pairs; existing files are kept, and an interrupted cache leaves no
    half-written pair behind. Returns the files."""
    from cade_cli.train.real import RealScenes
    from cade_cli.train.textures import TexturePool

    out.mkdir(parents=True, exist_ok=True)
    pool = TexturePool([textures])
    real = RealScenes(real_dir) if real_dir is not None else None
    files = []
    for index in range(count):
        target = out / f"{stem}-{seed}-{index:04d}.npz"
        files.append(target)
        if target.exists():
            continue
        left, right, gt, names = rendered_bands(np.random.default_rng([seed, index]), pool, real, size, levels)
        span = int(np.ceil(np.nanmax(gt) * MARGIN)) + 4
        save_atomically(target, store(left, right, gt, span))
        print(f"cached rendered pair {index} ({names[0]} against {names[1]}, up to {span} px)", flush=True)
    return files


def cache_synthetic(out: Path, *, model: str, count: int, seed: int, textures: Path, real_dir: Path | None = None,
                    candidates: str | None = None, size: tuple[int, int] = SIZE,
                    levels: int = LEVELS) -> list[Path]:
    """``count`` npz files in ``out`` (:func:`cache_rendered`), each one rendered pair's truth and the candidates of
    ``model``'s network and its card's refinement (or the one ``candidates`` names), under the task name
    :data:`PREFIX` (its right band too, ``synthetic_right``, as every task's); returns the files. ``size``:
    (height, width) of the pairs; ``levels``: their disparities lie below this (:data:`LEVELS`)."""
    network, refinement = candidate_stages(model, candidates)

    def store(left, right, gt, span):
        return {"gt": gt, **task_candidates(network, refinement, left, right, span, PREFIX)}

    files = cache_rendered(out, PREFIX, store, count=count, seed=seed, textures=textures, real_dir=real_dir,
                           size=size, levels=levels)
    add_right_bands(files, seed=seed, textures=textures, real_dir=real_dir, size=size, levels=levels)
    return files


def has_right_band(target: Path) -> bool:
    """Whether the cached pair ``target`` holds its right band (its index only is read)."""
    with np.load(target) as stored:
        return f"{PREFIX}_right" in stored.files


def add_right_bands(files: list[Path], *, seed: int, textures: Path, real_dir: Path | None = None,
                    size: tuple[int, int] = SIZE, levels: int = LEVELS) -> None:
    """Give the pairs of ``files`` cached before the right bands were stored (2026-12-07) their right band,
    rendered again from the pair's own stream (the other arrays as they were, no network run).

    Raises:
        ValueError: a pair rendered again differs from the cached one (the generator changed since)."""
    from cade_cli.train.real import RealScenes
    from cade_cli.train.textures import TexturePool

    lacking = [target for target in files if not has_right_band(target)]
    if not lacking:
        return
    pool = TexturePool([textures])
    real = RealScenes(real_dir) if real_dir is not None else None
    for target in lacking:
        index = int(target.stem.rsplit("-", 1)[1])
        left, right, _, _ = rendered_bands(np.random.default_rng([seed, index]), pool, real, size, levels)
        with np.load(target) as stored:
            arrays = {key: stored[key] for key in stored.files}
        if not np.array_equal(arrays[f"{PREFIX}_left"], left):
            raise ValueError(f"{target} is not the pair its stream renders now; remove the cache to rebuild it")
        save_atomically(target, {**arrays, f"{PREFIX}_right": right})
        print(f"added the right band to {target.name}", flush=True)
