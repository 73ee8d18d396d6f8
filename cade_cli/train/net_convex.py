"""CadeNet-Convex (``cadenet-convex``): the Accuracy V bake-off's stronger-aggregation design.

  features   CadeNet2D's 2D CNN (:class:`~cade_cli.train.net2d.Features2D`): CADE band -> 16
             channels at 1/2, ``features`` at 1/4;
  cost       CadeNet2D's normalised group-wise correlation at 1/4 (cosines, disparities as
             channels) and its correlation prior (the mean cosine times a learned gain);
  aggregate  a 2D encoder-decoder over 1/4, 1/8 and 1/16 of MobileNetV2 inverted-residual blocks
             (LightStereo's aggregation: the volume's disparities are channels), each level's
             channels gated per pixel by the reference view's features (CoEx's guided
             excitation) -> one logit per 1/4-level disparity;
  regress    soft-argmin at 1/4 (and its spread: the uncertainty);
  upsample   RAFT's learned convex upsampling x4: each full-resolution pixel a convex combination
             of its 1/4 pixel's 3x3 neighbours, weighted by a mask predicted from the reference
             view (its 1/4 features, the decoder's state, its 1/2 features and band rearranged to
             1/4): a depth edge lands where the image puts it, not smeared over 4 px.

No grid sample and no gather: it exports to convolutions, slices, element-wise arithmetic and
DepthToSpace. Inputs (B, 1, H, W), H and W multiples of :data:`DIVISOR`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cade_cli.train.model import conv2d, soft_argmin
from cade_cli.train.net2d import PRIOR_GAIN, Features2D, normalised_correlation
from cade_cli.train.net_blocks import (ConvexMask, GuidedExcitation, InvertedResidual, both_views, convex_upsample,
                                       upsampling_guide)

DIVISOR = 16
"""Input height and width must be multiples of this (the aggregation's 1/16 level)."""


class GuidedStage(nn.Module):
    """One level of the aggregation: guided excitation, then ``blocks`` inverted residuals."""

    def __init__(self, channels: int, guide: int, blocks: int, dilations=(1, 2)):
        super().__init__()
        self.excitation = GuidedExcitation(channels, guide)
        self.blocks = nn.Sequential(*[InvertedResidual(channels, 4, dilations[i % len(dilations)])
                                      for i in range(blocks)])

    def forward(self, x: torch.Tensor, guide: torch.Tensor) -> torch.Tensor:
        return self.blocks(self.excitation(x, guide))


class InvertedAggregation(nn.Module):
    """Cost volume and left features at 1/4 -> logits (B, levels, h, w) and the decoder's state
    (B, width, h, w): an encoder-decoder of guided inverted-residual stages at 1/4 (``width``),
    1/8 (4/3 width) and 1/16 (2x width)."""

    def __init__(self, inputs: int, levels: int, guide: int, width: int = 48):
        super().__init__()
        mid, low = width * 4 // 3, width * 2
        self.entry = nn.Sequential(nn.Conv2d(inputs, width, 1, bias=False), nn.BatchNorm2d(width),
                                   nn.LeakyReLU(0.1, inplace=True))
        self.enc0 = GuidedStage(width, guide, 2)
        self.down1 = conv2d(width, mid, stride=2)
        self.enc1 = GuidedStage(mid, guide, 3)
        self.down2 = conv2d(mid, low, stride=2)
        self.enc2 = GuidedStage(low, guide, 4, dilations=(1, 2, 4, 1))
        self.up2 = nn.Sequential(nn.ConvTranspose2d(low, mid, 2, stride=2, bias=False), nn.BatchNorm2d(mid))
        self.dec1 = GuidedStage(mid, guide, 2)
        self.up1 = nn.Sequential(nn.ConvTranspose2d(mid, width, 2, stride=2, bias=False), nn.BatchNorm2d(width))
        self.dec0 = GuidedStage(width, guide, 2)
        self.exit = nn.Conv2d(width, levels, 3, padding=1)
        nn.init.zeros_(self.exit.weight)  # start as the correlation prior alone
        nn.init.zeros_(self.exit.bias)

    def forward(self, x: torch.Tensor, guide: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        guide1 = F.avg_pool2d(guide, 2)
        guide2 = F.avg_pool2d(guide1, 2)
        x0 = self.enc0(self.entry(x), guide)
        x1 = self.enc1(self.down1(x0), guide1)
        x1 = self.dec1(F.leaky_relu(x1 + self.up2(self.enc2(self.down2(x1), guide2)), 0.1), guide1)
        state = self.dec0(F.leaky_relu(x0 + self.up1(x1), 0.1), guide)
        return self.exit(state), state


class CadeNetConvex(nn.Module):
    """Stereo network on color-agnostic bands: inverted-residual aggregation, convex upsampling
    (module docstring).

    Args:
        levels: searched width in full-resolution px (a multiple of 16): disparities 0 .. levels - 1.
        features, groups: the 1/4 features' channels and the correlation's groups.
        width: the aggregation's channels at 1/4.
        mask_channels: the convex mask head's hidden channels.
    """

    divisor = DIVISOR

    def __init__(self, levels: int = 192, features: int = 24, groups: int = 4, width: int = 48,
                 mask_channels: int = 32, blocks: int = 2):
        super().__init__()
        if levels % DIVISOR:
            raise ValueError(f"levels must be a multiple of {DIVISOR}, got {levels}")
        if features % groups:
            raise ValueError(f"features ({features}) must be a multiple of groups ({groups})")
        self.levels, self.groups, self.coarse_levels = levels, groups, levels // 4
        self.design = {"architecture": "cadenet-convex", "features": features, "groups": groups, "width": width,
                       "mask_channels": mask_channels, "blocks": blocks}
        self.features = Features2D(features, blocks)
        self.prior_gain = nn.Parameter(torch.tensor(PRIOR_GAIN))
        self.aggregation = InvertedAggregation(groups * self.coarse_levels + features, self.coarse_levels, features,
                                               width)
        self.mask = ConvexMask(features + width + 4 * 16 + 16, 4, mask_channels)

    def describe(self, output: str) -> str:
        """The model card's one-line ``architecture``."""
        design = self.design
        return (f"CadeNet-Convex: 2D features (1/2, 1/4 res) -> normalised group-wise correlation ({design['groups']} "
                f"groups) -> guided inverted-residual encoder-decoder ({design['width']} channels at 1/4) -> "
                "soft-argmin at 1/4 -> " + ("learned convex upsampling x4" if output == "disparity" else
                                            "bilinear x4 (coarse output: convex upsampling not exported)"))

    def forward(self, left: torch.Tensor, right: torch.Tensor, refine: bool = True) -> dict[str, torch.Tensor]:
        """left, right: (B, 1, H, W) -> ``coarse`` (soft-argmin, bilinearly upsampled),
        ``uncertainty`` (px) and, with ``refine``, ``disparity`` (convex upsampling); all
        (B, 1, H, W), full-resolution px; and the left view's 1/4 ``features``."""
        (half_left, _), (feat_left, feat_right) = both_views(self.features, left, right, self.training)
        cost = normalised_correlation(feat_left, feat_right, self.coarse_levels, self.groups)
        batch, _, height, width = cost.shape
        prior = cost.view(batch, self.coarse_levels, self.groups, height, width).mean(dim=2)
        residual, state = self.aggregation(torch.cat([cost, feat_left], dim=1), feat_left)
        mean, coarse, uncertainty = soft_argmin(self.prior_gain * prior + residual, left.shape[-2:])
        out = {"coarse": coarse, "uncertainty": uncertainty, "features": feat_left}
        if refine:
            mask = self.mask(upsampling_guide((feat_left, state), half_left, left))
            out["disparity"] = convex_upsample(mean, mask, 4)
        return out
