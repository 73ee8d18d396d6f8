"""The run of a batch, of pairs (`cade batch`) or of a flight's captures (`cade batch --captures`): the
bar (a plain line every 10 s when stderr is a log), each result shown above it as it comes, a warning
when interrupted, and the log written however the run ends."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path

from cade_cli.cli.options import PlainProgress, print_warning, progress_line


def progress_bar(noun: str):
    """The batch's bar on stderr (``noun`` done of those to do, per second, ETA); off when stderr is not a terminal."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeRemainingColumn
    from rich.text import Text

    class Rate(ProgressColumn):
        def render(self, task) -> Text:
            rate = task.completed / task.elapsed if task.elapsed else 0.0
            return Text(f"{rate:.2f} {noun}/s")

    console = Console(stderr=True, soft_wrap=True)
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), Rate(),
                    TextColumn("ETA"), TimeRemainingColumn(), console=console, transient=True,
                    disable=not console.is_terminal)


def run_jobs(todo: list, results: list, running: Iterable, *, total: int, noun: str, label: str, log: Path,
             config: dict, show: Callable):
    """Run ``todo`` (``running`` yields their results as an engine finishes them) after the ``results``
    of the jobs already finished: each result goes to ``results`` and to ``show(console, result)``
    above the bar; on an interruption a warning, then it propagates; the log (entries under
    ``noun``) is written at the end however the run ends. Returns the :class:`BatchSummary`."""
    from contextlib import nullcontext

    from cade_cli.io.atomic import atomic_output
    from cade_cli.batch.job import remove_stale_temporaries
    from cade_cli.batch.log import BatchSummary, log_document

    summary = BatchSummary(total=total, skipped=len(results))
    progress = progress_bar(noun)
    started = time.perf_counter()
    bar = progress.add_task(label, total=len(todo))
    plain = (PlainProgress(lambda: progress_line(progress.tasks[0], noun))
             if todo and not progress.console.is_terminal else nullcontext())  # a log: a line every 10 s
    try:
        with progress if todo else nullcontext(), plain:
            for result in running:
                results.append(result)
                summary.add(result)
                show(progress.console, result)
                progress.update(bar, advance=1)
    except KeyboardInterrupt:
        summary.interrupted = True
        print_warning(f"interrupted: {summary.done} of the {noun} finished in this run, their outputs complete; rerun "
                      f"the same command to go on (finished {noun} are skipped); log {log}")
        raise
    finally:
        summary.seconds = time.perf_counter() - started
        remove_stale_temporaries(todo)
        with atomic_output(log) as temporary:
            temporary.write_text(log_document(results, summary, config=config, entries=noun))
    return summary
