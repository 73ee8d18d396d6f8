"""The estimated search range (`--max-disp auto`, `--min-disp auto`) on pairs of known disparity."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.scale.range import AUTO, coarse_factor, estimate_range, parse_bound, resolve_range
from synthetic import render_pair


def cross_band(pair):
    """The right view as another filter would see it: a contrast inversion and a gamma."""
    return (1.0 - pair.right) ** 1.8


@pytest.mark.parametrize("background, foreground", [((12.0, 0.0), (40.0, 0.0)), ((-20.0, 0.0), (14.0, 0.0))],
                         ids=["positive", "signed"])
def test_auto_range_covers_the_true_range_across_bands(rng, background, foreground):
    pair = render_pair(rng, (160, 320), background=background, foreground=foreground)
    estimate = estimate_range(pair.left, cross_band(pair))
    truth = pair.disparity[pair.reliable]
    assert estimate.range.minimum <= truth.min() and estimate.range.maximum >= truth.max()
    # ... and stays near it: within the margin plus a few coarse pixels of the truth.
    slack = estimate.margin + 3 * estimate.factor
    assert estimate.range.minimum >= truth.min() - slack and estimate.range.maximum <= truth.max() + slack
    assert estimate.factor == 2  # 320 px wide: one halving brings it under 256


def test_a_given_bound_is_kept_and_only_the_other_estimated(rng):
    pair = render_pair(rng, (96, 192), background=(10.0, 0.0), foreground=(24.0, 0.0))
    searched, estimate = resolve_range(pair.left, pair.right, min_disp=0, max_disp=AUTO)
    assert searched.minimum == 0 and searched.maximum >= 24 and estimate is not None
    searched, estimate = resolve_range(pair.left, pair.right, min_disp=AUTO, max_disp=40)
    assert searched.maximum == 40 and 0 < searched.minimum <= 10
    assert "--min-disp auto" in estimate.describe(estimated=(True, False))


def test_fixed_bounds_are_not_estimated(rng):
    pair = render_pair(rng, (48, 64))
    assert resolve_range(pair.left, pair.right, min_disp=-3, max_disp=9) == (
        resolve_range(pair.left, pair.right, min_disp=-3, max_disp=9)[0], None)
    searched, estimate = resolve_range(pair.left, pair.right, min_disp=0, max_disp=None)
    assert (searched.minimum, searched.maximum, estimate) == (0, 16, None)  # a quarter of 64


def test_blank_pair_asks_for_a_range():
    blank = np.full((64, 128), 0.5, np.float32)
    with pytest.raises(CadeError, match="give --max-disp"):
        estimate_range(blank, blank)


def test_parse_bound():
    assert parse_bound("auto", option="max-disp") == AUTO and parse_bound("AUTO", option="max-disp") == AUTO
    assert parse_bound("-12", option="min-disp") == -12
    with pytest.raises(CadeError, match="--max-disp 'ten'"):
        parse_bound("ten", option="max-disp")
    with pytest.raises(CadeError, match="below 1"):
        parse_bound("0", option="max-disp", minimum=1)


def test_coarse_factor():
    assert [coarse_factor(width) for width in (100, 256, 257, 700, 1242)] == [1, 1, 2, 4, 8]


def test_disparity_command_announces_the_auto_range(tmp_path, rng, capsys):
    import cv2

    from cade_cli import cli
    from cade_cli.io.disparity import read_disparity

    pair = render_pair(rng, (64, 160), background=(-6.0, 0.0), foreground=(9.0, 0.0))
    paths = [tmp_path / "left.png", tmp_path / "right.png"]
    for path, band in zip(paths, (pair.left, 0.2 + 0.5 * pair.right**1.5)):
        cv2.imwrite(str(path), np.rint(band * 65535).astype(np.uint16))
    out = tmp_path / "d.pfm"
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["disparity", str(paths[0]), str(paths[1]), "-o", str(out),
                  "--method", "census-sgm", "--min-disp", "auto", "--max-disp", "auto"])
    captured = capsys.readouterr()
    assert exit_info.value.code == 0, captured.err
    assert "note: --min-disp and --max-disp auto: searching [" in captured.err
    searched = captured.out.split("searched [")[1].split("]")[0]
    minimum, maximum = (int(value) for value in searched.split(", "))
    assert minimum <= -6 and maximum >= 9
    disparity = read_disparity(out)
    assert abs(float(np.median(disparity[pair.reliable & (pair.disparity < 0)])) + 6.0) < 0.5
