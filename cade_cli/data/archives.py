"""Downloaded archives: checked against their sha256 and unpacked (zip or tar), every member's
path checked to stay inside the destination, into a scratch folder first and then moved into place.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import tarfile
import zipfile
from collections.abc import Callable
from contextlib import ExitStack
from functools import partial
from pathlib import Path, PurePosixPath

from cade_cli.errors import CadeError
from cade_cli.io.checksum import CHUNK_BYTES, file_sha256


_TAR_SUFFIXES = (".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")


def _kind(path: Path) -> str:
    name = path.name.lower()
    if name.endswith(".zip"):
        return "zip"
    if name.endswith(_TAR_SUFFIXES):
        return "tar"
    raise CadeError(f"{path.name} is neither a zip nor a tar archive; cade cannot unpack it")


def archive_corruption(path: Path, sha256: str | None) -> str | None:
    """Why ``path`` is not a sound archive (None: it is). Reads every member through."""
    if sha256 is not None and file_sha256(path) != sha256.lower():
        return "sha256 differs from the published one"
    try:
        if _kind(path) == "zip":
            with zipfile.ZipFile(path) as archive:
                bad = archive.testzip()
            return None if bad is None else f"member {bad} fails its CRC check"
        with tarfile.open(path) as archive:
            for member in archive:
                if member.isfile():
                    stream = archive.extractfile(member)
                    while stream is not None and stream.read(CHUNK_BYTES):
                        pass
        return None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, tarfile.TarError, EOFError, OSError, ValueError) as error:
        return " ".join(str(error).split()) or type(error).__name__


def _safe_relative(name: str, archive: Path) -> PurePosixPath:
    """Member ``name`` as a relative path; refuses absolute paths and ``..`` (zip-slip)."""
    posix = name.replace("\\", "/")
    relative = PurePosixPath(posix)
    if posix.startswith("/") or re.match(r"^[A-Za-z]:", posix) or ".." in relative.parts:
        raise CadeError(
            f"archive {archive.name} holds an unsafe member {name!r} (absolute or '..' path); "
            "nothing was extracted and the archive was deleted"
        )
    return relative


def _members(path: Path, stack: ExitStack) -> list[tuple[PurePosixPath, Callable]]:
    """(relative path, opener) of every regular file, the archive held open by ``stack``.

    Every name is checked before the list is returned, so nothing is written for an
    archive with one unsafe member.
    """
    if _kind(path) == "zip":
        archive = stack.enter_context(zipfile.ZipFile(path))
        infos = [(_safe_relative(info.filename, path), info) for info in archive.infolist()]
        return [(name, partial(archive.open, info)) for name, info in infos if not info.is_dir()]
    archive = stack.enter_context(tarfile.open(path))
    files = []
    for member in archive.getmembers():
        name = _safe_relative(member.name, path)
        if member.issym() or member.islnk() or member.isdev():
            raise CadeError(
                f"archive {path.name} holds a link or device {member.name!r}; "
                "nothing was extracted and the archive was deleted"
            )
        if member.isfile():
            files.append((name, partial(archive.extractfile, member)))
    return files


def extract_archive(path: Path, destination: Path, *, strip: str, scratch: Path) -> None:
    """Unpack ``path`` into ``destination`` through a scratch folder, merging with what is there.

    Every member name is checked before anything is written (an unsafe archive is
    deleted); ``strip`` is removed from the names when all of them start with it. Files
    are moved into place only once the whole archive is unpacked, so a damaged or unsafe
    archive adds nothing to ``destination``.
    """
    with ExitStack() as stack:
        try:
            members = _members(path, stack)
        except CadeError:
            stack.close()
            path.unlink(missing_ok=True)
            raise
        prefix = PurePosixPath(strip.strip("/")) if strip.strip("/") else None
        if prefix is not None and members and all(name.parts[: len(prefix.parts)] == prefix.parts
                                                  for name, _ in members):
            members = [(PurePosixPath(*name.parts[len(prefix.parts):]), opener) for name, opener in members]
        temporary = scratch / f".extract-{secrets.token_hex(8)}"
        try:
            temporary.mkdir(parents=True)
            for name, opener in members:
                if not name.parts:
                    continue
                target = temporary.joinpath(*name.parts)
                target.parent.mkdir(parents=True, exist_ok=True)
                with opener() as source, open(target, "wb") as out:
                    shutil.copyfileobj(source, out, CHUNK_BYTES)
            for file in sorted(p for p in temporary.rglob("*") if p.is_file()):
                final = destination / file.relative_to(temporary)
                final.parent.mkdir(parents=True, exist_ok=True)
                os.replace(file, final)
        except OSError as error:
            raise CadeError(f"cannot unpack {path.name} into {destination}: {error.strerror or error}; "
                            "free some space or choose another --to") from None
        finally:
            shutil.rmtree(temporary, ignore_errors=True)
