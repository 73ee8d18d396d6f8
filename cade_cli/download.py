"""Fetch the benchmark datasets from their official hosts into the layouts the readers expect.

One registry, :data:`SOURCES`: dataset name -> :class:`DatasetSource` (the same names as
:data:`cade_cli.datasets.DATASETS`). :func:`download_dataset` fetches each archive of a
source into ``<to>/.downloads/`` (resuming a ``.part`` left by an interrupted run with an
HTTP ``Range`` request), checks it (sha256 where known, then a full read of the archive),
extracts it safely (no absolute or ``..`` member may escape) into a temporary folder and
moves the files into ``<to>/<source.folder>``, where the reader finds them with
``--data-dir <to>``. Then it checks that the files the archive must hold are there.

Archives whose files are already in place are not fetched again; a run over a complete
dataset touches no network. The library never prints: pass a ``rich.progress.Progress``
(see :func:`download_progress`) to see the transfers.
"""

from __future__ import annotations

import http.client
import os
import re
import secrets
import shutil
import tarfile
import urllib.error
import urllib.request
import zipfile
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from functools import partial
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from cade_cli import __version__
from cade_cli.checksum import CHUNK_BYTES, file_sha256
from cade_cli.errors import CadeError, lookup

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress

BASE_URL_ENV = "CADE_DOWNLOAD_BASE_URL"
"""Environment variable that replaces the scheme, host (and a path prefix) of every URL: a mirror."""

DOWNLOADS_FOLDER = ".downloads"
"""Subfolder of the target where archives, ``.part`` files and extraction scratch live."""

TIMEOUT_S = 60.0
"""Seconds without an answer or a byte before a transfer counts as failed."""

RESOLUTIONS: tuple[str, ...] = ("Q", "H", "F")
"""What ``--resolution`` accepts: quarter, half, full (Middlebury 2005/2006: Q = ThirdSize)."""

_MIDDLEBURY_2VIEW_SIZE = {"Q": "ThirdSize", "H": "HalfSize", "F": "FullSize"}


@dataclass(frozen=True)
class Expected:
    """Files an archive must leave in the dataset folder.

    Attributes:
        pattern: path relative to the dataset folder, glob characters allowed.
        at_least: how many files must match.
    """

    pattern: str
    at_least: int = 1


@dataclass(frozen=True)
class Archive:
    """One file to fetch and unpack.

    Attributes:
        url: official address.
        filename: local name in ``<to>/.downloads/`` (unique within a source, resolution
            included, so that a ``.part`` is never resumed from another file).
        expected: what must exist in the dataset folder after extraction.
        strip: leading folder of the members removed on extraction when every member
            has it (``"MiddEval3/"``); an archive without it extracts unchanged.
        into: subfolder of the dataset folder to extract into (``"Art"``).
        sha256: hex digest where known; None: checked by reading the archive through.
    """

    url: str
    filename: str
    expected: tuple[Expected, ...]
    strip: str = ""
    into: str = ""
    sha256: str | None = None


ArchiveBuilder = Callable[["str | None", "Sequence[str]"], "tuple[Archive, ...]"]


@dataclass(frozen=True)
class DatasetSource:
    """Where one dataset comes from and where it goes.

    Attributes:
        name: registry key, as in :data:`cade_cli.datasets.DATASETS`.
        contents: what a download holds, one line.
        page: the dataset's official page.
        source: the archive URL(s), braces for the variants.
        folder: subfolder of the target, one the reader looks in.
        sizes: approximate download size per resolution (key ``""`` without resolutions).
        build: ``(resolution, scenes) -> archives``.
        resolutions: accepted ``resolution`` values (empty: none).
        default_resolution: used when none is given.
        scenes: the scenes that come as separate archives (empty: one bundle).
        refusal: why this dataset cannot be downloaded here (None: it can).
    """

    name: str
    contents: str
    page: str
    source: str
    folder: str
    sizes: dict[str, str]
    build: ArchiveBuilder | None = None
    resolutions: tuple[str, ...] = ()
    default_resolution: str | None = None
    scenes: tuple[str, ...] = ()
    refusal: str | None = None

    def archives(self, resolution: str | None = None, scenes: Sequence[str] | None = None) -> tuple[Archive, ...]:
        """The archives for ``resolution`` (default: :attr:`default_resolution`) and ``scenes`` (default: all).

        Raises:
            CadeError: a refused dataset, a resolution or scene this source does not offer.
        """
        if self.refusal is not None or self.build is None:
            raise CadeError(self.refusal or f"{self.name} cannot be downloaded by cade; see {self.page}")
        if resolution is None:
            resolution = self.default_resolution
        elif not self.resolutions:
            raise CadeError(f"{self.name} comes in one resolution only; drop --resolution")
        elif resolution not in self.resolutions:
            raise CadeError(f"{self.name} has no resolution {resolution!r}; use one of {', '.join(self.resolutions)}")
        if scenes is None:
            chosen: tuple[str, ...] = self.scenes
        elif not self.scenes:
            raise CadeError(f"{self.name} comes as one archive holding every scene; do not pick scenes")
        else:
            chosen = tuple(dict.fromkeys(scenes))
            unknown = [scene for scene in chosen if scene not in self.scenes]
            if unknown or not chosen:
                raise CadeError(
                    f"{self.name} has no downloadable scene(s) {', '.join(unknown) or '(none given)'}; "
                    f"choose from {', '.join(self.scenes)}"
                )
        return self.build(resolution, chosen)


@dataclass(frozen=True)
class DownloadReport:
    """What :func:`download_dataset` did.

    Attributes:
        name: dataset.
        resolution: the resolution fetched (None for datasets without one).
        folder: where the data lies now (``<to>/<source.folder>``).
        downloaded: archives fetched over the network (file names).
        extracted: archives unpacked in this run (downloaded or found complete on disk).
        present: archives whose files were already in place (nothing done).
        bytes_downloaded: bytes received in this run (a resumed file counts only the rest).
    """

    name: str
    resolution: str | None
    folder: Path
    downloaded: tuple[str, ...] = ()
    extracted: tuple[str, ...] = ()
    present: tuple[str, ...] = ()
    bytes_downloaded: int = 0

    @property
    def already_present(self) -> bool:
        """True when nothing had to be fetched or unpacked."""
        return not self.downloaded and not self.extracted


# --- the registry -----------------------------------------------------------------------

MIDDLEBURY_HOST = "https://vision.middlebury.edu"
KITTI_HOST = "https://s3.eu-central-1.amazonaws.com/avg-kitti"

MIDDLEBURY14_TRAINING: tuple[str, ...] = (
    "Adirondack", "ArtL", "Jadeplant", "Motorcycle", "MotorcycleE", "Piano", "PianoL", "Pipes",
    "Playroom", "Playtable", "PlaytableP", "Recycle", "Shelves", "Teddy", "Vintage",
)
"""The 15 MiddEval3 training scenes (the ones with public GT)."""

MIDDLEBURY05_SCENES: tuple[str, ...] = ("Art", "Books", "Dolls", "Laundry", "Moebius", "Reindeer")
"""The 2005 scenes with public GT; Computer, Drumsticks and Dwarves have none and are not fetched."""

MIDDLEBURY05_WITHOUT_GT: tuple[str, ...] = ("Computer", "Drumsticks", "Dwarves")

MIDDLEBURY06_SCENES: tuple[str, ...] = (
    "Aloe", "Baby1", "Baby2", "Baby3", "Bowling1", "Bowling2", "Cloth1", "Cloth2", "Cloth3", "Cloth4",
    "Flowerpots", "Lampshade1", "Lampshade2", "Midd1", "Midd2", "Monopoly", "Plastic", "Rocks1", "Rocks2",
    "Wood1", "Wood2",
)


def _middlebury14_archives(resolution: str | None, scenes: Sequence[str]) -> tuple[Archive, ...]:
    """MiddEval3 images (training + test) and GT0 (left GT, non-occluded mask) of one resolution."""
    training = f"training{resolution}"

    def expected(*names: str) -> tuple[Expected, ...]:
        return tuple(Expected(f"{training}/{scene}/{name}") for scene in MIDDLEBURY14_TRAINING for name in names)

    return tuple(
        Archive(
            url=f"{MIDDLEBURY_HOST}/stereo/submit3/zip/MiddEval3-{part}-{resolution}.zip",
            filename=f"MiddEval3-{part}-{resolution}.zip",
            expected=expected(*names),
            strip="MiddEval3/",
        )
        for part, names in (("data", ("im0.png", "im1.png", "calib.txt")), ("GT0", ("disp0GT.pfm", "mask0nocc.png")))
    )


def _middlebury_2view_archives(year: int, resolution: str | None, scenes: Sequence[str]) -> tuple[Archive, ...]:
    """One ``<Scene>-2views.zip`` per scene: ``<Scene>/{view1,view5,disp1,disp5}.png``."""
    size = _MIDDLEBURY_2VIEW_SIZE[resolution or "Q"]
    names = ("view1.png", "view5.png", "disp1.png", "disp5.png")
    return tuple(
        Archive(
            url=f"{MIDDLEBURY_HOST}/stereo/data/scenes{year}/{size}/zip-2views/{scene}-2views.zip",
            filename=f"{scene}-2views-{size}.zip",
            expected=tuple(Expected(f"{scene}/{name}") for name in names),
            strip=f"{scene}/",
            into=scene,
        )
        for scene in scenes
    )


def _kitti_archive(filename: str, folders: tuple[str, ...], frames: int) -> ArchiveBuilder:
    """One bundle with ``training/<folder>/NNNNNN_10.png`` for each of ``folders``."""

    def build(resolution: str | None, scenes: Sequence[str]) -> tuple[Archive, ...]:
        expected = tuple(Expected(f"training/{folder}/*_10.png", frames) for folder in folders)
        return (Archive(url=f"{KITTI_HOST}/{filename}", filename=filename, expected=expected,
                        strip=f"{filename.removesuffix('.zip')}/"),)

    return build


_FLYINGTHINGS3D_PAGE = "https://lmb.informatik.uni-freiburg.de/resources/datasets/SceneFlowDatasets.en.html"

SOURCES: dict[str, DatasetSource] = {
    "middlebury05": DatasetSource(
        "middlebury05",
        f"2005 scenes with GT ({', '.join(MIDDLEBURY05_SCENES)}): view1/view5 + disp1/disp5, one zip per scene",
        "https://vision.middlebury.edu/stereo/data/scenes2005/",
        f"{MIDDLEBURY_HOST}/stereo/data/scenes2005/{{ThirdSize,HalfSize,FullSize}}/zip-2views/<Scene>-2views.zip",
        "middlebury2005",
        {"Q": "~10 MB", "H": "~30 MB", "F": "~100 MB"},
        partial(_middlebury_2view_archives, 2005),
        RESOLUTIONS, "Q", MIDDLEBURY05_SCENES,
    ),
    "middlebury06": DatasetSource(
        "middlebury06",
        "21 scenes from 2006: view1/view5 + disp1/disp5, one zip per scene",
        "https://vision.middlebury.edu/stereo/data/scenes2006/",
        f"{MIDDLEBURY_HOST}/stereo/data/scenes2006/{{ThirdSize,HalfSize,FullSize}}/zip-2views/<Scene>-2views.zip",
        "middlebury2006",
        {"Q": "~25 MB", "H": "~80 MB", "F": "~300 MB"},
        partial(_middlebury_2view_archives, 2006),
        RESOLUTIONS, "Q", MIDDLEBURY06_SCENES,
    ),
    "middlebury14": DatasetSource(
        "middlebury14",
        "MiddEval3 v3 images (15 training + 15 test pairs, calib.txt) and training GT0 (disp0GT.pfm, mask0nocc.png)",
        "https://vision.middlebury.edu/stereo/submit3/",
        f"{MIDDLEBURY_HOST}/stereo/submit3/zip/MiddEval3-{{data,GT0}}-{{Q,H,F}}.zip",
        "middlebury2014",
        {"Q": "~60 MB", "H": "~200 MB", "F": "~750 MB"},
        _middlebury14_archives, RESOLUTIONS, "Q",
    ),
    "kitti2012": DatasetSource(
        "kitti2012",
        "KITTI stereo/flow 2012: 194 training pairs with GT (colored_0/1, disp_occ, disp_noc) and 195 test pairs",
        "https://www.cvlibs.net/datasets/kitti/eval_stereo_flow.php?benchmark=stereo",
        f"{KITTI_HOST}/data_stereo_flow.zip",
        "kitti/2012",
        {"": "~2 GB"},
        _kitti_archive("data_stereo_flow.zip", ("colored_0", "colored_1", "disp_occ", "disp_noc"), 194),
    ),
    "kitti2015": DatasetSource(
        "kitti2015",
        "KITTI scene flow 2015: 200 training pairs with GT (image_2/3, disp_occ_0, disp_noc_0) and 200 test pairs",
        "https://www.cvlibs.net/datasets/kitti/eval_scene_flow.php?benchmark=stereo",
        f"{KITTI_HOST}/data_scene_flow.zip",
        "kitti/2015",
        {"": "~1.7 GB"},
        _kitti_archive("data_scene_flow.zip", ("image_2", "image_3", "disp_occ_0", "disp_noc_0"), 200),
    ),
    "flyingthings3d": DatasetSource(
        "flyingthings3d",
        "synthetic SceneFlow subset (frames_cleanpass + disparity); not downloadable with cade",
        _FLYINGTHINGS3D_PAGE,
        _FLYINGTHINGS3D_PAGE,
        "flyingthings3d",
        {"": "hundreds of GB"},
        refusal=(
            "flyingthings3d is not downloadable with cade: its official archives are hundreds of GB "
            "(cleanpass images and disparity alone are well over 100 GB) and cannot be fetched piecemeal; "
            f"get them from {_FLYINGTHINGS3D_PAGE} and unpack into <DIR>/flyingthings3d"
        ),
    ),
}
"""Dataset name -> where to fetch it. URLs are the official hosts; sha256 digests are unknown (None)."""


def get_source(name: str) -> DatasetSource:
    """The source registered as ``name``.

    Raises:
        CadeError: unknown name; the message lists the choices.
    """
    return lookup(SOURCES, name, kind="dataset download")


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
    """A rich progress display for :func:`download_dataset`: file name, bar, bytes, speed, ETA."""
    from rich.progress import (BarColumn, DownloadColumn, Progress, TextColumn, TimeRemainingColumn,
                               TransferSpeedColumn)

    return Progress(
        TextColumn("{task.description}"), BarColumn(), DownloadColumn(), TransferSpeedColumn(), TimeRemainingColumn(),
        console=console, transient=True,
    )


# --- download ---------------------------------------------------------------------------

def download_dataset(
    name: str,
    to: Path,
    *,
    resolution: str | None = None,
    scenes: Sequence[str] | None = None,
    force: bool = False,
    progress: Progress | None = None,
    base_url: str | None = None,
    keep_archives: bool = False,
) -> DownloadReport:
    """Fetch dataset ``name`` into ``to`` so that its reader finds it with ``--data-dir to``.

    Args:
        name: a key of :data:`SOURCES`.
        to: target folder; created if missing (its parent must exist).
        resolution: ``"Q"``, ``"H"`` or ``"F"`` for the Middlebury sets (2005/2006: Q =
            ThirdSize); None for the source's default (the smallest) or for KITTI.
        scenes: for per-scene sources (Middlebury 2005/2006), fetch only these.
        force: fetch and unpack again even when the files are in place.
        progress: a ``rich.progress.Progress`` to report transfers to (one task per file).
        base_url: mirror replacing scheme and host of every URL (tests, local mirrors);
            default: the ``CADE_DOWNLOAD_BASE_URL`` environment variable, else the official hosts.
        keep_archives: keep the archives in ``to/.downloads`` after unpacking.

    Returns:
        A :class:`DownloadReport`.

    Raises:
        CadeError: unknown or refused dataset, bad resolution or scene, network failure
            (the ``.part`` file is kept for resuming), corrupt archive (deleted), unsafe
            archive member, files missing after extraction.
    """
    source = get_source(name)
    archives = source.archives(resolution, scenes)
    resolution = resolution if resolution is not None else source.default_resolution
    base_url = base_url if base_url is not None else os.environ.get(BASE_URL_ENV) or None
    urls = [mirror_url(archive.url, base_url) for archive in archives]
    to = Path(to)
    if to.exists() and not to.is_dir():
        raise CadeError(f"download target {to} is not a folder; give a folder with --to")
    if not to.parent.is_dir():
        raise CadeError(f"parent of download target {to} does not exist; create it first")
    folder = to / source.folder
    downloads = to / DOWNLOADS_FOLDER
    downloaded: list[str] = []
    extracted: list[str] = []
    present: list[str] = []
    received = 0
    for archive, url in zip(archives, urls):
        if not force and not _missing(folder, archive.expected):
            present.append(archive.filename)
            continue
        downloads.mkdir(parents=True, exist_ok=True)
        path = downloads / archive.filename
        part = _part(path)
        if force:
            path.unlink(missing_ok=True)
            part.unlink(missing_ok=True)
        if not (path.is_file() and _is_intact(path, archive.sha256)):  # else: a complete earlier download
            path.unlink(missing_ok=True)
            received += _fetch(url, path, progress=progress, page=source.page)
            downloaded.append(archive.filename)
            _check_intact(path, archive.sha256)
        _extract(path, folder, strip=archive.strip, into=archive.into, scratch=downloads)
        extracted.append(archive.filename)
        missing = _missing(folder, archive.expected)
        if missing:
            shown = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
            raise CadeError(
                f"{archive.filename} did not provide {shown} in {folder}; the official archive may have changed, "
                f"see {source.page}"
            )
        if not keep_archives:
            path.unlink(missing_ok=True)
    if downloads.is_dir() and not any(downloads.iterdir()):
        downloads.rmdir()
    return DownloadReport(
        name=name, resolution=resolution if source.resolutions else None, folder=folder,
        downloaded=tuple(downloaded), extracted=tuple(extracted), present=tuple(present), bytes_downloaded=received,
    )


def _part(path: Path) -> Path:
    return path.with_name(path.name + ".part")


def _missing(folder: Path, expected: Sequence[Expected]) -> list[str]:
    """Patterns of ``expected`` with fewer matches under ``folder`` than required."""
    missing = []
    for item in expected:
        if any(char in item.pattern for char in "*?["):
            count = sum(1 for path in folder.glob(item.pattern) if path.is_file()) if folder.is_dir() else 0
            if count < item.at_least:
                missing.append(f"{item.pattern} ({count} of {item.at_least})")
        elif not (folder / item.pattern).is_file():
            missing.append(item.pattern)
    return missing


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

_TAR_SUFFIXES = (".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")


def _kind(path: Path) -> str:
    name = path.name.lower()
    if name.endswith(".zip"):
        return "zip"
    if name.endswith(_TAR_SUFFIXES):
        return "tar"
    raise CadeError(f"{path.name} is neither a zip nor a tar archive; cade cannot unpack it")


def _corruption(path: Path, sha256: str | None) -> str | None:
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


def _is_intact(path: Path, sha256: str | None) -> bool:
    return _corruption(path, sha256) is None


def _check_intact(path: Path, sha256: str | None) -> None:
    """Delete ``path`` and raise when it is not a sound archive."""
    problem = _corruption(path, sha256)
    if problem is not None:
        path.unlink(missing_ok=True)
        raise CadeError(f"archive {path.name} is corrupt ({problem}); it was deleted, run again to re-download")


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


def _extract(path: Path, folder: Path, *, strip: str, into: str, scratch: Path) -> None:
    """Unpack ``path`` into ``folder/into`` through a scratch folder, merging with what is there.

    Every member name is checked before anything is written; ``strip`` is removed from
    the names when all of them start with it. Files are moved into place only once the
    whole archive is unpacked, so a damaged or unsafe archive adds nothing to ``folder``.
    """
    with ExitStack() as stack:
        try:
            members = _members(path, stack)
        except CadeError:
            stack.close()
            path.unlink(missing_ok=True)
            raise
        _unpack(path, members, folder, strip=strip, into=into, scratch=scratch)


def _unpack(path: Path, members: list, folder: Path, *, strip: str, into: str, scratch: Path) -> None:
    prefix = PurePosixPath(strip.strip("/")) if strip.strip("/") else None
    if prefix is not None and members and all(name.parts[: len(prefix.parts)] == prefix.parts for name, _ in members):
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
        destination = folder / into if into else folder
        for file in sorted(p for p in temporary.rglob("*") if p.is_file()):
            final = destination / file.relative_to(temporary)
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(file, final)
    except OSError as error:
        raise CadeError(f"cannot unpack {path.name} into {folder}: {error.strerror or error}; "
                        "free some space or choose another --to") from None
    finally:
        shutil.rmtree(temporary, ignore_errors=True)
