"""The census cost of the 1/4 level (the ``--census`` input of :class:`~cade_cli.train.model.CadeNet`):
sparse 5x5 census bits of each band, compared at every 4-px disparity, averaged over 4x4 blocks."""

from __future__ import annotations

import torch
import torch.nn.functional as F


CENSUS_OFFSETS = ((-2, -2), (-2, 0), (-2, 2), (0, -2), (0, 2), (2, -2), (2, 0), (2, 2))
"""(dy, dx) of the census comparisons: the 8 compass points at radius 2 (a sparse 5x5 census)."""


def census_bits(band: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) -> (B, 8, H, W): 1 where the neighbour at each offset of
    :data:`CENSUS_OFFSETS` is brighter than the pixel. Unchanged by any increasing
    intensity map, so the same on rendered and on real bands; no gradient flows through it."""
    height, width = band.shape[-2:]
    padded = F.pad(band, (2, 2, 2, 2), mode="replicate")
    return torch.cat([(padded[..., 2 + dy:2 + dy + height, 2 + dx:2 + dx + width] > band).to(band.dtype)
                      for dy, dx in CENSUS_OFFSETS], dim=1)


CENSUS_GAIN = 64.0
"""The census cost is scaled by this before it meets the learned correlation: its spread
along disparity is then about that of cade-v4's correlation (0.07 x 64 against 5.4 on
training batches), so a zero-initialised kernel learns to weigh it at the same pace."""


def census_cost(left: torch.Tensor, right: torch.Tensor, levels: int) -> torch.Tensor:
    """Cost volume (B, 1, D, H/4, W/4) of the 1/4 level: 0.5 minus the mean Hamming distance
    of the census bits of left(x) and right(x - 4d) over each 4x4 block (0.5: unrelated;
    positive: similar). Where x - 4d falls outside the right view the cost is 0.
    (:class:`CadeNet` multiplies it by :data:`CENSUS_GAIN`.)"""
    bits_left, bits_right = census_bits(left), census_bits(right)
    width = left.shape[-1]
    shift = 4 * (levels - 1)
    padded = F.pad(bits_right, (shift, 0), value=0.5)  # 0.5 vs a 0/1 bit: Hamming 0.5, cost 0
    slices = [F.avg_pool2d(0.5 - (bits_left - padded[..., shift - 4 * d:shift - 4 * d + width]).abs()
                           .mean(dim=1, keepdim=True), 4) for d in range(levels)]
    return torch.stack(slices, dim=2)
