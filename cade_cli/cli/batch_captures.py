"""``cade batch --captures FLIGHT``: a drone flight's captures registered into one cube each, on the
engines of the pair batch (worker processes or a Dask cluster), resumable (docs/drone.md, "A whole flight").
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

from cade_cli.cli.options import print_note


@dataclass(frozen=True)
class FlightArguments:
    """The options of ``cade batch`` that only a flight takes (register-capture's, and the panels')."""

    reference: str | None = None
    plane_only: bool = False
    dtype: str = "float32"
    ndvi: bool = False
    match_scale: float = 0.5
    skip_panels: bool = False
    panels: tuple[str, ...] = ()
    bands: str | None = None
    per_band: Path | None = None
    radiance: bool = False
    reflectance: bool = False
    panel_corners: tuple[str, ...] = ()
    panel_albedo: str | None = None
    near: float = 4.0

    def given(self) -> list[str]:
        """The options given a value other than their default, as the user writes them."""
        return [f"--{name.replace('_', '-')}".replace("--panels", "--panel") for name, value in vars(self).items()
                if value != getattr(FlightArguments, name)]


@dataclass(frozen=True)
class Engine:
    """Where the jobs run: ``jobs`` local processes with ``threads`` each, or a Dask scheduler."""

    jobs: int = 1
    threads: int | None = None
    scheduler: str | None = None
    scheduler_file: Path | None = None

    @property
    def cluster(self) -> bool:
        return self.scheduler is not None or self.scheduler_file is not None

    @property
    def name(self) -> str:
        return f"dask {self.scheduler or self.scheduler_file}" if self.cluster else f"{self.jobs} local job(s)"


def check_flight_sources(captures: Path | None, flight: FlightArguments, **pair_sources: object) -> None:
    """Refuse pair sources (``--left``, ``--manifest``, ``--rig`` ...) given with ``--captures``,
    and a flight's options given without it."""
    from cade_cli.errors import CadeError

    if captures is None:
        given = flight.given()
        if given:
            raise CadeError(f"{given[0]} is an option of a flight's batch; add --captures FLIGHT_FOLDER or drop it")
        return
    given = [f"--{name}" for name, value in pair_sources.items() if value is not None]
    if given:
        raise CadeError(f"{given[0]} belongs to a batch of pairs; --captures takes a flight's band files: drop one")


def batch_captures(captures: Path, output_dir: Path | None, flight: FlightArguments, *, method: str,
                   model: str | None, vis: bool, engine: Engine, force: bool, log: Path | None) -> None:
    """Register every capture of the flight folder ``captures`` into ``output_dir``, one cube each.

    A capture whose cube and record are verified (:func:`cade_cli.batch.captures.is_finished`)
    is skipped unless ``force``; the others run on ``engine`` (:func:`cade_cli.batch.engines.run_local`
    or :func:`~cade_cli.batch.engines.run_dask`) with the pair batch's bar and log (:mod:`cade_cli.cli.batch_run`).
    """
    from cade_cli.cli.options import check_output
    from cade_cli.errors import CadeError
    from cade_cli.batch.captures import is_finished, skipped_result
    from cade_cli.batch.flight import find_captures, flight_jobs
    from cade_cli.batch.job import remove_stale_temporaries

    if output_dir is None:
        raise CadeError("missing --output-dir: give --captures FLIGHT_FOLDER --output-dir CUBES")
    if engine.scheduler is not None and engine.scheduler_file is not None:
        raise CadeError("give --scheduler or --scheduler-file, not both")
    if engine.cluster and engine.jobs != 1:
        raise CadeError("--jobs sets processes on this machine; on a cluster the workers' own --nworkers do; "
                        "drop --jobs")
    options = _capture_options(flight, method=method, model=model, vis=vis)
    if output_dir.exists() and not output_dir.is_dir():
        raise CadeError(f"--output-dir {output_dir} is a file; give a folder")
    if flight.per_band is not None:
        from cade_cli.io.atomic import check_writable_folder

        check_writable_folder(flight.per_band)
    found, notes = find_captures(captures, output_dir, per_band=flight.per_band)
    options, values = _flight_irradiance(found, options, flight)
    jobs, panel_notes = flight_jobs(found, output_dir, options, skip_panels=flight.skip_panels, panels=flight.panels,
                                    per_band=flight.per_band)
    output_dir.mkdir(parents=True, exist_ok=True)
    log = output_dir / "cade-batch-log.json" if log is None else log
    check_output(log, suffixes=(".json",), inputs=())
    for note in notes + panel_notes:
        print_note(note)
    remove_stale_temporaries(jobs)  # left by a run that was killed
    results = [] if force else [skipped_result(job) for job in jobs if is_finished(job)]
    finished = {result.output for result in results}
    todo = [job for job in jobs if str(job.output) not in finished]
    if todo and not engine.cluster and engine.jobs > 1:
        engine = Engine(_jobs_that_fit(todo, engine.jobs), engine.threads)
    if engine.threads is None and not engine.cluster and engine.jobs > 1:
        engine = Engine(engine.jobs, max(1, (os.cpu_count() or 1) // engine.jobs))
    config = {"command": ["cade", *sys.argv[1:]] if sys.argv[1:2] == ["batch"] else None, "engine": engine.name,
              "captures": str(captures), "output_dir": str(output_dir), "force": force,
              "skip_panels": flight.skip_panels, "panels": list(flight.panels), "options": options.fingerprint()}
    if results:
        print_note(f"{len(results)} of {len(jobs)} captures already finished (cubes verified); --force redoes them")
    for line in values:  # what the cubes' values are, once for the flight
        print(line, file=sys.stderr)
    _run(todo, results, engine=engine, log=log, config=config)


def _capture_options(flight: FlightArguments, *, method: str, model: str | None, vis: bool):
    """The :class:`~cade_cli.batch.captures.CaptureOptions` of every capture, checked before any
    file is read (the panel's irradiance is added once the flight is found)."""
    from cade_cli.batch.captures import CaptureOptions
    from cade_cli.capture.model import parse_bands
    from cade_cli.cli.capture_radiometry import check_radiometry_options
    from cade_cli.errors import CadeError

    if (flight.panel_corners or flight.panel_albedo) and not flight.reflectance:
        raise CadeError("--panel-corners and --panel-albedo describe the panel of a reflectance; add --reflectance")
    check_radiometry_options(radiance=flight.radiance, reflectance=flight.reflectance,
                             panel=list(flight.panels) if flight.reflectance else None,
                             panel_corners=flight.panel_corners, panel_albedo=flight.panel_albedo, dtype=flight.dtype)
    radiometry = "radiance" if flight.radiance else "reflectance" if flight.reflectance else None
    options = CaptureOptions(reference=flight.reference, method=method, model=model, plane_only=flight.plane_only,
                             dtype=flight.dtype, match_scale=flight.match_scale, near=flight.near, vis=vis,
                             ndvi=flight.ndvi, bands=parse_bands(flight.bands), radiometry=radiometry)
    options.check()
    return options


def _flight_irradiance(found: list, options, flight: FlightArguments) -> tuple:
    """(``options`` with the panel shot's irradiance for every capture when ``--reflectance
    --panel`` is given: the first ``--panel`` value's shot, read and located once; the lines that
    say what the flight's values are, printed once after the run)."""
    from dataclasses import replace

    from cade_cli.batch.radiometry import first_whole_capture, kept_bands, panel_shot_files, values_note
    from cade_cli.cli.capture_radiometry import panel_radiometry

    lines = []
    if options.radiometry == "reflectance" and flight.panels:
        capture = first_whole_capture(found)
        paths, names = kept_bands(capture.paths, capture.bands, options.bands)
        radiometry, lines = panel_radiometry(panel_shot_files(flight.panels[0], found), paths, names,
                                             panel_corners=list(flight.panel_corners) or None,
                                             panel_albedo=flight.panel_albedo)
        options = replace(options, irradiance=dict(zip(names, radiometry.irradiance)),
                          irradiance_source=radiometry.source)
        if len(flight.panels) > 1:
            lines.append(f"  (the first --panel, {flight.panels[0]}, gives the irradiance; the others are only "
                         "marked as panel shots)")
    note = values_note(options, found)
    return options, ([note] if note else []) + lines[1:]


def _run(todo: list, results: list, *, engine: Engine, log: Path, config: dict) -> None:
    """Run ``todo`` on ``engine`` after the ``results`` of the captures already finished
    (:func:`~cade_cli.cli.batch_run.run_jobs`: the bar or a line every 10 s, each result shown above
    it, the log), then the summary line; CadeError when a capture failed."""
    from cade_cli.cli.batch_run import run_jobs
    from cade_cli.errors import CadeError
    from cade_cli.batch.engines import run_dask, run_local

    running = (run_dask(todo, address=engine.scheduler, scheduler_file=engine.scheduler_file, threads=engine.threads)
               if engine.cluster else run_local(todo, jobs=engine.jobs, threads=engine.threads))
    noted: dict[str, list[str]] = {}
    summary = run_jobs(todo, results, running, total=len(todo) + len(results), noun="captures",
                       label=f"captures ({engine.name})", log=log, config=config,
                       show=lambda console, result: _show(console, result, noted))
    for note, names in noted.items():
        print_note(summarise_note(note, names, total=summary.total))
    per_capture = f"{summary.seconds / summary.done:.1f} s per capture, " if summary.done else ""
    print(f"{summary.done} done, {summary.skipped} already finished, {summary.failed} failed, of {summary.total} "
          f"captures; {summary.seconds:.1f} s ({per_capture}{engine.name}); log {log}")
    if summary.failed:
        raise CadeError(f"{summary.failed} of {summary.total} captures failed (each named above and in {log})")


def summarise_note(note: str, names: list[str], *, total: int) -> str:
    """One line for a note that ``names`` (captures) share: the note, how many captures of
    ``total`` it applies to, the first few named."""
    if len(names) == 1:
        return f"{names[0]}: {note}"
    shown = ", ".join(names[:3]) + (" ..." if len(names) > 3 else "")
    return f"{note} ({len(names)} of {total} captures: {shown})"


def _show(console, result, noted: dict[str, list[str]]) -> None:
    """What one finished capture has to say above the bar: its failure; its notes are kept in
    ``noted`` (note -> captures) and shown once per flight, with a count, when all are done."""
    for note in result.notes:
        names = noted.setdefault(note, [])
        if result.name not in names:
            names.append(result.name)
    if result.status == "failed":
        console.print(f"warning: capture {result.name} failed: {result.error}", highlight=False, markup=False)


def _jobs_that_fit(todo: list, jobs: int) -> int:
    """``jobs``, lowered (with a note) until that many jobs of the largest capture fit the memory available."""
    from cade_cli.batch.engines import available_memory_bytes, cap_jobs
    from cade_cli.batch.captures import capture_memory_bytes

    size, per_job = capture_memory_bytes(todo)
    allowed = cap_jobs(jobs, per_job)
    if allowed < jobs:
        print_note(f"--jobs {jobs} lowered to {allowed}: the largest capture, {size}, may take "
                   f"{per_job / 2**30:.1f} GB per job and {available_memory_bytes() / 2**30:.1f} GB are available")
    return allowed
