"""Many pairs in one run (``cade batch``): the pair list, resume, one job per pair, and two engines.

A batch is a list of :class:`Pair` (from two glob patterns matched by file name,
:func:`pairs_from_patterns`, or a manifest CSV, :func:`pairs_from_manifest`). Each pair
is one job, :func:`run_pair`: it reads the two bands, resolves the range (``auto`` bounds
by :func:`cade_cli.scale.range.resolve_range`), calls :func:`cade_cli.scale.tiling.estimate_disparity_tiled`
(the path of ``cade disparity``: the pair matched whole when it fits ``--memory-limit``,
else as tiles) or, with a rig, :func:`cade_cli.rigs.pair.match_rig_pair` (the path of
``cade disparity --rig``, which does both on the rectified pair), and writes every output
of the pair with :func:`cade_cli.io.atomic.atomic_outputs`: the disparity, the optional
visualisation, validity, confidence, depth and points, and last a *record* beside the
disparity (``<output>.cade.json``) that holds the sha256 of the inputs and of every
output and the options that made them.

Resume: a pair is finished when its record is there, names the same inputs (by sha256) and
options, and every output it lists is there with the sha256 it lists
(:func:`is_finished`): a present but damaged, stale or foreign output is redone. The record
is renamed into place after the outputs, so an interruption between two renames leaves a
pair that is simply redone.

Engines (both yield :class:`PairResult` as pairs finish):

* :func:`run_local`: in this process (``jobs=1``) or in ``jobs`` worker processes, each
  running one pair at a time and keeping its network session (one per process, built on
  its first pair); a pair whose run raised an unexpected error, or whose worker died (a
  fresh worker replaces it), is tried once more, then reported failed; a
  :class:`~cade_cli.errors.CadeError` (bad input) is reported at once.
* :func:`run_dask`: on a Dask distributed cluster (the optional ``distributed``
  package), one task per pair, results streamed back in order of completion, a failed
  task retried once by the scheduler.

:func:`cap_jobs` limits the worker count so that jobs x a job's peak memory fits the memory
available: the planned memory of the largest pair (:func:`planned_pair_memory`), or the
memory limit when that is smaller (a worker tiles a pair that does not fit it).
"""

from __future__ import annotations

import collections
import csv
import datetime
import functools
import glob
import json
import multiprocessing
import multiprocessing.connection
import os
import re
import signal
import socket
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from cade_cli import __version__
from cade_cli.allocator import retain_freed_memory
from cade_cli.io.atomic import atomic_outputs, intended_path
from cade_cli.io.checksum import file_sha256
from cade_cli.io.disparity import DISPARITY_SUFFIXES
from cade_cli.errors import CadeError
from cade_cli.evaluation.timing import use_threads
from cade_cli.io.image_files import SUPPORTED_IMAGE_SUFFIXES
from cade_cli.scale.range import AUTO, RangeEstimate, parse_bound
from cade_cli.stereo import DEFAULT_METHOD
from cade_cli.scale.tiling import BASE_BYTES, available_memory_bytes, default_memory_limit, matching_memory_bytes

RECORD_SUFFIX = ".cade.json"
"""The record of a finished pair: ``<output><RECORD_SUFFIX>`` beside its disparity file."""
RECORD_FORMAT = 1
SIDE_OUTPUTS: dict[str, str] = {"vis": "_vis.png", "validity": "_validity.png", "confidence": "_confidence.tif",
                                "depth": "_depth.tif", "points": "_points.ply"}
"""Optional outputs of a pair, named after its disparity file: ``<stem><suffix>`` (depth and
points need a rig)."""
RIG_ONLY = ("camera", "frame", "fix_vertical", "depth", "points")
"""The :class:`PairOptions` that need ``rig``."""
MANIFEST_COLUMNS = ("left", "right", "output")
MANIFEST_OPTIONAL = ("min_disp", "max_disp", "left_band", "right_band")
ATTEMPTS = 2
"""Runs of a pair before its failure is reported: the first and one retry."""

WORKER_BASE_BYTES = BASE_BYTES
"""Resident memory of a worker before its first pair: Python, NumPy, OpenCV, onnxruntime.
With :data:`~cade_cli.scale.tiling.PIXEL_BYTES` per pixel the plan sits just above the measured
peaks of ``cade``: 0.30 GiB against 0.25-0.27 GiB on 640x480 (docs/scale.md, "Throughput"),
1.46 GB against 1.45 GB on 6 megapixels (models/README.md)."""
MEMORY_HEADROOM = 0.8
"""Share of the available memory the workers may plan to use."""


@dataclass(frozen=True)
class PairOptions:
    """The ``cade disparity`` options a batch applies to a pair.

    ``min_disp``/``max_disp`` are ints or ``"auto"``; ``max_disp`` None means the
    default (a quarter of the width). ``memory_limit``: the budget of a worker, bytes, as
    ``cade disparity --memory-limit`` (a pair that does not fit it is matched as tiles);
    None: the default, half the memory available when the pair runs. ``rig``: the path of
    a rig file; each pair is then matched as ``cade disparity LEFT RIGHT --rig`` does,
    with ``camera``, ``frame``, ``fix_vertical`` (:data:`RIG_ONLY`). ``vis``,
    ``validity``, ``confidence``, ``depth``, ``points`` ask for those outputs beside the
    disparity (:data:`SIDE_OUTPUTS`); ``vis_range``: the (min, max) px given the end
    colours of ``vis`` (None: each map's own robust range).
    """

    method: str = DEFAULT_METHOD
    min_disp: int | str = 0
    max_disp: int | str | None = None
    preprocess: str = "auto"
    model: str | None = None
    fill: str = "row"
    left_band: int | None = None
    right_band: int | None = None
    memory_limit: int | None = None
    rig: str | None = None
    camera: str | None = None
    frame: str = "rectified"
    fix_vertical: bool = False
    vis: bool = False
    validity: bool = False
    confidence: bool = False
    depth: bool = False
    points: bool = False
    vis_range: tuple[float, float] | None = None
    strict: bool = False
    """Refuse a pair the pair check (:mod:`cade_cli.pair_check`) finds a problem with (the
    pair fails, nothing written) instead of warning. Not part of the fingerprint: it
    decides whether outputs are written, never what they hold."""

    def check(self) -> None:
        """Refuse unknown names and impossible combinations before any pair runs (a rig
        file is read here: a bad one, or an unknown ``camera``, is refused now)."""
        from cade_cli.matching import get_matcher

        matcher = get_matcher(self.method, model=self.model)
        matcher.resolve_preprocess(self.preprocess)
        if self.fill not in ("row", "none"):
            raise CadeError(f"unknown --fill {self.fill!r}; choose row or none")
        if isinstance(self.min_disp, int) and isinstance(self.max_disp, int) and self.max_disp < self.min_disp:
            raise CadeError(f"--max-disp {self.max_disp} is below --min-disp {self.min_disp}; raise --max-disp")
        if self.vis_range is not None and not self.vis:
            raise CadeError("--vis-range sets the colours of the --vis pictures; add --vis or drop --vis-range")
        if self.rig is None:
            given = [name for name in RIG_ONLY if getattr(self, name) != getattr(PairOptions, name)]
            if given:
                option = "--" + given[0].replace("_", "-")
                raise CadeError(f"{option} needs --rig (the rig file that says how to rectify the pairs); add --rig "
                                f"RIG.json or drop {option}")
            return
        from cade_cli.rigs.outputs import FRAMES
        from cade_cli.rigs.rig_file import load_rig
        from cade_cli.rigs.pair import rig_pair_rectification

        if self.frame not in FRAMES:
            raise CadeError(f"unknown --frame {self.frame!r}; choose rectified or original")
        rig_pair_rectification(load_rig(self.rig), self.camera)

    def budget(self) -> int:
        """The memory limit of one worker, bytes: ``memory_limit``, or the machine's default."""
        return default_memory_limit() if self.memory_limit is None else self.memory_limit

    def fingerprint(self) -> dict:
        """What decides a pair's outputs, as stored in its record: these options and, for
        a learned method, the sha256 of the network files the model card names."""
        from cade_cli.matching import LEARNED_METHODS
        from cade_cli.model_card import DEFAULT_MODEL, read_card

        options = asdict(self)
        del options["strict"]
        if self.vis_range is None:  # left out, so that records written before it existed still match
            del options["vis_range"]
        else:
            options["vis_range"] = list(self.vis_range)  # as JSON gives it back
        if self.rig is None:  # without a rig its options are their defaults: left out
            for name in ("rig", *RIG_ONLY):
                del options[name]
        else:  # the rig by its content, wherever its file lies
            options["rig"] = file_sha256(Path(self.rig))
        if self.method in LEARNED_METHODS:
            card = read_card(self.model or DEFAULT_MODEL)
            options["model_sha256"] = sorted(variant.sha256 for variant in card.variants)
        return options


@dataclass(frozen=True)
class Pair:
    """One job: match ``left`` against ``right`` with ``options``, write ``output``."""

    left: Path
    right: Path
    output: Path
    options: PairOptions = PairOptions()

    def outputs(self) -> dict[str, Path]:
        """Role -> file of every output the pair writes: ``disparity`` and the side outputs asked for."""
        stem = self.output.with_suffix("")
        found = {"disparity": self.output}
        for role, suffix in SIDE_OUTPUTS.items():
            if getattr(self.options, role):
                found[role] = stem.parent / (stem.name + suffix)
        return found

    @property
    def record(self) -> Path:
        """The pair's record file."""
        return self.output.with_name(self.output.name + RECORD_SUFFIX)


@dataclass(frozen=True)
class PairResult:
    """What became of one pair.

    Attributes:
        status: ``done`` (computed now), ``skipped`` (verified as finished before) or ``failed``.
        error: one line, for a failed pair.
        range: the searched (min, max), px (resolved ``auto`` bounds included).
        range_note: how an ``auto`` bound was estimated, else None.
        outputs: role -> sha256 of the file written (done and skipped pairs).
        seconds: wall time of the run on its worker (0 for skipped pairs).
        worker: ``host:pid`` of the process that ran it.
        attempts: runs it took (0 when skipped).
        notes: notes for the user (e.g. a colour image converted to luminance).
        peak_rss_mb: the worker's peak resident memory so far (MiB), after this pair.
        tiles: tiles the pair was matched as (:mod:`cade_cli.scale.tiling`); 0: whole.
        warnings: what the pair check found wrong with the pair (:mod:`cade_cli.pair_check`).
        pair_check: the pair check's measurements (:meth:`~cade_cli.pair_check.PairCheck.record`):
            vertical offset (px), rotation (degrees), ...; None with a rig (its self-check is in the record).
    """

    left: str
    right: str
    output: str
    status: str
    error: str | None = None
    range: tuple[int, int] | None = None
    range_note: str | None = None
    outputs: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    worker: str | None = None
    attempts: int = 1
    valid_share: float | None = None
    notes: tuple[str, ...] = ()
    peak_rss_mb: float | None = None
    tiles: int | None = None
    warnings: tuple[str, ...] = ()
    pair_check: dict | None = None

    @classmethod
    def failure(cls, pair: Pair, error: str, *, attempts: int, worker: str | None = None) -> "PairResult":
        return cls(str(pair.left), str(pair.right), str(pair.output), "failed", error=error, attempts=attempts,
                   worker=worker)


# --- the pair list ---------------------------------------------------------------------------------------------------


def _image_files(pattern: str) -> list[Path]:
    return [Path(p) for p in sorted(glob.glob(pattern, recursive=True))
            if Path(p).suffix.lower() in SUPPORTED_IMAGE_SUFFIXES and Path(p).is_file()]


def _last_number(path: Path) -> str | None:
    numbers = re.findall(r"\d+", path.stem)
    return str(int(numbers[-1])) if numbers else None


def pairs_from_patterns(left: str, right: str, output_dir: Path, *, options: PairOptions,
                        suffix: str = ".pfm") -> list[Pair]:
    """Pairs of the image files two glob patterns match, matched by name.

    Files with the same name on both sides pair up (``cam0/0001.png`` with
    ``cam1/0001.png``); when no name is shared, files pair by the last number in their
    names (``left_07.png`` with ``right_07.png``). Every file must find its partner. Each
    output is ``output_dir/<left stem><suffix>``.

    Raises:
        CadeError: a pattern that matches no image, files without a partner, two pairs
            with one output, an unsupported output suffix.
    """
    if suffix.lower() not in DISPARITY_SUFFIXES:
        raise CadeError(f"--format {suffix.lstrip('.')} is not a disparity format; choose one of "
                        f"{', '.join(s.lstrip('.') for s in DISPARITY_SUFFIXES)}")
    files = {}
    for side, pattern in (("--left", left), ("--right", right)):
        files[side] = _image_files(pattern)
        if not files[side]:
            raise CadeError(f"{side} {pattern!r} matches no image file; check the pattern (relative to {Path.cwd()}) "
                            "and quote it so the shell does not expand it")
    by_name = [{path.name: path for path in files[side]} for side in ("--left", "--right")]
    for side, named in zip(("--left", "--right"), by_name):
        if len(named) != len(files[side]):
            twice = next(path for path in files[side] if named[path.name] != path)
            raise CadeError(f"{side} matches two files named {twice.name} ({twice}, {named[twice.name]}); pairs are "
                            "matched by name, so give each file of a side its own name")
    if set(by_name[0]) & set(by_name[1]):
        keys, how = by_name, "name"
    else:
        keys = [{_last_number(path): path for path in files[side]} for side in ("--left", "--right")]
        how = "the last number in the name"
        for side, keyed in zip(("--left", "--right"), keys):
            if None in keyed or len(keyed) != len(files[side]):
                raise CadeError(f"the {side} files share no names with the other side, and their numbers do not tell "
                                f"them apart; name each pair's files alike (cam0/0001.png, cam1/0001.png)")
    unmatched = [(side, key) for side, mine, other in (("--left", keys[0], keys[1]), ("--right", keys[1], keys[0]))
                 for key in mine if key not in other]
    if unmatched:
        side, key = unmatched[0]
        raise CadeError(f"{len(unmatched)} file(s) have no partner when matched by {how}, e.g. {side} "
                        f"{(keys[0] if side == '--left' else keys[1])[key]}; give both sides the same set of pairs")
    pairs = [Pair(keys[0][key], keys[1][key], Path(output_dir) / (keys[0][key].stem + suffix), options)
             for key in sorted(keys[0], key=lambda k: str(keys[0][k]))]
    check_distinct_outputs(pairs)
    return pairs


def pairs_from_manifest(manifest: Path, *, options: PairOptions) -> list[Pair]:
    """Pairs listed in a CSV file with a header row.

    Columns ``left``, ``right``, ``output`` (required) and ``min_disp``, ``max_disp``
    (an integer or ``auto``), ``left_band``, ``right_band`` (optional; an empty cell
    takes the batch's option). Relative paths are relative to the manifest's folder.

    Raises:
        CadeError: a missing or unreadable file, a missing column, an unknown column, a
            bad value (named by its line), two pairs with one output.
    """
    manifest = Path(manifest)
    try:
        text = manifest.read_text(encoding="utf-8-sig")
    except OSError as error:
        raise CadeError(f"cannot read the manifest {manifest}: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise CadeError(f"the manifest {manifest} is not a text (UTF-8 CSV) file") from None
    rows = csv.DictReader(text.splitlines())
    header = [name.strip().replace("-", "_") for name in (rows.fieldnames or [])]
    missing = [name for name in MANIFEST_COLUMNS if name not in header]
    if missing:
        raise CadeError(f"the manifest {manifest} has no column {', '.join(missing)}; its first line must name the "
                        f"columns: left,right,output[,{','.join(MANIFEST_OPTIONAL)}]")
    unknown = [name for name in header if name not in MANIFEST_COLUMNS + MANIFEST_OPTIONAL]
    if unknown:
        raise CadeError(f"the manifest {manifest} has an unknown column {unknown[0]!r}; the columns are "
                        f"{', '.join(MANIFEST_COLUMNS + MANIFEST_OPTIONAL)}")
    rows.fieldnames = header
    base = manifest.parent
    pairs = []
    for line, row in enumerate(rows, start=2):
        cells = {key: (value or "").strip() for key, value in row.items() if key is not None}
        if not any(cells.values()):
            continue
        where = f"{manifest}:{line}"
        if any(not cells.get(name) for name in MANIFEST_COLUMNS):
            raise CadeError(f"{where}: left, right and output must all be given")
        overrides = {}
        try:
            for name in ("min_disp", "max_disp"):
                if cells.get(name):
                    overrides[name] = parse_bound(cells[name], option=name.replace("_", "-"),
                                                  minimum=1 if name == "max_disp" else None)
            for name in ("left_band", "right_band"):
                if cells.get(name):
                    if not cells[name].isdigit():
                        raise CadeError(f"{name} must be a 0-based band number, got {cells[name]!r}")
                    overrides[name] = int(cells[name])
        except CadeError as error:
            raise CadeError(f"{where}: {error}") from None
        paths = [base / Path(cells[name]).expanduser() for name in MANIFEST_COLUMNS]
        if paths[2].suffix.lower() not in DISPARITY_SUFFIXES:
            raise CadeError(f"{where}: cannot write {paths[2]}: use one of {', '.join(DISPARITY_SUFFIXES)}")
        pairs.append(Pair(*paths, replace(options, **overrides)))
    if not pairs:
        raise CadeError(f"the manifest {manifest} lists no pairs")
    check_distinct_outputs(pairs)
    return pairs


def check_distinct_outputs(pairs: Sequence[Pair]) -> None:
    """Refuse two pairs writing one file, or a pair writing over an input."""
    seen: dict[Path, Pair] = {}
    inputs = {path.resolve() for pair in pairs for path in (pair.left, pair.right)}
    for pair in pairs:
        for path in (*pair.outputs().values(), pair.record):
            key = path.resolve()
            if key in seen:
                raise CadeError(f"{seen[key].left} and {pair.left} would both write {path}; give each pair its own "
                                "output name")
            if key in inputs:
                raise CadeError(f"output {path} is also an input; choose another output name or folder")
            seen[key] = pair


# --- resume ----------------------------------------------------------------------------------------------------------


def expected_record(pair: Pair) -> dict:
    """The part of a pair's record that its inputs and options decide."""
    return {
        "format": RECORD_FORMAT,
        "inputs": {"left": file_sha256(pair.left), "right": file_sha256(pair.right)},
        "options": pair.options.fingerprint(),
    }


def is_finished(pair: Pair) -> bool:
    """Whether the pair's outputs are verified as made from its inputs with its options.

    True only when its record parses, names the same input sha256 and options, lists
    exactly the outputs the options ask for, and each of them is there with the sha256
    listed. A missing or unreadable input is not finished (the run will report it).
    """
    try:
        record = json.loads(pair.record.read_text())
        expected = expected_record(pair)
    except (OSError, ValueError, CadeError):
        return False
    if not isinstance(record, dict) or any(record.get(key) != value for key, value in expected.items()):
        return False
    listed = record.get("outputs")
    wanted = pair.outputs()
    if not isinstance(listed, dict) or set(listed) != set(wanted):
        return False
    for role, path in wanted.items():
        entry = listed[role]
        try:
            if not isinstance(entry, dict) or entry.get("file") != path.name or file_sha256(path) != entry.get("sha256"):
                return False
        except OSError:
            return False
    return True


def skipped_result(pair: Pair) -> PairResult:
    """The result of a pair :func:`is_finished` found finished (read from its record)."""
    record = json.loads(pair.record.read_text())
    return PairResult(str(pair.left), str(pair.right), str(pair.output), "skipped",
                      range=tuple(record.get("range") or ()) or None,
                      outputs={role: entry["sha256"] for role, entry in record["outputs"].items()}, attempts=0)


def remove_stale_temporaries(pairs: Iterable[Pair]) -> int:
    """Delete the hidden temporaries (:func:`cade_cli.io.atomic.temporary_sibling`) of the
    pairs' outputs that a killed run left behind; returns how many. Call it only while no
    other run writes these outputs."""
    removed = 0
    for pair in pairs:
        for path in (*pair.outputs().values(), pair.record):
            # ".*": a writer killed inside a nested atomic write leaves a temporary of a
            # temporary (``..disp.tmp-<hex>.tmp-<hex>.pfm``); intended_path sorts out the rest
            for candidate in path.parent.glob(f".*{glob.escape(path.stem)}.tmp-*{glob.escape(path.suffix)}"):
                if intended_path(candidate) == path and candidate.is_file():
                    candidate.unlink(missing_ok=True)
                    removed += 1
    return removed


# --- one pair --------------------------------------------------------------------------------------------------------


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def peak_rss_mb() -> float:
    """This process's peak resident memory so far, MiB (Linux reports KiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_pair(pair: Pair) -> PairResult:
    """Match one pair and write its outputs and record, all or nothing.

    Without a rig the pair goes through :func:`cade_cli.scale.tiling.estimate_disparity_tiled`
    (whole when it fits the memory limit, else as tiles), as ``cade disparity`` does; with
    one through :func:`cade_cli.rigs.pair.match_rig_pair` and
    :func:`~cade_cli.rigs.pair.write_rig_outputs`, as ``cade disparity --rig`` does.

    Returns a ``done`` result, or a ``failed`` one for a :class:`CadeError` (bad input:
    unreadable image, a range that does not fit, ...). Any other exception propagates,
    so that the engine can retry the pair.
    """
    from cade_cli.io.images import read_band

    started = time.perf_counter()
    options = pair.options
    try:
        record = expected_record(pair)
        notes = []
        bands = []
        for path, band, option in ((pair.left, options.left_band, "left_band"),
                                   (pair.right, options.right_band, "right_band")):
            image, note = read_band(path, band)
            if note:
                notes.append(f"{note}; pick a band with --{option.replace('_', '-')} or the manifest's {option}")
            bands.append(image)
        left, right = bands
        wanted = pair.outputs()
        match = _match_with_rig if options.rig is not None else _match
        matched = match(pair, left, right, notes)
        for path in (*wanted.values(), pair.record):
            path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_outputs([*wanted.values(), pair.record]) as staged:  # the record is renamed last
            matched.write({role: staged[path] for role, path in wanted.items()})
            hashes = {role: file_sha256(staged[path]) for role, path in wanted.items()}
            record.update(
                range=list(matched.range),
                outputs={role: {"file": path.name, "sha256": hashes[role]} for role, path in wanted.items()},
                cade_version=__version__,
                **matched.facts,
            )
            staged[pair.record].write_text(json.dumps(record, indent=1) + "\n")
    except CadeError as error:
        return PairResult.failure(pair, str(error).splitlines()[0], attempts=1, worker=worker_name())
    return PairResult(
        str(pair.left), str(pair.right), str(pair.output), "done", range=matched.range, range_note=matched.range_note,
        outputs=hashes, seconds=time.perf_counter() - started, worker=worker_name(), valid_share=matched.valid_share,
        notes=tuple(notes), peak_rss_mb=peak_rss_mb(), tiles=matched.facts.get("tiles"),
        warnings=matched.warnings, pair_check=matched.facts.get("pair_check"),
    )


@dataclass(frozen=True)
class _Matched:
    """A pair matched, before its outputs are written: ``write`` writes them (role -> file)."""

    range: tuple[int, int]
    range_note: str | None
    valid_share: float
    write: Callable[[dict[str, Path]], None]
    facts: dict = field(default_factory=dict)
    """Added to the pair's record (how it was matched: tiles, the rig's self-check, the pair check)."""
    warnings: tuple[str, ...] = ()
    """What the pair check found wrong (one line each)."""


def _match(pair: Pair, left, right, notes: list[str]) -> _Matched:
    """The pair as ``cade disparity`` matches it: its range resolved, matched whole or as
    tiles within the memory limit (:func:`cade_cli.scale.tiling.estimate_disparity_tiled`)."""
    from cade_cli.io.disparity import write_match_outputs
    from cade_cli.matching import densify
    from cade_cli.pair_check import check_pair
    from cade_cli.scale.range import resolve_range
    from cade_cli.scale.tiling import estimate_disparity_tiled

    options = pair.options
    if left.shape != right.shape:
        raise CadeError(f"{pair.left} is {left.shape[1]}x{left.shape[0]} but {pair.right} is "
                        f"{right.shape[1]}x{right.shape[0]}; a pair's images must have one size")
    searched, estimate = resolve_range(left, right, min_disp=options.min_disp, max_disp=options.max_disp)
    checked = check_pair(left, right, min_disp=searched.minimum, max_disp=searched.maximum)
    if checked.problems and options.strict:
        raise CadeError(f"{checked.describe()} (--strict)")
    budget = options.budget()
    result, plan = estimate_disparity_tiled(left, right, method=options.method, min_disp=searched.minimum,
                                            max_disp=searched.maximum, preprocess=options.preprocess,
                                            model=options.model, memory_limit=budget)
    if plan.tiled:
        notes.append(_tiled_note(budget))
    if options.confidence and result.confidence is None:
        raise CadeError(f"method {options.method} gives no confidence; drop --confidence")

    def write(files: dict[str, Path]) -> None:
        write_match_outputs(files, dense=densify(result.disparity, result.valid), disparity=result.disparity,
                            valid=result.valid, confidence=result.confidence, fill=options.fill,
                            vis_range=options.vis_range)

    return _Matched((searched.minimum, searched.maximum), _range_note(options, estimate), float(result.valid.mean()),
                    write, {"tiles": len(plan.tiles), "pair_check": checked.record()},
                    (checked.describe(),) if checked.problems else ())


def _tiled_note(budget: int) -> str:
    """The note of a batch whose pairs, some of them, were matched as tiles within ``budget`` (bytes)."""
    return (f"a pair that does not fit --memory-limit {budget / 2**30:.1f} GB whole is matched as tiles "
            "(docs/scale.md, \"Tiling\"); the log gives each pair's tile count")


def _range_note(options: PairOptions, estimate: RangeEstimate | None) -> str | None:
    """How the ``auto`` bounds of ``options`` were estimated, as ``cade disparity`` announces
    it; None when ``estimate`` is None (no ``auto`` bound)."""
    if estimate is None:
        return None
    return estimate.describe(estimated=(options.min_disp == AUTO, options.max_disp == AUTO))


def _match_with_rig(pair: Pair, left, right, notes: list[str]) -> _Matched:
    """The pair as ``cade disparity LEFT RIGHT --rig`` matches it (:mod:`cade_cli.rigs.pair`:
    an ``auto`` bound estimated on the rectified pair, matched whole or as tiles within the
    memory limit); a rectification self-check above tolerance, or skipped, is a note."""
    from cade_cli.rigs.self_check import VERTICAL_TOLERANCE_PX
    from cade_cli.rigs.rig_file import load_rig
    from cade_cli.rigs.pair import check_rig_pair, match_rig_pair, rig_pair_rectification, write_rig_outputs

    options = pair.options
    rig = load_rig(options.rig)
    other, rectification = rig_pair_rectification(rig, options.camera)
    check_rig_pair(rig, rectification, left, right, paths=(pair.left, pair.right))
    width = rectification.image_size[0]
    budget = options.budget()
    found, framed = match_rig_pair(rig, left, right, other=other, frame=options.frame, fill=options.fill,
                                   fix_vertical=options.fix_vertical, method=options.method, min_disp=options.min_disp,
                                   max_disp=options.max_disp, preprocess=options.preprocess, model=options.model,
                                   memory_limit=budget)
    if found.plan.tiled:
        notes.append(_tiled_note(budget))
    check = found.misalignment
    if check is None:
        notes.append(f"{pair.left}: rectification self-check skipped: {found.self_check_problem}")
        self_check = None
    else:
        worst = check.worst(width)
        if worst > VERTICAL_TOLERANCE_PX and not options.fix_vertical and options.strict:
            raise CadeError(f"rectification self-check: vertical misalignment up to {worst:.2f} px, above "
                            f"{VERTICAL_TOLERANCE_PX} px; add --fix-vertical or recalibrate (--strict)")
        if worst > VERTICAL_TOLERANCE_PX and not options.fix_vertical:
            notes.append(f"{pair.left}: rectification self-check: vertical misalignment up to {worst:.2f} px, above "
                         f"{VERTICAL_TOLERANCE_PX} px; add --fix-vertical or recalibrate")
        self_check = {"offset_px": check.offset, "roll_rad": check.roll, "worst_px": worst, "matches": check.matches,
                      "corrected": found.corrected}

    def write(files: dict[str, Path]) -> None:
        write_rig_outputs(files, framed, fill=options.fill, method=options.method, vis_range=options.vis_range)

    return _Matched((found.range.minimum, found.range.maximum), _range_note(options, found.range_estimate),
                    float(framed.valid.mean()), write,
                    {"tiles": len(found.plan.tiles), "rectification": list(rectification.cameras),
                     "self_check": self_check})


# --- memory ----------------------------------------------------------------------------------------------------------


def pair_memory_bytes(method: str, width: int, height: int, disparities: int) -> int:
    """Planned peak resident memory (bytes) of a worker matching one ``width`` x ``height``
    pair over ``disparities`` levels with ``method``: the worker's base, the per-pixel
    arrays, and the matcher's cost volume (:attr:`~cade_cli.matching.Matcher.volume_bytes`
    per pixel and disparity; 0 for the learned methods, whose strips bound it)."""
    return int(WORKER_BASE_BYTES + matching_memory_bytes(method, width, height, disparities))


def planned_pair_memory(pair: Pair) -> tuple[int, int, int]:
    """(width, height, bytes): the size a pair is matched at and its :func:`pair_memory_bytes`.

    The size is read from the left file's header (:func:`image_size`), or with a rig is the
    rectified size; the range is the pair's, an ``auto`` bound counted as a quarter of the
    width (the default bound) on that side of zero.
    """
    from cade_cli.stereo import default_max_disparity

    options = pair.options
    if options.rig is not None:
        width, height = _rectified_size(options.rig, options.camera)
    else:
        width, height = image_size(pair.left)
    top = options.max_disp if isinstance(options.max_disp, int) else default_max_disparity(width)
    bottom = options.min_disp if isinstance(options.min_disp, int) else -default_max_disparity(width)
    return width, height, pair_memory_bytes(options.method, width, height, top - bottom + 1)


@functools.lru_cache(maxsize=4)
def _rectified_size(rig: str, camera: str | None) -> tuple[int, int]:
    from cade_cli.rigs.rig_file import load_rig
    from cade_cli.rigs.pair import rig_pair_rectification

    return tuple(rig_pair_rectification(load_rig(rig), camera)[1].image_size)


def job_memory_bytes(pairs: Sequence[Pair]) -> tuple[int, int, int]:
    """(width, height, bytes) of the largest of ``pairs`` (:func:`planned_pair_memory`), the
    bytes lowered to a worker's memory limit when that is smaller (a worker matches a pair,
    rectified or not, that does not fit its limit as tiles)."""
    width, height, largest = max((planned_pair_memory(pair) for pair in pairs), key=lambda plan: plan[2])
    options = pairs[0].options  # the limit is the batch's, not a manifest row's
    budget = options.budget()
    return width, height, min(largest, budget)


def cap_jobs(jobs: int, per_job_bytes: int, available_bytes: int | None = None) -> int:
    """``jobs`` lowered (to at least 1) so that ``jobs * per_job_bytes`` stays within
    :data:`MEMORY_HEADROOM` of the available memory."""
    available = available_memory_bytes() if available_bytes is None else available_bytes
    return max(1, min(jobs, int(MEMORY_HEADROOM * available // max(1, per_job_bytes))))


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file, from its header where it tells, else by decoding it."""
    from cade_cli.io.images import load_image
    from cade_cli.io.image_files import header_size

    with open(path, "rb") as stream:
        size = header_size(stream.read(1 << 16))
    if size is None:
        image = load_image(path)
        size = (image.shape[1], image.shape[0])
    return size


# --- engines ---------------------------------------------------------------------------------------------------------


def _start_worker(threads: int | None) -> None:
    retain_freed_memory()  # as the cade command does
    use_threads(threads)


def _attempt(pair: Pair) -> PairResult:
    """:func:`run_pair`, its unexpected errors turned into a failed result after :data:`ATTEMPTS` runs."""
    for attempt in range(1, ATTEMPTS + 1):
        try:
            return replace(run_pair(pair), attempts=attempt)
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as error:  # noqa: BLE001 - reported for this pair, the batch goes on
            if attempt == ATTEMPTS:
                return PairResult.failure(pair, f"{type(error).__name__}: {error}".splitlines()[0],
                                          attempts=attempt, worker=worker_name())
    raise AssertionError("unreachable")


def _worker_main(connection, threads: int | None) -> None:
    """A worker process: run the pairs its ``connection`` sends (``(index, pair)``, None to
    stop) and send back ``(index, result, error)``; an interruption ends it quietly (the pair
    in hand discards its temporaries). Each worker has its own pipe: a worker killed while
    writing cannot block another."""
    try:
        _start_worker(threads)
        while (item := connection.recv()) is not None:
            index, pair = item
            try:
                connection.send((index, run_pair(pair), None))
            except Exception as error:  # noqa: BLE001 - reported for this pair, the worker goes on
                connection.send((index, None, f"{type(error).__name__}: {error}".splitlines()[0]))
    except (KeyboardInterrupt, EOFError, BrokenPipeError):
        return


@dataclass
class _Worker:
    process: multiprocessing.process.BaseProcess
    connection: multiprocessing.connection.Connection
    running: tuple[int, Pair] | None = None


def run_local(pairs: Sequence[Pair], *, jobs: int = 1, threads: int | None = None) -> Iterator[PairResult]:
    """Run ``pairs`` here (``jobs=1``) or in ``jobs`` worker processes; yield results as pairs finish.

    Each worker runs one pair at a time and keeps its network session between pairs. A
    pair whose run raised an unexpected error, or whose worker died (killed, out of
    memory; a fresh worker takes its place), is tried once more, then reported failed.
    On an interruption (KeyboardInterrupt, or the caller closing this generator) every
    worker is interrupted too: the pairs in hand discard their temporaries, finished
    outputs stay, and the interruption propagates.

    Args:
        threads: threads of each worker (None: leave the defaults).
    """
    if jobs <= 1:
        use_threads(threads)
        for pair in pairs:
            yield _attempt(pair)
        return
    context = multiprocessing.get_context("spawn")  # no fork of a process whose libraries hold threads

    def start() -> _Worker:
        mine, theirs = context.Pipe()
        process = context.Process(target=_worker_main, args=(theirs, threads), daemon=True)
        process.start()
        theirs.close()
        return _Worker(process, mine)

    waiting = collections.deque(enumerate(pairs))
    attempts: collections.Counter[int] = collections.Counter()
    workers = [start() for _ in range(min(jobs, len(waiting)))]
    try:
        while waiting or any(worker.running for worker in workers):
            for worker in workers:
                if worker.running is None and waiting:
                    worker.running = waiting.popleft()
                    attempts[worker.running[0]] += 1
                    try:
                        worker.connection.send(worker.running)
                    except (BrokenPipeError, OSError):
                        pass  # a dead worker: found below by its sentinel
            busy = [worker for worker in workers if worker.running is not None]
            ready = multiprocessing.connection.wait([w.connection for w in busy] + [w.process.sentinel for w in busy])
            for slot, worker in enumerate(workers):
                if worker.running is None or not ({worker.connection, worker.process.sentinel} & set(ready)):
                    continue
                index, pair = worker.running
                try:
                    answer = worker.connection.recv() if worker.connection.poll() else None
                except (EOFError, OSError):
                    answer = None
                if answer is None:  # the process ended without answering: it died
                    worker.connection.close()
                    worker.process.join()
                    remove_stale_temporaries([pair])  # what it was writing; no one else writes this pair
                    workers[slot] = start()
                    failed = _retry_or_fail(index, pair, "its worker process died (killed, or out of memory)",
                                            attempts, waiting)
                    if failed is not None:
                        yield failed
                    continue
                _, result, error = answer
                worker.running = None
                if result is not None:
                    yield replace(result, attempts=attempts[index])
                elif (failed := _retry_or_fail(index, pair, error, attempts, waiting)) is not None:
                    yield failed
    except BaseException:
        for worker in workers:  # interrupt the pairs in hand; their temporaries are discarded
            if worker.process.is_alive():
                os.kill(worker.process.pid, signal.SIGINT)
        raise
    finally:
        for worker in workers:
            try:
                worker.connection.send(None)
            except (BrokenPipeError, OSError):
                pass
        for worker in workers:
            worker.process.join(timeout=30)
            if worker.process.is_alive():
                worker.process.terminate()
                worker.process.join()
            worker.connection.close()


def _retry_or_fail(index: int, pair: Pair, error: str, attempts: collections.Counter,
                   waiting: collections.deque) -> PairResult | None:
    """Queue ``pair`` again if it has runs left (None), else its failed result."""
    if attempts[index] < ATTEMPTS:
        waiting.appendleft((index, pair))
        return None
    return PairResult.failure(pair, error, attempts=attempts[index])


def run_dask(pairs: Sequence[Pair], *, address: str | None = None, scheduler_file: Path | None = None,
             client=None, threads: int | None = None) -> Iterator[PairResult]:
    """Run ``pairs`` on a Dask distributed cluster, one task per pair; yield results as they complete.

    The workers need cade installed (with its models) and the inputs and outputs at the
    same paths (a shared filesystem); relative paths are made absolute here first. A task that raises (an unexpected error, or a
    worker lost mid-pair) is retried once by the scheduler, then reported failed.

    Args:
        address: the scheduler, ``tcp://host:8786``; or ``scheduler_file``, the JSON file
            ``dask scheduler --scheduler-file`` writes; or ``client``, a connected
            ``distributed.Client``.
        threads: threads of each worker process (OpenCV's pool and the variables
            onnxruntime reads), set on the workers present at the start; None: leave them.

    Raises:
        CadeError: ``distributed`` is not installed, or the scheduler cannot be reached.
    """
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise CadeError("running on a cluster needs the distributed package; pip install 'cade-cli[distributed]'") from None
    own = client is None
    if own:
        try:
            client = Client(address, scheduler_file=None if scheduler_file is None else str(scheduler_file),
                            timeout="20s")
        except (OSError, TimeoutError, ValueError) as error:
            where = address or scheduler_file
            raise CadeError(f"cannot reach the Dask scheduler {where}: {str(error).splitlines()[0] if str(error) else type(error).__name__}; "
                            "start it (dask scheduler) and check the address") from None
    futures = {}
    try:
        if threads is not None:
            client.run(_start_worker, threads)
        token = f"{os.getpid()}-{time.time_ns()}"
        for index, pair in enumerate(pairs):  # the workers' current folder is not ours: absolute paths
            pair = replace(pair, left=pair.left.absolute(), right=pair.right.absolute(), output=pair.output.absolute())
            future = client.submit(run_pair, pair, key=f"cade-pair-{token}-{index}", pure=False,
                                   retries=ATTEMPTS - 1)
            futures[future] = pair
        for future in as_completed(futures):
            pair = futures[future]
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 - reported for this pair, the batch goes on
                yield PairResult.failure(pair, f"{type(exc).__name__}: {exc}".splitlines()[0], attempts=ATTEMPTS)
    finally:
        client.cancel(list(futures))
        if own:
            client.close()


# --- the log ---------------------------------------------------------------------------------------------------------


@dataclass
class BatchSummary:
    """Counts and timing of a batch."""

    total: int
    done: int = 0
    skipped: int = 0
    failed: int = 0
    seconds: float = 0.0
    interrupted: bool = False

    def add(self, result: PairResult) -> None:
        setattr(self, result.status, getattr(self, result.status) + 1)

    @property
    def pairs_per_minute(self) -> float:
        return 60.0 * self.done / self.seconds if self.seconds > 0 else 0.0


def log_document(results: Sequence[PairResult], summary: BatchSummary, *, config: dict) -> str:
    """The JSON log of a batch: its configuration, summary and one entry per pair."""
    return json.dumps({
        "cade_version": __version__,
        "finished_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "config": config,
        "summary": {**asdict(summary), "pairs_per_minute": summary.pairs_per_minute},
        "pairs": [{key: value for key, value in asdict(result).items() if value not in (None, (), {})}
                  for result in results],
    }, indent=1) + "\n"
