"""The network architectures a training config can name, and the one place that builds them."""

from __future__ import annotations

from torch import nn

from cade_cli.train.model import CadeNet, design_of
from cade_cli.train.net2d import CadeNet2D

ARCHITECTURES = ("cadenet", "cadenet2d")
"""``cadenet``: :class:`~cade_cli.train.model.CadeNet` (3D aggregation; cade-v1 ... v8);
``cadenet2d``: the all-2D generation (:class:`~cade_cli.train.net2d.CadeNet2D`, Accuracy III)."""


def network_of(config: dict) -> nn.Module:
    """The untrained network a training config describes (its ``architecture``, default
    ``cadenet``, and that architecture's design keys)."""
    architecture = config.get("architecture") or "cadenet"
    levels = config.get("levels", config.get("max_disp"))  # "max_disp": runs before v6
    if architecture == "cadenet2d":
        return CadeNet2D(levels, features=config.get("features2d", 32), groups=config.get("groups2d", 4),
                         width=config.get("width2d", 48), half_channels=config.get("half_channels", 16),
                         refine_channels=config.get("full_refinement", 0), slice_channels=config.get("slice_channels", 0))
    if architecture != "cadenet":
        raise ValueError(f"architecture must be one of {', '.join(ARCHITECTURES)}, got {architecture!r}")
    return CadeNet(levels, **design_of(config))
