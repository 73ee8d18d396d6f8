"""CadeNet-Iterative (``cadenet-iterative``): the Accuracy V bake-off's coarse-to-fine
local re-matching design (HITNet's and RAFT-Stereo's idea, light enough for the CPU).

  features   CadeNet2D's 2D CNN at 1/2 (16 channels) and 1/4 (``features``), and one more
             stride-2 stage at 1/8 (``features``);
  initialise a small normalised correlation volume at 1/8 (levels/8 disparities as channels,
             the correlation prior plus a residual 2D aggregation) -> soft-argmin at 1/8;
  re-match   at 1/4 (``steps4`` updates) and, with ``steps2``, at 1/2: the estimate upsampled x2, then
             each update reads the level's normalised correlation at the current estimate
             plus k for k in -``radius`` .. ``radius`` (:func:`~cade_cli.train.net_blocks.hat_lookup`:
             the 1-D correlation with the right features shifted by the estimate, written as
             integer-shift slices weighted by linear-interpolation weights, no GridSample, no
             Gather) and a small residual 2D CNN on those local costs, the left features and the
             estimate predicts a correction (its exit starts at zero);
  upsample   learned convex upsampling from the last level to full resolution (x4 from 1/4, the
             mask from the left view's 1/4 and 1/2 features and band; x2 from 1/2 with ``steps2``).
             With ``mask_evidence`` the x4 mask also sees, for each of the nine 1/4 estimates it
             combines, the 1/4 correlation at that estimate in the pixel's own cell and how far it lies
             from the cell's estimate: the matching evidence to pick one surface at a depth edge, which
             the left view alone cannot give (docs/research/refinement.md, 2026-12-07). Its weights
             start at zero, so a checkpoint without it loads (``--init-partial``) and computes the same.
             With ``fine_evidence`` it also sees that evidence inside the cell: for each candidate and
             each of the cell's four 1/2 pixels, the cosine of the left view's 1/2 features and the
             right view's read at the candidate (:meth:`CadeNetIterative.fine_evidence`; new inputs
             at zero too). An edge runs through a cell; the 1/4 correlation is one value for all its
             sixteen pixels, this says which side of it matches which surface. Its reads are
             GatherElements (two columns a candidate, linear weights): slices would need the whole
             1/2 volume, which cost more than the rest of the network (below).

The 1/2 level is off by default (``steps2`` 0): its volume of levels/2 disparities at 1/2 cost
more than the rest of the network (untrained ONNX at 720x496, 2 threads, CPU shared with
training: 5.2 s with one 1/2 update of +-1 px against 2.1 s without and 1.5 s for the control;
``benchmarks/design_speed.py``). Without a gather, a per-pixel shift reads every integer shift.

Supervised: ``coarse`` (the 1/8 estimate), ``half`` (after the 1/4 updates) and ``disparity``.
Inputs (B, 1, H, W), H and W multiples of :data:`DIVISOR`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cade_cli.train.model import DISPARITY_SCALE, conv2d
from cade_cli.train.net2d import PRIOR_GAIN, Features2D, Residual2D, normalised_correlation, unit_groups
from cade_cli.train.net_blocks import (ConvexMask, both_views, convex_mixture, convex_upsample, expectation,
                                       hat_lookup, neighbours3x3, upsampled, upsampling_guide)

DIVISOR = 8
"""Input height and width must be multiples of this (the 1/8 level)."""


class PyramidFeatures(nn.Module):
    """(B, 1, H, W) -> 16 channels at 1/2, ``channels`` at 1/4 and at 1/8."""

    def __init__(self, channels: int, blocks: int = 2):
        super().__init__()
        self.lower = Features2D(channels, blocks)
        self.eighth = nn.Sequential(conv2d(channels, channels, stride=2), Residual2D(channels),
                                    nn.Conv2d(channels, channels, 3, padding=1))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        half, quarter = self.lower(x)
        return half, quarter, self.eighth(quarter)


class LocalUpdate(nn.Module):
    """One level's update: local costs (``costs`` channels), the left features (``features``) and
    the estimate -> a correction in px of the level (the exit starts at zero)."""

    def __init__(self, costs: int, features: int, channels: int):
        super().__init__()
        self.net = nn.Sequential(conv2d(costs + features + 1, channels), Residual2D(channels),
                                 Residual2D(channels, 2), nn.Conv2d(channels, 1, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, costs: torch.Tensor, features: torch.Tensor, disparity: torch.Tensor, scale: float):
        return self.net(torch.cat([costs, features, disparity / scale], dim=1))


class CadeNetIterative(nn.Module):
    """Stereo network on color-agnostic bands: a 1/8 initial estimate re-matched locally at 1/4
    and 1/2, convex upsampling to full resolution (module docstring).

    Args:
        levels: searched width in full-resolution px (a multiple of 16): disparities 0 .. levels - 1.
        features, groups: the 1/4 and 1/8 features' channels and the correlation's groups.
        width: the 1/8 aggregation's channels; the 1/4 update has ``width``, the 1/2 one half of it.
        radius: local costs at the estimate plus -radius .. radius px of the level.
        steps4, steps2: updates at 1/4 and at 1/2 (each level's updates share their weights).
    """

    divisor = DIVISOR

    def __init__(self, levels: int = 192, features: int = 24, groups: int = 4, width: int = 32, radius: int = 2,
                 steps4: int = 2, steps2: int = 0, blocks: int = 2, mask_evidence: bool = False,
                 fine_evidence: bool = False):
        super().__init__()
        if levels % 16:
            raise ValueError(f"levels must be a multiple of 16, got {levels}")
        if features % groups or 16 % groups:
            raise ValueError(f"features ({features}) and 16 must be multiples of groups ({groups})")
        self.levels, self.groups, self.offsets = levels, groups, tuple(range(-radius, radius + 1))
        if (mask_evidence or fine_evidence) and steps2:
            raise ValueError("the mask's evidence is for the x4 mask from 1/4 (steps2 0)")
        self.steps4, self.steps2, self.mask_evidence, self.fine_evidence = steps4, steps2, mask_evidence, fine_evidence
        self.design = {"architecture": "cadenet-iterative", "features": features, "groups": groups, "width": width,
                       "radius": radius, "steps4": steps4, "steps2": steps2, "blocks": blocks}
        if mask_evidence:  # the key only where it is on: earlier cards and configs stay as they were
            self.design["mask_evidence"] = True
        if fine_evidence:
            self.design["fine_evidence"] = True
        self.mask_uncertainty = False  # an export option: with_mask_uncertainty
        self.features = PyramidFeatures(features, blocks)
        self.prior_gain = nn.Parameter(torch.tensor(PRIOR_GAIN))
        eighth = levels // 8
        self.initial = nn.Sequential(nn.Conv2d(groups * eighth + features, width, 1, bias=False),
                                     nn.BatchNorm2d(width), nn.LeakyReLU(0.1, inplace=True),
                                     Residual2D(width), Residual2D(width, 2), Residual2D(width, 4),
                                     nn.Conv2d(width, eighth, 3, padding=1))
        nn.init.zeros_(self.initial[-1].weight)  # start as the correlation prior alone
        nn.init.zeros_(self.initial[-1].bias)
        local = len(self.offsets) * groups
        self.update4 = LocalUpdate(local, features, width)
        self.update2 = LocalUpdate(local, 16, max(8, width // 2)) if steps2 else None
        # the last level's estimate to full resolution: from 1/2 (x2), or from 1/4 (x4) without 1/2 updates
        evidence = (9 * (groups + 1) if mask_evidence else 0) + (9 * 4 * groups if fine_evidence else 0)
        self.mask = (ConvexMask(16 + 4, 2, 16) if steps2 else ConvexMask(features + 4 * 16 + 16 + evidence, 4, 32))

    def with_mask_uncertainty(self) -> "CadeNetIterative":
        """Make ``uncertainty`` also carry the x4 mask's doubt: the root of the sum of squares of the
        1/8 spread and the spread of :func:`~cade_cli.train.net_blocks.convex_mixture` (no weight changes: an export
        option, ``export --mask-uncertainty``, for the chooser to read where the mask is torn between
        two surfaces). Returns self."""
        if self.steps2:
            raise ValueError("the mask's uncertainty is the x4 mask's (steps2 0)")
        self.mask_uncertainty = True
        self.design["mask_uncertainty"] = True
        return self

    def describe(self, output: str) -> str:
        """The model card's one-line ``architecture``."""
        design = self.design
        return (f"CadeNet-Iterative: 2D features (1/2, 1/4, 1/8 res) -> normalised correlation at 1/8 "
                f"({design['groups']} groups) + 2D aggregation -> soft-argmin at 1/8 -> "
                + (f"{design['steps4']} local re-matching updates at 1/4 and {design['steps2']} at 1/2 (correlation "
                   f"at the estimate +-{design['radius']} px, slices and hat weights) -> learned convex upsampling "
                   + ("x2" if design["steps2"] else "x4")
                   + (" (its mask sees the correlation at its nine candidates)" if self.mask_evidence else "")
                   + (" (its mask sees the 1/2 features' cosine at its nine candidates)" if self.fine_evidence else "")
                   if output == "disparity" else "bilinear x8 (coarse output: re-matching not exported)"))

    def rematched(self, disparity: torch.Tensor, left: torch.Tensor, right: torch.Tensor, update: LocalUpdate,
                  steps: int, factor: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``disparity`` (px of the level of ``left``/``right``, 1/``factor`` resolution) after
        ``steps`` local updates on that level's correlation (levels / ``factor`` disparities), and
        that correlation volume."""
        volume = normalised_correlation(left, right, self.levels // factor, self.groups)
        scale = DISPARITY_SCALE / factor
        for _ in range(steps):
            disparity = disparity + update(hat_lookup(volume, disparity, self.offsets, self.groups), left,
                                           disparity, scale)
        return disparity, volume

    def evidence(self, disparity: torch.Tensor, volume: torch.Tensor) -> torch.Tensor:
        """(B, 9 * (groups + 1), h, w): for each of the nine neighbours' estimates (px of the 1/4 level)
        the correlation at it in this cell (``groups`` channels) and its distance from this cell's own
        estimate (in :data:`~cade_cli.train.model.DISPARITY_SCALE` units of the level)."""
        options = neighbours3x3(disparity)
        reads = [hat_lookup(volume, options[:, k:k + 1], (0,), self.groups) for k in range(9)]
        return torch.cat([*reads, (options - disparity) * (4 / DISPARITY_SCALE)], dim=1)

    def fine_evidence_of(self, disparity: torch.Tensor, half_left: torch.Tensor,
                         half_right: torch.Tensor) -> torch.Tensor:
        """(B, 9 * groups * 4, h, w), candidate-major, then group, then the cell's four 1/2 pixels
        (row-major, as ``pixel_unshuffle`` lays them): for each of the nine neighbours' estimates
        (``disparity``, px of the 1/4 level; held fixed: this reads, it does not move them), the cosine
        per channel group of the left view's 1/2 features at each 1/2 pixel of the cell and the right
        view's at the estimate (two columns linearly weighted; 0 where it falls outside the right view)."""
        options = 2 * F.interpolate(neighbours3x3(disparity.detach()), scale_factor=2, mode="nearest")  # 1/2 px
        left, right = unit_groups(half_left, self.groups), unit_groups(half_right, self.groups)
        batch, channels, height, width = left.shape
        columns = torch.arange(width, dtype=options.dtype, device=options.device).view(1, 1, 1, width)
        reads = []
        for k in range(9):
            position = columns - options[:, k:k + 1]
            lower = torch.floor(position)
            weight = position - lower
            warped = 0
            for column, share in ((lower, 1 - weight), (lower + 1, weight)):
                inside = ((column >= 0) & (column <= width - 1)).to(left.dtype)
                index = column.clamp(0, width - 1).long().expand(batch, channels, height, width)
                warped = warped + torch.gather(right, 3, index) * (share * inside)
            cosine = (left * warped).view(batch, self.groups, channels // self.groups, height, width).sum(dim=2)
            reads.append(F.pixel_unshuffle(cosine, 2))
        return torch.cat(reads, dim=1)

    def forward(self, left: torch.Tensor, right: torch.Tensor, refine: bool = True) -> dict[str, torch.Tensor]:
        """left, right: (B, 1, H, W) -> ``coarse`` (the 1/8 soft-argmin, bilinearly upsampled),
        ``uncertainty`` (px), with ``refine`` ``half`` (after the 1/4 updates, upsampled) and
        ``disparity`` (the last level's estimate, convex-upsampled); all (B, 1, H, W), full-resolution
        px; and the left view's 1/4 ``features``. With the x4 mask from 1/4 (``steps2`` 0) also what that mask
        combines: the 1/4 estimate ``quarter`` (1/4 px) and the mask's logits ``mask`` (B, 9·16, H/4, W/4)."""
        (half_left, half_right), (quarter_left, quarter_right), (eighth_left, eighth_right) = both_views(
            self.features, left, right, self.training)
        eighth = self.levels // 8
        cost = normalised_correlation(eighth_left, eighth_right, eighth, self.groups)
        batch, _, height, width = cost.shape
        prior = cost.view(batch, eighth, self.groups, height, width).mean(dim=2)
        mean, spread = expectation(self.prior_gain * prior + self.initial(torch.cat([cost, eighth_left], dim=1)))
        size = left.shape[-2:]
        out = {"coarse": upsampled(mean, 8, size), "uncertainty": upsampled(spread, 8, size), "features": quarter_left}
        if refine:
            quarter, volume = self.rematched(upsampled(mean, 2), quarter_left, quarter_right, self.update4,
                                             self.steps4, 4)
            out["half"] = upsampled(quarter, 4, size)
            if not self.steps2:
                guide = upsampling_guide((quarter_left,), half_left, left)
                if self.mask_evidence:
                    guide = torch.cat([guide, self.evidence(quarter, volume)], dim=1)
                if self.fine_evidence:
                    guide = torch.cat([guide, self.fine_evidence_of(quarter, half_left, half_right)], dim=1)
                mask = self.mask(guide)
                if self.mask_uncertainty:
                    out["disparity"], spread = convex_mixture(quarter, mask, 4)
                    out["uncertainty"] = torch.sqrt(out["uncertainty"] ** 2 + spread ** 2)
                else:
                    out["disparity"] = convex_upsample(quarter, mask, 4)
                out.update(quarter=quarter, mask=mask)  # what it combines, for cade_cli.train.mask_headroom
                return out
            half, _ = self.rematched(upsampled(quarter, 2), half_left, half_right, self.update2, self.steps2, 2)
            mask = self.mask(torch.cat([half_left, F.pixel_unshuffle(left, 2)], dim=1))
            out["disparity"] = convex_upsample(half, mask, 2)
        return out
