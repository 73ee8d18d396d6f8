"""The self-supervised loss of real cross-spectral pairs without ground truth (issue 38 item 5,
:mod:`~cade_cli.train.selfsup_pairs`): the right view's gradients warped to the left by the
predicted disparity (differentiable ``grid_sample``) should be parallel or anti-parallel to the
left view's, whatever the bands' contrast (a local normalised correlation of the gradient
vectors, squared: unchanged when one band's contrast is inverted); masked where the warp leaves
the right view or a band did not see the pixel; plus an edge-aware smoothness term."""

from __future__ import annotations

import torch
import torch.nn.functional as F

WINDOW = 5
"""Side of the box over which the gradient vectors are correlated."""
EPSILON = 1e-4
"""Added to the gradients' energies (guides in about [0, 1]: gradients of ~0.01 per px count)."""
SMOOTHNESS = 0.05
"""Weight of the edge-aware smoothness term beside the consistency term (in [0, 1])."""
EDGE_SCALE = 10.0
"""exp(-EDGE_SCALE · |guide gradient|): the smoothness relaxes across the left view's edges."""


def gradients(image: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) -> (B, 2, H, W): central differences in x and y (replicated borders)."""
    padded = F.pad(image, (1, 1, 1, 1), mode="replicate")
    gx = (padded[..., 1:-1, 2:] - padded[..., 1:-1, :-2]) / 2
    gy = (padded[..., 2:, 1:-1] - padded[..., :-2, 1:-1]) / 2
    return torch.cat([gx, gy], dim=1)


def warp_right(right: torch.Tensor, disparity: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``right`` (B, C, H, W) sampled at (x - disparity, y) (bilinear, differentiable in the
    disparity), and (B, 1, H, W) where that sample lies inside the view."""
    _, _, height, width = right.shape
    columns = torch.arange(width, dtype=right.dtype, device=right.device).view(1, 1, 1, width)
    rows = torch.arange(height, dtype=right.dtype, device=right.device).view(1, 1, height, 1)
    x = columns - disparity
    grid = torch.stack([2 * x[:, 0] / (width - 1) - 1, (2 * rows / (height - 1) - 1).expand_as(x)[:, 0]], dim=-1)
    warped = F.grid_sample(right, grid, mode="bilinear", padding_mode="border", align_corners=True)
    return warped, ((x >= 0) & (x <= width - 1)).to(right.dtype)


def gradient_consistency(left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor,
                         seen_left: torch.Tensor, seen_right: torch.Tensor) -> torch.Tensor:
    """(B,) 1 - the squared normalised correlation of the left view's gradient vectors and the
    right view's at (x - d) over :data:`WINDOW` boxes, averaged over each sample's pixels
    seen in both (weighted by the left view's gradient energy: flat areas say nothing)."""
    grad_left = gradients(left)
    warped, inside = warp_right(torch.cat([gradients(right), seen_right], dim=1), disparity)
    grad_right, seen = warped[:, :2], warped[:, 2:] > 0.99
    box = lambda value: F.avg_pool2d(value, WINDOW, stride=1, padding=WINDOW // 2, count_include_pad=False)
    cross = box((grad_left * grad_right).sum(dim=1, keepdim=True))
    energy_left = box((grad_left ** 2).sum(dim=1, keepdim=True))
    energy_right = box((grad_right ** 2).sum(dim=1, keepdim=True))
    correlation = cross ** 2 / ((energy_left + EPSILON) * (energy_right + EPSILON))
    weight = energy_left / (energy_left + EPSILON) * inside * seen * (seen_left > 0.5)
    return ((1 - correlation) * weight).sum(dim=(1, 2, 3)) / weight.sum(dim=(1, 2, 3)).clamp_min(1.0)


def smoothness(disparity: torch.Tensor, left: torch.Tensor) -> torch.Tensor:
    """(B,) edge-aware smoothness: |∂d| / mean d, damped where the left guide has an edge."""
    scaled = disparity / disparity.mean(dim=(1, 2, 3), keepdim=True).clamp_min(1.0)
    dx = (scaled[..., :, 1:] - scaled[..., :, :-1]).abs() * torch.exp(
        -EDGE_SCALE * (left[..., :, 1:] - left[..., :, :-1]).abs())
    dy = (scaled[..., 1:, :] - scaled[..., :-1, :]).abs() * torch.exp(
        -EDGE_SCALE * (left[..., 1:, :] - left[..., :-1, :]).abs())
    return dx.mean(dim=(1, 2, 3)) + dy.mean(dim=(1, 2, 3))


def selfsup_loss(disparity: torch.Tensor, guides: torch.Tensor, chosen: torch.Tensor) -> torch.Tensor:
    """The self-supervised loss of the samples ``chosen`` (B,) bool of a batch: ``guides``
    (B, 4, H, W) = left and right guides and where each band saw the pixel
    (:class:`~cade_cli.train.selfsup_pairs.SelfSupCrop`); ``disparity`` (B, 1, H, W). 0 when none."""
    if not bool(chosen.any()):
        return disparity.sum() * 0
    disparity, guides = disparity[chosen], guides[chosen]
    left, right, seen_left, seen_right = guides[:, :1], guides[:, 1:2], guides[:, 2:3], guides[:, 3:4]
    terms = gradient_consistency(left, right, disparity, seen_left, seen_right)
    return (terms + SMOOTHNESS * smoothness(disparity, left)).mean()
