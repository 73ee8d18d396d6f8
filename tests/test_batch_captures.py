"""cade batch --captures: a drone flight's band files grouped into captures by the capture id in
their metadata (file names shuffled), one cube per capture, resumed, the same cubes on two
worker processes and on a Dask cluster, panel shots skipped, a broken capture failing alone."""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest
import tifffile

from capture_scenes import write_capture
from cli_runner import run_cade
from cade_cli.capture.flight import capture_name, group_captures

SIZE = (96, 72)
IDS = {"IMG_0001": "FIRST", "IMG_0002": "SECOND", "IMG_0003": "THIRD"}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Three synthetic captures (each its own texture) in one folder, written once for the module."""
    folder = tmp_path_factory.mktemp("rendered") / "flight"
    rng = np.random.default_rng(7)
    for name, capture_id in IDS.items():
        write_capture(folder, rng, size=SIZE, name=name, capture_id=capture_id)
    return folder


@pytest.fixture
def flight(rendered, tmp_path):
    """A copy of the three captures whose names are shuffled across captures: IMG_0001's Green
    file is called IMG_0002_2.tif and the reverse, IMG_0002's NIR is IMG_0003_4.tif and the
    reverse; plus a TIFF that is no band file."""
    folder = tmp_path / "flight"
    shutil.copytree(rendered, folder)
    for a, b in (("IMG_0001_2", "IMG_0002_2"), ("IMG_0002_4", "IMG_0003_4")):
        (folder / f"{a}.tif").rename(folder / "swap.tif")
        (folder / f"{b}.tif").rename(folder / f"{a}.tif")
        (folder / "swap.tif").rename(folder / f"{b}.tif")
    tifffile.imwrite(folder / "notes.tif", np.zeros((4, 4), np.uint8))
    return folder


def digests(folder):
    return {path.name: hashlib.sha256(path.read_bytes()).hexdigest() for path in sorted(folder.glob("*.tif"))}


def test_a_flight_is_grouped_by_capture_id_one_cube_each_and_resumes(flight, tmp_path, capsys):
    out = tmp_path / "cubes"
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only"], capsys)
    assert code == 0, err
    assert "notes.tif skipped" in err and "3 done, 0 already finished, 0 failed, of 3 captures" in stdout
    assert sorted(digests(out)) == ["IMG_0001.tif", "IMG_0002.tif", "IMG_0003.tif"]
    # the reference band is carried bit-exact: IMG_0001's cube holds the Green of the file with its
    # capture id, which is now named IMG_0002_2.tif (grouped by names, it would hold the other one)
    for cube, green in (("IMG_0001", "IMG_0002_2"), ("IMG_0002", "IMG_0001_2"), ("IMG_0003", "IMG_0003_2")):
        pages = tifffile.imread(out / f"{cube}.tif")
        assert pages.shape == (5, SIZE[1], SIZE[0])
        assert np.array_equal(pages[1], tifffile.imread(flight / f"{green}.tif").astype(np.float32))
        record = json.loads((out / f"{cube}.tif.cade.json").read_text())
        assert record["registration"]["Green"] == "reference" and set(record["registration"]) == {
            "Blue", "Green", "Red", "NIR", "Red edge"}
    log = json.loads((out / "cade-batch-log.json").read_text())
    assert sorted(entry["name"] for entry in log["captures"]) == ["IMG_0001", "IMG_0002", "IMG_0003"]
    assert {len(entry["inputs"]) for entry in log["captures"]} == {5}
    before = {path.name: path.stat().st_mtime_ns for path in out.iterdir() if path.suffix == ".tif"}
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only"], capsys)
    assert code == 0 and "0 done, 3 already finished" in stdout and "3 of 3 captures already finished" in err
    assert before == {path.name: path.stat().st_mtime_ns for path in out.iterdir() if path.suffix == ".tif"}
    (out / "IMG_0002.tif").write_bytes(b"damaged")  # a damaged cube is redone, the others kept
    code, stdout, _ = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only"], capsys)
    assert code == 0 and "1 done, 2 already finished" in stdout
    code, stdout, _ = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only", "--dtype", "uint16"], capsys)
    assert code == 0 and "3 done, 0 already finished" in stdout  # other options: redone
    assert (out / "IMG_0001.valid.tif").is_file() and tifffile.imread(out / "IMG_0001.tif").dtype == np.uint16


def test_two_jobs_and_a_dask_cluster_give_the_cubes_of_one(flight, tmp_path, capsys):
    code, _, err = run_cade(["batch", "--captures", flight, "-o", tmp_path / "one", "--plane-only"], capsys)
    assert code == 0, err
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", tmp_path / "two", "--plane-only", "--jobs",
                                  "2"], capsys)
    assert code == 0 and "2 local job(s)" in stdout, err
    assert digests(tmp_path / "two") == digests(tmp_path / "one") and len(digests(tmp_path / "one")) == 3
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        code, stdout, err = run_cade(["batch", "--captures", flight, "-o", tmp_path / "dask", "--plane-only",
                                      "--scheduler", cluster.scheduler_address], capsys)
    assert code == 0 and "3 done" in stdout and "dask tcp://127.0.0.1" in stdout, err
    assert digests(tmp_path / "dask") == digests(tmp_path / "one")


def test_panel_shots_are_skipped_with_a_note(flight, tmp_path, capsys):
    write_capture(flight, np.random.default_rng(3), size=SIZE, name="IMG_0000", capture_id="PANEL", panel=True)
    out = tmp_path / "cubes"
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only", "--skip-panels"], capsys)
    assert code == 0, err
    assert "IMG_0000: a calibration panel shot (tagged Camera:CalibrationPicture): skipped" in err
    assert "of 3 captures" in stdout and not (out / "IMG_0000.tif").exists()
    # MicaSense tags no panel: --panel names it (by name or capture id)
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only", "--skip-panels",
                                  "--panel", "IMG_0003", "--panel", "SECOND"], capsys)
    assert code == 0 and "IMG_0003: a calibration panel shot (named by --panel): skipped" in err
    assert "IMG_0002: a calibration panel shot (named by --panel)" in err and "of 1 captures" in stdout
    # without --skip-panels the panel is registered, with a note saying how to leave it out
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only"], capsys)
    assert code == 0 and "1 done, 3 already finished" in stdout and "--skip-panels leaves it out" in err


def test_a_broken_capture_fails_alone_and_the_log_says_why(flight, tmp_path, capsys):
    rng = np.random.default_rng(5)
    write_capture(flight, rng, size=SIZE, name="IMG_0004", capture_id="NO_ROTATION",
                  drop=("Red", "Camera:RigRelatives"))
    write_capture(flight, rng, size=SIZE, name="IMG_0005", capture_id="SHORT")
    (flight / "IMG_0005_5.tif").unlink()  # a band missing
    broken = flight / "IMG_0003_1.tif"
    broken.write_bytes(broken.read_bytes()[:4000])  # its tags readable, its pixels cut short
    out = tmp_path / "cubes"
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", out, "--plane-only", "--jobs", "2"], capsys)
    assert code == 1 and "2 done, 0 already finished, 3 failed, of 5 captures" in stdout
    assert sorted(digests(out)) == ["IMG_0001.tif", "IMG_0002.tif"]
    errors = {entry["name"]: entry.get("error") for entry in json.loads((out / "cade-batch-log.json").read_text())[
        "captures"]}
    assert "IMG_0003_1.tif: cannot read its pixels" in errors["IMG_0003"]
    assert "IMG_0004_3.tif: no Camera:RigRelatives in its metadata" in errors["IMG_0004"]
    assert errors["IMG_0005"].startswith("no Red edge (rig index 4) band file: a MicaSense RedEdge-M has Blue, "
                                         "Green, Red, NIR, Red edge")
    assert "warning: capture IMG_0004 failed" in err and err.strip().splitlines()[-1].startswith("cade: error: 3 of 5")
    assert not list(out.glob(".*tmp*"))  # nothing half-written


def test_flight_errors_are_one_line(flight, tmp_path, capsys):
    cases = [
        (["--captures", flight, "-o", tmp_path / "o", "--left", "a/*.png"], "--left belongs to a batch of pairs"),
        (["--captures", flight], "missing --output-dir"),
        (["--left", "a", "--right", "b", "-o", tmp_path / "o", "--skip-panels"],
         "--skip-panels is an option of a flight"),
        (["--captures", flight, "-o", tmp_path / "o", "--panel", "IMG_9"], "--panel IMG_9 names no capture"),
        (["--captures", flight, "-o", tmp_path / "o", "--dtype", "int8"], "unknown --dtype 'int8'"),
        (["--captures", tmp_path / "o2", "-o", tmp_path / "o"], "no capture found"),
    ]
    (tmp_path / "o2").mkdir()
    for args, message in cases:
        code, _, err = run_cade(["batch", *args], capsys)
        assert code != 0 and message in err and len(err.strip().splitlines()) == 1, (args, err)
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").glob("*.tif"))


def test_a_capture_is_named_by_the_name_most_of_its_files_share(tmp_path):
    names = ["IMG_0001_1.tif", "IMG_0001_2.tif", "IMG_0002_3.tif", "IMG_0001_4.tif", "IMG_0001_5.tif"]
    assert capture_name([tmp_path / name for name in names]) == "IMG_0001"
    sequoia = [f"IMG_180413_080658_0000_{band}.TIF" for band in ("GRE", "RED", "REG", "NIR")]
    assert capture_name([tmp_path / name for name in sequoia]) == "IMG_180413_080658_0000"
    assert capture_name([tmp_path / name for name in ("a_1.tif", "b_2.tif", "c_3.tif")]) is None


def test_the_real_captures_are_grouped_by_their_ids(shared_data):
    folder = shared_data / "micasense"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    captures, notes = group_captures(folder)
    assert not notes
    found = {(str(capture.folder), capture.name): len(capture.paths) for capture in captures}
    assert found == {("rededge-m-bench", "IMG_0001"): 5, ("rededge-m-bench", "IMG_0007"): 5,
                     ("rededge-m-field", "IMG_0008"): 5, ("sequoia-tabletop", "IMG_180413_080658_0000"): 4,
                     ("rededge-m-field", "IMG_0000"): 5, ("rededge-mx-dual", "IMG_0000"): 10}  # two panel shots
    assert all(capture.problem is None for capture in captures)  # 4 bands: another camera; 10: the Dual
    assert {(str(c.folder), c.name) for c in captures if c.panel} == {("rededge-m-field", "IMG_0000"),
                                                                      ("rededge-mx-dual", "IMG_0000")}


def test_jobs_are_lowered_to_what_the_largest_capture_leaves_room_for(flight, tmp_path, capsys, monkeypatch):
    from cade_cli.batch import engines as batch
    from cade_cli.batch.captures import (CAPTURE_MATCHING_BYTES, CAPTURE_PIXEL_BYTES, CaptureJob,
                                               capture_memory_bytes)

    small = CaptureJob("a", tuple(sorted(flight.glob("IMG_0001_*.tif"))), tmp_path / "a.tif")
    size, planned = capture_memory_bytes([small])
    assert size == f"5 bands of {SIZE[0]}x{SIZE[1]}"
    assert planned == batch.BASE_BYTES + CAPTURE_MATCHING_BYTES + CAPTURE_PIXEL_BYTES * 5 * SIZE[0] * SIZE[1]
    monkeypatch.setattr(batch, "available_memory_bytes", lambda: int(1.5 * planned / batch.MEMORY_HEADROOM))
    code, stdout, err = run_cade(["batch", "--captures", flight, "-o", tmp_path / "o", "--plane-only", "--jobs", "2"],
                                 capsys)
    assert code == 0 and "--jobs 2 lowered to 1: the largest capture, 5 bands of 96x72" in err
    assert "1 local job(s)" in stdout


def test_a_flight_without_a_terminal_logs_its_progress(flight, tmp_path, capsys, monkeypatch):
    """As the pair batch: without a terminal, a plain line (captures done of all, elapsed) every
    interval, here 20 ms with each capture made 50 ms slower (one job: they run in this process)."""
    import re
    import time

    import cade_cli.batch.engines
    from cade_cli.cli import options

    attempt = cade_cli.batch.engines._attempt
    monkeypatch.setattr(cade_cli.batch.engines, "_attempt", lambda job: time.sleep(0.05) or attempt(job))
    monkeypatch.setattr(options, "PLAIN_PROGRESS_SECONDS", 0.02)
    code, _, err = run_cade(["batch", "--captures", flight, "-o", tmp_path / "cubes", "--plane-only"], capsys)
    assert code == 0, err
    lines = re.findall(r": (\d+) of 3 captures done, \d+ min \d\d s$", err, flags=re.M)
    assert lines and [int(done) for done in lines] == sorted(int(done) for done in lines)


def test_a_capture_record_fingerprints_the_network_as_a_pair_record_does():
    """One digest of a learned method's network for both kinds of batch record (the model card's
    network files by sha256, its non-default runtime settings); none for a classical matcher or
    without dense matching."""
    from cade_cli.matching import method_fingerprint
    from cade_cli.model_card import network_fingerprint
    from cade_cli.batch.captures import CaptureOptions
    from cade_cli.batch.pairs import PairOptions

    for model in ("fast", "accurate"):
        digest = network_fingerprint(model)
        assert digest["model_sha256"] and method_fingerprint("cade", model=model) == digest
        capture = CaptureOptions(method="cade", model=model).fingerprint()
        pair = PairOptions(method="cade", model=model).fingerprint()
        assert {key: capture[key] for key in digest} == {key: pair[key] for key in digest} == digest
    assert method_fingerprint("sgbm") == {}
    assert "model_sha256" not in CaptureOptions(method="sgbm").fingerprint()
    assert "model_sha256" not in CaptureOptions(method="cade", plane_only=True).fingerprint()


def test_a_capture_record_holds_the_near_factor_a_run_before_near_matches_1():
    """A changed --near changes the record (the capture is redone); --near 1, the search of the runs
    before --near existed, leaves it out, so their records still hold; without dense matching it
    decides nothing."""
    import inspect

    from cade_cli.batch.captures import CaptureOptions
    from cade_cli.capture.register import NEAR_FACTOR
    from cade_cli.cli.batch_captures import FlightArguments

    assert CaptureOptions().near == FlightArguments().near == NEAR_FACTOR
    assert inspect.signature(CaptureOptions).parameters["near"].default == NEAR_FACTOR
    default, wider, own = (CaptureOptions(method="sgbm", near=near).fingerprint() for near in (NEAR_FACTOR, 8.0, 1.0))
    assert default["near"] == NEAR_FACTOR and wider["near"] == 8.0 and "near" not in own
    assert len({json.dumps(options, sort_keys=True) for options in (default, wider, own)}) == 3
    assert "near" not in CaptureOptions(plane_only=True, near=8.0).fingerprint()
