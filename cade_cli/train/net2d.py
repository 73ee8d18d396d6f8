"""CadeNet2D: the CPU-native network generation (Accuracy III).

Every stage is a 2D convolution, which onnxruntime runs about 2.3x faster per
multiply-add than a 3x3x3 Conv3D on this project's CPUs, and which int8 quantisation
can speed up further (docs/research/network-design.md, 2026-11-25):

  features   2D CNN, CADE band -> 16 channels at 1/2 and ``features`` at 1/4 resolution;
  cost       normalised group-wise correlation at 1/4 (each group of channels scaled to
             unit length first, so the volume holds cosines: GraftNet's domain-robust
             volume), ``groups`` x levels/4 channels;
  aggregate  a 2D U-Net over 1/4, 1/8 and 1/16 (the volume's disparities are channels, as
             in LightStereo and MobileStereoNet-2D), guided by the left features, ->
             one logit per 1/4-level disparity, added to a correlation prior (the mean
             cosine, times a learned gain: :data:`PRIOR_GAIN`);
  regress    soft-argmin, and the spread of that distribution as the uncertainty;
  refine     image-guided residual refinement at 1/2 (the right view's 1/2 features
             warped by the estimate, one bilinear read; StereoNet/HITNet) and at full
             resolution (the left band), each a small dilated 2D CNN.

The weights depend on the searched width (``levels``: the volume's disparities are
channels): one network searches 0 .. levels - 1 px, and wider spans run on a
downscaled pair (the runtime's pyramid). Inputs: (B, 1, H, W) bands with H and W
multiples of :data:`DIVISOR2D`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cade_cli.train.model import DISPARITY_SCALE, conv2d, shifted_right, soft_argmin

DIVISOR2D = 16
"""Input height and width must be multiples of this (the U-Net's 1/16 level)."""
PRIOR_GAIN = 8.0
"""Initial weight of the correlation prior in the logits (learned): the volume's mean cosine
over groups, in [-1, 1], times this. The U-Net's output is added to it and starts at zero,
so an untrained network is already a soft winner-takes-all matcher of its features, and the
U-Net learns the aggregation as a residual: the 2D net has no built-in sliding along
disparity, and without this prior it spent its first 700 steps predicting about the
range's middle (train EPE 33 px at step 500; docs/research/network-design.md, 2026-11-25)."""


class Residual2D(nn.Module):
    """Two 3x3 convolutions with a skip: x + f(x), then LeakyReLU."""

    def __init__(self, channels: int, dilation: int = 1):
        super().__init__()
        self.body = nn.Sequential(conv2d(channels, channels, dilation=dilation),
                                  nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation, bias=False),
                                  nn.BatchNorm2d(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.leaky_relu(x + self.body(x), 0.1)


class Features2D(nn.Module):
    """(B, 1, H, W) -> (B, 16, H/2, W/2) and (B, C, H/4, W/4)."""

    def __init__(self, channels: int = 32, blocks: int = 2):
        super().__init__()
        self.to_half = nn.Sequential(conv2d(1, 16, stride=2), conv2d(16, 16))
        self.quarter = nn.Sequential(conv2d(16, channels, stride=2),
                                     *[Residual2D(channels, 1 + i % 2) for i in range(blocks)],
                                     nn.Conv2d(channels, channels, 3, padding=1))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        half = self.to_half(x)
        return half, self.quarter(half)


def unit_groups(x: torch.Tensor, groups: int) -> torch.Tensor:
    """(B, C, h, w) with each group of C / ``groups`` channels scaled to unit length at each pixel."""
    batch, channels, height, width = x.shape
    grouped = x.view(batch, groups, channels // groups, height, width)
    return (grouped / (grouped.pow(2).sum(dim=2, keepdim=True) + 1e-6).sqrt()).view(batch, channels, height, width)


def normalised_correlation(left: torch.Tensor, right: torch.Tensor, levels: int, groups: int) -> torch.Tensor:
    """(B, groups * levels, h, w), disparity-major: the cosine of each channel group of
    left(x) and right(x - d), d = 0 .. levels - 1 (0 where x - d is outside the right view)."""
    batch, channels, height, width = left.shape
    left, right = unit_groups(left, groups), unit_groups(right, groups)
    padded = F.pad(right, (levels - 1, 0))
    slices = [(left * padded[..., levels - 1 - d:levels - 1 - d + width])
              .view(batch, groups, channels // groups, height, width).sum(dim=2) for d in range(levels)]
    return torch.cat(slices, dim=1)


class SliceAggregation(nn.Module):
    """Spatial aggregation of the correlation volume, one small 2D CNN shared by every
    disparity (the volume's slices run as a batch: a 1x3x3 Conv3D's weight sharing at 2D
    cost): (B, levels * groups, h, w) -> one score per disparity, (B, levels, h, w), added
    to the logits. The U-Net sees disparities as channels and must learn each one's
    aggregation apart; this stage learns one window filter for all of them (SGBM's block
    aggregation, learned). Its exit starts at zero: an untrained stage changes nothing."""

    def __init__(self, groups: int, channels: int = 4):
        super().__init__()
        self.groups = groups
        self.net = nn.Sequential(conv2d(groups, channels), conv2d(channels, channels, dilation=2),
                                 nn.Conv2d(channels, 1, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, cost: torch.Tensor, levels: int) -> torch.Tensor:
        if torch.onnx.is_in_onnx_export():
            return self.grouped(cost, levels)
        batch, _, height, width = cost.shape
        slices = cost.reshape(batch * levels, self.groups, height, width)  # disparity-major: one slice per row
        return self.net(slices).reshape(batch, levels, height, width)

    def grouped(self, cost: torch.Tensor, levels: int) -> torch.Tensor:
        """:meth:`forward` in eval, as the ONNX export spells it: each layer one grouped
        convolution over the disparity-major volume (``levels`` groups, the shared kernel
        repeated, BatchNorm folded in) instead of a batch of ``levels`` 4-channel slices;
        the same values within float rounding, half the time in onnxruntime (10.5 against
        20.2 ms for 32 levels at 180x124, 2 threads)."""
        x = cost
        for layer in self.net:
            conv, norm = (layer[0], layer[1]) if isinstance(layer, nn.Sequential) else (layer, None)
            weight = conv.weight.detach()
            bias = conv.bias.detach() if conv.bias is not None else torch.zeros(weight.shape[0])
            if norm is not None:
                scale = (norm.weight / torch.sqrt(norm.running_var + norm.eps)).detach()
                weight, bias = weight * scale.view(-1, 1, 1, 1), (norm.bias - norm.running_mean * scale).detach() + bias * scale
            x = F.conv2d(x, weight.repeat(levels, 1, 1, 1), bias.repeat(levels), padding=conv.padding,
                         dilation=conv.dilation, groups=levels)
            if norm is not None:
                x = F.leaky_relu(x, 0.1)
        return x


class UNet2D(nn.Module):
    """Cost volume and left features at 1/4 -> logits (B, levels, h, w): a 2D U-Net with
    levels at 1/4 (``width``), 1/8 (4/3 width) and 1/16 (2x width)."""

    def __init__(self, inputs: int, levels: int, width: int = 48):
        super().__init__()
        mid, low = width * 4 // 3, width * 2
        self.entry = nn.Sequential(nn.Conv2d(inputs, width, 1, bias=False), nn.BatchNorm2d(width),
                                   nn.LeakyReLU(0.1, inplace=True), Residual2D(width))
        self.down1 = nn.Sequential(conv2d(width, mid, stride=2), Residual2D(mid))
        self.down2 = nn.Sequential(conv2d(mid, low, stride=2), Residual2D(low), Residual2D(low, 2))
        self.up2 = nn.Sequential(nn.ConvTranspose2d(low, mid, 2, stride=2, bias=False), nn.BatchNorm2d(mid))
        self.dec1 = Residual2D(mid)
        self.up1 = nn.Sequential(nn.ConvTranspose2d(mid, width, 2, stride=2, bias=False), nn.BatchNorm2d(width))
        self.dec0 = Residual2D(width)
        self.exit = nn.Conv2d(width, levels, 3, padding=1)
        nn.init.zeros_(self.exit.weight)  # start as the correlation prior alone (CadeNet2D.forward)
        nn.init.zeros_(self.exit.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x0 = self.entry(x)
        x1 = self.down1(x0)
        x1 = self.dec1(F.leaky_relu(x1 + self.up2(self.down2(x1)), 0.1))
        return self.exit(self.dec0(F.leaky_relu(x0 + self.up1(x1), 0.1)))


class HalfRefinement(nn.Module):
    """The 1/2-level residual: the left 1/2 features, the difference of ``compared``
    channels projected from both views' 1/2 features, the right ones read at the estimate
    (one bilinear warp, on few channels: GridSample is slow on CPU), and the estimate ->
    a residual in 1/2-level px."""

    def __init__(self, features: int = 16, channels: int = 16, compared: int = 8):
        super().__init__()
        self.compare = nn.Conv2d(features, compared, 1)
        self.net = nn.Sequential(conv2d(features + compared + 1, channels), conv2d(channels, channels, dilation=2),
                                 conv2d(channels, channels, dilation=4), conv2d(channels, channels),
                                 nn.Conv2d(channels, 1, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)  # start as the 1/4 level's estimate
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
        compared_left, compared_right = self.compare(left), self.compare(right)
        difference = compared_left - shifted_right(compared_right, disparity)
        guide = torch.cat([left, difference, disparity / (0.5 * DISPARITY_SCALE)], dim=1)
        return disparity + self.net(guide)


class FullRefinement(nn.Module):
    """Full-resolution residual on the upsampled disparity, guided by the left band."""

    def __init__(self, channels: int = 12):
        super().__init__()
        self.net = nn.Sequential(conv2d(2, channels), conv2d(channels, channels, dilation=2),
                                 conv2d(channels, channels, dilation=4), conv2d(channels, channels),
                                 nn.Conv2d(channels, 1, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, disparity: torch.Tensor, left: torch.Tensor) -> torch.Tensor:
        return disparity + self.net(torch.cat([disparity / DISPARITY_SCALE, left], dim=1))


class CadeNet2D(nn.Module):
    """Stereo network on color-agnostic bands, all-2D (module docstring).

    Args:
        levels: searched width in full-resolution px (a multiple of 16): disparities
            0 .. levels - 1; the volume holds levels/4 disparities of the 1/4 level.
        features, groups: the 1/4 features' channels and the correlation's groups.
        width: the U-Net's channels at 1/4.
        half_channels, refine_channels: the 1/2 and full-resolution refinements' channels
            (``refine_channels`` 0: no full-resolution stage, the 1/2 estimate upsampled).
        slice_channels: channels of the per-disparity aggregation (:class:`SliceAggregation`;
            0: none, the design before it).
    """

    divisor = DIVISOR2D

    def __init__(self, levels: int = 192, features: int = 32, groups: int = 4, width: int = 48,
                 half_channels: int = 16, refine_channels: int = 0, blocks: int = 2, slice_channels: int = 0):
        super().__init__()
        if levels % DIVISOR2D:
            raise ValueError(f"levels must be a multiple of {DIVISOR2D}, got {levels}")
        self.levels, self.groups, self.coarse_levels = levels, groups, levels // 4
        self.design = {"architecture": "cadenet2d", "features": features, "groups": groups, "width": width,
                       "half_channels": half_channels, "refine_channels": refine_channels, "blocks": blocks,
                       "slice_channels": slice_channels}
        self.features = Features2D(features, blocks)
        self.aggregation = UNet2D(groups * self.coarse_levels + features, self.coarse_levels, width)
        self.prior_gain = nn.Parameter(torch.tensor(PRIOR_GAIN))
        self.slices = SliceAggregation(groups, slice_channels) if slice_channels else None
        self.half_refinement = HalfRefinement(16, half_channels)
        self.refinement = FullRefinement(refine_channels) if refine_channels else None

    def forward(self, left: torch.Tensor, right: torch.Tensor, refine: bool = True) -> dict[str, torch.Tensor]:
        """left, right: (B, 1, H, W) -> ``coarse`` (soft-argmin, upsampled), ``uncertainty``
        (px), ``half`` (after the 1/2-level refinement, upsampled) and, with ``refine``,
        ``disparity`` (after the full-resolution one); all (B, 1, H, W), full-resolution px;
        and the left view's 1/4 ``features`` (B, C, H/4, W/4), for the consistency loss."""
        if self.training:  # one batch: BatchNorm's statistics over both views
            half, quarter = self.features(torch.cat([left, right], dim=0))
            (half_left, half_right), (feat_left, feat_right) = half.chunk(2, dim=0), quarter.chunk(2, dim=0)
        else:  # the same values (BatchNorm's running statistics), without copying the views apart
            (half_left, feat_left), (half_right, feat_right) = self.features(left), self.features(right)
        cost = normalised_correlation(feat_left, feat_right, self.coarse_levels, self.groups)
        size = left.shape[-2:]
        batch, _, height, width = cost.shape
        prior = cost.view(batch, self.coarse_levels, self.groups, height, width).mean(dim=2)
        logits = self.prior_gain * prior + self.aggregation(torch.cat([cost, feat_left], dim=1))
        if self.slices is not None:
            logits = logits + self.slices(cost, self.coarse_levels)
        mean, coarse, uncertainty = soft_argmin(logits, size)
        start = 2.0 * F.interpolate(mean, size=half_left.shape[-2:], mode="bilinear", align_corners=False)
        half_estimate = 2.0 * F.interpolate(self.half_refinement(half_left, half_right, start), size=size,
                                            mode="bilinear", align_corners=False)
        out = {"coarse": coarse, "uncertainty": uncertainty, "half": half_estimate, "features": feat_left}
        if refine:
            out["disparity"] = half_estimate if self.refinement is None else self.refinement(half_estimate, left)
        return out


def fewer_levels(state: dict[str, torch.Tensor], net: CadeNet2D) -> bool:
    """Whether ``state`` is a CadeNet2D's with fewer levels than ``net`` (its aggregation scores
    fewer disparities)."""
    bias = state.get("aggregation.exit.bias")
    return bias is not None and bias.shape[0] < net.coarse_levels


def with_more_levels(state: dict[str, torch.Tensor], net: CadeNet2D) -> dict[str, torch.Tensor]:
    """The weights of a CadeNet2D trained with fewer levels (``state``), laid out for ``net``
    (more levels, otherwise the same design): the aggregation's entry keeps its weights for
    the old disparities' correlation channels and for the features, which now come after more
    disparities, and gets zeros for the new disparities; its exit keeps its rows for the old
    disparities and gets zeros (its initial value) for the new ones. So ``net`` scores the old
    disparities exactly as the checkpoint did and the new ones by the correlation prior and the
    per-disparity stage alone, until training teaches it more. Every other tensor is copied.

    Raises:
        ValueError: ``state`` is not a narrower-range twin of ``net``.
    """
    target = net.state_dict()
    entry, exit_weight, exit_bias = "aggregation.entry.0.weight", "aggregation.exit.weight", "aggregation.exit.bias"
    features = net.design["features"]
    old_levels, new_levels = state[exit_bias].shape[0], net.coarse_levels
    others = [key for key in target if key not in (entry, exit_weight, exit_bias)]
    if old_levels >= new_levels or any(key not in state or state[key].shape != target[key].shape for key in others):
        raise ValueError("the checkpoint is not the same design with fewer levels")
    old_cost, new_cost = net.groups * old_levels, net.groups * new_levels
    widened = torch.zeros_like(target[entry])
    widened[:, :old_cost] = state[entry][:, :old_cost]  # disparity-major: the old disparities come first
    widened[:, new_cost:new_cost + features] = state[entry][:, old_cost:old_cost + features]
    rows, bias = torch.zeros_like(target[exit_weight]), torch.zeros_like(target[exit_bias])
    rows[:old_levels], bias[:old_levels] = state[exit_weight], state[exit_bias]
    return {**{key: state[key] for key in others}, entry: widened, exit_weight: rows, exit_bias: bias}

