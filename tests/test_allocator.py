"""cade_cli.allocator: glibc keeps freed memory for the next temporary array."""

from __future__ import annotations

import platform

import pytest

from cade_cli import allocator, cli

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


@pytest.mark.skipif(not GLIBC, reason="the thresholds are glibc's")
def test_thresholds_are_set_on_glibc():
    assert allocator.retain_freed_memory() is True
    assert allocator.retain_freed_memory() is True  # once per process; later calls are free


@pytest.mark.skipif(GLIBC, reason="a no-op only where the C library is not glibc")
def test_no_op_elsewhere():
    assert allocator.retain_freed_memory() is False


def test_the_command_sets_them_before_it_runs(monkeypatch, capsys):
    calls = []
    monkeypatch.setattr(allocator, "retain_freed_memory", lambda: calls.append(True))
    with pytest.raises(SystemExit):
        cli.main(["--version"])
    assert calls == [True] and capsys.readouterr().out.startswith("cade ")
