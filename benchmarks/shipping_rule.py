"""Accuracy III's shipping rule, read from `cade benchmark --json` files.

A candidate ships as the fast tier when, against the shipped model in the same runs, its
mean EPE and mean BMP3 over Middlebury 2005 and 2014 CS are both lower, and no set
(every dataset x protocol in the files) is worse by more than 3 % in EPE or BMP3.

    .venv/bin/python benchmarks/shipping_rule.py --shipped cade:cade-v4 --candidate cade:c8kc \
        /tmp/c8k/c_middlebury05.json /tmp/c8k/c_middlebury14.json /tmp/c8k/c_kitti2015.json ...

Means are over every record of a set (scene x task), all pixels, as the benchmark's tables.
Exit 0 when the candidate passes, 1 when it does not.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys

RULE_SETS = (("middlebury05", "cs"), ("middlebury14", "cs"))
"""The sets whose means decide the first half of the rule."""
TOLERANCE = 0.03
"""No set may be worse than the shipped model's by more than this share."""


def set_means(paths: list[str]) -> dict[tuple[str, str, str], tuple[float, float]]:
    """(dataset, protocol, method) -> (mean EPE, mean BMP3) over its records, all pixels."""
    scores: dict[tuple[str, str, str], list[dict]] = {}
    for path in paths:
        with open(path, encoding="utf-8") as file:
            run = json.load(file)
        for record in run["records"]:
            scores.setdefault((run["config"]["dataset"], record["protocol"], record["method"]), []).append(
                record["scores"])
    return {key: (statistics.mean(s["epe_all"] for s in values), statistics.mean(s["bad3_all"] for s in values))
            for key, values in scores.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shipped", required=True, help="method row of the shipped model, e.g. cade:cade-v4")
    parser.add_argument("--candidate", required=True, help="method row of the candidate, e.g. cade:c8kc")
    parser.add_argument("runs", nargs="+", help="cade benchmark --json files holding both rows")
    args = parser.parse_args(argv)
    means = set_means(args.runs)
    sets = sorted({(dataset, protocol) for dataset, protocol, _ in means})
    worse, passes = [], True
    print("| set | shipped EPE / BMP3 | candidate EPE / BMP3 | change |")
    print("|---|---|---|---|")
    for dataset, protocol in sets:
        old, new = means.get((dataset, protocol, args.shipped)), means.get((dataset, protocol, args.candidate))
        if old is None or new is None:
            print(f"| {dataset} {protocol} | {'missing' if old is None else ''} | {'missing' if new is None else ''} | |")
            passes = False
            continue
        change = [new[i] / old[i] - 1 for i in (0, 1)]
        if max(change) > TOLERANCE:
            worse.append(f"{dataset} {protocol}")
        print(f"| {dataset} {protocol} | {old[0]:.3f} / {old[1]:.2f} | {new[0]:.3f} / {new[1]:.2f} | "
              f"{change[0]:+.1%} / {change[1]:+.1%} |")
    rule = [key for key in RULE_SETS if (*key, args.shipped) in means and (*key, args.candidate) in means]
    if len(rule) < len(RULE_SETS):
        print("the runs lack Middlebury 2005 or 2014 CS: the rule cannot be decided")
        return 1
    old_mean = [statistics.mean(means[(*key, args.shipped)][i] for key in rule) for i in (0, 1)]
    new_mean = [statistics.mean(means[(*key, args.candidate)][i] for key in rule) for i in (0, 1)]
    lower = new_mean[0] < old_mean[0] and new_mean[1] < old_mean[1]
    print(f"\nMiddlebury 2005 + 2014 CS means: EPE {new_mean[0]:.3f} against {old_mean[0]:.3f}, "
          f"BMP3 {new_mean[1]:.2f} against {old_mean[1]:.2f}: {'both lower' if lower else 'not both lower'}")
    print(f"sets worse by more than {TOLERANCE:.0%}: {', '.join(worse) or 'none'}")
    passes = passes and lower and not worse
    print("passes: ships as the fast tier" if passes else "does not pass")
    return 0 if passes else 1


if __name__ == "__main__":
    sys.exit(main())
