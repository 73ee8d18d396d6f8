"""Running the ``cade`` command in-process, for the CLI tests of every module."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli import cli


def run_cade(args, capsys) -> tuple[int, str, str]:
    """Run the CLI in-process (fast) and return (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main([str(a) for a in args])
    captured = capsys.readouterr()
    return exit_info.value.code, captured.out, captured.err


def write_png16(path: Path, band: np.ndarray) -> Path:
    """``band`` in [0, 1] as a 16-bit PNG at ``path``."""
    cv2.imwrite(str(path), np.rint(np.clip(band, 0, 1) * 65535).astype(np.uint16))
    return path
