"""One pair's job in a batch: read, check, match (whole, as tiles, or through a rig) and write
its outputs and record together (:func:`run_pair`), the code every engine runs in its workers;
and the sweep of temporaries a killed worker left.
"""

from __future__ import annotations

import glob
import json
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from cade_cli.version import __version__
from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_outputs, intended_path
from cade_cli.io.disparity import check_disparity_range
from cade_cli.io.checksum import file_sha256
from cade_cli.batch.pairs import Pair, PairOptions, PairResult, expected_record, worker_name
from cade_cli.scale.range import AUTO, RangeEstimate


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


def run_job(job):
    """Run one job of a batch: a :class:`Pair` by :func:`run_pair`, anything else (a flight's capture) by
    its ``run()``; the task every engine's worker runs."""
    return run_pair(job) if isinstance(job, Pair) else job.run()


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
    from cade_cli.io.match_outputs import write_match_outputs
    from cade_cli.matching import densify
    from cade_cli.pair_check import check_pair
    from cade_cli.scale.range import resolve_range
    from cade_cli.scale.tiling import estimate_disparity_tiled

    options = pair.options
    if left.shape != right.shape:
        raise CadeError(f"{pair.left} is {left.shape[1]}x{left.shape[0]} but {pair.right} is "
                        f"{right.shape[1]}x{right.shape[0]}; a pair's images must have one size")
    warp = None
    if options.fix_vertical:  # no rig: the warp from the pair itself
        from cade_cli.rigs.uncalibrated import estimate_pair_rectification

        warp = estimate_pair_rectification(left, right)
        left, right = warp.rectify(left, right)
    searched, estimate = resolve_range(left, right, min_disp=options.min_disp, max_disp=options.max_disp)
    check_disparity_range(pair.output, searched.minimum, searched.maximum)  # an auto bound, before matching
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

    framed = (result.disparity, result.valid, densify(result.disparity, result.valid), result.confidence)
    if warp is not None and options.frame == "original":
        from cade_cli.rigs.uncalibrated import match_in_original_frame

        framed = match_in_original_frame(warp, *framed)
    unfilled, valid, dense, confidence = framed

    def write(files: dict[str, Path]) -> None:
        write_match_outputs(files, dense=dense, disparity=unfilled, valid=valid, confidence=confidence,
                            fill=options.fill, vis_range=options.vis_range)

    facts = {"tiles": len(plan.tiles), "pair_check": checked.record()}
    if warp is not None:
        facts["uncalibrated_rectification"] = warp.record()
    return _Matched((searched.minimum, searched.maximum), _range_note(options, estimate), float(valid.mean()),
                    write, facts, (checked.describe(),) if checked.problems else ())


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
    from cade_cli.rigs.pair import check_rig_pair, match_rig_pair, rig_pair_rectification, write_rig_outputs
    from cade_cli.rigs.rig_file import load_rig
    from cade_cli.rigs.self_check import VERTICAL_TOLERANCE_PX

    options = pair.options
    rig = load_rig(options.rig)
    other, rectification = rig_pair_rectification(rig, options.camera)
    check_rig_pair(rig, rectification, left, right, paths=(pair.left, pair.right))
    width = rectification.image_size[0]
    budget = options.budget()
    found, framed = match_rig_pair(rig, left, right, other=other, frame=options.frame, fill=options.fill,
                                   fix_vertical=options.fix_vertical, method=options.method, min_disp=options.min_disp,
                                   max_disp=options.max_disp, preprocess=options.preprocess, model=options.model,
                                   memory_limit=budget, on_range=lambda searched: check_disparity_range(
                                       pair.output, searched.minimum, searched.maximum))
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
