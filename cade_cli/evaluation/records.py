"""One scored prediction of a benchmark run (:class:`Record`): what the loop
(:mod:`~cade_cli.evaluation.loop`) returns, the album (:mod:`~cade_cli.evaluation.album`)
files its pictures under and the reports read.
"""

from __future__ import annotations

import gzip
import json
from dataclasses import asdict, dataclass
from pathlib import Path


@dataclass(frozen=True)
class Record:
    """Scores of one scored prediction (one CS task, or the RGB median map).

    ``seconds`` is the matcher's wall time (median of the timed runs; for the RGB median
    the sum of its ``matcher_runs`` runs); ``degradation`` names what was done to the
    right band (:mod:`~cade_cli.evaluation.degradations`).
    """

    dataset: str
    resolution: str
    scene: str
    protocol: str
    method: str
    preprocess: str
    task: str
    seconds: float
    matcher_runs: int
    scores: dict[str, float]
    degradation: str = "none"

    def to_dict(self) -> dict:
        """The record as JSON-ready dict; ``degradation`` only when the band was degraded."""
        record = asdict(self)
        if self.degradation == "none":
            del record["degradation"]
        return record


def read_run(path: str | Path) -> dict:
    """A ``cade benchmark --json`` file (its ``config``, ``summary`` and ``records``), plain or gzipped
    (``.json.gz``: how the repository keeps its larger records)."""
    raw = Path(path).read_bytes()
    return json.loads(gzip.decompress(raw) if str(path).endswith(".gz") else raw)
