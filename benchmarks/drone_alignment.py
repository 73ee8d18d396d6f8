"""Drone multispectral captures (one file per band, ../shared/data/micasense): how well each
way of registering the bands onto the reference band lines them up, without ground truth.

    python benchmarks/drone_alignment.py --data-dir ../shared/data/micasense --markdown table.md --pictures crops/
    python benchmarks/drone_alignment.py --data-dir ../shared/data/micasense --only rededge-m-bench \
        --models cade-v13,cade-v13-accurate,cade-v13-accurate-edges --markdown table.md --edge-crops crops/
    python benchmarks/drone_alignment.py --data-dir ../shared/data/micasense --only rededge-m-bench \
        --near 1,4 --markdown table.md --edge-crops crops/

Every method reads the capture with the product's reader (cade_cli.capture.model.load_capture)
and ends on the same grid, the reference band's raw pixels (the grid of register-capture's
cube), with the band's raw values resampled once, bilinearly, NaN where not seen:
  unaligned   the raw bands, as the cameras wrote them;
  rotations   undistorted and turned by the lens rotations of the files (RigRelatives) into
              the product's common pinhole frame (cade_cli.capture.anchors);
  homography  one ECC homography per band on gradient images in that frame (the vendor's
              method, cade_cli.capture.homography), started from the rotations; where ECC
              fails from there, from a feature-match homography (marked homography*), then
              from register-capture's sparse plane (marked homography**);
  plane-only  register_capture(plane_only=True): `cade register-capture --plane-only`;
  cade        register_capture(): `cade register-capture`, the default method; with --models
              M1,M2,... (cards' names or paths) instead one method per card, cade:M1, cade:M2 ...:
              register_capture(model=M), `cade register-capture --model M`; with --near F1,F2,...
              each of those once per factor, cade@nearF1 (cade:M@nearF1 ...):
              register_capture(near=F), `cade register-capture --near F`.
Each is scored per band with cade_cli.capture.alignment (residual shift of gradient-image
correlation in 64 px windows on one grid: median, 90th percentile, share > 1 px, coverage)
twice: on every window the method could score, and on the windows every method could score
("common"). The times are wall and CPU (user + sys, all threads) of this process.

--pictures: a crop of unaligned, homography and the cade method(s) where the homography leaves
the largest residual. --edge-crops: per capture, a few crops where the reference band has strong
edges and the cade methods' largest residual is largest (the rule: benchmarks/drone_edges.py),
the reference beside each cade method's overlay; their places and residuals follow the tables.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from cade_cli.capture.alignment import Alignment, WindowShifts, coverage, summarise, window_shifts
from cade_cli.capture.anchors import register_anchor
from cade_cli.capture.flight import group_captures
from cade_cli.capture.model import Capture, load_capture
from cade_cli.capture.register import NEAR_FACTOR, check_near, read_raw, register_capture
from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_outputs
from cade_cli.model_card import read_card

sys.path.insert(0, str(Path(__file__).resolve().parent))  # drone_edges.py beside it, however this script is run
from drone_edges import edge_table, same_registration, write_edge_crops  # noqa: E402

METHODS = ("unaligned", "rotations", "homography", "plane-only", "cade")
"""The methods without --models; with it, "cade" gives way to one "cade:<card>" per model."""
SEARCH = 96
"""px searched around each window: above the largest offsets of these cameras' raw bands (~50 px)
and the parallax a homography leaves on the Sequoia capture (tens of px)."""
CROP = 192
"""Side, px, of a picture's crop (written at full resolution)."""
PICTURED = ("unaligned", "homography", "cade")
EDGE_CROPS = 3
"""Edge crops per capture (--edge-crops)."""


def parse_models(text: str | None) -> dict[str, str] | None:
    """``--models M1,M2,...`` as {method: model}: method ``cade:<card name>`` (a path's file
    stem), each card read now (:func:`~cade_cli.model_card.read_card`) so an unknown one is
    refused before any work; None for None (the one ``cade`` method, default model).

    Raises:
        CadeError: an empty list, a card given twice, or a card that cannot be read.
    """
    if text is None:
        return None
    models = [part.strip() for part in text.split(",") if part.strip()]
    if not models:
        raise CadeError(f"--models {text!r} names no model; give card names or paths, comma-separated "
                        "(e.g. cade-v13,cade-v13-accurate)")
    methods = {}
    for model in models:
        method = "cade:" + (Path(model).stem if model.endswith(".json") else model)
        if method in methods:
            raise CadeError(f"--models names {method.removeprefix('cade:')} twice")
        read_card(model)
        methods[method] = model
    return methods


def parse_near(text: str | None) -> tuple[float, ...] | None:
    """``--near F1,F2,...`` as the factors of
    :func:`~cade_cli.capture.register.search_range`, in the order given; None for None (the
    product's default, :data:`~cade_cli.capture.register.NEAR_FACTOR`, methods not renamed).

    Raises:
        CadeError: an empty list, a value that is no number or below 1, or one given twice.
    """
    if text is None:
        return None
    try:
        factors = tuple(float(part) for part in text.split(","))
        for factor in factors:
            check_near(factor)
    except ValueError:  # no number, or check_near's CadeError (a ValueError): the one message below
        factors = ()
    if not factors or len(set(factors)) < len(factors):
        raise CadeError(f"--near {text!r}: give factors of at least 1, comma-separated, each once (e.g. 1,4)")
    return factors


def cade_methods(models: dict[str, str] | None, near: tuple[float, ...] | None) -> dict[str, tuple[str | None, float]]:
    """{method: (model, near factor)} of the cade runs: ``cade`` (or ``cade:<card>`` per model of
    :func:`parse_models`), each once per factor of :func:`parse_near` as ``<method>@near<F>``."""
    base = {"cade": None} if models is None else models
    if near is None:
        return {method: (model, NEAR_FACTOR) for method, model in base.items()}
    return {f"{method}@near{factor:g}": (model, factor) for method, model in base.items() for factor in near}


def _cade(method: str) -> bool:
    return method.split("@")[0] == "cade" or method.startswith("cade:")


def find_captures(data_dir: Path) -> dict[str, Capture]:
    """The captures under ``data_dir``, grouped by the capture id in their metadata
    (:func:`~cade_cli.capture.flight.group_captures`), each read by
    :func:`~cade_cli.capture.model.load_capture`; named ``<folder>/<common file name>``."""
    found, _ = group_captures(data_dir)
    if not found:
        raise CadeError(f"no band files (*.tif) under {data_dir}; pass --data-dir the folder of the captures")
    captures = {}
    for flight_capture in found:
        name = f"{(data_dir / flight_capture.folder).resolve().name}/{flight_capture.name}"
        captures[name] = load_capture(flight_capture.paths)
    return dict(sorted(captures.items()))


@dataclass
class Registered:
    """One method's result on one capture: every band on the reference band's raw grid
    (the reference band included, as its raw values)."""

    bands: dict[str, np.ndarray]
    seconds: float
    cpu: float
    failures: dict[str, str] = field(default_factory=dict)
    starts: dict[str, str] = field(default_factory=dict)
    """Where each band's ECC started: "rotations", "features" or "plane"."""
    notes: dict[str, str] = field(default_factory=dict)
    """register-capture's path per band (parallax, plane ...), with the range searched (px)."""


def _timed(work):
    wall, cpu = time.perf_counter(), time.process_time()
    result = work()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def _profiled(work, top: int):
    """``work()`` under cProfile (CPU time of all threads); its ``top`` stages by cumulative
    time to stderr."""
    profile = cProfile.Profile(time.process_time)
    result = profile.runcall(work)
    pstats.Stats(profile, stream=sys.stderr).sort_stats("cumulative").print_stats(top)
    return result


def register(capture: Capture, *, profile: int = 0,
             cade: dict[str, tuple[str | None, float]] | None = None) -> dict[str, Registered]:
    """Every method of :data:`METHODS` on one capture, "cade" as the runs of ``cade``
    (:func:`cade_methods`; None: the default model and near factor) (``profile`` > 0: cade under
    cProfile, its top ``profile`` stages to stderr)."""
    raw = read_raw(capture)
    results = {"unaligned": Registered({b.name: np.asarray(r, np.float32) for b, r in zip(capture.bands, raw)},
                                       0.0, 0.0)}
    for method, ecc in (("rotations", False), ("homography", True)):
        anchor, wall, cpu = _timed(lambda: register_anchor(capture, ecc=ecc, raw=raw))
        results[method] = Registered(anchor.bands, wall, cpu, anchor.failures, anchor.starts)
    cade = cade_methods(None, None) if cade is None else cade
    runs = (("plane-only", True, None, NEAR_FACTOR), *((m, False, model, near) for m, (model, near) in cade.items()))
    for method, plane_only, model, near in runs:
        # load_capture is timed too: register-capture reads the metadata for each capture
        def work(plane_only=plane_only, model=model, near=near):
            return register_capture(load_capture([b.path for b in capture.bands]), plane_only=plane_only,
                                    model=model, near=near)
        done, wall, cpu = _timed(lambda: _profiled(work, profile) if profile and not plane_only else work())
        results[method] = Registered({b.name: image for b, image in zip(capture.bands, done.bands)}, wall, cpu,
                                     notes={r.name: r.path + ("" if r.search is None else
                                                              f" [{r.search[0]}, {r.search[1]}]")
                                            for r in done.results})
    return results


@dataclass
class Scored:
    """One method's scores on one capture: per band, on its own windows and on the common ones."""

    own: dict[str, Alignment]
    common: dict[str, Alignment]
    shifts: dict[str, WindowShifts] = field(default_factory=dict)
    """Per band, the windows' residual shifts behind ``own``."""


def _only(shifts: WindowShifts, keep: np.ndarray) -> WindowShifts:
    return replace(shifts, shifts=np.where(keep[:, None], shifts.shifts, np.nan))


def score(capture: Capture, results: dict[str, Registered]) -> dict[str, Scored]:
    """Per method, per band: its :class:`Alignment` with the reference band on every window it
    could score, and on the windows that every method (that registered the band) could score."""
    reference_name = capture.reference_band.name
    reference = results["unaligned"].bands[reference_name]
    scored = {method: Scored({}, {}) for method in results}
    for band in capture.bands:
        if band.name == reference_name:
            continue
        found = {method: (window_shifts(reference, result.bands[band.name], search=SEARCH),
                          coverage(reference, result.bands[band.name]))
                 for method, result in results.items() if band.name in result.bands}
        common = np.logical_and.reduce([np.isfinite(shifts.shifts).all(axis=1) for shifts, _ in found.values()])
        for method, (shifts, kept) in found.items():
            scored[method].own[band.name] = summarise(shifts, kept)
            scored[method].shifts[band.name] = shifts
            scored[method].common[band.name] = summarise(_only(shifts, common), kept)
    return scored


def _cell(value: float, scale: float = 1.0, digits: int = 2) -> str:
    return "n/a" if not np.isfinite(value) else f"{value * scale:.{digits}f}"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _mean(rows: list[Alignment], name: str) -> float:
    return float(np.nanmean([getattr(a, name) for a in rows])) if rows else float("nan")


def summary_table(scores: dict[str, dict[str, Scored]], results: dict[str, dict[str, Registered]]) -> str:
    """Markdown: a row per capture x method, the bands' means, on the method's own windows and
    on the common ones, with the method's wall and CPU time."""
    header = ["capture", "method", "median px", "p90 px", "> 1 px %", "coverage %", "windows",
              "common: median px", "common: p90 px", "common: > 1 px %", "common windows", "wall s", "CPU s"]
    lines = [_row(header), "|" + "---|" * len(header)]
    for capture, per_method in scores.items():
        for method in per_method:
            own, common = list(per_method[method].own.values()), list(per_method[method].common.values())
            result = results[capture][method]
            label = method + (f" ({len(result.failures)} bands failed)" if result.failures else "")
            times = ["", ""] if method == "unaligned" else [f"{result.seconds:.1f}", f"{result.cpu:.1f}"]
            lines.append(_row([capture, label, _cell(_mean(own, "median")), _cell(_mean(own, "p90")),
                               _cell(_mean(own, "share_over_1px"), 100, 1), _cell(_mean(own, "coverage"), 100, 1),
                               str(sum(a.windows for a in own)), _cell(_mean(common, "median")),
                               _cell(_mean(common, "p90")), _cell(_mean(common, "share_over_1px"), 100, 1),
                               str(sum(a.windows for a in common)), *times]))
    return "\n".join(lines)


def band_table(scores: dict[str, dict[str, Scored]], results: dict[str, dict[str, Registered]]) -> str:
    """Markdown: a row per capture x band x method (own windows | common windows)."""
    header = ["capture", "band", "method", "median px", "p90 px", "> 1 px %", "coverage %", "windows",
              "common: median / p90 / > 1 px % / windows"]
    lines = [_row(header), "|" + "---|" * len(header)]
    for capture, per_method in scores.items():
        for method in per_method:
            result = results[capture][method]
            for band, a in per_method[method].own.items():
                c = per_method[method].common[band]
                shown = method + {"features": "*", "plane": "**"}.get(result.starts.get(band, ""), "")
                shown += f" ({result.notes[band]})" if _cade(method) and band in result.notes else ""
                lines.append(_row([capture, band, shown, _cell(a.median), _cell(a.p90),
                                   _cell(a.share_over_1px, 100, 1), _cell(a.coverage, 100, 1), str(a.windows),
                                   f"{_cell(c.median)} / {_cell(c.p90)} / {_cell(c.share_over_1px, 100, 1)} / "
                                   f"{c.windows}"]))
            for band, why in result.failures.items():
                lines.append(_row([capture, band, method, why, "", "", "", "", ""]))
    return "\n".join(lines)


def overlay(reference: np.ndarray, band: np.ndarray) -> np.ndarray:
    """BGR picture: the reference in green, the band in magenta (grey where they agree, colour
    fringes where they are displaced), each stretched by its own 1-99 percentiles; black = NaN."""
    channels = []
    for image in (reference, band):
        finite = np.isfinite(image)
        low, high = np.percentile(image[finite], [1, 99]) if finite.any() else (0.0, 1.0)
        channels.append(np.where(finite, np.clip((image - low) / max(high - low, 1e-6), 0, 1), 0))
    return (np.stack([channels[1], channels[0], channels[1]], -1) * 255).astype(np.uint8)


def worst_place(reference: np.ndarray, registered: dict[str, np.ndarray]) -> tuple[str, int, int]:
    """(band, row, column) of the centre of the window where the homography leaves the largest shift."""
    worst = ("", reference.shape[0] // 2, reference.shape[1] // 2, -1.0)
    for name, image in registered.items():
        found = window_shifts(reference, image, search=SEARCH)
        magnitudes = np.nan_to_num(found.magnitudes, nan=-1.0)
        k = int(np.argmax(magnitudes))
        if magnitudes[k] > worst[3]:
            worst = (name, int(found.centres[k, 0]), int(found.centres[k, 1]), float(magnitudes[k]))
    return worst[:3]


def write_pictures(folder: Path, capture: Capture, name: str, results: dict[str, Registered]) -> list[Path]:
    """A crop (:data:`CROP` px) of each of :data:`PICTURED` where the homography leaves the
    largest residual shift, as ``<capture>-<band>-<method>.png``."""
    reference_name = capture.reference_band.name
    reference = results["unaligned"].bands[reference_name]
    others = {k: v for k, v in results["homography"].bands.items() if k != reference_name}
    if not others:
        return []
    band, row, column = worst_place(reference, others)
    height, width = reference.shape
    top = int(np.clip(row - CROP // 2, 0, height - CROP))
    left = int(np.clip(column - CROP // 2, 0, width - CROP))
    crop = (slice(top, top + CROP), slice(left, left + CROP))
    written = []
    for method in [m for m in results if m in PICTURED or _cade(m)]:
        if band not in results[method].bands:
            continue
        path = folder / f"{name.replace('/', '-')}-{band.replace(' ', '')}-{method.replace(':', '-')}.png"
        cv2.imwrite(str(path), overlay(reference[crop], results[method].bands[band][crop]),
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
        written.append(path)
    return written


def edge_crops(folder: Path, capture: Capture, name: str, results: dict[str, Registered],
               scored: dict[str, Scored], *, count: int = EDGE_CROPS):
    """One capture's edge crops (benchmarks/drone_edges.py) of its cade method(s); None, and no
    crop, where several were compared and every one registered the capture alike."""
    methods = [m for m in results if _cade(m)]
    if len(methods) > 1 and same_registration({m: results[m].bands for m in methods}):
        return None
    reference = results["unaligned"].bands[capture.reference_band.name]
    shifts = {band: {m: scored[m].shifts[band] for m in methods}
              for band in capture.names() if all(band in scored[m].shifts for m in methods)}
    return write_edge_crops(folder, name, reference, {m: results[m].bands for m in methods}, shifts, overlay,
                            count=count)


def run(data_dir: Path, *, pictures: Path | None, only: str | None = None, profile: int = 0,
        cade: dict[str, tuple[str | None, float]] | None = None, edges: Path | None = None) -> str:
    """Every capture under ``data_dir`` (``only``: those whose name holds one of its
    comma-separated texts) registered by every method (``cade``: :func:`cade_methods`) and
    scored (the Markdown tables are returned; each capture's times go to stderr as it ends);
    crops into ``pictures``, edge crops into ``edges``."""
    scores, results, crops = {}, {}, {}
    wanted = None if only is None else [text for text in only.split(",") if text]
    for name, capture in find_captures(data_dir).items():
        if wanted is not None and not any(text in name for text in wanted):
            continue
        results[name] = register(capture, profile=profile, cade=cade)
        scores[name] = score(capture, results[name])
        times = ", ".join(f"{m} {r.seconds:.1f} s wall / {r.cpu:.1f} s CPU"
                          + (f" ({len(r.failures)} bands failed)" if r.failures else "")
                          for m, r in results[name].items() if m != "unaligned")
        print(f"{name}: {len(capture.bands)} bands; {times}", file=sys.stderr)
        if pictures is not None:
            write_pictures(pictures, capture, name, results[name])
        if edges is not None:
            crops[name] = edge_crops(edges, capture, name, results[name], scores[name])
    text = summary_table(scores, results) + "\n\nPer band:\n\n" + band_table(scores, results)
    if edges is not None:
        methods = [m for m in next(iter(results.values()), {}) if _cade(m)]
        text += "\n\nEdge crops (residual shift in the crop's centre window, px):\n\n" + edge_table(crops, methods)
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="folder of the captures' band files")
    parser.add_argument("--markdown", type=Path, help="write the tables to this file")
    parser.add_argument("--pictures", type=Path, help="folder for the crops (before / homography / cade)")
    parser.add_argument("--only", help="only the captures whose name holds this text (or one of these, "
                        "comma-separated)")
    parser.add_argument("--models", help="instead of cade with its default model, cade once per model: card "
                        "names or paths, comma-separated (methods cade:<card>)")
    parser.add_argument("--near", metavar="F1,F2", help="cade once per near factor (register-capture --near), "
                        "comma-separated, each with every model (methods cade@near<F>)")
    parser.add_argument("--edge-crops", type=Path, metavar="FOLDER", help="folder for the edge crops: where the "
                        "reference has strong edges and the cade method(s) leave the largest residual")
    parser.add_argument("--profile", type=int, default=0, metavar="N",
                        help="profile cade (cProfile, CPU time) and print its top N stages to stderr")
    arguments = parser.parse_args()
    try:
        if not arguments.data_dir.is_dir():
            raise CadeError(f"--data-dir {arguments.data_dir} is not a folder")
        cade = cade_methods(parse_models(arguments.models), parse_near(arguments.near))
        with atomic_outputs([arguments.markdown], folders=[arguments.pictures, arguments.edge_crops]) as staged:
            text = run(arguments.data_dir, pictures=staged.get(arguments.pictures), only=arguments.only,
                       profile=arguments.profile, cade=cade, edges=staged.get(arguments.edge_crops))
            print(text)
            if arguments.markdown is not None:
                staged[arguments.markdown].write_text(text + "\n")
    except CadeError as error:
        raise SystemExit(f"drone_alignment: error: {error}") from None


if __name__ == "__main__":
    main()
