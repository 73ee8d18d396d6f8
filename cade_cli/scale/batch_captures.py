"""A drone flight as a batch (``cade batch --captures``): one job per capture
(:class:`CaptureJob`, with the job protocol the engines of :mod:`cade_cli.scale.batch` run),
registered as ``cade register-capture`` does and written with a record beside its cube that
makes the flight resumable; the jobs of a flight folder (grouped by capture id, calibration
panels set aside); the memory plan of a capture job.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from cade_cli.version import __version__
from cade_cli.capture.cube import DTYPES, mask_path
from cade_cli.capture.flight import group_captures
from cade_cli.capture.register import DEFAULT_MATCH_SCALE
from cade_cli.errors import CadeError
from cade_cli.io.checksum import file_sha256
from cade_cli.scale.batch_job import peak_rss_mb
from cade_cli.scale.batch_pairs import RECORD_SUFFIX, worker_name
from cade_cli.scale.memory import BASE_BYTES
from cade_cli.stereo import DEFAULT_METHOD

CAPTURE_RECORD_FORMAT = 1

SIDE_PICTURES = {"vis": "_vis.png", "ndvi": "_ndvi.png"}
"""The pictures a capture job may write beside its cube, ``<stem><suffix>``."""

CAPTURE_PIXEL_BYTES = 48
"""Planned bytes per pixel of every band: the raw band, its float32 registered copy, the
validity, saturation and per-band maps (docs/drone.md, "A whole flight")."""
CAPTURE_MATCHING_BYTES = 700 * 2**20
"""Planned bytes of the dense matching of one band, which keeps to 1.5 MP whatever the size."""


@dataclass(frozen=True)
class CaptureOptions:
    """The ``cade register-capture`` options a flight's batch applies to every capture."""

    reference: str | None = None
    method: str = DEFAULT_METHOD
    model: str | None = None
    plane_only: bool = False
    dtype: str = "float32"
    match_scale: float = DEFAULT_MATCH_SCALE
    vis: bool = False
    ndvi: bool = False

    def check(self) -> None:
        """Refuse an unknown ``dtype`` or method before any capture runs."""
        from cade_cli.matching import get_matcher

        if self.dtype not in DTYPES:
            raise CadeError(f"unknown --dtype {self.dtype!r}; choose one of {', '.join(DTYPES)}")
        if not self.plane_only:
            get_matcher(self.method, model=self.model)

    def fingerprint(self) -> dict:
        """What decides a capture's outputs, as stored in its record (a learned method's
        network files by sha256, as for pairs)."""
        from cade_cli.matching import LEARNED_METHODS
        from cade_cli.model_card import network_fingerprint

        options = asdict(self)
        if self.plane_only:  # no dense matching: its options do not change the cube
            for name in ("method", "model", "match_scale"):
                del options[name]
        elif self.method in LEARNED_METHODS:
            options.update(network_fingerprint(self.model))
        return options


@dataclass(frozen=True)
class CaptureResult:
    """What became of one capture: ``status`` done, skipped (verified as finished) or failed
    (``error``, one line); ``outputs`` role -> sha256; ``registration`` band -> how it was
    registered (reference, plane, parallax, plane-only); ``seen`` band -> share of the
    reference's pixels it saw."""

    name: str
    output: str
    status: str
    inputs: tuple[str, ...] = ()
    error: str | None = None
    outputs: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    worker: str | None = None
    attempts: int = 1
    registration: dict[str, str] = field(default_factory=dict)
    seen: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    peak_rss_mb: float | None = None


@dataclass(frozen=True)
class CaptureJob:
    """One capture of a flight: register the band files ``paths`` with ``options`` into
    ``output``; ``problem``: why it cannot run (it fails with that line)."""

    name: str
    paths: tuple[Path, ...]
    output: Path
    options: CaptureOptions = CaptureOptions()
    problem: str | None = None

    def outputs(self) -> dict[str, Path]:
        """Role -> file: the cube, the uint16 cube's mask, the pictures asked for."""
        found = {"cube": self.output}
        if self.options.dtype == "uint16":
            found["mask"] = mask_path(self.output)
        stem = self.output.with_suffix("")
        for role, suffix in SIDE_PICTURES.items():
            if getattr(self.options, role):
                found[role] = stem.parent / (stem.name + suffix)
        return found

    @property
    def record(self) -> Path:
        return self.output.with_name(self.output.name + RECORD_SUFFIX)

    def run(self) -> CaptureResult:
        return run_capture(self)

    def failure(self, error: str, *, attempts: int, worker: str | None = None) -> CaptureResult:
        return CaptureResult(self.name, str(self.output), "failed", tuple(map(str, self.paths)), error=error,
                             attempts=attempts, worker=worker)

    def absolute(self) -> "CaptureJob":
        return replace(self, paths=tuple(path.absolute() for path in self.paths), output=self.output.absolute())


def expected_record(job: CaptureJob) -> dict:
    """The part of a capture's record that its band files (by name and sha256) and options decide."""
    return {"format": CAPTURE_RECORD_FORMAT, "inputs": {path.name: file_sha256(path) for path in job.paths},
            "options": job.options.fingerprint()}


def run_capture(job: CaptureJob) -> CaptureResult:
    """Register one capture and write its cube, pictures and record, all or nothing; a
    :class:`CadeError` (bad input) is a ``failed`` result, any other exception propagates (the
    engine retries the capture)."""
    from cade_cli.capture.cube import write_registration
    from cade_cli.capture.model import load_capture
    from cade_cli.capture.register import matching_scale, register_capture
    from cade_cli.io.atomic import atomic_outputs

    started, options = time.perf_counter(), job.options
    try:
        if job.problem is not None:
            raise CadeError(job.problem)
        record = expected_record(job)
        capture = load_capture(job.paths, reference=options.reference)
        registration = register_capture(capture, plane_only=options.plane_only, method=options.method,
                                        scale=options.match_scale, model=options.model)
        wanted = job.outputs()
        for path in (*wanted.values(), job.record):
            path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_outputs([*wanted.values(), job.record]) as staged:  # the record is renamed last
            write_registration(registration, cube=staged[job.output], dtype=options.dtype,
                               **{role: staged[path] for role, path in wanted.items() if role != "cube"})
            hashes = {role: file_sha256(staged[path]) for role, path in wanted.items()}
            how = {result.name: result.path for result in registration.results}
            seen = {band.name: round(float(valid.mean()), 4) for band, valid in zip(capture.bands, registration.valid)}
            record.update(outputs={role: {"file": path.name, "sha256": hashes[role]} for role, path in wanted.items()},
                          cade_version=__version__, registration=how, seen=seen)
            staged[job.record].write_text(json.dumps(record, indent=1) + "\n")
    except CadeError as error:
        return job.failure(str(error).splitlines()[0], attempts=1, worker=worker_name())
    notes = [f"{name}: parallax below 0.3 px everywhere (a high flight): registered by its plane homography alone"
             for name, path in how.items() if path == "plane"]
    scale = matching_scale(capture, options.match_scale)
    if scale < options.match_scale and not options.plane_only:
        notes.append(f"bands of {capture.size[0]}x{capture.size[1]} are matched at scale {scale:.2f} instead of "
                     f"{options.match_scale:g} (dense matching keeps to 1.5 MP per band)")
    return CaptureResult(job.name, str(job.output), "done", tuple(map(str, job.paths)), outputs=hashes,
                         seconds=time.perf_counter() - started, worker=worker_name(), registration=how, seen=seen,
                         notes=tuple(notes), peak_rss_mb=peak_rss_mb())


def is_finished(job: CaptureJob) -> bool:
    """Whether the capture's outputs are verified as made from its band files with its options:
    its record names the same files, sha256 and options, and lists exactly the outputs asked
    for, each there with the sha256 listed."""
    try:
        record = json.loads(job.record.read_text())
        expected = expected_record(job)
    except (OSError, ValueError, CadeError):
        return False
    if not isinstance(record, dict) or any(record.get(key) != value for key, value in expected.items()):
        return False
    listed, wanted = record.get("outputs"), job.outputs()
    if not isinstance(listed, dict) or set(listed) != set(wanted):
        return False
    try:
        return all(isinstance(listed[role], dict) and listed[role].get("file") == path.name
                   and file_sha256(path) == listed[role].get("sha256") for role, path in wanted.items())
    except OSError:
        return False


def skipped_result(job: CaptureJob) -> CaptureResult:
    """The result of a capture :func:`is_finished` found finished (read from its record)."""
    record = json.loads(job.record.read_text())
    return CaptureResult(job.name, str(job.output), "skipped", tuple(map(str, job.paths)),
                         outputs={role: entry["sha256"] for role, entry in record["outputs"].items()}, attempts=0,
                         registration=record.get("registration") or {}, seen=record.get("seen") or {})


def flight_jobs(folder: Path, output_dir: Path, options: CaptureOptions, *, skip_panels: bool = False,
                panels: tuple[str, ...] = ()) -> tuple[list[CaptureJob], list[str]]:
    """The jobs of a flight folder (:func:`cade_cli.capture.flight.group_captures`: grouped by
    capture id; ``<output_dir>/<subfolder>/<name>.tif`` each) and the notes to show (files
    that are not band files, panels skipped or kept).

    A capture is a calibration panel when its files say so (``Camera:CalibrationPicture`` 1 or
    2: the Sequoia, and any camera following Pix4D's tags) or when ``panels`` names it (by
    name or capture id: MicaSense RedEdge files carry no such tag). With ``skip_panels`` the
    panels get no job.

    Raises:
        CadeError: no capture in the folder, or a name in ``panels`` that is no capture's.
    """
    captures, notes = group_captures(folder, skip=(output_dir,))
    if not captures:
        raise CadeError(f"no capture found in {folder}: no TIFF there carries a band name and a capture id in its XMP")
    known = {capture.name for capture in captures} | {capture.capture_id for capture in captures}
    unknown = [name for name in panels if name not in known]
    if unknown:
        raise CadeError(f"--panel {unknown[0]} names no capture of {folder}; its captures are "
                        f"{', '.join(capture.name for capture in captures[:5])}{' ...' if len(captures) > 5 else ''}")
    jobs = []
    for capture in captures:
        if capture.panel or capture.name in panels or capture.capture_id in panels:
            why = "tagged Camera:CalibrationPicture" if capture.panel else "named by --panel"
            if skip_panels:
                notes.append(f"{capture.name}: a calibration panel shot ({why}): skipped (--skip-panels)")
                continue
            notes.append(f"{capture.name}: a calibration panel shot ({why}), registered; --skip-panels leaves it out")
        jobs.append(CaptureJob(capture.name, capture.paths, capture.output(output_dir), options, capture.problem))
    return jobs, notes


def capture_memory_bytes(jobs: list[CaptureJob]) -> tuple[str, int]:
    """(the largest capture's size, its planned peak bytes): a worker's base, the dense matching of
    a band (:data:`CAPTURE_MATCHING_BYTES`) and :data:`CAPTURE_PIXEL_BYTES` per pixel of every band."""
    import tifffile

    def plan(job: CaptureJob) -> tuple[str, int]:
        try:
            with tifffile.TiffFile(job.paths[0]) as tiff:
                height, width = tiff.pages[0].shape[:2]
        except (OSError, tifffile.TiffFileError, IndexError, ValueError):
            return "unreadable", 0  # the job reports it
        pixels = width * height * len(job.paths)
        return (f"{len(job.paths)} bands of {width}x{height}",
                BASE_BYTES + CAPTURE_MATCHING_BYTES + CAPTURE_PIXEL_BYTES * pixels)

    return max((plan(job) for job in jobs), key=lambda planned: planned[1])
