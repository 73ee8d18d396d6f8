"""The ``cade`` command: a thin layer over the library that parses, validates and prints.

Heavy modules (NumPy, OpenCV, the matchers) are imported inside the commands, so
``cade --help`` and ``cade --version`` answer at once. Any user error ends as one line
on stderr and a non-zero exit; outputs are written atomically and only at the end.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli import __version__

METHOD_NAMES = ("census-sgm", "zncc-sgm", "sgbm", "cade", "cade-network")
"""Registered matchers, listed here so that --help needs no heavy import (a test keeps
this in step with :data:`cade_cli.matching.MATCHERS`)."""
BENCHMARK_METHODS = METHOD_NAMES[:4]
"""What ``cade benchmark`` compares by default: the four matchers (cade-network is cade's
first stage, there to analyse the network; name it with --methods)."""
DEFAULT_METHOD = "cade"
"""The default matcher, here so that --help needs no heavy import (a test keeps it equal
to :data:`cade_cli.stereo.DEFAULT_METHOD`)."""

EXIT_INPUT_ERROR = 1
EXIT_USAGE_ERROR = 2

app = typer.Typer(
    name="cade",
    help="Cross-spectral stereo: disparity between bands seen through different filters, and band registration.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        print(f"cade {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """Cross-spectral stereo toolkit (CADE, ICASSP 2024)."""


MethodOption = Annotated[
    str,
    typer.Option(
        "--method",
        "-m",
        help=f"Matcher: {', '.join(METHOD_NAMES)}. The default, cade (the CADE network), has the lowest error "
        "of the four on the cross-spectral benchmark and is about 3x faster than census-sgm, the best "
        "classical one (docs/results.md).",
    ),
]
MaxDispOption = Annotated[
    Optional[int],
    typer.Option("--max-disp", min=1, help="Largest disparity searched, px (default: a quarter of the width)."),
]
MinDispOption = Annotated[
    int, typer.Option("--min-disp", help="Smallest disparity searched, px; negative for pairs registered to a plane.")
]
ModelOption = Annotated[
    Optional[str],
    typer.Option("--model", help="Network of the learned methods: the path of a model card (.json, its ONNX files "
                 "beside it, as `python -m cade_cli.train export` writes them) or a card name in the model folder "
                 "($CADE_MODEL_DIR, default the shipped models/). Default: the shipped cade-v4."),
]
PreprocessOption = Annotated[
    str,
    typer.Option(
        "--preprocess",
        help="'cade' (color agnostic transform on both bands), 'none', or 'auto': the matcher's more "
        "accurate choice on cross-spectral pairs (census-sgm, zncc-sgm: none; sgbm, cade: cade).",
    ),
]


def _band_option(side: str) -> object:
    return typer.Option(f"--{side}-band", min=0, help=f"0-based band of a multi-band {side} file (default: luminance of colour images).")


@app.command()
def disparity(
    left: Annotated[Path, typer.Argument(help="Reference (left) image.", show_default=False)],
    right: Annotated[Path, typer.Argument(help="Other (right) image, possibly another band.", show_default=False)],
    output: Annotated[Path, typer.Option("--output", "-o", help="Disparity file: .pfm, .tif, .png (KITTI uint16) or .npy.")],
    method: MethodOption = DEFAULT_METHOD,
    max_disp: MaxDispOption = None,
    min_disp: MinDispOption = 0,
    preprocess: PreprocessOption = "auto",
    model: ModelOption = None,
    vis: Annotated[Optional[Path], typer.Option("--vis", help="Also write a colourised PNG (invalid = black).")] = None,
    left_band: Annotated[Optional[int], _band_option("left")] = None,
    right_band: Annotated[Optional[int], _band_option("right")] = None,
    fill: Annotated[
        str, typer.Option("--fill", help="Pixels the matcher rejected: 'row' (filled from the background side "
                          "along the row; dense output) or 'none' (written as the format's invalid marker).")
    ] = "row",
    validity: Annotated[
        Optional[Path], typer.Option("--validity", help="Also write the validity mask: PNG (255 = valid, 0 = rejected) "
                                     "or TIFF (uint8 1/0).")
    ] = None,
    confidence: Annotated[
        Optional[Path], typer.Option("--confidence", help="Also write the matcher's confidence: float32 TIFF in [0, 1], "
                                     "higher = more trusted, 0 = rejected; keep pixels above a threshold to mask what "
                                     "the matcher is unsure of (README: what each method measures).")
    ] = None,
) -> None:
    """Disparity of LEFT against RIGHT, written to OUTPUT."""
    from cade_cli.disparity_io import (
        DISPARITY_SUFFIXES,
        VALIDITY_SUFFIXES,
        write_disparity,
        write_validity,
        write_visualization,
    )
    from cade_cli.atomic import atomic_outputs
    from cade_cli.errors import CadeError
    from cade_cli.matching import densify, get_matcher
    from cade_cli.stereo import estimate_disparity

    if fill not in ("row", "none"):
        raise CadeError(f"unknown --fill {fill!r}; choose row or none")
    _check_output(output, suffixes=DISPARITY_SUFFIXES, inputs=(left, right))
    if confidence is not None and confidence.suffix.lower() not in (".tif", ".tiff"):
        raise CadeError(f"cannot write --confidence {confidence}: the confidence is a float32 TIFF; "
                        f"name it .tif or .tiff")
    for option, side_output, suffixes in (("--vis", vis, (".png",)), ("--validity", validity, VALIDITY_SUFFIXES),
                                          ("--confidence", confidence, (".tif", ".tiff"))):
        if side_output is not None:
            _check_output(side_output, suffixes=suffixes, inputs=(left, right))
            if side_output.resolve() == output.resolve():
                raise CadeError(f"{option} {side_output} is the same file as --output; give it another name")
    if vis is not None and validity is not None and vis.resolve() == validity.resolve():
        raise CadeError(f"--vis and --validity both name {vis}; give them different names")
    if confidence is not None and validity is not None and confidence.resolve() == validity.resolve():
        raise CadeError(f"--confidence and --validity both name {confidence}; give them different names")
    left_image, right_image = _read_pair(left, right, left_band, right_band)
    started = time.perf_counter()
    max_disp = _resolve_max_disp(max_disp, left_image.shape[1])
    result = estimate_disparity(
        left_image, right_image, method=method, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess,
        model=model,
    )
    seconds = time.perf_counter() - started
    preprocess = get_matcher(method).resolve_preprocess(preprocess)
    dense = densify(result.disparity, result.valid)
    _warn_if_textureless(left, right, left_image, right_image)
    if confidence is not None and result.confidence is None:
        raise CadeError(f"method {method} gives no confidence; drop --confidence")
    with atomic_outputs([output, vis, validity, confidence]) as staged:  # all outputs appear together, or none
        write_disparity(staged[output], dense if fill == "row" else result.disparity)
        if vis is not None:
            write_visualization(staged[vis], result.disparity)
        if validity is not None:
            write_validity(staged[validity], result.valid)
        if confidence is not None:  # a float32 TIFF, by the disparity writer (no NaN: 0 where rejected)
            write_disparity(staged[confidence], result.confidence)
    height, width = dense.shape
    print(
        f"{output}: {width}x{height}, {method}+{preprocess}, searched [{min_disp}, {max_disp}], "
        f"disparity {float(dense.min()):.2f}..{float(dense.max()):.2f} px, "
        f"valid {100.0 * result.valid.mean():.1f}%, fill {fill}, {seconds:.2f} s"
    )


@app.command()
def register(
    context: typer.Context,
    moving: Annotated[Path, typer.Argument(help="Band to warp (right view).", show_default=False)],
    reference: Annotated[Path, typer.Argument(help="Reference band (left view).", show_default=False)],
    output: Annotated[Path, typer.Option("--output", "-o", help="Float32 TIFF: reference, registered, validity bands.")],
    disparity_file: Annotated[
        Optional[Path], typer.Option("--disparity", help="Use this reference-view disparity instead of estimating it "
                                     "(its invalid markers -- inf, NaN, 0 in PNG -- are not trusted).")
    ] = None,
    validity_file: Annotated[
        Optional[Path], typer.Option("--validity", help="With --disparity: the validity mask `cade disparity "
                                     "--validity` wrote; only its valid pixels are trusted.")
    ] = None,
    method: MethodOption = DEFAULT_METHOD,
    max_disp: MaxDispOption = None,
    min_disp: MinDispOption = 0,
    preprocess: PreprocessOption = "auto",
    model: ModelOption = None,
    fill: Annotated[
        str, typer.Option("--fill", help="Occluded pixels: 'row' (background along the row) or 'none' (NaN).")
    ] = "row",
    moving_band: Annotated[Optional[int], typer.Option("--moving-band", min=0, help="0-based band of the moving file.")] = None,
    reference_band: Annotated[
        Optional[int], typer.Option("--reference-band", min=0, help="0-based band of the reference file.")
    ] = None,
) -> None:
    """Warp MOVING into the view of REFERENCE and write both as one multi-band TIFF."""
    from cade_cli.disparity_io import read_disparity
    from cade_cli.registration import register as register_band
    from cade_cli.registration_io import write_registration

    from cade_cli.errors import CadeError

    inputs = tuple(p for p in (moving, reference, disparity_file, validity_file) if p is not None)
    _check_output(output, suffixes=(".tif", ".tiff"), inputs=inputs)
    if validity_file is not None and disparity_file is None:
        raise CadeError("--validity needs --disparity (it masks that map); drop it or give the disparity file")
    if fill not in ("row", "none"):
        raise CadeError(f"unknown --fill {fill!r}; choose row or none")
    if disparity_file is not None:
        estimation = [f"--{name.replace('_', '-')}" for name in ("method", "max_disp", "min_disp", "preprocess", "model")
                      if context.get_parameter_source(name).name != "DEFAULT"]
        if estimation:
            named = " and ".join([", ".join(estimation[:-1]), estimation[-1]] if len(estimation) > 1 else estimation)
            verb, pronoun = ("apply", "them") if len(estimation) > 1 else ("applies", "it")
            raise CadeError(f"{named} only {verb} when the disparity is estimated, but --disparity gives it; drop "
                            f"{pronoun} or --disparity")
    else:
        from cade_cli.matching import get_matcher

        get_matcher(method).resolve_preprocess(preprocess)  # refuse unknown names before reading anything
    reference_image, moving_image = _read_pair(
        reference, moving, reference_band, moving_band, names=("--reference-band", "--moving-band")
    )
    started = time.perf_counter()
    if disparity_file is not None:
        from cade_cli.disparity_io import read_validity

        trusted = read_validity(validity_file) if validity_file is not None else None
        result = register_band(moving_image, reference_image, disparity=read_disparity(disparity_file),
                               disparity_valid=trusted, fill=fill, disparity_name=str(disparity_file))
        source = f"disparity from {disparity_file}" + (f", validity from {validity_file}" if trusted is not None else "")
    else:
        max_disp = _resolve_max_disp(max_disp, reference_image.shape[1])
        result = register_band(
            moving_image, reference_image, method=method, max_disp=max_disp, min_disp=min_disp,
            preprocess=preprocess, fill=fill, model=model,
        )
        from cade_cli.matching import get_matcher

        source = f"{method}+{get_matcher(method).resolve_preprocess(preprocess)} over [{min_disp}, {max_disp}]"
        _warn_if_textureless(reference, moving, reference_image, moving_image)
    seconds = time.perf_counter() - started
    write_registration(output, result)
    height, width = result.reference.shape
    print(f"{output}: {width}x{height}, {source}, fill {fill}, valid {100.0 * result.valid.mean():.1f}%, {seconds:.2f} s")


@app.command()
def benchmark(
    dataset: Annotated[str, typer.Option("--dataset", "-d", help="middlebury05, middlebury06, middlebury14, flyingthings3d, kitti2012, kitti2015 or folder.")],
    data_dir: Annotated[Path, typer.Option("--data-dir", help="Folder holding the dataset in its official layout.")],
    methods: Annotated[str, typer.Option("--methods", help="Comma-separated matchers.")] = ",".join(BENCHMARK_METHODS),
    protocol: Annotated[str, typer.Option("--protocol", help="Comma-separated: cs (six band pairs), rgb (median of R/G/B), native (grey pair).")] = "cs,rgb",
    preprocess: Annotated[str, typer.Option("--preprocess", help="Comma-separated: none, cade, auto.")] = "none,cade",
    scenes: Annotated[Optional[str], typer.Option("--scenes", help="Comma-separated scene names (default: all).")] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", min=1, help="Worker processes.")] = 1,
    json_file: Annotated[Optional[Path], typer.Option("--json", help="Write every number as JSON.")] = None,
    report: Annotated[Optional[Path], typer.Option("--report", help="Write a Markdown report.")] = None,
    save_dir: Annotated[Optional[Path], typer.Option("--save-dir", help="Write each disparity (PFM) and error map (PNG) here.")] = None,
    model: ModelOption = None,
) -> None:
    """Score matchers on a dataset with the paper's protocols (CS, RGB) and print a Table-1-style summary."""
    import shlex

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from cade_cli.atomic import atomic_outputs
    from cade_cli.evaluation.loop import run_benchmark
    from cade_cli.evaluation.report import confidence_table, confidence_title, markdown, pixel_sets, table, title
    from cade_cli.errors import CadeError
    from cade_cli.matching import LEARNED_METHODS, MATCHERS, get_matcher

    for path, suffix in ((json_file, ".json"), (report, ".md")):
        if path is not None:
            _check_output(path, suffixes=(suffix,), inputs=())
    split = lambda text: [item.strip() for item in text.split(",") if item.strip()]  # noqa: E731
    for option, value in (("--methods", methods), ("--protocol", protocol), ("--preprocess", preprocess),
                          ("--scenes", scenes)):
        if value is not None and not split(value):
            raise CadeError(f"{option} {value!r} names nothing; give comma-separated names, or leave it out for the default")
    console = Console(stderr=True)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    # Every output is checked before the run and staged during it; all appear at the end, or none.
    with atomic_outputs([json_file, report], folders=[save_dir]) as staged:
        with Progress(*columns, console=console, transient=True, disable=not console.is_terminal) as progress:
            bar = progress.add_task(f"benchmark {dataset}", total=None)

            def advance(scene: str, records: list) -> None:
                progress.update(bar, advance=1, description=f"{dataset} {scene} done")

            learned = [name for name in split(methods) if name in LEARNED_METHODS]
            if model is not None and not learned:
                raise CadeError(f"--model applies to {', '.join(LEARNED_METHODS)}; add one to --methods")
            matchers = {**MATCHERS, **{name: get_matcher(name, model=model) for name in learned}}
            run = run_benchmark(
                dataset=dataset, data_dir=data_dir, methods=split(methods), protocols=split(protocol),
                preprocess=split(preprocess), scenes=None if scenes is None else split(scenes), jobs=jobs,
                save_dir=None if save_dir is None else staged[save_dir], on_scene_done=advance, matchers=matchers,
                on_start=lambda total: progress.update(bar, total=total),
            )
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
        command = shlex.join(["cade", *sys.argv[1:]]) if sys.argv[1:2] == ["benchmark"] else None
        if json_file is not None:
            staged[json_file].write_text(run.to_json())
        if report is not None:
            staged[report].write_text(markdown(run, command=command))


datasets_app = typer.Typer(
    help="List the benchmark datasets and download them from their official hosts.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
app.add_typer(datasets_app, name="datasets")


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


def _read_pair(
    left: Path, right: Path, left_band: int | None, right_band: int | None,
    names: tuple[str, str] = ("--left-band", "--right-band"),
):
    from cade_cli.imageio import read_band

    images = []
    for path, band, option in ((left, left_band, names[0]), (right, right_band, names[1])):
        image, note = read_band(path, band)
        if note:
            _note(f"{note}; pick a band with {option} N")
        images.append(image)
    return images


def _warn_if_textureless(left: Path, right: Path, left_image, right_image) -> None:
    """Warn when much of the pair is flat (:func:`cade_cli.stereo.textureless`): no disparity there."""
    from cade_cli.stereo import TEXTURE_WINDOW, textureless

    flat = textureless(left_image) | textureless(right_image)
    share = float(flat.mean())
    if share == 1.0:
        _warn(f"{left} and {right} have no texture at all (constant images?): there is no disparity to find and "
              "every pixel is marked invalid; check that these are the right, correctly exposed images")
    elif share >= 0.5:
        _warn(f"{100 * share:.0f}% of {left} / {right} is flat (one value over {TEXTURE_WINDOW}x{TEXTURE_WINDOW} px "
              "in a band: blank, saturated or underexposed); disparity there is marked invalid")


def _resolve_max_disp(max_disp: int | None, width: int) -> int:
    from cade_cli.stereo import default_max_disparity

    if max_disp is not None:
        return max_disp
    chosen = default_max_disparity(width)
    _note(f"--max-disp not given: searching up to {chosen} px (a quarter of the width); "
          "set it to your scene's largest disparity for speed and accuracy")
    return chosen


def _check_output(path: Path, *, suffixes: tuple[str, ...], inputs: tuple[Path, ...]) -> None:
    """Refuse, before any work, outputs we could not write or must not overwrite."""
    from cade_cli.atomic import check_writable
    from cade_cli.errors import CadeError

    if path.suffix.lower() not in suffixes:
        raise CadeError(f"cannot write {path}: unsupported extension {path.suffix or '(none)'}; use one of {', '.join(suffixes)}")
    check_writable(path)  # the folder exists, is one, and takes new files; path is not a folder
    for source in inputs:
        if source.exists() and path.exists() and path.resolve() == source.resolve():
            raise CadeError(f"output {path} is also an input; choose another output name")


def _note(message: str) -> None:
    print(f"note: {message}", file=sys.stderr)


def _warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, turning every user error into one stderr line."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")  # decoders would print their own warnings
    from cade_cli.allocator import retain_freed_memory
    from cade_cli.errors import CadeError

    retain_freed_memory()

    argv = sys.argv[1:] if argv is None else argv
    try:
        code = app(args=argv or ["--help"], standalone_mode=False)
    except CadeError as error:
        _fail(str(error), EXIT_INPUT_ERROR)
    except typer.TyperException as error:  # usage errors: unknown option, bad value, ...
        _fail(f"{error.format_message().rstrip('.')}; see 'cade --help'", getattr(error, "exit_code", EXIT_USAGE_ERROR))
    except (typer.Abort, KeyboardInterrupt):
        _fail("interrupted", 130)
    except MemoryError:
        _fail("out of memory; lower --max-disp or downscale the images", EXIT_INPUT_ERROR)
    sys.exit(code if isinstance(code, int) else 0)


def _fail(message: str, code: int) -> None:
    print(f"cade: error: {message.splitlines()[0] if message else 'failed'}", file=sys.stderr)
    sys.exit(code)
