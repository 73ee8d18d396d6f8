"""The edge-assignment probe (cade_cli/train/edge_assignment.py): its fetch, its labels, its picks and a
run end to end on pairs it builds itself."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from cade_cli.train import edge_assignment as probe  # noqa: E402


def test_fetch_finds_features_shifted_by_a_known_disparity():
    right = torch.randn(1, 4, 6, 40)
    left = torch.zeros_like(right)
    left[..., 5:] = right[..., :-5]  # left(x) = right(x - 5)
    fetched = probe.fetch(right, torch.full((1, 1, 6, 40), 5.0))
    assert torch.allclose(fetched[..., 5:], left[..., 5:])
    halfway = probe.fetch(right, torch.full((1, 1, 6, 40), 2.5))
    assert torch.allclose(halfway[..., 3:], (right[..., :-3] + right[..., 1:-2]) / 2, atol=1e-6)


def _pair(own, low, high, gt):
    arrays = [np.array([values], np.float32) for values in (own, low, high, gt)]
    return {"own": arrays[0], "low": arrays[1], "high": arrays[2], "gt": arrays[3],
            "edge": arrays[2] - arrays[1] > probe.JUMP}


def test_labels_keep_a_right_value_switch_a_wrong_one_and_skip_the_rest():
    x = _pair(own=[5.0, 5.0, 5.0, 5.0, 5.0], low=[2, 2, 2, 2, 5], high=[9, 9, 9, 9, 5],
              gt=[5.5, 8.8, 7.0, np.inf, 5.0])
    label, weight = probe.labels(x)
    # kept (own within 1 px); switched to the highest (own 3.8 px off, highest 0.2); undecided (own 2 px off,
    # none within 1); unknown ground truth; no depth edge in the window
    assert label[0, :2].tolist() == [0, 2]
    assert weight[0].tolist() == [1.0, 1.0, 0.0, 0.0, 0.0]


def test_a_pick_moves_only_edge_pixels_and_a_margin_beyond_reach_moves_none():
    rng = np.random.default_rng(1)
    own = np.tile(np.r_[np.full(12, 3.0), np.full(12, 9.0)], (16, 1)).astype(np.float32)
    own[:, 12:14] = 6.0  # an in-between value at the edge
    x = {"left": rng.random((16, 24), np.float32), "right": rng.random((16, 24), np.float32), "own": own,
         "low": np.full_like(own, 3.0), "high": np.full_like(own, 9.0)}
    x["edge"] = np.zeros(own.shape, bool)
    x["edge"][:, 8:18] = True
    torch.manual_seed(0)
    model = probe.AssignmentHead()
    assert np.array_equal(probe.pick(model, x, margin=1.01), own)
    picked = probe.pick(model, x, margin=-1.0)  # always the most probable candidate
    assert np.array_equal(picked[:, ~x["edge"][0]], own[:, ~x["edge"][0]])
    assert set(np.unique(picked[:, x["edge"][0]])) <= {3.0, 6.0, 9.0}


def test_the_probe_runs_end_to_end_on_cached_pairs(tmp_path, capsys):
    rng = np.random.default_rng(0)
    texture = rng.random((100, 140)).astype(np.float32)
    gt = np.where(np.arange(140)[None, :] < 70, 2.0, 14.0).repeat(100, 0).astype(np.float32)
    right = rng.random((100, 140)).astype(np.float32)
    for column in range(140):  # left(x) = right(x - d(x)); what the near surface hides stays noise
        if column >= gt[0, column]:
            right[:, column - int(gt[0, column])] = texture[:, column]
    disparity = gt.copy()
    disparity[:, 70:74] = 2.0  # the map's edge 4 px into the near surface, beyond the edge filter's reach
    for i in range(2):
        np.savez_compressed(tmp_path / f"pair{i}.npz", left=texture, right=right, disparity=disparity, gt=gt,
                            nonocc=np.ones(gt.shape, bool))
    assert probe.main(["--train", str(tmp_path), "--evaluate", f"toy={tmp_path}", "--steps", "2"]) == 0
    rows = {line.split("|")[2].strip(): line for line in capsys.readouterr().out.splitlines()
            if line.startswith("| toy |")}
    assert set(rows) == {"filtered map", "oracle", *(f"head, margin {m}" for m in probe.MARGINS)}

    def edge_bmp3(row):
        return float(rows[row].split("|")[-2])

    assert edge_bmp3("oracle") < edge_bmp3("filtered map")


TEXTURES = Path(__file__).resolve().parents[2] / "shared" / "data" / "textures"


@pytest.mark.skipif(not TEXTURES.is_dir(), reason="needs ../shared/data/textures")
def test_rendered_pairs_are_cached_as_a_real_pair_is_and_kept(tmp_path):
    files = probe.cache_rendered(tmp_path, model="cade-v13", count=1, seed=3, textures=TEXTURES)
    pair = np.load(files[0])
    assert set(pair.files) == {"left", "right", "disparity", "gt", "nonocc"}
    assert pair["left"].shape == pair["right"].shape == pair["disparity"].shape == pair["gt"].shape
    known = np.isfinite(pair["gt"])
    assert known.mean() > 0.99 and pair["gt"][known].max() > 1.0
    # the map is the model's, not the truth: close to it on most pixels, yet not equal
    error = np.abs(pair["disparity"] - pair["gt"])[known]
    assert 0.0 < np.mean(error > 3.0) < 0.6
    stamp = files[0].stat().st_mtime_ns
    assert probe.cache_rendered(tmp_path, model="cade-v13", count=1, seed=3, textures=TEXTURES) == files
    assert files[0].stat().st_mtime_ns == stamp  # an existing pair is kept, not rendered again
    assert probe.pair(files[0])["edge"].any()


def test_a_card_that_filters_its_map_is_refused_for_rendered_pairs(tmp_path):
    with pytest.raises(ValueError, match="already filters its map"):
        probe.cache_rendered(tmp_path, model="cade-v13-accurate-synthetic", count=1, seed=3, textures=TEXTURES)
    assert not any(tmp_path.iterdir())  # refused before anything is rendered or written
