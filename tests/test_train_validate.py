"""`python -m cade_cli.train validate RUN`: a run trained where the validation sets were not (a lent
GPU's) gets the rows `fit` would have written at its last step -- the same figures, added once."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.usefixtures("small_validation")  # conftest: a test-sized synthetic set

from cade_cli.train.checkpoints import compact_checkpoint  # noqa: E402
from cade_cli.train.config import TrainConfig  # noqa: E402
from cade_cli.train.fit import train, validate_run  # noqa: E402
from synthetic import write_real_scene  # noqa: E402


def rows(run: Path) -> list[dict]:
    return list(csv.DictReader((run / "log.csv").open()))


def test_validate_adds_the_rows_fit_writes_at_the_last_step_once(tmp_path: Path):
    data_dir = tmp_path / "data"  # one MiddEval3 training scene at quarter size: a texture shifted by 5 px
    write_real_scene(data_dir / "middlebury2014" / "trainingQ" / "Adirondack", np.random.default_rng(0))
    run = tmp_path / "run"
    train(TrainConfig(out=str(run), textures=[], data_dir=str(data_dir), steps=3, batch=1, height=32, width=64,
                      levels=16, workers=0, validate_every=100, validate_rgb=True))
    by_fit = {row["set"]: row for row in rows(run) if row["step"] == "3" and row["set"] != "train"}
    assert set(by_fit) == {"synthetic", "middlebury14Q-cs", "middlebury14Q-rgb"}

    # as a GPU's run: its log has the synthetic row only, and it did not ask for the same-band sets
    lines = (run / "log.csv").read_text().splitlines(keepends=True)
    (run / "log.csv").write_text("".join(line for line in lines if ",middlebury14Q-" not in line))
    checkpoint = torch.load(run / "last.pt", weights_only=False)
    torch.save({**checkpoint, "config": {**checkpoint["config"], "validate_rgb": False}}, run / "last.pt")
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
