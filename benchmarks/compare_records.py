#!/usr/bin/env python
"""Compare two `cade benchmark --json` files record by record (scores only; timing ignored).

Records are keyed by (dataset, scene, protocol, method, preprocess, task, degradation);
a record only in one file, a metric only in one record, or a score that differs by more
than ``--tolerance`` is printed. Records of OLD outside NEW's scenes / methods / protocols /
preprocessing are not reported missing (compare a partial run against a full one)::

    .venv/bin/python benchmarks/compare_records.py docs/bench/middlebury05.json.gz new05.json [--tolerance 0]

A run made before a score was added (the region scores ``*_edge``, ``*_occ`` of 2026-11-28) compares
equal on the scores both carry with ``--new-metrics``. Exit status 0 when nothing differs, 1 otherwise.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from cade_cli.evaluation.records import read_run

KEY = ("dataset", "scene", "protocol", "method", "preprocess", "task")


def records_by_key(path: Path) -> tuple[dict, dict[tuple, dict[str, float]]]:
    """(config, {record key: scores}) of a benchmark JSON file, plain or gzipped (``.json.gz``, as
    docs/bench keeps its largest); degradation "none" when absent."""
    data = read_run(path)
    records = {}
    for record in data["records"]:
        key = (*(record[name] for name in KEY), record.get("degradation", "none"))
        if key in records:
            raise SystemExit(f"{path}: two records for {key}")
        records[key] = record["scores"]
    return data["config"], records


def same(old: float, new: float, tolerance: float) -> bool:
    if math.isnan(old) or math.isnan(new):
        return math.isnan(old) and math.isnan(new)
    return abs(old - new) <= tolerance


def differences(old: dict, new: dict, new_config: dict, tolerance: float, *, new_metrics: bool = False) -> list[str]:
    """One line per difference, in OLD's order then NEW's extra records; with
    ``new_metrics`` a metric that only NEW's records carry (a score added since) is not one."""
    covered = {"scene": "scenes", "method": "methods", "protocol": "protocols", "preprocess": "preprocess"}
    lines = []
    for key, scores in old.items():
        fields = dict(zip(KEY, key))
        if key not in new:
            if all(fields[name] in new_config[option] for name, option in covered.items()):
                lines.append(f"only in OLD: {' / '.join(key)}")
            continue
        for metric in sorted(set(scores) | set(new[key])):
            a, b = scores.get(metric), new[key].get(metric)
            if a is None and b is not None and new_metrics:
                continue
            if a is None or b is None:
                lines.append(f"{' / '.join(key)}: {metric} only in {'NEW' if a is None else 'OLD'}")
            elif not same(float(a), float(b), tolerance):
                lines.append(f"{' / '.join(key)}: {metric} {a!r} -> {b!r} ({float(b) - float(a):+.6g})")
    lines += [f"only in NEW: {' / '.join(key)}" for key in new if key not in old]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--tolerance", type=float, default=0.0, help="largest |new - old| that counts as equal")
    parser.add_argument("--new-metrics", action="store_true",
                        help="metrics that only NEW's records carry (scores added since OLD) are not differences")
    args = parser.parse_args(argv)
    _, old = records_by_key(args.old)
    new_config, new = records_by_key(args.new)
    lines = differences(old, new, new_config, args.tolerance, new_metrics=args.new_metrics)
    compared = sum(key in new for key in old)
    print("\n".join(lines) if lines else "no difference")
    print(f"{compared} records compared, {len(lines)} difference(s)", file=sys.stderr)
    return 1 if lines else 0


if __name__ == "__main__":
    raise SystemExit(main())
