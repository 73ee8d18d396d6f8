"""Errors by region: the masks on scenes whose occlusions and edges we know by construction,
the left-right check of a two-view ground truth, KITTI's noc/occ split, and the records,
tables and reports that carry the region rows."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli import cli
from cade_cli.data import get_dataset, nonoccluded_mask
from cade_cli.errors import CadeError
from cade_cli.evaluation import loop
from cade_cli.evaluation.html_report import html_report
from cade_cli.evaluation.loop import run_benchmark
from cade_cli.evaluation.metrics import score
from cade_cli.evaluation.regions import EDGE_RADIUS, depth_jumps, region_masks
from cade_cli.evaluation.report import markdown
from cade_cli.matching import DisparityResult

# A foreground square at disparity FORE over a background at BACK, in both views.
HEIGHT, WIDTH = 40, 420  # 420 px: a Middlebury 2005 ThirdSize width
BACK, FORE = 4, 12
TOP, X0, SIZE = 10, 200, 20


def square_gt(*, view: str) -> np.ndarray:
    """The GT of one view: the square at columns [X0, X0 + SIZE) in the left view, shifted left
    by FORE in the right view (``I_left(x) = I_right(x - d)``)."""
    gt = np.full((HEIGHT, WIDTH), float(BACK), np.float32)
    x0 = X0 if view == "left" else X0 - FORE
    gt[TOP:TOP + SIZE, x0:x0 + SIZE] = FORE
    return gt


def expected_occluded() -> np.ndarray:
    """Left pixels the right view does not see: the background band of width FORE - BACK left of
    the square (hidden behind it in the right view) and the first BACK columns (out of view)."""
    occluded = np.zeros((HEIGHT, WIDTH), bool)
    occluded[TOP:TOP + SIZE, X0 - (FORE - BACK):X0] = True
    occluded[:, :BACK] = True
    return occluded


def test_the_left_right_check_finds_the_occluded_band_of_width_fore_minus_back():
    nonocc = nonoccluded_mask(square_gt(view="left"), square_gt(view="right"))
    np.testing.assert_array_equal(~nonocc, expected_occluded())
    band = ~nonocc[TOP + SIZE // 2, BACK:X0]
    assert band.sum() == FORE - BACK  # one row through the square: the band's width


def test_region_masks_put_occluded_edge_and_visible_pixels_where_they_must_be():
    regions = region_masks(square_gt(view="left"), nonocc=~expected_occluded())
    np.testing.assert_array_equal(regions["occ"], expected_occluded())
    np.testing.assert_array_equal(regions["nonocc"], ~expected_occluded())
    edge, row = regions["edge"], TOP + SIZE // 2
    right_side = X0 + SIZE  # first background column right of the square: on the jump
    assert edge[row, right_side + EDGE_RADIUS] and not edge[row, right_side + EDGE_RADIUS + 1]
    assert edge[row, right_side - 1 - EDGE_RADIUS] and not edge[row, right_side - 1 - EDGE_RADIUS - 1]
    assert edge[TOP + EDGE_RADIUS, X0 + SIZE // 2] and not edge[TOP + EDGE_RADIUS + 1, X0 + SIZE // 2]
    assert edge[TOP - 1 - EDGE_RADIUS, X0 + SIZE // 2] and not edge[TOP - 2 - EDGE_RADIUS, X0 + SIZE // 2]
    assert not (edge & regions["occ"]).any()  # the band left of the square is occluded, not edge
    assert edge[row, X0] and not edge[row, X0 - 1]  # the square's own left side is visible
    assert not edge[:, :X0 - (FORE - BACK) - EDGE_RADIUS - 1].any()  # flat background far from it


def test_an_error_only_in_the_occluded_band_shows_in_occ_and_not_in_nonocc():
    gt = square_gt(view="left")
    regions = region_masks(gt, nonocc=nonoccluded_mask(gt, square_gt(view="right")))
    pred = gt.copy()
    pred[TOP:TOP + SIZE, X0 - (FORE - BACK):X0] = FORE  # the square bleeds into the band: 8 px off
    scores = score(pred, gt, **regions)
    assert scores["epe_nonocc"] == 0.0 and scores["bad3_nonocc"] == 0.0 and scores["bad3_edge"] == 0.0
    band = (FORE - BACK) * SIZE
    assert scores["bad3_occ"] == pytest.approx(100.0 * band / regions["occ"].sum())
    assert scores["epe_occ"] == pytest.approx((FORE - BACK) * band / regions["occ"].sum())
    assert scores["bad3_all"] == pytest.approx(100.0 * band / gt.size)


def test_an_error_along_the_square_s_visible_side_shows_in_edge_and_nonocc_not_occ():
    gt = square_gt(view="left")
    regions = region_masks(gt, nonocc=~expected_occluded())
    pred = gt.copy()
    pred[TOP:TOP + SIZE, X0 + SIZE:X0 + SIZE + 2] = FORE  # the square's right side bleeds 2 px out
    scores = score(pred, gt, **regions)
    assert scores["bad3_occ"] == 0.0
    assert scores["bad3_edge"] > 10 * scores["bad3_nonocc"] > 0


def test_a_jump_needs_two_neighbours_with_gt_that_differ_by_more_than_2_px():
    gt = np.array([[1.0, 3.0, 3.0, np.nan, 9.0, 9.0],
                   [1.0, 1.0, 1.0, 1.0, 1.0, 5.5]], np.float32)
    jumps = depth_jumps(gt)
    # 1 -> 3 is exactly 2 px: no jump; NaN next to 9 is none; 9 over 1 (vertical) and 1 -> 5.5 are
    np.testing.assert_array_equal(jumps, [[False, False, False, False, True, True],
                                          [False, False, False, False, True, True]])
    assert not depth_jumps(np.full((4, 4), np.nan)).any()


def test_without_occlusion_information_only_edges_and_no_region_without_a_pixel():
    gt = square_gt(view="left")
    only_edges = region_masks(gt, nonocc=None)
    assert list(only_edges) == ["edge"]
    assert only_edges["edge"][TOP + SIZE // 2, X0 - 1]  # no occlusion to take out
    flat = np.full((8, 8), 3.0, np.float32)
    assert region_masks(flat, nonocc=None) == {}
    assert list(region_masks(flat, nonocc=np.ones((8, 8), bool))) == ["nonocc"]
    with pytest.raises(CadeError, match="bool mask"):
        region_masks(flat, nonocc=np.ones((8, 8), np.uint8))


# --- through the readers and the loop ---------------------------------------------------

def _texture(rng: np.random.Generator) -> np.ndarray:
    return rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)


def write_kitti(root: Path, rng: np.random.Generator) -> Path:
    """One KITTI 2015 frame: disp_occ_0 holds every pixel of the square scene, disp_noc_0 leaves
    out the occluded band and the out-of-view columns; a 16-pixel hole has no GT at all."""
    gt = square_gt(view="left")
    occ = np.round(gt * 256).astype(np.uint16)
    occ[0:4, 300:304] = 0
    noc = np.where(expected_occluded(), 0, occ).astype(np.uint16)
    for folder, image in (("image_2", _texture(rng)), ("image_3", _texture(rng)), ("disp_occ_0", occ),
                          ("disp_noc_0", noc)):
        (root / "training" / folder).mkdir(parents=True, exist_ok=True)
        assert cv2.imwrite(str(root / "training" / folder / "000000_10.png"), image)
    return root


class BandBleeder:
    """A matcher that knows the square scene: right everywhere but FORE in the occluded band."""

    def __call__(self, left, right, *, max_disp, min_disp=0, preprocess="auto"):
        disparity = square_gt(view="left")
        disparity[TOP:TOP + SIZE, X0 - (FORE - BACK):X0] = FORE
        return DisparityResult(disparity, np.ones(disparity.shape, bool))


def test_a_middlebury_2005_scene_reads_its_occlusions_from_both_views_gt(tmp_path, rng):
    folder = tmp_path / "middlebury2005" / "Square"
    folder.mkdir(parents=True)
    for name, image in (("view1.png", _texture(rng)), ("view5.png", _texture(rng)),
                        ("disp1.png", (3 * square_gt(view="left")).astype(np.uint8)),  # ThirdSize: 3 x d
                        ("disp5.png", (3 * square_gt(view="right")).astype(np.uint8))):
        assert cv2.imwrite(str(folder / name), image)
    scene = next(iter(get_dataset("middlebury05")(tmp_path)))
    regions = region_masks(scene.disparity, nonocc=scene.nonocc)
    np.testing.assert_array_equal(regions["occ"], expected_occluded())
    run = run_benchmark(dataset="middlebury05", data_dir=tmp_path, methods=["bleeder"],
                        matchers={"bleeder": BandBleeder()}, protocols=["cs"], tasks=["R>B"], preprocess=["none"])
    (record,) = run.records
    assert record.scores["bad3_nonocc"] == 0.0 and record.scores["bad3_occ"] > 0


def test_kitti_noc_and_occ_split_into_nonocc_and_occ(tmp_path, rng):
    root = write_kitti(tmp_path / "kitti", rng)
    scene = next(iter(get_dataset("kitti2015")(root)))
    regions = region_masks(scene.disparity, nonocc=scene.nonocc)
    hole = np.zeros((HEIGHT, WIDTH), bool)
    hole[0:4, 300:304] = True
    np.testing.assert_array_equal(regions["occ"], expected_occluded() & ~hole)
    np.testing.assert_array_equal(regions["nonocc"], ~expected_occluded() & ~hole)

    run = run_benchmark(dataset="kitti2015", data_dir=root, methods=["bleeder"], matchers={"bleeder": BandBleeder()},
                        protocols=["native"], preprocess=["none"])
    (record,) = run.records
    assert record.scores["epe_nonocc"] == 0.0 and record.scores["bad3_edge"] == 0.0
    assert record.scores["bad3_occ"] == pytest.approx(100.0 * (FORE - BACK) * SIZE / regions["occ"].sum())
    assert record.scores["epe_all"] > 0


def test_region_masks_are_computed_once_per_scene(tmp_path, rng, monkeypatch):
    root = write_kitti(tmp_path / "kitti", rng)
    calls = []
    monkeypatch.setattr(loop, "region_masks", lambda gt, **kw: calls.append(gt.shape) or region_masks(gt, **kw))
    run_benchmark(dataset="kitti2015", data_dir=root, methods=["a", "b"],
                  matchers={"a": BandBleeder(), "b": BandBleeder()}, protocols=["native", "cs"], preprocess=["none"])
    assert calls == [(HEIGHT, WIDTH)]


def test_json_markdown_and_html_carry_the_region_rows(tmp_path, rng):
    root = write_kitti(tmp_path / "kitti", rng)
    run = run_benchmark(dataset="kitti2015", data_dir=root, methods=["bleeder"], matchers={"bleeder": BandBleeder()},
                        protocols=["native"], preprocess=["none"], tile_width=64)
    data = json.loads(run.to_json())
    scores = data["records"][0]["scores"]
    for region in ("all", "nonocc", "edge", "occ"):
        assert {f"epe_{region}", f"bad3_{region}"} <= set(scores)
    assert data["summary"][0]["scores"]["bad3_occ"] == scores["bad3_occ"] > 0
    report = markdown(run)
    for heading in ("non-occluded pixels", "depth edges", "occluded pixels with ground truth"):
        assert heading in report
    assert "BMP3 occ" in report.split("## Per scene and task")[1]
    page = html_report(run)
    assert "depth edges" in page and "occluded pixels with ground truth" in page
    assert all(f"<dt>{name} (pixels)</dt>" in page for name in ("all", "nonocc", "edge", "occ"))  # the legend
    assert f"{scores['bad3_occ']:.1f}" in page


def test_the_cli_prints_a_table_per_region(tmp_path, rng, capsys):
    root = write_kitti(tmp_path / "kitti", rng)
    out = tmp_path / "run.json"
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "kitti2015", "--data-dir", str(root), "--methods", "sgbm",
                  "--protocol", "native", "--preprocess", "none", "--json", str(out)])
    assert exit_info.value.code == 0
    printed = capsys.readouterr().out
    assert "non-occluded pixels" in printed and "depth edges" in printed and "occluded pixels with" in printed
    assert "epe_occ" in json.loads(out.read_text())["records"][0]["scores"]
