"""The convex mask's headroom (cade_cli/train/mask_headroom.py): the nine candidates it reads off the network
are the ones the network's last stage combines, its hard pick is the heaviest one, and it runs end to end."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from cade_cli.train import mask_headroom  # noqa: E402
from cade_cli.train.networks import network_of  # noqa: E402

CONFIG = {"architecture": "cadenet-iterative", "levels": 32, "features2d": 8, "width2d": 8}


def _bands(seed=0, shape=(40, 56)):
    rng = np.random.default_rng(seed)
    left = rng.random(shape).astype(np.float32)
    return left, np.roll(left, -3, axis=1)


def test_an_untrained_mask_averages_the_nine_candidates_it_is_said_to_read():
    torch.manual_seed(0)
    net = network_of(CONFIG).eval()  # the mask's exit starts at zero: equal weights
    disparity, options, _ = mask_headroom.candidates(net, *_bands())
    assert options.shape == (9, *disparity.shape)
    assert np.allclose(disparity, options.mean(0), atol=1e-4)


def test_a_decisive_mask_makes_the_hard_pick_the_network_map():
    torch.manual_seed(0)
    net = network_of(CONFIG).eval()
    exit_layer = net.mask.net[-1]
    with torch.no_grad():
        exit_layer.weight.normal_(0, 50.0)  # near one-hot weights
    disparity, options, heaviest = mask_headroom.candidates(net, *_bands(1))
    hard = np.take_along_axis(options, heaviest[None], 0)[0]
    spread = options.max(0) - options.min(0)
    assert spread.max() > 0.5  # the candidates differ, so a wrong index would show
    assert np.mean(np.abs(hard - disparity) < 0.05 * np.maximum(spread, 1e-3) + 1e-4) > 0.9


def test_the_oracle_takes_the_candidate_nearest_the_truth():
    options = np.stack([np.full((2, 2), v, np.float32) for v in (1, 4, 9, 2, 3, 5, 6, 7, 8)])
    gt = np.array([[4.4, 8.6], [np.inf, 0.0]], np.float32)
    rows = mask_headroom.maps(options.mean(0), options, np.zeros((2, 2), np.int64), gt)
    assert rows["oracle"].tolist() == [[4.0, 9.0], [1.0, 1.0]]
    assert rows["hard pick"].tolist() == [[1.0, 1.0], [1.0, 1.0]]


def test_it_runs_end_to_end_and_refuses_another_design(tmp_path, capsys):
    torch.manual_seed(0)
    net = network_of(CONFIG)
    torch.save({"config": {**CONFIG, "network_input": "cade-floor"}, "model": net.state_dict()}, tmp_path / "it.pt")
    left, right = _bands(2)
    gt = np.full(left.shape, 3.0, np.float32)
    np.savez_compressed(tmp_path / "pair.npz", left=left, right=right, gt=gt, nonocc=np.ones(left.shape, bool))
    assert mask_headroom.main([str(tmp_path / "it.pt"), f"toy={tmp_path}"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| toy |")]
    assert [line.split("|")[2].strip() for line in rows] == list(mask_headroom.ROWS)
    torch.save({"config": {"architecture": "cadenet2d", "levels": 32}, "model": {}}, tmp_path / "other.pt")
    with pytest.raises(SystemExit):
        mask_headroom.main([str(tmp_path / "other.pt"), f"toy={tmp_path}"])
