#!/usr/bin/env python3
"""Models side by side from several `cade benchmark --json` runs: one row a model (method), one column a set and
region, the mean BMP3 % (or EPE px) over the set's records of one protocol. For judging refits and seeds that were
run against the same shipped card in separate runs: a model met in more than one run is taken from the first (the
product is deterministic, so its records are the same in each; the runs' scores of it are compared and a
difference is reported).

    .venv/bin/python benchmarks/model_table.py RUN_DIR... [--protocol cs] [--metric bad3] [--markdown T.md]

A run folder holds ``<set>.json`` or ``<set>.json.gz`` files (other JSON files there, such as model cards, are
skipped). Columns: Middlebury 2014 and 2005 on all,
non-occluded and depth-edge pixels, msir-outdoor (its native protocol) on all pixels.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

from cade_cli.evaluation.records import read_run

COLUMNS = (("middlebury14", "all"), ("middlebury14", "nonocc"), ("middlebury14", "edge"), ("middlebury05", "all"),
           ("middlebury05", "nonocc"), ("middlebury05", "edge"), ("msir-outdoor", "all"))
LABELS = {"all": "all", "nonocc": "non-occluded", "edge": "depth edges"}


def run_files(folder: Path) -> list[Path]:
    return sorted([*folder.glob("*.json"), *folder.glob("*.json.gz")])


def means(path: Path, protocol: str, metric: str) -> dict[tuple[str, str, str], float]:
    """{(method, set, region): mean score} of one run file, the records of ``protocol`` (msir-outdoor: all)."""
    data = read_run(path)
    if "records" not in data:  # another JSON in the folder (a model card): not a run
        return {}
    found: dict[tuple[str, str, str], list[float]] = {}
    for record in data["records"]:
        dataset = record.get("dataset", data["config"]["dataset"])
        if dataset != "msir-outdoor" and record["protocol"] != protocol:
            continue
        for region in ("all", "nonocc", "edge"):
            value = record["scores"].get(f"{metric}_{region}")
            if value is not None:
                found.setdefault((record["method"], dataset, region), []).append(value)
    return {key: statistics.fmean(values) for key, values in found.items()}


def table(folders: list[Path], protocol: str, metric: str) -> str:
    rows: dict[str, dict[tuple[str, str], float]] = {}
    for folder in folders:
        for path in run_files(folder):
            for (method, dataset, region), value in means(path, protocol, metric).items():
                row = rows.setdefault(method, {})
                if (dataset, region) in row and abs(row[dataset, region] - value) > 1e-9:
                    print(f"note: {method} {dataset} {region} differs between runs ({row[dataset, region]:.4f} "
                          f"against {value:.4f} in {path})", file=sys.stderr)
                row.setdefault((dataset, region), value)
    header = "| model | " + " | ".join(f"{dataset} {LABELS[region]}" for dataset, region in COLUMNS) + " |"
    lines = [header, "|---" * (len(COLUMNS) + 1) + "|"]
    for method, row in rows.items():
        cells = [f"{row[column]:.2f}" if column in row else "–" for column in COLUMNS]
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="folders of benchmark runs")
    parser.add_argument("--protocol", default="cs")
    parser.add_argument("--metric", default="bad3", help="bad3 (BMP3 %%), epe, bad1, ...")
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    text = table(args.runs, args.protocol, args.metric)
    print(text, end="")
    if args.markdown:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
