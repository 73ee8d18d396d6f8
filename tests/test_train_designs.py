"""The Accuracy V bake-off's network designs (cadenet-convex, cadenet-iterative, cadenet-peak):
shapes, learning, their export to ONNX (numbers and operators), their building blocks, and the
shipped ``cade disparity`` running an exported one (skipped where torch is not installed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")

from cli_runner import run_cade, write_png16  # noqa: E402
from synthetic import smooth_texture  # noqa: E402

from cade_cli.io.disparity import read_disparity  # noqa: E402
from cade_cli.train.config import TrainConfig  # noqa: E402
from cade_cli.train.export import export_checkpoint, export_onnx, verify_onnx  # noqa: E402
from cade_cli.train.fit import loss_terms, pick_loss, train  # noqa: E402
from cade_cli.train.net2d import normalised_correlation  # noqa: E402
from cade_cli.train.net_iterative import CadeNetIterative  # noqa: E402
from cade_cli.train.net_blocks import (convex_mixture, convex_upsample, convex_weights, expectation,  # noqa: E402
                                       hat_lookup)
from cade_cli.train.net_peak import peak_expectation  # noqa: E402
from cade_cli.train.model import transferable  # noqa: E402
from cade_cli.train.networks import ARCHITECTURES, network_of  # noqa: E402

DESIGNS = ("cadenet-convex", "cadenet-iterative", "cadenet-peak")
TINY = {"levels": 32, "features2d": 8, "width2d": 8}
"""Test-sized designs: 32 levels, 8 feature channels, 8 aggregation channels."""


def tiny(architecture: str) -> torch.nn.Module:
    torch.manual_seed(0)
    if architecture == "cadenet-iterative with 1/2 updates":  # the optional 1/2 level, off by default
        return CadeNetIterative(TINY["levels"], features=8, width=8, steps2=1)
    if architecture == "cadenet-iterative with mask evidence":  # the mask sees the correlation at its candidates
        return network_of({"architecture": "cadenet-iterative", **TINY, "mask_evidence": True})
    if architecture == "cadenet-iterative with fine evidence":  # ... and the 1/2 features' cosine at them
        return network_of({"architecture": "cadenet-iterative", **TINY, "mask_evidence": True, "fine_evidence": True})
    return network_of({"architecture": architecture, **TINY})


def shifted_pair(rng: np.random.Generator, shape: tuple[int, int], shift: int) -> tuple[np.ndarray, np.ndarray]:
    """A seeded texture as the left view and the right view with right(x) = left(x + shift):
    constant disparity ``shift`` everywhere (left(x) = right(x - shift))."""
    height, width = shape
    texture = smooth_texture(rng, (height, width + shift), sigma=1.0)
    return texture[:, :width].copy(), texture[:, shift:shift + width].copy()


def trained_looking(net: torch.nn.Module) -> torch.nn.Module:
    """``net`` with non-trivial BatchNorm statistics and its zero-started exits (mask heads,
    updates, aggregation exits, gates) drawn at random, so that every stage counts in a comparison."""
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.normal_(0, 0.1, generator=generator)
                module.running_var.uniform_(0.5, 1.5, generator=generator)
        for parameter in net.parameters():
            if parameter.dim() > 0 and not parameter.any():
                parameter.normal_(0, 0.05, generator=generator)
    return net.eval()


@pytest.mark.parametrize("architecture", DESIGNS)
def test_each_design_is_registered_and_gives_full_resolution_maps(architecture):
    assert architecture in ARCHITECTURES
    net = tiny(architecture)
    assert net.design["architecture"] == architecture
    height, width = 3 * net.divisor * 2, 5 * net.divisor
    left, right = torch.rand(2, 2, 1, height, width)
    for training in (True, False):
        net.train(training)
        out = net(left, right)
        for key in ("disparity", "coarse", "uncertainty"):
            assert out[key].shape == (2, 1, height, width), key
            assert torch.isfinite(out[key]).all()
    assert "disparity" not in net.eval()(left, right, refine=False)


@pytest.mark.parametrize("architecture", (*DESIGNS, "cadenet-iterative with mask evidence",
                                          "cadenet-iterative with fine evidence"))
def test_a_few_steps_on_a_shifted_texture_lower_the_loss(architecture):
    rng = np.random.default_rng(3)
    pairs = [shifted_pair(rng, (32, 64), 6) for _ in range(2)]
    left = torch.from_numpy(np.stack([p[0] for p in pairs]))[:, None]
    right = torch.from_numpy(np.stack([p[1] for p in pairs]))[:, None]
    target = torch.full_like(left, 6.0)
    target[..., :8] = -1  # no match left of the shift: outside the loss's mask
    net = tiny(architecture).train()
    optimizer = torch.optim.Adam(net.parameters(), lr=2e-3)
    losses = []
    for _ in range(6):
        loss, _ = loss_terms(net(left, right), target, 32, 0.5)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert np.isfinite(losses).all() and min(losses[-3:]) < 0.8 * losses[0], losses


@pytest.mark.parametrize("architecture", (*DESIGNS, "cadenet-iterative with 1/2 updates",
                                          "cadenet-iterative with mask evidence"))
def test_the_export_agrees_with_torch_and_holds_no_grid_sample_or_data_gather(architecture, tmp_path: Path):
    net = trained_looking(tiny(architecture))
    path = tmp_path / "net.onnx"
    export_onnx(net, path, sample_size=(64, 96))
    assert verify_onnx(net, path, sizes=((48, 64), (80, 208))) < 1e-3
    graph = onnx.load(str(path)).graph
    operators = {node.op_type for node in graph.node}
    assert "GridSample" not in operators and not {"GatherElements", "GatherND"} & operators
    made_by = {output: node.op_type for node in graph.node for output in node.output}
    # a Gather may only read a shape (the exporter's size arithmetic), never a feature map
    assert all(made_by.get(node.input[0]) == "Shape" for node in graph.node if node.op_type == "Gather")


@pytest.mark.parametrize("source_design, design, key, inputs", (
    ("cadenet-iterative", "cadenet-iterative with mask evidence", "mask_evidence", 9 * 5),  # 4 groups + the distance
    ("cadenet-iterative with mask evidence", "cadenet-iterative with fine evidence", "fine_evidence", 9 * 4 * 4)))
def test_the_mask_evidence_starts_as_the_checkpoint_it_widens_and_then_counts(source_design, design, key, inputs):
    source = trained_looking(tiny(source_design))
    widened = tiny(design)
    assert widened.design[key] and key not in source.design
    widened.load_state_dict(transferable(source.state_dict(), widened))  # fit --init-partial
    widened.eval()
    left, right = torch.rand(2, 1, 1, 48, 64)
    with torch.no_grad():
        assert torch.allclose(source(left, right)["disparity"], widened(left, right)["disparity"], atol=1e-5)
        widened.mask.net[0][0].weight[:, -inputs:].normal_(0, 0.5)  # the new evidence's inputs, last in the guide
        assert not torch.allclose(source(left, right)["disparity"], widened(left, right)["disparity"])


def test_the_fine_evidence_exports_with_its_reads_as_the_only_gathers(tmp_path: Path):
    net = trained_looking(tiny("cadenet-iterative with fine evidence"))
    path = tmp_path / "net.onnx"
    export_onnx(net, path, sample_size=(64, 96))
    assert verify_onnx(net, path, sizes=((48, 64), (80, 208))) < 1e-3
    operators = [node.op_type for node in onnx.load(str(path)).graph.node]
    assert "GridSample" not in operators and "GatherND" not in operators
    assert operators.count("GatherElements") == 9 * 2  # two columns for each of the nine candidates


def test_the_fine_evidence_reads_each_half_pixel_at_each_neighbours_estimate():
    net = tiny("cadenet-iterative with fine evidence").eval()
    generator = torch.Generator().manual_seed(5)
    texture = torch.randn(1, 16, 10, 20, generator=generator)  # 1/2 features: 4 groups of 4 channels
    left, right = texture[..., :14], texture[..., 6:]  # (1, 16, 10, 14), 5 x 7 cells of 2 x 2 half pixels
    # right(x) = left(x + 6): left(x) matches right(x - 6), 6 half px, 3 px of the 1/4 level
    disparity = torch.full((1, 1, 5, 7), 3.0)
    disparity[..., 6:] = 1.25  # the last column of cells holds a wrong estimate, 2.5 half px
    evidence = net.fine_evidence_of(disparity, left, right).view(1, 9, 4, 4, 5, 7)  # candidate, group, half pixel
    # cell (2, 4): every neighbour holds the match, so every half pixel and group reads a cosine of 1
    assert torch.allclose(evidence[0, :, :, :, 2, 4], torch.ones(9, 4, 4), atol=1e-4)
    # cell (2, 5): its right neighbours (2, 5, 8) hold the wrong estimate; the others match
    assert torch.allclose(evidence[0, [0, 1, 3, 4, 6, 7], :, :, 2, 5], torch.ones(6, 4, 4), atol=1e-4)
    assert (evidence[0, [2, 5, 8], :, :, 2, 5] < 0.9).all()
    # the wrong estimate by hand: the right view's features at x - 2.5, half of columns x - 2 and x - 3
    def unit(x):
        return x / x.view(4, 4).norm(dim=1).repeat_interleave(4)

    row, column = 4, 10  # the half pixel (0, 0) of cell (2, 5)
    read = 0.5 * unit(right[0, :, row, column - 2]) + 0.5 * unit(right[0, :, row, column - 3])
    cosine = (unit(left[0, :, row, column]) * read).view(4, 4).sum(dim=1)
    assert torch.allclose(evidence[0, 5, :, 0, 2, 5], cosine, atol=1e-4)
    # where the match falls outside the right view, 0 (cell (2, 1): x - 6 < 0)
    assert (evidence[0, :, :, :, 2, 1] == 0).all()
    # a candidate that reads outside the right view reads 0
    assert (net.fine_evidence_of(torch.full((1, 1, 5, 7), 40.0), left, right) == 0).all()


def test_the_mask_evidence_is_refused_for_another_design_before_anything_is_written(tmp_path: Path):
    from cade_cli.train.config import TrainConfig

    out = tmp_path / "run"
    with pytest.raises(ValueError, match="cadenet-iterative"):
        train(TrainConfig(out=str(out), textures=[], architecture="cadenet2d", mask_evidence=True, steps=1))
    with pytest.raises(ValueError, match="cadenet-iterative"):
        train(TrainConfig(out=str(out), textures=[], architecture="cadenet-peak", fine_evidence=True, steps=1))
    assert not out.exists()


def test_the_mask_evidence_reads_the_correlation_at_each_neighbours_estimate():
    net = tiny("cadenet-iterative with mask evidence").eval()
    generator = torch.Generator().manual_seed(4)
    volume = torch.rand(1, 8 * 4, 5, 6, generator=generator)  # 8 levels at 1/4, 4 groups, disparity-major
    disparity = torch.zeros(1, 1, 5, 6)
    disparity[..., 3:] = 5.0  # two surfaces: 0 px left of column 3, 5 px from it
    evidence = net.evidence(disparity, volume)
    assert evidence.shape == (1, 9 * 5, 5, 6)
    at = volume.view(1, 8, 4, 5, 6)
    # cell (2, 2): its right neighbour (index 5) lies on the 5 px surface, itself (index 4) on 0 px
    assert torch.allclose(evidence[0, 4 * 4:5 * 4, 2, 2], at[0, 0, :, 2, 2])
    assert torch.allclose(evidence[0, 5 * 4:6 * 4, 2, 2], at[0, 5, :, 2, 2])
    assert evidence[0, 36 + 5, 2, 2] > 0 and evidence[0, 36 + 4, 2, 2] == 0


def test_the_convex_mixture_spread_is_zero_where_the_candidates_agree_and_the_split_surfaces_deviation_otherwise():
    disparity = torch.zeros(1, 1, 3, 3)
    disparity[..., 2] = 2.0  # the right column of cells lies on a surface 2 px (8 fine px) further
    mask = torch.full((1, 9 * 16, 3, 3), -30.0)
    mask.view(1, 9, 16, 3, 3)[:, 4] = 0.0  # every fine pixel takes its own cell's estimate ...
    blend, spread = convex_mixture(disparity, mask, 4)
    assert torch.equal(blend, convex_upsample(disparity, mask, 4))
    assert torch.allclose(spread, torch.zeros(1, 1, 12, 12), atol=1e-5)
    mask.view(1, 9, 16, 3, 3)[:, 5] = 0.0  # ... and its right neighbour's, half and half
    spread = convex_mixture(disparity, mask, 4)[1]
    assert torch.allclose(spread[0, 0, 4:8, 4:8], torch.full((4, 4), 4.0), atol=1e-4)  # 0 and 8 px: 4 px apart
    assert torch.allclose(spread[0, 0, 4:8, 8:12], torch.zeros(4, 4), atol=1e-4)  # its neighbour: the border again


def test_the_mask_uncertainty_keeps_the_disparity_and_raises_the_uncertainty_where_the_mask_is_torn(tmp_path: Path):
    net = trained_looking(tiny("cadenet-iterative with mask evidence"))
    left, right = torch.rand(2, 1, 1, 48, 64)
    with torch.no_grad():
        plain = net(left, right)
        torn = net.with_mask_uncertainty()(left, right)
        spread = convex_mixture(torn["quarter"], torn["mask"], 4)[1]
    assert net.design["mask_uncertainty"]
    assert torch.equal(plain["disparity"], torn["disparity"])
    assert torch.allclose(torn["uncertainty"], torch.sqrt(plain["uncertainty"] ** 2 + spread ** 2))
    assert (torn["uncertainty"] > plain["uncertainty"] + 1e-3).any()
    path = tmp_path / "net.onnx"
    export_onnx(net, path, sample_size=(64, 96))
    assert verify_onnx(net, path, sizes=((48, 64),)) < 1e-3  # both outputs
    with pytest.raises(ValueError, match="x4 mask"):
        tiny("cadenet-iterative with 1/2 updates").with_mask_uncertainty()


def test_the_convex_upsampler_keeps_a_constant_and_its_weights_sum_to_one():
    generator = torch.Generator().manual_seed(0)
    mask = torch.randn(2, 9 * 16, 5, 7, generator=generator) * 3
    weights = convex_weights(mask, 4)
    assert (weights >= 0).all() and torch.allclose(weights.sum(dim=1), torch.ones(2, 16, 5, 7), atol=1e-6)
    constant = torch.full((2, 1, 5, 7), 3.25)
    assert torch.allclose(convex_upsample(constant, mask, 4), torch.full((2, 1, 20, 28), 4 * 3.25), atol=1e-5)


def test_the_convex_upsampler_takes_the_neighbour_its_mask_picks_so_an_edge_stays_sharp():
    coarse = torch.zeros(1, 1, 4, 4)
    coarse[..., 2:] = 10.0  # a depth edge between coarse columns 1 and 2
    mask = torch.full((1, 9, 4, 4, 4), -30.0)  # (batch, neighbour, fine pixel i * 2 + j, row, column)
    mask[:, 4] = 30.0  # every fine pixel takes its own coarse pixel (the centre, row-major index 4) ...
    mask[:, 5, [1, 3]] = 60.0  # ... but the right half (j = 1) of each coarse pixel takes its right neighbour
    fine = convex_upsample(coarse, mask.view(1, 36, 4, 4), 2)[0, 0] / 2
    assert fine.shape == (8, 8)
    assert torch.allclose(fine[:, :3], torch.zeros(8, 3), atol=1e-4)  # coarse column 1's left half stays 0 ...
    assert torch.allclose(fine[:, 3:], torch.full((8, 5), 10.0), atol=1e-4)  # ... its right half takes 10: no blend


def _edge_cell(truth_value: float):
    """A 1/4 estimate with a depth edge (0 px left of coarse column 2, 2.5 px from it: 10 px at full
    resolution), a uniform mask and a constant full-resolution truth ``truth_value``."""
    quarter = torch.zeros(1, 1, 3, 4)
    quarter[..., 2:] = 2.5
    return quarter, torch.zeros(1, 9 * 16, 3, 4, requires_grad=True), torch.full((1, 1, 12, 16), truth_value)


def test_the_pick_loss_is_the_truths_likelihood_under_the_masks_mixture():
    quarter, mask, target = _edge_cell(10.0)
    target[..., 0, 0] = float("inf")  # no ground truth here: left out, and no NaN in the gradient
    loss = pick_loss(quarter, mask, target, levels=32)
    # by hand, for the fine pixel (row 0, column 5) of coarse cell (0, 1): its nine neighbours are
    # coarse columns 0, 1, 2 of rows -1, 0, 1 (replicated at the border) at 0, 0, 10 px
    options = np.array([0, 0, 10] * 3, float)
    by_hand = -np.log(np.mean(np.exp(-np.abs(options - 10.0))))
    per_pixel = -torch.logsumexp(torch.log(torch.full((9,), 1 / 9)) - (torch.tensor(options) - 10).abs(), 0)
    assert abs(per_pixel.item() - by_hand) < 1e-6
    assert torch.isfinite(loss)
    loss.backward()
    assert torch.isfinite(mask.grad).all()
    # coarse cell (0, 1)'s fine pixels: the gradient raises the right neighbours' weights (at 10 px, the truth)
    # and lowers the others'
    grad = mask.grad.view(1, 9, 16, 3, 4)[0, :, :, 0, 1]
    assert (grad[[2, 5, 8]] < 0).all() and (grad[[0, 1, 3, 4, 6, 7]] > 0).all()


def test_the_pick_loss_moves_a_confidently_wrong_mask_where_the_blends_l1_loss_hardly_does():
    quarter, _, target = _edge_cell(10.0)
    # coarse cell column 1 (at 0 px, truth 10 px) picks its left neighbour with confidence: the wrong surface
    logits = torch.full((1, 9, 16, 3, 4), -4.0)
    logits[:, 3] = 4.0
    logits = logits.view(1, 144, 3, 4).requires_grad_()
    blend_l1 = torch.nn.functional.smooth_l1_loss(convex_upsample(quarter, logits, 4), target)
    l1_grad = torch.autograd.grad(blend_l1, logits)[0].view(1, 9, 16, 3, 4)[0, [2, 5, 8], :, 0, 1]
    pick_grad = torch.autograd.grad(pick_loss(quarter, logits, target, 32), logits)[0].view(1, 9, 16, 3, 4)
    pick_grad = pick_grad[0, [2, 5, 8], :, 0, 1]
    # both raise the right neighbours' logits (at 10 px, the truth): a negative gradient ...
    assert (l1_grad < 0).all() and (pick_grad < 0).all()
    # ... but the blend's saturated softmax passes the L1 loss's push on at the weight the right candidates
    # have (about e^-8 each), and the pick loss at their share of the truth's likelihood (about a third each)
    assert pick_grad.abs().min() > 50 * l1_grad.abs().max()  # about 100 times here


def test_the_pick_loss_trains_the_iterative_design_and_is_refused_for_another_before_anything_is_written(
        tmp_path: Path):
    small = dict(textures=[], steps=2, batch=1, height=64, width=128, levels=32, workers=0, validate_every=10,
                 features2d=8, width2d=8)
    with_pick = train(TrainConfig(out=str(tmp_path / "pick"), architecture="cadenet-iterative", mask_pick=0.5,
                                  **small))
    state = torch.load(with_pick, map_location="cpu", weights_only=False)
    assert state["step"] == 2 and state["config"]["mask_pick"] == 0.5
    out = tmp_path / "run"
    with pytest.raises(ValueError, match="cadenet-iterative"):
        train(TrainConfig(out=str(out), textures=[], architecture="cadenet2d", mask_pick=1.0, steps=1))
    assert not out.exists()


def test_the_hat_lookup_equals_a_correlation_with_the_right_view_shifted_bilinearly():
    generator = torch.Generator().manual_seed(2)
    left, right = torch.randn(2, 1, 8, 6, 40, generator=generator)
    levels, groups = 12, 2
    volume = normalised_correlation(left, right, levels, groups)
    disparity = torch.rand(1, 1, 6, 40, generator=generator) * 8 + 1  # 1 .. 9 px
    got = hat_lookup(volume, disparity, (-1, 0, 1), groups).view(1, 3, groups, 6, 40)

    def unit(x):
        grouped = x.view(1, groups, 4, 6, 40)
        return grouped / (grouped.pow(2).sum(dim=2, keepdim=True) + 1e-6).sqrt()

    unit_left, unit_right = unit(left), unit(right)
    columns = torch.arange(40).view(1, 1, 40)
    for index, offset in enumerate((-1, 0, 1)):
        position = columns - (disparity[:, 0] + offset)  # read right at x - d - k, linearly between columns
        low = position.floor()
        fraction = position - low
        expected = 0
        for column, weight in ((low, 1 - fraction), (low + 1, fraction)):
            inside = (column >= 0) & (column <= columns) & (columns - column < levels)
            at = column.clamp(0, 39).long().view(1, 1, 1, 6, 40).expand(1, groups, 4, 6, 40)
            read = torch.gather(unit_right, 4, at)  # the slow, obvious reference: a gather
            expected = expected + (weight * inside).unsqueeze(1) * (unit_left * read).sum(dim=2)
        assert torch.allclose(got[:, index], expected, atol=1e-5)


def test_the_lookups_and_the_upsampler_keep_float32_under_bf16_autocast():
    generator = torch.Generator().manual_seed(5)
    volume = torch.rand(1, 96 * 2, 4, 6, generator=generator).bfloat16()  # as a bf16 forward pass makes them
    disparity = (70 + torch.rand(1, 1, 4, 6, generator=generator)).bfloat16()  # where bf16's step is 0.5 px
    mask = torch.randn(1, 9 * 4, 4, 6, generator=generator).bfloat16()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        low = (hat_lookup(volume, disparity, (-1, 0, 1), 2), convex_upsample(disparity, mask, 2))
    exact = (hat_lookup(volume.float(), disparity.float(), (-1, 0, 1), 2),
             convex_upsample(disparity.float(), mask.float(), 2))
    for got, expected in zip(low, exact):
        assert got.dtype == torch.float32 and torch.allclose(got, expected, atol=1e-5)


def test_the_peak_expectation_picks_the_stronger_of_two_peaks_where_the_soft_argmin_averages():
    logits = torch.full((1, 24, 1, 1), -20.0)
    logits[0, 4], logits[0, 18], logits[0, 19] = 5.0, 5.5, 5.0  # background near 4, foreground near 18.5
    mean, _ = expectation(logits)
    peak = peak_expectation(logits, radius=2)
    assert 8 < float(mean) < 16  # the soft-argmin: between the surfaces, on neither
    assert abs(float(peak) - 18.38) < 0.05  # the foreground peak's own sub-pixel mean


@pytest.mark.usefixtures("small_validation")
@pytest.mark.parametrize("architecture", DESIGNS)
def test_a_trained_exported_design_runs_in_the_shipped_cli(architecture, tmp_path: Path, capsys):
    config = TrainConfig(out=str(tmp_path / "run"), textures=[], steps=2, batch=1, height=48, width=64, levels=32,
                         workers=0, validate_every=100, architecture=architecture, width2d=8, features2d=8)
    card = export_checkpoint(train(config), tmp_path / "tiny.onnx", tmp_path / "tiny.json")
    assert card["design"]["architecture"] == architecture and card["divisor"] == network_of(
        {"architecture": architecture, **TINY}).divisor
    assert card["architecture"].startswith("CadeNet-") and card["onnx_vs_torch_max_abs_diff"] < 1e-3
    rng = np.random.default_rng(4)
    left, right = shifted_pair(rng, (50, 90), 5)  # not multiples of the divisor: padded, cropped
    left_file, right_file = write_png16(tmp_path / "l.png", left), write_png16(tmp_path / "r.png", right)
    code, _, stderr = run_cade(["disparity", left_file, right_file, "-o", tmp_path / "d.pfm", "--max-disp", 20,
                                "--model", tmp_path / "tiny.json"], capsys)
    assert code == 0, stderr
    disparity = read_disparity(tmp_path / "d.pfm")
    assert disparity.shape == (50, 90) and np.isfinite(disparity).any()
