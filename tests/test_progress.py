"""Progress without a terminal: long commands print a plain line every few seconds (task i of n,
elapsed); a note that repeats for every pair is printed once per run, with its count."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from cade_cli.cli import options
from cli_runner import run_cade
from synthetic import render_pair

PROGRESS = re.compile(r": (\d+) of (\d+) (\w+) done, \d+ min \d\d s$")


@pytest.fixture
def every_20_ms(monkeypatch):
    """The plain progress line every 20 ms instead of every 10 s, so that short runs show it."""
    monkeypatch.setattr(options, "PLAIN_PROGRESS_SECONDS", 0.02)


def progress_lines(stderr: str) -> list[re.Match]:
    return [match for line in stderr.splitlines() if (match := PROGRESS.search(line))]


def test_a_step_bar_without_a_terminal_prints_plain_lines_while_it_runs(every_20_ms, capsys):
    with options.StepBar(4, "benchmark x", plain=True, noun="tasks") as bar:
        bar.advance("benchmark x scene1")
        time.sleep(0.2)  # no step ends meanwhile: the lines still come
    lines = progress_lines(capsys.readouterr().err)
    assert len(lines) >= 2
    assert all(line.group(1, 2, 3) == ("1", "4", "tasks") for line in lines)


def test_a_short_command_s_bar_prints_nothing_without_a_terminal(every_20_ms, capsys):
    with options.StepBar(3, "checking the pair") as bar:  # not plain: disparity, register, rectify
        bar.advance()
        time.sleep(0.1)
    assert capsys.readouterr().err == ""


def test_the_plain_line_waits_for_its_interval(capsys):
    """At the default interval a run shorter than it prints no progress line at all."""
    assert options.PLAIN_PROGRESS_SECONDS == pytest.approx(10.0)
    with options.StepBar(2, "benchmark y", plain=True) as bar:
        bar.advance()
    assert progress_lines(capsys.readouterr().err) == []


def test_benchmark_logs_its_tasks_as_it_goes(folder_dataset, tmp_path, every_20_ms, capsys, monkeypatch):
    advance = options.StepBar.advance

    def slow_advance(bar, *args, **kwargs):  # each matcher run takes 50 ms: warm, the tiny runs take less
        time.sleep(0.05)
        return advance(bar, *args, **kwargs)

    monkeypatch.setattr(options.StepBar, "advance", slow_advance)
    code, _, stderr = run_cade(["benchmark", "-d", "folder", "--data-dir", folder_dataset, "--methods", "sgbm",
                                "--protocol", "cs", "--preprocess", "none"], capsys)
    assert code == 0
    lines = progress_lines(stderr)
    assert lines and all(line.group(3) == "tasks" for line in lines)
    done = [int(line.group(1)) for line in lines]
    assert done == sorted(done) and int(lines[-1].group(2)) >= done[-1]


def test_batch_logs_its_pairs_and_says_a_repeated_note_once_with_its_count(tmp_path, rng, every_20_ms, capsys,
                                                                           monkeypatch):
    import cade_cli.batch.engines

    attempt = cade_cli.batch.engines._attempt

    def slow_attempt(pair):  # each pair takes 50 ms more (one job: pairs run in this process)
        time.sleep(0.05)
        return attempt(pair)

    monkeypatch.setattr(cade_cli.batch.engines, "_attempt", slow_attempt)
    for side in ("rgb", "nir"):
        (tmp_path / side).mkdir()
    import cv2

    for index in range(3):
        pair = render_pair(rng, (40, 64), background=(4.0 + index, 0.0))
        colour = np.stack([pair.left, 0.8 * pair.left, 0.5 + 0.5 * pair.left], axis=2)
        cv2.imwrite(str(tmp_path / "rgb" / f"{index}.png"), np.rint(colour * 255).astype(np.uint8))
        cv2.imwrite(str(tmp_path / "nir" / f"{index}.png"), np.rint(pair.right * 255).astype(np.uint8))
    code, _, stderr = run_cade(["batch", "--left", tmp_path / "rgb" / "*.png", "--right", tmp_path / "nir" / "*.png",
                                "-o", tmp_path / "out", "-m", "sgbm", "--max-disp", "16"], capsys)
    assert code == 0
    luminance = [line for line in stderr.splitlines() if "converted to luminance" in line]
    assert len(luminance) == 2  # the note, once; then its count
    assert luminance[0].startswith("note: ") and str(tmp_path / "rgb" / "0.png") in luminance[0]
    assert "3 pairs in this run had the note shown once above" in luminance[1]
    lines = progress_lines(stderr)
    assert lines and all(line.group(2, 3) == ("3", "pairs") for line in lines)
