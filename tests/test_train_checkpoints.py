"""Compact checkpoints: a run saved compactly resumes with its weights and moments, a checkpoint
of the earlier full form still loads and compacts, a weights-only one exports but does not resume
(skipped where torch is not installed)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from typer.testing import CliRunner  # noqa: E402

from cade_cli.train.__main__ import app  # noqa: E402
from cade_cli.train.checkpoints import COMPACT, WEIGHTS_ONLY, compact_checkpoint, restore  # noqa: E402
from cade_cli.train.config import TrainConfig  # noqa: E402
from cade_cli.train.export import load_checkpoint  # noqa: E402
from cade_cli.train.fit import train  # noqa: E402
from cade_cli.train.networks import network_of  # noqa: E402


@pytest.fixture(autouse=True)
def no_validation(monkeypatch):
    """These tests are about checkpoints: the loop's validation (24 rendered pairs) is left out."""
    monkeypatch.setattr("cade_cli.train.fit.validation_sets", lambda config: {})


def tiny_run(folder: Path, **changes) -> TrainConfig:
    return TrainConfig(out=str(folder), textures=[], steps=3, batch=1, height=32, width=64, levels=16, workers=0,
                       validate_every=100, checkpoint_every=100, stop_after=2, **changes)


def restored(config: TrainConfig, checkpoint: Path):
    """A fresh net and optimiser restored from ``checkpoint``, and the step it gave."""
    net = network_of(dataclasses.asdict(config))
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    step = restore(net, optimizer, config, checkpoint)[0]
    return net, optimizer, step


def full_form(state: dict) -> dict:
    """``state`` as the training loop wrote it before compact checkpoints: float32 moments, no format."""
    moments = {index: {key: value.float() for key, value in entry.items()}
               for index, entry in state["optimizer"]["state"].items()}
    kept = {key: value for key, value in state.items() if key != "format"}
    return {**kept, "optimizer": {**state["optimizer"], "state": moments}}


def test_a_compact_checkpoint_resumes_with_its_weights_and_moments(tmp_path):
    config = tiny_run(tmp_path / "run")
    checkpoint = train(config)
    state = torch.load(checkpoint, weights_only=False)
    assert state["format"] == COMPACT and state["step"] == 2
    entries = list(state["optimizer"]["state"].values())
    assert all(entry["exp_avg"].dtype == entry["exp_avg_sq"].dtype == torch.bfloat16 for entry in entries)
    assert all(entry["step"].dtype == torch.float32 and float(entry["step"]) == 2 for entry in entries)
    assert any(float(entry["exp_avg_sq"].abs().sum()) > 0 for entry in entries)
    assert all(value.dtype == torch.float32 for value in state["model"].values() if value.is_floating_point())

    net, optimizer, step = restored(config, checkpoint)
    assert step == 2
    for key, value in net.state_dict().items():
        assert torch.equal(value, state["model"][key]), key
    moments = optimizer.state_dict()["state"]
    for index, entry in state["optimizer"]["state"].items():
        for key in ("exp_avg", "exp_avg_sq"):
            assert moments[index][key].dtype == torch.float32
            assert torch.equal(moments[index][key], entry[key].float())
    config.stop_after = None
    assert torch.load(train(config), weights_only=False)["step"] == 3


def test_a_full_checkpoint_loads_compacts_and_both_resume_alike(tmp_path):
    """An old-form checkpoint restores exactly; compacted it is smaller, restores the same weights,
    and one more step from either lands within a few percent of that step's size of the other."""
    trained = torch.load(train(tiny_run(tmp_path / "source")), weights_only=False)
    old = tmp_path / "old" / "last.pt"
    old.parent.mkdir()
    torch.save(full_form(trained), old)
    _, optimizer, _ = restored(tiny_run(old.parent), old)
    full_moments = full_form(trained)["optimizer"]["state"]
    for index, entry in optimizer.state_dict()["state"].items():
        assert torch.equal(entry["exp_avg_sq"], full_moments[index]["exp_avg_sq"])

    new = tmp_path / "new" / "last.pt"
    new.parent.mkdir()
    before, after = compact_checkpoint(old, new)
    assert after < 0.8 * before and before == old.stat().st_size
    assert torch.load(new, weights_only=False)["format"] == COMPACT
    net, _, step = restored(tiny_run(new.parent), new)
    assert step == 2 and all(torch.equal(value, trained["model"][key]) for key, value in net.state_dict().items())

    stepped = {}
    for folder in (old.parent, new.parent):
        config = tiny_run(folder)
        config.stop_after = None
        stepped[folder.name] = torch.load(train(config), weights_only=False)["model"]
    moved = max(float((stepped["old"][key] - value).abs().max())
                for key, value in trained["model"].items() if value.is_floating_point())
    apart = max(float((stepped["new"][key] - value).abs().max())
                for key, value in stepped["old"].items() if value.is_floating_point())
    assert moved > 0 and apart < 0.05 * moved


def test_weights_only_exports_but_does_not_resume_and_the_command_says_the_sizes(tmp_path):
    checkpoint = train(tiny_run(tmp_path / "run"))
    finished = tmp_path / "finished.pt"
    result = CliRunner().invoke(app, ["compact", str(checkpoint), "-o", str(finished), "--weights-only"])
    assert result.exit_code == 0, result.output
    assert f"{checkpoint}: " in result.output and " MB -> " in result.output and "(weights only)" in result.output
    state = torch.load(finished, weights_only=False)
    assert state["format"] == WEIGHTS_ONLY and state["optimizer"] is None and "torch_rng" not in state
    assert finished.stat().st_size < 0.6 * checkpoint.stat().st_size
    net, loaded = load_checkpoint(finished)
    assert loaded["step"] == 2 and all(torch.equal(value, state["model"][key]) for key, value in net.state_dict().items())
    with pytest.raises(ValueError, match="weights only"):
        restored(tiny_run(tmp_path / "again"), finished)
    result = CliRunner().invoke(app, ["compact", str(checkpoint)])  # in place
    assert result.exit_code == 0 and "(compact)" in result.output
    assert torch.load(checkpoint, weights_only=False)["format"] == COMPACT


def test_a_compiled_run_steps_the_compiled_network_on_the_runs_own_parameters(tmp_path, monkeypatch):
    """``compile``: every training step goes through torch.compile's module, which shares the network's parameters,
    so the checkpoint holds what those steps made (here a compile that changes no arithmetic: the weights are the
    plain run's exactly); without it nothing is compiled."""
    compiled = []

    class Recorded(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.net, self.calls = net, 0

        def forward(self, *args):
            self.calls += 1
            return self.net(*args)

    def record(net):
        compiled.append(Recorded(net))
        return compiled[-1]

    monkeypatch.setattr(torch, "compile", record)
    plain = torch.load(train(tiny_run(tmp_path / "plain")), weights_only=False)["model"]
    assert compiled == []
    through = torch.load(train(tiny_run(tmp_path / "compiled", compile=True)), weights_only=False)["model"]
    assert len(compiled) == 1 and compiled[0].calls == 2
    assert all(torch.equal(value, plain[key]) for key, value in through.items())
