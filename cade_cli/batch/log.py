"""A batch's JSON log (``cade batch``'s ``<name>.log.json``): the counts and timing of the run, its
configuration, and one entry per pair (:class:`~cade_cli.batch.pairs.PairResult`)."""

from __future__ import annotations

import datetime
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass

from cade_cli.batch.pairs import PairResult
from cade_cli.version import __version__


@dataclass
class BatchSummary:
    """Counts and timing of a batch."""

    total: int
    done: int = 0
    skipped: int = 0
    failed: int = 0
    seconds: float = 0.0
    interrupted: bool = False

    def add(self, result: PairResult) -> None:
        setattr(self, result.status, getattr(self, result.status) + 1)

    @property
    def pairs_per_minute(self) -> float:
        return 60.0 * self.done / self.seconds if self.seconds > 0 else 0.0


def log_document(results: Sequence[PairResult], summary: BatchSummary, *, config: dict, entries: str = "pairs") -> str:
    """The JSON log of a batch: its configuration, summary and one entry per job, under ``entries``."""
    return json.dumps({
        "cade_version": __version__,
        "finished_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "config": config,
        "summary": {**asdict(summary), "pairs_per_minute": summary.pairs_per_minute},
        entries: [{key: value for key, value in asdict(result).items() if value not in (None, (), {})}
                  for result in results],
    }, indent=1) + "\n"
