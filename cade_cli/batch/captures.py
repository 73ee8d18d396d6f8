"""A drone flight as a batch (``cade batch --captures``): one job per capture
(:class:`CaptureJob`, with the job protocol the engines of :mod:`cade_cli.batch.engines` run),
registered as ``cade register-capture`` does and written with a record beside its cube that
makes the flight resumable; the memory plan of a capture job. The jobs of a flight folder are
:mod:`cade_cli.batch.flight`.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from cade_cli.version import __version__
from cade_cli.capture.cube import DTYPES, mask_path
from cade_cli.capture.metadata import quiet_tifffile
from cade_cli.capture.register import DEFAULT_MATCH_SCALE, NEAR_FACTOR, check_near
from cade_cli.errors import CadeError
from cade_cli.io.checksum import file_sha256
from cade_cli.batch.job import peak_rss_mb
from cade_cli.batch.pairs import RECORD_SUFFIX, outputs_verified, worker_name
from cade_cli.batch.radiometry import capture_radiometry, check_quantity
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
    near: float = NEAR_FACTOR
    vis: bool = False
    ndvi: bool = False
    bands: tuple[str, ...] | None = None
    radiometry: str | None = None
    irradiance: dict[str, float] | None = None
    irradiance_source: str | None = None
    """``radiometry``: None (raw values), ``"radiance"`` or ``"reflectance"``; ``irradiance``: the
    panel shot's, band name -> W/m^2/nm, for every capture (None: each capture's own DLS), from
    ``irradiance_source`` (``"panel IMG_0000"``); :mod:`cade_cli.batch.radiometry`."""

    def check(self) -> None:
        """Refuse an unknown ``dtype``, method, radiometric quantity or a near factor below 1
        before any capture runs."""
        from cade_cli.matching import get_matcher

        if self.dtype not in DTYPES:
            raise CadeError(f"unknown --dtype {self.dtype!r}; choose one of {', '.join(DTYPES)}")
        check_quantity(self.radiometry, self.dtype, self.irradiance)
        check_near(self.near)
        if not self.plane_only:
            get_matcher(self.method, model=self.model)

    def fingerprint(self) -> dict:
        """What decides a capture's outputs, as stored in its record (a learned method's
        network files by sha256, as for pairs)."""
        from cade_cli.matching import method_fingerprint

        options = asdict(self)
        if self.bands is None:  # all bands: the records of runs before --bands existed still hold
            del options["bands"]
        else:
            options["bands"] = list(self.bands)
        for name in ("radiometry", "irradiance", "irradiance_source"):  # raw values: older records still hold
            if options[name] is None:
                del options[name]
        if self.near == 1:  # the matches' own range: the records of runs before --near existed still hold
            del options["near"]
        if self.plane_only:  # no dense matching: its options do not change the cube
            for name in ("method", "model", "match_scale", "near"):
                options.pop(name, None)
        else:
            options.update(method_fingerprint(self.method, model=self.model))
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
    ``output``; ``problem``: why it cannot run (it fails with that line); ``per_band``: the
    aligned single-band files to write (``--per-band``), one per band kept, each named as its
    source file."""

    name: str
    paths: tuple[Path, ...]
    output: Path
    options: CaptureOptions = CaptureOptions()
    problem: str | None = None
    per_band: tuple[Path, ...] = ()

    def outputs(self) -> dict[str, Path]:
        """Role -> file: the cube, the uint16 cube's mask, the pictures asked for."""
        found = {"cube": self.output}
        if self.options.dtype == "uint16":
            found["mask"] = mask_path(self.output)
        stem = self.output.with_suffix("")
        for role, suffix in SIDE_PICTURES.items():
            if getattr(self.options, role):
                found[role] = stem.parent / (stem.name + suffix)
        found.update((f"per-band {path.name}", path) for path in self.per_band)
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
        return replace(self, paths=tuple(path.absolute() for path in self.paths), output=self.output.absolute(),
                       per_band=tuple(path.absolute() for path in self.per_band))


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
    from cade_cli.capture.radiometry import describe
    from cade_cli.capture.register import matching_scale, register_capture
    from cade_cli.io.atomic import atomic_outputs

    started, options = time.perf_counter(), job.options
    try:
        if job.problem is not None:
            raise CadeError(job.problem)
        record = expected_record(job)
        capture = load_capture(job.paths, reference=options.reference, bands=options.bands)
        paths = [band.path for band in capture.bands]
        radiometry = capture_radiometry(options, paths, capture.names())
        registration = register_capture(capture, plane_only=options.plane_only, method=options.method,
                                        scale=options.match_scale, model=options.model, near=options.near,
                                        radiometry=radiometry)
        wanted = job.outputs()
        for path in (*wanted.values(), job.record):
            path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_outputs([*wanted.values(), job.record]) as staged:  # the record is renamed last
            per_band = None
            if job.per_band:
                missing = [band.path.name for band in capture.bands if f"per-band {band.path.name}" not in wanted]
                if missing:
                    raise CadeError(f"--per-band: no aligned file planned for {missing[0]}")
                per_band = [staged[wanted[f"per-band {band.path.name}"]] for band in capture.bands]
            write_registration(registration, cube=staged[job.output], dtype=options.dtype, per_band=per_band,
                               **{role: staged[path] for role, path in wanted.items()
                                  if role != "cube" and not role.startswith("per-band ")})
            hashes = {role: file_sha256(staged[path]) for role, path in wanted.items()}
            how = {result.name: result.path for result in registration.results}
            seen = {band.name: round(float(valid.mean()), 4) for band, valid in zip(capture.bands, registration.valid)}
            record.update(outputs={role: {"file": path.name, "sha256": hashes[role]} for role, path in wanted.items()},
                          cade_version=__version__, registration=how, seen=seen,
                          **({"radiometry": describe(radiometry, paths)} if radiometry else {}),
                          **({"measured_rotation_deg": dict(registration.capture.linked)}
                             if registration.capture.linked else {}))
            staged[job.record].write_text(json.dumps(record, indent=1) + "\n")
    except CadeError as error:
        return job.failure(str(error).splitlines()[0], attempts=1, worker=worker_name())
    remove_stale_outputs(job)
    notes = capture_notes(registration.capture, how)
    measured = [name for name, angle in registration.capture.linked if angle is not None]
    near = [name for name, angle in registration.capture.linked if angle is None]
    if measured:
        notes.append(f"{', '.join(measured)}: a second camera's reference band, its rotation against the reference "
                     "measured from the images (angles in the record)")
    if near:
        notes.append(f"{', '.join(near)}: a second camera's reference band; too near to measure its rotation against "
                     "the first camera: its tags' rotations kept")
    scale = matching_scale(capture, options.match_scale)
    if scale < options.match_scale and not options.plane_only:
        notes.append(f"bands of {capture.size[0]}x{capture.size[1]} are matched at scale {scale:.2f} instead of "
                     f"{options.match_scale:g} (dense matching keeps to 1.5 MP per band)")
    return CaptureResult(job.name, str(job.output), "done", tuple(map(str, job.paths)), outputs=hashes,
                         seconds=time.perf_counter() - started, worker=worker_name(), registration=how, seen=seen,
                         notes=tuple(notes), peak_rss_mb=peak_rss_mb())


def capture_notes(capture, how: dict[str, str]) -> list[str]:
    """What a registered capture has to say, each note worded the same for every capture it
    applies to, so that a flight shows it once with a count (the angles measured stay in the
    record): bands left out by ``--bands``, bands registered by their plane alone or by the rig
    alone."""
    notes = []
    if capture.left_out:
        notes.append(f"{', '.join(band.name for band in capture.left_out)}: left out by --bands")
    plane = [name for name, path in how.items() if path == "plane"]
    if plane:
        notes.append(f"{', '.join(plane)}: parallax below 0.3 px everywhere (a high flight): registered by its plane "
                     "homography alone")
    rig = [name for name, path in how.items() if path == "rig"]
    if rig:
        notes.append(f"{', '.join(rig)}: too coarse to match (a thermal band?): placed by its lens and rotation alone")
    return notes


def remove_stale_outputs(job: CaptureJob) -> None:
    """Remove what the capture's last run wrote and this run did not (the ``.valid.tif`` of a
    uint16 run, the pictures no longer asked for): the files its record listed before, by the
    names :meth:`CaptureJob.outputs` gives them, beside the cube. Call once the new record is in
    place; the files of this run are kept."""
    wanted = job.outputs()
    stale = {role: path for role, path in CaptureJob(job.name, job.paths, job.output,
                                                      _every_side_output(job.options)).outputs().items()
             if role not in wanted}
    for path in stale.values():
        if path.is_file():
            path.unlink()


def _every_side_output(options: CaptureOptions) -> CaptureOptions:
    return replace(options, dtype="uint16", **{role: True for role in SIDE_PICTURES})


def is_finished(job: CaptureJob) -> bool:
    """Whether the capture's outputs are verified as made from its band files with its options:
    its record names the same files, sha256 and options, and lists exactly the outputs asked
    for, each there with the sha256 listed (:func:`~cade_cli.batch.pairs.outputs_verified`)."""
    return outputs_verified(job.record, lambda: expected_record(job), job.outputs())


def skipped_result(job: CaptureJob) -> CaptureResult:
    """The result of a capture :func:`is_finished` found finished (read from its record)."""
    record = json.loads(job.record.read_text())
    return CaptureResult(job.name, str(job.output), "skipped", tuple(map(str, job.paths)),
                         outputs={role: entry["sha256"] for role, entry in record["outputs"].items()}, attempts=0,
                         registration=record.get("registration") or {}, seen=record.get("seen") or {})


def capture_memory_bytes(jobs: list[CaptureJob]) -> tuple[str, int]:
    """(the largest capture's size, its planned peak bytes): a worker's base, the dense matching of
    a band (:data:`CAPTURE_MATCHING_BYTES`) and :data:`CAPTURE_PIXEL_BYTES` per pixel of every band."""
    import tifffile

    def plan(job: CaptureJob) -> tuple[str, int]:
        sizes = []
        for path in job.paths:  # bands may differ in size (a panchromatic band at 2x)
            try:
                with quiet_tifffile(), tifffile.TiffFile(path) as tiff:
                    sizes.append(tiff.pages[0].shape[:2])
            except (OSError, tifffile.TiffFileError, IndexError, ValueError):
                return "unreadable", 0  # the job reports it
        height, width = sizes[0]
        pixels = sum(h * w for h, w in sizes)
        return (f"{len(job.paths)} bands of {width}x{height}" + ("" if len(set(sizes)) == 1 else " and other sizes"),
                BASE_BYTES + CAPTURE_MATCHING_BYTES + CAPTURE_PIXEL_BYTES * pixels)

    return max((plan(job) for job in jobs), key=lambda planned: planned[1])
