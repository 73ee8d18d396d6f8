"""CadeNet, its training loop and its ONNX export (skipped where torch is not installed)."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.usefixtures("small_validation")  # conftest: a test-sized validation set

from cade_cli.train.batches import GeneratedBatches
from cade_cli.train.config import TrainConfig
from cade_cli.train.export import export_checkpoint, verify_onnx  # noqa: E402
from cade_cli.train.checkpoints import average_checkpoints  # noqa: E402
from cade_cli.train.fit import learning_rate, train  # noqa: E402
from cade_cli.train.model import (  # noqa: E402
    LEGACY_DESIGN,
    CadeNet,
    ExportWrapper,
    Refinement,
    adapt_state_dict,
    groupwise_correlation,
    parameter_count,
)
from synthetic import write_real_scene  # noqa: E402


def test_groupwise_correlation_matches_a_loop_reference():
    generator = torch.Generator().manual_seed(0)
    left, right = torch.rand(2, 8, 5, 12, generator=generator), torch.rand(2, 8, 5, 12, generator=generator)
    volume = groupwise_correlation(left, right, levels=4, groups=2)
    assert volume.shape == (2, 2, 4, 5, 12)
    for d in range(4):
        for x in range(12):
            for g in range(2):
                channels = slice(4 * g, 4 * g + 4)
                expected = (left[:, channels, :, x] * right[:, channels, :, x - d]).mean(1) if x >= d else 0.0
                torch.testing.assert_close(volume[:, g, d, :, x], torch.as_tensor(expected).expand(2, 5).float())


def test_network_shapes_and_range():
    net = CadeNet(levels=32).eval()
    with torch.no_grad():
        out = net(torch.rand(1, 1, 48, 64), torch.rand(1, 1, 48, 64))
    assert set(out) == {"disparity", "coarse", "uncertainty"}
    assert all(value.shape == (1, 1, 48, 64) for value in out.values())
    assert 0 <= out["coarse"].min() and out["coarse"].max() <= 32 - 4
    assert parameter_count(net) < 200_000
    with pytest.raises(ValueError, match="multiple of 8"):
        CadeNet(levels=30)


def test_batches_depend_only_on_seed_and_step():
    config = TrainConfig(out="unused", textures=[], steps=10, batch=2, height=32, width=64, levels=16)
    batches = GeneratedBatches(config)
    first, again, other = batches[3], GeneratedBatches(config)[3], batches[4]
    assert torch.equal(first["left"], again["left"]) and torch.equal(first["disparity"], again["disparity"])
    assert not torch.equal(first["left"], other["left"])
    assert first["left"].shape == (2, 1, 32, 64) and first["disparity"].max() < 16


def test_learning_rate_warms_up_then_decays():
    config = TrainConfig(out="unused", textures=[], steps=1000, warmup=100, lr=1e-3)
    rates = [learning_rate(config, step) for step in range(1000)]
    assert rates[0] < rates[99] == pytest.approx(1e-3)
    assert rates[-1] == pytest.approx(5e-5, rel=0.05) and all(a >= b for a, b in zip(rates[100:], rates[101:]))


def test_a_cpu_budget_ends_the_cosine_when_it_is_spent():
    config = TrainConfig(out="unused", textures=[], steps=100_000, warmup=100, lr=1e-3, cpu_budget_s=3600)
    assert learning_rate(config, 50, cpu_s=3000) == learning_rate(TrainConfig(
        out="unused", textures=[], steps=100_000, warmup=100, lr=1e-3), 50)  # the warm-up is by steps
    by_cpu = [learning_rate(config, 500, cpu_s=cpu) for cpu in (0, 900, 1800, 2700, 3600, 5000)]
    assert by_cpu[0] == pytest.approx(1e-3, rel=1e-3) and by_cpu[2] == pytest.approx(0.525e-3, rel=1e-3)
    assert by_cpu[-2] == by_cpu[-1] == pytest.approx(5e-5) and all(a > b for a, b in zip(by_cpu[:4], by_cpu[1:5]))
    assert learning_rate(config, 99_000, cpu_s=0) < 1e-4  # the steps still end it where they come first


def test_a_cpu_budget_stops_the_run_checkpointed_and_a_resume_after_it_takes_one_step(tmp_path: Path):
    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=10_000, batch=1, height=32, width=64,
                         levels=16, workers=0, validate_every=10_000, checkpoint_every=10_000, cpu_budget_s=1.0)
    state = torch.load(train(config), weights_only=False)
    assert 1 <= state["step"] < 10_000 and state["cpu_s"] > 1.0
    again = torch.load(train(config), weights_only=False)  # the budget is the run's, over resumes
    assert again["step"] == state["step"] + 1


def test_training_logs_checkpoints_resumes_and_exports(tmp_path: Path, capsys):
    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=4, batch=1, height=32, width=64,
                         levels=16, workers=0, validate_every=2, checkpoint_every=2, stop_after=3)
    checkpoint = train(config)
    assert torch.load(checkpoint, weights_only=False)["step"] == 3
    assert "finished:" not in capsys.readouterr().out  # stopped early: a queue relaunches it
    config.stop_after = None
    train(config)
    state = torch.load(checkpoint, weights_only=False)
    assert state["step"] == 4
    assert "finished: step 4 of 4 (checkpointed)" in capsys.readouterr().out
    train(config)  # nothing left to train: says so again, so a queue never relaunches it
    assert "finished: step 4 of 4" in capsys.readouterr().out
    config.steps = 6
    with (tmp_path / "run" / "log.csv").open("a") as log:  # as a run killed after an unsaved step 5 leaves it
        log.write("5,0,1e-3,1.0,1.0,train,,\n")
    train(config)  # resumes at step 4
    rows = list(csv.DictReader((tmp_path / "run" / "log.csv").open()))
    validated = [int(row["step"]) for row in rows if row["set"] == "synthetic"]
    assert validated == [2, 4, 6]
    assert [row["step"] for row in rows].count("5") == 0  # the unsaved step's row was dropped on resume
    assert torch.load(checkpoint, weights_only=False)["step"] == 6

    onnx_path = tmp_path / "tiny.onnx"
    card = export_checkpoint(checkpoint, onnx_path, tmp_path / "tiny.json", other_ranges=(40, 8, 16))
    assert card["trained_levels"] == 16 and card["divisor"] == 8 and card["steps"] == 6
    assert [v["levels"] for v in card["variants"]] == [8, 16, 40]
    assert [v["file"] for v in card["variants"]] == ["tiny-8.onnx", "tiny.onnx", "tiny-40.onnx"]
    assert all(len(v["sha256"]) == 64 for v in card["variants"])
    assert card["onnx_vs_torch_max_abs_diff"] < 1e-3
    assert card["output"] == "disparity" and card["architecture"].endswith("full-res refinement")


def test_onnx_agrees_with_torch_on_odd_sizes(tmp_path: Path):
    from cade_cli.train.export import export_onnx

    net = CadeNet(levels=24).eval()
    for module in net.modules():  # non-trivial batch-norm statistics
        if isinstance(module, (torch.nn.BatchNorm2d, torch.nn.BatchNorm3d)):
            module.running_mean.uniform_(-0.1, 0.1)
            module.running_var.uniform_(0.5, 1.5)
    path = tmp_path / "net.onnx"
    export_onnx(net, path)
    assert verify_onnx(net, path, sizes=((40, 56), (72, 200))) < 1e-3


def test_a_separable_aggregation_slides_along_disparity_and_exports(tmp_path: Path):
    from cade_cli.train.export import export_onnx

    net = CadeNet(levels=24, channels3d=4, aggregation="separable").eval()
    kernels = [m.kernel_size for m in net.aggregation.modules() if isinstance(m, torch.nn.Conv3d)]
    assert kernels and all(sorted(k) != [3, 3, 3] for k in kernels) and (3, 1, 1) in kernels and (1, 3, 3) in kernels
    # no weight depends on the range: the state dict of one width loads into another
    wide = CadeNet(levels=48, channels3d=4, aggregation="separable").eval()
    wide.load_state_dict(net.state_dict())
    left = torch.rand(1, 1, 32, 64)
    right = torch.roll(left, -2, dims=-1)
    assert wide(left, right)["disparity"].shape == (1, 1, 32, 64)
    path = tmp_path / "net.onnx"
    export_onnx(net, path)
    assert verify_onnx(net, path, sizes=((40, 56),)) < 1e-3
    with pytest.raises(ValueError, match="aggregation"):
        CadeNet(levels=24, aggregation="2d")


@pytest.mark.parametrize("output", ["coarse", "disparity"])
def test_export_output_picks_the_map_and_leaves_the_refinement_net_out_of_coarse_graphs(tmp_path: Path, output):
    import onnx

    from cade_cli.train.export import export_onnx

    torch.manual_seed(0)
    net = CadeNet(levels=24).eval()
    torch.nn.init.normal_(net.refinement.net[-1].weight, std=0.1)  # a refinement that changes the map
    path = tmp_path / "net.onnx"
    export_onnx(net, path, output=output)
    assert verify_onnx(net, path, output=output, sizes=((40, 56),)) < 1e-3
    left, right = torch.rand(1, 1, 40, 56), torch.rand(1, 1, 40, 56)
    with torch.no_grad():
        out = net(left, right)
        exported, _ = ExportWrapper(net, output)(left, right)
    assert torch.equal(exported, out[output]) and not torch.allclose(out["coarse"], out["disparity"])
    # The refinement net's 2-channel input convolution is in the graph only when exported.
    first_refinement = net.refinement.net[0][0].weight.detach().numpy()
    initializers = [onnx.numpy_helper.to_array(t) for t in onnx.load(str(path)).graph.initializer]
    present = any(a.shape == first_refinement.shape and np.allclose(a, first_refinement) for a in initializers)
    assert present == (output == "disparity")


def test_export_output_must_be_known():
    with pytest.raises(ValueError, match="coarse"):
        ExportWrapper(CadeNet(levels=16), "refined")


def test_refinement_sees_a_map_beyond_its_scale_as_relative_depth():
    torch.manual_seed(0)
    refinement = Refinement(8).eval()
    torch.nn.init.normal_(refinement.net[-1].weight, std=0.1)  # not the identity it starts as
    left = torch.rand(1, 1, 24, 32)
    disparity = 100.0 * torch.rand(1, 1, 24, 32)
    disparity[0, 0, 0, 0] = 128.0  # reaches the scale exactly: no shift yet
    with torch.no_grad():
        inside = refinement(disparity, left, 128.0) - disparity
        beyond = refinement(disparity + 60.0, left, 128.0) - (disparity + 60.0)
        below = refinement(disparity - 60.0, left, 128.0) - (disparity - 60.0)
    torch.testing.assert_close(beyond, inside)  # lowered by its 60 px excess: same residual
    assert (below - inside).abs().max() > 1e-3   # within the scale, absolute depth still counts


def test_a_3x3x3_entry_kernel_becomes_the_1x1x1_kernel_with_the_same_flat_response():
    torch.manual_seed(0)
    legacy, current = CadeNet(levels=32, **LEGACY_DESIGN).eval(), CadeNet(levels=32).eval()
    current.load_state_dict(adapt_state_dict(legacy.state_dict(), current))  # every key, every shape
    wide, narrow = legacy.aggregation.entry[0][0], current.aggregation.entry[0][0]
    assert wide.kernel_size == (3, 3, 3) and narrow.kernel_size == (1, 1, 1)
    flat = torch.full((1, 8, 6, 7, 9), 0.3) + torch.arange(8.0).view(1, 8, 1, 1, 1)  # constant per group
    with torch.no_grad():
        torch.testing.assert_close(narrow(flat)[..., 1:-1, 1:-1, 1:-1], wide(flat)[..., 1:-1, 1:-1, 1:-1])
        ramp = torch.rand(1, 8, 6, 7, 9)
        assert (narrow(ramp) - wide(ramp)).abs().max() > 1e-3  # not the same layer on a textured volume


def test_checkpoints_keep_their_design_through_fine_tuning_and_export(tmp_path: Path):
    legacy = CadeNet(levels=16, **LEGACY_DESIGN)
    config = TrainConfig(out="old", textures=[], levels=16)
    old_config = {k: v for k, v in vars(config).items() if k not in ("padding", "entry_kernel", "channels3d")}
    torch.save({"model": legacy.state_dict(), "config": old_config, "step": 1, "elapsed_s": 0.0},
               tmp_path / "legacy.pt")
    # a checkpoint written before the design keys existed exports as the design it was trained with
    card = export_checkpoint(tmp_path / "legacy.pt", tmp_path / "old.onnx", tmp_path / "old.json", other_ranges=())
    assert card["design"] == LEGACY_DESIGN
    # and starts a fine-tuning run of the current design
    tuned = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=1, batch=1, height=32, width=64,
                        levels=16, workers=0, init=str(tmp_path / "legacy.pt"))
    card = export_checkpoint(train(tuned), tmp_path / "new.onnx", tmp_path / "new.json", other_ranges=(24,))
    assert card["design"] == {"padding": "zeros", "entry_kernel": 1, "channels3d": 8, "census": False,
                              "aggregation": "3d", "second_scale": False}
    assert card["onnx_vs_torch_max_abs_diff"] < 1e-3
    assert card["output"] == "disparity" and card["architecture"].endswith("full-res refinement")


def test_a_soup_is_the_mean_of_its_checkpoints_weights_and_exports(tmp_path: Path):
    """Two nets of one design (different weights and BatchNorm statistics) average key by key;
    the integer buffers stay the first's; another design is refused; the soup exports."""
    paths = []
    for seed in (1, 2):
        torch.manual_seed(seed)
        net = CadeNet(levels=16)
        with torch.no_grad():  # every weight and BatchNorm statistic differs between the two
            for tensor in net.state_dict().values():
                if tensor.is_floating_point():
                    tensor.uniform_(0.5, 1.5)
        config = TrainConfig(out="run", textures=[], levels=16)
        torch.save({"model": net.state_dict(), "config": dataclasses.asdict(config), "step": 500, "elapsed_s": 0.0},
                   tmp_path / f"{seed}.pt")
        paths.append(tmp_path / f"{seed}.pt")
    first, second = (torch.load(path, weights_only=False)["model"] for path in paths)
    soup = average_checkpoints(paths)
    assert soup["optimizer"] is None and soup["step"] == 500
    for key, value in soup["model"].items():
        if value.is_floating_point():
            torch.testing.assert_close(value, (first[key] + second[key]) / 2)
            assert not torch.equal(value, first[key])
        else:
            assert torch.equal(value, first[key])
    other = TrainConfig(out="run", textures=[], levels=24)
    torch.save({"model": CadeNet(levels=24, channels3d=16).state_dict(), "config": dataclasses.asdict(other)},
               tmp_path / "other.pt")
    with pytest.raises(ValueError, match="another design"):
        average_checkpoints([paths[0], tmp_path / "other.pt"])
    with pytest.raises(ValueError, match="at least two"):
        average_checkpoints(paths[:1])
    torch.save(soup, tmp_path / "soup.pt")
    card = export_checkpoint(tmp_path / "soup.pt", tmp_path / "soup.onnx", tmp_path / "soup.json", other_ranges=())
    assert card["onnx_vs_torch_max_abs_diff"] < 1e-3


class _EchoNet(torch.nn.Module):
    """Stands in for CadeNet: its 'disparity' is the (padded) left band itself."""

    def __init__(self):
        super().__init__()
        self.shapes = []

    def forward(self, left, right):
        self.shapes.append(tuple(left.shape))
        return {"disparity": left}


def test_validation_pads_like_the_runtime_and_pools_the_benchmark_metrics():
    from cade_cli.train.validation import evaluate, predict

    net = _EchoNet()
    left = np.arange(5 * 9, dtype=np.float32).reshape(5, 9)  # not a multiple of the divisor
    np.testing.assert_array_equal(predict(net, left, left, "cpu"), left)  # padded, then cropped back
    assert net.shapes == [(1, 1, 8, 16)]
    gt_a = np.full((5, 9), 0.0, np.float32)
    gt_a[0, 0] = np.nan  # unknown: not scored
    gt_b = np.full((2, 3), 1.0, np.float32)
    ones, fives = np.full((5, 9), 1.0, np.float32), np.full((2, 3), 5.0, np.float32)
    pairs = [(ones, ones, gt_a), (fives, fives, gt_b)]
    epe, bad3 = evaluate(net, pairs, "cpu")
    # pooled over the 44 + 6 scored pixels: errors 1 (44 times) and 4 (6 times)
    assert epe == pytest.approx((44 * 1 + 6 * 4) / 50)
    assert bad3 == pytest.approx(100 * 6 / 50)


def test_the_gpu_recipe_runs_its_cpu_path_in_budgeted_resumable_calls(tmp_path: Path, monkeypatch):
    """docs/gpu-recipe.md's options on the CPU: bf16 autocast, data from worker processes
    (rendered and real pairs), and calls cut short by a time budget that resume where the
    last one stopped and end at the schedule's last step."""
    real = tmp_path / "real"
    for index, name in enumerate(("a", "b")):
        write_real_scene(real / name, np.random.default_rng(index))
    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=4, batch=2, height=32, width=64, levels=16,
                         workers=1, validate_every=100, checkpoint_every=100, amp=True, time_budget_s=1e-3,
                         real_dir=str(real), real_share=0.5)
    steps = []
    for _ in range(6):
        train(config)
        steps.append(torch.load(tmp_path / "run" / "last.pt", weights_only=False)["step"])
    assert steps[:4] == [1, 2, 3, 4] and steps[-1] == 4  # one step per call, then nothing left to do
    rows = list(csv.DictReader((tmp_path / "run" / "log.csv").open()))
    assert [row["step"] for row in rows if row["set"] == "synthetic"] == ["4"]


def test_a_wider_3d_part_starts_from_a_narrower_checkpoints_2d_weights(tmp_path: Path):
    """--channels3d 16 --init-partial: the 2D features and the refinement come from the
    8-channel checkpoint, the 3D aggregation starts fresh, and the design survives export."""
    from cade_cli.train.export import load_checkpoint

    narrow = CadeNet(levels=16)
    torch.save({"model": narrow.state_dict()}, tmp_path / "narrow.pt")
    config = TrainConfig(out=str(tmp_path / "wide"), textures=[], steps=1, batch=1, height=32, width=64, levels=16,
                         workers=0, validate_every=100, channels3d=16, init=str(tmp_path / "narrow.pt"),
                         init_partial=True, lr=1e-12, warmup=0)
    train(config)
    wide, _ = load_checkpoint(tmp_path / "wide" / "last.pt")
    assert wide.design["channels3d"] == 16 and parameter_count(wide) > parameter_count(narrow)
    first = "features.net.0.0.weight" if "features.net.0.0.weight" in narrow.state_dict() else next(
        key for key in narrow.state_dict() if key.startswith("features"))
    torch.testing.assert_close(wide.state_dict()[first], narrow.state_dict()[first], atol=1e-6, rtol=0)
    with pytest.raises(RuntimeError):  # without --init-partial the shapes do not fit
        train(TrainConfig(out=str(tmp_path / "strict"), textures=[], steps=1, batch=1, height=32, width=64,
                          levels=16, workers=0, channels3d=16, init=str(tmp_path / "narrow.pt")))


def test_census_cost_peaks_at_the_shift_and_ignores_monotonic_intensity_changes():
    """A texture and its copy shifted by 8 px, the copy through an increasing tone curve:
    the census cost of the 1/4 level is 0.5 (identical bits) at level 2 (8 px) and lower
    at every other level."""
    from cade_cli.train.census import census_cost

    generator = torch.Generator().manual_seed(1)
    left = torch.rand(1, 1, 32, 64, generator=generator)
    right = torch.roll(left, -8, dims=-1) ** 3 * 2 + 0.1  # right(x - 8) = f(left(x)), f increasing
    cost = census_cost(left, right, levels=6)
    assert cost.shape == (1, 1, 6, 8, 16)
    inside = cost[0, 0, :, 1:-1, 3:-3]  # away from the borders the roll wraps
    assert torch.all(inside[2] == 0.5)
    assert torch.all(inside[[0, 1, 3, 4, 5]].amax(dim=0) < 0.5)


def test_a_census_net_starts_as_the_checkpoint_it_was_widened_from(tmp_path: Path):
    """--census --init-partial: the aggregation's first kernel gains one input with zero
    weights, so before training the net computes what the checkpoint computed; the design
    survives export and the ONNX graph agrees with torch."""
    from cade_cli.train.export import export_onnx, load_checkpoint
    from cade_cli.train.model import transferable

    plain = CadeNet(levels=16).eval()
    census = CadeNet(levels=16, census=True).eval()
    census.load_state_dict(transferable(plain.state_dict(), census))
    left, right = torch.rand(1, 1, 32, 48), torch.rand(1, 1, 32, 48)
    with torch.no_grad():
        torch.testing.assert_close(census(left, right)["disparity"], plain(left, right)["disparity"])
    torch.save({"model": plain.state_dict()}, tmp_path / "plain.pt")
    config = TrainConfig(out=str(tmp_path / "census"), textures=[], steps=1, batch=1, height=32, width=64,
                         levels=16, workers=0, validate_every=100, census=True, init=str(tmp_path / "plain.pt"),
                         init_partial=True)
    train(config)
    trained, _ = load_checkpoint(tmp_path / "census" / "last.pt")
    assert trained.design["census"] is True
    assert trained.aggregation.entry[0][0].weight.shape[1] == 9  # 8 correlation groups + the census cost
    path = tmp_path / "census.onnx"
    export_onnx(trained.eval(), path)
    assert verify_onnx(trained.eval(), path, sizes=((40, 56),)) < 1e-3


def test_a_batch_without_ground_truth_is_skipped_not_learned(tmp_path: Path, monkeypatch, capsys):
    """A batch whose loss is not finite (no pixel with ground truth in range, or a bf16
    overflow) is skipped: one such step would otherwise leave NaN weights for the rest of the run."""
    import cade_cli.train.batches as batches

    real_pair = batches.training_pair

    def no_ground_truth(rng, pool, real, config, *size, **sources):
        pair = real_pair(rng, pool, real, config, *size, **sources)
        return dataclasses.replace(pair, disparity=np.full_like(pair.disparity, np.nan))

    monkeypatch.setattr(batches, "training_pair", no_ground_truth)
    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=2, batch=1, height=32, width=64, levels=16,
                         workers=0, validate_every=100, lr=1.0, warmup=0)
    state = torch.load(train(config), weights_only=False)["model"]
    assert all(torch.isfinite(value).all() for value in state.values() if value.is_floating_point())
    assert capsys.readouterr().out.count("step skipped") == 2


def test_the_second_scale_reads_the_right_view_at_the_shifted_column_and_its_volume_peaks_at_the_truth():
    from cade_cli.train.model import HALF_OFFSETS, local_correlation, shifted_right

    generator = torch.Generator().manual_seed(0)
    right = torch.rand(1, 8, 6, 40, generator=generator)
    # bilinear reading at x - d, zeros outside the view
    for d in (0.0, 3.0, 2.25, -1.5):
        read = shifted_right(right, torch.full((1, 1, 6, 40), d))
        for x in range(40):
            position = x - d
            low, weight = int(np.floor(position)), position - np.floor(position)
            expected = sum(w * (right[..., c] if 0 <= c < 40 else torch.zeros_like(right[..., 0]))
                           for c, w in ((low, 1 - weight), (low + 1, weight)) if w > 0)
            torch.testing.assert_close(read[..., x], expected)
    # right = left moved by a known disparity; a start 2 px off: the volume peaks at offset +2
    left = torch.rand(1, 8, 6, 60, generator=generator)
    truth = 7
    shifted = torch.zeros_like(left)
    shifted[..., :-truth] = left[..., truth:]  # right(x) = left(x + truth): disparity 7
    volume = local_correlation(left, shifted, torch.full((1, 1, 6, 60), truth - 2.0), groups=2)
    per_offset = volume[..., 20:50].view(1, 2 * HALF_OFFSETS + 1, 2, 6, 30).mean(dim=(2, 3, 4))
    assert int(per_offset.argmax()) - HALF_OFFSETS == 2


def test_a_second_scale_starts_at_the_quarter_estimate_and_exports(tmp_path: Path):
    from cade_cli.train.export import export_onnx

    torch.manual_seed(0)
    net = CadeNet(levels=24, second_scale=True).eval()
    left = torch.rand(1, 1, 40, 64)
    right = torch.roll(left, -4, dims=-1)
    with torch.no_grad():
        out = net(left, right)
    # a zero-initialised last layer: a uniform choice, no residual (only the 1/2-level resampling)
    assert (out["half"] - out["coarse"]).abs().max() < 0.05 * out["coarse"].abs().max() + 1e-3
    torch.nn.init.normal_(net.second_scale.net[-1].weight, std=0.1)
    with torch.no_grad():
        changed = net(left, right)
    assert not torch.allclose(changed["half"], out["half"], atol=1e-3)
    wide = CadeNet(levels=48, second_scale=True).eval()  # no weight depends on the range
    wide.load_state_dict(net.state_dict())
    path = tmp_path / "net.onnx"
    export_onnx(net, path)
    assert verify_onnx(net, path, sizes=((40, 56), (72, 200))) < 1e-3


def test_validation_scores_a_downscaled_pair_in_the_scenes_px_over_all_its_pixels():
    from cade_cli.train.validation import at_truth_scale, evaluate

    half = np.full((4, 6), 10.0, np.float32)  # a pair run at half size: 10 px there
    truth = np.full((8, 12), 21.0, np.float32)  # 21 px at the scene's size
    brought = at_truth_scale(half, truth)
    assert brought.shape == (8, 12) and np.allclose(brought, 20.0)
    epe, bad3 = evaluate(_EchoNet(), [(half, half, truth)], "cpu")
    assert epe == pytest.approx(1.0) and bad3 == 0.0  # 1 px of the scene, on all 96 of its pixels
    same = np.full((8, 12), 3.0, np.float32)
    assert at_truth_scale(same, truth) is same
