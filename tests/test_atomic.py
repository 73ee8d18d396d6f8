"""atomic_output and atomic_outputs: all-or-nothing output files."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from cade_cli.io.atomic import (
    atomic_output,
    atomic_outputs,
    check_writable,
    check_writable_folder,
    intended_path,
    temporary_sibling,
)
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


# --- atomic_outputs: several outputs, all or none ---

def test_outputs_appear_together_at_the_end(tmp_path: Path) -> None:
    first, second, folder = tmp_path / "a.pfm", tmp_path / "b.png", tmp_path / "maps"
    with atomic_outputs([first, None, second], folders=[folder]) as staged:
        assert set(staged) == {first, second, folder} and staged[folder].is_dir()
        staged[first].write_bytes(b"1")
        staged[second].write_bytes(b"2")
        (staged[folder] / "sub").mkdir()
        (staged[folder] / "sub" / "x.pfm").write_bytes(b"3")
        assert not first.exists() and not second.exists() and not folder.exists()
    assert first.read_bytes() == b"1" and second.read_bytes() == b"2"
    assert (folder / "sub" / "x.pfm").read_bytes() == b"3"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pfm", "b.png", "maps"]


def test_a_failure_replaces_no_output(tmp_path: Path) -> None:
    first, second, folder = tmp_path / "a.pfm", tmp_path / "b.png", tmp_path / "maps"
    first.write_bytes(b"old")
    folder.mkdir()
    (folder / "kept.txt").write_bytes(b"mine")
    with pytest.raises(Boom):
        with atomic_outputs([first, second], folders=[folder]) as staged:
            staged[first].write_bytes(b"new")
            (staged[folder] / "x.pfm").write_bytes(b"new")
            raise Boom
    assert first.read_bytes() == b"old" and not second.exists()
    assert sorted(p.name for p in folder.iterdir()) == ["kept.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pfm", "maps"]


def test_writers_may_write_their_stand_in_atomically(tmp_path: Path) -> None:
    target = tmp_path / "d.pfm"
    with atomic_outputs([target]) as staged:
        with atomic_output(staged[target]) as temporary:
            temporary.write_bytes(b"x")
    assert target.read_bytes() == b"x" and sorted(p.name for p in tmp_path.iterdir()) == ["d.pfm"]


def test_an_os_error_names_the_users_file(tmp_path: Path) -> None:
    target = tmp_path / "d.pfm"
    with pytest.raises(CadeError, match=r"could not write .*d\.pfm: No space left on device; check free space"):
        with atomic_outputs([target]) as staged:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(staged[target]))
    with pytest.raises(CadeError, match=r"could not write .*d\.pfm"):
        with atomic_output(target) as temporary:
            with atomic_output(temporary) as inner:  # a temporary of a temporary still names d.pfm
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(inner))
    assert list(tmp_path.iterdir()) == []


def test_an_os_error_about_another_file_is_left_alone(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        with atomic_outputs([tmp_path / "d.pfm"]):
            (tmp_path / "missing-input.png").read_bytes()


def test_the_same_output_twice_is_refused(tmp_path: Path) -> None:
    with pytest.raises(CadeError, match="same output"):
        with atomic_outputs([tmp_path / "a.png", tmp_path / "." / "a.png"]):
            pytest.fail("body must not run")


def test_unwritable_outputs_are_refused_before_the_body(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    with pytest.raises(CadeError, match="not a directory"):
        with atomic_outputs([tmp_path / "ok.png", tmp_path / "file" / "out.pfm"]):
            pytest.fail("body must not run")
    with pytest.raises(CadeError, match="is a file, not a folder"):
        with atomic_outputs(folders=[tmp_path / "file"]):
            pytest.fail("body must not run")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_check_writable_tries_to_create_a_file(tmp_path: Path) -> None:
    check_writable(tmp_path / "fine.pfm")
    check_writable_folder(tmp_path / "new")
    check_writable_folder(tmp_path)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(CadeError, match="cannot write /proc/out.pfm: .*choose a folder you can write to"):
        check_writable(Path("/proc/out.pfm"))  # no new file in /proc, even for root
    with pytest.raises(CadeError, match="cannot write /proc"):
        check_writable_folder(Path("/proc"))


def test_intended_path_undoes_temporary_names(tmp_path: Path) -> None:
    target = tmp_path / "disp.tar.gz"
    assert intended_path(temporary_sibling(temporary_sibling(target))) == target
    assert intended_path(tmp_path / ".hidden.png") == tmp_path / ".hidden.png"
