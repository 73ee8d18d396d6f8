"""The HTML report of a benchmark run: one self-contained page a person looks at.

The page carries what made the numbers (cade version, dataset, date, the command line and
each network's name and sha256), the tables of the Markdown report
(:mod:`cade_cli.evaluation.report`, the same rows), and per scene and task the two bands
that were matched, then per method its disparity picture and its error picture side by
side, with that map's scores beside them. The pictures come from the run's albums
(:class:`~cade_cli.evaluation.album.SceneAlbum`, kept by ``run_benchmark(tile_width=...)``)
and are embedded as base64 PNG data URIs, so the page is one file that can be mailed.
Plain string formatting; every text from the run is escaped.
"""

from __future__ import annotations

import base64
from datetime import datetime, timezone
from html import escape

from cade_cli.errors import CadeError
from cade_cli.evaluation.album import TILE_WIDTH, SceneAlbum, map_key
from cade_cli.evaluation.loop import BenchmarkRun, Record
from cade_cli.evaluation.report import (
    confidence_table, confidence_title, left_out, pixel_sets, record_table, table, title,
)

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
        header(run, command=command, created=created), tables(run), pictures(run, width=width),
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def header(run: BenchmarkRun, *, command: str | None, created: datetime) -> str:
    """The provenance table: version, date, command line, dataset, configuration, models."""
    from cade_cli import __version__

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
    """The summary tables of the Markdown report (means over scenes and tasks)."""
    parts = [html_table(title(run, pixels), *table(run, pixels)) for pixels in pixel_sets(run)]
    confidence = confidence_table(run)
    if confidence is not None:
        parts.append(html_table(confidence_title(run), *confidence))
    return '<h2>Results</h2><div class="tables">' + "".join(parts) + "</div>"


def pictures(run: BenchmarkRun, *, width: int) -> str:
    """Per scene: its ground truth, then per task the bands and each method's maps, then
    every record's scores (the Markdown report's last table)."""
    header_cells, rows = record_table(run)
    scores = {id(record): row for record, row in zip(run.records, rows)}
    groups: dict[str, dict[tuple[str, str, str], list[Record]]] = {}
    for record in run.records:  # in scene, protocol, method, ... order: group by scene and task
        key = (record.protocol, record.degradation, record.task)
        groups.setdefault(record.scene, {}).setdefault(key, []).append(record)
    links = "".join(
        f'<p><a href="#{anchor(scene)}"><b>{escape(scene)}</b></a> '
        + " ".join(f'<a href="#{anchor(scene, *key)}">{escape(task_title(*key))}</a>' for key in tasks) + "</p>"
        for scene, tasks in groups.items())
    parts = [
        "<h2>Pictures</h2>",
        f'<p class="note">Pictures at most {width} px wide (maps downscaled by nearest neighbour, bands by area); '
        "numbers at full resolution. The disparity pictures of a scene share its ground truth's colour range, so "
        "that methods compare. EPE in px; BMP3, D1 in % of the pixels with ground truth.</p>",
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
    tile = "" if album is None else f' style="--tile: {png_width(album.ground_truth)}px"'
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


def png_width(picture: bytes) -> int:
    """Width (px) of a PNG, read from its header (IHDR, right after the 8-byte signature)."""
    return int.from_bytes(picture[16:20], "big")


def image(picture: bytes, alt: str) -> str:
    """An ``img`` element holding the PNG as a base64 data URI (nothing to fetch)."""
    data = base64.b64encode(picture).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{escape(alt)}">'


def html_table(caption: str, header: list[str], rows: list[list[str]]) -> str:
    """A table under its title (wrapped to the table's width), with a header row and formatted
    cells, all escaped."""
    head = "".join(f"<th>{escape(cell)}</th>" for cell in header)
    body = "".join("<tr>" + "".join(f"<td>{escape(cell)}</td>" for cell in cells) + "</tr>" for cells in rows)
    return (f'<div class="table"><p class="title">{escape(caption)}</p>'
            f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>")


def anchor(*parts: str) -> str:
    """An element id from names (letters, digits and dashes only)."""
    text = "-".join(parts)
    return "s-" + "".join(c if c.isalnum() else "-" for c in text)
