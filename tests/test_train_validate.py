"""`python -m cade_cli.train validate RUN`: a run trained where the validation sets were not (a lent
GPU's) gets the rows `fit` would have written at its last step -- the same figures, added once."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.usefixtures("small_validation")  # conftest: a test-sized synthetic set

from cade_cli.train.checkpoints import compact_checkpoint  # noqa: E402
from cade_cli.train.config import TrainConfig  # noqa: E402
from cade_cli.train.fit import train, validate_run  # noqa: E402

CALIB = "cam0=[500 0 48; 0 500 24; 0 0 1]\ncam1=[500 0 48; 0 500 24; 0 0 1]\ndoffs=0\nbaseline=100\n" \
        "width=96\nheight=48\nndisp=12\nisint=0\nvmin=4\nvmax=4\n"


def write_middlebury14q(data_dir: Path, rng: np.random.Generator, shift: int = 4) -> None:
    """One MiddEval3 training scene at quarter size: a texture and its copy shifted by ``shift`` px."""
    scene = data_dir / "middlebury2014" / "trainingQ" / "Adirondack"
    scene.mkdir(parents=True)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (48, 96 + shift, 3), dtype=np.uint8), (3, 3), 0)
    cv2.imwrite(str(scene / "im0.png"), texture[:, shift:])
    cv2.imwrite(str(scene / "im1.png"), texture[:, :96])
    (scene / "calib.txt").write_text(CALIB)
    gt = np.full((48, 96), float(shift), np.float32)
    (scene / "disp0GT.pfm").write_bytes(b"Pf\n96 48\n-1.0\n" + np.ascontiguousarray(gt[::-1]).tobytes())
    cv2.imwrite(str(scene / "mask0nocc.png"), np.full((48, 96), 255, np.uint8))


def rows(run: Path) -> list[dict]:
    return list(csv.DictReader((run / "log.csv").open()))


def test_validate_adds_the_rows_fit_writes_at_the_last_step_once(tmp_path: Path):
    data_dir = tmp_path / "data"
    write_middlebury14q(data_dir, np.random.default_rng(0))
    run = tmp_path / "run"
    train(TrainConfig(out=str(run), textures=[], data_dir=str(data_dir), steps=3, batch=1, height=32, width=64,
                      levels=16, workers=0, validate_every=100, validate_rgb=True))
    by_fit = {row["set"]: row for row in rows(run) if row["step"] == "3" and row["set"] != "train"}
    assert set(by_fit) == {"synthetic", "middlebury14Q-cs", "middlebury14Q-rgb"}

    # as a GPU's run: its log has the synthetic row only, and it did not ask for the same-band sets
    lines = (run / "log.csv").read_text().splitlines(keepends=True)
    (run / "log.csv").write_text("".join(line for line in lines if ",middlebury14Q-" not in line))
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "validate_rgb": False}))
    added = validate_run(run, data_dir, threads=1)
    assert [name for name, _, _ in added] == ["middlebury14Q-cs", "middlebury14Q-rgb"]
    after = {row["set"]: row for row in rows(run) if row["step"] == "3" and row["set"] != "train"}
    assert after == by_fit  # the same figures, elapsed and CPU columns as fit's own rows
    assert validate_run(run, data_dir, threads=1) == []  # nothing twice
    assert len(rows(run)) == len(lines) - 1

    # a finished run's checkpoint, weights only (as runs/README.md keeps one): the same rows again
    compact_checkpoint(run / "last.pt", run / "last.pt", weights_only=True)
    (run / "log.csv").write_text("".join(line for line in lines if ",middlebury14Q-" not in line))
    assert len(validate_run(run, data_dir, threads=1)) == 2
    assert {row["set"]: row for row in rows(run) if row["step"] == "3" and row["set"] != "train"} == by_fit
