"""The benchmark datasets: reading their scenes and fetching them from their official hosts.

One registry, :data:`DATASETS`: name -> :class:`Dataset`. Each entry is built in its
family's module (:mod:`~cade_cli.data.middlebury`, :mod:`~cade_cli.data.kitti`,
:mod:`~cade_cli.data.flyingthings3d`, :mod:`~cade_cli.data.msir`, :mod:`~cade_cli.data.folder`) from one set of layout
constants, which both its reader and its archive list (:class:`DatasetSource`) use.
:mod:`~cade_cli.data.fetch` fetches, resumes, verifies and unpacks archives without
knowing any dataset.
"""

from cade_cli.data.catalogue import (
    DATASETS, DOWNLOADS_FOLDER, SOURCES, DownloadReport, download_dataset, get_dataset, get_source,
)
from cade_cli.data.dataset import Dataset, DatasetSource, Scene, max_disp_from_gt, nonoccluded_mask
from cade_cli.data.fetch import BASE_URL_ENV, Archive, Expected, download_progress, mirror_url
from cade_cli.data.middlebury import MIDDLEBURY14_TRAINING, read_calib

__all__ = [
    "BASE_URL_ENV", "DATASETS", "DOWNLOADS_FOLDER", "MIDDLEBURY14_TRAINING", "SOURCES", "Archive", "Dataset",
    "DatasetSource", "DownloadReport", "Expected", "Scene", "download_dataset", "download_progress", "get_dataset",
    "get_source", "max_disp_from_gt", "mirror_url", "nonoccluded_mask", "read_calib",
]
