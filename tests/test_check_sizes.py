""".ci/check-sizes: a tracked file over 5 MB outside models/ and the runs listed in runs/LIVE
fails the check in one line naming it; the same file in models/ or a live run passes. Tracked
files outside models/ (live runs included) over 15 MB in all fail it too, in one line."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / ".ci" / "check-sizes"

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="needs git")


def check(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), str(root)], capture_output=True, text=True)


def track(root: Path, name: str, size: int) -> None:
    path = root / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\0" * size)
    subprocess.run(["git", "-C", str(root), "add", name], check=True)


def test_a_large_file_outside_models_and_the_live_runs_fails_the_check(tmp_path):
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    track(tmp_path, "models/big.onnx", 6_000_000)
    track(tmp_path, "runs/old/last.pt", 4_900_000)
    track(tmp_path, "runs/live/last.pt", 6_000_000)
    track(tmp_path, "runs/LIVE", 0)
    (tmp_path / "runs" / "LIVE").write_text("# still training\nruns/live\n")
    result = check(tmp_path)
    assert result.returncode == 0 and "runs/live/" in result.stdout, result.stderr

    track(tmp_path, "runs/old/last.pt", 5_100_000)
    result = check(tmp_path)
    assert result.returncode == 1 and len(result.stderr.strip().splitlines()) == 1
    assert "runs/old/last.pt (5.1 MB)" in result.stderr and "big.onnx" not in result.stderr
    assert "runs/live/last.pt" not in result.stderr

    (tmp_path / "runs" / "LIVE").write_text("")
    result = check(tmp_path)
    assert result.returncode == 1 and "runs/live/last.pt (6.0 MB)" in result.stderr


def test_over_15_mb_in_all_outside_models_fails_the_check(tmp_path):
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    track(tmp_path, "models/big.onnx", 4_900_000)  # models/ never counts
    track(tmp_path, "models/bigger.onnx", 4_900_000)
    track(tmp_path, "docs/a.png", 4_900_000)
    track(tmp_path, "docs/b.png", 4_900_000)
    track(tmp_path, "runs/live/last.pt", 4_900_000)
    track(tmp_path, "runs/LIVE", 0)
    (tmp_path / "runs" / "LIVE").write_text("runs/live\n")
    result = check(tmp_path)  # 14.7 MB outside models/: every file under 5 MB, the sum under 15
    assert result.returncode == 0 and "14.7 MB outside models/" in result.stdout, result.stderr

    track(tmp_path, "benchmarks/results/r.json", 400_000)  # 15.1 MB: the live run counts in the total
    result = check(tmp_path)
    assert result.returncode == 1 and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "15.1 MB tracked outside models/, over 15 MB" in result.stderr
    assert "the most in docs 9.8 MB, runs/live 4.9 MB" in result.stderr

    (tmp_path / "docs" / "b.png").unlink()  # deleted from the work tree: no longer counted
    result = check(tmp_path)
    assert result.returncode == 0 and "10.2 MB outside models/" in result.stdout, result.stderr
