"""CadeNet-Peak (``cadenet-peak``): the Accuracy V bake-off's own design, aimed at depth edges.

Where a 1/4 pixel straddles a depth edge, CadeNet2D's distribution over disparities has two
peaks (foreground and background); its soft-argmin returns their weighted mean, a disparity
that belongs to neither surface, and the bilinear upsampling then spreads that value over
4 px on each side of the edge. Both are gross errors at exactly the pixels where census+SGM
(a winner-takes-all matcher: it picks one peak) beats the network. This design keeps the
control's features, volume and U-Net (so the bake-off isolates the change) and changes what
comes after:

  regress    the peak's expectation: the softmax renormalised over a window of +-``radius``
             1/4-level disparities around the arg-max (ACVNet's / CFNet's unimodal
             regression): one surface's disparity, sub-pixel; the full distribution's mean is
             still the ``coarse`` output (supervised: it shapes the whole distribution) and its
             spread the uncertainty;
  upsample   learned convex upsampling x4 (:func:`~cade_cli.train.net_blocks.convex_upsample`),
             the mask from the reference view (as ``cadenet-convex``): a full-resolution pixel
             takes the value of the neighbours on its side of the image's edge, and a convex
             combination of one surface's values stays on that surface;
  refine     a full-resolution edge-aware residual (:class:`~cade_cli.train.net2d.FullRefinement`
             on the left band and the estimate, dilated 2D CNN), for the last pixel of an edge.

No grid sample and no gather; ArgMax is the only non-convolution, non-element-wise operator
beside slices and DepthToSpace. Inputs (B, 1, H, W), H and W multiples of :data:`DIVISOR`.
"""

from __future__ import annotations

import torch
from torch import nn

from cade_cli.train.model import soft_argmin
from cade_cli.train.net2d import PRIOR_GAIN, Features2D, FullRefinement, UNet2D, normalised_correlation
from cade_cli.train.net_blocks import ConvexMask, both_views, convex_upsample, softmax_channels, upsampling_guide

DIVISOR = 16
"""Input height and width must be multiples of this (the U-Net's 1/16 level)."""


def peak_expectation(logits: torch.Tensor, radius: int = 2) -> torch.Tensor:
    """Logits (B, D, h, w) -> (B, 1, h, w): the mean of the softmax restricted to the disparities
    within ``radius`` of the arg-max and renormalised there (px of the level). For a
    distribution with two separate peaks it returns the stronger peak's position, where the
    soft-argmin returns a value between them. The gradient reaches the window's logits."""
    probability = softmax_channels(logits)
    levels = torch.arange(logits.shape[1], dtype=probability.dtype, device=probability.device).view(1, -1, 1, 1)
    peak = logits.argmax(dim=1, keepdim=True).to(probability.dtype)
    window = probability * ((levels - peak).abs() <= radius).to(probability.dtype)
    return (window * levels).sum(dim=1, keepdim=True) / window.sum(dim=1, keepdim=True).clamp_min(1e-12)


class CadeNetPeak(nn.Module):
    """Stereo network on color-agnostic bands: the control's volume and U-Net, the peak's
    expectation, convex upsampling and a full-resolution refinement (module docstring).

    Args:
        levels: searched width in full-resolution px (a multiple of 16): disparities 0 .. levels - 1.
        features, groups, width: as :class:`~cade_cli.train.net2d.CadeNet2D`'s.
        radius: the peak window's half width, 1/4-level disparities.
        refine_channels: the full-resolution refinement's channels (0: none).
    """

    divisor = DIVISOR

    def __init__(self, levels: int = 192, features: int = 16, groups: int = 4, width: int = 32, radius: int = 2,
                 mask_channels: int = 32, refine_channels: int = 8, blocks: int = 2):
        super().__init__()
        if levels % DIVISOR:
            raise ValueError(f"levels must be a multiple of {DIVISOR}, got {levels}")
        self.levels, self.groups, self.coarse_levels, self.radius = levels, groups, levels // 4, radius
        self.design = {"architecture": "cadenet-peak", "features": features, "groups": groups, "width": width,
                       "radius": radius, "mask_channels": mask_channels, "refine_channels": refine_channels,
                       "blocks": blocks}
        self.features = Features2D(features, blocks)
        self.prior_gain = nn.Parameter(torch.tensor(PRIOR_GAIN))
        self.aggregation = UNet2D(groups * self.coarse_levels + features, self.coarse_levels, width)
        self.mask = ConvexMask(features + self.coarse_levels + 4 * 16 + 16, 4, mask_channels)
        self.refinement = FullRefinement(refine_channels) if refine_channels else None

    def describe(self, output: str) -> str:
        """The model card's one-line ``architecture``."""
        design = self.design
        return (f"CadeNet-Peak: 2D features (1/2, 1/4 res) -> normalised group-wise correlation ({design['groups']} "
                f"groups) -> 2D U-Net ({design['width']} channels at 1/4) -> "
                + (f"peak-window expectation (+-{design['radius']}) -> learned convex upsampling x4"
                   + (" -> full-res refinement" if design["refine_channels"] else "") if output == "disparity"
                   else "soft-argmin -> bilinear x4 (coarse output)"))

    def forward(self, left: torch.Tensor, right: torch.Tensor, refine: bool = True) -> dict[str, torch.Tensor]:
        """left, right: (B, 1, H, W) -> ``coarse`` (soft-argmin, bilinearly upsampled),
        ``uncertainty`` (px), with ``refine`` ``half`` (the peak's expectation, convex-upsampled)
        and ``disparity`` (after the full-resolution refinement); all (B, 1, H, W), full-resolution
        px; and the left view's 1/4 ``features``."""
        (half_left, _), (feat_left, feat_right) = both_views(self.features, left, right, self.training)
        cost = normalised_correlation(feat_left, feat_right, self.coarse_levels, self.groups)
        batch, _, height, width = cost.shape
        prior = cost.view(batch, self.coarse_levels, self.groups, height, width).mean(dim=2)
        logits = self.prior_gain * prior + self.aggregation(torch.cat([cost, feat_left], dim=1))
        _, coarse, uncertainty = soft_argmin(logits, left.shape[-2:])
        out = {"coarse": coarse, "uncertainty": uncertainty, "features": feat_left}
        if refine:
            # the mask sees the logits too: how many surfaces a pixel's neighbourhood holds
            mask = self.mask(upsampling_guide((feat_left, logits), half_left, left))
            out["half"] = convex_upsample(peak_expectation(logits, self.radius), mask, 4)
            out["disparity"] = out["half"] if self.refinement is None else self.refinement(out["half"], left)
        return out
