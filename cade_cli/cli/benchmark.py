"""``cade benchmark`` (matchers against ground truth) and ``cade datasets`` (list and download the
benchmark data).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli.cli.options import BENCHMARK_METHODS, StepBar, check_output, print_note


def benchmark(
    dataset: Annotated[str, typer.Option("--dataset", "-d", help="middlebury05, middlebury06, middlebury14, flyingthings3d, kitti2012, kitti2015, msir-outdoor or folder.")],
    data_dir: Annotated[Path, typer.Option("--data-dir", help="Folder holding the dataset in its official layout.")],
    methods: Annotated[str, typer.Option("--methods", help="Comma-separated matchers.")] = ",".join(BENCHMARK_METHODS),
    protocol: Annotated[Optional[str], typer.Option("--protocol", help="Comma-separated: cs (six band pairs), rgb (median of R/G/B), native (grey pair). Default: cs,rgb; native for msir-outdoor (its pairs are already cross-spectral).", show_default=False)] = None,
    preprocess: Annotated[str, typer.Option("--preprocess", help="Comma-separated: none, cade, auto.")] = "none,cade",
    scenes: Annotated[Optional[str], typer.Option("--scenes", help="Comma-separated scene names (default: all).")] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", min=1, help="Worker processes.")] = 1,
    json_file: Annotated[Optional[Path], typer.Option("--json", help="Write every number as JSON.")] = None,
    report: Annotated[Optional[Path], typer.Option("--report", help="Write a Markdown report.")] = None,
    html: Annotated[Optional[Path], typer.Option("--html", help="Write an HTML report: the tables, and per scene and "
                                                 "task the bands, each method's disparity and error pictures "
                                                 "(one self-contained file).")] = None,
    html_pictures: Annotated[str, typer.Option("--html-pictures", help="With --html: pictures of one task per scene "
                                               "('scene', its first task; the tables score every task) or of "
                                               "every task ('all', a much larger page).")] = "scene",
    save_dir: Annotated[Optional[Path], typer.Option("--save-dir", help="Write each disparity (PFM) and error map (PNG) here.")] = None,
    model: Annotated[Optional[str], typer.Option("--model", help="Network(s) of the learned methods, as for `cade "
                                                 "disparity --model`; several, comma-separated, score each learned "
                                                 "method once per model in the same run (rows METHOD:MODEL, e.g. "
                                                 "cade:cade-v4, cade:runs/x.json -> cade:x).")] = None,
) -> None:
    """Score matchers on a dataset with the paper's protocols (CS, RGB) and print a Table-1-style summary."""
    import shlex

    from cade_cli.data import get_dataset
    from cade_cli.errors import CadeError
    from cade_cli.evaluation.album import TILE_WIDTH
    from cade_cli.evaluation.html_report import html_report
    from cade_cli.evaluation.loop import run_benchmark
    from cade_cli.evaluation.report import left_out, markdown
    from cade_cli.io.atomic import atomic_outputs

    from cade_cli.evaluation.album import PICTURE_SETS

    if html_pictures not in PICTURE_SETS:
        raise CadeError(f"unknown --html-pictures {html_pictures!r}; choose {' or '.join(PICTURE_SETS)}")
    if html is None and html_pictures != "scene":
        raise CadeError("--html-pictures says which pictures --html shows; add --html REPORT.html or drop it")
    if protocol is None:
        protocol = ",".join(get_dataset(dataset).default_protocols)
    for path, suffixes in ((json_file, (".json",)), (report, (".md",)), (html, (".html", ".htm"))):
        if path is not None:
            check_output(path, suffixes=suffixes, inputs=())
    split = lambda text: [item.strip() for item in text.split(",") if item.strip()]  # noqa: E731
    for option, value in (("--methods", methods), ("--protocol", protocol), ("--preprocess", preprocess),
                          ("--scenes", scenes)):
        if value is not None and not split(value):
            raise CadeError(f"{option} {value!r} names nothing; give comma-separated names, or leave it out for the default")
    # Every output is checked before the run and staged during it; all appear at the end, or none.
    with atomic_outputs([json_file, report, html], folders=[save_dir]) as staged:
        with StepBar(None, f"benchmark {dataset}", plain=True, noun="tasks") as bar:  # one step per matcher run
            chosen, matchers = benchmark_matchers(split(methods), model)
            run = run_benchmark(
                dataset=dataset, data_dir=data_dir, methods=chosen, protocols=split(protocol),
                preprocess=split(preprocess), scenes=None if scenes is None else split(scenes), jobs=jobs,
                save_dir=None if save_dir is None else staged[save_dir], matchers=matchers,
                tile_width=None if html is None else TILE_WIDTH, pictures=html_pictures,
                on_start=bar.set_total,
                on_run=lambda done: bar.advance(f"{dataset} {done}"),
            )
        if left_out(run):
            print_note(f"left out, as they do not apply: {left_out(run)}")
        print_tables(run)
        command = shlex.join(["cade", *sys.argv[1:]]) if sys.argv[1:2] == ["benchmark"] else None
        if json_file is not None:
            staged[json_file].write_text(run.to_json())
        if report is not None:
            staged[report].write_text(markdown(run, command=command))
        if html is not None:
            staged[html].write_text(html_report(run, command=command), encoding="utf-8")


def benchmark_matchers(methods: list[str], model: str | None) -> tuple[list[str], dict]:
    """The rows ``cade benchmark`` scores and the matcher of each: ``methods`` as named, the
    learned ones on the one ``--model`` given, or with several (comma-separated) one row per
    learned method and model, ``METHOD:MODEL``."""
    from cade_cli.errors import CadeError
    from cade_cli.matching import LEARNED_METHODS, MATCHERS, get_matcher

    learned = [name for name in methods if name in LEARNED_METHODS]
    if model is not None and not learned:
        raise CadeError(f"--model applies to {', '.join(LEARNED_METHODS)}; add one to --methods")
    models = [item.strip() for item in model.split(",") if item.strip()] if model is not None else []
    if model is not None and not models:
        raise CadeError(f"--model {model!r} names nothing; give a model, or leave it out for the shipped one")
    chosen, matchers = methods, dict(MATCHERS)
    if len(models) == 1:
        matchers.update({name: get_matcher(name, model=models[0]) for name in learned})
    elif models:  # one row per learned method and model: METHOD:MODEL
        labels = [Path(name).stem if name.endswith(".json") else name for name in models]
        if len(set(labels)) != len(labels):
            raise CadeError(f"--model names two models called the same ({', '.join(labels)}); rename a card")
        chosen = [f"{name}:{label}" if name in learned else name
                  for name in chosen for label in (labels if name in learned else [None])]
        matchers.update({f"{name}:{label}": get_matcher(name, model=path)
                         for name in learned for label, path in zip(labels, models)})
    return chosen, matchers


def print_tables(run) -> None:
    """The benchmark's tables on stdout: one per pixel set, then how well each matcher's
    confidence ranks its errors (where any matcher gives a confidence)."""
    from rich.console import Console
    from rich.table import Table

    from cade_cli.evaluation.report import confidence_table, confidence_title, pixel_sets, table, title

    out = Console()
    tables = [(title(run, pixels), *table(run, pixels)) for pixels in pixel_sets(run)]
    confidence = confidence_table(run)  # how well each matcher's confidence ranks its errors
    if confidence is not None:
        tables.append((confidence_title(run), *confidence))
    for heading, header, rows in tables:
        rich_table = Table(title=heading, title_justify="left")
        for i, name in enumerate(header):
            rich_table.add_column(name, justify="left" if i == 0 else "right", no_wrap=i == 0)
        for row in rows:
            rich_table.add_row(*row)
        out.print(rich_table)


datasets_app = typer.Typer(
    help="List the benchmark datasets and download them from their official hosts.",
    no_args_is_help=True,
    rich_markup_mode=None,
)


@datasets_app.command("list")
def datasets_list() -> None:
    """Each dataset: what a download holds, its approximate size and where it comes from."""
    from cade_cli.data import SOURCES

    width = max(len(name) for name in SOURCES) + 2
    for source in SOURCES.values():
        sizes = ", ".join(f"{key} {size}" if key else size for key, size in source.sizes.items())
        print(f"{source.name:<{width}}{source.contents} [{sizes}]")
        print(f"{'':<{width}}{source.source}")
    print("download with: cade datasets download NAME --to DIR (Middlebury: --resolution Q|H|F); read with --data-dir DIR")


@datasets_app.command("download")
def datasets_download(
    name: Annotated[str, typer.Argument(help="middlebury05, middlebury06, middlebury14, kitti2012 or kitti2015.", show_default=False)],
    to: Annotated[Path, typer.Option("--to", help="Data folder; the dataset lands in its usual subfolder, read with --data-dir DIR.")],
    resolution: Annotated[
        Optional[str],
        typer.Option("--resolution", help="Middlebury only: Q, H or F (default Q; 2005/2006: Q = ThirdSize).", show_default=False),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Download and unpack again even if the files are in place.")] = False,
) -> None:
    """Download dataset NAME into DIR (resuming an interrupted download) and check its files."""
    from contextlib import nullcontext

    from rich.console import Console

    from cade_cli.data import download_dataset, download_progress, get_source

    resolution = resolution.upper() if resolution else None
    get_source(name).archives(resolution)  # refuse a bad request before any output
    console = Console(stderr=True)
    progress = download_progress(console) if console.is_terminal else None  # no bars in logs
    with progress if progress is not None else nullcontext():
        report = download_dataset(name, to, resolution=resolution, force=force, progress=progress)
    at = f" ({report.resolution})" if report.resolution else ""
    if report.already_present:
        print(f"{name}{at}: already present in {report.folder}; use --data-dir {to}")
    else:
        print(
            f"{name}{at}: {len(report.downloaded)} archive(s) downloaded ({report.bytes_downloaded / 1e6:.1f} MB), "
            f"{len(report.extracted)} unpacked, {len(report.present)} already present, in {report.folder}; "
            f"use --data-dir {to}"
        )
