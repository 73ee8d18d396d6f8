"""Many pairs in one run (``cade batch``): the pair list, resume, one job per pair, and two engines.

The pairs, their options and records are :mod:`cade_cli.batch.pairs`, one pair's job
:mod:`cade_cli.batch.job`, the run's JSON log :mod:`cade_cli.batch.log`; this module holds
the engines and the memory plan.

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

Engines (both run any job with :class:`Pair`'s protocol, a pair or a flight's capture; results as jobs end):

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
import functools
import multiprocessing
import multiprocessing.connection
import os
import signal
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from cade_cli.allocator import retain_freed_memory
from cade_cli.errors import CadeError
from cade_cli.evaluation.timing import use_threads
from cade_cli.batch.job import remove_stale_temporaries, run_job
from cade_cli.batch.pairs import Pair, PairResult, worker_name
from cade_cli.scale.memory import BASE_BYTES, available_memory_bytes, matching_memory_bytes

ATTEMPTS = 2
"""Runs of a pair before its failure is reported: the first and one retry."""

WORKER_BASE_BYTES = BASE_BYTES
"""Resident memory of a worker before its first pair: Python, NumPy, OpenCV, onnxruntime.
With :data:`~cade_cli.scale.memory.PIXEL_BYTES` per pixel the plan sits just above the measured
peaks of ``cade``: 0.30 GiB against 0.25-0.27 GiB on 640x480 (docs/scale.md, "Throughput"),
1.46 GB against 1.45 GB on 6 megapixels (docs/research/speed.md)."""
MEMORY_HEADROOM = 0.8
"""Share of the available memory the workers may plan to use."""


# --- the pair list ---------------------------------------------------------------------------------------------------


# --- resume ----------------------------------------------------------------------------------------------------------


# --- one pair --------------------------------------------------------------------------------------------------------


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


def check_output_ranges(pairs: Sequence[Pair]) -> None:
    """Refuse, before any pair runs, a pair whose disparity output cannot hold the range it
    searches (a 16-bit PNG: :func:`~cade_cli.io.disparity.check_disparity_range`), from its
    given bounds or the default one; a bound ``auto`` is checked by the job once estimated."""
    from cade_cli.io.disparity import check_disparity_range
    from cade_cli.stereo import default_max_disparity

    for pair in pairs:
        options = pair.options
        if pair.output.suffix.lower() != ".png":
            continue
        top = options.max_disp if isinstance(options.max_disp, int) else 0
        if options.max_disp is None:
            width = (_rectified_size(options.rig, options.camera) if options.rig is not None
                     else image_size(pair.left))[0]
            top = default_max_disparity(width)
        check_disparity_range(pair.output, options.min_disp if isinstance(options.min_disp, int) else 0, top)


@functools.lru_cache(maxsize=4)
def _rectified_size(rig: str, camera: str | None) -> tuple[int, int]:
    from cade_cli.rigs.pair import rig_pair_rectification
    from cade_cli.rigs.rig_file import load_rig

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
    from cade_cli.io.image_files import header_size
    from cade_cli.io.images import load_image

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
            return replace(run_job(pair), attempts=attempt)
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as error:  # noqa: BLE001 - reported for this pair, the batch goes on
            if attempt == ATTEMPTS:
                return pair.failure(f"{type(error).__name__}: {error}".splitlines()[0], attempts=attempt,
                                    worker=worker_name())
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
                connection.send((index, run_job(pair), None))
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
    interrupted: list[Pair] = []
    attempts: collections.Counter[int] = collections.Counter()
    workers = [start() for _ in range(min(jobs, len(waiting)))]
    try:
        while waiting or any(worker.running for worker in workers):
            _hand_out(workers, waiting, attempts)
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
        interrupted = [worker.running[1] for worker in workers if worker.running is not None]
        for worker in workers:  # interrupt the pairs in hand; their temporaries are discarded
            if worker.process.is_alive():
                os.kill(worker.process.pid, signal.SIGINT)
        raise
    finally:
        _stop_workers(workers)
        # a signal that lands while a worker discards its temporary (or before it is tracked) leaves
        # it behind; every worker has ended, so no one else writes these pairs: as for a dead worker
        remove_stale_temporaries(interrupted)


def _hand_out(workers: list[_Worker], waiting: collections.deque, attempts: collections.Counter) -> None:
    """Send each idle worker the next waiting pair (counting its attempt)."""
    for worker in workers:
        if worker.running is None and waiting:
            worker.running = waiting.popleft()
            attempts[worker.running[0]] += 1
            try:
                worker.connection.send(worker.running)
            except (BrokenPipeError, OSError):
                pass  # a dead worker: found by its sentinel


def _stop_workers(workers: list[_Worker]) -> None:
    """Tell every worker to stop, wait for each (30 s, then terminate it), close its pipe."""
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
    return pair.failure(error, attempts=attempts[index])


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
            pair = pair.absolute()
            future = client.submit(run_job, pair, key=f"cade-pair-{token}-{index}", pure=False,
                                   retries=ATTEMPTS - 1)
            futures[future] = pair
        for future in as_completed(futures):
            pair = futures[future]
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 - reported for this pair, the batch goes on
                yield pair.failure(f"{type(exc).__name__}: {exc}".splitlines()[0], attempts=ATTEMPTS)
    finally:
        client.cancel(list(futures))
        if own:
            client.close()
