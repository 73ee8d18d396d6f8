"""The CADE stereo network: small enough to train and run on a CPU.

Design (justified in docs/research/network-design.md):
  features   2D CNN, CADE band -> 32 channels at 1/4 resolution;
  cost       group-wise correlation (8 groups) over levels/4 disparities of the 1/4 level;
  aggregate  3D CNN with one stride-2 hourglass, 8-16 channels;
  regress    soft-argmin over the levels (x4 to full-resolution pixels), plus the
             standard deviation of that distribution as an uncertainty;
  half       optional second scale (``second_scale``): a local cost volume at 1/2
             resolution, +-8 px around the 1/4 level's estimate, decided by a small 2D CNN
             (:class:`SecondScale`; the Accuracy II lever for thin structures);
  refine     full-resolution 2D residual refinement guided by the left band
             (dilated convolutions, 16 channels), for edges and sub-pixel detail.
             An export can leave it out (:class:`ExportWrapper`, ``output="coarse"``):
             faster, less accurate on unseen data (docs/research/network-design.md, 2026-11-22).

Inputs are color-agnostic bands (cade_cli.spectral.color_agnostic), (B, 1, H, W) with H
and W multiples of :data:`DIVISOR`. Everything exports to ONNX with standard ops.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cade_cli.train.census import CENSUS_GAIN, census_cost

DIVISOR = 8
"""Input height and width must be multiples of this (1/4 features, one more stride-2 3D level)."""
DISPARITY_SCALE = 128.0
"""Disparity is divided by this before it enters the refinement net, whatever the searched range."""


def conv2d(cin: int, cout: int, *, stride: int = 1, dilation: int = 1, act: bool = True,
           padding: str = "zeros") -> nn.Sequential:
    layers: list[nn.Module] = [
        nn.Conv2d(cin, cout, 3, stride, padding=dilation, dilation=dilation, bias=not act, padding_mode=padding)
    ]
    if act:
        layers += [nn.BatchNorm2d(cout), nn.LeakyReLU(0.1, inplace=True)]
    return nn.Sequential(*layers)


def conv3d(cin: int, cout: int, *, stride: int = 1, act: bool = True, kernel: int = 3,
           separable: bool = False) -> nn.Sequential:
    """A 3D convolution over (disparity, y, x), then batch norm and LeakyReLU (``act``).

    ``separable`` (a ``kernel`` of 3 only): a 2D 1x3x3 convolution over each disparity
    slice (shared weights), then a 3x1x1 one along disparity; stride applies to both
    parts' own axes. 12 taps per channel pair instead of 27."""
    if separable and kernel == 3:
        layers: list[nn.Module] = [
            nn.Conv3d(cin, cout, (1, 3, 3), (1, stride, stride), padding=(0, 1, 1), bias=False),
            nn.Conv3d(cout, cout, (3, 1, 1), (stride, 1, 1), padding=(1, 0, 0), bias=not act),
        ]
    else:
        layers = [nn.Conv3d(cin, cout, kernel, stride, padding=kernel // 2, bias=not act)]
    if act:
        layers += [nn.BatchNorm3d(cout), nn.LeakyReLU(0.1, inplace=True)]
    return nn.Sequential(*layers)


class ResidualBlock(nn.Module):
    def __init__(self, channels: int, dilation: int = 1, padding: str = "zeros"):
        super().__init__()
        self.body = nn.Sequential(conv2d(channels, channels, dilation=dilation, padding=padding),
                                  nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation,
                                            bias=False, padding_mode=padding),
                                  nn.BatchNorm2d(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.leaky_relu(x + self.body(x), 0.1)


class FeatureNet(nn.Module):
    """(B, 1, H, W) -> (B, C, H/4, W/4)."""

    def __init__(self, channels: int = 32, padding: str = "zeros"):
        super().__init__()
        self.net = nn.Sequential(
            conv2d(1, 16, stride=2, padding=padding), conv2d(16, 16, padding=padding),
            conv2d(16, channels, stride=2, padding=padding), ResidualBlock(channels, padding=padding),
            ResidualBlock(channels, 2, padding=padding), ResidualBlock(channels, padding=padding),
            nn.Conv2d(channels, channels, 3, padding=1, padding_mode=padding),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)

    def both_scales(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 1, H, W) -> the 1/2-level features (B, 16, H/2, W/2) on the way, and the output."""
        half = self.net[:2](x)
        return half, self.net[2:](half)


def groupwise_correlation(left: torch.Tensor, right: torch.Tensor, levels: int, groups: int) -> torch.Tensor:
    """Cost volume (B, G, D, h, w): mean product of each channel group of left(x) and right(x - d).

    Where x - d falls outside the right view the correlation is 0."""
    batch, channels, height, width = left.shape
    padded = F.pad(right, (levels - 1, 0))  # once, not per level: a single Pad in the ONNX graph
    slices = [(left * padded[..., levels - 1 - d:levels - 1 - d + width])
              .view(batch, groups, channels // groups, height, width).mean(dim=2) for d in range(levels)]
    return torch.stack(slices, dim=2)


AGGREGATIONS = ("3d", "separable")
"""How :class:`Aggregation` convolves the cost volume: full 3x3x3 kernels (cade-v1 … v6),
or each split into a 2D spatial kernel per disparity slice and a 1D kernel along
disparity (the 2D-aggregation lever of Accuracy II; still range-independent weights)."""


class Aggregation(nn.Module):
    """3D CNN over the cost volume, one hourglass level, -> logits (B, D, h, w)."""

    def __init__(self, groups: int = 8, channels: int = 8, entry_kernel: int = 1, extra_inputs: int = 0,
                 kind: str = "3d"):
        super().__init__()
        if kind not in AGGREGATIONS:
            raise ValueError(f"aggregation must be one of {', '.join(AGGREGATIONS)}, got {kind!r}")
        sep = kind == "separable"
        self.entry = nn.Sequential(conv3d(groups + extra_inputs, channels, kernel=entry_kernel, separable=sep),
                                   conv3d(channels, channels, separable=sep))
        self.down = nn.Sequential(conv3d(channels, 2 * channels, stride=2, separable=sep),
                                  conv3d(2 * channels, 2 * channels, separable=sep))
        self.up = nn.Sequential(nn.ConvTranspose3d(2 * channels, channels, 2, stride=2, bias=False),
                                nn.BatchNorm3d(channels))
        self.exit = nn.Sequential(conv3d(channels, channels, separable=sep), conv3d(channels, 1, act=False, separable=sep))

    def forward(self, cost: torch.Tensor) -> torch.Tensor:
        x = self.entry(cost)
        x = F.leaky_relu(x + self.up(self.down(x)), 0.1)
        return self.exit(x).squeeze(1)


HALF_OFFSETS = 4
"""The second scale searches +-this many 1/2-level px (+-8 full-resolution px, in 2 px
steps; its soft-argmin gives the sub-pixel value) around the 1/4 level's estimate."""


def shifted_right(features: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
    """``features`` (B, C, h, w) of the right view read at x - ``disparity`` (B, 1, h, w,
    px of this level), bilinearly; zeros outside the view. One GridSample in training; in an
    ONNX export two gathers along the row (:func:`row_gathered`: 4x faster in onnxruntime)."""
    if torch.onnx.is_in_onnx_export():
        return row_gathered(features, disparity)
    batch, _, height, width = features.shape
    xs = torch.arange(width, dtype=features.dtype, device=features.device).view(1, 1, width)
    ys = torch.arange(height, dtype=features.dtype, device=features.device).view(1, height, 1)
    x = (xs - disparity[:, 0]) * (2.0 / (width - 1)) - 1.0
    y = (ys * (2.0 / (height - 1)) - 1.0).expand_as(x)
    return F.grid_sample(features, torch.stack([x, y], dim=-1), mode="bilinear", padding_mode="zeros",
                         align_corners=True)


def row_gathered(features: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
    """:func:`shifted_right` as two reads along each row and a linear blend (the warp moves
    along rows only); equal to GridSample's bilinear read within float rounding (3.7e-5 on
    features in [0, 1]), 1.6 ms against 6.4 for 8 channels at 360x248 on 2 threads."""
    batch, channels, height, width = features.shape
    x = torch.arange(width, dtype=features.dtype, device=features.device).view(1, 1, 1, width) - disparity
    floor = torch.floor(x)
    fraction = x - floor

    def read(column: torch.Tensor) -> torch.Tensor:
        inside = ((column >= 0) & (column <= width - 1)).to(features.dtype)
        index = column.clamp(0, width - 1).long().expand(batch, channels, height, width)
        return torch.gather(features, 3, index) * inside

    return read(floor) * (1 - fraction) + read(floor + 1) * fraction


def local_correlation(left: torch.Tensor, right: torch.Tensor, start: torch.Tensor, groups: int) -> torch.Tensor:
    """(B, groups * (2 * :data:`HALF_OFFSETS` + 1), h, w): the group-wise correlation of
    ``left`` (B, C, h, w) with ``right`` read at x - (``start`` + o), for each offset o in
    -HALF_OFFSETS .. HALF_OFFSETS (offset-major: the channels of offset o come together)."""
    batch, channels, height, width = left.shape
    return torch.cat([(left * shifted_right(right, start + offset))
                      .view(batch, groups, channels // groups, height, width).mean(dim=2)
                      for offset in range(-HALF_OFFSETS, HALF_OFFSETS + 1)], dim=1)


class SecondScale(nn.Module):
    """The 1/2-resolution stage: correlates the left view's 1/2-level features with the right
    view's, shifted by the 1/4 level's estimate plus each of 2 * :data:`HALF_OFFSETS` + 1
    offsets (4 channel groups each), and a 2D CNN that also sees the left features and the
    estimate turns that local volume into a soft-argmin residual. Its cost grows with the
    image, not with the searched range."""

    def __init__(self, features: int = 16, groups: int = 4, channels: int = 32):
        super().__init__()
        self.groups = groups
        self.head = nn.Sequential(conv2d(features, features), nn.Conv2d(features, features, 3, padding=1))
        offsets = 2 * HALF_OFFSETS + 1
        self.net = nn.Sequential(conv2d(groups * offsets + features + 1, channels), conv2d(channels, channels, dilation=2),
                                 conv2d(channels, channels), nn.Conv2d(channels, offsets, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)  # start as the 1/4 level's estimate (a uniform distribution)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, half_left: torch.Tensor, half_right: torch.Tensor, coarse: torch.Tensor) -> torch.Tensor:
        """(B, 16, H/2, W/2) features of both views and the full-resolution 1/4-level estimate
        (B, 1, H, W) -> the full-resolution estimate of this stage (B, 1, H, W)."""
        feat_left, feat_right = self.head(torch.cat([half_left, half_right], dim=0)).chunk(2, dim=0)
        start = 0.5 * F.interpolate(coarse, size=feat_left.shape[-2:], mode="bilinear", align_corners=False)
        volume = local_correlation(feat_left, feat_right, start, self.groups)
        logits = self.net(torch.cat([volume, feat_left, start / (0.5 * DISPARITY_SCALE)], dim=1))
        offsets = torch.arange(-HALF_OFFSETS, HALF_OFFSETS + 1, dtype=logits.dtype, device=logits.device)
        residual = (torch.softmax(logits, dim=1) * offsets.view(1, -1, 1, 1)).sum(dim=1, keepdim=True)
        return 2.0 * F.interpolate(start + residual, size=coarse.shape[-2:], mode="bilinear", align_corners=False)


def soft_argmin(logits: torch.Tensor, size) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Logits (B, D, h, w) over the 1/4 level's disparities 0 .. D - 1 -> the distribution's
    mean (B, 1, h, w; 1/4-level px), and its mean and standard deviation upsampled to
    ``size`` in full-resolution px (x4): the ``coarse`` estimate and the ``uncertainty``."""
    if torch.onnx.is_in_onnx_export():  # onnxruntime's Softmax over axis 1 transposes twice; spelt out, it does not
        exponential = torch.exp(logits - logits.amax(dim=1, keepdim=True))
        probability = exponential / exponential.sum(dim=1, keepdim=True)
    else:
        probability = torch.softmax(logits, dim=1)
    levels = torch.arange(logits.shape[1], dtype=probability.dtype, device=probability.device).view(1, -1, 1, 1)
    mean = (probability * levels).sum(dim=1, keepdim=True)
    variance = (probability * (levels - mean) ** 2).sum(dim=1, keepdim=True)
    coarse = 4.0 * F.interpolate(mean, size=size, mode="bilinear", align_corners=False)
    uncertainty = 4.0 * F.interpolate(variance.clamp_min(0).sqrt(), size=size, mode="bilinear", align_corners=False)
    return mean, coarse, uncertainty


class Refinement(nn.Module):
    """Full-resolution residual on the upsampled disparity, guided by the left band."""

    def __init__(self, channels: int = 16, padding: str = "zeros"):
        super().__init__()
        self.net = nn.Sequential(
            conv2d(2, channels, padding=padding), conv2d(channels, channels, dilation=2, padding=padding),
            conv2d(channels, channels, dilation=4, padding=padding), conv2d(channels, channels, padding=padding),
            nn.Conv2d(channels, 1, 3, padding=1, padding_mode=padding),
        )
        nn.init.zeros_(self.net[-1].weight)  # start as the identity: refine what the cost volume found
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, disparity: torch.Tensor, left: torch.Tensor, scale: float) -> torch.Tensor:
        """Training disparities stay below ``scale``, so the guide ``disparity / scale`` lies in
        [0, 1]. A map reaching beyond ``scale`` (a range variant wider than the trained one)
        is first lowered by its excess over ``scale``: the residual then sees relative depth
        in the range it was trained on, instead of adding a bias that grows with disparity
        (docs/research/network-design.md)."""
        excess = (disparity.amax(dim=(2, 3), keepdim=True) - scale).clamp_min(0.0)
        return disparity + self.net(torch.cat([(disparity - excess) / scale, left], dim=1))


class CadeNet(nn.Module):
    """Stereo network on color-agnostic bands.

    No weight depends on the searched range (the 3D convolutions slide along disparity),
    so one trained state dict can be loaded into nets of several widths.

    Args:
        levels: width of the searched range in full-resolution px (a multiple of 8): the
            cost volume holds ``levels // 4`` disparities of the 1/4 level, i.e. 0 ..
            ``levels - 4`` px in steps of 4; the soft-argmin and the refinement reach
            ``levels - 1`` at most (the model card's ``levels``).
        padding: the 2D convolutions' padding mode. ``"zeros"`` (cade-v4 on) lets
            onnxruntime fuse the padding into each convolution and keep its blocked
            layout; ``"replicate"`` (cade-v1 … v3) costs a Pad node and layout
            reorders around each convolution (docs/research/network-design.md).
        entry_kernel: kernel size of the first 3D convolution, which mixes the
            correlation groups: 1 (cade-v4 on) or 3 (cade-v1 … v3; a quarter of the 3D
            multiply-adds).
        census: feed the aggregation a census cost volume of the input bands
            (:func:`~cade_cli.train.census.census_cost`) beside the learned correlation: a cost that no
            monotonic change of intensity alters, so identical on rendered and real data
            (the Accuracy II lever; docs/research/network-design.md says what it measured).
        aggregation: ``"3d"`` (every shipped model) or ``"separable"``
            (:data:`AGGREGATIONS`; the 2D-aggregation lever).
        second_scale: a 1/2-resolution stage (:class:`SecondScale`) between the 1/4
            level's soft-argmin and the refinement (the second-scale lever).
    """

    def __init__(self, levels: int = 128, features: int = 32, groups: int = 8, channels3d: int = 8,
                 refine_channels: int = 16, padding: str = "zeros", entry_kernel: int = 1, census: bool = False,
                 aggregation: str = "3d", second_scale: bool = False):
        super().__init__()
        if levels % DIVISOR:
            raise ValueError(f"levels must be a multiple of {DIVISOR}, got {levels}")
        self.levels, self.groups = levels, groups
        self.coarse_levels = levels // 4
        self.design = {"padding": padding, "entry_kernel": entry_kernel, "channels3d": channels3d, "census": census,
                       "aggregation": aggregation, "second_scale": second_scale}
        self.census = census
        self.features = FeatureNet(features, padding)
        self.aggregation = Aggregation(groups, channels3d, entry_kernel, extra_inputs=int(census), kind=aggregation)
        self.second_scale = SecondScale() if second_scale else None
        self.refinement = Refinement(refine_channels, padding)

    def forward(self, left: torch.Tensor, right: torch.Tensor, refine: bool = True) -> dict[str, torch.Tensor]:
        """left, right: (B, 1, H, W) -> dict with ``disparity`` (B, 1, H, W) refined (only
        when ``refine``), ``coarse`` (B, 1, H, W) soft-argmin upsampled, ``uncertainty``
        (B, 1, H, W) px; with a second scale also ``half`` (B, 1, H, W), its estimate, which
        the refinement then starts from."""
        half, both = self.features.both_scales(torch.cat([left, right], dim=0))
        feat_left, feat_right = both.chunk(2, dim=0)
        cost = groupwise_correlation(feat_left, feat_right, self.coarse_levels, self.groups)
        if self.census:
            cost = torch.cat([cost, CENSUS_GAIN * census_cost(left, right, self.coarse_levels)], dim=1)
        _, coarse, uncertainty = soft_argmin(self.aggregation(cost), left.shape[-2:])
        out = {"coarse": coarse, "uncertainty": uncertainty}
        if self.second_scale is not None:
            out["half"] = self.second_scale(*half.chunk(2, dim=0), coarse)
        if refine:
            out["disparity"] = self.refinement(out.get("half", coarse), left, DISPARITY_SCALE)
        return out


EXPORT_OUTPUTS = ("coarse", "disparity")
"""What an export's ``disparity`` output is: the soft-argmin map upsampled to full
resolution (``coarse``: the refinement net is left out of the graph), or the refinement
net's output (``disparity``)."""


class ExportWrapper(nn.Module):
    """``forward(left, right) -> (disparity, uncertainty)`` for ONNX: fixed eval settings.

    ``output`` picks which of the net's maps becomes ``disparity`` (:data:`EXPORT_OUTPUTS`);
    with ``"coarse"`` the refinement net is not traced, so it costs nothing at run time."""

    def __init__(self, net: CadeNet, output: str = "disparity"):
        super().__init__()
        if output not in EXPORT_OUTPUTS:
            raise ValueError(f"output must be one of {', '.join(EXPORT_OUTPUTS)}, got {output!r}")
        self.net, self.output = net.eval(), output

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(left, right, refine=self.output == "disparity")
        return out[self.output], out["uncertainty"]


LEGACY_DESIGN = {"padding": "replicate", "entry_kernel": 3, "channels3d": 8, "census": False, "aggregation": "3d",
                 "second_scale": False}
"""The design of checkpoints whose config predates the ``padding``/``entry_kernel`` keys (cade-v1 … v3)."""


def design_of(config: dict) -> dict:
    """CadeNet keyword arguments recorded in a training config (old configs: :data:`LEGACY_DESIGN`)."""
    return {key: config.get(key, default) for key, default in LEGACY_DESIGN.items()}


def adapt_state_dict(state: dict[str, torch.Tensor], net: nn.Module) -> dict[str, torch.Tensor]:
    """``state`` made loadable into ``net`` when only kernel sizes differ: a 3x3x3 kernel
    becomes the 1x1x1 kernel that gives the same response on a locally constant input
    (the sum of its taps). Used to start cade-v4 from cade-v3's weights."""
    target = net.state_dict()
    adapted = {}
    for key, value in state.items():
        shape = target[key].shape if key in target else value.shape  # unknown keys: load_state_dict names them
        if value.shape != shape and value.dim() == 5 and shape[2:] == (1, 1, 1) and value.shape[:2] == shape[:2]:
            value = value.sum(dim=(2, 3, 4), keepdim=True)
        adapted[key] = value
    return adapted


def transferable(state: dict[str, torch.Tensor], net: nn.Module) -> dict[str, torch.Tensor]:
    """The tensors of ``state`` that fit ``net`` (same name, same shape): a wider net starts
    from a narrower one's 2D features and refinement, its 3D part fresh. A kernel that only
    gained inputs (a census cost beside the correlation) keeps its weights, with zeros for
    the new inputs: the net starts out computing exactly what the checkpoint did."""
    target = net.state_dict()
    fitting = {}
    for key, value in state.items():
        if key not in target:
            continue
        shape = target[key].shape
        if shape == value.shape:
            fitting[key] = value
        elif (value.dim() >= 2 and len(shape) == value.dim() and shape[0] == value.shape[0]
              and shape[2:] == value.shape[2:] and shape[1] > value.shape[1]):
            widened = torch.zeros(shape, dtype=value.dtype)
            widened[:, :value.shape[1]] = value
            fitting[key] = widened
    return fitting


def parameter_count(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())
