#!/usr/bin/env python
"""Speed and accuracy of cade's matchers against CNES Pandora (census + SGM).

Runs every requested method through the benchmark loop (:mod:`cade_cli.evaluation.loop`)
on Middlebury 2014 (MiddEval3) training pairs with the ``native`` protocol (both views
grey: Rec. 601 luminance, float32 in [0, 1]), search range [0, ndisp - 1] from
``calib.txt``, and prints a Markdown report: mean seconds per pair, ns per pixel x
disparity, EPE and bad-2 on non-occluded pixels (the reader's ``nonocc``:
``mask0nocc.png == 255`` and finite GT), per method and per scene.

Methods:
    census-sgm, zncc-sgm,        ``cade_cli.matching.MATCHERS[name]`` on the raw bands.
    dasc-sgm, sgbm
    cade                         the CADE network (onnxruntime), color agnostic transform included.
    cade-network                 the same network without the runtime's SGBM refinement.
    pandora-census-sgm           Pandora 1.9 + libsgm plugin, configured like cade's
                                 census-sgm (see :func:`pandora_pipeline_config`), its
                                 invalid pixels filled and median-filtered by the same
                                 code census-sgm uses, then marked invalid again.

Timing (the loop's ``Timing(warmup=1, repeat=--repeat, threads=--threads)``): each
method runs once untimed on every scene (imports, allocations, lazy initialisation: the
cade matcher builds one onnxruntime session per range variant the first time a scene
needs it), then ``--repeat`` timed runs; a method's time for a scene is the median of its
runs. The timed section goes from the two float32 bands to the matcher's result (NaN
where invalid); image and GT reading, Pandora's configuration check (its ``prepare``)
and the scoring fill (``cade_cli.matching.densify``) stay outside it.

Needs the bench environment (Pandora is not a cade dependency)::

    python3 -m venv .venv-bench
    .venv-bench/bin/pip install -e . -r benchmarks/requirements-speed.txt
    .venv-bench/bin/python benchmarks/speed.py --data-dir ../shared/data/middlebury2014/trainingQ
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import shlex
import sys
from pathlib import Path

from cade_cli.evaluation.timing import THREAD_VARIABLES  # light: NumPy is not loaded yet

ALL_METHODS = ("census-sgm", "zncc-sgm", "dasc-sgm", "sgbm", "cade", "cade-network", "pandora-census-sgm")
PANDORA = "pandora-census-sgm"

# cade's census-sgm settings (cade_cli.matching.classical.census_sgm), used when they
# cannot be read from the installed package; the report prints the values in force.
CENSUS_SGM_DEFAULTS = {"window": 7, "p1": 7.0, "p2": 72.0, "lr_tolerance": 1.0, "median": 3}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="MiddEval3 folder holding <Scene>/im0.png ...")
    parser.add_argument("--scenes", default="", help="comma-separated scene names (default: every scene found)")
    parser.add_argument(
        "--methods", default=",".join(ALL_METHODS), help=f"comma-separated, from {', '.join(ALL_METHODS)}"
    )
    parser.add_argument("--repeat", type=int, default=1, help="timed runs per method and scene (default 1)")
    parser.add_argument(
        "--threads", type=int, default=None,
        help="OMP/OpenBLAS/MKL threads and cv2.setNumThreads for every method "
        "(default: $OMP_NUM_THREADS if set, else the CPUs this process may use)",
    )
    parser.add_argument(
        "--pandora-refinement", choices=("quadratic", "vfit"), default="quadratic",
        help="Pandora sub-pixel method; quadratic (default) is the parabola census-sgm fits",
    )
    parser.add_argument(
        "--pandora-validation", choices=("cross_checking_fast", "cross_checking_accurate"),
        default="cross_checking_fast",
        help="Pandora LR check; fast (default) reads the right view from the left SGM volume, as census-sgm does; "
        "accurate runs census + SGM a second time from the right view",
    )
    parser.add_argument(
        "--default-malloc", action="store_true",
        help="leave glibc's malloc thresholds as they are (default: set them as the cade command does, "
        "cade_cli.allocator.retain_freed_memory)",
    )
    parser.add_argument("--model", default=None,
                        help="the network of the cade method, as for `cade disparity --model` (default: the shipped one)")
    parser.add_argument("--markdown", type=Path, default=None, help="also write the report to this file")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    args.method_list = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in args.method_list if m not in ALL_METHODS]
    if unknown or not args.method_list:
        parser.error(f"unknown method(s) {unknown}; choose from {', '.join(ALL_METHODS)}")
    return args


def usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


# ------------------------------------------------------------------------ Pandora


def census_sgm_settings() -> tuple[dict, str]:
    """cade census-sgm's window, penalties (cost units: Hamming bit counts), LR tolerance
    and median size, read from the installed package when it exposes them."""
    settings = dict(CENSUS_SGM_DEFAULTS)
    try:
        from cade_cli.matching.classical import census_sgm

        read = {
            "window": int(census_sgm.cost.keywords["window"]),
            "p1": float(census_sgm.p1),
            "p2": float(census_sgm.p2),
            "lr_tolerance": float(census_sgm.lr_tolerance),
            "median": int(census_sgm.median),
        }
    except (ImportError, AttributeError, KeyError, TypeError):
        return settings, "script defaults (cade_cli.matching.classical.census_sgm not readable)"
    settings.update(read)
    return settings, "read from cade_cli.matching.classical.census_sgm"


def pandora_pipeline_config(settings: dict, refinement: str, validation: str) -> dict:
    """Pandora pipeline mirroring cade's census-sgm.

    Both census costs are raw Hamming bit counts, so the SGM penalties carry over as they are.
    """
    return {
        "pipeline": {
            "matching_cost": {"matching_cost_method": "census", "window_size": settings["window"], "subpix": 1},
            "optimization": {
                "optimization_method": "sgm",  # libsgm plugin, 8 directions, C++ version
                "penalty": {
                    "penalty_method": "sgm_penalty",
                    "P1": settings["p1"],
                    "P2": settings["p2"],
                    "p2_method": "constant",
                },
            },
            "disparity": {"disparity_method": "wta", "invalid_disparity": "NaN"},
            "refinement": {"refinement_method": refinement},
            "validation": {"validation_method": validation, "cross_checking_threshold": settings["lr_tolerance"]},
        }
    }


@functools.cache
def _pandora():
    """Pandora's modules, its libsgm plugin registered once."""
    import logging

    import pandora
    from pandora import check_configuration
    from pandora.constants import Criteria
    from pandora.img_tools import add_disparity
    from pandora.state_machine import PandoraMachine

    pandora.import_plugin()  # registers the libsgm "sgm" optimisation
    # Pandora re-binds its check transitions on every configuration check; transitions
    # logs each as a harmless warning. (PandoraMachine() resets the "transitions"
    # logger's level, so set it on the child logger that emits them.)
    logging.getLogger("transitions.core").setLevel(logging.ERROR)
    return pandora, check_configuration.check_pipeline_section, PandoraMachine, add_disparity, int(
        Criteria.PANDORA_MSK_PIXEL_INVALID)


class PandoraCensusSgm:
    """Pandora's census + SGM on in-memory grey arrays, behind cade's matcher contract:
    ``(left, right, *, max_disp, min_disp, preprocess) -> DisparityResult``, NaN where invalid.

    Pandora's left disparity is signed the other way (I_left(x) ~ I_right(x + d)), so
    the range passed is [-max, -min] and the result is negated. Its invalid pixels
    (validity-mask bits of PANDORA_MSK_PIXEL_INVALID: borders, no right match, LR
    occlusion / mismatch) are filled by ``cade_cli.matching.disparity.fill_invalid_along_rows``
    and median-filtered, and the median kept at the valid pixels, as census-sgm does.
    Each run needs a state machine whose configuration was checked for it:
    :meth:`prepare` (untimed in the loop) builds it.
    """

    def __init__(self, settings: dict, refinement: str, validation: str):
        _pandora()  # fail now, with the ImportError, when Pandora is missing
        self.settings = settings
        self.user_config = pandora_pipeline_config(settings, refinement, validation)
        self.checked_config: dict | None = None
        self._prepared = None

    def resolve_preprocess(self, preprocess: str) -> str:
        from cade_cli.errors import CadeError

        if preprocess not in ("none", "auto"):
            raise CadeError(f"{PANDORA} matches the raw bands only; use preprocess none")
        return "none"

    @staticmethod
    def _dataset(image, disparity):
        import numpy as np
        import xarray as xr

        height, width = image.shape
        dataset = xr.Dataset(
            {"im": (["row", "col"], image)},
            coords={"row": np.arange(height), "col": np.arange(width)},
            # Attributes create_dataset_from_inputs sets for a file without georeferencing.
            attrs={"no_data_img": -9999, "valid_pixels": 0, "no_data_mask": 1, "crs": None, "transform": None},
        )
        return _pandora()[3](dataset, disparity, None)  # None (right view): derived from the left

    def prepare(self, left, right, *, max_disp: int, min_disp: int = 0, preprocess: str = "none") -> None:
        """Check the configuration on a fresh state machine for the next call."""
        import copy

        _, check, machine_type, _, _ = _pandora()
        disparity = [-int(max_disp), -int(min_disp)]
        # The configuration check reads band names, as from a file's metadata.
        meta_left = self._dataset(left, disparity).assign_coords(band_im=[None])
        meta_right = self._dataset(right, None).assign_coords(band_im=[None])
        machine = machine_type()
        self.checked_config = check(copy.deepcopy(self.user_config), meta_left, meta_right, machine)
        self._prepared = (machine, self.checked_config, disparity)

    def __call__(self, left, right, *, max_disp: int, min_disp: int = 0, preprocess: str = "none"):
        import cv2
        import numpy as np

        from cade_cli.matching import DisparityResult
        from cade_cli.matching.disparity import fill_invalid_along_rows

        self.resolve_preprocess(preprocess)
        if self._prepared is None or self._prepared[2] != [-int(max_disp), -int(min_disp)]:
            self.prepare(left, right, max_disp=max_disp, min_disp=min_disp)
        (machine, config, disparity), self._prepared = self._prepared, None
        pandora, _, _, _, invalid_bits = _pandora()
        # pandora.run adds variables to its input datasets: build fresh ones each call.
        out_left, _ = pandora.run(machine, self._dataset(left, disparity), self._dataset(right, None), config)
        estimate = -out_left["disparity_map"].data.astype(np.float32)
        valid = ((out_left["validity_mask"].data & invalid_bits) == 0) & np.isfinite(estimate)
        if self.settings["median"] > 1:
            estimate = cv2.medianBlur(fill_invalid_along_rows(np.where(valid, estimate, np.float32(0)), valid),
                                      self.settings["median"])
        return DisparityResult(np.where(valid, estimate, np.float32(np.nan)), valid)


# ---------------------------------------------------------------------- reporting


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def versions() -> str:
    from importlib.metadata import PackageNotFoundError, version

    parts = [f"Python {platform.python_version()}"]
    for package in ("numpy", "opencv-contrib-python-headless", "onnxruntime", "pandora", "pandora-plugin-libsgm",
                    "libsgm"):
        try:
            parts.append(f"{package} {version(package)}")
        except PackageNotFoundError:
            pass
    return ", ".join(parts)


def interpreter() -> str:
    """sys.executable, relative to the working directory when it lies below it."""
    relative = os.path.relpath(sys.executable)
    return relative if not relative.startswith("..") else sys.executable


def mean(values) -> float:
    values = list(values)
    return sum(values) / len(values)


def build_report(run, args, threads_line: str, notes: list[str], pandora_config: dict | None) -> str:
    """The Markdown report of a :class:`~cade_cli.evaluation.loop.BenchmarkRun` of the native protocol."""
    from cade_cli.evaluation.report import markdown_row

    def per_mp(r) -> float:
        height, width, _ = run.scene_shapes[r.scene]
        return r.seconds / (height * width / 1e6)

    def ns(r) -> float:
        height, width, max_disp = run.scene_shapes[r.scene]
        return r.seconds / (height * width * (max_disp + 1)) * 1e9

    def accuracy(r) -> list[str]:
        return [f"{r.scores['epe_nonocc']:.3f}", f"{r.scores['bad2_nonocc']:.2f}", f"{100 - r.scores['invalid']:.1f}"]

    methods = [m for m in args.method_list if any(r.method == m for r in run.records)]
    lines = [
        "# Stereo matcher speed benchmark",
        "",
        f"- Machine: {usable_cpus()} usable CPU(s) (os.cpu_count() = {os.cpu_count()}), {cpu_model()}",
        f"- Software: {versions()}",
        f"- Threads: {threads_line}",
        f"- Allocator: {args.allocator_line}",
        f"- Command: `{shlex.join([interpreter(), *sys.argv])}` (run from `{os.getcwd()}`)",
        f"- Data: {args.data_dir} — {len(run.scene_shapes)} scene(s), protocol native: grey (Rec. 601 luminance) "
        "float32 in [0, 1], range [0, ndisp - 1] from calib.txt",
        f"- Timing: 1 untimed warm-up run per method and scene (the cade matcher builds each range variant's "
        f"onnxruntime session there), then {args.repeat} timed run(s) per scene (time.perf_counter; the median "
        "is reported), bands in to the matcher's result out",
        "- Accuracy: EPE and bad-2 (% of pixels with error > 2 px) over mask0nocc.png == 255 with finite GT, "
        "on each method's map filled by cade_cli.matching.densify (as every cade benchmark scores), unclipped; "
        "valid = pixels the method itself accepts; method rows average the per-scene values",
        "",
        markdown_row(["method", "s / pair", "s / MP", "ns / (px·disp)", "EPE nonocc (px)", "bad-2 nonocc (%)",
                      "valid (%)"]),
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for method in methods:
        own = [r for r in run.records if r.method == method]
        lines.append(markdown_row([
            method, f"{mean(r.seconds for r in own):.3f}", f"{mean(per_mp(r) for r in own):.3f}",
            f"{mean(ns(r) for r in own):.2f}", f"{mean(r.scores['epe_nonocc'] for r in own):.3f}",
            f"{mean(r.scores['bad2_nonocc'] for r in own):.2f}", f"{mean(100 - r.scores['invalid'] for r in own):.1f}",
        ]))
    lines += [
        "",
        "## Per scene",
        "",
        markdown_row(["scene", "W×H", "ndisp", "method", "s / pair", "ns / (px·disp)", "EPE nonocc (px)",
                      "bad-2 nonocc (%)", "valid (%)"]),
        "|---|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for scene, (height, width, max_disp) in run.scene_shapes.items():
        for method in methods:
            for r in run.records:
                if r.method == method and r.scene == scene:
                    lines.append(markdown_row([scene, f"{width}×{height}", str(max_disp + 1), method,
                                               f"{r.seconds:.3f}", f"{ns(r):.2f}", *accuracy(r)]))
    if pandora_config is not None:
        lines += [
            "",
            f"## {PANDORA} configuration",
            "",
            "Pandora left disparity is signed the other way; it searches [-(ndisp - 1), 0] and its "
            "output is negated. Pixels it flags invalid (border, no right match, LR occlusion / "
            "mismatch) are filled along the row from the smaller (background) neighbouring valid "
            "value and median-filtered, with census-sgm's own code; the median is kept at the valid pixels.",
            "",
            "```json",
            json.dumps(pandora_config, indent=2, default=str),
            "```",
        ]
    if notes:
        lines += ["", *[f"- {note}" for note in notes]]
    if PANDORA in methods and "census-sgm" in methods:
        pandora_s = mean(r.seconds for r in run.records if r.method == PANDORA)
        cade_s = mean(r.seconds for r in run.records if r.method == "census-sgm")
        lines += [
            "",
            f"**Speed ratio: {PANDORA} takes {pandora_s / cade_s:.2f}× the time of census-sgm "
            f"({pandora_s:.3f} s vs {cade_s:.3f} s per pair, mean over {len(run.scene_shapes)} scene(s)).**",
        ]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    threads = args.threads or int(os.environ.get("OMP_NUM_THREADS", "0") or 0) or usable_cpus()
    for name in THREAD_VARIABLES:  # before NumPy is imported, so its BLAS reads them
        os.environ[name] = str(threads)
    import cv2

    from cade_cli.allocator import MMAP_THRESHOLD, TRIM_THRESHOLD, retain_freed_memory
    from cade_cli.errors import CadeError
    from cade_cli.evaluation.loop import run_benchmark, takes_preprocess
    from cade_cli.evaluation.timing import Timing
    from cade_cli.matching import MATCHERS, get_matcher

    if args.default_malloc:
        args.allocator_line = "glibc defaults (--default-malloc)"
    elif retain_freed_memory():
        args.allocator_line = (f"glibc mmap threshold {MMAP_THRESHOLD >> 20} MiB, trim threshold {TRIM_THRESHOLD >> 20} "
                               "MiB (cade_cli.allocator.retain_freed_memory, as the cade command sets them)")
    else:
        args.allocator_line = "the C library's defaults (not glibc)"

    notes: list[str] = []
    learned = ("cade", "cade-network")
    matchers = {name: get_matcher(name, model=args.model) if args.model is not None and name in learned
                else MATCHERS[name] for name in args.method_list if name in MATCHERS}
    if PANDORA in args.method_list:
        settings, source = census_sgm_settings()
        try:
            matchers[PANDORA] = PandoraCensusSgm(settings, args.pandora_refinement, args.pandora_validation)
        except ImportError as error:
            raise SystemExit(f"{PANDORA} needs Pandora and its libsgm plugin ({error}); "
                             "pip install -r benchmarks/requirements-speed.txt") from error
        notes.append(f"census-sgm settings mirrored by {PANDORA}: {settings} ({source})")
    # Raw bands where the method takes them (one sensor's grey pair); the CADE network needs its transform.
    preprocess = {name: ["none" if takes_preprocess(matcher, "none") else "cade"] for name, matcher in matchers.items()}

    def progress(scene: str, records) -> None:
        for r in records:
            print(f"{r.method:>20} {scene:<12} {r.seconds:8.3f} s  EPE {r.scores['epe_nonocc']:6.3f}  "
                  f"bad-2 {r.scores['bad2_nonocc']:6.2f} %", file=sys.stderr)

    try:
        run = run_benchmark(
            dataset="middlebury14", data_dir=args.data_dir, methods=args.method_list, matchers=matchers,
            protocols=["native"], preprocess=preprocess,
            scenes=[s.strip() for s in args.scenes.split(",") if s.strip()] or None,
            timing=Timing(warmup=1, repeat=args.repeat, threads=threads), on_scene_done=progress,
        )
    except CadeError as error:
        raise SystemExit(str(error)) from None
    threads_line = (
        f"{threads} (OMP_NUM_THREADS = OPENBLAS_NUM_THREADS = MKL_NUM_THREADS = {threads}, "
        f"cv2.setNumThreads({threads}) -> cv2.getNumThreads() = {cv2.getNumThreads()}; "
        "Pandora's C++ kernels and libsgm are single-threaded)"
    )
    pandora = matchers.get(PANDORA)
    report = build_report(run, args, threads_line, notes, None if pandora is None else pandora.checked_config)
    print(report)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
