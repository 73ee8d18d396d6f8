"""Write output files all-or-nothing: a failed run leaves no half-written file behind."""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from cade_cli.errors import CadeError


def temporary_sibling(path: Path) -> Path:
    """A fresh hidden name beside ``path`` that keeps its suffix.

    ``out/disp.pfm`` gives e.g. ``out/.disp.tmp-1a2b3c4d5e6f7a8b.pfm``: same directory
    (so ``os.replace`` is an atomic rename on one file system) and same suffix (so
    encoders that choose the format by extension, cv2 and tifffile, pick the right one).
    """
    return path.with_name(f".{path.stem}.tmp-{secrets.token_hex(8)}{path.suffix}")


@contextmanager
def atomic_output(path: Path) -> Iterator[Path]:
    """Yield a temporary path to write to; move it onto ``path`` only if the body succeeds.

    On normal exit the temporary file replaces ``path`` with ``os.replace`` (atomic, and
    it overwrites an existing file). On any exception the temporary file is deleted, an
    existing ``path`` is left untouched, and the exception propagates unchanged. The
    body must create the temporary file; if it does not, ``os.replace`` raises
    ``FileNotFoundError``.

    Raises:
        CadeError: up front, when the parent directory does not exist or ``path`` is a
            directory.
    """
    path = Path(path)
    parent = path.parent
    if not parent.is_dir():
        if parent.exists():
            raise CadeError(f"output directory {parent} is not a directory; choose another output path")
        raise CadeError(f"output directory {parent} does not exist; create it first")
    if path.is_dir():
        raise CadeError(f"output {path} is a directory; give a file name instead")
    temporary = temporary_sibling(path)
    try:
        yield temporary
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
