"""Tables of a :class:`~cade_cli.evaluation.loop.BenchmarkRun`, shaped like the paper's Table 1.

Rows are method + preprocessing, columns EPE / BMP3 / BMP5 per protocol (and KITTI's D1 for
the KITTI sets, :data:`D1_DATASETS`), one table per
pixel set ("all" pixels with ground truth; "nonocc", "edge" and "occ" as far as the dataset
allows, :mod:`~cade_cli.evaluation.regions`), and
one table of how well each matcher's confidence ranks its errors (:func:`confidence_table`).
The same rows feed the terminal table, the Markdown report and the HTML report
(:mod:`~cade_cli.evaluation.html_report`).
"""

from __future__ import annotations

from cade_cli.evaluation.loop import BenchmarkRun
from cade_cli.evaluation.regions import EDGE_JUMP, EDGE_RADIUS

COLUMNS: tuple[tuple[str, str], ...] = (("epe", "EPE"), ("bad3", "BMP3"), ("bad5", "BMP5"))
D1_COLUMN: tuple[str, str] = ("d1", "D1")
D1_DATASETS: tuple[str, ...] = ("kitti2012", "kitti2015")
"""Datasets whose tables add KITTI's own metric, D1 (:func:`cade_cli.evaluation.metrics.d1_rate`);
every record carries it in the JSON."""
PIXEL_SETS: tuple[str, ...] = ("all", "nonocc", "edge", "occ")
PIXEL_SET_NAMES: dict[str, str] = {
    "all": "all pixels with ground truth",
    "nonocc": "non-occluded pixels with ground truth",
    "edge": f"depth edges (pixels with ground truth within {EDGE_RADIUS:g} px of a jump > {EDGE_JUMP:g} px between "
            "4-neighbours; non-occluded ones where the dataset has occlusion information)",
    "occ": "occluded pixels with ground truth",
}
"""What each pixel set of :data:`PIXEL_SETS` is, for table headings."""


def columns(run: BenchmarkRun) -> tuple[tuple[str, str], ...]:
    """(metric, label) of the columns per protocol: :data:`COLUMNS`, then D1 for KITTI."""
    return COLUMNS + ((D1_COLUMN,) if run.config["dataset"] in D1_DATASETS else ())


def pixel_sets(run: BenchmarkRun) -> list[str]:
    """Pixel sets that have a score (not NaN) in ``run``, in a fixed order: a region no scene
    has (no depth jump in any ground truth) gets no table."""
    present = {key.rsplit("_", 1)[-1] for record in run.records for key, value in record.scores.items()
               if value == value}
    return [name for name in PIXEL_SETS if name in present]


def table(run: BenchmarkRun, pixels: str) -> tuple[list[str], list[list[str]]]:
    """(header, rows) for one pixel set; cells are formatted numbers. A method + preprocessing
    that was not run (one the matcher does not take, :func:`~cade_cli.evaluation.loop.takes_preprocess`)
    has no row."""
    protocols = run.config["protocols"]
    shown = columns(run)
    header = ["method"] + [f"{protocol.upper()} {label}" for protocol in protocols for _, label in shown]
    header.append("s / pair")
    summary = run.summary()
    ran = {(row["method"], row["preprocess"]) for row in summary}
    rows = []
    for method in run.config["methods"]:
        for preprocess in run.config["preprocess"]:
            if (method, preprocess) not in ran:
                continue
            cells, seconds = [f"{method} + {preprocess}"], []
            for protocol in protocols:
                row = next((r for r in summary if (r["method"], r["preprocess"], r["protocol"])
                            == (method, preprocess, protocol)), None)
                for metric, _ in shown:
                    value = None if row is None else row["scores"].get(f"{metric}_{pixels}")
                    cells.append("—" if value is None else (f"{value:.2f}" if metric == "epe" else f"{value:.1f}"))
                if row is not None:
                    seconds.append(row["seconds_per_pair"])
            cells.append(f"{sum(seconds) / len(seconds):.2f}" if seconds else "—")
            rows.append(cells)
    return header, rows


def confidence_table(run: BenchmarkRun) -> tuple[list[str], list[list[str]]] | None:
    """(header, rows) of the sparsification areas, or None when no record has them.

    Per protocol: ``random`` (the area of a random order, i.e. the mean ``epe_all``),
    ``AUC`` (the confidence's, ``auc_conf_all``), ``oracle`` (``auc_oracle_all``), all in
    px, and ``gain %`` = 100 (random - AUC) / (random - oracle): the share of the
    oracle's improvement over a random order that the confidence achieves (0: no better
    than random, 100: ranks errors perfectly).
    """
    if not any("auc_conf_all" in record.scores for record in run.records):
        return None
    protocols = run.config["protocols"]
    header = ["method"] + [f"{protocol.upper()} {label}" for protocol in protocols
                           for label in ("random", "AUC", "oracle", "gain %")]
    summary = run.summary()
    rows = []
    for method in run.config["methods"]:
        for preprocess in run.config["preprocess"]:
            cells, found = [f"{method} + {preprocess}"], False
            for protocol in protocols:
                row = next((r for r in summary if (r["method"], r["preprocess"], r["protocol"])
                            == (method, preprocess, protocol)), None)
                scores = {} if row is None else row["scores"]
                random, auc, oracle = (scores.get(key) for key in ("epe_all", "auc_conf_all", "auc_oracle_all"))
                if auc is None:
                    cells += ["—"] * 4
                    continue
                found = True
                gain = 100.0 * (random - auc) / (random - oracle) if random > oracle else float("nan")
                cells += [f"{random:.2f}", f"{auc:.2f}", f"{oracle:.2f}", f"{gain:.0f}"]
            if found:
                rows.append(cells)
    return header, rows


def confidence_title(run: BenchmarkRun) -> str:
    """Heading of :func:`confidence_table`."""
    return (f"{run.config['dataset']}, confidence: area under the sparsification curve (EPE px of the pixels kept "
            "as the least confident are removed; all pixels with ground truth); gain % = share of the oracle's "
            "improvement over a random order")


def title(run: BenchmarkRun, pixels: str) -> str:
    """Table heading naming the dataset, resolution, scene count and pixel set."""
    resolutions = sorted({record.resolution for record in run.records}) or ["?"]
    scenes = len(run.config["scenes"])
    what = PIXEL_SET_NAMES[pixels]
    d1 = ", D1 % off by > 3 px and > 5 %" if D1_COLUMN in columns(run) else ""
    return (f"{run.config['dataset']} ({', '.join(resolutions)}, {scenes} scenes), {what}: "
            f"EPE px, BMP3/BMP5 % of pixels off by > 3/5 px{d1}")


def record_table(run: BenchmarkRun) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of every record: scene, protocol, task, method + preprocess, its
    EPE, BMP3 (and D1 for KITTI) on each pixel set the run scored (:func:`pixel_sets`), invalid % and seconds."""
    metrics = [("epe", "EPE"), ("bad3", "BMP3")] + ([D1_COLUMN] if D1_COLUMN in columns(run) else [])
    present = pixel_sets(run)
    keys = [f"{metric}_{pixels}" for pixels in present for metric, _ in metrics]
    header = ["scene", "protocol", "task", "method",
              *(f"{label} {pixels}" for pixels in present for _, label in metrics), "invalid %", "s"]
    rows = [[r.scene, r.protocol, r.task, f"{r.method} + {r.preprocess}",
             *(_fmt(r.scores.get(key)) for key in (*keys, "invalid")), f"{r.seconds:.2f}"] for r in run.records]
    return header, rows


def left_out(run: BenchmarkRun) -> str:
    """The method + preprocessing pairs the run left out and why, one clause per reason:
    ``cade:a + none, cade:b + none: method cade takes ...``; empty when none was."""
    by_reason: dict[str, list[str]] = {}
    for pair, reason in run.config.get("not_applicable", {}).items():
        by_reason.setdefault(reason, []).append(pair)
    return "; ".join(f"{', '.join(pairs)}: {reason}" for reason, pairs in by_reason.items())


def markdown(run: BenchmarkRun, *, command: str | None = None) -> str:
    """The full Markdown report: the tables, then per-scene, per-task numbers."""
    lines = ["# cade benchmark", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    if left_out(run):
        lines += [f"Left out, as they do not apply: {left_out(run)}.", ""]
    for pixels in pixel_sets(run):
        header, rows = table(run, pixels)
        lines += [f"## {title(run, pixels)}", "", markdown_row(header), markdown_row(["---"] + ["---:"] * (len(header) - 1))]
        lines += [markdown_row(row) for row in rows] + [""]
    confidence = confidence_table(run)
    if confidence is not None:
        header, rows = confidence
        lines += [f"## {confidence_title(run)}", "", markdown_row(header),
                  markdown_row(["---"] + ["---:"] * (len(header) - 1))]
        lines += [markdown_row(row) for row in rows] + [""]
    header, rows = record_table(run)
    lines += ["## Per scene and task", "", markdown_row(header), markdown_row(["---"] * 4 + ["---:"] * (len(header) - 4))]
    lines += [markdown_row(row) for row in rows]
    return "\n".join(lines) + "\n"


def _fmt(value: float | None) -> str:
    return "—" if value is None else f"{value:.2f}"


def markdown_row(cells: list[str]) -> str:
    """One Markdown table row: ``| a | b |``."""
    return "| " + " | ".join(cells) + " |"
