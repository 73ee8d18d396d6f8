"""The registry, :data:`DATASETS`: dataset name -> :class:`Dataset`, and :func:`download_dataset`.

A download lands in ``<to>/<source.folder>``, a folder the reader searches, so that
``--data-dir <to>`` finds it; archives whose files are already in place are not fetched
again. The library never prints: pass a ``rich.progress.Progress`` (see
:func:`download_progress`) to see the transfers.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cade_cli.data.dataset import Dataset, DatasetSource
from cade_cli.data.fetch import BASE_URL_ENV, install, mirror_url
from cade_cli.data.flyingthings3d import FLYINGTHINGS3D
from cade_cli.data.folder import FOLDER
from cade_cli.data.kitti import KITTI2012, KITTI2015
from cade_cli.data.middlebury import MIDDEVAL3, MIDDLEBURY05, MIDDLEBURY06, MIDDLEBURY14
from cade_cli.data.msir import MSIR_OUTDOOR
from cade_cli.errors import CadeError, lookup
from cade_cli.io.atomic import check_writable_folder

if TYPE_CHECKING:
    from rich.progress import Progress

DATASETS: dict[str, Dataset] = {
    dataset.name: dataset
    for dataset in (MIDDLEBURY05, MIDDLEBURY06, MIDDLEBURY14, MIDDEVAL3, KITTI2012, KITTI2015, FLYINGTHINGS3D,
                    MSIR_OUTDOOR, FOLDER)
}
"""Dataset name -> reader and source."""

SOURCES: dict[str, DatasetSource] = {name: d.download for name, d in DATASETS.items() if d.download is not None}
"""Dataset name -> where to fetch it, for the datasets that have one. URLs are the official hosts;
sha256 digests are unknown (None)."""

DOWNLOADS_FOLDER = ".downloads"
"""Subfolder of the target where archives, ``.part`` files and extraction scratch live."""


def get_dataset(name: str) -> Dataset:
    """The dataset registered as ``name``.

    Raises:
        CadeError: unknown name; the message lists the choices.
    """
    return lookup(DATASETS, name, kind="dataset")


def get_source(name: str) -> DatasetSource:
    """The source of the dataset registered as ``name``.

    Raises:
        CadeError: unknown name or a dataset with no source; the message lists the choices.
    """
    return lookup(SOURCES, name, kind="dataset download")


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
        CadeError: unknown or refused dataset, bad resolution or scene, and what
            :func:`~cade_cli.data.fetch.install` raises.
    """
    source = get_source(name)
    archives = source.archives(resolution, scenes)
    base_url = base_url if base_url is not None else os.environ.get(BASE_URL_ENV) or None
    urls = [mirror_url(archive.url, base_url) for archive in archives]
    to = Path(to)
    if to.exists() and not to.is_dir():
        raise CadeError(f"download target {to} is not a folder; give a folder with --to")
    check_writable_folder(to)  # before any transfer: a folder we cannot create or fill is refused at once
    folder, downloads = to / source.folder, to / DOWNLOADS_FOLDER
    done: dict[str, list[str]] = {"present": [], "extracted": [], "downloaded": []}
    received = 0
    for archive, url in zip(archives, urls):
        what, got = install(archive, folder, url=url, scratch=downloads, page=source.page, force=force,
                            keep_archive=keep_archives, progress=progress)
        done[what].append(archive.filename)
        if what == "downloaded":
            done["extracted"].append(archive.filename)
        received += got
    if downloads.is_dir() and not any(downloads.iterdir()):
        downloads.rmdir()
    return DownloadReport(
        name=name, resolution=resolution or source.default_resolution, folder=folder,
        downloaded=tuple(done["downloaded"]), extracted=tuple(done["extracted"]), present=tuple(done["present"]),
        bytes_downloaded=received,
    )
