"""cade's radiance, irradiance and reflectance against MicaSense's own library
(micasense/imageprocessing, MIT), on every RedEdge capture in ../shared/data/micasense.

    python benchmarks/micasense_radiometry.py --micasense-src /tmp/micasense-src \\
        --data-dir ../shared/data/micasense --markdown radiometry.md

``--micasense-src`` is a folder holding the library's source (its ``micasense/`` package and
``setup.py``), e.g. ``git --git-dir=<mirror> archive HEAD micasense setup.py LICENSE | tar -x -C DIR``.
The library is installed, with the few PyPI packages its image/capture/panel modules import,
into a throwaway virtual environment (``--venv``, default ``.venv-micasense``, git-ignored),
never into cade's; it reads the tags with exiftool (``/usr/bin/exiftool`` must exist). Its
``panel.py`` imports pyzbar, whose zbar system library may be missing: a stand-in module that
refuses to decode is put in its place (the panel shots here carry the camera's own panel tags,
ReflectArea and Albedo, so the library never decodes the QR code itself).

Per capture and band (the vendor's ``Capture``/``Image`` on one side, cade_cli.capture on the
other, both on the band's raw pixel grid, before any resampling):
  radiance      median and 99th percentile over the image of |cade - vendor| / vendor, where the
                vendor's radiance is above 1 % of its 99th percentile;
  irradiance    the DLS horizontal irradiance (vendor: Capture.dls_irradiance(), pysolar for the
                sun; cade: cade_cli.capture.irradiance with its own NOAA sun), relative difference;
  reflectance   DLS reflectance images, median relative difference;
  panel         on panel shots: mean panel radiance and panel irradiance (vendor:
                Capture.panel_radiance()/panel_irradiance() on the camera's ReflectArea over its
                undistorted radiance; cade: cade_cli.capture.panel on the raw grid), relative
                difference; and cade's QR-code square against the camera's ReflectArea square.
Then the flight check: IMG_0008 (flight) and IMG_0000 (panel shot, other exposures) of
rededge-m-field, reflectance of bare soil from the panel and from the DLS.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import venv
from pathlib import Path

import numpy as np
import tifffile

from cade_cli.capture.irradiance import dls_irradiances
from cade_cli.capture.metadata import parse_xmp
from cade_cli.capture.panel import find_panel_qr, measure_panel, region_stats, square_from_qr
from cade_cli.capture.radiometry import radiance, read_radiometric_model

VENDOR_PACKAGES = ("numpy<2", "opencv-python-headless", "scikit-image", "matplotlib", "imageio", "pysolar", "pytz",
                   "pyexiftool", "packaging")
"""What the library's image, capture, panel, dls, metadata, imageutils and plotutils modules import
(its setup.py also lists gdal, requests and pyzbar, which these modules do not need here)."""

VENDOR_SIDE = r'''
import json, sys, types
import numpy as np
stub = types.ModuleType("pyzbar"); stub.pyzbar = types.ModuleType("pyzbar.pyzbar")
def _refuse(*args, **kwargs):
    raise RuntimeError("pyzbar stand-in: QR decoding not available")
stub.pyzbar.decode = _refuse; stub.pyzbar.ZBarSymbol = types.SimpleNamespace(QRCODE=64)
sys.modules.setdefault("pyzbar", stub); sys.modules.setdefault("pyzbar.pyzbar", stub.pyzbar)
import micasense.capture as capture
jobs, out = json.loads(sys.argv[1]), sys.argv[2]
results = {}
for name, files in jobs.items():
    cap = capture.Capture.from_filelist(files)
    entry = {"bands": [img.band_name for img in cap.images], "paths": [img.path for img in cap.images]}
    for i, img in enumerate(cap.images):
        np.save(f"{out}/{name.replace('/', '+')}_{i}_radiance.npy", img.radiance().astype(np.float64))
    entry["dls"] = [float(v) for v in cap.dls_irradiance()] if cap.dls_present() else None
    entry["solar_elevation_deg"] = float(np.degrees(cap.images[0].solar_elevation))
    if all(img.auto_calibration_image for img in cap.images):
        entry["panel_radiance"] = [float(v) for v in cap.panel_radiance()]
        entry["panel_albedo"] = [float(v) for v in cap.panel_albedo()]
        entry["panel_irradiance"] = [float(v) for v in cap.panel_irradiance()]
    results[name] = entry
json.dump(results, open(f"{out}/vendor.json", "w"))
'''


def build_vendor_venv(folder: Path, source: Path) -> Path:
    """The throwaway environment with the library installed; its python."""
    python = folder / "bin" / "python"
    if not (source / "micasense" / "image.py").is_file():
        raise SystemExit(f"--micasense-src {source} has no micasense/image.py")
    if not python.exists():
        venv.EnvBuilder(with_pip=True).create(folder)
        subprocess.run([str(python), "-m", "pip", "install", "-q", *VENDOR_PACKAGES], check=True)
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--force-reinstall", str(source)],
                   check=True)
    return python


def rededge_captures(data_dir: Path) -> dict[str, list[Path]]:
    """``folder/IMG_NNNN`` -> its band files, for the MicaSense folders (the library has no Sequoia support)."""
    found: dict[str, list[Path]] = {}
    for path in sorted(data_dir.glob("*/IMG_*_*.tif")):
        model = tifffile.TiffFile(path).pages[0].tags.get(271)
        if model is None or "MicaSense" not in str(model.value):
            continue
        stem = path.stem.rpartition("_")[0]
        found.setdefault(f"{path.parent.name}/{stem}", []).append(path)
    return {name: sorted(files, key=lambda p: int(p.stem.rpartition("_")[2])) for name, files in found.items()}


def relative(a: np.ndarray, b: np.ndarray, *, floor: float) -> np.ndarray:
    keep = np.isfinite(a) & np.isfinite(b) & (b > floor)
    return np.abs(a[keep] - b[keep]) / b[keep]


def compare(captures: dict[str, list[Path]], vendor: dict, vendor_dir: Path) -> list[dict]:
    rows = []
    for name, files in captures.items():
        entry = vendor[name]
        paths = [Path(p) for p in entry["paths"]]
        dls = dls_irradiances(paths, entry["bands"]) if entry["dls"] is not None else None
        for i, (band, path) in enumerate(zip(entry["bands"], paths)):
            ours = radiance(tifffile.imread(path), read_radiometric_model(path)).astype(np.float64)
            theirs = np.load(vendor_dir / f"{name.replace('/', '+')}_{i}_radiance.npy")
            floor = 0.01 * np.percentile(theirs, 99)
            diff = relative(ours, theirs, floor=floor)
            row = {"capture": name, "band": band, "radiance_median": float(np.median(diff)),
                   "radiance_p99": float(np.percentile(diff, 99)),
                   "radiance_max_abs": float(np.abs(ours - theirs).max())}
            if dls is not None:
                row["dls_cade"], row["dls_vendor"] = dls[i], entry["dls"][i]
                row["dls_rel"] = abs(dls[i] - entry["dls"][i]) / entry["dls"][i]
                reflectance_diff = relative(ours * np.pi / dls[i], theirs * np.pi / entry["dls"][i],
                                            floor=floor * np.pi / entry["dls"][i])
                row["reflectance_median"] = float(np.median(reflectance_diff))
            if "panel_irradiance" in entry:
                measure = measure_panel(path)
                vendor_panel = entry["panel_radiance"][i]
                row["panel_radiance_rel"] = abs(measure.radiance - vendor_panel) / vendor_panel
                row["panel_irradiance_cade"], row["panel_irradiance_vendor"] = (measure.irradiance,
                                                                                entry["panel_irradiance"][i])
                row["panel_irradiance_rel"] = (abs(measure.irradiance - entry["panel_irradiance"][i])
                                               / entry["panel_irradiance"][i])
                raw = tifffile.imread(path)
                qr = find_panel_qr(raw)
                if qr is not None:
                    qr_mean, _, _ = region_stats(ours, square_from_qr(qr, raw))
                    row["qr_vs_tag_rel"] = abs(qr_mean - measure.radiance) / measure.radiance
                if dls is not None:  # the DLS irradiance against the panel's
                    row["panel_reflectance_by_dls"] = np.pi * measure.radiance / dls[i]
                    row["panel_albedo"] = measure.albedo
            rows.append(row)
    return rows


def soil_check(data_dir: Path) -> list[dict]:
    """Bare soil in the panel shot (IMG_0000, outside the panel case) and the dirt road in the
    flight capture (IMG_0008), each band's reflectance by the panel's irradiance and by each
    capture's own DLS: not the same ground (see docs/drone.md)."""
    folder = data_dir / "rededge-m-field"
    panel_files = sorted(folder.glob("IMG_0000_*.tif"))
    flight_files = sorted(folder.glob("IMG_0008_*.tif"))
    if len(panel_files) != 5 or len(flight_files) != 5:
        return []
    names = [parse_xmp(tifffile.TiffFile(p).pages[0].tags[700].value)["Camera:BandName"] for p in panel_files]
    panel_e = [measure_panel(p).irradiance for p in panel_files]
    dls_panel_shot, dls_flight = dls_irradiances(panel_files, names), dls_irradiances(flight_files, names)
    rows = []
    for i, name in enumerate(names):
        shot = radiance(tifffile.imread(panel_files[i]), read_radiometric_model(panel_files[i]))
        flight = radiance(tifffile.imread(flight_files[i]), read_radiometric_model(flight_files[i]))
        soil_shot = float(np.median(shot[:, :200]))  # left strip: bare soil beside the panel case
        soil_flight = float(np.median(flight[:120, :500]))  # upper left: the dirt road
        exif_shot = tifffile.TiffFile(panel_files[i]).pages[0].tags[34665].value
        exif_flight = tifffile.TiffFile(flight_files[i]).pages[0].tags[34665].value
        rows.append({"band": name,
                     "exposure_ms": (1000 * exif_shot["ExposureTime"][0] / exif_shot["ExposureTime"][1],
                                     1000 * exif_flight["ExposureTime"][0] / exif_flight["ExposureTime"][1]),
                     "iso": (exif_shot["ISOSpeed"], exif_flight["ISOSpeed"]),
                     "soil_shot_panel": np.pi * soil_shot / panel_e[i],
                     "road_flight_panel": np.pi * soil_flight / panel_e[i],
                     "soil_shot_dls": np.pi * soil_shot / dls_panel_shot[i],
                     "road_flight_dls": np.pi * soil_flight / dls_flight[i],
                     "dls_ratio_flight_to_shot": dls_flight[i] / dls_panel_shot[i]})
    return rows


def markdown(rows: list[dict], soil: list[dict]) -> str:
    lines = ["| capture | band | radiance median / p99 rel. diff | DLS E cade / vendor (W/m²/nm) | DLS reflectance "
             "median rel. diff | panel radiance rel. diff | panel E cade / vendor | QR square vs tag square |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        dls = (f"{r['dls_cade']:.4f} / {r['dls_vendor']:.4f} ({100 * r['dls_rel']:.2f} %)" if "dls_rel" in r
               else "no DLS")
        refl = f"{100 * r['reflectance_median']:.2f} %" if "reflectance_median" in r else "–"
        panel = f"{100 * r['panel_radiance_rel']:.2f} %" if "panel_radiance_rel" in r else "–"
        panel_e = (f"{r['panel_irradiance_cade']:.4f} / {r['panel_irradiance_vendor']:.4f} "
                   f"({100 * r['panel_irradiance_rel']:.2f} %)" if "panel_irradiance_rel" in r else "–")
        qr = f"{100 * r['qr_vs_tag_rel']:.2f} %" if "qr_vs_tag_rel" in r else "–"
        lines.append(f"| {r['capture']} | {r['band']} | {100 * r['radiance_median']:.4f} % / "
                     f"{100 * r['radiance_p99']:.4f} % | {dls} | {refl} | {panel} | {panel_e} | {qr} |")
    panels = [r for r in rows if "panel_reflectance_by_dls" in r]
    if panels:
        lines += ["", "Panel reflectance from each panel shot's own DLS irradiance (should be the albedo):", "",
                  "| capture | band | π L_panel / E_DLS | albedo |", "|---|---|---|---|"]
        lines += [f"| {r['capture']} | {r['band']} | {r['panel_reflectance_by_dls']:.3f} | {r['panel_albedo']:.4f} |"
                  for r in panels]
    if soil:
        lines += ["", "| band | exposure ms shot / flight | ISO shot / flight | soil (shot) by panel E | road "
                  "(flight) by panel E | soil (shot) by its DLS | road (flight) by its DLS | DLS flight / shot |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {s['band']} | {s['exposure_ms'][0]:.3f} / {s['exposure_ms'][1]:.3f} | {s['iso'][0]} / "
                  f"{s['iso'][1]} | {s['soil_shot_panel']:.3f} | {s['road_flight_panel']:.3f} | "
                  f"{s['soil_shot_dls']:.3f} | {s['road_flight_dls']:.3f} | {s['dls_ratio_flight_to_shot']:.2f} |"
                  for s in soil]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--micasense-src", type=Path, required=True,
                        help="folder with the library's micasense/ and setup.py")
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data/micasense"))
    parser.add_argument("--venv", type=Path, default=Path(".venv-micasense"))
    parser.add_argument("--markdown", type=Path, help="also write the tables here")
    parser.add_argument("--json", type=Path, help="also write every figure here")
    args = parser.parse_args()
    captures = rededge_captures(args.data_dir)
    if not captures:
        raise SystemExit(f"no MicaSense captures under {args.data_dir}")
    python = build_vendor_venv(args.venv.resolve(), args.micasense_src.resolve())
    with tempfile.TemporaryDirectory() as scratch:
        jobs = {name: [str(p.resolve()) for p in files] for name, files in captures.items()}
        subprocess.run([str(python), "-c", VENDOR_SIDE, json.dumps(jobs), scratch], check=True,
                       cwd=tempfile.gettempdir())
        vendor = json.loads((Path(scratch) / "vendor.json").read_text())
        rows = compare(captures, vendor, Path(scratch))
    soil = soil_check(args.data_dir)
    text = markdown(rows, soil)
    print(text)
    if args.markdown:
        args.markdown.write_text(text)
    if args.json:
        args.json.write_text(json.dumps({"bands": rows, "soil": soil,
                                         "vendor_solar_elevation_deg": {k: v["solar_elevation_deg"]
                                                                        for k, v in vendor.items()}}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
