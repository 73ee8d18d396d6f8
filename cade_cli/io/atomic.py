"""Write output files all-or-nothing: a failed run leaves no half-written file behind.

A command with several outputs (a map, its visualisation, its validity, a report, a
folder of maps) stages every one of them with :func:`atomic_outputs` and renames them
into place only once all were written, so a failure half-way replaces none of them.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from cade_cli.errors import CadeError

_TEMPORARY_NAME = re.compile(r"^\.(?P<stem>.*)\.tmp-[0-9a-f]{16}(?P<suffix>.*)$")
"""The names :func:`temporary_sibling` makes: ``.<stem>.tmp-<16 hex digits><suffix>``."""

_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
"""Errors only writing can meet (full disk, quota, file too large): an ``OSError`` with one
of these and no file name, raised while outputs are staged, is about them."""


def temporary_sibling(path: Path) -> Path:
    """A fresh hidden name beside ``path`` that keeps its suffix.

    ``out/disp.pfm`` gives e.g. ``out/.disp.tmp-1a2b3c4d5e6f7a8b.pfm``: same directory
    (so ``os.replace`` is an atomic rename on one file system) and same suffix (so
    encoders that choose the format by extension, cv2 and tifffile, pick the right one).
    """
    return path.with_name(f".{path.stem}.tmp-{secrets.token_hex(8)}{path.suffix}")


def intended_path(path: Path) -> Path:
    """The output that a :func:`temporary_sibling` name (or one of a temporary) stands for.

    ``out/.disp.tmp-1a2b3c4d5e6f7a8b.pfm`` gives ``out/disp.pfm``; any other path is
    returned as is. Error messages name this path, the one the user asked for.
    """
    path = Path(path)
    while (match := _TEMPORARY_NAME.match(path.name)) is not None:
        path = path.with_name(match["stem"] + match["suffix"])
    return path


def write_error(path: Path | str, error: OSError) -> CadeError:
    """The :class:`CadeError` for an OS error (permissions, full disk, ...) while writing ``path``."""
    reason = error.strerror or type(error).__name__
    shown = intended_path(Path(path)) if isinstance(path, Path) else path
    return CadeError(f"could not write {shown}: {reason}; check free space and permissions")


def check_writable(path: Path) -> None:
    """Refuse, before any work, an output file that could not be created.

    The parent must be an existing directory that this process can create files in
    (tried by creating and deleting a hidden file beside ``path``), and ``path`` must
    not be a directory. An existing file at ``path`` is fine: it will be replaced.

    Raises:
        CadeError: naming the path, the reason and the fix.
    """
    path = Path(path)
    _check_target(path)
    _probe(temporary_sibling(path), shown=path)


def check_writable_folder(folder: Path) -> None:
    """Refuse, before any work, an output folder that could not be created or filled.

    ``folder`` may exist (it must be a directory this process can write in) or not (its
    parent must be such a directory).

    Raises:
        CadeError: naming the folder, the reason and the fix.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise CadeError(f"{folder} is a file, not a folder; give a folder name (it is created if missing)")
    if folder.is_dir():
        _probe(folder / f".probe.tmp-{secrets.token_hex(8)}", shown=folder)
    else:
        check_writable(folder)


@contextmanager
def atomic_output(path: Path) -> Iterator[Path]:
    """Yield a temporary path to write to; move it onto ``path`` only if the body succeeds.

    On normal exit the temporary file replaces ``path`` with ``os.replace`` (atomic, and
    it overwrites an existing file). On any exception the temporary file is deleted and
    an existing ``path`` is left untouched; an ``OSError`` (permissions, full disk)
    becomes a :class:`CadeError` naming ``path``, any other exception propagates
    unchanged. The body must create the temporary file.

    Raises:
        CadeError: up front, when the parent directory does not exist or ``path`` is a
            directory; an OS error while writing or renaming.
    """
    path = Path(path)
    _check_target(path)
    temporary = temporary_sibling(path)
    try:
        yield temporary
        os.replace(temporary, path)
    except OSError as exc:
        _discard(temporary)
        raise write_error(path, exc) from exc
    except BaseException:
        _discard(temporary)
        raise


@contextmanager
def atomic_outputs(
    files: Iterable[Path | None] = (), *, folders: Iterable[Path | None] = ()
) -> Iterator[dict[Path, Path]]:
    """Stage every output of one command; put them all in place only if the body succeeds.

    Every output is checked first (:func:`check_writable`, :func:`check_writable_folder`),
    so a run that could not save its results stops before computing them. The body then
    writes each output to its stand-in: a hidden temporary file beside each of ``files``
    (any writer may be used on it, atomic ones included), and a hidden, empty staging
    folder for each of ``folders``, beside it (or inside it when it already exists).
    On normal exit each temporary file replaces its output, and each staging folder's
    files are moved to the same place under their output folder (which is created if
    missing; other files already there are kept). On any exception nothing is renamed
    or moved and every stand-in is deleted: no output appears or changes.

    Args:
        files: output files; None entries (options not given) are skipped.
        folders: output folders; None entries are skipped.

    Yields:
        ``{output: stand-in}`` for every given file and folder.

    Raises:
        CadeError: an output that cannot be written (checked before the body runs) or the
            same output given twice; an OS error while writing (the body) or renaming.
    """
    files = [Path(path) for path in files if path is not None]
    folders = [Path(path) for path in folders if path is not None]
    seen: dict[Path, Path] = {}
    for path in (*files, *folders):
        key = path.resolve()
        if key in seen:
            raise CadeError(f"{seen[key]} and {path} are the same output; give each output its own name")
        seen[key] = path
    for path in files:
        check_writable(path)
    for folder in folders:
        check_writable_folder(folder)
    staged: dict[Path, Path] = {path: temporary_sibling(path) for path in files}
    try:
        for folder in folders:
            staging = (folder / f".staging.tmp-{secrets.token_hex(8)}") if folder.is_dir() else temporary_sibling(folder)
            staging.mkdir()
            staged[folder] = staging
        yield staged
        for path in files:
            if not staged[path].is_file():
                raise RuntimeError(f"{path} was staged but the command never wrote it")  # a bug, not bad input
        for path in files:
            os.replace(staged[path], path)
        for folder in folders:
            _merge_folder(staged[folder], folder)
    except OSError as exc:
        _discard_all(staged)
        if exc.filename is None and exc.errno in _WRITE_ERRNOS and staged:  # a stream meeting a full disk
            raise write_error(", ".join(map(str, staged)), exc) from exc
        output = _output_named(exc.filename, staged)
        if output is None:
            raise  # not about our outputs: the body's own business
        raise write_error(output, exc) from exc
    except BaseException:
        _discard_all(staged)
        raise


def _probe(probe: Path, *, shown: Path) -> None:
    """Create and delete the file ``probe``; CadeError naming ``shown`` if it cannot be created."""
    try:
        descriptor = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise CadeError(f"cannot write {shown}: {reason} in {probe.parent}; choose a folder you can write to") from exc
    os.close(descriptor)
    _discard(probe)


def _check_target(path: Path) -> None:
    """CadeError unless ``path``'s parent is an existing directory and ``path`` is not one."""
    parent = path.parent
    if not parent.is_dir():
        if parent.exists():
            raise CadeError(f"output directory {parent} is not a directory; choose another output path")
        raise CadeError(f"output directory {parent} does not exist; create it first")
    if path.is_dir():
        raise CadeError(f"output {path} is a directory; give a file name instead")


def _output_named(filename: object, staged: dict[Path, Path]) -> Path | None:
    """The output an OS error's file name belongs to (a stand-in, or a file under a
    staged or output folder, shown under its output), or None if it is none of ours."""
    if not isinstance(filename, (str, os.PathLike)):
        return None
    path = Path(os.fsdecode(filename))
    for output, stand_in in staged.items():
        for root, shown in ((stand_in, output), (output, output)):
            if path == root or root in path.parents:
                return shown / path.relative_to(root) if path != root else intended_path(shown)
        if intended_path(path) == output:  # a writer's own temporary of the stand-in
            return output
    return None


def _merge_folder(staging: Path, folder: Path) -> None:
    """Move every file under ``staging`` to the same relative place under ``folder``."""
    for source in sorted(p for p in staging.rglob("*") if p.is_file()):
        target = folder / source.relative_to(staging)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, target)
    shutil.rmtree(staging)


def _discard(path: Path) -> None:
    """Delete a temporary file if it is there; failing to (it never was made) is not an error."""
    with suppress(OSError):
        path.unlink(missing_ok=True)


def _discard_all(staged: dict[Path, Path]) -> None:
    for stand_in in staged.values():
        if stand_in.is_dir():
            shutil.rmtree(stand_in, ignore_errors=True)
        else:
            _discard(stand_in)
