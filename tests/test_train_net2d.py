"""CadeNet2D, the all-2D network generation: its volume, shapes, training, export and the
runtime running its card (skipped where torch is not installed)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.usefixtures("small_validation")  # conftest: a test-sized validation set

from cade_cli.train.config import TrainConfig
from cade_cli.train.export import export_checkpoint, export_onnx, verify_onnx  # noqa: E402
from cade_cli.train.fit import train  # noqa: E402
from cade_cli.train.net2d import (  # noqa: E402
    DIVISOR2D,
    CadeNet2D,
    HalfRefinement,
    normalised_correlation,
    with_more_levels,
)
from cade_cli.train.networks import network_of  # noqa: E402
from cade_cli.train.validation import predict


def _with_batch_statistics(net: torch.nn.Module) -> torch.nn.Module:
    for module in net.modules():  # non-trivial batch-norm statistics
        if isinstance(module, torch.nn.BatchNorm2d):
            module.running_mean.uniform_(-0.1, 0.1)
            module.running_var.uniform_(0.5, 1.5)
    return net.eval()


def test_the_normalised_volume_holds_cosines_and_peaks_at_the_shift():
    generator = torch.Generator().manual_seed(0)
    right = torch.randn(1, 8, 6, 40, generator=generator)
    shift = 5
    left = 3.0 * torch.roll(right, shift, dims=-1)  # left(x) = 3 right(x - shift): a scaled copy
    volume = normalised_correlation(left, right, levels=9, groups=2).view(1, 9, 2, 6, 40)
    inside = volume[..., shift + 1:]  # columns whose match at every level is inside the right view
    assert torch.allclose(inside[:, shift], torch.ones_like(inside[:, shift]), atol=1e-4)  # cosine 1, whatever the gain
    assert (inside.argmax(dim=1) == shift).all()
    assert inside.abs().max() <= 1.0 + 1e-5
    assert (volume[..., :1][:, 1:] == 0).all()  # no right pixel at x - d < 0: zero


def test_the_2d_network_shapes_and_its_divisor():
    net = CadeNet2D(levels=32, width=16).eval()
    left, right = torch.rand(2, 1, 1, 48, 64).unbind(0)
    with torch.no_grad():
        out = net(left, right)
    assert set(out) == {"coarse", "uncertainty", "half", "disparity", "features"}
    assert out.pop("features").shape == (1, 32, 12, 16)
    assert all(value.shape == (1, 1, 48, 64) for value in out.values())
    assert torch.equal(out["disparity"], out["half"])  # no full-resolution stage by default
    assert 0 <= float(out["coarse"].min()) and float(out["coarse"].max()) <= 32 - 4
    with pytest.raises(ValueError, match="multiple of 16"):
        CadeNet2D(levels=40)
    assert CadeNet2D(levels=32, refine_channels=4).refinement is not None


def test_the_half_refinement_starts_as_its_input_and_reads_the_right_view_at_the_estimate():
    stage = HalfRefinement(features=4, channels=8).eval()
    left, right = torch.rand(2, 1, 4, 16, 24).unbind(0)
    estimate = torch.full((1, 1, 16, 24), 3.0)
    assert torch.equal(stage(left, right, estimate), estimate)  # zero-initialised last layer


def test_a_config_names_its_architecture():
    config = TrainConfig(out="x", textures=[], levels=32, architecture="cadenet2d", width2d=16, full_refinement=4)
    net = network_of(vars(config))
    assert isinstance(net, CadeNet2D) and net.design["width"] == 16 and net.design["refine_channels"] == 4
    with pytest.raises(ValueError, match="architecture"):
        network_of({**vars(config), "architecture": "nope"})


def test_a_config_sets_the_narrow_designs_widths_and_an_older_config_keeps_the_campaigns():
    narrow = network_of(vars(TrainConfig(out="x", textures=[], levels=32, architecture="cadenet2d", features2d=16,
                                         half_channels=8)))
    assert (narrow.design["features"], narrow.design["half_channels"]) == (16, 8)
    left = right = torch.rand(1, 1, 32, 48)
    with torch.no_grad():
        assert narrow.eval()(left, right)["features"].shape == (1, 16, 8, 12)
    older = {"architecture": "cadenet2d", "levels": 32}  # a config.json written before the keys existed
    assert (network_of(older).design["features"], network_of(older).design["half_channels"]) == (32, 16)


def test_the_slice_aggregation_applies_one_filter_to_every_disparity_and_starts_at_zero():
    from cade_cli.train.net2d import SliceAggregation

    stage = SliceAggregation(groups=4, channels=4).eval()
    cost = torch.rand(2, 8 * 4, 12, 16)  # 8 disparities x 4 group cosines, disparity-major
    assert torch.equal(stage(cost, 8), torch.zeros(2, 8, 12, 16))  # zero exit: an untrained stage changes nothing
    torch.nn.init.normal_(stage.net[-1].weight)
    with torch.no_grad():
        out = stage(cost, 8)
        alone = [stage(cost[:, 4 * d:4 * d + 4], 1) for d in range(8)]  # each disparity's slice by itself
        rolled = stage(torch.cat([cost[:, 4:], cost[:, :4]], dim=1), 8)
    assert float(out.abs().max()) > 0
    assert all(torch.allclose(out[:, d:d + 1], alone[d], atol=1e-6) for d in range(8))
    assert torch.allclose(rolled, torch.cat([out[:, 1:], out[:, :1]], dim=1), atol=1e-6)
    net = CadeNet2D(levels=32, width=16, slice_channels=4)
    assert net.slices is not None and CadeNet2D(levels=32).slices is None


def test_onnx_agrees_with_torch(tmp_path: Path):
    net = _with_batch_statistics(CadeNet2D(levels=32, width=16, refine_channels=4, slice_channels=4))
    torch.nn.init.normal_(net.slices.net[-1].weight, std=0.1)  # a trained-looking stage, not its zero start
    path = tmp_path / "net.onnx"
    export_onnx(net, path)
    assert verify_onnx(net, path, sizes=((48, 64), (80, 208))) < 1e-3


def test_a_2d_run_trains_resumes_exports_one_variant_and_the_runtime_runs_its_card(tmp_path: Path, monkeypatch):
    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=3, batch=1, height=48, width=64, levels=32,
                         workers=0, validate_every=3, checkpoint_every=2, stop_after=2, architecture="cadenet2d",
                         width2d=16)
    train(config)
    config.stop_after = None
    checkpoint = train(config)  # resumes at step 2
    state = torch.load(checkpoint, weights_only=False)
    assert state["step"] == 3 and state["config"]["architecture"] == "cadenet2d"

    card = export_checkpoint(checkpoint, tmp_path / "tiny2d.onnx", tmp_path / "tiny2d.json")
    assert card["divisor"] == DIVISOR2D and [v["levels"] for v in card["variants"]] == [32]
    assert card["architecture"].startswith("CadeNet2D") and card["onnx_vs_torch_max_abs_diff"] < 1e-3
    assert json.loads((tmp_path / "tiny2d.json").read_text())["design"]["architecture"] == "cadenet2d"

    from cade_cli.matching.base import DisparityRange
    from cade_cli.matching.network import NetworkStage

    rng = np.random.default_rng(0)
    left, right = rng.random((2, 50, 70), dtype=np.float32)  # not multiples of the divisor: padded, cropped
    got = NetworkStage(str(tmp_path / "tiny2d.json")).estimate(left, right, DisparityRange(0, 20))
    assert got.disparity.shape == (50, 70) and np.isfinite(got.disparity).all()
    wide = NetworkStage(str(tmp_path / "tiny2d.json")).estimate(left, right, DisparityRange(0, 40))
    assert wide.disparity.shape == (50, 70)  # a span beyond the one variant runs on the pyramid


def test_validation_predicts_with_the_networks_own_divisor():
    net = CadeNet2D(levels=32, width=16).eval()
    rng = np.random.default_rng(1)
    left, right = rng.random((2, 40, 50), dtype=np.float32)  # padded to 48 x 64, not to 40 x 56
    assert predict(net, left, right, "cpu").shape == (40, 50)


def test_the_data_levers_are_drawn_only_when_on_and_feed_the_consistency_loss(tmp_path: Path):
    from cade_cli.train.batches import GeneratedBatches

    base = TrainConfig(out="x", textures=[], batch=2, height=48, width=64, levels=32, architecture="cadenet2d",
                       width2d=16)
    plain = GeneratedBatches(base)[3]
    assert "left_alt" not in plain
    levers = GeneratedBatches(TrainConfig(**{**vars(base), "feature_consistency": 0.1, "scene_range": 0.2,
                                             "eraser": 1.0, "misaligned": 1.0, "misaligned_offset": 2.0,
                                             "ground": 1.0}))[3]
    assert levers["left_alt"].shape == levers["left"].shape
    assert not torch.equal(levers["left_alt"], levers["left"])  # another band of the same view
    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=2, batch=1, height=48, width=64, levels=32,
                         workers=0, validate_every=100, architecture="cadenet2d", width2d=16,
                         feature_consistency=0.1, eraser=0.5, scene_range=0.25, ground=0.5)
    assert torch.load(train(config), weights_only=False)["step"] == 2
    with pytest.raises(ValueError, match="cadenet2d"):
        train(TrainConfig(**{**vars(config), "architecture": "cadenet", "out": str(tmp_path / "other")}))


def test_the_consistency_loss_is_zero_for_the_same_band_and_positive_for_another():
    from cade_cli.train.fit import feature_consistency

    net = CadeNet2D(levels=32, width=16).eval()
    left = torch.rand(1, 1, 48, 64)
    with torch.no_grad():
        features = net(left, left)["features"]
        assert float(feature_consistency(net, features, left)) < 1e-5
        assert float(feature_consistency(net, features, 1.0 - left)) > 1e-3


def test_an_int8_twin_runs_in_the_runtime_and_stays_near_its_float_model(tmp_path: Path):
    pytest.importorskip("onnxruntime.quantization")
    from cade_cli.matching.base import DisparityRange
    from cade_cli.matching.network import NetworkStage
    from cade_cli.train.quantize import quantise_card

    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=2, batch=1, height=48, width=64, levels=32,
                         workers=0, validate_every=100, architecture="cadenet2d", width2d=16)
    export_checkpoint(train(config), tmp_path / "f32.onnx", tmp_path / "f32.json")
    card = quantise_card(tmp_path / "f32.json", tmp_path / "q8.json", [], count=2)
    assert card["quantised"]["from"] == "f32.json" and card["variants"][0]["file"] == "f32-int8.onnx"
    import onnx

    ops = {node.op_type for node in onnx.load(str(tmp_path / "f32-int8.onnx")).graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= ops
    rng = np.random.default_rng(0)
    left, right = rng.random((2, 48, 64), dtype=np.float32)
    results = [NetworkStage(str(tmp_path / name)).estimate(left, right, DisparityRange(0, 20)).disparity
               for name in ("f32.json", "q8.json")]
    assert np.isfinite(results[1]).all()
    assert np.abs(results[0] - results[1]).mean() < 2.0  # px: int8 rounding, not another network


def test_a_card_without_runtime_refinement_returns_the_networks_map(tmp_path: Path):
    from cade_cli.matching import get_matcher
    from cade_cli.matching.base import DisparityRange
    from cade_cli.matching.network import NetworkStage

    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=1, batch=1, height=48, width=64, levels=32,
                         workers=0, validate_every=100, architecture="cadenet2d", width2d=16)
    checkpoint = train(config)
    export_checkpoint(checkpoint, tmp_path / "plain.onnx", tmp_path / "plain.json", runtime_refinement="none")
    export_checkpoint(checkpoint, tmp_path / "sgbm.onnx", tmp_path / "sgbm.json")
    rng = np.random.default_rng(2)
    left = rng.random((48, 96), dtype=np.float32)
    right = np.roll(left, -6, axis=1)
    disparity_range = DisparityRange(0, 24)
    network = NetworkStage(str(tmp_path / "plain.json"))(left, right, disparity_range)
    plain = get_matcher("cade", model=str(tmp_path / "plain.json")).kernel(left, right, disparity_range)
    refined = get_matcher("cade", model=str(tmp_path / "sgbm.json")).kernel(left, right, disparity_range)
    np.testing.assert_array_equal(plain.disparity[plain.valid], network[plain.valid])
    assert not np.array_equal(refined.disparity[refined.valid], network[refined.valid])  # SGBM took its matches


def test_a_crop_schedule_grows_the_crops_at_its_steps_and_refuses_malformed_entries():
    from cade_cli.train.batches import GeneratedBatches, crop_at, parse_crop_schedule

    config = TrainConfig(out="x", textures=[], batch=1, height=64, width=96, levels=32,
                         crop_schedule="0:64x64,3:64x128")
    assert [crop_at(config, step) for step in (0, 2, 3, 9)] == [(64, 64), (64, 64), (64, 128), (64, 128)]
    assert GeneratedBatches(config)[4]["left"].shape == (1, 1, 64, 128)
    assert crop_at(TrainConfig(out="x", textures=[], height=64, width=96), 5) == (64, 96)
    for bad in ("0:64x60", "5:64x64,2:64x64", "64x64", "0:axb"):
        with pytest.raises(ValueError):
            parse_crop_schedule(bad)


def test_the_exported_row_read_equals_the_bilinear_grid_read_zeros_outside_included():
    from cade_cli.train.model import row_gathered, shifted_right

    generator = torch.Generator().manual_seed(0)
    features = torch.rand(2, 8, 12, 40, generator=generator)
    disparity = torch.rand(2, 1, 12, 40, generator=generator) * 60 - 10  # some reads fall off either edge
    expected = shifted_right(features, disparity)
    assert torch.allclose(row_gathered(features, disparity), expected, atol=1e-4)
    assert float(expected.abs().sum()) > 0 and torch.equal(row_gathered(features, torch.full_like(disparity, 50.0)),
                                                           torch.zeros_like(features))


def test_in_eval_the_views_run_apart_and_give_what_the_batched_views_give():
    net = CadeNet2D(levels=32, features=16, width=16).eval()
    left, right = torch.rand(2, 1, 1, 32, 48).unbind(0)
    with torch.no_grad():
        half, quarter = net.features(torch.cat([left, right]))
        apart = net.features(right)
    assert torch.allclose(half[1:], apart[0], atol=1e-6) and torch.allclose(quarter[1:], apart[1], atol=1e-6)


def test_the_exported_per_disparity_stage_is_one_grouped_convolution_a_layer_with_the_same_values():
    from cade_cli.train.net2d import SliceAggregation

    torch.manual_seed(0)
    stage = SliceAggregation(groups=4, channels=4)
    for module in stage.modules():  # trained-looking BatchNorm statistics and a non-zero exit
        if isinstance(module, torch.nn.BatchNorm2d):
            module.running_mean.uniform_(-0.5, 0.5), module.running_var.uniform_(0.5, 2.0)
            module.weight.data.uniform_(0.5, 1.5), module.bias.data.uniform_(-0.2, 0.2)
    torch.nn.init.normal_(stage.net[-1].weight)
    cost = torch.rand(1, 8 * 4, 12, 16) * 2 - 1
    with torch.no_grad():
        batched, grouped = stage.eval()(cost, 8), stage.grouped(cost, 8)
    assert grouped.shape == batched.shape == (1, 8, 12, 16) and float(batched.abs().max()) > 0.1
    assert torch.allclose(grouped, batched, atol=1e-5)


def test_a_net_widened_to_more_levels_scores_the_old_disparities_as_the_checkpoint_did(tmp_path: Path):
    """with_more_levels: the 64-level net's weights in a 128-level twin give the same
    aggregation logits for disparities 0..15 of the 1/4 level (every weight random, so a
    misplaced feature or disparity channel shows) and zeros for the new ones before the
    prior; a run started with --init-partial from the narrower checkpoint loads them."""
    torch.manual_seed(3)
    design = dict(features=8, width=16, half_channels=8, slice_channels=4)
    narrow, wide = CadeNet2D(levels=64, **design), CadeNet2D(levels=128, **design)
    with torch.no_grad():
        for name, tensor in narrow.state_dict().items():
            if name.endswith("running_var"):
                tensor.uniform_(0.5, 1.5)
            elif tensor.is_floating_point():
                tensor.normal_(0.0, 0.3)
    wide.load_state_dict(with_more_levels(narrow.state_dict(), wide))
    narrow.eval(), wide.eval()
    left, right = torch.rand(1, 1, 64, 96), torch.rand(1, 1, 64, 96)
    with torch.no_grad():
        (_, feat_left), (_, feat_right) = narrow.features(left), narrow.features(right)
        logits = {}
        for net in (narrow, wide):
            cost = normalised_correlation(feat_left, feat_right, net.coarse_levels, net.groups)
            logits[net.coarse_levels] = net.aggregation(torch.cat([cost, feat_left], dim=1))
    assert logits[32].shape[1] == 32 and logits[16].abs().mean() > 0.01
    torch.testing.assert_close(logits[32][:, :16], logits[16], atol=1e-5, rtol=1e-5)
    assert torch.all(logits[32][:, 16:] == 0)
    with pytest.raises(ValueError, match="fewer levels"):
        with_more_levels(CadeNet2D(levels=64, features=16, width=16).state_dict(), wide)
    config = TrainConfig(out=str(tmp_path / "narrow"), textures=[], levels=64, architecture="cadenet2d")
    torch.save({"model": narrow.state_dict(), "config": config.__dict__ | {"features2d": 8, "width2d": 16,
                "half_channels": 8, "slice_channels": 4}}, tmp_path / "narrow.pt")
    run = TrainConfig(out=str(tmp_path / "wide"), textures=[], steps=1, batch=1, height=64, width=128, levels=128,
                      workers=0, architecture="cadenet2d", features2d=8, width2d=16, half_channels=8, slice_channels=4,
                      init=str(tmp_path / "narrow.pt"), init_partial=True)
    trained = torch.load(train(run), weights_only=False)["model"]
    assert trained["aggregation.entry.0.weight"].shape[1] == 4 * 32 + 8

