"""The network architectures a training config can name, and the one place that builds them."""

from __future__ import annotations

from torch import nn

from cade_cli.train.model import CadeNet, design_of
from cade_cli.train.net2d import CadeNet2D
from cade_cli.train.net_convex import CadeNetConvex
from cade_cli.train.net_iterative import CadeNetIterative
from cade_cli.train.net_peak import CadeNetPeak

ARCHITECTURES = ("cadenet", "cadenet2d", "cadenet-convex", "cadenet-iterative", "cadenet-peak")
"""``cadenet``: :class:`~cade_cli.train.model.CadeNet` (3D aggregation; cade-v1 ... v8);
``cadenet2d``: the all-2D generation (:class:`~cade_cli.train.net2d.CadeNet2D`, Accuracy III);
the Accuracy V bake-off's designs: ``cadenet-convex`` (inverted-residual aggregation, convex
upsampling: :mod:`~cade_cli.train.net_convex`), ``cadenet-iterative`` (a 1/8 estimate re-matched
locally at 1/4 and 1/2: :mod:`~cade_cli.train.net_iterative`) and ``cadenet-peak`` (the control's
aggregation, peak-window regression, convex upsampling: :mod:`~cade_cli.train.net_peak`).
Those three take ``features2d`` and ``width2d`` from the config, the rest of their design from
their modules' defaults."""

BAKEOFF_DESIGNS = {"cadenet-convex": CadeNetConvex, "cadenet-iterative": CadeNetIterative, "cadenet-peak": CadeNetPeak}


def network_of(config: dict) -> nn.Module:
    """The untrained network a training config describes (its ``architecture``, default
    ``cadenet``, and that architecture's design keys)."""
    architecture = config.get("architecture") or "cadenet"
    levels = config.get("levels", config.get("max_disp"))  # "max_disp": runs before v6
    if architecture == "cadenet2d":
        return CadeNet2D(levels, features=config.get("features2d", 32), groups=config.get("groups2d", 4),
                         width=config.get("width2d", 48), half_channels=config.get("half_channels", 16),
                         refine_channels=config.get("full_refinement", 0), slice_channels=config.get("slice_channels", 0))
    if architecture in BAKEOFF_DESIGNS:
        extra = {key: True for key in ("mask_evidence", "fine_evidence") if config.get(key)}  # cadenet-iterative's
        return BAKEOFF_DESIGNS[architecture](levels, features=config.get("features2d", 32),
                                             width=config.get("width2d", 48), **extra)
    if architecture != "cadenet":
        raise ValueError(f"architecture must be one of {', '.join(ARCHITECTURES)}, got {architecture!r}")
    return CadeNet(levels, **design_of(config))
