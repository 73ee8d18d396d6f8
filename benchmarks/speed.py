#!/usr/bin/env python
"""Speed and accuracy of cade's classical matchers against CNES Pandora (census + SGM).

Runs every requested method on Middlebury 2014 (MiddEval3) training pairs, grey
(OpenCV luminance) float32 in [0, 1], search range [0, ndisp - 1] from ``calib.txt``,
and prints a Markdown report: mean seconds per pair, ns per pixel x disparity, EPE
and bad-2 on non-occluded pixels (``mask0nocc.png == 255`` and finite GT), per method
and per scene.

Methods:
    census-sgm, zncc-sgm, sgbm   ``cade_cli.matching.MATCHERS[name]`` on the raw bands (dense output).
    cade                         the CADE network (onnxruntime), color agnostic transform included
                                 in the timed section.
    pandora-census-sgm           Pandora 1.9 + libsgm plugin, configured like cade's
                                 census-sgm (see :func:`pandora_pipeline_config`), its
                                 invalid pixels filled and median-filtered by the same
                                 code census-sgm uses.

Timing: each method runs once untimed on every scene (imports, allocations, lazy
initialisation: the cade matcher builds one onnxruntime session per range variant the
first time a scene needs it), then ``--repeat`` timed runs per scene with
``time.perf_counter``; a method's time for a scene is the median of its runs.
The timed section goes from the two float32 arrays to the dense float32 disparity
map; image and GT reading, and Pandora's configuration check, stay outside it.

Needs the bench environment (Pandora is not a cade dependency)::

    python3 -m venv .venv-bench
    .venv-bench/bin/pip install -e . -r benchmarks/requirements-speed.txt
    .venv-bench/bin/python benchmarks/speed.py --data-dir ../shared/data/middlebury2014/trainingQ
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ALL_METHODS = ("census-sgm", "zncc-sgm", "sgbm", "cade", "pandora-census-sgm")
PANDORA = "pandora-census-sgm"
BAD_THRESHOLD = 2.0

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
        "--threads",
        type=int,
        default=None,
        help="OMP/OpenBLAS/MKL threads and cv2.setNumThreads for every method "
        "(default: $OMP_NUM_THREADS if set, else the CPUs this process may use)",
    )
    parser.add_argument(
        "--pandora-refinement",
        choices=("quadratic", "vfit"),
        default="quadratic",
        help="Pandora sub-pixel method; quadratic (default) is the parabola census-sgm fits",
    )
    parser.add_argument(
        "--pandora-validation",
        choices=("cross_checking_fast", "cross_checking_accurate"),
        default="cross_checking_fast",
        help="Pandora LR check; fast (default) reads the right view from the left SGM volume, as census-sgm does; "
        "accurate runs census + SGM a second time from the right view",
    )
    parser.add_argument(
        "--default-malloc",
        action="store_true",
        help="leave glibc's malloc thresholds as they are (default: set them as the cade command does, "
        "cade_cli.allocator.retain_freed_memory)",
    )
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


def set_thread_env(threads: int) -> None:
    """Cap the native thread pools; must run before numpy / cv2 are imported."""
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
        os.environ[name] = str(threads)


# --------------------------------------------------------------------------- data


def read_pfm(path: Path):
    """(H, W) float32 from a 1-channel PFM: byte order from the scale's sign, rows
    stored bottom-to-top; non-finite values (``inf`` = unknown) become NaN."""
    import numpy as np

    with open(path, "rb") as handle:
        kind = handle.readline().strip()
        if kind != b"Pf":
            raise ValueError(f"{path}: expected a 1-channel PFM ('Pf'), got {kind!r}")
        width, height = (int(v) for v in handle.readline().split())
        scale = float(handle.readline())
        data = np.fromfile(handle, dtype="<f4" if scale < 0 else ">f4", count=width * height)
    if data.size != width * height:
        raise ValueError(f"{path}: truncated PFM ({data.size} of {width * height} values)")
    disparity = np.flipud(data.reshape(height, width)).astype(np.float32)
    disparity[~np.isfinite(disparity)] = np.nan
    return disparity


@dataclass
class Scene:
    name: str
    left: object  # (H, W) float32 in [0, 1]
    right: object
    gt: object  # (H, W) float32, NaN = unknown
    nonocc: object  # (H, W) bool: scored pixels
    ndisp: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.left.shape


def load_grey(path: Path):
    import cv2
    import numpy as np

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32) / np.float32(255.0)


def load_scene(folder: Path) -> Scene:
    import cv2
    import numpy as np

    gt = read_pfm(folder / "disp0GT.pfm")
    mask = cv2.imread(str(folder / "mask0nocc.png"), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise FileNotFoundError(f"cannot read {folder / 'mask0nocc.png'}")
    left, right = load_grey(folder / "im0.png"), load_grey(folder / "im1.png")
    if not (left.shape == right.shape == gt.shape == mask.shape):
        raise ValueError(f"{folder}: image, GT and mask shapes differ")
    from cade_cli.datasets import read_calib

    ndisp = read_calib(folder / "calib.txt")["ndisp"]
    return Scene(folder.name, left, right, gt, (mask == 255) & np.isfinite(gt), ndisp)


def find_scenes(data_dir: Path, names: str) -> list[Path]:
    if names:
        folders = [data_dir / n.strip() for n in names.split(",") if n.strip()]
        missing = [str(f) for f in folders if not (f / "im0.png").is_file()]
        if missing:
            raise SystemExit(f"scene folder(s) without im0.png: {', '.join(missing)}")
        return folders
    folders = sorted(p for p in data_dir.iterdir() if (p / "im0.png").is_file()) if data_dir.is_dir() else []
    if not folders:
        raise SystemExit(f"no <Scene>/im0.png under {data_dir}")
    return folders


# ------------------------------------------------------------------------ methods


def census_sgm_settings() -> tuple[dict, str]:
    """cade census-sgm's window, penalties (cost units: Hamming bit counts), LR tolerance
    and median size, read from the installed package when it exposes them."""
    settings = dict(CENSUS_SGM_DEFAULTS)
    try:
        from cade_cli.matching.classical import census_sgm

        window = census_sgm.cost.keywords["window"]
        read = {
            "window": int(window),
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


class PandoraCensusSgm:
    """Pandora's census + SGM on in-memory grey arrays, output in cade's convention.

    Pandora's left disparity is signed the other way (I_left(x) ~ I_right(x + d)), so
    the range passed is [-max, -min] and the result is negated. Its invalid pixels
    (validity-mask bits of PANDORA_MSK_PIXEL_INVALID: borders, no right match, LR
    occlusion / mismatch) are filled by ``cade_cli.matching.disparity.fill_invalid_along_rows``
    (the smaller of the nearest valid values left and right on the row) and then
    median-filtered like census-sgm's output.
    """

    def __init__(self, settings: dict, refinement: str, validation: str):
        import copy
        import logging

        import pandora
        from pandora import check_configuration
        from pandora.constants import Criteria
        from pandora.img_tools import add_disparity
        from pandora.state_machine import PandoraMachine

        from cade_cli.matching.disparity import fill_invalid_along_rows

        pandora.import_plugin()  # registers the libsgm "sgm" optimisation
        # Pandora re-binds its check transitions on every configuration check; transitions
        # logs each as a harmless warning. (PandoraMachine() resets the "transitions"
        # logger's level, so set it on the child logger that emits them.)
        logging.getLogger("transitions.core").setLevel(logging.ERROR)
        self._pandora = pandora
        self._check = check_configuration.check_pipeline_section
        self._machine_type = PandoraMachine
        self._add_disparity = add_disparity
        self._invalid_bits = int(Criteria.PANDORA_MSK_PIXEL_INVALID)
        self._fill = fill_invalid_along_rows
        self._copy = copy.deepcopy
        self.settings = settings
        self.user_config = pandora_pipeline_config(settings, refinement, validation)
        self.checked_config: dict | None = None

    def _dataset(self, image, disparity):
        import numpy as np
        import xarray as xr

        height, width = image.shape
        dataset = xr.Dataset(
            {"im": (["row", "col"], image)},
            coords={"row": np.arange(height), "col": np.arange(width)},
            # Attributes create_dataset_from_inputs sets for a file without georeferencing.
            attrs={"no_data_img": -9999, "valid_pixels": 0, "no_data_mask": 1, "crs": None, "transform": None},
        )
        return self._add_disparity(dataset, disparity, None)  # None (right view): derived from the left

    def prepare(self, left, right, min_disp: int, max_disp: int):
        """Check the configuration on a fresh state machine (untimed); return the timed call."""
        disparity = [-int(max_disp), -int(min_disp)]
        # The configuration check reads band names, as from a file's metadata.
        meta_left = self._dataset(left, disparity).assign_coords(band_im=[None])
        meta_right = self._dataset(right, None).assign_coords(band_im=[None])
        machine = self._machine_type()
        config = self._check(self._copy(self.user_config), meta_left, meta_right, machine)
        self.checked_config = config

        def run():
            import cv2
            import numpy as np

            # pandora.run adds variables to its input datasets: build fresh ones each call.
            img_left = self._dataset(left, disparity)
            img_right = self._dataset(right, None)
            out_left, _ = self._pandora.run(machine, img_left, img_right, config)
            estimate = -out_left["disparity_map"].data.astype(np.float32)
            valid = ((out_left["validity_mask"].data & self._invalid_bits) == 0) & np.isfinite(estimate)
            dense = self._fill(np.where(valid, estimate, np.float32(0)), valid)
            if self.settings["median"] > 1:
                dense = cv2.medianBlur(dense, self.settings["median"])
            return dense, valid

        return run


def make_runner(name: str, args: argparse.Namespace, notes: list[str]):
    """``prepare(scene) -> run()``: ``run`` (timed) returns (dense disparity, valid mask)."""
    if name == PANDORA:
        try:
            settings, source = census_sgm_settings()
            matcher = PandoraCensusSgm(settings, args.pandora_refinement, args.pandora_validation)
        except ImportError as error:
            raise SystemExit(
                f"{PANDORA} needs Pandora and its libsgm plugin ({error}); "
                "pip install -r benchmarks/requirements-speed.txt"
            ) from error
        notes.append(f"census-sgm settings mirrored by {PANDORA}: {settings} ({source})")
        return lambda scene: matcher.prepare(scene.left, scene.right, 0, scene.ndisp - 1), matcher

    from cade_cli.matching import MATCHERS

    if name not in MATCHERS:
        raise SystemExit(f"cade has no matcher {name!r}; registered: {', '.join(MATCHERS)}")
    matcher = MATCHERS[name]

    def prepare(scene: Scene):
        def run():
            result = matcher(scene.left, scene.right, min_disp=0, max_disp=scene.ndisp - 1,
                             preprocess="none" if matcher.accepts_raw else "cade")
            return result.disparity, result.valid

        return run

    return prepare, matcher


# ---------------------------------------------------------------------- reporting


@dataclass
class Row:
    method: str
    scene: str
    height: int
    width: int
    ndisp: int
    seconds: list[float] = field(default_factory=list)
    epe: float = float("nan")
    bad: float = float("nan")
    valid: float = float("nan")

    @property
    def pair_seconds(self) -> float:
        """The median of the timed runs (robust to a run slowed by the machine)."""
        return statistics.median(self.seconds)

    @property
    def ns_per_pixel_disparity(self) -> float:
        return self.pair_seconds / (self.height * self.width * self.ndisp) * 1e9


def score(disparity, scene: Scene) -> tuple[float, float]:
    import numpy as np

    error = np.abs(disparity.astype(np.float64) - scene.gt)[scene.nonocc]
    if not np.isfinite(error).all():
        raise ValueError("estimate is not finite on scored pixels (matchers must return dense maps)")
    return float(error.mean()), float((error > BAD_THRESHOLD).mean() * 100.0)


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
    for package in ("numpy", "opencv-contrib-python-headless", "pandora", "pandora-plugin-libsgm", "libsgm"):
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


def build_report(rows: list[Row], args, threads_line: str, notes: list[str], pandora_config: dict | None) -> str:
    import json

    methods = [m for m in args.method_list if any(r.method == m for r in rows)]
    scenes = sorted({(r.scene, r.height, r.width, r.ndisp) for r in rows})
    lines = [
        "# Stereo matcher speed benchmark",
        "",
        f"- Machine: {usable_cpus()} usable CPU(s) (os.cpu_count() = {os.cpu_count()}), {cpu_model()}",
        f"- Software: {versions()}",
        f"- Threads: {threads_line}",
        f"- Allocator: {args.allocator_line}",
        f"- Command: `{shlex.join([interpreter(), *sys.argv])}` (run from `{os.getcwd()}`)",
        (
            f"- Data: {args.data_dir} — {len(scenes)} scene(s), grey (cv2 luminance) float32 in [0, 1], "
            "range [0, ndisp - 1] from calib.txt"
        ),
        (
            f"- Timing: 1 untimed warm-up run per method and scene (the cade matcher builds each range variant's "
            f"onnxruntime session there), then {args.repeat} timed run(s) per scene (time.perf_counter; "
            f"the median is reported), "
            "arrays in to dense disparity out"
        ),
        (
            f"- Accuracy: EPE and bad-{BAD_THRESHOLD:g} (% of pixels with error > {BAD_THRESHOLD:g} px) over "
            "mask0nocc.png == 255 with finite GT, on each method's dense (filled) map, unclipped; "
            "method rows average the per-scene values"
        ),
        "",
        "| method | s / pair | s / MP | ns / (px·disp) | EPE nonocc (px) | bad-2 nonocc (%) | valid (%) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for method in methods:
        own = [r for r in rows if r.method == method]
        lines.append(
            f"| {method} | {mean(r.pair_seconds for r in own):.3f} "
            f"| {mean(r.pair_seconds / (r.height * r.width / 1e6) for r in own):.3f} "
            f"| {mean(r.ns_per_pixel_disparity for r in own):.2f} "
            f"| {mean(r.epe for r in own):.3f} | {mean(r.bad for r in own):.2f} | {mean(r.valid for r in own):.1f} |"
        )
    lines += [
        "",
        "## Per scene",
        "",
        (
            "| scene | W×H | ndisp | method | s / pair | ns / (px·disp) "
            "| EPE nonocc (px) | bad-2 nonocc (%) | valid (%) |"
        ),
        "|---|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for name, height, width, ndisp in scenes:
        for method in methods:
            for r in rows:
                if r.method == method and r.scene == name:
                    lines.append(
                        f"| {name} | {width}×{height} | {ndisp} | {method} | {r.pair_seconds:.3f} "
                        f"| {r.ns_per_pixel_disparity:.2f} | {r.epe:.3f} | {r.bad:.2f} | {r.valid:.1f} |"
                    )
    if pandora_config is not None:
        lines += [
            "",
            f"## {PANDORA} configuration",
            "",
            (
                "Pandora left disparity is signed the other way; it searches [-(ndisp - 1), 0] and its "
                "output is negated. Pixels it flags invalid (border, no right match, LR occlusion / "
                "mismatch) are filled along the row from the smaller (background) neighbouring valid "
                "value, then median-filtered, with census-sgm's own code."
            ),
            "",
            "```json",
            json.dumps(pandora_config, indent=2, default=str),
            "```",
        ]
    if notes:
        lines += ["", *[f"- {note}" for note in notes]]
    if PANDORA in methods and "census-sgm" in methods:
        pandora_s = mean(r.pair_seconds for r in rows if r.method == PANDORA)
        cade_s = mean(r.pair_seconds for r in rows if r.method == "census-sgm")
        lines += [
            "",
            (
                f"**Speed ratio: {PANDORA} takes {pandora_s / cade_s:.2f}× the time of census-sgm "
                f"({pandora_s:.3f} s vs {cade_s:.3f} s per pair, mean over {len(scenes)} scene(s)).**"
            ),
        ]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    threads = args.threads or int(os.environ.get("OMP_NUM_THREADS", "0") or 0) or usable_cpus()
    set_thread_env(threads)
    from cade_cli.allocator import MMAP_THRESHOLD, TRIM_THRESHOLD, retain_freed_memory

    if args.default_malloc:
        args.allocator_line = "glibc defaults (--default-malloc)"
    elif retain_freed_memory():
        args.allocator_line = (f"glibc mmap threshold {MMAP_THRESHOLD >> 20} MiB, trim threshold {TRIM_THRESHOLD >> 20} "
                               "MiB (cade_cli.allocator.retain_freed_memory, as the cade command sets them)")
    else:
        args.allocator_line = "the C library's defaults (not glibc)"

    import gc

    import cv2

    cv2.setNumThreads(threads)
    threads_line = (
        f"{threads} (OMP_NUM_THREADS = OPENBLAS_NUM_THREADS = MKL_NUM_THREADS = {threads}, "
        f"cv2.setNumThreads({threads}) -> cv2.getNumThreads() = {cv2.getNumThreads()}; "
        "Pandora's C++ kernels and libsgm are single-threaded)"
    )
    print(f"threads: {threads_line}", file=sys.stderr)

    scenes = [load_scene(folder) for folder in find_scenes(args.data_dir, args.scenes)]
    notes: list[str] = []
    rows: list[Row] = []
    pandora_config = None
    for method in args.method_list:
        prepare, matcher = make_runner(method, args, notes)
        for scene in scenes:
            prepare(scene)()  # warm-up, untimed: lazy initialisation for this scene's size and range
            row = Row(method, scene.name, *scene.shape, scene.ndisp)
            for _ in range(args.repeat):
                run = prepare(scene)
                gc.collect()
                start = time.perf_counter()
                disparity, valid = run()
                row.seconds.append(time.perf_counter() - start)
            row.epe, row.bad = score(disparity, scene)
            row.valid = float(valid.mean() * 100.0)
            rows.append(row)
            print(
                f"{method:>20} {scene.name:<12} {row.pair_seconds:8.3f} s  EPE {row.epe:6.3f}  bad-2 {row.bad:6.2f} %",
                file=sys.stderr,
            )
        if method == PANDORA:
            pandora_config = matcher.checked_config

    report = build_report(rows, args, threads_line, notes, pandora_config)
    print(report)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
