#!/usr/bin/env python3
"""Accuracy V's bake-off table (issue 51 item 2): every judged run of ``benchmarks/bakeoff_judge.sh``
side by side, EPE px / BMP3 % by region on each set, the network alone and the whole matcher; with
``--speed`` (each run's seconds per megapixel, measured on a quiet CPU) also the plot of non-occluded
and edge BMP3 against s/MP.

    benchmarks/bakeoff_table.py benchmarks/results/2026-11-28-bakeoff [--markdown T.md] \\
        [--speed RUN=S_PER_MP,...] [--plot P.png]

A judged run is a folder holding the judge's ``<set>.json.gz`` files (``cade benchmark --json``, gzipped to
keep the records small in git). The
figures are the benchmark's own summary means (every record of the set, cs protocol where it has one);
a set or region a run lacks shows as "–".
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cade_cli.evaluation.records import read_run

SETS = ("middlebury14", "middlebury05", "msir-outdoor", "kitti2012", "kitti2015")
REGIONS = ("all", "nonocc", "edge", "occ")
METHODS = ("cade-network", "cade")


def record_file(run: Path, name: str) -> Path:
    """The judge's gzipped record of set ``name`` in a judged run's folder."""
    return run / f"{name}.json.gz"


def summary_scores(path: Path, method: str) -> dict[str, float] | None:
    """The summary scores of ``method`` (``cade-network`` or ``cade``, whatever model it names) in one
    gzipped ``cade benchmark --json`` file; None when the file or the method is not there."""
    if not path.is_file():
        return None
    for row in read_run(path)["summary"]:
        if row["method"].split(":")[0] == method:
            return row["scores"]
    return None


def cell(scores: dict[str, float] | None, region: str) -> str:
    if scores is None or f"epe_{region}" not in scores:
        return "–"
    return f"{scores[f'epe_{region}']:.2f} / {scores[f'bad3_{region}']:.1f}"


def table(judged: Path) -> tuple[str, dict[str, dict[str, float]]]:
    """The Markdown tables (one per set and method) and, per run, the whole matcher's Middlebury 2014 scores."""
    runs = sorted(path for path in judged.iterdir()
                  if path.is_dir() and any(record_file(path, name).is_file() for name in SETS))
    lines, middlebury = [], {}
    for name in SETS:
        for method in METHODS:
            rows = [(run.name, summary_scores(record_file(run, name), method)) for run in runs]
            if all(scores is None for _, scores in rows):
                continue
            lines += [f"\n### {name}, {method} (EPE px / BMP3 %)\n", "| run | " + " | ".join(REGIONS) + " |",
                      "|---|" + "---|" * len(REGIONS)]
            lines += [f"| {run} | " + " | ".join(cell(scores, region) for region in REGIONS) + " |"
                      for run, scores in rows]
            if name == "middlebury14" and method == "cade":
                middlebury = {run: scores for run, scores in rows if scores is not None}
    return "\n".join(lines).lstrip("\n") + "\n", middlebury


def parse_speed(text: str) -> dict[str, float]:
    speeds = {}
    for item in filter(None, text.split(",")):
        run, _, value = item.partition("=")
        try:
            speeds[run.strip()] = float(value)
        except ValueError:
            raise SystemExit(f"bakeoff_table: --speed wants RUN=S_PER_MP,..., got {item!r}") from None
    return speeds


def plot(middlebury: dict[str, dict[str, float]], speeds: dict[str, float], path: Path) -> None:
    """Non-occluded and edge BMP3 (Middlebury 2014, whole matcher) against s/MP, one point pair a run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(6.4, 4.2), dpi=100)
    for run, scores in sorted(middlebury.items()):
        if run not in speeds:
            continue
        x = speeds[run]
        axis.plot([x, x], [scores["bad3_nonocc"], scores["bad3_edge"]], color="0.8", zorder=0)
        axis.scatter(x, scores["bad3_nonocc"], marker="o", color="tab:blue")
        axis.scatter(x, scores["bad3_edge"], marker="^", color="tab:red")
        axis.annotate(run.replace("bakeoff-2026-11-28-", ""), (x, scores["bad3_edge"]), fontsize=8,
                      xytext=(4, 2), textcoords="offset points")
    axis.scatter([], [], marker="o", color="tab:blue", label="non-occluded")
    axis.scatter([], [], marker="^", color="tab:red", label="depth edges")
    axis.set_xlabel("s / MP (whole matcher, quiet CPU)")
    axis.set_ylabel("BMP3 %  (Middlebury 2014 Q, cs)")
    axis.legend()
    axis.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("judged", type=Path, help="folder of judged runs (benchmarks/bakeoff_judge.sh's OUT_DIRs)")
    parser.add_argument("--markdown", type=Path, help="write the tables here")
    parser.add_argument("--speed", default="", help="RUN=S_PER_MP,... (quiet CPU) for the plot")
    parser.add_argument("--plot", type=Path, help="PNG: non-occluded and edge BMP3 against s/MP (needs --speed)")
    args = parser.parse_args(argv)
    if not args.judged.is_dir():
        raise SystemExit(f"bakeoff_table: {args.judged} is not a folder")
    if args.plot and not args.speed:
        raise SystemExit("bakeoff_table: --plot needs --speed")
    text, middlebury = table(args.judged)
    print(text, end="")
    if args.markdown:
        args.markdown.write_text(text)
    if args.plot:
        plot(middlebury, parse_speed(args.speed), args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
