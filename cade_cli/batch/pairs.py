"""The pairs of a batch and their records: what each pair is (:class:`Pair`), the options every
pair is matched with (:class:`PairOptions`, checked before any pair runs), what became of it
(:class:`PairResult`, written beside its outputs as a record that makes a batch resumable), and
the pair lists: image patterns matched by their numbers, or a CSV manifest.
"""

from __future__ import annotations

import csv
import glob
import json
import os
import re
import socket
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from cade_cli.errors import CadeError
from cade_cli.io.checksum import file_sha256
from cade_cli.io.disparity import DISPARITY_SUFFIXES
from cade_cli.io.image_files import SUPPORTED_IMAGE_SUFFIXES
from cade_cli.scale.memory import default_memory_limit
from cade_cli.scale.range import check_bounds, parse_bound
from cade_cli.stereo import DEFAULT_METHOD


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


@dataclass(frozen=True)
class PairOptions:
    """The ``cade disparity`` options a batch applies to a pair.

    ``min_disp``/``max_disp`` are ints or ``"auto"``; ``max_disp`` None means the
    default (a quarter of the width). ``memory_limit``: the budget of a worker, bytes, as
    ``cade disparity --memory-limit`` (a pair that does not fit it is matched as tiles);
    None: the default, half the memory available when the pair runs. ``rig``: the path of
    a rig file; each pair is then matched as ``cade disparity LEFT RIGHT --rig`` does,
    with ``camera``, ``frame``, ``fix_vertical`` (:data:`RIG_ONLY`; the last two also without, per pair). ``vis``,
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
        from cade_cli.rigs.outputs import FRAMES

        matcher = get_matcher(self.method, model=self.model)
        matcher.resolve_preprocess(self.preprocess)
        if self.fill not in ("row", "none"):
            raise CadeError(f"unknown --fill {self.fill!r}; choose row or none")
        check_bounds(self.min_disp, self.max_disp)
        if self.vis_range is not None and not self.vis:
            raise CadeError("--vis-range sets the colours of the --vis pictures; add --vis or drop --vis-range")
        if self.rig is None:  # --fix-vertical alone: the warp from each pair itself, in either --frame
            given = [name for name in RIG_ONLY if getattr(self, name) != getattr(PairOptions, name)
                     and not (self.fix_vertical and name in ("fix_vertical", "frame"))]
            if given:
                option = "--" + given[0].replace("_", "-")
                raise CadeError(f"{option} needs --rig (the rig file that says how to rectify the pairs); add --rig "
                                f"RIG.json or drop {option}")
            if self.frame in FRAMES:
                return
        from cade_cli.rigs.pair import rig_pair_rectification
        from cade_cli.rigs.rig_file import load_rig

        if self.frame not in FRAMES:
            raise CadeError(f"unknown --frame {self.frame!r}; choose rectified or original")
        rig_pair_rectification(load_rig(self.rig), self.camera)

    def budget(self) -> int:
        """The memory limit of one worker, bytes: ``memory_limit``, or the machine's default."""
        return default_memory_limit() if self.memory_limit is None else self.memory_limit

    def fingerprint(self) -> dict:
        """What decides a pair's outputs, as stored in its record: these options and, for
        a learned method, the sha256 of the network files the model card names."""
        from cade_cli.matching import method_fingerprint

        options = asdict(self)
        del options["strict"]
        if self.vis_range is None:  # left out, so that records written before it existed still match
            del options["vis_range"]
        else:
            options["vis_range"] = list(self.vis_range)  # as JSON gives it back
        if self.rig is None:  # without a rig its options are their defaults (but --fix-vertical's): left out
            for name in ("rig", *RIG_ONLY):
                if not (self.fix_vertical and name in ("fix_vertical", "frame")):
                    del options[name]
        else:  # the rig by its content, wherever its file lies
            options["rig"] = file_sha256(Path(self.rig))
        options.update(method_fingerprint(self.method, model=self.model))
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

    def failure(self, error: str, *, attempts: int, worker: str | None = None) -> "PairResult":
        """The engines' job protocol (cade_cli.batch.engines, run by job.run_job): failure, absolute."""
        return PairResult.failure(self, error, attempts=attempts, worker=worker)

    def absolute(self) -> "Pair":
        return replace(self, left=self.left.absolute(), right=self.right.absolute(), output=self.output.absolute())


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
                    overrides[name] = parse_bound(cells[name], option=name.replace("_", "-"))
            for name in ("left_band", "right_band"):
                if cells.get(name):
                    if not cells[name].isdigit():
                        raise CadeError(f"{name} must be a 0-based band number, got {cells[name]!r}")
                    overrides[name] = int(cells[name])
            check_bounds(overrides.get("min_disp", options.min_disp), overrides.get("max_disp", options.max_disp))
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


def expected_record(pair: Pair) -> dict:
    """The part of a pair's record that its inputs and options decide."""
    return {
        "format": RECORD_FORMAT,
        "inputs": {"left": file_sha256(pair.left), "right": file_sha256(pair.right)},
        "options": pair.options.fingerprint(),
    }


def is_finished(pair: Pair) -> bool:
    """Whether the pair's outputs are verified as made from its inputs with its options
    (:func:`outputs_verified`). A missing or unreadable input is not finished (the run will report it)."""
    return outputs_verified(pair.record, lambda: expected_record(pair), pair.outputs())


def outputs_verified(record_path: Path, expected: Callable[[], dict], wanted: dict[str, Path]) -> bool:
    """Whether a batch job's record proves its outputs: the record parses, holds every item of
    ``expected()`` (its inputs' sha256 and options; computed here, so an unreadable input is a
    False), lists exactly the outputs ``wanted`` (role -> path), and each is there with the sha256
    listed. Shared by the pairs' and the captures' batches."""
    try:
        record = json.loads(record_path.read_text())
        expected_items = expected().items()
    except (OSError, ValueError, CadeError):
        return False
    if not isinstance(record, dict) or any(record.get(key) != value for key, value in expected_items):
        return False
    listed = record.get("outputs")
    if not isinstance(listed, dict) or set(listed) != set(wanted):
        return False
    try:
        return all(isinstance(listed[role], dict) and listed[role].get("file") == path.name
                   and file_sha256(path) == listed[role].get("sha256") for role, path in wanted.items())
    except OSError:
        return False


def skipped_result(pair: Pair) -> PairResult:
    """The result of a pair :func:`is_finished` found finished (read from its record)."""
    record = json.loads(pair.record.read_text())
    return PairResult(str(pair.left), str(pair.right), str(pair.output), "skipped",
                      range=tuple(record.get("range") or ()) or None,
                      outputs={role: entry["sha256"] for role, entry in record["outputs"].items()}, attempts=0)


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"
