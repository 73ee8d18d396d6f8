"""cade: cross-spectral stereo — disparity between bands taken through different filters.

Public API (imported lazily, so ``import cade_cli`` and ``cade --help`` stay light):

- :func:`estimate_disparity` — dense disparity of a left band against a right band.
- :func:`register` — warp the right band into the left view.
- :func:`color_agnostic` — the CADE transform of one band.
- :func:`synthesize_bands` — 11 synthetic spectral bands from an RGB image.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from cade_cli.version import __version__

_LAZY = {
    "estimate_disparity": "cade_cli.stereo",
    "register": "cade_cli.registration",
    "color_agnostic": "cade_cli.spectral",
    "synthesize_bands": "cade_cli.spectral",
    "CadeError": "cade_cli.errors",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'cade_cli' has no attribute {name!r}")
