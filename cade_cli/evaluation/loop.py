"""The benchmark loop: dataset x protocol x method x preprocessing, scored the paper's way.

One unit of work is one scene: it is decoded once, then every protocol x method x
preprocessing (x degradation) runs on it and is scored into flat records
(:func:`evaluate_scene`). Scenes run in parallel worker processes with ``jobs > 1``;
results come back in scene order whatever ``jobs`` is, so runs are deterministic.
Task subsets, degraded right bands and timing (warm-up, repeats, threads) are options
of the same loop; ``cade benchmark`` and every script in ``benchmarks/`` use it.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from cade_cli.allocator import retain_freed_memory
from cade_cli.data import Dataset, Scene, get_dataset
from cade_cli.errors import CadeError, lookup
from cade_cli.evaluation.degradations import DEGRADATIONS, degrade
from cade_cli.evaluation.metrics import METRIC_NAMES, score
from cade_cli.evaluation.protocols import get_protocol, run_protocol
from cade_cli.evaluation.timing import Timing, use_threads
from cade_cli.io.atomic import atomic_output
from cade_cli.matching import MATCHERS, PREPROCESS_CHOICES

T = TypeVar("T")

SUMMARY_GROUPS: dict[str, str] = {
    "method": "methods", "preprocess": "preprocess", "protocol": "protocols", "degradation": "degradations"}
"""Record field a summary can group by -> the config list that orders its values."""


@dataclass(frozen=True)
class Record:
    """Scores of one scored prediction (one CS task, or the RGB median map).

    ``seconds`` is the matcher's wall time (median of the timed runs; for the RGB median
    the sum of its ``matcher_runs`` runs); ``degradation`` names what was done to the
    right band (:mod:`~cade_cli.evaluation.degradations`).
    """

    dataset: str
    resolution: str
    scene: str
    protocol: str
    method: str
    preprocess: str
    task: str
    seconds: float
    matcher_runs: int
    scores: dict[str, float]
    degradation: str = "none"

    def to_dict(self) -> dict:
        """The record as JSON-ready dict; ``degradation`` only when the band was degraded."""
        record = asdict(self)
        if self.degradation == "none":
            del record["degradation"]
        return record


@dataclass
class BenchmarkRun:
    """Everything a benchmark produced: its configuration and one record per scored map.

    Attributes:
        config: the resolved options (dataset, scenes, methods, protocols, ...).
        records: in scene, protocol, method, preprocess, degradation, task order.
        scene_shapes: scene name -> (height, width, max_disp) in pixels; not in the JSON.
    """

    config: dict
    records: list[Record] = field(default_factory=list)
    scene_shapes: dict[str, tuple[int, int, int]] = field(default_factory=dict)

    def summary(self, by: Sequence[str] = ("method", "preprocess", "protocol")) -> list[dict]:
        """Mean of every metric and of seconds per group of records, in config order.

        Args:
            by: record fields to group by, from :data:`SUMMARY_GROUPS`.

        Returns:
            One row per group that has records: the ``by`` fields, ``scores`` (NaN-ignoring
            means over scenes and tasks), ``maps`` (distinct scene x task pairs) and
            ``seconds_per_pair`` (seconds per matcher run).
        """
        values = [self.config[lookup(SUMMARY_GROUPS, name, kind="summary group")] for name in by]
        rows = []
        for key in itertools.product(*values):
            chosen = [r for r in self.records if tuple(getattr(r, name) for name in by) == key]
            if not chosen:
                continue
            means = {name: float(np.nanmean([r.scores.get(name, np.nan) for r in chosen]))
                     for name in sorted({k for r in chosen for k in r.scores})}
            rows.append({
                **dict(zip(by, key)), "scores": means, "maps": len({(r.scene, r.task) for r in chosen}),
                "seconds_per_pair": float(sum(r.seconds for r in chosen) / sum(r.matcher_runs for r in chosen)),
            })
        return rows

    def to_json(self) -> str:
        return json.dumps(
            {"config": self.config, "summary": self.summary(), "records": [r.to_dict() for r in self.records]},
            indent=1, allow_nan=True,
        )


@dataclass(frozen=True)
class Plan:
    """What :func:`evaluate_scene` runs on each scene (resolved, checked, picklable).

    Attributes:
        dataset: dataset name, copied into the records.
        matchers: method name -> matcher, in the order they run.
        preprocess: method name -> its preprocessing values, in order.
        protocols: protocol names.
        tasks: task names to run (None: every task of each protocol).
        degradations: names from :data:`~cade_cli.evaluation.degradations.DEGRADATIONS`.
        timing: warm-up, repeats and threads of every matcher call.
        seed: seed of the random draws of a degradation (the same for every band).
        save_dir: where to write each scored map and its error map, or None.
    """

    dataset: str
    matchers: Mapping[str, Any]
    preprocess: Mapping[str, tuple[str, ...]]
    protocols: tuple[str, ...]
    tasks: tuple[str, ...] | None = None
    degradations: tuple[str, ...] = ("none",)
    timing: Timing = Timing()
    seed: int = 0
    save_dir: str | None = None


def evaluate_scene(scene: Scene, plan: Plan) -> list[Record]:
    """Run and score every protocol x method x preprocess x degradation of ``plan`` on one scene.

    The search range is [0, ``scene.max_disp``] (inclusive). A matcher is called as
    ``matcher(left, right, max_disp=..., min_disp=0, preprocess=...)``; one with a
    ``prepare`` method taking the same arguments has it called, untimed, before each
    call (the speed script's Pandora adapter checks its configuration there).
    """
    records = []
    runs = [(protocol, method, preprocess, degradation) for protocol in plan.protocols for method in plan.matchers
            for preprocess in plan.preprocess[method] for degradation in plan.degradations]
    for protocol, method, preprocess, degradation in runs:
        matcher, options = plan.matchers[method], dict(max_disp=scene.max_disp, min_disp=0, preprocess=preprocess)
        prepare = getattr(matcher, "prepare", None)
        results = run_protocol(protocol, partial(matcher, **options), scene.left, scene.right, tasks=plan.tasks,
                               degrade=partial(degrade, name=degradation, seed=plan.seed), timing=plan.timing,
                               prepare=None if prepare is None else partial(prepare, **options))
        combined = get_protocol(protocol).combine is not None
        for result in (result for result in results if result.scored):
            records.append(Record(
                dataset=plan.dataset, resolution=scene.resolution, scene=scene.name, protocol=protocol,
                method=method, preprocess=preprocess, task=result.name, seconds=result.seconds,
                matcher_runs=len(results) - 1 if combined else 1,  # a combined map costs a run per task
                scores=score(result.disparity, scene.disparity, nonocc=scene.nonocc, pred_valid=result.valid,
                             confidence=result.confidence),
                degradation=degradation,
            ))
            if plan.save_dir is not None:
                folder = Path(plan.save_dir) / f"{method}+{preprocess}" / (
                    protocol if degradation == "none" else f"{protocol}+{degradation}")
                save_maps(folder, f"{scene.name}_{result.name}", result.disparity, scene.disparity)
    return records


def map_scenes(function: Callable[[Scene], T], reader: Dataset, data_dir: Path, names: Sequence[str], *,
               jobs: int = 1, threads: int | None = None) -> Iterator[tuple[str, T]]:
    """The one loop over scenes: decode each scene once and apply ``function`` to it.

    Args:
        function: ``function(scene)``; with ``jobs > 1`` it and its result must pickle.
        reader: the dataset's reader; data_dir: where the dataset lies.
        names: scene names, in the order the results come back.
        jobs: worker processes (1: in this process).
        threads: threads of each process that runs scenes (:func:`use_threads`). Worker
            processes also keep freed memory (:func:`retain_freed_memory`, as the ``cade``
            command does at start); with ``jobs=1`` this process's allocator is left alone.

    Yields:
        (scene name, ``function(scene)``) in the order of ``names``.
    """
    if jobs <= 1:
        use_threads(threads)
        for name in names:
            yield name, _load_and_apply(function, reader, str(data_dir), name)
        return
    with ProcessPoolExecutor(max_workers=jobs, initializer=_start_worker, initargs=(threads,)) as pool:
        futures = [pool.submit(_load_and_apply, function, reader, str(data_dir), name) for name in names]
        for name, future in zip(names, futures):  # in submission order: deterministic
            yield name, future.result()


def _start_worker(threads: int | None) -> None:
    retain_freed_memory()  # as the cade command does, so timings are the command's
    use_threads(threads)


def _load_and_apply(function: Callable[[Scene], T], reader: Dataset, data_dir: str, name: str) -> T:
    scene = next(iter(reader(Path(data_dir), scenes=[name])))
    return function(scene)


def _scene_unit(scene: Scene, plan: Plan) -> tuple[list[Record], tuple[int, int, int]]:
    return evaluate_scene(scene, plan), (*scene.disparity.shape, scene.max_disp)


def run_benchmark(
    *,
    dataset: str,
    data_dir: Path,
    methods: Sequence[str],
    protocols: Sequence[str],
    preprocess: Sequence[str] | Mapping[str, Sequence[str]],
    scenes: Sequence[str] | None = None,
    tasks: Sequence[str] | None = None,
    degradations: Sequence[str] = ("none",),
    timing: Timing = Timing(),
    matchers: Mapping[str, Any] = MATCHERS,
    jobs: int = 1,
    save_dir: Path | None = None,
    on_scene_done: Callable[[str, list[Record]], None] | None = None,
    on_start: Callable[[int], None] | None = None,
) -> BenchmarkRun:
    """Run every protocol x method x preprocess (x degradation) on every scene and score it.

    Args:
        dataset: a name from :data:`cade_cli.data.DATASETS`.
        data_dir: where that dataset lies (its official layout).
        methods: names from ``matchers``.
        protocols: names from :data:`cade_cli.evaluation.protocols.PROTOCOLS` (``cs``, ``rgb``, ``native``).
        preprocess: values of the matchers' ``preprocess`` (``none``, ``cade``, ``auto``) for
            every method, or a mapping method -> its values; values a matcher does not
            take are skipped (:func:`takes_preprocess`: ``none`` for the CADE network).
        scenes: restrict to these scene names (default: all).
        tasks: run only these tasks of the protocols, e.g. ``["R>B", "G>B"]`` (default: all).
        degradations: names from :data:`~cade_cli.evaluation.degradations.DEGRADATIONS`,
            each applied to the right band of every task in turn (default: none).
        timing: warm-up runs, timed repeats and threads (:class:`Timing`).
        matchers: name -> matcher called as ``matcher(left, right, max_disp=, min_disp=,
            preprocess=)`` returning a :class:`~cade_cli.matching.DisparityResult`
            (default: the registry, :data:`cade_cli.matching.MATCHERS`).
        jobs: worker processes, each running whole scenes (1 = run in this process).
        save_dir: when given, each scored disparity (PFM, filled) and a colourised error
            map (PNG) are written under ``save_dir/<method>+<preprocess>/<protocol>/``.
        on_scene_done: called with the scene name and its records after each scene.
        on_start: called once with the number of scenes before the first runs.

    Raises:
        CadeError: an unknown dataset, scene, method, protocol, task, degradation or
            preprocessing value; a task subset that leaves a protocol without tasks.
    """
    chosen = {method: lookup(matchers, method, kind="method") for method in methods}
    per_method = preprocess if isinstance(preprocess, Mapping) else {method: preprocess for method in methods}
    for value in {value for values in per_method.values() for value in values}:
        lookup(dict.fromkeys(PREPROCESS_CHOICES), value, kind="preprocess")
    plan = Plan(
        dataset=dataset, matchers=chosen, protocols=tuple(protocols),
        preprocess={method: tuple(value for value in per_method.get(method, ()) if takes_preprocess(matcher, value))
                    for method, matcher in chosen.items()},
        tasks=None if tasks is None else tuple(tasks), degradations=tuple(degradations), timing=timing,
        save_dir=None if save_dir is None else str(save_dir),
    )
    if plan.tasks is not None:
        known = [task.name for name in plan.protocols for task in get_protocol(name).tasks]
        for task in plan.tasks:
            lookup(dict.fromkeys(known), task, kind="task")
    for name in plan.protocols:
        get_protocol(name).select(plan.tasks)
    for name in plan.degradations:
        lookup(DEGRADATIONS, name, kind="degradation")
    reader = get_dataset(dataset)
    if scenes:
        reader(Path(data_dir), scenes=scenes)  # checks the names; loads nothing
    scene_names = [name for name in reader.scene_names(Path(data_dir)) if not scenes or name in set(scenes)]
    config = {
        "dataset": dataset, "data_dir": str(data_dir), "scenes": scene_names, "methods": list(methods),
        "protocols": list(protocols), "preprocess": list(dict.fromkeys(v for vs in per_method.values() for v in vs)),
        "metrics": list(METRIC_NAMES), "tasks": None if tasks is None else list(tasks),
        "degradations": list(degradations), "timing": asdict(timing),
    }
    run = BenchmarkRun(config)
    if on_start is not None:
        on_start(len(scene_names))
    for name, (records, shape) in map_scenes(partial(_scene_unit, plan=plan), reader, Path(data_dir), scene_names,
                                             jobs=jobs, threads=timing.threads):
        run.records.extend(records)
        run.scene_shapes[name] = shape
        if on_scene_done is not None:
            on_scene_done(name, records)
    return run


def takes_preprocess(matcher: Any, value: str) -> bool:
    """Whether ``matcher`` takes ``preprocess=value``: its ``resolve_preprocess(value)``
    does not raise :class:`CadeError` (a matcher without that method takes every value)."""
    resolve = getattr(matcher, "resolve_preprocess", None)
    if resolve is None:
        return True
    try:
        resolve(value)
    except CadeError:
        return False
    return True


ERROR_SCALE_PX = 8.0
"""The error at the top of the scale of ``*_error.png`` (px): larger errors share its colour."""
NO_GT_COLOUR = (80, 0, 0)
"""BGR of the pixels without ground truth in ``*_error.png``: dark blue (inferno has no blue)."""
NO_ESTIMATE_COLOUR = (160, 160, 160)
"""BGR of the pixels with ground truth but no estimate (NaN) in ``*_error.png``: grey."""


def error_picture(disparity: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """|disparity - gt| for looking at: 0 px black to >= :data:`ERROR_SCALE_PX` white-hot
    (inferno), pixels without GT dark blue, pixels with GT but no estimate grey; a scale
    bar in px of error and a legend of those colours drawn under it.

    Returns:
        (H + legend, max(W, 360), 3) uint8, B, G, R (:func:`cade_cli.io.pictures.with_legend`).
    """
    import cv2

    from cade_cli.io.pictures import ColourBar, Swatch, colour_map, with_legend

    error = np.abs(np.asarray(disparity, np.float64) - gt)
    colour = colour_map(error, colormap=cv2.COLORMAP_INFERNO, low=0.0, high=ERROR_SCALE_PX, missing=NO_ESTIMATE_COLOUR)
    no_gt = ~np.isfinite(gt)
    colour[no_gt] = NO_GT_COLOUR
    swatches = [Swatch(NO_GT_COLOUR, "no ground truth")]
    if (~np.isfinite(disparity) & ~no_gt).any():
        swatches.append(Swatch(NO_ESTIMATE_COLOUR, "no estimate"))
    bar = ColourBar(cv2.COLORMAP_INFERNO, 0.0, ERROR_SCALE_PX,
                    f"|disparity - ground truth|, px of error; {ERROR_SCALE_PX:g} px and more: the end colour")
    return with_legend(colour, bar=bar, swatches=swatches)


def save_maps(folder: Path, stem: str, disparity: np.ndarray, gt: np.ndarray) -> None:
    """Write ``<stem>.pfm`` (the disparity) and ``<stem>_error.png`` (:func:`error_picture`,
    with its scale and legend) into ``folder``."""
    import cv2

    from cade_cli.io.disparity import write_disparity

    folder.mkdir(parents=True, exist_ok=True)
    stem = stem.replace("/", "_").replace(">", "to")
    write_disparity(folder / f"{stem}.pfm", disparity)
    encoded = cv2.imencode(".png", error_picture(disparity, gt))[1]
    with atomic_output(folder / f"{stem}_error.png") as temporary:  # an OS error becomes a CadeError
        temporary.write_bytes(encoded.tobytes())
