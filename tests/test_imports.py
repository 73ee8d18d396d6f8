"""The runtime package never pulls in the training or inference frameworks on its own."""

from __future__ import annotations

import subprocess
import sys

RUNTIME_MODULES = [
    "cade_cli", "cade_cli.cli", "cade_cli.stereo", "cade_cli.registration", "cade_cli.registration_io",
    "cade_cli.matching", "cade_cli.spectral", "cade_cli.imageio", "cade_cli.disparity_io", "cade_cli.atomic",
]


def test_runtime_modules_do_not_import_torch():
    probe = (
        "import importlib, sys\n"
        f"for name in {RUNTIME_MODULES!r}: importlib.import_module(name)\n"
        "from cade_cli import estimate_disparity, register, color_agnostic, synthesize_bands\n"
        "print('torch' in sys.modules)"
    )
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "False"


def test_public_api_is_importable_from_the_package():
    import cade_cli

    assert callable(cade_cli.estimate_disparity) and callable(cade_cli.register)
    assert callable(cade_cli.color_agnostic) and callable(cade_cli.synthesize_bands)
    assert cade_cli.estimate_disparity.__doc__ and "(H, W)" in cade_cli.estimate_disparity.__doc__
