"""``cade batch``: many pairs, resumable, on worker processes or a Dask cluster (docs/scale.md).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli.cli.capture_radiometry import PanelAlbedoOption, PanelCornersOption
from cade_cli.cli.options import (
    DEFAULT_METHOD, MaxDispAutoOption, MethodOption, MinDispAutoOption, ModelOption, PreprocessOption,
    VisRangeOption, band_option, check_output, parse_memory_limit, parse_range_options, parse_vis_range, print_note,
)


def batch(
    left: Annotated[Optional[str], typer.Option("--left", help="Glob pattern of the left images, quoted (e.g. "
                                                "'cam0/*.png'); paired with --right by file name (or, without "
                                                "shared names, by the last number in the names).")] = None,
    right: Annotated[Optional[str], typer.Option("--right", help="Glob pattern of the right images, quoted.")] = None,
    output_dir: Annotated[Optional[Path], typer.Option("--output-dir", "-o", help="With --left/--right: folder for "
                                                       "the outputs, <left name>.<format> (created if missing); with "
                                                       "--captures, the cubes.")] = None,
    manifest: Annotated[Optional[Path], typer.Option("--manifest", help="CSV with a header row: left,right,output "
                                                     "and optionally min_disp,max_disp,left_band,right_band (empty = "
                                                     "the option's value); relative paths start at its folder.")] = None,
    output_format: Annotated[str, typer.Option("--format", help="With --left/--right: disparity format, pfm, tif, "
                                               "png (KITTI uint16) or npy.")] = "pfm",
    method: MethodOption = DEFAULT_METHOD,
    max_disp: MaxDispAutoOption = None,
    min_disp: MinDispAutoOption = "0",
    preprocess: PreprocessOption = "auto",
    model: ModelOption = None,
    fill: Annotated[str, typer.Option("--fill", help="As `cade disparity --fill`: 'row' (dense) or 'none'.")] = "row",
    left_band: Annotated[Optional[int], band_option("left")] = None,
    right_band: Annotated[Optional[int], band_option("right")] = None,
    vis: Annotated[bool, typer.Option("--vis", help="Also write <name>_vis.png (colourised, with a colour bar in px; "
                                      "invalid = black).")] = False,
    vis_range: VisRangeOption = None,
    validity: Annotated[bool, typer.Option("--validity", help="Also write <name>_validity.png (255 = valid).")] = False,
    confidence: Annotated[bool, typer.Option("--confidence", help="Also write <name>_confidence.tif (float32, "
                                             "[0, 1]).")] = False,
    memory_limit: Annotated[
        Optional[str], typer.Option("--memory-limit", help="Memory budget of each job, like 4GB or 512MB (default: "
                                    "half the memory available): a pair that does not fit it whole is matched as "
                                    "tiles, as by `cade disparity --memory-limit`; --jobs is lowered so that the "
                                    "jobs fit.", show_default=False)
    ] = None,
    rig_file: Annotated[
        Optional[Path], typer.Option("--rig", help="Rig file (`cade calibrate`): each LEFT is its reference camera's "
                                     "image, each RIGHT another camera's; every pair is rectified first, as by "
                                     "`cade disparity --rig` (docs/rigs.md).")
    ] = None,
    camera: Annotated[Optional[str], typer.Option("--camera", help="With --rig: the camera that took the RIGHT images "
                                                  "(default: the rig's rectified pair, else the first other "
                                                  "camera).")] = None,
    frame: Annotated[
        str, typer.Option("--frame", help="With --rig or --fix-vertical: outputs on the 'rectified' reference image, "
                          "or resampled onto the 'original' one (disparity stays in rectified px).")
    ] = "rectified",
    depth: Annotated[bool, typer.Option("--depth", help="With --rig: also write <name>_depth.tif (float32, metres, "
                                        "NaN unknown).")] = False,
    points: Annotated[bool, typer.Option("--points", help="With --rig: also write <name>_points.ply (binary PLY, "
                                         "metres, reference camera frame).")] = False,
    fix_vertical: Annotated[bool, typer.Option("--fix-vertical", help="Correct the vertical offset and roll before "
                                               "matching: with --rig, what the rectification self-check measures; "
                                               "without, the warp estimated from each pair (as cade rectify "
                                               "--uncalibrated; recorded in its .cade.json).")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="A pair the pair check finds unrectified, swapped or "
                                         "outside the range searched fails (nothing written for it) instead of "
                                         "warning.")] = False,
    jobs: Annotated[int, typer.Option("--jobs", "-j", min=1, help="Worker processes on this machine, each loading "
                                      "the model once; lowered if their memory would not fit.")] = 1,
    threads: Annotated[Optional[int], typer.Option("--threads", min=1, help="Threads of each worker (default: the "
                                                   "cores shared among --jobs; on a cluster, the workers' own).")] = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Run on a Dask cluster: its scheduler, "
                                                     "tcp://host:8786 (needs the 'distributed' extra; docs/scale.md).")] = None,
    scheduler_file: Annotated[Optional[Path], typer.Option("--scheduler-file", help="Run on the Dask cluster whose "
                                                           "scheduler wrote this file.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Redo every pair, even those verified as finished.")] = False,
    log: Annotated[Optional[Path], typer.Option("--log", help="JSON log of the run (default: cade-batch-log.json in "
                                                "--output-dir, or <manifest>.log.json).")] = None,
    captures: Annotated[Optional[Path], typer.Option("--captures", help="A drone flight's folder of band files "
                                                     "instead of pairs: one cube per capture (grouped by the capture "
                                                     "id in the metadata) in --output-dir, as register-capture writes "
                                                     "it; --vis adds its false-colour picture (docs/drone.md).",
                                                     file_okay=False, show_default=False)] = None,
    reference: Annotated[Optional[str], typer.Option("--reference", help="With --captures: the reference band "
                                                     "(default: Green).", show_default=False)] = None,
    bands: Annotated[Optional[str], typer.Option("--bands", help="With --captures: the bands to keep, by name, "
                                                 "separated by commas (e.g. 'Blue,Green,Red,NIR,Red edge').",
                                                 show_default=False)] = None,
    plane_only: Annotated[bool, typer.Option("--plane-only", help="With --captures: one homography per band, no "
                                             "parallax.")] = False,
    dtype: Annotated[str, typer.Option("--dtype", help="With --captures: float32, or uint16 with a .valid.tif mask "
                                       "beside each cube.")] = "float32",
    ndvi: Annotated[bool, typer.Option("--ndvi", help="With --captures: also write <name>_ndvi.png.")] = False,
    match_scale: Annotated[float, typer.Option("--match-scale", min=0.05, max=1.0, help="With --captures: dense "
                                               "matching at this fraction of the resolution.")] = 0.5,
    near: Annotated[float, typer.Option("--near", min=1.0, help="With --captures: each band's dense search reaches "
                                        "up to this many times the sparse matches' largest parallax, as "
                                        "register-capture --near; 1: the matches' own range.")] = 4.0,
    skip_panels: Annotated[bool, typer.Option("--skip-panels", help="With --captures: leave out the calibration "
                                              "panel shots (tagged Camera:CalibrationPicture, or named by --panel), "
                                              "with a note.")] = False,
    panel: Annotated[Optional[list[str]], typer.Option("--panel", help="With --captures: a panel shot, by capture "
                                                       "name, capture id or one of its band files (for cameras that "
                                                       "do not tag them: MicaSense); repeat it for several. With "
                                                       "--reflectance the first one's irradiance, measured once, "
                                                       "serves every capture of the flight.", metavar="NAME|FILE",
                                                       show_default=False)] = None,
    per_band: Annotated[Optional[Path], typer.Option("--per-band", help="With --captures: also write every capture's "
                                                     "aligned single-band TIFFs into this folder (the flight's "
                                                     "subfolders mirrored), named and tagged as their source files: "
                                                     "OpenDroneMap's multispectral input (docs/drone.md).",
                                                     file_okay=False, show_default=False)] = None,
    radiance: Annotated[bool, typer.Option("--radiance", help="With --captures: write radiance instead of raw "
                                           "values, every band by its own camera's radiometric model, as "
                                           "register-capture --radiance. float32 only.")] = False,
    reflectance: Annotated[bool, typer.Option("--reflectance", help="With --captures: write reflectance (pi * "
                                              "radiance / irradiance): the irradiance of each capture's own DLS "
                                              "tags, or with --panel the panel shot's for the whole flight (as "
                                              "MicaSense's flight workflow: right only under the panel shot's "
                                              "light). float32 only.")] = False,
    panel_corners: PanelCornersOption = None,
    panel_albedo: PanelAlbedoOption = None,
) -> None:
    """Disparity of many pairs: resumable, one pair failing does not stop the others, on N processes or a Dask cluster.

    A rerun skips every pair whose outputs are verified (sha256 and options in the record
    beside each output, <output>.cade.json); --force redoes them. The exit status is 1 if
    any pair failed. With --captures: a drone flight, one registered cube per capture (docs/drone.md).
    """
    from cade_cli.cli.batch_captures import Engine, FlightArguments, batch_captures, check_flight_sources
    from cade_cli.batch.engines import check_output_ranges, run_dask, run_local
    from cade_cli.batch.job import remove_stale_temporaries
    from cade_cli.batch.pairs import PairOptions, is_finished, skipped_result

    flight = FlightArguments(reference, plane_only, dtype, ndvi, match_scale, skip_panels, tuple(panel or ()),
                             bands=bands, per_band=per_band, radiance=radiance, reflectance=reflectance,
                             panel_corners=tuple(panel_corners or ()), panel_albedo=panel_albedo, near=near)
    check_flight_sources(captures, flight, left=left, right=right, manifest=manifest, rig=rig_file)
    if captures is not None:
        return batch_captures(captures, output_dir, flight, method=method, model=model, vis=vis, force=force, log=log,
                              engine=Engine(jobs, threads, scheduler, scheduler_file))
    by_pattern = (left, right, output_dir)
    _check_sources(manifest, by_pattern, scheduler, scheduler_file, jobs)
    cluster = scheduler is not None or scheduler_file is not None
    min_disp, max_disp = parse_range_options(min_disp, max_disp)
    options = PairOptions(method=method, min_disp=min_disp, max_disp=max_disp, preprocess=preprocess, model=model,
                          fill=fill, left_band=left_band, right_band=right_band,
                          memory_limit=None if memory_limit is None else parse_memory_limit(memory_limit),
                          rig=None if rig_file is None else str(rig_file.absolute()), camera=camera, frame=frame,
                          fix_vertical=fix_vertical, vis=vis, validity=validity, confidence=confidence, depth=depth,
                          points=points, vis_range=parse_vis_range(vis_range, vis), strict=strict)
    options.check()
    pairs, log = _pairs_and_log(options, manifest=manifest, left=left, right=right, output_dir=output_dir,
                                output_format=output_format, log=log)
    check_output(log, suffixes=(".json",), inputs=())
    check_output_ranges(pairs)  # a 16-bit PNG refuses a range beyond [0, 256) px before any pair runs
    remove_stale_temporaries(pairs)  # left by a run that was killed
    results = [] if force else [skipped_result(pair) for pair in pairs if is_finished(pair)]
    finished = {result.output for result in results}
    todo = [pair for pair in pairs if str(pair.output) not in finished]
    if todo and not cluster and jobs > 1:
        jobs = _jobs_that_fit(todo, jobs)
    engine_name = f"dask {scheduler or scheduler_file}" if cluster else f"{jobs} local job(s)"
    if threads is None and not cluster and jobs > 1:
        threads = max(1, (os.cpu_count() or 1) // jobs)
    engine = (run_dask(todo, address=scheduler, scheduler_file=scheduler_file, threads=threads) if cluster
              else run_local(todo, jobs=jobs, threads=threads))
    config = {"command": ["cade", *sys.argv[1:]] if sys.argv[1:2] == ["batch"] else None, "engine": engine_name,
              "manifest": None if manifest is None else str(manifest), "left": left, "right": right,
              "output_dir": None if output_dir is None else str(output_dir), "force": force,
              "rig": None if rig_file is None else str(rig_file),
              "options": {key: value for key, value in options.fingerprint().items()}}
    _run_pairs(todo, results, engine, total=len(pairs), engine_name=engine_name, log=log, config=config)


def _run_pairs(todo: list, results: list, engine, *, total: int, engine_name: str, log: Path, config: dict) -> None:
    """Run ``todo`` on ``engine`` (its results as they come) after the ``results`` of the pairs
    already finished (:func:`~cade_cli.cli.batch_run.run_jobs`: the bar or a line every 10 s, each
    result shown above it, the log), then the notes that repeated and the summary line; CadeError
    when a pair failed."""
    from cade_cli.cli.batch_run import run_jobs
    from cade_cli.errors import CadeError

    if results:
        print_note(f"{len(results)} of {total} pairs already finished (outputs verified); --force redoes them")
    shown_notes: dict[str, int] = {}
    summary = run_jobs(todo, results, engine, total=total, noun="pairs", label=f"batch ({engine_name})", log=log,
                       config=config, show=lambda console, result: _show_result(console, result, shown_notes))
    _show_repeated_notes(shown_notes)
    print(f"{summary.done} done, {summary.skipped} already finished, {summary.failed} failed, of {summary.total} pairs; "
          f"{summary.seconds:.1f} s ({summary.pairs_per_minute:.1f} pairs/min, {engine_name}); log {log}")
    if summary.failed:
        raise CadeError(f"{summary.failed} of {summary.total} pairs failed (each named above and in {log})")


def _pairs_and_log(options, *, manifest: Path | None, left: str | None, right: str | None, output_dir: Path | None,
                   output_format: str, log: Path | None) -> tuple[list, Path]:
    """The batch's pairs (from the manifest, or the two patterns into ``output_dir``, made if
    missing) and its log file (default: beside the manifest, or in ``output_dir``)."""
    from cade_cli.errors import CadeError
    from cade_cli.batch.pairs import pairs_from_manifest, pairs_from_patterns

    if manifest is not None:
        pairs = pairs_from_manifest(manifest, options=options)
        return pairs, log if log is not None else manifest.with_name(manifest.stem + ".log.json")
    pairs = pairs_from_patterns(left, right, output_dir, options=options, suffix="." + output_format.lower().lstrip("."))
    if output_dir.exists() and not output_dir.is_dir():
        raise CadeError(f"--output-dir {output_dir} is a file; give a folder")
    output_dir.mkdir(parents=True, exist_ok=True)
    return pairs, log if log is not None else output_dir / "cade-batch-log.json"


def _jobs_that_fit(todo: list, jobs: int) -> int:
    """``jobs``, lowered (with a note) until that many jobs of the largest pair fit the memory available."""
    from cade_cli.batch.engines import available_memory_bytes, cap_jobs, job_memory_bytes

    width, height, per_job = job_memory_bytes(todo)  # the largest pair, or the memory limit
    allowed = cap_jobs(jobs, per_job)
    if allowed < jobs:
        print_note(f"--jobs {jobs} lowered to {allowed}: the largest pair, {width}x{height}, may take "
                   f"{per_job / 2**30:.1f} GB per job (within its memory limit) and "
                   f"{available_memory_bytes() / 2**30:.1f} GB are available")
    return allowed


def _show_result(console, result, shown_notes: dict[str, int]) -> None:
    """Print what one finished pair has to say above the progress bar: its notes (each kind of
    note once per run, counted in ``shown_notes``: the same note about another pair's files is
    the same kind), the pair check's warnings, its failure or its range note."""
    def say(line: str) -> None:
        console.print(line, highlight=False, markup=False)

    for note in result.notes:
        kind = note.replace(str(result.left), "LEFT").replace(str(result.right), "RIGHT")
        shown_notes[kind] = shown_notes.get(kind, 0) + 1
        if shown_notes[kind] == 1:
            say(f"note: {note}")
    for warning in result.warnings:  # the pair check's findings
        say(f"warning: {result.output}: {warning}")
    if result.status == "failed":
        say(f"warning: pair {result.left}, {result.right} failed: {result.error}")
    elif result.range_note is not None:
        say(f"note: {result.output}: {result.range_note}")


def _show_repeated_notes(shown_notes: dict[str, int]) -> None:
    """After the run: how often each note shown once came up (``N`` pairs' files in all)."""
    for kind, count in shown_notes.items():
        if count > 1:
            print_note(f"{count} pairs in this run had the note shown once above: {kind}")


def _check_sources(manifest: Path | None, by_pattern: tuple, scheduler: str | None, scheduler_file: Path | None,
                   jobs: int) -> None:
    """Refuse a manifest given with patterns, patterns given in part, two schedulers, or --jobs on a cluster."""
    from cade_cli.errors import CadeError

    if manifest is not None and any(value is not None for value in by_pattern):
        raise CadeError("give either --manifest or --left, --right and --output-dir, not both")
    if manifest is None and any(value is None for value in by_pattern):
        missing = [name for name, value in zip(("--left", "--right", "--output-dir"), by_pattern) if value is None]
        raise CadeError(f"missing {', '.join(missing)}: give --left 'A/*.png' --right 'B/*.png' --output-dir OUT, or "
                        "--manifest pairs.csv")
    if scheduler is not None and scheduler_file is not None:
        raise CadeError("give --scheduler or --scheduler-file, not both")
    if (scheduler is not None or scheduler_file is not None) and jobs != 1:
        raise CadeError("--jobs sets processes on this machine; on a cluster the workers' own --nworkers do; drop --jobs")


