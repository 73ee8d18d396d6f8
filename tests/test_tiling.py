"""Tiled matching within a memory budget (cade_cli.scale.tiling): the tiles fit, their ranges
cover the truth, and away from the seams the stitched map is the untiled one."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.scale.memory import BASE_BYTES, IMAGE_BYTES, matching_memory_bytes, tile_memory_bytes, parse_memory
from cade_cli.scale.tiling import estimate_disparity_tiled, plan_tiles, seam_distance
from cade_cli.scale.windows import method_collar, window_alignment
from cade_cli.stereo import estimate_disparity
from cli_runner import run_cade, write_png16
from cade_cli.model_card import read_card
from synthetic import render_pair

MAX_DISP = 64


@pytest.fixture
def pair(rng):
    """240x400: a background sloping from 20 to 32 px down the rows, a 40 px box in front."""
    return render_pair(rng, (240, 400), background=(20.0, 0.05), foreground=(40.0, 0.0))


def test_parse_memory():
    assert parse_memory("4GB") == 4 * 2**30
    assert parse_memory("512MB") == 512 * 2**20
    assert parse_memory("1.5g") == 3 * 2**29
    assert parse_memory("2GiB") == 2 * 2**30
    for bad in ("", "four GB", "4 parsecs", "-1GB", "0MB", "GB"):
        with pytest.raises(CadeError, match="--memory-limit"):
            parse_memory(bad)


@pytest.mark.parametrize("method", ["census-sgm", "sgbm"])
def test_tiled_map_equals_the_untiled_one_away_from_seams(pair, method):
    whole = estimate_disparity(pair.left, pair.right, method=method, max_disp=MAX_DISP)
    progress = []
    tiled, plan = estimate_disparity_tiled(pair.left, pair.right, method=method, max_disp=MAX_DISP,
                                           memory_limit=2**30, core=96,
                                           on_tile=lambda done, total: progress.append((done, total)))
    assert plan.tiled and len(plan.tiles) == 3 * 5
    assert progress == [(done, 15) for done in range(1, 16)]  # a progress bar moves with every tile
    away = seam_distance(plan, pair.left.shape) >= 16
    both = whole.valid & tiled.valid & pair.reliable
    assert (both & away).sum() > 0.3 * pair.reliable.sum()
    difference = np.abs(whole.disparity - tiled.disparity)
    assert np.mean(difference[both & away] < 1e-3) > 0.98
    # the stitched map finds the truth, seams included, and keeps (at least) as many pixels
    error = np.abs(tiled.disparity - pair.disparity)[tiled.valid & pair.reliable]
    assert np.median(error) < 0.25 and np.mean(error > 1) < 0.02
    assert tiled.valid[pair.reliable].mean() >= whole.valid[pair.reliable].mean() - 0.01
    assert tiled.confidence is not None and np.all(tiled.confidence[~tiled.valid] == 0)


@pytest.fixture
def wide_pair(rng):
    """480x800, the same scene: wide enough that a learned window (core + 2 x 128 px collar)
    is well short of the whole picture, so tiles see less than the untiled map does."""
    return render_pair(rng, (480, 800), background=(20.0, 0.05), foreground=(40.0, 0.0))


@pytest.mark.parametrize("method, agreeing", [("cade-network", 0.99), ("cade", 0.99)])
def test_learned_tiles_equal_the_untiled_map_away_from_seams(wide_pair, method, agreeing):
    """160 px cores, windows on the network's input grid, the card's collar (cade-v11: 128 px).
    Measured with cade-v11 (``cade-network``): 0.7 % of the pixels 16 px or more from a seam
    are more than 0.05 px off the untiled map, 0.3 % more than 0.1 px; with a 64 px collar
    3.2 % and 1.0 % (checked below: the collar is what keeps the tiles equal; cade-v10: 0.4 and
    2.5 %). ``cade``'s refinement and chooser hide most of the network's residue."""
    pair = wide_pair
    whole = estimate_disparity(pair.left, pair.right, method=method, max_disp=MAX_DISP)

    def agreement(collar):
        tiled, plan = estimate_disparity_tiled(pair.left, pair.right, method=method, max_disp=MAX_DISP,
                                               memory_limit=2**30, core=160, seed=False, collar=collar)
        assert plan.tiled and len(plan.tiles) == 3 * 5
        alignment = window_alignment(method, MAX_DISP)
        assert all(tile.window_rows[0] % alignment == tile.window_columns[0] % alignment == 0 for tile in plan.tiles)
        away = seam_distance(plan, pair.left.shape) >= 16
        both = whole.valid & tiled.valid
        assert (both & away).sum() > 0.4 * both.size
        return plan.collar, np.mean(np.abs(whole.disparity - tiled.disparity)[both & away] <= 0.05)

    collar, agreeing_pixels = agreement(None)
    assert collar == method_collar(method) == read_card().context == 128  # cade-v11's card
    assert window_alignment(method, MAX_DISP) == read_card().divisor  # the shipped network's input grid
    assert agreeing_pixels > agreeing
    if method == "cade-network":
        assert agreement(64)[1] < agreeing  # half the card's collar: visibly off


def test_seeded_ranges_cover_the_truth_and_narrow_the_search(pair):
    plan = plan_tiles(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP, memory_limit=2**30, core=96)
    assert all(tile.seeded for tile in plan.tiles)
    for tile in plan.tiles:
        core = (slice(*tile.core_rows), slice(*tile.core_columns))
        truth = pair.disparity[core][pair.reliable[core]]
        if truth.size:
            assert tile.range.minimum <= truth.min() and truth.max() <= tile.range.maximum, tile
    assert max(tile.range.count for tile in plan.tiles) < MAX_DISP + 1
    assert min(tile.range.count for tile in plan.tiles) < 30  # background-only tiles: about 20..32 px


def test_every_tile_fits_the_budget_and_a_pair_that_fits_is_matched_whole(pair):
    height, width = pair.left.shape
    untiled = BASE_BYTES + matching_memory_bytes("census-sgm", width, height, MAX_DISP + 1)
    limit = BASE_BYTES + untiled // 8
    plan = plan_tiles(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP, memory_limit=limit)
    assert plan.tiled and untiled > limit
    budget = limit - BASE_BYTES - IMAGE_BYTES * width * height
    for tile in plan.tiles:
        assert tile_memory_bytes("census-sgm", *tile.window_size, tile.range.count) <= budget
    covered = np.zeros(pair.left.shape, int)
    for tile in plan.tiles:
        covered[slice(*tile.core_rows), slice(*tile.core_columns)] += 1
    assert covered.min() >= 1

    whole, whole_plan = estimate_disparity_tiled(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP,
                                                 memory_limit=untiled)
    assert not whole_plan.tiled
    expected = estimate_disparity(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP)
    np.testing.assert_array_equal(whole.disparity, expected.disparity)
    np.testing.assert_array_equal(whole.valid, expected.valid)


def test_a_budget_too_small_for_any_tile_says_what_it_needs(pair):
    with pytest.raises(CadeError, match=r"does not fit --memory-limit .* raise --memory-limit"):
        plan_tiles(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP, memory_limit=BASE_BYTES + 2**20)


def test_disparity_command_tiles_a_pair_the_untiled_path_refuses(tmp_path, pair, capsys, monkeypatch):
    from cade_cli import stereo
    from cade_cli.io.disparity import read_disparity

    left, right = write_png16(tmp_path / "l.png", pair.left), write_png16(tmp_path / "r.png", pair.right)
    # the untiled path refuses this pair under a small volume limit...
    monkeypatch.setattr(stereo, "MEMORY_LIMIT_BYTES", 64 * 2**20)
    with pytest.raises(CadeError, match="needs about"):
        estimate_disparity(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP)
    # ...and the command matches it as tiles whose volumes stay under it
    out = tmp_path / "d.pfm"
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", out, "--method", "census-sgm",
                                     "--max-disp", MAX_DISP, "--memory-limit", "330MB"], capsys)
    assert code == 0, stderr
    assert "note: the pair does not fit --memory-limit" in stderr and " tiles of " in stderr
    disparity = read_disparity(out)
    error = np.abs(disparity - pair.disparity)[pair.reliable]
    assert np.median(error) < 0.25 and np.mean(error > 1) < 0.03


@pytest.mark.parametrize("value", ["lots", "0GB", "12 parsecs"])
def test_bad_memory_limit_is_one_clear_line(tmp_path, pair, capsys, value):
    left, right = write_png16(tmp_path / "l.png", pair.left), write_png16(tmp_path / "r.png", pair.right)
    code, stdout, stderr = run_cade(["disparity", left, right, "-o", tmp_path / "d.pfm", "--method", "census-sgm",
                                     "--memory-limit", value], capsys)
    assert code == 1
    assert stderr.count("\n") == 1 and stderr.startswith("cade: error: --memory-limit") and "4GB" in stderr
    assert not (tmp_path / "d.pfm").exists()


def test_a_learned_method_plans_its_network_strip_and_its_tiles_fit(rng):
    """Planning only (no matching): a pair large enough that a small core's window, with the
    network's collar (128 px for CadeNet2D), is well under half of it."""
    pair = render_pair(rng, (480, 800), background=(20.0, 0.05), foreground=(40.0, 0.0))
    height, width = pair.left.shape
    assert tile_memory_bytes("cade", width, height, 65) > matching_memory_bytes("cade", width, height, 65)
    assert tile_memory_bytes("sgbm", width, height, 65) == matching_memory_bytes("sgbm", width, height, 65)
    untiled = tile_memory_bytes("cade", width, height, MAX_DISP + 1)
    limit = BASE_BYTES + IMAGE_BYTES * width * height + untiled // 2
    plan = plan_tiles(pair.left, pair.right, method="cade", max_disp=MAX_DISP, memory_limit=limit)
    assert plan.tiled
    for tile in plan.tiles:
        assert tile_memory_bytes("cade", *tile.window_size, tile.range.count) <= untiled // 2


def test_the_budget_plan_cuts_only_the_cores_that_need_it(pair):
    """The quadtree: cores that partition the image, each tile within the budget, and less
    matching work than the best regular grid of one core side that fits the same budget."""
    height, width = pair.left.shape
    untiled = BASE_BYTES + matching_memory_bytes("census-sgm", width, height, MAX_DISP + 1)
    limit = BASE_BYTES + untiled // 8
    plan = plan_tiles(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP, memory_limit=limit)
    covered = np.zeros(pair.left.shape, int)
    for tile in plan.tiles:
        covered[slice(*tile.core_rows), slice(*tile.core_columns)] += 1
    np.testing.assert_array_equal(covered, 1)

    def work(tiles):
        return sum(np.prod(tile.window_size) * tile.range.count for tile in tiles)

    for side in range(max(height, width), 16, -16):  # the largest regular grid that fits
        try:
            grid = plan_tiles(pair.left, pair.right, method="census-sgm", max_disp=MAX_DISP, memory_limit=limit,
                              core=side)
            break
        except CadeError:
            continue
    sides = {tile.side for tile in plan.tiles}
    assert len(sides) > 1, sides  # the box's edges cost more range than the plain background
    assert work(plan.tiles) < work(grid.tiles)
