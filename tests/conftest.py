"""Shared fixtures: the development data beside the repo, and seeded textures."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from synthetic import render_pair

REPO = Path(__file__).resolve().parents[1]
FOLDER_DISPARITY = 5.0
"""Disparity (px) of the scenes in :func:`folder_dataset`."""
SHARED_DATA = Path(os.environ.get("CADE_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def shared_data() -> Path:
    """Root of ../shared/data; tests using it skip where it is absent (a user's clone)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"development data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240414)


@pytest.fixture
def folder_dataset(tmp_path, rng) -> Path:
    """Two scenes in the `folder` layout: RGB views whose channels respond differently."""
    return write_folder_dataset(tmp_path / "mine", rng)


def write_folder_dataset(root: Path, rng: np.random.Generator) -> Path:
    """:func:`folder_dataset`'s two scenes written under ``root`` (for fixtures of a wider scope)."""
    for sub in ("left", "right", "gt"):
        (root / sub).mkdir(parents=True)
    for name in ("first", "second"):
        pair = render_pair(rng, (40, 64), background=(FOLDER_DISPARITY, 0.0))

        def rgb(band):  # three 'filters' with different monotone responses, stored as BGR
            return (np.stack([0.2 + 0.6 * band, band**1.5, band], axis=2) * 255).astype(np.uint8)

        cv2.imwrite(str(root / "left" / f"{name}.png"), rgb(pair.left))
        cv2.imwrite(str(root / "right" / f"{name}.png"), rgb(pair.right))
        np.save(root / "gt" / f"{name}.npy", pair.disparity)
    return root


@pytest.fixture
def small_validation(monkeypatch):
    """Training runs in tests validate on 4 generated pairs of 96 x 128 px instead of a real
    run's 24 of 256 x 384: the same code, a sixth of the pairs at an eighth of the size."""
    validation = pytest.importorskip("cade_cli.train.validation")
    monkeypatch.setattr(validation, "SYNTHETIC_PAIRS", 4)
    monkeypatch.setattr(validation, "SYNTHETIC_SIZE", (96, 128))
