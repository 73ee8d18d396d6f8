"""The chooser's rendered pairs (cade_cli.train.chooser_synthetic): cached as a real scene's task is, with truth that
fits the bands, each pair its own."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli.matching.base import DisparityRange
from cade_cli.matching.disparity import visible_in_right_view
from cade_cli.matching.network import NetworkStage

SIZE = (96, 128)


def cached(folder: Path, count: int, tmp_path: Path) -> list[Path]:
    pytest.importorskip("torch")
    from cade_cli.train.chooser_synthetic import cache_synthetic

    textures = tmp_path / "textures"  # one photo-like texture: smoothed noise (floating scenes need a photo)
    if not textures.exists():
        textures.mkdir()
        noise = np.random.default_rng(0).random((160, 200, 3)).astype(np.float32)
        cv2.imwrite(str(textures / "noise.png"), (cv2.GaussianBlur(noise, (0, 0), 2) * 255).astype(np.uint8))
    return cache_synthetic(folder, model="cade-v13", count=count, seed=3, textures=textures, size=SIZE, levels=24)


def test_rendered_pairs_are_tasks_whose_network_maps_follow_their_truth(tmp_path: Path):
    """The fit reads a rendered pair as it reads a real scene's task; the stored map is the model's own on the
    stored bands, and it follows the stored truth (over four pairs most of it within 3 px, more than of the truth
    moved by 4 px: a truth of the other view or off by a shift would not)."""
    from cade_cli.train.chooser import tasks_of

    near, moved = [], []
    for file in cached(tmp_path / "cache", 4, tmp_path):
        ((gt, task),) = list(tasks_of(file))
        assert {name: array.shape for name, array in task.items()} == dict.fromkeys(task, SIZE)
        assert task["accepted"].dtype == bool and np.isfinite(gt).all() and gt.min() >= 0
        span = int(np.ceil(gt.max() * 1.15)) + 4
        again = NetworkStage(model="cade-v13").estimate(task["left"], np.load(file)["synthetic_right"],
                                                         DisparityRange(0, span))
        np.testing.assert_allclose(again.disparity, task["network"], atol=1e-4)
        visible = visible_in_right_view(gt)
        near.append(np.mean(np.abs(task["network"] - gt)[visible] <= 3))
        moved.append(np.mean(np.abs(task["network"] - gt - 4)[visible] <= 3))
    assert np.mean(near) > max(0.5, np.mean(moved))


def test_a_cache_grows_without_rendering_its_pairs_again_and_each_pair_is_its_own(tmp_path: Path):
    (first,) = cached(tmp_path / "a", 1, tmp_path)
    written = first.stat().st_mtime_ns
    grown = cached(tmp_path / "a", 2, tmp_path)
    assert grown[0] == first and first.stat().st_mtime_ns == written
    fresh = cached(tmp_path / "b", 2, tmp_path)
    one, other = np.load(grown[1]), np.load(fresh[1])
    assert sorted(one.files) == sorted(other.files)
    for name in one.files:
        np.testing.assert_array_equal(one[name], other[name])
    assert not np.array_equal(np.load(grown[0])["gt"], one["gt"])


def test_rendering_pairs_without_textures_is_refused_before_any_work(tmp_path: Path):
    pytest.importorskip("torch")
    from typer.testing import CliRunner

    from cade_cli.train.__main__ import app

    result = CliRunner().invoke(app, ["chooser", "--real-dir", str(tmp_path), "--cache", str(tmp_path / "cache"),
                                      "--model", "cade-v13", "--synthetic", "4"])
    assert result.exit_code == 2 and "--textures" in result.output
    assert not (tmp_path / "cache").exists()


def test_a_cache_written_before_the_right_bands_gets_the_ones_its_pairs_render(tmp_path: Path):
    """A pair cached without its right band (as before 2026-12-07) gets the one a fresh cache stores, the other
    arrays as they were; a cached pair its stream no longer renders is one clear error, not a wrong band."""
    from cade_cli.train.chooser import save_atomically

    (fresh,) = cached(tmp_path / "fresh", 1, tmp_path)
    (old,) = cached(tmp_path / "old", 1, tmp_path)
    with np.load(old) as stored:
        arrays = {key: stored[key] for key in stored.files if key != "synthetic_right"}
    save_atomically(old, arrays)
    cached(tmp_path / "old", 1, tmp_path)
    completed, expected = np.load(old), np.load(fresh)
    assert sorted(completed.files) == sorted(expected.files)
    for name in completed.files:
        np.testing.assert_array_equal(completed[name], expected[name])
    save_atomically(old, {**arrays, "synthetic_left": arrays["synthetic_left"] + 1})
    with pytest.raises(ValueError, match="remove the cache"):
        cached(tmp_path / "old", 1, tmp_path)
