#!/usr/bin/env python
"""Tiled matching (``--memory-limit``): what the seams cost, and a large pair in a budget.

1. **Seams.** On Middlebury 2014 (Q) scenes, cross-spectral task ``R>B`` (red band left,
   blue band right), each method runs once untiled and once tiled with a forced small core
   (:func:`cade_cli.scale.tiling.estimate_disparity_tiled` with ``core``; each method's own
   collar, :func:`cade_cli.scale.windows.method_collar`), over [0, the scene's max_disp]. Over
   the pixels valid in both maps, the mean |tiled - untiled| (px) and the share of pixels
   that differ by more than 0.01 px are reported by distance to the nearest seam
   (:func:`cade_cli.scale.tiling.seam_distance`); EPE against the ground truth (densified maps,
   every GT pixel) for both.
2. **A large pair.** A synthetic pair of ``--large`` size (a random texture on a slanted
   plane, disparity 10..390 px; the right band a gain and gamma of the left one), written as
   16-bit PNGs, goes through ``cade disparity --max-disp 400 --memory-limit BUDGET`` in a
   fresh process per method; wall time and the process's peak RSS (its VmHWM, polled) are recorded,
   and the EPE on the valid pixels against the known plane.

    .venv/bin/python benchmarks/tiling.py --data-dir ../shared/data --scenes 5 --core 128 \\
        --large 6000x4000 --budget 2GB --markdown docs/bench/tiling.md
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from cade_cli.allocator import retain_freed_memory
from cade_cli.data import get_dataset
from cade_cli.evaluation.protocols import get_protocol
from cade_cli.matching import densify
from cade_cli.scale.memory import BASE_BYTES, matching_memory_bytes, parse_memory
from cade_cli.scale.tiling import estimate_disparity_tiled, seam_distance
from cade_cli.scale.windows import method_collar
from cade_cli.stereo import estimate_disparity

METHODS = ("census-sgm", "sgbm", "cade")
BINS = ((0, 8), (8, 32), (32, None))
"""Distance to the nearest seam, px: [low, high)."""
LARGE_RANGE = 400


def seam_rows(data_dir: Path, scenes: int, core: int, methods: tuple[str, ...]) -> list[dict]:
    task = next(task for task in get_protocol("cs").tasks if task.name == "R>B")
    rows = []
    for scene in list(get_dataset("middlebury14")(data_dir))[:scenes]:
        left, right = task.bands(scene.left, scene.right)
        known = np.isfinite(scene.disparity)
        for method in methods:
            started = time.perf_counter()
            whole = estimate_disparity(left, right, method=method, max_disp=scene.max_disp)
            whole_s = time.perf_counter() - started
            for seed in (False, True):
                started = time.perf_counter()
                tiled, plan = estimate_disparity_tiled(left, right, method=method, max_disp=scene.max_disp,
                                                       memory_limit=2**40, core=core, seed=seed)
                tiled_s = time.perf_counter() - started
                distance = seam_distance(plan, left.shape)
                both = whole.valid & tiled.valid
                difference = np.abs(whole.disparity - tiled.disparity)
                row = {"scene": scene.name, "method": method, "seed": seed, "tiles": len(plan.tiles),
                       "whole_s": whole_s, "tiled_s": tiled_s}
                for low, high in BINS:
                    mask = both & (distance >= low) & (distance < (np.inf if high is None else high))
                    row[(low, high)] = (float(difference[mask].mean()), float((difference[mask] > 0.01).mean()),
                                        int(mask.sum()))
                for name, result in (("whole", whole), ("tiled", tiled)):
                    dense = densify(result.disparity, result.valid)
                    row[f"epe_{name}"] = float(np.abs(dense - scene.disparity)[known].mean())
                    row[f"valid_{name}"] = float(result.valid.mean())
                rows.append(row)
            print(f"{scene.name} {method}: {row}", file=sys.stderr, flush=True)
    return rows


def large_pair(folder: Path, width: int, height: int, rng: np.random.Generator) -> tuple[Path, Path]:
    """A textured slanted plane, d(y, x) = 10 + 300 y / H + 80 x / W px, as two 16-bit PNGs."""
    padding = 512
    texture = cv2.GaussianBlur(rng.random((height, width + padding), dtype=np.float32), (0, 0), 1.5)
    texture = (texture - texture.min()) / (texture.max() - texture.min())
    rows = np.arange(height, dtype=np.float32)[:, None]
    columns = np.arange(width, dtype=np.float32)[None, :]
    slope = 80.0 / width
    offset = 10.0 + 300.0 * rows / height
    # left(y, x) = texture(y, x); the right pixel xr sees left x with x - d(y, x) = xr
    source = (columns + offset) / (1.0 - slope) + 0 * rows
    row_map = np.broadcast_to(rows, source.shape).astype(np.float32)
    right = cv2.remap(texture, source.astype(np.float32), np.ascontiguousarray(row_map), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REFLECT)
    del source, row_map
    left = texture[:, :width]
    right = 0.1 + 0.8 * right**1.6 + rng.normal(0, 0.005, right.shape).astype(np.float32)
    paths = folder / "large_left.png", folder / "large_right.png"
    for path, band in zip(paths, (left, right)):
        cv2.imwrite(str(path), np.rint(np.clip(band, 0, 1) * 65535).astype(np.uint16))
    return paths


def large_truth(width: int, height: int) -> np.ndarray:
    rows = np.arange(height, dtype=np.float32)[:, None]
    columns = np.arange(width, dtype=np.float32)[None, :]
    return 10.0 + 300.0 * rows / height + 80.0 * columns / width


def high_water_kib(pid: int) -> int:
    """Peak resident memory (VmHWM, KiB) of a running process; 0 once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as stream:
            for line in stream:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def run_large(paths: tuple[Path, Path], method: str, budget: str, folder: Path, timeout: float) -> dict:
    output = folder / f"large_{method}.npy"
    command = [str(Path(sys.executable).parent / "cade"), "disparity", str(paths[0]), str(paths[1]), "-o",
               str(output), "--method", method, "--max-disp", str(LARGE_RANGE), "--memory-limit", budget,
               "--fill", "none"]
    logs = folder / f"{method}.out", folder / f"{method}.err"
    started = time.perf_counter()
    with open(logs[0], "w") as out, open(logs[1], "w") as err:
        process = subprocess.Popen(command, stdout=out, stderr=err)
        # The child's own high-water mark, VmHWM, polled: wait4's ru_maxrss would start from
        # this (large) process's resident size at fork, which Linux carries across exec.
        peak_kib = 0
        while process.poll() is None:
            peak_kib = max(peak_kib, high_water_kib(process.pid))
            if time.perf_counter() - started > timeout:
                process.kill()
            time.sleep(0.05)
    seconds = time.perf_counter() - started
    code = process.returncode
    stdout, stderr = (path.read_text().strip() for path in logs)
    if code != 0:
        reason = f"over {timeout:.0f} s" if seconds >= timeout else (stderr.splitlines() or [f"exit {code}"])[-1]
        return {"method": method, "status": reason, "command": shlex.join(command)}
    return {"method": method, "status": "ok", "seconds": seconds, "peak_gb": peak_kib * 1024 / 2**30,
            "stderr": stderr, "stdout": stdout, "command": shlex.join(command), "output": output}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    parser.add_argument("--scenes", type=int, default=5)
    parser.add_argument("--core", type=int, default=128)
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--large", default="6000x4000", help="WxH of the large pair; '' to skip")
    parser.add_argument("--budget", default="2GB")
    parser.add_argument("--timeout", type=float, default=300.0)
    parser.add_argument("--skip-seams", action="store_true")
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    retain_freed_memory()
    methods = tuple(args.methods.split(","))
    lines = ["# Tiling (`benchmarks/tiling.py`)", "",
             f"`{shlex.join(['.venv/bin/python', 'benchmarks/tiling.py', *sys.argv[1:]])}`", "",
             f"Machine: {os.cpu_count()} CPUs; timings move with whatever else runs (docs/scale.md says).", ""]
    if not args.skip_seams:
        rows = seam_rows(args.data_dir, args.scenes, args.core, methods)
        collars = ", ".join(f"{method} {method_collar(method)} px" for method in methods)
        lines += [f"## Seams: middlebury14 (Q), task R>B, {args.core} px cores, collar: {collars}", "",
                  "Over pixels valid in both maps: mean |tiled - untiled| (px) / share differing by > 0.01 px, "
                  "by distance to the nearest seam. EPE: densified maps, every GT pixel.", "",
                  "| method | tile ranges | scenes | tiles | < 8 px | 8-32 px | >= 32 px | EPE untiled | EPE tiled | valid untiled | "
                  "valid tiled | s untiled | s tiled |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for method, seed in ((method, seed) for method in methods for seed in (False, True)):
            chosen = [row for row in rows if row["method"] == method and row["seed"] == seed]
            cells = []
            for bin_ in BINS:
                weights = np.array([row[bin_][2] for row in chosen], float)
                mean = np.average([row[bin_][0] for row in chosen], weights=weights)
                share = np.average([row[bin_][1] for row in chosen], weights=weights)
                cells.append(f"{mean:.3f} / {100 * share:.1f}%")
            average = {key: np.mean([row[key] for row in chosen]) for key in
                       ("tiles", "epe_whole", "epe_tiled", "valid_whole", "valid_tiled", "whole_s", "tiled_s")}
            lines.append(f"| {method} | {'seeded' if seed else 'whole range'} | {len(chosen)} | {average['tiles']:.0f} | {' | '.join(cells)} | "
                         f"{average['epe_whole']:.2f} | {average['epe_tiled']:.2f} | "
                         f"{100 * average['valid_whole']:.1f}% | {100 * average['valid_tiled']:.1f}% | "
                         f"{average['whole_s']:.1f} | {average['tiled_s']:.1f} |")
        lines += ["", "Scenes: " + ", ".join(sorted({row["scene"] for row in rows})), ""]
    if args.large:
        width, height = (int(value) for value in args.large.lower().split("x"))
        lines += [f"## A {width}x{height} ({width * height / 1e6:.0f} MP) pair, range [0, {LARGE_RANGE}], "
                  f"`--memory-limit {args.budget}`", "",
                  "| method | pair | untiled plan (GB) | s | peak RSS (GB) | budget (GB) | tiles | EPE (px) | valid | note |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        notes = ["", "Untiled plan: `cade batch`'s plan for the pair matched whole (250 MiB + 200 B/px + "
                 "the cost volume); EPE: mean |d - truth| over the valid pixels whose match lies inside the right "
                 "image (x - d >= 0); valid: share of all pixels.", ""]
        with tempfile.TemporaryDirectory() as folder:
            folder = Path(folder)
            paths = large_pair(folder, width, height, np.random.default_rng(7))
            truth = large_truth(width, height)
            visible = np.arange(width)[None, :] - truth >= 0  # pixels whose match lies inside the right image
            for method in methods:
                untiled = (BASE_BYTES + matching_memory_bytes(method, width, height, LARGE_RANGE + 1)) / 2**30
                found = run_large(paths, method, args.budget, folder, args.timeout)
                if found["status"] != "ok":
                    lines.append(f"| {method} | {width}x{height} | {untiled:.1f} | - | - | {parse_memory(args.budget) / 2**30:.1f} "
                                 f"| - | - | - | {found['status'].splitlines()[-1][:120]} |")
                    print(found, file=sys.stderr, flush=True)
                    continue
                disparity = np.load(found["output"])
                valid = np.isfinite(disparity)
                epe = float(np.abs(disparity - truth)[valid & visible].mean())
                tiles = found["stderr"].split(" tiles of ")[0].rsplit(" ", 1)[-1] if " tiles of " in found["stderr"] else "1"
                lines.append(f"| {method} | {width}x{height} | {untiled:.1f} | {found['seconds']:.0f} | {found['peak_gb']:.2f} | "
                             f"{parse_memory(args.budget) / 2**30:.1f} | {tiles} | {epe:.2f} | "
                             f"{100 * valid.mean():.1f}% | |")
                print(found, file=sys.stderr, flush=True)
                found["output"].unlink()
        lines += notes
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown:
        args.markdown.write_text(text)


if __name__ == "__main__":
    main()
