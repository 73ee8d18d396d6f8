""".ci/check-sizes: a tracked file over 5 MB outside models/ and the runs listed in runs/LIVE
fails the check in one line naming it; the same file in models/ or a live run passes."""

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
