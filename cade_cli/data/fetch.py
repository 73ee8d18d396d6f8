"""Put the files of one archive in place: fetch over HTTP(S), resume, verify, unpack safely.

Nothing here knows a dataset. :func:`install` makes the files an :class:`Archive`
promises (:class:`Expected`) present in a folder: when some are missing it fetches the
archive (continuing a ``.part`` left by an interrupted run with an HTTP ``Range``
request), checks it (sha256 where known, then a full read of the archive), extracts it
(no absolute or ``..`` member may escape) into a scratch folder, moves the files into
place and checks the promise again.
"""

from __future__ import annotations

import http.client
import os
import re
import urllib.error
import urllib.request
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal
from urllib.parse import urlsplit

from cade_cli.version import __version__
from cade_cli.data.archives import archive_corruption, extract_archive
from cade_cli.errors import CadeError
from cade_cli.io.checksum import CHUNK_BYTES

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress

BASE_URL_ENV = "CADE_DOWNLOAD_BASE_URL"
"""Environment variable that replaces the scheme, host (and a path prefix) of every URL: a mirror."""

TIMEOUT_S = 60.0
"""Seconds without an answer or a byte before a transfer counts as failed."""


@dataclass(frozen=True)
class Expected:
    """Files an archive must leave in the destination folder.

    Attributes:
        pattern: path relative to the destination folder, glob characters allowed.
        at_least: how many files must match.
    """

    pattern: str
    at_least: int = 1


@dataclass(frozen=True)
class Archive:
    """One file to fetch and unpack.

    Attributes:
        url: official address.
        filename: local name in the scratch folder (unique among the archives fetched
            there, resolution included, so that a ``.part`` is never resumed from another file).
        expected: what must exist in the destination folder after extraction.
        strip: leading folder of the members removed on extraction when every member
            has it (``"MiddEval3/"``); an archive without it extracts unchanged.
        into: subfolder of the destination folder to extract into (``"Art"``).
        sha256: hex digest where known; None: checked by reading the archive through.
    """

    url: str
    filename: str
    expected: tuple[Expected, ...]
    strip: str = ""
    into: str = ""
    sha256: str | None = None


def mirror_url(url: str, base_url: str | None) -> str:
    """``url`` with its scheme and host replaced by ``base_url`` (which may add a path prefix).

    ``mirror_url("https://vision.middlebury.edu/stereo/x.zip", "http://127.0.0.1:8000/m")``
    gives ``"http://127.0.0.1:8000/m/stereo/x.zip"``; ``base_url=None`` leaves ``url`` as is.
    """
    if not base_url:
        return url
    parts = urlsplit(base_url)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise CadeError(f"download base URL {base_url!r} is not an http(s) address; fix it or unset {BASE_URL_ENV}")
    return base_url.rstrip("/") + urlsplit(url).path


def download_progress(console: Console | None = None) -> Progress:
    """A rich progress display for :func:`install`: file name, bar, bytes, speed, ETA."""
    from rich.progress import (BarColumn, DownloadColumn, Progress, TextColumn, TimeRemainingColumn,
                               TransferSpeedColumn)

    return Progress(
        TextColumn("{task.description}"), BarColumn(), DownloadColumn(), TransferSpeedColumn(), TimeRemainingColumn(),
        console=console, transient=True,
    )


def missing(folder: Path, expected: Sequence[Expected]) -> list[str]:
    """Patterns of ``expected`` with fewer matches under ``folder`` than required."""
    absent = []
    for item in expected:
        if any(char in item.pattern for char in "*?["):
            count = sum(1 for path in folder.glob(item.pattern) if path.is_file()) if folder.is_dir() else 0
            if count < item.at_least:
                absent.append(f"{item.pattern} ({count} of {item.at_least})")
        elif not (folder / item.pattern).is_file():
            absent.append(item.pattern)
    return absent


def install(
    archive: Archive, folder: Path, *, url: str, scratch: Path, page: str, force: bool = False,
    keep_archive: bool = False, progress: Progress | None = None,
) -> tuple[Literal["present", "extracted", "downloaded"], int]:
    """Make the files ``archive`` promises present in ``folder`` (created as needed, merged with what is there).

    ``url`` is ``archive.url`` or a mirror of it; ``scratch`` holds the archive, its
    ``.part`` and the extraction (the archive is removed unless ``keep_archive``);
    ``page`` is where a user reads about the data, for error messages. ``force``
    fetches and unpacks again even when the files are in place.

    Returns:
        (``"present"``: nothing done, ``"extracted"``: a complete archive in ``scratch``
        unpacked, ``"downloaded"``: fetched and unpacked; bytes received).

    Raises:
        CadeError: network failure (the ``.part`` file is kept for resuming), corrupt
            archive (deleted), unsafe archive member, files missing after extraction.
    """
    if not force and not missing(folder, archive.expected):
        return "present", 0
    scratch.mkdir(parents=True, exist_ok=True)
    path = scratch / archive.filename
    if force:
        path.unlink(missing_ok=True)
        _part(path).unlink(missing_ok=True)
    done, received = "extracted", 0
    if not (path.is_file() and archive_corruption(path, archive.sha256) is None):  # else: a complete earlier download
        path.unlink(missing_ok=True)
        done, received = "downloaded", _fetch(url, path, progress=progress, page=page)
        problem = archive_corruption(path, archive.sha256)
        if problem is not None:
            path.unlink(missing_ok=True)
            raise CadeError(f"archive {path.name} is corrupt ({problem}); it was deleted, run again to re-download")
    extract_archive(path, folder / archive.into if archive.into else folder, strip=archive.strip, scratch=scratch)
    absent = missing(folder, archive.expected)
    if absent:
        shown = ", ".join(absent[:3]) + (f" and {len(absent) - 3} more" if len(absent) > 3 else "")
        raise CadeError(
            f"{archive.filename} did not provide {shown} in {folder}; the official archive may have changed, "
            f"see {page}"
        )
    if not keep_archive:
        path.unlink(missing_ok=True)
    return done, received


def _part(path: Path) -> Path:
    return path.with_name(path.name + ".part")


# --- transfer ---------------------------------------------------------------------------

_CONTENT_RANGE = re.compile(r"bytes\s+(?:(\d+)-(\d+)|\*)/(\d+|\*)")


def _content_range(value: str | None) -> tuple[int | None, int | None]:
    """(first byte, total size) from a ``Content-Range`` header; None where absent."""
    match = _CONTENT_RANGE.match(value or "")
    if not match:
        return None, None
    first = int(match.group(1)) if match.group(1) is not None else None
    total = int(match.group(3)) if match.group(3) != "*" else None
    return first, total


def _fetch(url: str, path: Path, *, progress: Progress | None, page: str) -> int:
    """Download ``url`` to ``path`` through ``path.part``, resuming it; returns the bytes received.

    A ``.part`` left by an earlier run is continued with ``Range: bytes=N-``; a server
    that answers 200 (no range support) restarts it from 0. The received size must equal
    the announced one before ``.part`` becomes ``path``.
    """
    part = _part(path)
    received = 0
    for _attempt in range(2):
        start = part.stat().st_size if part.is_file() else 0
        request = urllib.request.Request(url, headers={"User-Agent": f"cade-cli/{__version__}"})
        if start:
            request.add_header("Range", f"bytes={start}-")
        try:
            response = urllib.request.urlopen(request, timeout=TIMEOUT_S)
        except urllib.error.HTTPError as error:
            error.close()
            if error.code == 416 and start:  # our .part is as long as the file, or longer
                _, total = _content_range(error.headers.get("Content-Range"))
                if total == start:
                    os.replace(part, path)
                    return received
                part.unlink()
                continue
            raise _network_error(url, error, part, page) from None
        except (http.client.HTTPException, OSError) as error:  # URLError, timeouts, resets
            raise _network_error(url, error, part, page) from None
        with response:
            status = response.status
            length = response.headers.get("Content-Length")
            length = int(length) if length and length.isdigit() else None
            if start and status == 206:
                first, total = _content_range(response.headers.get("Content-Range"))
                if first != start:  # not the bytes we asked for: start over
                    part.unlink()
                    continue
                if total is None and length is not None:
                    total = start + length
                mode = "ab"
            else:
                start, total, mode = 0, length, "wb"
            task = progress.add_task(path.name, total=total, completed=start) if progress is not None else None
            on_chunk = (lambda size: progress.update(task, completed=size)) if task is not None else None
            try:
                got = _stream(response, part, mode, start=start, on_chunk=on_chunk, url=url, page=page)
            finally:
                if task is not None:
                    progress.remove_task(task)
        received += got
        size = start + got
        if total is not None and size > total:
            part.unlink()
            raise CadeError(f"download of {url} gave {size} bytes, more than the announced {total}; run again")
        if total is not None and size != total:
            raise CadeError(
                f"download of {url} stopped at {size} of {total} bytes; check your connection and run again "
                f"(the partial download {part} is kept for resuming)"
            )
        os.replace(part, path)
        return received
    raise CadeError(f"{url} did not honour the resume request twice; delete {part} and run again")


def _stream(
    response, part: Path, mode: str, *, start: int, on_chunk: Callable[[int], object] | None, url: str, page: str
) -> int:
    """Copy ``response`` onto ``part`` (``mode`` "wb" or "ab") chunk by chunk; returns the bytes received.

    ``on_chunk(size of part)`` follows each chunk. Read failures become the network
    :class:`CadeError` (what arrived stays in ``part``); write failures name the file.
    """
    got = 0
    try:
        out = open(part, mode)
    except OSError as error:
        raise CadeError(
            f"cannot write {part}: {error.strerror or error}; check permissions or choose another --to"
        ) from None
    with out:
        while True:
            try:
                chunk = response.read(CHUNK_BYTES)
            except (http.client.HTTPException, OSError) as error:  # timeouts, resets, TLS errors
                out.close()
                raise _network_error(url, error, part, page) from None
            if not chunk:
                return got
            try:
                out.write(chunk)
            except OSError as error:
                raise CadeError(
                    f"cannot write {part}: {error.strerror or error}; free some space or choose another --to"
                ) from None
            got += len(chunk)
            if on_chunk is not None:
                on_chunk(start + got)


def _network_error(url: str, error: BaseException, part: Path, page: str) -> CadeError:
    kept = f"; the partial download {part} is kept for resuming" if part.is_file() and part.stat().st_size else ""
    if isinstance(error, urllib.error.HTTPError):
        reason = f"HTTP {error.code} {error.reason}"
        if 400 <= error.code < 500 and error.code not in (408, 429):
            return CadeError(f"cannot download {url}: {reason}; the file may have moved, see {page}{kept}")
    elif isinstance(error, urllib.error.URLError):
        reason = str(error.reason)
    else:
        reason = str(error) or type(error).__name__
    reason = " ".join(reason.split())
    return CadeError(f"cannot download {url}: {reason}; check your connection and try again{kept}")


# --- integrity and extraction -----------------------------------------------------------


