#!/usr/bin/env python3
"""Models side by side from several `cade benchmark --json` runs: one row a model (method), one column a set and
region, the mean BMP3 % (or EPE px) over the set's records of one protocol. For judging refits and seeds that were
run against the same shipped card in separate runs: a model met in more than one run is taken from the first (the
product is deterministic, so its records are the same in each; the runs' scores of it are compared and a
difference is reported).

    .venv/bin/python benchmarks/model_table.py RUN_DIR... [--protocol cs] [--metric bad3] [--markdown T.md]

A run folder holds ``<set>.json`` or ``<set>.json.gz`` files (other files there, such as model cards, are not read).
Records and means are ``benchmarks/shipping_rule.py``'s (a region's mean over the records that score it). Columns: Middlebury 2014 and 2005 on all,
non-occluded and depth-edge pixels, msir-outdoor (its native protocol) on all pixels.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from shipping_rule import means, read_records  # noqa: E402

COLUMNS = (("middlebury14", "all"), ("middlebury14", "nonocc"), ("middlebury14", "edge"), ("middlebury05", "all"),
           ("middlebury05", "nonocc"), ("middlebury05", "edge"), ("msir-outdoor", "all"))
LABELS = {"all": "all", "nonocc": "non-occluded", "edge": "depth edges"}
METRICS = {"epe": 0, "bad3": 1}
"""The metric's place in :func:`shipping_rule.means`' (EPE, BMP3)."""


def run_files(folder: Path) -> list[Path]:
    """The runs of the sets of :data:`COLUMNS` in ``folder`` (``<set>.json`` or ``.json.gz``; other files, such as
    a model card beside them, are not read)."""
    names = dict.fromkeys(dataset for dataset, _ in COLUMNS)
    return [path for name in names for path in (folder / f"{name}.json", folder / f"{name}.json.gz") if path.exists()]


def table(folders: list[Path], protocol: str, metric: str) -> str:
    """The markdown table: one row a model, each cell :func:`shipping_rule.means` over the column's set and region
    (the records of ``protocol``; msir-outdoor's all)."""
    rows: dict[str, dict[tuple[str, str], float]] = {}
    for folder in folders:
        for path in run_files(folder):
            records = read_records([str(path)])
            for method in dict.fromkeys(record["method"] for record in records):
                row = rows.setdefault(method, {})
                for dataset, region in COLUMNS:
                    keep = lambda r, dataset=dataset: (  # noqa: E731
                        r["dataset"] == dataset and (dataset == "msir-outdoor" or r["protocol"] == protocol))
                    found = means(records, method, keep, region=region)
                    if found is None:
                        continue
                    value = found[METRICS[metric]]
                    if (dataset, region) in row and abs(row[dataset, region] - value) > 1e-9:
                        print(f"note: {method} {dataset} {region} differs between runs "
                              f"({row[dataset, region]:.4f} against {value:.4f} in {path})", file=sys.stderr)
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
    parser.add_argument("--metric", default="bad3", choices=sorted(METRICS), help="bad3 (BMP3 %%) or epe (px)")
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    text = table(args.runs, args.protocol, args.metric)
    print(text, end="")
    if args.markdown:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
