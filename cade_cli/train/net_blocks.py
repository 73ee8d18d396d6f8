"""Building blocks shared by the Accuracy V bake-off's designs (``cadenet-convex``,
``cadenet-iterative``, ``cadenet-peak``): every one exports to ONNX operators that onnxruntime
runs well on the CPU (convolutions, slices, element-wise arithmetic, DepthToSpace: no GridSample,
no Gather).

Shapes are (B, C, h, w); a disparity map is (B, 1, h, w) in px of the level it belongs to.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cade_cli.train.model import conv2d


def softmax_channels(logits: torch.Tensor, dim: int = 1) -> torch.Tensor:
    """Softmax over ``dim``, spelt out in the ONNX export (onnxruntime's Softmax over a middle axis
    transposes twice; as in :func:`~cade_cli.train.model.soft_argmin`)."""
    if torch.onnx.is_in_onnx_export():
        exponential = torch.exp(logits - logits.amax(dim=dim, keepdim=True))
        return exponential / exponential.sum(dim=dim, keepdim=True)
    return torch.softmax(logits, dim=dim)


def expectation(logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Logits (B, D, h, w) over the level's disparities 0 .. D - 1 -> the distribution's mean and
    standard deviation, (B, 1, h, w) each, in px of the level."""
    probability = softmax_channels(logits)
    levels = torch.arange(logits.shape[1], dtype=probability.dtype, device=probability.device).view(1, -1, 1, 1)
    mean = (probability * levels).sum(dim=1, keepdim=True)
    variance = (probability * (levels - mean) ** 2).sum(dim=1, keepdim=True)
    return mean, variance.clamp_min(0).sqrt()


def upsampled(disparity: torch.Tensor, factor: int, size=None) -> torch.Tensor:
    """A disparity map of one level bilinearly upsampled by ``factor`` (or to ``size``), in px of
    the finer level (values times ``factor``)."""
    size = size if size is not None else (disparity.shape[-2] * factor, disparity.shape[-1] * factor)
    return factor * F.interpolate(disparity, size=size, mode="bilinear", align_corners=False)


def neighbours3x3(x: torch.Tensor) -> torch.Tensor:
    """(B, 1, h, w) -> (B, 9, h, w): each pixel's 3x3 neighbourhood, row-major (the border
    replicated), as nine slices of the padded map (no Unfold: it exports as an Im2Col-like gather)."""
    height, width = x.shape[-2:]
    padded = F.pad(x, (1, 1, 1, 1), mode="replicate")
    return torch.cat([padded[..., row:row + height, column:column + width] for row in range(3) for column in range(3)],
                     dim=1)


def convex_weights(mask_logits: torch.Tensor, factor: int) -> torch.Tensor:
    """Mask logits (B, 9 * factor², h, w) -> weights (B, 9, factor², h, w), non-negative and
    summing to 1 over the nine neighbours (axis 1) for each of the factor² fine pixels."""
    batch, _, height, width = mask_logits.shape
    return softmax_channels(mask_logits.view(batch, 9, factor * factor, height, width), dim=1)


def _mixture(disparity: torch.Tensor, mask_logits: torch.Tensor, factor: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The convex upsampler's weights (B, 9, factor², h, w) and its nine candidates (B, 9, 1, h, w), px of
    the finer level, in float32 whatever the autocast (as hat_lookup)."""
    return convex_weights(mask_logits.float(), factor), factor * neighbours3x3(disparity.float()).unsqueeze(2)


def convex_upsample(disparity: torch.Tensor, mask_logits: torch.Tensor, factor: int) -> torch.Tensor:
    """RAFT's learned convex upsampling: ``disparity`` (B, 1, h, w; px of its level) ->
    (B, 1, h * factor, w * factor), px of the finer level (values times ``factor``). Each fine pixel
    is a convex combination of its coarse pixel's 3x3 neighbours, weighted by the softmax of
    ``mask_logits`` (B, 9 * factor², h, w), which the network predicts from the reference image:
    an edge stays where the image puts it instead of being smeared over a coarse pixel. Written
    with slices, a sum and a DepthToSpace (pixel shuffle), which export well."""
    weights, candidates = _mixture(disparity, mask_logits, factor)
    return F.pixel_shuffle((weights * candidates).sum(dim=1), factor)


def convex_mixture(disparity: torch.Tensor, mask_logits: torch.Tensor, factor: int
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`convex_upsample`'s map and, (B, 1, h * factor, w * factor), the standard deviation (px of the
    finer level) of the nine candidates it blends at each fine pixel under its weights: 0 where the
    candidates agree or one weighs all, large where the mask is torn between two surfaces."""
    weights, candidates = _mixture(disparity, mask_logits, factor)
    mean = (weights * candidates).sum(dim=1, keepdim=True)  # (B, 1, factor², h, w)
    variance = (weights * (candidates - mean) ** 2).sum(dim=1)
    return F.pixel_shuffle(mean[:, 0], factor), torch.sqrt(F.pixel_shuffle(variance, factor) + 1e-12)


def upsampling_guide(maps, half: torch.Tensor, band: torch.Tensor) -> torch.Tensor:
    """A convex x4 mask's guidance at 1/4: ``maps`` (the left view's 1/4 features, a decoder's
    state: (B, C, h, w) each), and the left view's 1/2 features (B, 16, 2h, 2w) and full-resolution
    band (B, 1, 4h, 4w) rearranged to 1/4 (space-to-depth: 64 and 16 channels a pixel), so the
    mask sees where inside a 1/4 pixel the image's edge runs."""
    return torch.cat([*maps, F.pixel_unshuffle(half, 2), F.pixel_unshuffle(band, 4)], dim=1)


class ConvexMask(nn.Module):
    """The convex upsampler's mask logits (B, 9 * factor², h, w) from guidance features at the
    coarse level. Its exit starts at zero: equal weights, a 3x3 box filter of the coarse map."""

    def __init__(self, inputs: int, factor: int, channels: int = 32):
        super().__init__()
        self.factor = factor
        self.net = nn.Sequential(conv2d(inputs, channels), nn.Conv2d(channels, 9 * factor * factor, 1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, guide: torch.Tensor) -> torch.Tensor:
        return self.net(guide)


class InvertedResidual(nn.Module):
    """MobileNetV2's block on ``channels``: 1x1 expansion (x ``expansion``), 3x3 depthwise
    convolution (``dilation``), 1x1 projection, and the skip."""

    def __init__(self, channels: int, expansion: int = 4, dilation: int = 1):
        super().__init__()
        hidden = channels * expansion
        self.body = nn.Sequential(
            nn.Conv2d(channels, hidden, 1, bias=False), nn.BatchNorm2d(hidden), nn.LeakyReLU(0.1, inplace=True),
            nn.Conv2d(hidden, hidden, 3, padding=dilation, dilation=dilation, groups=hidden, bias=False),
            nn.BatchNorm2d(hidden), nn.LeakyReLU(0.1, inplace=True),
            nn.Conv2d(hidden, channels, 1, bias=False), nn.BatchNorm2d(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class GuidedExcitation(nn.Module):
    """CoEx's guided cost excitation: the aggregation's channels scaled per pixel by a gate in
    (0, 2) that the reference image's features predict (1 at the start: the gate's layer starts
    at zero). Per pixel, not a global pooling: a strip of the image gives the values it gives
    in the whole image (the runtime runs strips)."""

    def __init__(self, channels: int, guide: int):
        super().__init__()
        self.gate = nn.Conv2d(guide, channels, 1)
        nn.init.zeros_(self.gate.weight)
        nn.init.zeros_(self.gate.bias)

    def forward(self, x: torch.Tensor, guide: torch.Tensor) -> torch.Tensor:
        return x * (2.0 * torch.sigmoid(self.gate(guide)))


def both_views(features: nn.Module, left: torch.Tensor, right: torch.Tensor, training: bool):
    """``features`` of both views: one batch in training (BatchNorm's statistics over both), apart
    in eval (the same values, without copying the views together); a tuple of (left, right) per output."""
    if training:
        return tuple(out.chunk(2, dim=0) for out in features(torch.cat([left, right], dim=0)))
    return tuple(zip(features(left), features(right)))


def hat_lookup(volume: torch.Tensor, disparity: torch.Tensor, offsets, groups: int) -> torch.Tensor:
    """Correlations read at fractional disparities, without Gather or GridSample.

    ``volume`` (B, levels * groups, h, w), disparity-major (as
    :func:`~cade_cli.train.net2d.normalised_correlation` lays it out: the cosine of left(x) and
    right(x - s) for integer s = 0 .. levels - 1); ``disparity`` (B, 1, h, w), px of the level.
    For each offset k, the correlation at ``disparity + k``: a sum over the integer shifts weighted
    by the linear-interpolation (hat) weights max(0, 1 - |s - d - k|). As the correlation is linear
    in the right features, this equals correlating with the right features bilinearly shifted by
    d + k (0 outside the searched range). Returns (B, len(offsets) * groups, h, w), offset-major.
    Computed in float32 whatever the autocast (the GPU recipe's bf16 keeps 8 significant bits: a
    disparity of 64 .. 128 px in steps of 0.5 px, and a sum over ~100 shifts off by about 1 %)."""
    volume, disparity = volume.float(), disparity.float()
    batch, _, height, width = volume.shape
    levels = volume.shape[1] // groups
    reach = max(abs(offset) for offset in offsets)
    # group-major, so each read is a product of two (B, levels, h, w) maps (onnxruntime broadcasts
    # a middle axis slowly), and the hat weights computed once over levels + 2 * reach shifts: the
    # weights at offset k are those at 0 moved by k shifts (a slice), exact at the range's ends too
    grouped = volume.view(batch, levels, groups, height, width).transpose(1, 2).reshape(batch, groups * levels,
                                                                                      height, width)
    shifts = torch.arange(-reach, levels + reach, dtype=volume.dtype, device=volume.device).view(1, -1, 1, 1)
    hat = F.relu(1.0 - (shifts - disparity).abs())  # (B, levels + 2 reach, h, w): the weight of shift t at d
    reads = []
    for offset in offsets:
        weight = hat[:, reach - offset:reach - offset + levels]  # weight of shift s at d + k = hat at s - k
        reads.extend((grouped[:, group * levels:(group + 1) * levels] * weight).sum(dim=1, keepdim=True)
                     for group in range(groups))  # slices, not an integer index (a Gather in ONNX)
    return torch.cat(reads, dim=1)
