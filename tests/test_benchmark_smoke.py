"""The maintained benchmarks still run: every script in benchmarks/ is listed in benchmarks/README.md
and answers ``--help`` (its imports and options parse); the ones that can be made cheap also do a
tiny real run on generated data. Deeper checks of a script's results live beside the code they
measure (see :data:`SCRIPTS`). Scripts run in this process (``runpy``), so the package is imported
once for all of them."""

from __future__ import annotations

import gzip
import json
import os
import re
import runpy
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"

SCRIPTS: dict[str, str] = {
    # script -> what exercises it beyond --help ("" : --help alone, its run needs ../shared/data or minutes)
    "auto_range.py": "",
    "brightness.py": "tests/test_benchmark.py (count_scene on a generated pair)",
    "cade_errors.py": "tests/test_cade_errors.py (its regions and error classes on built maps)",
    "cade_stages.py": "",
    "bakeoff_judge.sh": "here: its usage line, and a one-step checkpoint judged on one Middlebury scene",
    "bakeoff_table.py": "here: the table and plot of that judged checkpoint",
    "candidate_check.sh": "here: its syntax and its usage line",
    "compare_records.py": "tests/test_benchmark.py (records compared on a generated dataset)",
    "cross_spectral.py": "",
    "dasc_speed.py": "here: one tiny case",
    "design_speed.py": "",
    "drone_alignment.py": "tests/test_drone_alignment.py",
    "edge_filter_sweep.py": "",
    "edge_headroom.py": "tests/test_edge_headroom.py (candidates, oracle, correlation and consistency on built edges)",
    "gpu_data.py": "tests/test_gpu_data.py (a small data folder packed and unpacked)",
    "memory.py": "here: a 96x64 generated pair",
    "msir_alignment.py": "tests/test_msir.py, tests/test_array.py (its rig file, with ../shared/data)",
    "model_table.py": "tests/test_benchmark.py (the table of generated runs)",
    "msir_pseudo_gt.py": "",
    "network_profile.py": "here: the shipped network on 64x64 bands",
    "pair_check.py": "",
    "pipeline_profile.py": "",
    "rig_imperfections.py": "tests/test_rig_imperfections.py",
    "shipping_rule.py": "tests/test_benchmark.py (the rule on generated records)",
    "speed.py": "",  # Pandora lives in its own venv (.venv-bench); --help needs only the package
    "throughput.py": "",  # a real run starts a Dask cluster: tens of seconds
    "tiling.py": "here: a 160x96 generated pair in a budget",
    "uncalibrated.py": "here: the bundled samples pair",
}
"""Every maintained script (benchmarks/README.md's table lists each with its command)."""

LISTED_ONLY = {"micasense_radiometry.py": "being written beside this test; its own test comes with it"}
"""Scripts the README lists that no smoke test here runs, and why."""

HELPERS = {"drone_edges.py": "drone_alignment.py's edge crops (tests/test_drone_alignment.py)"}
"""Modules in benchmarks/ that a script imports, not scripts themselves: not listed, no --help."""


def readme_scripts() -> set[str]:
    """The scripts named in the first column of benchmarks/README.md's table."""
    return set(re.findall(r"^\| `([\w.]+\.(?:py|sh))` \|", (BENCHMARKS / "README.md").read_text(), flags=re.M))


def test_every_script_is_listed_in_the_readme_and_smoke_tested_here():
    on_disk = {path.name for path in BENCHMARKS.iterdir() if path.suffix in (".py", ".sh")} - set(HELPERS)
    listed = readme_scripts()
    assert on_disk - listed == set(), f"add to benchmarks/README.md's table: {sorted(on_disk - listed)}"
    assert listed - on_disk <= set(LISTED_ONLY), f"listed but not in benchmarks/: {sorted(listed - on_disk - set(LISTED_ONLY))}"
    untested = on_disk - set(SCRIPTS) - set(LISTED_ONLY)
    assert not untested, f"add a smoke test (SCRIPTS) for {sorted(untested)}, or retire it (docs/research/retired-experiments.md)"
    assert set(SCRIPTS) <= on_disk, f"gone from benchmarks/, remove from SCRIPTS: {sorted(set(SCRIPTS) - on_disk)}"


def run_script(name: str, *args: str, monkeypatch) -> int:
    """Run benchmarks/``name`` as ``python benchmarks/name args`` would, in this process; its exit status."""
    monkeypatch.setattr(sys, "argv", [str(BENCHMARKS / name), *args])
    try:
        runpy.run_path(str(BENCHMARKS / name), run_name="__main__")
    except SystemExit as exit_:
        return 0 if exit_.code is None else exit_.code if isinstance(exit_.code, int) else 1
    return 0


@pytest.mark.parametrize("name", sorted(name for name in SCRIPTS if name.endswith(".py")))
def test_each_script_answers_help(name, monkeypatch, capsys):
    assert run_script(name, "--help", monkeypatch=monkeypatch) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: ") and name in out.splitlines()[0], out[:200]


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_candidate_check_parses_and_asks_for_its_arguments():
    script = BENCHMARKS / "candidate_check.sh"
    assert subprocess.run(["bash", "-n", str(script)], capture_output=True).returncode == 0
    run = subprocess.run(["bash", str(script)], capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 2 and run.stderr.strip().startswith("usage: benchmarks/candidate_check.sh CHECKPOINT NAME")


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_bakeoff_judge_scores_a_run_by_region_through_the_cli(tmp_path):
    script = BENCHMARKS / "bakeoff_judge.sh"
    run = subprocess.run(["bash", str(script)], capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 2 and run.stderr.strip().startswith("usage: benchmarks/bakeoff_judge.sh RUN_DIR OUT_DIR")
    data = ROOT.parent / "shared" / "data"
    if not (data / "middlebury2014").is_dir():
        pytest.skip("../shared/data is absent")
    pytest.importorskip("torch")
    from cade_cli.train.config import TrainConfig
    from cade_cli.train.fit import train

    train(TrainConfig(out=str(tmp_path / "run"), textures=[], steps=1, batch=1, height=64, width=128, levels=64,
                      workers=0, validate_every=10, architecture="cadenet2d", features2d=8, width2d=8,
                      half_channels=4))
    judged = subprocess.run(["bash", str(script), str(tmp_path / "run"), str(tmp_path / "out")], cwd=ROOT,
                            capture_output=True, text=True, env={**os.environ, "SETS": "middlebury14",
                                                                 "SCENES": "ArtL", "OMP_NUM_THREADS": "1"})
    assert judged.returncode == 0, judged.stderr
    assert not (tmp_path / "out" / "middlebury14.json").exists()  # kept gzipped only
    judged_set = json.loads(gzip.decompress((tmp_path / "out" / "middlebury14.json.gz").read_bytes()))
    records = judged_set["records"]
    methods = {record["method"] for record in records}
    assert {"cade-network", "cade"} <= {method.split(":")[0] for method in methods}
    assert all({"bad3_all", "bad3_nonocc", "bad3_edge", "bad3_occ"} <= set(record["scores"]) for record in records)
    # the bake-off table reads the judged folder: the whole matcher's summary means, by region, and the plot
    summary = next(row["scores"] for row in judged_set["summary"] if row["method"].split(":")[0] == "cade")
    table = runpy.run_path(str(BENCHMARKS / "bakeoff_table.py"))
    assert table["main"]([str(tmp_path), "--markdown", str(tmp_path / "t.md"), "--speed", "out=1.5",
                          "--plot", str(tmp_path / "p.png")]) == 0
    text = (tmp_path / "t.md").read_text()
    assert "### middlebury14, cade (" in text and "| run |" in text
    row = [line for line in text.split("### middlebury14, cade (")[1].splitlines() if line.startswith("| out |")][0]
    assert row == "| out | " + " | ".join(f"{summary[f'epe_{r}']:.2f} / {summary[f'bad3_{r}']:.1f}"
                                          for r in ("all", "nonocc", "edge", "occ")) + " |"
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_memory_matches_a_small_generated_pair(monkeypatch, capsys):
    code = run_script("memory.py", "--width", "96", "--height", "64", "--disparity", "6", "--max-disp", "16",
                      "--method", "sgbm", monkeypatch=monkeypatch)
    out = capsys.readouterr().out
    assert code == 0, out
    epe = float(re.search(r"EPE ([\d.]+) px against the true 6 px", out).group(1))
    assert epe < 1.0  # a textured pair shifted by 6 px: sgbm finds it


def test_dasc_speed_times_one_tiny_case_and_both_volumes_agree(monkeypatch, capsys):
    code = run_script("dasc_speed.py", "--cases", "24x40:0:7", "--repeat", "1", monkeypatch=monkeypatch)
    out = capsys.readouterr().out
    assert code == 0, out
    row = next(line for line in out.splitlines() if line.startswith("| 24x40 |"))
    assert float(row.strip(" |").split("|")[-1]) < 1e-4  # max abs difference of the old and new volumes


def test_network_profile_profiles_the_shipped_network(monkeypatch, capsys):
    from cade_cli.model_card import read_card

    onnx = read_card().variants[0].path  # the shipped network (models/ also holds a chooser's network)
    code = run_script("network_profile.py", str(onnx), "--size", "64x64", "--runs", "1", "--threads", "1",
                      monkeypatch=monkeypatch)
    out = capsys.readouterr().out
    assert code == 0, out
    assert "Conv" in out and "%" in out


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the EPE of a pair with no valid pixel is NaN
def test_tiling_runs_cade_disparity_on_a_generated_pair_within_a_budget(monkeypatch, capsys):
    """The large-pair half on a small pair (its range is fixed at 400 px, so 480 px wide): the
    command runs and its memory is measured (the scores of so thin a pair mean nothing)."""
    code = run_script("tiling.py", "--skip-seams", "--large", "480x48", "--budget", "1GB", "--methods", "sgbm",
                      monkeypatch=monkeypatch)
    out = capsys.readouterr().out
    assert code == 0, out
    row = next(line for line in out.splitlines() if line.startswith("| sgbm | 480x48 |")).strip(" |").split(" | ")
    assert "error" not in row[-1], row  # the note column: cade disparity's own error, if any
    seconds, peak_gb, tiles = float(row[3]), float(row[4]), int(row[6])
    # the time column is printed to 0.01 s, and so thin an sgbm pair can take less: only its presence is checked
    assert seconds >= 0 and 0 < peak_gb < 1.0 and tiles >= 1


def test_uncalibrated_rectifies_the_bundled_pair(monkeypatch, capsys):
    """Without --data-dir: samples/middlebury2005-art alone (already rectified, so the vertical model
    fits it and leaves a residual under a pixel)."""
    code = run_script("uncalibrated.py", monkeypatch=monkeypatch)
    out = capsys.readouterr().out
    assert code == 0, out
    row = next(line for line in out.splitlines() if line.startswith("| samples Art")).strip(" |").split(" | ")
    assert float(row[2]) < 1.0, row
