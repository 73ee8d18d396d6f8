"""Synthetic candidate caches for the choosers' fits (the npz layout of cade_cli.train.chooser.cache_candidates):
SGBM's match is right (within 0.3 px) at half the pixels, at random, and 25 px off at the others; the network is
5 px off everywhere. A fitted chooser must take the near matches and leave the far ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np

SHAPE = (40, 60)


def near_far_caches(folder: Path, rng: np.random.Generator, scenes: int = 3) -> list[Path]:
    """``scenes`` cached scenes of one task (RB) in ``folder``; their paths."""
    for index in range(scenes):
        gt = rng.uniform(5, 50, SHAPE).astype(np.float32)
        near = rng.random(SHAPE) < 0.5
        candidate = np.where(near, gt + rng.normal(0, 0.3, SHAPE), gt + 25).astype(np.float32)
        np.savez(folder / f"scene{index}.npz", gt=gt, RB_network=gt + 5, RB_uncertainty=np.ones(SHAPE, np.float32),
                 RB_candidate=candidate, RB_accepted=np.ones(SHAPE, bool),
                 RB_left=rng.random(SHAPE).astype(np.float32))
    return sorted(folder.glob("scene*.npz"))


def near_far_agreement(chooser, rng: np.random.Generator) -> float:
    """The share of a new such scene's pixels where ``chooser.take`` takes SGBM's match exactly where it is near."""
    gt = rng.uniform(5, 50, SHAPE).astype(np.float32)
    near = rng.random(SHAPE) < 0.5
    candidate = np.where(near, gt, gt + 25).astype(np.float32)
    taken = chooser.take(rng.random(SHAPE).astype(np.float32), gt + 5, np.ones(SHAPE, np.float32), candidate,
                         np.ones(SHAPE, bool))
    return float((taken == near).mean())
