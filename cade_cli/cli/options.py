"""Options and checks shared by the commands: the option types, reading a pair, the range and memory
options, output checks, notes and warnings on stderr.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer


METHOD_NAMES = ("census-sgm", "zncc-sgm", "sgbm", "cade", "cade-network", "dasc-sgm")
"""Registered matchers, listed here so that --help needs no heavy import (a test keeps
this in step with :data:`cade_cli.matching.MATCHERS`)."""

BENCHMARK_METHODS = METHOD_NAMES[:4] + ("dasc-sgm",)
"""What ``cade benchmark`` compares by default: the matchers of the paper's Table 1 that we
have (cade-network is cade's first stage, there to analyse the network; name it with --methods)."""

DEFAULT_METHOD = "cade"
"""The default matcher, here so that --help needs no heavy import (a test keeps it equal
to :data:`cade_cli.stereo.DEFAULT_METHOD`)."""

MethodOption = Annotated[
    str,
    typer.Option(
        "--method",
        "-m",
        help=f"Matcher: {', '.join(METHOD_NAMES)}. The default, cade (the CADE network), is the most accurate "
        "on cross-spectral pairs in the project's benchmarks, and faster than census-sgm; census-sgm keeps thin "
        "structures better (figures: docs/research/evaluation.md).",
    ),
]

MaxDispAutoOption = Annotated[
    Optional[str],
    typer.Option("--max-disp", help="Largest disparity searched, px (at least --min-disp; 0 or below for a pair seen "
                 "entirely behind its plane), or 'auto': estimated from a coarse match of the pair, with a margin "
                 "(docs/scale.md). Default: a quarter of the width."),
]

MinDispAutoOption = Annotated[
    str, typer.Option("--min-disp", help="Smallest disparity searched, px (negative for pairs registered to a plane), "
                      "or 'auto': estimated like --max-disp auto, and possibly negative.")
]

ModelOption = Annotated[
    Optional[str],
    typer.Option("--model", help="Network of the learned methods: a tier, fast (the default: cade-v13, "
                 "models/cade-v13.md) or accurate (cade-v13-accurate-synthetic: the same network with a second pass on the "
                 "pair enlarged 1.5x, a chooser that sees around each pixel and depth edges put where the image has "
                 "them, about three times the time), a shipped card's name (cade-v13, cade-v13-accurate-synthetic, "
                 "cade-v13-accurate-context, cade-v13-accurate-edges, cade-v13-accurate, cade-v4; older models are retired, docs/research/models.md), the path of a "
                 "model card (.json, its ONNX files beside it, as `python -m cade_cli.train export` writes them) or "
                 "a card name in the model folder ($CADE_MODEL_DIR, default the shipped models/)."),
]

MemoryLimitOption = Annotated[
    Optional[str],
    typer.Option("--memory-limit", help="Memory budget, like 4GB or 512MB (default: half the memory available). A "
                 "pair that does not fit it whole is matched as overlapping tiles, each with a range seeded from a "
                 "coarse pass (docs/scale.md, \"Tiling\").", show_default=False),
]

PreprocessOption = Annotated[
    str,
    typer.Option(
        "--preprocess",
        help="'cade' (color agnostic transform on both bands), 'none', or 'auto': the matcher's more "
        "accurate choice on cross-spectral pairs (census-sgm, zncc-sgm: none; sgbm, cade: cade).",
    ),
]

VisRangeOption = Annotated[
    Optional[str],
    typer.Option("--vis-range", help="With --vis: disparities MIN:MAX (px, e.g. 0:80) given the two end colours of "
                 "the picture, values beyond clipped to them, so that pictures of two runs compare (default: the "
                 "1st-99th percentile of the map's valid disparities).", show_default=False),
]


def band_option(side: str) -> object:
    return typer.Option(f"--{side}-band", min=0, help=f"0-based band of a multi-band {side} file (default: luminance of colour images).")


def report_misalignment(found, width: int, *, fixed: bool, corrected: bool) -> None:
    """Tell the user what the rectification self-check measured (a warning above the tolerance)."""
    import math

    from cade_cli.rigs.self_check import MIN_CORRECTION_PX, VERTICAL_TOLERANCE_PX

    worst = found.worst(width)
    measured = (f"offset {found.offset:+.2f} px, roll {math.degrees(found.roll):+.3f} deg (up to {worst:.2f} px at "
                f"the edges), from {found.matches} matches")
    if corrected:
        print_note(f"rectification self-check: {measured}; corrected (--fix-vertical)")
    elif fixed:
        print_note(f"rectification self-check: {measured}; below {MIN_CORRECTION_PX} px, left as is (--fix-vertical)")
    elif worst > VERTICAL_TOLERANCE_PX:
        print_warning(f"rectification self-check: vertical misalignment {measured}, above {VERTICAL_TOLERANCE_PX} px; "
              "add --fix-vertical or recalibrate")
    else:
        print_note(f"rectification self-check: {measured}")


def read_pair(
    left: Path, right: Path, left_band: int | None, right_band: int | None,
    names: tuple[str, str] = ("--left-band", "--right-band"),
):
    from cade_cli.io.images import read_band

    images = []
    for path, band, option in ((left, left_band, names[0]), (right, right_band, names[1])):
        image, note = read_band(path, band)
        if note:
            print_note(f"{note}; pick a band with {option} N")
        images.append(image)
    return images


def warn_if_textureless(left: Path, right: Path, left_image, right_image) -> None:
    """Warn when much of the pair is flat (:func:`cade_cli.stereo.textureless`): no disparity there."""
    from cade_cli.stereo import TEXTURE_WINDOW, textureless

    flat = textureless(left_image) | textureless(right_image)
    share = float(flat.mean())
    if share == 1.0:
        print_warning(f"{left} and {right} have no texture at all (constant images?): there is no disparity to find and "
              "every pixel is marked invalid; check that these are the right, correctly exposed images")
    elif share >= 0.5:
        print_warning(f"{100 * share:.0f}% of {left} / {right} is flat (one value over {TEXTURE_WINDOW}x{TEXTURE_WINDOW} px "
              "in a band: blank, saturated or underexposed); disparity there is marked invalid")


def resolve_max_disp(max_disp: int | None, width: int) -> int:
    """``max_disp``, or when not given the library's default for ``width``
    (:func:`cade_cli.stereo.default_max_disparity`), announced on stderr."""
    from cade_cli.stereo import default_max_disparity

    if max_disp is not None:
        return max_disp
    chosen = default_max_disparity(width)
    print_note(f"--max-disp not given: searching up to {chosen} px (a quarter of the width); "
               "set it to your scene's largest disparity for speed and accuracy")
    return chosen


def parse_range_options(min_disp: str | int, max_disp: str | int | None) -> tuple[int | str, int | str | None]:
    """--min-disp and --max-disp as given: whole pixels or 'auto' (:func:`cade_cli.scale.range.parse_bound`);
    any range with max > min, below zero included (:func:`cade_cli.scale.range.check_bounds`)."""
    from cade_cli.scale.range import check_bounds, parse_bound

    low = parse_bound(min_disp, option="min-disp")
    high = None if max_disp is None else parse_bound(max_disp, option="max-disp")
    check_bounds(low, high)
    return low, high


def resolve_range_options(min_disp: int | str, max_disp: int | str | None, left_image, right_image) -> tuple[int, int]:
    """The searched (min, max), px, as the library resolves it (:func:`cade_cli.scale.range.resolve_range`:
    'auto' bounds estimated, a missing --max-disp defaulted), with what was chosen announced on stderr."""
    from cade_cli.scale.range import AUTO, resolve_range

    searched, estimate = resolve_range(left_image, right_image, min_disp=min_disp, max_disp=max_disp)
    if estimate is not None:
        print_note(estimate.describe(estimated=(min_disp == AUTO, max_disp == AUTO)))
    elif max_disp is None:
        resolve_max_disp(None, left_image.shape[1])  # the note of the default
    return searched.minimum, searched.maximum


def parse_vis_range(vis_range: str | None, vis: object) -> tuple[float, float] | None:
    """--vis-range MIN:MAX as (min, max) px (:func:`cade_cli.io.pictures.parse_value_range`),
    refused without --vis (``vis``: its value, None or False when not given)."""
    from cade_cli.errors import CadeError
    from cade_cli.io.pictures import parse_value_range

    if vis_range is None:
        return None
    if vis is None or vis is False:
        raise CadeError("--vis-range sets the colours of the --vis picture; add --vis PICTURE.png or drop --vis-range")
    return parse_value_range(vis_range, option="--vis-range")


def parse_memory_limit(memory_limit: str | None) -> int:
    """--memory-limit in bytes (:func:`cade_cli.scale.memory.parse_memory`); None: the default budget."""
    from cade_cli.scale.memory import default_memory_limit, parse_memory

    return default_memory_limit() if memory_limit is None else parse_memory(memory_limit)


def check_output(path: Path, *, suffixes: tuple[str, ...], inputs: tuple[Path, ...]) -> None:
    """Refuse, before any work, outputs we could not write or must not overwrite."""
    from cade_cli.errors import CadeError
    from cade_cli.io.atomic import check_writable

    if path.suffix.lower() not in suffixes:
        raise CadeError(f"cannot write {path}: unsupported extension {path.suffix or '(none)'}; use one of {', '.join(suffixes)}")
    check_writable(path)  # the folder exists, is one, and takes new files; path is not a folder
    for source in inputs:
        if source.exists() and path.exists() and path.resolve() == source.resolve():
            raise CadeError(f"output {path} is also an input; choose another output name")


PLAIN_PROGRESS_SECONDS = 10.0
"""Without a terminal, a long command prints its progress as a plain line on stderr this often (s)."""


class PlainProgress:
    """Progress for logs: while active, a daemon thread prints ``line()`` on stderr every
    :data:`PLAIN_PROGRESS_SECONDS` (read when it starts), whether or not a step ended meanwhile."""

    def __init__(self, line) -> None:
        import threading

        self.line, self.stopped = line, threading.Event()
        self.thread = threading.Thread(target=self._run, name="cade-progress", daemon=True)

    def _run(self) -> None:
        every = PLAIN_PROGRESS_SECONDS
        while not self.stopped.wait(every):
            print(self.line(), file=sys.stderr, flush=True)

    def __enter__(self) -> "PlainProgress":
        self.thread.start()
        return self

    def __exit__(self, *exc_info) -> None:
        self.stopped.set()
        self.thread.join()


def progress_line(task, noun: str = "steps") -> str:
    """One plain progress line of a ``rich`` task: what runs, ``i of n`` done, time elapsed."""
    elapsed = int(task.elapsed or 0)
    total = "?" if task.total is None else f"{task.total:.0f}"
    return f"{task.description}: {task.completed:.0f} of {total} {noun} done, {elapsed // 60} min {elapsed % 60:02d} s"


class StepBar:
    """A transient progress bar on stderr for one long command, counting its steps (stages, tiles,
    tasks, matcher runs): what runs now, steps done of all, time elapsed. Shown only when stderr is
    a terminal; with ``plain`` (the long commands: benchmark, register-array), a log instead gets a
    :class:`PlainProgress` line every :data:`PLAIN_PROGRESS_SECONDS`."""

    def __init__(self, total: int | None, description: str, *, plain: bool = False, noun: str = "steps") -> None:
        from contextlib import nullcontext

        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        console = Console(stderr=True)
        self.progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), console=console, transient=True,
                                 disable=not console.is_terminal)
        self.task = self.progress.add_task(description, total=total)
        self.plain = (PlainProgress(lambda: progress_line(self.progress.tasks[0], noun))
                      if plain and not console.is_terminal else nullcontext())

    def __enter__(self) -> "StepBar":
        self.progress.start()
        self.plain.__enter__()
        return self

    def __exit__(self, *exc_info) -> None:
        self.plain.__exit__(*exc_info)
        self.progress.stop()

    def set_total(self, total: int) -> None:
        """The number of steps, once known (a bar made with ``total`` None spins until then)."""
        self.progress.update(self.task, total=total)

    def advance(self, description: str | None = None, *, steps: int = 1, more: int = 0) -> None:
        """Count ``steps`` done and ``more`` steps added to the total, then show ``description`` (what runs now)."""
        task = self.progress.tasks[0]
        self.progress.update(self.task, advance=steps, total=(task.total or 0) + more,
                             description=task.description if description is None else description)


def print_note(message: str) -> None:
    print(f"note: {message}", file=sys.stderr)


def print_warning(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)
