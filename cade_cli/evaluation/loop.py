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
from cade_cli.evaluation.album import SceneAlbum
from cade_cli.evaluation.degradations import DEGRADATIONS, degrade
from cade_cli.evaluation.error_maps import save_maps
from cade_cli.evaluation.metrics import METRIC_NAMES, score
from cade_cli.evaluation.protocols import get_protocol, run_protocol
from cade_cli.evaluation.records import Record
from cade_cli.evaluation.regions import region_masks
from cade_cli.evaluation.timing import Timing, use_threads
from cade_cli.matching import MATCHERS, PREPROCESS_CHOICES

T = TypeVar("T")

SUMMARY_GROUPS: dict[str, str] = {
    "method": "methods", "preprocess": "preprocess", "protocol": "protocols", "degradation": "degradations"}
"""Record field a summary can group by -> the config list that orders its values."""


@dataclass
class BenchmarkRun:
    """Everything a benchmark produced: its configuration and one record per scored map.

    Attributes:
        config: the resolved options (dataset, scenes, methods, protocols, ...).
        records: in scene, protocol, method, preprocess, degradation, task order.
        scene_shapes: scene name -> (height, width, max_disp) in pixels; not in the JSON.
        albums: scene name -> its pictures for the HTML report, when the run kept them
            (``run_benchmark(tile_width=...)``); not in the JSON.
    """

    config: dict
    records: list[Record] = field(default_factory=list)
    scene_shapes: dict[str, tuple[int, int, int]] = field(default_factory=dict)
    albums: dict[str, SceneAlbum] = field(default_factory=dict)

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
            means = {name: _nanmean([r.scores.get(name, np.nan) for r in chosen])
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


def _nanmean(values: Sequence[float]) -> float:
    """Mean of the finite ``values``; NaN, without a warning, when none is (a region no scene has)."""
    finite = [value for value in values if np.isfinite(value)]
    return float(np.mean(finite)) if finite else float("nan")


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
        tile_width: keep each scene's pictures for the HTML report, at most this many px
            wide (:class:`~cade_cli.evaluation.album.SceneAlbum`); None keeps none.
        pictures: of one task per scene (``scene``) or of every task (``all``).
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
    tile_width: int | None = None
    pictures: str = "scene"


def evaluate_scene(scene: Scene, plan: Plan, *, album: SceneAlbum | None = None,
                   on_run: Callable[[str], None] | None = None) -> list[Record]:
    """Run and score every protocol x method x preprocess x degradation of ``plan`` on one scene.

    The search range is [0, ``scene.max_disp``] (inclusive). A matcher is called as
    ``matcher(left, right, max_disp=..., min_disp=0, preprocess=...)``; one with a
    ``prepare`` method taking the same arguments has it called, untimed, before each
    call (the speed script's Pandora adapter checks its configuration there). Every map is
    scored on all pixels and on the scene's regions (:func:`region_masks`, computed once
    here: non-occluded, depth edges, occluded, as far as the dataset allows). Each scored
    map's pictures (and its task's bands) are added to ``album`` when one is given.
    ``on_run`` is called with a description (scene, task, method + preprocessing) after
    every matcher run.
    """
    records = []
    regions = region_masks(scene.disparity, nonocc=scene.nonocc)
    runs = [(protocol, method, preprocess, degradation) for protocol in plan.protocols for method in plan.matchers
            for preprocess in plan.preprocess[method] for degradation in plan.degradations]
    for protocol, method, preprocess, degradation in runs:
        matcher, options = plan.matchers[method], dict(max_disp=scene.max_disp, min_disp=0, preprocess=preprocess)
        prepare = getattr(matcher, "prepare", None)
        done = None if on_run is None else (lambda task: on_run(f"{scene.name} {task}: {method} + {preprocess}"))
        results = run_protocol(protocol, partial(matcher, **options), scene.left, scene.right, tasks=plan.tasks,
                               degrade=partial(degrade, name=degradation, seed=plan.seed), timing=plan.timing,
                               prepare=None if prepare is None else partial(prepare, **options), on_task=done)
        combined = get_protocol(protocol).combine is not None
        for result in (result for result in results if result.scored):
            record = Record(
                dataset=plan.dataset, resolution=scene.resolution, scene=scene.name, protocol=protocol,
                method=method, preprocess=preprocess, task=result.name, seconds=result.seconds,
                matcher_runs=len(results) - 1 if combined else 1,  # a combined map costs a run per task
                scores=score(result.disparity, scene.disparity, **regions, pred_valid=result.valid,
                             confidence=result.confidence),
                degradation=degradation,
            )
            records.append(record)
            if plan.save_dir is not None:
                folder = Path(plan.save_dir) / f"{method}+{preprocess}" / (
                    protocol if degradation == "none" else f"{protocol}+{degradation}")
                save_maps(folder, f"{scene.name}_{result.name}", result.disparity, scene.disparity)
            if album is not None:
                album.add(record, result.disparity, scene, valid=result.valid)
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


def _scene_unit(scene: Scene, plan: Plan, on_run: Callable[[str], None] | None = None,
                ) -> tuple[list[Record], tuple[int, int, int], SceneAlbum | None]:
    album = None if plan.tile_width is None else SceneAlbum.of(scene, width=plan.tile_width,
                                                              every_task=plan.pictures == "all")
    return evaluate_scene(scene, plan, album=album, on_run=on_run), (*scene.disparity.shape, scene.max_disp), album


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
    tile_width: int | None = None,
    pictures: str = "scene",
    on_scene_done: Callable[[str, list[Record]], None] | None = None,
    on_start: Callable[[int], None] | None = None,
    on_run: Callable[[str], None] | None = None,
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
        tile_width: when given, the run keeps each scene's pictures (bands, ground truth,
            each scored map and its errors), at most this many px wide, in ``run.albums``
            for :func:`cade_cli.evaluation.html_report.html_report`: of each scene's first task
            (``pictures="scene"``) or of every task (``"all"``).
        on_scene_done: called with the scene name and its records after each scene.
        on_start: called once, before the first, with the number of matcher runs (scene x
            protocol task x method x preprocessing x degradation).
        on_run: called with a description after each matcher run (with ``jobs > 1``, for
            every run of a scene once the scene is done), so that it is called
            ``on_start``'s number of times: a progress bar that moves during a scene.

    Raises:
        CadeError: an unknown dataset, scene, method, protocol, task, degradation or
            preprocessing value; a task subset that leaves a protocol without tasks; no
            method that takes any of the preprocessing values (nothing to score). What a
            matcher does not take is left out and listed in ``config["not_applicable"]``.
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
        save_dir=None if save_dir is None else str(save_dir), tile_width=tile_width, pictures=pictures,
    )
    not_applicable = _not_applicable(plan, per_method)
    reader = _check_selection(plan)
    if scenes:
        reader(Path(data_dir), scenes=scenes)  # checks the names; loads nothing
    scene_names = [name for name in reader.scene_names(Path(data_dir)) if not scenes or name in set(scenes)]
    run = BenchmarkRun(_run_config(plan, data_dir=data_dir, scenes=scene_names, methods=methods,
                                   preprocess=per_method, not_applicable=not_applicable))
    _run_scenes(run, plan, reader, Path(data_dir), scene_names, jobs=jobs, on_start=on_start, on_run=on_run,
                on_scene_done=on_scene_done)
    return run


def _run_scenes(run: BenchmarkRun, plan: Plan, reader: Dataset, data_dir: Path, scene_names: Sequence[str], *,
                jobs: int, on_start: Callable[[int], None] | None, on_run: Callable[[str], None] | None,
                on_scene_done: Callable[[str, list[Record]], None] | None) -> None:
    """Run ``plan`` on every scene (whole scenes in ``jobs`` worker processes) and add its records,
    shape and album to ``run``, in scene order; the callbacks as :func:`run_benchmark` says."""
    per_scene = sum(len(get_protocol(name).select(plan.tasks).tasks) for name in plan.protocols) * sum(
        map(len, plan.preprocess.values())) * len(plan.degradations)  # matcher runs
    if on_start is not None:
        on_start(per_scene * len(scene_names))
    live = on_run if jobs == 1 else None  # worker processes report a scene's runs once it is done
    for name, (records, shape, album) in map_scenes(partial(_scene_unit, plan=plan, on_run=live), reader,
                                                    data_dir, scene_names, jobs=jobs, threads=plan.timing.threads):
        if on_run is not None and live is None:  # a worker's scene: its runs all at once
            for _ in range(per_scene):
                on_run(f"{name} done")
        run.records.extend(records)
        run.scene_shapes[name] = shape
        if album is not None:
            run.albums[name] = album
        if on_scene_done is not None:
            on_scene_done(name, records)


def _check_selection(plan: Plan) -> Dataset:
    """Refuse an unknown task, a task subset that leaves a protocol without tasks, an unknown
    degradation, an unknown dataset or a protocol its pairs cannot run; returns the dataset's reader."""
    if plan.tasks is not None:
        known = [task.name for name in plan.protocols for task in get_protocol(name).tasks]
        for task in plan.tasks:
            lookup(dict.fromkeys(known), task, kind="task")
    for name in plan.protocols:
        get_protocol(name).select(plan.tasks)
    for name in plan.degradations:
        lookup(DEGRADATIONS, name, kind="degradation")
    reader = get_dataset(plan.dataset)
    if reader.grey and set(plan.protocols) - {"native"}:
        others = ", ".join(name for name in plan.protocols if name != "native")
        raise CadeError(f"{plan.dataset} pairs are already of two spectral bands, one band per view: only protocol "
                        f"native applies (not {others}); use --protocol native")
    return reader


def _run_config(plan: Plan, *, data_dir: Path, scenes: list[str], methods: Sequence[str],
                preprocess: Mapping[str, Sequence[str]], not_applicable: dict[str, str]) -> dict:
    """The run's configuration (:attr:`BenchmarkRun.config`): what was asked, as the reports and
    ``--json`` show it; ``preprocess``: method -> the values asked for it."""
    return {
        "dataset": plan.dataset, "data_dir": str(data_dir), "scenes": scenes, "methods": list(methods),
        "protocols": list(plan.protocols), "preprocess": list(dict.fromkeys(v for vs in preprocess.values() for v in vs)),
        "metrics": list(METRIC_NAMES), "tasks": None if plan.tasks is None else list(plan.tasks),
        "degradations": list(plan.degradations), "timing": asdict(plan.timing),
        "models": network_models(plan.matchers), "not_applicable": not_applicable,
    }


def _not_applicable(plan: Plan, asked: Mapping[str, Sequence[str]]) -> dict[str, str]:
    """``"method + value"`` -> why its matcher does not take that preprocessing, for each value
    ``asked`` that ``plan`` left out; CadeError when nothing is left to run."""
    left_out = {f"{method} + {value}": preprocess_refusal(matcher, value) for method, matcher in plan.matchers.items()
                for value in asked.get(method, ()) if value not in plan.preprocess[method]}
    if not any(plan.preprocess.values()):
        raise CadeError(f"nothing to score: {'; '.join(left_out.values()) or 'no preprocessing given'}; "
                        "give a --preprocess the methods take (auto always applies)")
    return left_out


def network_models(matchers: Mapping[str, Any]) -> dict[str, dict]:
    """Method -> the network it runs (:func:`cade_cli.model_card.describe_model`: name,
    card, sha256s), for the matchers that run one (a ``kernel.network.model``)."""
    from cade_cli.model_card import describe_model

    models = {}
    for method, matcher in matchers.items():
        model = getattr(getattr(getattr(matcher, "kernel", None), "network", None), "model", None)
        if model is not None:
            models[method] = describe_model(model)
    return models


def takes_preprocess(matcher: Any, value: str) -> bool:
    """Whether ``matcher`` takes ``preprocess=value`` (:func:`preprocess_refusal` is None)."""
    return preprocess_refusal(matcher, value) is None


def preprocess_refusal(matcher: Any, value: str) -> str | None:
    """Why ``matcher`` does not take ``preprocess=value``: the :class:`CadeError` of its
    ``resolve_preprocess(value)``; None when it takes it (or has no such method)."""
    try:
        getattr(matcher, "resolve_preprocess", lambda value: value)(value)
    except CadeError as error:
        return str(error)
    return None
