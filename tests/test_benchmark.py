"""The benchmark loop end to end on a tiny dataset we render ourselves."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli import cli
from cade_cli.benchmark import run_benchmark
from cade_cli.benchmark_report import markdown
from cade_cli.errors import CadeError
from cade_cli.matching import MATCHERS, DisparityResult, Matcher
from synthetic import render_pair

DISPARITY = 5.0


@pytest.fixture
def folder_dataset(tmp_path, rng) -> Path:
    """Two scenes in the `folder` layout: RGB views whose channels respond differently."""
    root = tmp_path / "mine"
    for sub in ("left", "right", "gt"):
        (root / sub).mkdir(parents=True)
    for name in ("first", "second"):
        pair = render_pair(rng, (40, 64), background=(DISPARITY, 0.0))

        def rgb(band):  # three 'filters' with different monotone responses, stored as BGR
            return (np.stack([0.2 + 0.6 * band, band**1.5, band], axis=2) * 255).astype(np.uint8)

        cv2.imwrite(str(root / "left" / f"{name}.png"), rgb(pair.left))
        cv2.imwrite(str(root / "right" / f"{name}.png"), rgb(pair.right))
        np.save(root / "gt" / f"{name}.npy", pair.disparity)
    return root


@pytest.fixture
def oracle(monkeypatch):
    """A matcher that returns the known disparity: every score must be exactly 0."""
    def kernel(left, right, disparity_range):
        return DisparityResult(np.full(left.shape, DISPARITY, np.float32), np.ones(left.shape, bool))

    monkeypatch.setitem(MATCHERS, "oracle", Matcher("oracle", "returns the ground truth", kernel))
    return "oracle"


def test_a_matcher_returning_the_ground_truth_scores_zero(folder_dataset, oracle):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=[oracle],
                        protocols=["cs", "rgb", "native"], preprocess=["none"])
    assert len(run.records) == 2 * (6 + 1 + 1)  # scenes x (CS tasks + RGB median + native)
    for record in run.records:
        assert record.scores["epe_all"] == 0.0
        assert all(record.scores[f"bad{t}_all"] == 0.0 for t in (1, 2, 3, 5))
        assert record.scores["invalid"] == 0.0
    assert [row["protocol"] for row in run.summary()] == ["cs", "rgb", "native"]


def test_a_real_matcher_scores_plausibly_and_orders_columns(folder_dataset):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["census-sgm", "sgbm"],
                        protocols=["cs"], preprocess=["none", "cade"])
    rows = run.summary()
    assert [(r["method"], r["preprocess"]) for r in rows] == [
        ("census-sgm", "none"), ("census-sgm", "cade"), ("sgbm", "none"), ("sgbm", "cade")]
    census = rows[0]["scores"]
    assert census["epe_all"] < 1.0 and census["bad3_all"] < 10.0
    assert rows[0]["maps"] == 2 * 6


def test_jobs_do_not_change_the_results(folder_dataset):
    kwargs = dict(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["cs", "rgb"],
                  preprocess=["cade"])
    serial, parallel = run_benchmark(jobs=1, **kwargs), run_benchmark(jobs=2, **kwargs)
    strip = lambda run: [(r.scene, r.task, r.scores) for r in run.records]  # noqa: E731
    assert strip(serial) == strip(parallel)


def test_save_dir_writes_disparities_and_error_maps(folder_dataset, tmp_path):
    save = tmp_path / "saved"
    run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["rgb"],
                  preprocess=["none"], scenes=["first"], save_dir=save)
    folder = save / "sgbm+none" / "rgb"
    assert sorted(p.name for p in folder.iterdir()) == ["first_RGB-median.pfm", "first_RGB-median_error.png"]


def test_unknown_names_fail_with_the_choices(folder_dataset):
    with pytest.raises(CadeError, match="census-sgm"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["nope"], protocols=["cs"], preprocess=["none"])
    with pytest.raises(CadeError, match="cs"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["xx"], preprocess=["none"])
    with pytest.raises(CadeError, match="second"):
        run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["cs"],
                      preprocess=["none"], scenes=["third"])


def test_cli_writes_json_and_markdown(folder_dataset, tmp_path, capsys):
    out_json, out_md = tmp_path / "r.json", tmp_path / "r.md"
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--methods", "sgbm",
                  "--protocol", "cs", "--preprocess", "cade", "--json", str(out_json), "--report", str(out_md)])
    assert exit_info.value.code == 0
    printed = capsys.readouterr().out
    assert "sgbm + cade" in printed and "all pixels with ground truth" in printed
    data = json.loads(out_json.read_text())
    assert len(data["records"]) == 12 and data["summary"][0]["method"] == "sgbm"
    report = out_md.read_text()
    assert "folder (64x40, 2 scenes)" in report and "| sgbm + cade |" in report


def test_cli_bad_dataset_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "nope", "--data-dir", str(tmp_path)])
    err = capsys.readouterr().err
    assert exit_info.value.code != 0 and len(err.strip().splitlines()) == 1 and "middlebury14" in err


def test_markdown_names_resolution_and_pixel_set(folder_dataset, oracle):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=[oracle], protocols=["cs"],
                        preprocess=["none"])
    text = markdown(run, command="cade benchmark ...")
    assert "all pixels with ground truth" in text and "non-occluded" not in text  # folder has no masks
    assert "| oracle + none | 0.00 | 0.0 | 0.0 |" in text
