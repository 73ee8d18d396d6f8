"""atomic_output: all-or-nothing output files."""

from __future__ import annotations

from pathlib import Path

import pytest

from cade_cli.atomic import atomic_output
from cade_cli.errors import CadeError


class Boom(Exception):
    pass


def test_success_moves_temporary_onto_target(tmp_path: Path) -> None:
    target = tmp_path / "out.pfm"
    with atomic_output(target) as temporary:
        assert temporary.parent == target.parent
        assert temporary.name.startswith(".")
        assert temporary.suffix == ".pfm"
        assert temporary != target
        temporary.write_bytes(b"payload")
        assert not target.exists()
    assert target.read_bytes() == b"payload"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.pfm"]


def test_success_replaces_existing_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old")
    with atomic_output(target) as temporary:
        temporary.write_text("new")
    assert target.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_failure_leaves_no_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "out.png"
    with pytest.raises(Boom):
        with atomic_output(target) as temporary:
            temporary.write_bytes(b"half")
            raise Boom
    assert list(tmp_path.iterdir()) == []


def test_failure_does_not_clobber_existing_file(tmp_path: Path) -> None:
    target = tmp_path / "out.png"
    target.write_bytes(b"precious")
    with pytest.raises(Boom):
        with atomic_output(target) as temporary:
            temporary.write_bytes(b"half")
            raise Boom
    assert target.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]


def test_failure_before_anything_is_written(tmp_path: Path) -> None:
    with pytest.raises(Boom):
        with atomic_output(tmp_path / "out.tif"):
            raise Boom
    assert list(tmp_path.iterdir()) == []


def test_temporary_names_are_unique(tmp_path: Path) -> None:
    with atomic_output(tmp_path / "a.npy") as first, atomic_output(tmp_path / "a.npy") as second:
        first.write_bytes(b"1")
        second.write_bytes(b"2")
        assert first != second


def test_missing_parent_directory_is_a_cade_error(tmp_path: Path) -> None:
    target = tmp_path / "missing" / "out.pfm"
    with pytest.raises(CadeError, match="does not exist; create it first"):
        with atomic_output(target):
            pytest.fail("body must not run")
    assert not (tmp_path / "missing").exists()


def test_parent_that_is_a_file_is_a_cade_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    with pytest.raises(CadeError, match="not a directory"):
        with atomic_output(tmp_path / "file" / "out.pfm"):
            pytest.fail("body must not run")


def test_target_that_is_a_directory_is_a_cade_error(tmp_path: Path) -> None:
    (tmp_path / "out.png").mkdir()
    with pytest.raises(CadeError, match="is a directory"):
        with atomic_output(tmp_path / "out.png"):
            pytest.fail("body must not run")
