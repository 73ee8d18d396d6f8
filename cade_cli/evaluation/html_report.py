"""The HTML report of a benchmark run: one self-contained page a person looks at.

The page carries what made the numbers (cade version, dataset, date, the command line and
each network's name and sha256), the tables of the Markdown report
(:mod:`cade_cli.evaluation.report`, the same rows), and per scene and task the two bands
that were matched, then per method its disparity picture and its error picture side by
side, with that map's scores beside them. The pictures come from the run's albums
(:class:`~cade_cli.evaluation.album.SceneAlbum`, kept by ``run_benchmark(tile_width=...)``)
and are embedded as base64 JPEG data URIs, so the page is one file that can be mailed
(pictures of one task per scene by default). The best figure of each column of the summary
tables is marked, and a legend says what each method label, preprocessing and protocol means.
Plain string formatting; every text from the run is escaped.
"""

from __future__ import annotations

import base64
from datetime import datetime, timezone
from html import escape

from cade_cli.errors import CadeError
from cade_cli.evaluation.album import TILE_WIDTH, SceneAlbum, map_key
from cade_cli.evaluation.loop import BenchmarkRun
from cade_cli.evaluation.records import Record
from cade_cli.evaluation.report import (
    PIXEL_SET_NAMES, confidence_table, confidence_title, left_out, pixel_sets, record_table, table, title,
)
from cade_cli.version import __version__

STYLE = """
body { font: 14px/1.4 system-ui, sans-serif; color: #222; margin: 12px 16px; max-width: 1248px; }
h1 { font-size: 22px; margin: 0 0 8px; } h2 { font-size: 18px; margin: 20px 0 6px; border-bottom: 1px solid #ccc; }
h3 { font-size: 15px; margin: 18px 0 6px; }
table { border-collapse: collapse; margin: 2px 0 12px; }
.title { font-weight: 600; font-size: 13px; margin: 6px 0 2px; }
.tables { display: flex; flex-wrap: wrap; column-gap: 16px; } div.table { width: min-content; min-width: 280px; }
th, td { border: 1px solid #ddd; padding: 1px 6px; text-align: right; white-space: nowrap; font-size: 13px; }
th:first-child, td:first-child { text-align: left; } th { background: #f3f3f3; }
table.meta th, table.meta td { text-align: left; white-space: normal; vertical-align: top; }
code { font-size: 13px; word-break: break-all; } .note { color: #555; }
.row { display: grid; grid-template-columns: 190px repeat(2, minmax(0, var(--tile, TILEpx))); gap: 8px; margin: 6px 0; }
.row figure { margin: 0; } .row img { max-width: 100%; height: auto; display: block; border: 1px solid #ccc; }
figcaption { font-size: 12px; color: #555; } .label { font-size: 13px; } .label b { font-size: 14px; }
.scores td { border: none; padding: 0 6px 0 0; font-size: 12px; }
.bands div { display: flex; gap: 4px; } .bands img { width: calc(50% - 2px); }
nav p { margin: 2px 0; } nav a { margin-right: 8px; white-space: nowrap; }
td.best { font-weight: 700; background: #e6f4e6; } dl.legend dt { font-weight: 600; } dl.legend dd { margin: 0 0 4px 16px; }
"""
"""The page's CSS; ``TILE`` stands for the widest picture's width in px; a scene's section
sets ``--tile`` to its own pictures' width, so that its columns fit them."""


def html_report(run: BenchmarkRun, *, command: str | None = None, created: datetime | None = None) -> str:
    """The report page of ``run``, which must hold its pictures (``run.albums``).

    Args:
        run: a finished run of :func:`~cade_cli.evaluation.loop.run_benchmark` with ``tile_width``.
        command: the command line that ran it, shell-quoted; None: not recorded.
        created: the time shown on the page (default: now, UTC).

    Returns:
        The HTML text (UTF-8), pictures included.

    Raises:
        CadeError: the run kept no pictures.
    """
    if run.records and not run.albums:
        raise CadeError("this benchmark run kept no pictures; run it with tile_width (cade benchmark --html)")
    created = created or datetime.now(timezone.utc)
    dataset = escape(str(run.config["dataset"]))
    width = max((album.width for album in run.albums.values()), default=TILE_WIDTH)
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>cade benchmark: {dataset}</title>", f"<style>{STYLE.replace('TILE', str(width))}</style>",
        "</head><body>", f"<h1>cade benchmark: {dataset}</h1>",
        header(run, command=command, created=created), tables(run), legend(run), pictures(run, width=width),
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def header(run: BenchmarkRun, *, command: str | None, created: datetime) -> str:
    """The provenance table: version, date, command line, dataset, configuration, models."""
    config = run.config
    resolutions = ", ".join(sorted({record.resolution for record in run.records})) or "?"
    rows = [
        ("cade", __version__),
        ("date", created.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")),
        ("command", f"<code>{escape(command)}</code>" if command else "not recorded (run from Python)"),
        ("dataset", f"{escape(str(config['dataset']))} ({escape(resolutions)}) in "
                    f"<code>{escape(str(config['data_dir']))}</code>; scenes {escape(', '.join(config['scenes']))}"),
        ("run", "; ".join(f"{name} {escape(', '.join(config[name]))}"
                          for name in ("methods", "protocols", "preprocess"))),
    ]
    if left_out(run):
        rows.append(("left out", escape(left_out(run))))
    for method, model in config.get("models", {}).items():
        variants = "<br>".join(
            f"{escape(str(v['file']))} ({v['levels']} levels): <code>{escape(str(v['sha256']))}</code>"
            for v in model.get("variants", []))
        rows.append((f"model of {escape(method)}",
                     f"{escape(str(model['name']))}, card <code>{escape(str(model['card']))}</code> sha256 "
                     f"<code>{escape(str(model['sha256']))}</code><details><summary>variants</summary>{variants}"
                     "</details>"))
    body = "".join(f"<tr><th>{name}</th><td>{value}</td></tr>" for name, value in rows)
    return f'<table class="meta">{body}</table>'


def tables(run: BenchmarkRun) -> str:
    """The summary tables of the Markdown report (means over scenes and tasks), the best figure
    of each column marked (:func:`best_cells`: the lowest; for the confidence's gain, the highest)."""
    parts = []
    for pixels in pixel_sets(run):
        header_cells, rows = table(run, pixels)
        parts.append(html_table(title(run, pixels), header_cells, rows, best=best_cells(header_cells, rows)))
    confidence = confidence_table(run)
    if confidence is not None:
        header_cells, rows = confidence
        parts.append(html_table(confidence_title(run), header_cells, rows, best=best_cells(header_cells, rows)))
    return ('<h2>Results</h2><p class="note">Means over scenes and tasks; the best figure of each column is '
            '<b>bold on green</b> (the lowest error, time or area; the highest gain).</p><div class="tables">'
            + "".join(parts) + "</div>")


def best_cells(header_cells: list[str], rows: list[list[str]]) -> set[tuple[int, int]]:
    """(row, column) of the best figure of each numeric column: the lowest (errors, seconds,
    areas), or the highest for a ``gain %`` column; every tie is marked; a column of one row none."""
    best = set()
    for column in range(1, len(header_cells)):
        values = {}
        for index, cells in enumerate(rows):
            try:
                values[index] = float(cells[column])
            except (ValueError, IndexError):
                continue
        values = {index: value for index, value in values.items() if value == value}  # NaN: no figure
        if len(values) < 2:
            continue
        target = (max if header_cells[column].endswith("gain %") else min)(values.values())
        best |= {(index, column) for index, value in values.items() if value == target}
    return best


def legend(run: BenchmarkRun) -> str:
    """What the page's labels mean: METHOD + PREPROCESSING, each protocol run, the pictures' colours."""
    from cade_cli.evaluation.protocols import get_protocol

    meanings = {
        "none": "the matcher compares the two bands as they are, with its own matching cost.",
        "cade": "both bands first go through the CADE colour-agnostic transform (METHOD.md), which makes bands "
                "through different filters look alike; then the matcher runs as with none.",
        "auto": "each matcher's own default of the two.",
    }
    items = [(f"METHOD + {value}", meanings[value]) for value in run.config["preprocess"] if value in meanings]
    items += [(f"{name.upper()} (protocol)", get_protocol(name).summary) for name in run.config["protocols"]]
    items += [(f"{name} (pixels)", f"{PIXEL_SET_NAMES[name]}.") for name in pixel_sets(run)]
    items += [("R>B and the like", "left band R of the left view matched against band B of the right view."),
              ("disparity pictures", "Turbo colours over the scene's ground-truth range; black = the matcher "
                                     "rejected the pixel (the map scored is filled there) or, in the ground "
                                     "truth, no ground truth."),
              ("error pictures", "|disparity - ground truth| of the map scored (filled), from 0 px (black) to 8 px "
                                 "and more (white-hot), as the picture's scale says; dark blue = no ground truth.")]
    body = "".join(f"<dt>{escape(term)}</dt><dd>{escape(text)}</dd>" for term, text in items)
    return f'<h2>How to read this page</h2><dl class="legend">{body}</dl>'



def pictures(run: BenchmarkRun, *, width: int) -> str:
    """Per scene: its ground truth, then per task the bands and each method's maps, then
    every record's scores (the Markdown report's last table)."""
    header_cells, rows = record_table(run)
    scores = {id(record): row for record, row in zip(run.records, rows)}
    groups: dict[str, dict[tuple[str, str, str], list[Record]]] = {}
    every_task = all(album.every_task for album in run.albums.values())
    for record in run.records:  # in scene, protocol, method, ... order: group by scene and task
        key = (record.protocol, record.degradation, record.task)
        album = run.albums.get(record.scene)
        if album is not None and not album.every_task and key != album.shown_task:
            continue  # its scores are in the tables; its pictures were not drawn
        groups.setdefault(record.scene, {}).setdefault(key, []).append(record)
    links = "".join(
        f'<p><a href="#{anchor(scene)}"><b>{escape(scene)}</b></a> '
        + " ".join(f'<a href="#{anchor(scene, *key)}">{escape(task_title(*key))}</a>' for key in tasks) + "</p>"
        for scene, tasks in groups.items())
    parts = [
        "<h2>Pictures</h2>",
        f'<p class="note">Pictures at most {width} px wide (maps downscaled by nearest neighbour, bands by area); '
        "numbers at full resolution. The disparity pictures of a scene share its ground truth's colour range, so "
        "that methods compare. EPE in px; BMP3, D1 in % of the pixels with ground truth. "
        + ("Pictures of every task." if every_task else "Pictures of one task per scene, its first; every task's "
           "scores are in the tables (cade benchmark --html-pictures all draws every task).") + "</p>",
        f"<nav>{links}</nav>",
    ]
    for scene, tasks in groups.items():
        album = run.albums.get(scene)
        parts.append(scene_section(scene, album, tasks, scores=scores, score_names=header_cells[4:]))
    parts.append(html_table("Per scene and task", header_cells, rows))
    return "\n".join(parts)


def scene_section(scene: str, album: SceneAlbum | None, tasks: dict[tuple[str, str, str], list[Record]], *,
                  scores: dict[int, list[str]], score_names: list[str]) -> str:
    """One scene, one block per task: the ground truth and the two bands matched, then per
    method its disparity picture (right under the ground truth) and its error picture."""
    tile = "" if album is None else f' style="--tile: {picture_width(album.ground_truth)}px"'
    parts = [f'<section{tile}><h2 id="{anchor(scene)}">{escape(scene)}</h2>']
    for (protocol, degradation, task), records in tasks.items():
        parts.append(f'<h3 id="{anchor(scene, protocol, degradation, task)}">{escape(scene)}: '
                     f"{escape(task_title(protocol, degradation, task))}</h3>")
        bands = None if album is None else album.bands.get((protocol, task))
        if bands is not None:
            low, high = album.value_range
            names = band_names(task)
            parts.append(row(
                f"<b>ground truth</b> and the bands matched<br>disparity colours span {low:.1f} to {high:.1f} px "
                f"in every picture of {escape(scene)} (the ground truth's range)", [
                    figure(album.ground_truth, f"{scene} ground truth", "ground truth"),
                    band_pair(bands, f"{scene} {task}", names)]))
        for record in records:
            label = f"<b>{escape(record.method)} + {escape(record.preprocess)}</b>" + score_list(
                score_names, scores[id(record)][4:])
            maps = None if album is None else album.maps.get(map_key(record))
            name = f"{scene} {protocol} {task} {record.method} + {record.preprocess}"
            parts.append(row(label, [] if maps is None else [
                figure(maps[0], f"{name} disparity", "disparity"), figure(maps[1], f"{name} error", "error")]))
    return "\n".join(parts) + "</section>"


def task_title(protocol: str, degradation: str, task: str) -> str:
    """``CS R>B``, ``RGB RGB-median``; the degradation of the right band when there is one."""
    return f"{protocol.upper()} {task}" + ("" if degradation == "none" else f", right band {degradation}")


def band_names(task: str) -> tuple[str, str]:
    """What the left and right pictures of a task show: ``R>B`` -> band R, band B."""
    if ">" in task:
        left, right = task.split(">", 1)
        return f"band {left}", f"band {right}"
    if task == "grey":
        return "grey (luminance)", "grey (luminance)"
    return "colour view", "colour view"


def score_list(names: list[str], values: list[str]) -> str:
    """A map's scores as a small two-column table (name, value), skipping missing values."""
    cells = "".join(f"<tr><td>{escape(name)}</td><td>{escape(value)}</td></tr>"
                    for name, value in zip(names, values) if value != "—")
    return f'<table class="scores">{cells}</table>'


def row(label: str, figures: list[str]) -> str:
    """A grid row: the label (HTML) then up to two pictures."""
    return f'<div class="row"><div class="label">{label}</div>{"".join(figures)}</div>'


def figure(picture: bytes, alt: str, caption: str) -> str:
    """An embedded PNG with its caption."""
    return f'<figure>{image(picture, alt)}<figcaption>{escape(caption)}</figcaption></figure>'


def band_pair(bands: tuple[bytes, bytes], alt: str, names: tuple[str, str]) -> str:
    """The left and right bands side by side, at half size, with one caption."""
    return (f'<figure class="bands"><div>{image(bands[0], f"{alt} left")}{image(bands[1], f"{alt} right")}</div>'
            f"<figcaption>left: {escape(names[0])}; right: {escape(names[1])}</figcaption></figure>")


def picture_width(picture: bytes) -> int:
    """Width (px) of an encoded picture (PNG: read from its header; JPEG: decoded)."""
    if picture[:8] == b"\x89PNG\r\n\x1a\n":
        return int.from_bytes(picture[16:20], "big")
    import cv2
    import numpy as np

    return int(cv2.imdecode(np.frombuffer(picture, np.uint8), cv2.IMREAD_UNCHANGED).shape[1])


def image(picture: bytes, alt: str) -> str:
    """An ``img`` element holding the picture (JPEG or PNG) as a base64 data URI (nothing to fetch)."""
    data = base64.b64encode(picture).decode("ascii")
    kind = "png" if picture[:4] == b"\x89PNG" else "jpeg"
    return f'<img src="data:image/{kind};base64,{data}" alt="{escape(alt)}">'


def html_table(caption: str, header: list[str], rows: list[list[str]],
               best: set[tuple[int, int]] = frozenset()) -> str:
    """A table under its title (wrapped to the table's width), with a header row and formatted
    cells, all escaped; the cells (row, column) in ``best`` marked ``class="best"``."""
    head = "".join(f"<th>{escape(cell)}</th>" for cell in header)
    body = "".join("<tr>" + "".join(f'<td class="best">{escape(cell)}</td>' if (index, column) in best
                                    else f"<td>{escape(cell)}</td>" for column, cell in enumerate(cells)) + "</tr>"
                   for index, cells in enumerate(rows))
    return (f'<div class="table"><p class="title">{escape(caption)}</p>'
            f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>")


def anchor(*parts: str) -> str:
    """An element id from names (letters, digits and dashes only)."""
    text = "-".join(parts)
    return "s-" + "".join(c if c.isalnum() else "-" for c in text)
