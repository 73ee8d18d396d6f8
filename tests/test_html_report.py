"""The HTML report of ``cade benchmark --html`` on a tiny dataset we render ourselves: every
scene, task and method is on the page, its pictures decode, it is refused with a wrong
suffix before any work, and a real headless Chromium renders it with the pictures visible."""

from __future__ import annotations

import base64
import json
import re
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli import __version__, cli
from cade_cli.errors import CadeError
from cade_cli.evaluation.album import TILE_WIDTH
from cade_cli.evaluation.html_report import html_report
from cade_cli.evaluation.loop import BenchmarkRun, Record, run_benchmark
from cade_cli.evaluation.report import markdown, table, title
from cade_cli.io.pictures import MIN_WIDTH
from cade_cli.model_card import DEFAULT_MODEL, describe_model
from synthetic import render_pair

CHROMIUM = Path("/usr/bin/chromium")
SCENES = ("first", "second")
TASKS = ("R&gt;G", "R&gt;B", "G&gt;R", "G&gt;B", "B&gt;R", "B&gt;G", "RGB-median")  # as the page escapes them


def pictures_of(page: str) -> list[np.ndarray]:
    """Every embedded picture of ``page``, decoded."""
    data = re.findall(r'src="data:image/(?:jpeg|png);base64,([A-Za-z0-9+/=]+)"', page)
    return [cv2.imdecode(np.frombuffer(base64.b64decode(item), np.uint8), cv2.IMREAD_COLOR) for item in data]


@pytest.fixture(scope="module")
def report_page(tmp_path_factory) -> Path:
    """``cade benchmark --html`` of the two-scene folder dataset: sgbm, CS and RGB; run once for
    the tests that only read the page."""
    from conftest import write_folder_dataset

    root = tmp_path_factory.mktemp("report")
    data = write_folder_dataset(root / "mine", np.random.default_rng(20240414))
    return html_of(data, root / "report.html", None, protocol="cs,rgb", preprocess="none,cade")


def html_of(data_dir: Path, page: Path, capsys, *, protocol: str, preprocess: str, extra=()) -> Path:
    """Run ``cade benchmark --html page`` with sgbm on the folder dataset at ``data_dir``
    (``capsys``: to show stderr on failure, None outside a test's own scope)."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(data_dir), "--methods", "sgbm",
                  "--protocol", protocol, "--preprocess", preprocess, "--html", str(page), *extra])
    assert exit_info.value.code == 0, "" if capsys is None else capsys.readouterr().err
    return page


def test_the_page_holds_every_scene_task_and_method_with_decodable_pictures(report_page):
    page = report_page.read_text(encoding="utf-8")
    for text in (*SCENES, *TASKS, "sgbm + none", "sgbm + cade", f"<td>{__version__}</td>",
                 "all pixels with ground truth"):
        assert text in page
    pictures = pictures_of(page)
    # per scene, of its first task (CS R>G) only: the ground truth, 2 bands, then a
    # disparity and an error picture per method and preprocessing (2); every task's scores in the tables
    assert len(pictures) == len(SCENES) * (1 + 2 + 2 * 2)
    assert page.count("<h3 id=") == len(SCENES) and "first: CS R&gt;G</h3>" in page
    assert all(f"<td>{scene}</td><td>rgb</td><td>RGB-median</td>" in page for scene in SCENES)
    assert all(picture is not None and picture.size for picture in pictures)
    assert max(picture.shape[1] for picture in pictures) <= max(TILE_WIDTH, MIN_WIDTH)
    assert "http://" not in page and "https://" not in page  # self-contained: nothing to fetch


def test_every_task_s_pictures_with_html_pictures_all(folder_dataset, tmp_path, capsys):
    page = html_of(folder_dataset, tmp_path / "all.html", capsys, protocol="cs,rgb", preprocess="none,cade",
                   extra=["--html-pictures", "all"]).read_text(encoding="utf-8")
    # per scene and task (6 CS + the RGB median): the ground truth, 2 bands, then 2 pictures per method row (2)
    assert len(pictures_of(page)) == len(SCENES) * len(TASKS) * (1 + 2 + 2 * 2)
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--html-pictures", "some"])
    assert exit_info.value.code == 1 and "--html-pictures 'some'" in capsys.readouterr().err


FULL_RUN_SCENES = 15
"""Middlebury 2014's training scenes: what a whole run of ``cade benchmark -d middlebury14`` pictures."""
FULL_RUN_PICTURE_PX = 360 * 300
"""A Middlebury 2014 picture at the report's width (its scenes are about 0.7 as high as wide,
plus a legend under the maps), px."""
MAX_PAGE_BYTES = 15_000_000


def test_a_whole_middlebury_run_s_page_stays_under_15_mb_in_proportion(picture_page):
    """Scaled by picture area from this run (a 300 px wide textured scene), the page of a whole
    Middlebury 2014 run with the default methods stays under 15 MB."""
    from cade_cli.cli.options import BENCHMARK_METHODS
    from cade_cli.evaluation.loop import takes_preprocess
    from cade_cli.matching import MATCHERS

    page = picture_page.read_text(encoding="utf-8")
    data = re.findall(r'src="data:image/(?:jpeg|png);base64,([A-Za-z0-9+/=]+)"', page)
    pixels = sum(picture.shape[0] * picture.shape[1] for picture in pictures_of(page))
    bytes_per_px = sum(len(item) for item in data) / pixels
    rows = sum(takes_preprocess(MATCHERS[method], value) for method in BENCHMARK_METHODS for value in ("none", "cade"))
    pictures = FULL_RUN_SCENES * (1 + 2 + 2 * rows)  # ground truth, bands, a disparity and an error per row
    around = len(page) - sum(len(item) for item in data)  # tables and text, for one scene and one row
    assert bytes_per_px * FULL_RUN_PICTURE_PX * pictures + around * FULL_RUN_SCENES * rows < MAX_PAGE_BYTES


def test_the_best_figure_of_each_column_is_marked_and_the_labels_explained(report_page):
    page = report_page.read_text(encoding="utf-8")
    tables = re.findall(r"<thead>(.*?)</thead><tbody>(.*?)</tbody>", page)
    summary = [(head, body) for head, body in tables if head.startswith("<tr><th>method</th>")]
    assert summary
    for head, body in summary:
        names = re.findall(r"<th>(.*?)</th>", head)
        rows = [re.findall(r"<td( class=\"best\")?>(.*?)</td>", row) for row in re.findall(r"<tr>(.*?)</tr>", body)]
        for column in range(1, len(names)):
            values = [float(row[column][1]) for row in rows if row[column][1] not in ("—", "nan")]
            marked = [float(row[column][1]) for row in rows if row[column][0]]
            best = max(values) if names[column].endswith("gain %") else min(values)
            assert marked and all(value == best for value in marked), (names[column], values, marked)
    for text in ("How to read this page", "METHOD + none", "METHOD + cade", "CS (protocol)", "RGB (protocol)",
                 "cross-spectral: six tasks", "black = the matcher rejected the pixel"):
        assert text in page


def test_a_disparity_picture_draws_rejected_pixels_black():
    """A filled map (every pixel a value) whose left half the matcher rejected: its picture is
    black there and coloured elsewhere, though the error picture scores the filled map."""
    from types import SimpleNamespace

    from cade_cli.evaluation.album import SceneAlbum

    truth = np.tile(np.linspace(5, 20, 200, dtype=np.float32), (120, 1))
    view = np.zeros((120, 200, 3), np.float32)
    scene = SimpleNamespace(name="s", disparity=truth, max_disp=32, left=view, right=view)
    album = SceneAlbum.of(scene, width=TILE_WIDTH)
    valid = np.ones_like(truth, bool)
    valid[:, :100] = False
    record = SimpleNamespace(protocol="native", method="m", preprocess="none", degradation="none", task="grey")
    album.add(record, truth, scene, valid=valid)
    disparity, error = (cv2.imdecode(np.frombuffer(item, np.uint8), cv2.IMREAD_COLOR) for item in
                        album.maps[("native", "m", "none", "none", "grey")])
    top = disparity[5:100]  # the map, above its legend
    left, right = top[:, 10:90].max(axis=2), top[:, 110:190].max(axis=2)
    assert np.median(left) < 30 and np.median(right) > 100


def test_the_header_names_the_network_and_its_sha256(folder_dataset, tmp_path, capsys):
    page = tmp_path / "report.htm"
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--methods", "cade-network",
                  "--protocol", "native", "--scenes", "first", "--html", str(page), "--json", str(tmp_path / "r.json")])
    assert exit_info.value.code == 0, capsys.readouterr().err
    model = describe_model(DEFAULT_MODEL)
    text = page.read_text(encoding="utf-8")
    assert model["sha256"] in text and model["variants"][0]["sha256"] in text and "model of cade-network" in text
    assert json.loads((tmp_path / "r.json").read_text())["config"]["models"] == {"cade-network": model}


def test_a_wrong_suffix_is_refused_before_any_work(folder_dataset, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("cade_cli.evaluation.loop.run_benchmark", lambda **_: pytest.fail("the run started"))
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["benchmark", "--dataset", "folder", "--data-dir", str(folder_dataset), "--methods", "sgbm",
                  "--html", str(tmp_path / "report.txt")])
    err = capsys.readouterr().err
    assert exit_info.value.code != 0 and len(err.strip().splitlines()) == 1 and ".html" in err
    assert not (tmp_path / "report.txt").exists()


def test_a_run_without_pictures_is_refused(folder_dataset):
    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm"], protocols=["native"],
                        preprocess=["none"], scenes=["first"])
    with pytest.raises(CadeError, match="--html"):
        html_report(run)


def test_kitti_tables_add_d1():
    scores = {"epe_all": 1.0, "bad3_all": 10.0, "bad5_all": 5.0, "d1_all": 7.5, "invalid": 0.0}
    record = Record(dataset="kitti2015", resolution="1242x375", scene="000000_10", protocol="native",
                    method="sgbm", preprocess="none", task="grey", seconds=0.5, matcher_runs=1, scores=scores)
    run = BenchmarkRun({"dataset": "kitti2015", "scenes": ["000000_10"], "methods": ["sgbm"],
                        "protocols": ["native"], "preprocess": ["none"]}, [record])
    header, rows = table(run, "all")
    assert header == ["method", "NATIVE EPE", "NATIVE BMP3", "NATIVE BMP5", "NATIVE D1", "s / pair"]
    assert rows == [["sgbm + none", "1.00", "10.0", "5.0", "7.5", "0.50"]]
    assert "D1 % off by > 3 px and > 5 %" in title(run, "all")
    assert "| D1 all |" in markdown(run) and "| 7.50 |" in markdown(run)
    middlebury = BenchmarkRun({**run.config, "dataset": "middlebury14"}, [record])
    assert "D1" not in " ".join(table(middlebury, "all")[0]) and "D1" not in markdown(middlebury)


@pytest.fixture
def picture_page(tmp_path, rng, capsys) -> Path:
    """``cade benchmark --html`` of one 180 x 300 px scene (a sloped plane and a nearer box),
    big enough that its pictures fill much of a browser window."""
    root = tmp_path / "scenes"
    for sub in ("left", "right", "gt"):
        (root / sub).mkdir(parents=True)
    pair = render_pair(rng, (180, 300), background=(4.0, 0.05), foreground=(14.0, 0.0))
    for side, band in (("left", pair.left), ("right", pair.right)):
        cv2.imwrite(str(root / side / "scene.png"), (np.stack([band, band**1.5, 0.2 + 0.6 * band], axis=2) * 255)
                    .astype(np.uint8))
    np.save(root / "gt" / "scene.npy", pair.disparity)
    return html_of(root, tmp_path / "pictures.html", capsys, protocol="native", preprocess="none")


@pytest.mark.skipif(not CHROMIUM.exists(), reason="no /usr/bin/chromium (Debian package chromium)")
def test_chromium_renders_the_page_with_its_pictures(picture_page, tmp_path):
    screenshot = tmp_path / "shot.png"
    command = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--hide-scrollbars", f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={screenshot}",
               "--window-size=1280,1600", picture_page.as_uri()]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert screenshot.is_file(), done.stderr[-2000:]
    shot = cv2.imread(str(screenshot), cv2.IMREAD_COLOR)
    assert shot.shape[:2] == (1600, 1280)
    # text and tables are grey on white; the pictures (Turbo, inferno) are colourful
    colourful = (shot.max(axis=2).astype(int) - shot.min(axis=2)) > 80
    assert colourful.mean() > 0.02, "no pictures visible in the rendering"
    rows = np.flatnonzero(colourful.mean(axis=1) > 0.05)
    assert rows.size > 100  # several hundred rows of pictures, not a stray coloured line
    picture_area = shot[rows.min():rows.max() + 1]
    assert len(np.unique(picture_area.reshape(-1, 3), axis=0)) > 300  # colour ramps, not flat fills


def test_the_page_says_what_was_left_out_and_why(folder_dataset):
    from cade_cli.evaluation.html_report import html_report
    from cade_cli.evaluation.loop import run_benchmark

    run = run_benchmark(dataset="folder", data_dir=folder_dataset, methods=["sgbm", "cade-network"],
                        protocols=["native"], preprocess=["none", "cade"], scenes=["first"], tile_width=200)
    page = html_report(run)
    assert "<th>left out</th><td>cade-network + none: method cade-network takes --preprocess cade" in page
    assert "cade-network + cade" in page and "sgbm + none" in page
