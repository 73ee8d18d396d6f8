"""`cade batch`: many pairs, resume on verified outputs, failures that do not stop the rest,
worker processes and a Dask cluster giving the same bytes as one process."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.io.disparity import read_disparity
from cade_cli.batch.engines import cap_jobs, pair_memory_bytes
from cade_cli.batch.pairs import Pair, PairOptions, is_finished, pairs_from_manifest, pairs_from_patterns
from synthetic import render_pair
from cli_runner import run_cade, write_png16

FAST = ["--method", "census-sgm", "--max-disp", "16"]
"""A quick classical matcher over a small range: these tests are about the batch, not the matching."""


def cross_band_pairs(folder: Path, rng, sides: tuple[str, str], *, count: int, shape: tuple[int, int],
                     background: float) -> Path:
    """``<side>/000N.png`` for N < count: rendered pairs (background disparity ``background + N``,
    a foreground at 10 px), the right band a non-linear change of the left's."""
    for side in sides:
        (folder / side).mkdir()
    for index in range(count):
        pair = render_pair(rng, shape, background=(background + index, 0.0), foreground=(10.0, 0.0))
        write_png16(folder / sides[0] / f"{index:04d}.png", pair.left)
        write_png16(folder / sides[1] / f"{index:04d}.png", 0.1 + 0.6 * pair.right**2)
    return folder


@pytest.fixture
def cameras(tmp_path, rng) -> Path:
    """cam0/000N.png and cam1/000N.png: three cross-band pairs of known disparity."""
    return cross_band_pairs(tmp_path, rng, ("cam0", "cam1"), count=3, shape=(48, 96), background=4.0)


def batch_args(root: Path, out: str, *extra) -> list:
    return ["batch", "--left", root / "cam0" / "*.png", "--right", root / "cam1" / "*.png", "-o", root / out, *FAST,
            *extra]


def outputs(folder: Path) -> dict[str, bytes]:
    """Every disparity and side output of a batch folder (not its log, whose times differ)."""
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir()) if path.suffix in (".pfm", ".png")}


def log_of(folder: Path) -> dict:
    return json.loads((folder / "cade-batch-log.json").read_text())


def test_batch_writes_what_disparity_writes(cameras, capsys):
    code, stdout, _ = run_cade(batch_args(cameras, "out", "--vis"), capsys)
    assert code == 0 and "3 done, 0 already finished, 0 failed, of 3 pairs" in stdout
    written = outputs(cameras / "out")
    assert sorted(written) == ["0000.pfm", "0000_vis.png", "0001.pfm", "0001_vis.png", "0002.pfm", "0002_vis.png"]
    single = cameras / "single.pfm"
    assert run_cade(["disparity", cameras / "cam0" / "0001.png", cameras / "cam1" / "0001.png", "-o", single, *FAST],
                    capsys)[0] == 0
    assert written["0001.pfm"] == single.read_bytes()  # one matching code path
    disparity = read_disparity(cameras / "out" / "0002.pfm")
    assert abs(float(np.median(disparity)) - 6.0) < 0.5  # the background of pair 2
    log = log_of(cameras / "out")
    assert [entry["status"] for entry in log["pairs"]] == ["done"] * 3
    assert log["summary"]["done"] == 3 and log["config"]["options"]["method"] == "census-sgm"
    assert not [p for p in (cameras / "out").iterdir() if ".tmp-" in p.name]


def test_rerun_skips_verified_outputs_and_redoes_a_damaged_one(cameras, capsys):
    assert run_cade(batch_args(cameras, "out"), capsys)[0] == 0
    first = outputs(cameras / "out")
    code, stdout, stderr = run_cade(batch_args(cameras, "out"), capsys)
    assert code == 0 and "0 done, 3 already finished" in stdout and "3 of 3 pairs already finished" in stderr
    damaged = cameras / "out" / "0001.pfm"
    damaged.write_bytes(damaged.read_bytes()[:-4] + b"\0\0\0\0")  # same size, other content
    code, stdout, _ = run_cade(batch_args(cameras, "out"), capsys)
    assert code == 0 and "1 done, 2 already finished" in stdout
    assert [e["output"].endswith("0001.pfm") for e in log_of(cameras / "out")["pairs"] if e["status"] == "done"] == [True]
    assert outputs(cameras / "out") == first
    # Other options, other outputs: nothing is finished; --force redoes everything.
    code, stdout, _ = run_cade(batch_args(cameras, "out", "--fill", "none"), capsys)
    assert code == 0 and "3 done, 0 already finished" in stdout
    code, stdout, _ = run_cade(batch_args(cameras, "out", "--fill", "none", "--force"), capsys)
    assert code == 0 and "3 done, 0 already finished" in stdout


def test_is_finished_checks_inputs_and_record(cameras, capsys):
    assert run_cade(batch_args(cameras, "out"), capsys)[0] == 0
    options = PairOptions(method="census-sgm", max_disp=16)
    pair = Pair(cameras / "cam0" / "0000.png", cameras / "cam1" / "0000.png", cameras / "out" / "0000.pfm", options)
    assert is_finished(pair)
    assert not is_finished(Pair(pair.left, cameras / "cam1" / "0001.png", pair.output, options))  # another input
    assert not is_finished(Pair(pair.left, pair.right, pair.output, PairOptions(method="census-sgm", max_disp=17)))
    pair.record.write_text("{not json")
    assert not is_finished(pair)


def test_a_failing_pair_is_reported_and_the_rest_go_on(cameras, capsys):
    (cameras / "cam1" / "0001.png").write_bytes(b"not an image")
    code, stdout, stderr = run_cade(batch_args(cameras, "out"), capsys)
    assert code == 1
    assert "2 done, 0 already finished, 1 failed, of 3 pairs" in stdout
    lines = stderr.strip().splitlines()
    assert any(line.startswith("warning: pair") and "0001.png" in line for line in lines)
    assert lines[-1].startswith("cade: error: 1 of 3 pairs failed")
    assert sorted(outputs(cameras / "out")) == ["0000.pfm", "0002.pfm"]
    failed = [entry for entry in log_of(cameras / "out")["pairs"] if entry["status"] == "failed"]
    assert len(failed) == 1 and failed[0]["right"].endswith("0001.png") and "cannot decode" in failed[0]["error"]


def test_two_jobs_give_the_bytes_of_one(cameras, capsys):
    assert run_cade(batch_args(cameras, "one", "--validity", "--min-disp", "auto"), capsys)[0] == 0
    code, stdout, _ = run_cade(batch_args(cameras, "two", "--validity", "--min-disp", "auto", "--jobs", 2), capsys)
    assert code == 0 and "2 local job(s)" in stdout
    assert outputs(cameras / "one") == outputs(cameras / "two") and len(outputs(cameras / "one")) == 6
    workers = {entry["worker"] for entry in log_of(cameras / "two")["pairs"]}
    assert len(workers) >= 1 and all(":" in worker for worker in workers)


def test_dask_local_cluster_gives_the_bytes_of_the_jobs_run(cameras, capsys):
    distributed = pytest.importorskip("distributed")
    assert run_cade(batch_args(cameras, "jobs", "--jobs", 2), capsys)[0] == 0
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None, protocol="tcp") as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        code, stdout, _ = run_cade(batch_args(cameras, "dask", "--scheduler", cluster.scheduler_address), capsys)
    assert code == 0 and "3 done" in stdout and "dask tcp://127.0.0.1" in stdout
    assert outputs(cameras / "dask") == outputs(cameras / "jobs")


def test_manifest_with_per_pair_range(cameras, capsys):
    manifest = cameras / "pairs.csv"
    manifest.write_text("left,right,output,max_disp\n"
                        "cam0/0000.png,cam1/0000.png,m/first.pfm,\n"
                        "cam0/0002.png,cam1/0002.png,m/third.npy,12\n")
    code, stdout, _ = run_cade(["batch", "--manifest", manifest, *FAST], capsys)
    assert code == 0 and "2 done" in stdout
    log = json.loads((cameras / "pairs.log.json").read_text())
    assert [tuple(entry["range"]) for entry in log["pairs"]] == [(0, 16), (0, 12)]
    assert read_disparity(cameras / "m" / "third.npy").shape == (48, 96)


def test_a_record_tells_the_tiers_apart_though_they_share_a_network():
    """The accurate tier's card names the fast tier's ONNX file: the record's fingerprint must still
    differ (its second pass changes every output); a card's non-default refinement enters it too, and
    a card with neither (cade-v4) keeps the fingerprint records had before those fields existed."""
    fast = PairOptions(method="cade", model="fast").fingerprint()
    accurate = PairOptions(method="cade", model="accurate").fingerprint()
    assert fast["model_sha256"] == accurate["model_sha256"]
    assert fast != accurate and "test_time_augmentation" not in fast
    assert accurate["test_time_augmentation"] == ["upscaled-x1.5"]
    assert fast["runtime_refinement"] == accurate["runtime_refinement"] == "rank-sgbm-two-scales"
    legacy = PairOptions(method="cade", model="cade-v4").fingerprint()
    assert "model_sha256" in legacy and not {"test_time_augmentation", "runtime_refinement"} & set(legacy)
    assert "model_sha256" not in PairOptions(method="sgbm").fingerprint()


def test_pairs_by_number_when_names_differ(tmp_path):
    for side, name in (("a", "left_{}.png"), ("b", "right_{}.png")):
        (tmp_path / side).mkdir()
        for number in (3, 10):
            write_png16(tmp_path / side / name.format(number), np.zeros((8, 8)))
    pairs = pairs_from_patterns(str(tmp_path / "a/*.png"), str(tmp_path / "b/*.png"), tmp_path / "out",
                                options=PairOptions())
    assert [(p.left.name, p.right.name, p.output.name) for p in pairs] == [
        ("left_10.png", "right_10.png", "left_10.pfm"), ("left_3.png", "right_3.png", "left_3.pfm")]
    (tmp_path / "b" / "right_3.png").unlink()
    with pytest.raises(CadeError, match="no partner"):
        pairs_from_patterns(str(tmp_path / "a/*.png"), str(tmp_path / "b/*.png"), tmp_path / "out",
                            options=PairOptions())


def test_manifest_errors_name_the_line(tmp_path):
    manifest = tmp_path / "pairs.csv"
    manifest.write_text("left,right,output,max_disp\na.png,b.png,o.pfm,many\n")
    with pytest.raises(CadeError, match=r"pairs.csv:2: --max-disp 'many'"):
        pairs_from_manifest(manifest, options=PairOptions())
    manifest.write_text("left,right,output,min_disp,max_disp\na.png,b.png,o.pfm,,-1\nc.png,d.png,p.pfm,5,5\n")
    with pytest.raises(CadeError, match=r"pairs.csv:2: --max-disp -1 is below --min-disp 0"):
        pairs_from_manifest(manifest, options=PairOptions())
    manifest.write_text("left,right,output,min_disp,max_disp\nc.png,d.png,p.pfm,5,5\n")
    with pytest.raises(CadeError, match=r"pairs.csv:2: --min-disp 5 and --max-disp 5 leave one disparity"):
        pairs_from_manifest(manifest, options=PairOptions())
    manifest.write_text("left,right\na.png,b.png\n")
    with pytest.raises(CadeError, match="no column output"):
        pairs_from_manifest(manifest, options=PairOptions())


def test_stale_temporaries_of_a_killed_run_are_removed(cameras, capsys):
    out = cameras / "out"
    out.mkdir()
    stale = out / ".0001.tmp-0123456789abcdef.pfm"
    stale.write_bytes(b"half a map")
    other = out / ".notes.tmp-0123456789abcdef.txt"  # not one of the batch's outputs: kept
    other.write_bytes(b"x")
    assert run_cade(batch_args(cameras, "out"), capsys)[0] == 0
    assert not stale.exists() and other.exists()


BAD_BATCHES = {
    "nothing given": ([], "missing --left, --right, --output-dir"),
    "both ways": (["--manifest", "m.csv", "--left", "a/*.png"], "either --manifest or"),
    "pattern matches nothing": (["--left", "nowhere/*.png", "--right", "cam1/*.png", "-o", "out"], "matches no image"),
    "jobs on a cluster": (["--left", "cam0/*.png", "--right", "cam1/*.png", "-o", "out", "--scheduler",
                           "tcp://127.0.0.1:1", "--jobs", "2"], "drop --jobs"),
    "bad format": (["--left", "cam0/*.png", "--right", "cam1/*.png", "-o", "out", "--format", "jpg"], "--format jpg"),
    "bad max-disp": (["--left", "cam0/*.png", "--right", "cam1/*.png", "-o", "out", "--max-disp", "x"], "--max-disp"),
    "unknown method": (["--left", "cam0/*.png", "--right", "cam1/*.png", "-o", "out", "--method", "magic"],
                       "unknown method"),
    "one-value range": (["--left", "cam0/*.png", "--right", "cam1/*.png", "-o", "out", "--max-disp", "0"],
                        "give a --max-disp above --min-disp"),
}


@pytest.mark.parametrize("case", BAD_BATCHES)
def test_batch_errors_are_one_line(cameras, capsys, monkeypatch, case):
    monkeypatch.chdir(cameras)
    args, message = BAD_BATCHES[case]
    code, _, stderr = run_cade(["batch", *args], capsys)
    assert code != 0
    assert len(stderr.strip().splitlines()) == 1, stderr
    assert stderr.startswith("cade: error:") and message in stderr


def test_jobs_are_capped_by_memory():
    gib = 2**30
    assert cap_jobs(4, 3 * gib, available_bytes=8 * gib) == 2  # 0.8 x 8 GB holds two 3 GB jobs
    assert cap_jobs(4, 30 * gib, available_bytes=8 * gib) == 1  # never below one
    assert cap_jobs(2, 1 * gib, available_bytes=64 * gib) == 2  # never above the request
    small, wide = (pair_memory_bytes("census-sgm", 1000, 1000, count) for count in (64, 256))
    assert wide - small == 20 * 1000 * 1000 * 192  # the cost volume: 20 bytes per pixel and disparity
    assert pair_memory_bytes("cade", 1000, 1000, 64) == pair_memory_bytes("cade", 1000, 1000, 256)  # strips


def slow_pairs(root: Path, rng, count: int) -> list[Pair]:
    """``count`` pairs big enough that a worker is still busy when the test acts."""
    (root / "l").mkdir()
    (root / "r").mkdir()
    for index in range(count):
        pair = render_pair(rng, (120, 240), background=(8.0, 0.0), foreground=(20.0, 0.0))
        write_png16(root / "l" / f"{index}.png", pair.left)
        write_png16(root / "r" / f"{index}.png", pair.right)
    options = PairOptions(method="census-sgm", max_disp=48)
    return [Pair(root / "l" / f"{i}.png", root / "r" / f"{i}.png", root / "out" / f"{i}.pfm", options)
            for i in range(count)]


def test_killed_workers_are_replaced_and_no_output_is_lost(tmp_path, rng):
    import multiprocessing
    import os
    import signal

    from cade_cli.batch.engines import run_local

    pairs = slow_pairs(tmp_path, rng, 6)
    results = run_local(pairs, jobs=2, threads=1)
    first = next(results)
    for child in multiprocessing.active_children():  # both workers die, one of them mid-pair
        os.kill(child.pid, signal.SIGKILL)
    rest = list(results)
    assert sorted(r.output for r in [first, *rest]) == sorted(str(p.output) for p in pairs)
    assert all(r.status == "done" for r in [first, *rest]), [r.error for r in rest]
    assert all(is_finished(pair) for pair in pairs)
    assert not [p for p in (tmp_path / "out").iterdir() if ".tmp-" in p.name]


def test_stopping_a_local_run_stops_its_workers_and_keeps_finished_outputs(tmp_path, rng):
    import multiprocessing

    from cade_cli.batch.engines import run_local

    pairs = slow_pairs(tmp_path, rng, 8)
    results = run_local(pairs, jobs=2, threads=1)
    first = next(results)
    results.close()  # what an interruption of the consumer does: the workers are interrupted and joined
    assert multiprocessing.active_children() == []
    finished = [pair for pair in pairs if is_finished(pair)]
    assert first.status == "done" and first.output in {str(pair.output) for pair in finished}
    assert len(finished) < len(pairs)
    assert not [p for p in (tmp_path / "out").iterdir() if ".tmp-" in p.name]


def test_two_files_of_one_name_on_a_side_are_refused(tmp_path):
    for folder in ("a/x", "a/y", "b"):
        (tmp_path / folder).mkdir(parents=True)
    for path in ("a/x/1.png", "a/y/1.png", "b/1.png"):
        write_png16(tmp_path / path, np.zeros((8, 8)))
    with pytest.raises(CadeError, match="two files named 1.png"):
        pairs_from_patterns(str(tmp_path / "a/**/*.png"), str(tmp_path / "b/*.png"), tmp_path / "out",
                            options=PairOptions())


# --- the memory limit (tiling) and the rig options: what `cade disparity` does, pair by pair -----------------------


def memory_limit_that_tiles() -> str:
    """A --memory-limit a 96x192 pair over 17 disparities does not fit whole (census-sgm:
    about 10 MB beyond the process's base), matched as a handful of tiles instead."""
    from cade_cli.scale.memory import BASE_BYTES

    return f"{(BASE_BYTES + 6000 * 2**10) // 2**10}KB"


@pytest.fixture
def wide(tmp_path, rng) -> Path:
    """l/000N.png and r/000N.png: two 96x192 cross-band pairs."""
    return cross_band_pairs(tmp_path, rng, ("l", "r"), count=2, shape=(96, 192), background=6.0)


def test_memory_limit_tiles_each_pair_as_disparity_does_and_a_new_limit_redoes_them(wide, capsys):
    limit = memory_limit_that_tiles()
    side = ["--vis", "--validity", "--confidence"]
    args = ["batch", "--left", wide / "l" / "*.png", "--right", wide / "r" / "*.png", "-o", wide / "out", *FAST]
    code, stdout, stderr = run_cade([*args, "--memory-limit", limit, *side], capsys)
    assert code == 0 and "2 done" in stdout, stderr
    assert "matched as tiles" in stderr
    log = log_of(wide / "out")
    assert all(entry["tiles"] > 1 for entry in log["pairs"]), log["pairs"]
    for index in range(2):
        name = f"{index:04d}"
        single = wide / "single"
        single.mkdir(exist_ok=True)
        code, _, stderr = run_cade(["disparity", wide / "l" / f"{name}.png", wide / "r" / f"{name}.png", "-o",
                                    single / f"{name}.pfm", *FAST, "--memory-limit", limit, "--vis",
                                    single / f"{name}_vis.png", "--validity", single / f"{name}_validity.png",
                                    "--confidence", single / f"{name}_confidence.tif"], capsys)
        assert code == 0 and " tiles of " in stderr, stderr
        for suffix in (".pfm", "_vis.png", "_validity.png", "_confidence.tif"):
            assert (wide / "out" / f"{name}{suffix}").read_bytes() == (single / f"{name}{suffix}").read_bytes(), suffix
    code, stdout, _ = run_cade([*args, "--memory-limit", limit, *side], capsys)
    assert code == 0 and "0 done, 2 already finished" in stdout
    # another limit may tile otherwise: the finished pairs are not trusted, and matched whole now
    code, stdout, _ = run_cade([*args, "--memory-limit", "4GB", *side], capsys)
    assert code == 0 and "2 done, 0 already finished" in stdout
    assert [entry["tiles"] for entry in log_of(wide / "out")["pairs"]] == [0, 0]
    record = json.loads((wide / "out" / "0000.pfm.cade.json").read_text())
    assert record["options"]["memory_limit"] == 4 * 2**30 and record["tiles"] == 0


def test_job_memory_is_planned_from_the_largest_pair_and_capped_by_the_limit(tmp_path):
    from cade_cli.batch.engines import job_memory_bytes
    from cade_cli.scale.memory import BASE_BYTES

    for name, shape in (("small", (16, 32)), ("large", (64, 128))):
        write_png16(tmp_path / f"{name}.png", np.zeros(shape))
    options = PairOptions(method="census-sgm", max_disp=16)
    pairs = [Pair(tmp_path / f"{name}.png", tmp_path / f"{name}.png", tmp_path / f"{name}.pfm", options)
             for name in ("small", "large")]  # the largest is not the first
    assert job_memory_bytes(pairs) == (128, 64, pair_memory_bytes("census-sgm", 128, 64, 17))
    limit = BASE_BYTES + 2**20  # below the large pair's plan: its worker tiles it within the limit
    limited = [Pair(p.left, p.right, p.output, PairOptions(method="census-sgm", max_disp=16, memory_limit=limit))
               for p in pairs]
    assert job_memory_bytes(limited) == (128, 64, limit)
    wide_range = [pairs[0], Pair(pairs[1].left, pairs[1].right, pairs[1].output,
                                 PairOptions(method="census-sgm", min_disp="auto", max_disp=16))]
    assert job_memory_bytes(wide_range)[2] == pair_memory_bytes("census-sgm", 128, 64, 16 + 32 + 1)  # auto: -w/4


def test_jobs_are_lowered_to_what_the_largest_pair_leaves_room_for(cameras, capsys, monkeypatch):
    from cade_cli.batch import engines as batch

    planned = pair_memory_bytes("census-sgm", 96, 48, 17)
    monkeypatch.setattr(batch, "available_memory_bytes", lambda: int(1.5 * planned / batch.MEMORY_HEADROOM))
    code, stdout, stderr = run_cade(batch_args(cameras, "out", "--jobs", 3), capsys)
    assert code == 0 and "1 local job(s)" in stdout
    assert "--jobs 3 lowered to 1: the largest pair, 96x48" in stderr


@pytest.fixture
def rig_cameras(tmp_path, rng) -> Path:
    """rig.json (the synthetic rig of test_rig) and cam0/000N.png, cam1/000N.png: two
    views of a textured plane, at 1.2 and 1.5 m."""
    import cv2

    from cade_cli.rigs.rig_file import save_rig
    from test_rig import scene_pair, synthetic_rig

    save_rig(synthetic_rig(), tmp_path / "rig.json")
    for side in ("cam0", "cam1"):
        (tmp_path / side).mkdir()
    for index, depth in enumerate((1.2, 1.5)):
        for side, image in zip(("cam0", "cam1"), scene_pair(depth, rng, invert_right=False)):
            cv2.imwrite(str(tmp_path / side / f"{index:04d}.png"), np.round(image * 255).astype(np.uint8))
    return tmp_path


def test_batch_with_a_rig_writes_what_disparity_with_the_rig_writes(rig_cameras, capsys):
    from cade_cli.rigs.rig import Rig
    from cade_cli.rigs.rig_file import load_rig, save_rig

    root = rig_cameras
    rig_options = ["--rig", root / "rig.json", "--frame", "original", "-m", "sgbm", "--max-disp", 48]
    args = ["batch", "--left", root / "cam0" / "*.png", "--right", root / "cam1" / "*.png", "-o", root / "out",
            *rig_options, "--depth", "--points", "--validity"]
    code, stdout, stderr = run_cade(args, capsys)
    assert code == 0 and "2 done" in stdout, stderr
    suffixes = (".pfm", "_depth.tif", "_points.ply", "_validity.png")
    assert sorted(p.name for p in (root / "out").iterdir() if not p.name.endswith(".json")) == sorted(
        f"{index:04d}{suffix}" for index in range(2) for suffix in suffixes)
    single = root / "single"
    single.mkdir()
    for index in range(2):
        name = f"{index:04d}"
        code, _, stderr = run_cade(["disparity", root / "cam0" / f"{name}.png", root / "cam1" / f"{name}.png", "-o",
                                    single / f"{name}.pfm", *rig_options, "--depth", single / f"{name}_depth.tif",
                                    "--points", single / f"{name}_points.ply", "--validity",
                                    single / f"{name}_validity.png"], capsys)
        assert code == 0, stderr
        for suffix in suffixes:
            assert (root / "out" / f"{name}{suffix}").read_bytes() == (single / f"{name}{suffix}").read_bytes(), suffix
    record = json.loads((root / "out" / "0001.pfm.cade.json").read_text())
    assert set(record["outputs"]) == {"disparity", "depth", "points", "validity"}
    assert record["options"]["frame"] == "original" and record["rectification"] == ["left", "right"]
    assert record["self_check"]["worst_px"] < 0.5 and record["range"] == [0, 48]
    code, stdout, _ = run_cade(args, capsys)
    assert code == 0 and "0 done, 2 already finished" in stdout
    (root / "out" / "0000_points.ply").unlink()  # a missing side output: that pair is redone
    code, stdout, _ = run_cade(args, capsys)
    assert code == 0 and "1 done, 1 already finished" in stdout
    # another rig file (here the same cameras, without the stored rectification): every pair is redone
    rig = load_rig(root / "rig.json")
    save_rig(Rig(rig.reference, rig.cameras), root / "rig.json")
    code, stdout, _ = run_cade(args, capsys)
    assert code == 0 and "2 done, 0 already finished" in stdout


def test_batch_with_a_rig_estimates_the_range_on_each_rectified_pair_and_tiles_it(rig_cameras, capsys):
    """--max-disp auto and a --memory-limit that tiles, with a rig: each pair's range is its
    own, announced and logged as without a rig, and the bytes are `cade disparity --rig`'s."""
    from cade_cli.scale.memory import BASE_BYTES
    from test_rig import plane_disparity

    root = rig_cameras
    limit = f"{(BASE_BYTES + 40 * 2**20) // 2**10}KB"  # the 480x360 rectified pair: tens of tiles
    rig_options = ["--rig", root / "rig.json", "-m", "sgbm", "--max-disp", "auto", "--memory-limit", limit]
    args = ["batch", "--left", root / "cam0" / "*.png", "--right", root / "cam1" / "*.png", "-o", root / "out",
            *rig_options, "--depth"]
    code, stdout, batch_stderr = run_cade(args, capsys)
    assert code == 0 and "2 done" in stdout, batch_stderr
    assert "matched as tiles" in batch_stderr
    entries = {Path(entry["output"]).stem: entry for entry in log_of(root / "out")["pairs"]}
    single = root / "single"
    single.mkdir()
    for index, depth in enumerate((1.2, 1.5)):
        name = f"{index:04d}"
        entry = entries[name]
        low, high = entry["range"]
        assert low == 0 and plane_disparity(depth) + 2 <= high <= plane_disparity(depth) + 20, entry
        assert entry["range_note"].startswith(f"--max-disp auto: searching [0, {high}] px")
        assert f"note: {root / 'out' / name}.pfm: --max-disp auto: searching [0, {high}] px" in batch_stderr
        assert entry["tiles"] > 1
        record = json.loads((root / "out" / f"{name}.pfm.cade.json").read_text())
        assert record["range"] == [low, high] and record["tiles"] == entry["tiles"]
        code, _, stderr = run_cade(["disparity", root / "cam0" / f"{name}.png", root / "cam1" / f"{name}.png", "-o",
                                    single / f"{name}.pfm", *rig_options, "--depth", single / f"{name}_depth.tif"],
                                   capsys)
        assert code == 0 and f"searching [0, {high}] px" in stderr and " tiles of " in stderr, stderr
        for suffix in (".pfm", "_depth.tif"):
            assert (root / "out" / f"{name}{suffix}").read_bytes() == (single / f"{name}{suffix}").read_bytes(), suffix
        assert np.nanmedian(read_disparity(single / f"{name}.pfm")) == pytest.approx(plane_disparity(depth), abs=1.0)
    # the --jobs plan: a rig's pair that does not fit the limit is tiled within it, so the limit is its plan
    from cade_cli.batch.engines import job_memory_bytes

    options = PairOptions(method="sgbm", max_disp="auto", rig=str(root / "rig.json"),
                          memory_limit=BASE_BYTES + 40 * 2**20)
    pair = Pair(root / "cam0" / "0000.png", root / "cam1" / "0000.png", root / "plan.pfm", options)
    assert job_memory_bytes([pair]) == (480, 360, BASE_BYTES + 40 * 2**20)


RIG_BATCH_ERRORS = {
    "depth without a rig": (["--depth"], "--depth needs --rig"),
    "frame without a rig or --fix-vertical": (["--frame", "original"], "--frame needs --rig"),
    "unknown frame with --fix-vertical": (["--fix-vertical", "--frame", "sideways"], "unknown --frame 'sideways'"),
    "missing rig": (["--rig", "missing.json"], "does not exist"),
    "unknown camera": (["--rig", "rig.json", "--camera", "nir"], "no camera 'nir'"),
    "bad memory limit": (["--memory-limit", "lots"], "--memory-limit 'lots'"),
}


@pytest.mark.parametrize("case", RIG_BATCH_ERRORS)
def test_rig_and_memory_options_are_checked_before_any_pair(cameras, capsys, monkeypatch, case):
    from cade_cli.rigs.rig_file import save_rig
    from test_rig import synthetic_rig

    save_rig(synthetic_rig(), cameras / "rig.json")
    monkeypatch.chdir(cameras)
    args, message = RIG_BATCH_ERRORS[case]
    code, _, stderr = run_cade(["batch", "--left", "cam0/*.png", "--right", "cam1/*.png", "-o", "out", *args], capsys)
    assert code == 1 and len(stderr.strip().splitlines()) == 1, stderr
    assert stderr.startswith("cade: error:") and message in stderr
    assert not (cameras / "out").exists()


def test_stale_temporaries_of_a_pair_go_nested_ones_included_and_no_other_file(tmp_path):
    from cade_cli.io.atomic import temporary_sibling
    from cade_cli.batch.job import remove_stale_temporaries

    output = tmp_path / "0.pfm"
    outer = temporary_sibling(output)
    inner = temporary_sibling(outer)  # a nested atomic write killed half-way
    neighbour = temporary_sibling(tmp_path / "10.pfm")  # another pair's: kept
    for path in (outer, inner, neighbour):
        path.write_bytes(b"partial")

    class OnePair:
        record = tmp_path / "0.json"

        def outputs(self):
            return {"disparity": output}

    assert remove_stale_temporaries([OnePair()]) == 2
    assert not outer.exists() and not inner.exists() and neighbour.exists()


def test_png_batch_refuses_a_range_it_cannot_hold_before_any_pair(cameras, capsys):
    """--format png holds 0 <= d < 256: a range reaching past it is refused before any pair runs,
    naming a pair's output (not a temporary file) and the fix; a range that fits runs."""
    patterns = ["--left", cameras / "cam0" / "*.png", "--right", cameras / "cam1" / "*.png"]
    for bounds in (["--max-disp", "300"], ["--min-disp", "-2", "--max-disp", "16"]):
        code, _, stderr = run_cade(["batch", *patterns, "-o", cameras / "out", "--format", "png", "-m", "census-sgm",
                                    *bounds], capsys)
        assert code != 0 and "16-bit PNG" in stderr and "0000.png" in stderr and ".tmp-" not in stderr
        assert not list((cameras / "out").glob("*.png"))  # nothing written (a missing folder globs empty)
    code, stdout, stderr = run_cade(["batch", *patterns, "-o", cameras / "out", "--format", "png", *FAST], capsys)
    assert code == 0 and "3 done" in stdout, stderr
