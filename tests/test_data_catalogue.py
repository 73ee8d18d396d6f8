"""One entry per dataset: what the downloader promises is what the reader looks for."""

from __future__ import annotations

from pathlib import PurePosixPath
from urllib.parse import urlsplit

import numpy as np
import pytest

from cade_cli.data import DATASETS, MIDDLEBURY14_TRAINING, SOURCES


def frames(count: int) -> list[str]:
    return [f"{i:06d}_10" for i in range(count)]


PROMISED = {"middlebury14": MIDDLEBURY14_TRAINING, "kitti2015": frames(200), "kitti2012": frames(194)}
"""Scenes of the sources that come as one bundle (per-scene sources list theirs)."""

DOWNLOADABLE = [(name, resolution) for name, source in SOURCES.items() if source.refusal is None
                for resolution in source.resolutions or (None,)]


def expected_files(name: str, resolution: str | None) -> list[PurePosixPath]:
    """Every file the archives promise, ``*`` in a pattern spelt ``000000``, ``000001``... (``at_least`` of them)."""
    files = []
    for archive in SOURCES[name].archives(resolution):
        for item in archive.expected:
            assert not any(char in item.pattern for char in "?["), item.pattern
            copies = [f"{i:06d}" for i in range(item.at_least)] if "*" in item.pattern else [""]
            files += [PurePosixPath(item.pattern.replace("*", copy)) for copy in copies]
    return files


def test_every_source_is_the_download_of_a_dataset_entry():
    for name, source in SOURCES.items():
        dataset = DATASETS[name]
        assert dataset.download is source and source.name == name
        assert source.folder == dataset.subfolders[0]  # a folder its reader searches
        if source.refusal is not None:
            continue
        for resolution in source.resolutions or (None,):
            archives = source.archives(resolution)
            assert len({a.filename for a in archives}) == len(archives)
            for archive in archives:
                assert urlsplit(archive.url).netloc in ("vision.middlebury.edu", "s3.eu-central-1.amazonaws.com")
                assert archive.url.startswith("https://") and archive.expected


@pytest.mark.parametrize(("name", "resolution"), DOWNLOADABLE)
def test_the_promised_files_are_the_scenes_the_reader_lists(tmp_path, name, resolution):
    source, dataset = SOURCES[name], DATASETS[name]
    for file in expected_files(name, resolution):
        path = tmp_path / source.folder / file
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()
    option = resolution if resolution in dataset.resolutions else None
    assert dataset.scene_names(tmp_path, resolution=option) == sorted(source.scenes or PROMISED[name])


@pytest.mark.parametrize("name", [name for name, resolution in DOWNLOADABLE if resolution in (None, "Q")])
def test_the_reader_needs_no_file_beyond_the_promised_ones(shared_data, tmp_path, name):
    """A tree of promised files only, each a link to the development data's file of that
    folder and name where it has one, loads completely."""
    source = SOURCES[name]
    donors = {(path.parent.name, path.name): path for path in (shared_data / source.folder).rglob("*")
              if path.is_file()}
    if not donors:
        pytest.skip(f"no {name} in the development data")
    for file in expected_files(name, source.default_resolution):
        donor = donors.get((file.parent.name, file.name))
        if donor is not None:
            path = tmp_path / source.folder / file
            path.parent.mkdir(parents=True, exist_ok=True)
            path.symlink_to(donor)
    scenes = list(DATASETS[name](tmp_path))
    assert scenes and all(np.isfinite(scene.disparity).any() for scene in scenes)
