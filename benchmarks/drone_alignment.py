"""Drone multispectral captures (one file per band, ../shared/data/micasense): how well each
way of registering the bands onto the reference band lines them up, without ground truth.

    python benchmarks/drone_alignment.py --data-dir ../shared/data/micasense --markdown table.md --pictures crops/

Methods, each scored per band with cade_cli.capture.alignment (residual shift of
gradient-image correlation in 64 px windows: median, 90th percentile, share > 1 px, and the
coverage kept):
  unaligned   the raw bands, as the cameras wrote them;
  rotations   undistorted (Brown-Conrady for MicaSense, Parrot's fisheye for the Sequoia), then
              the lens rotations of the RigRelatives tags, K_ref R_ref^T R_band K_band^-1;
  homography  one ECC homography per band on gradient images, started from the rotations
              (the vendor's method, cade_cli.capture.homography); where ECC fails from there,
              started from a feature-match homography instead (marked homography*);
  cade        `python -m cade_cli register-capture` where that command exists, else n/a.
The times are of this process on whatever machine runs it.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import tifffile

from cade_cli.capture.alignment import Alignment, alignment, window_shifts
from cade_cli.capture.homography import ecc_homography, feature_homography, warp_band
from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_outputs

METHODS = ("unaligned", "rotations", "homography", "cade")
REFERENCE_BAND = "Green"
"""The vendors' reference band (MicaSense: RigCameraIndex 1; Sequoia: the rig reference)."""
SEARCH = 96
"""px searched around each window: above the largest offsets of these cameras' raw bands (~50 px)
and the parallax a homography leaves on the Sequoia capture (tens of px)."""
CROP = 192
"""Side, px, of a picture's crop (written at full resolution)."""


# --- A minimal reader of the bands' metadata, private to this benchmark: to be replaced by the
# --- capture reader of cade_cli/capture (branch drone) once it lands.
@dataclass
class _Band:
    path: Path
    capture: str
    name: str
    index: int
    image: np.ndarray          # (H, W) float32, as stored
    camera: np.ndarray         # (3, 3) K, px
    model: str                 # "perspective" or "fisheye"
    distortion: np.ndarray     # Brown [k1, k2, p1, p2, k3] or fisheye [p0..p3, C, D, E, F]
    rotation: np.ndarray       # (3, 3) R of the RigRelatives (identity when absent)


def _xmp_fields(path: Path) -> dict[str, str]:
    """Every XMP element's text and attribute by its local name (lists joined by commas)."""
    with tifffile.TiffFile(path) as tif:
        tags = tif.pages[0].tags
        packet = tags[700].value if 700 in tags else b""
    text = packet.decode("utf-8", "replace") if isinstance(packet, bytes) else str(packet)
    start = text.find("<x:xmpmeta")
    if start < 0:
        raise CadeError(f"{path}: no XMP packet (TIFF tag 700); not a MicaSense or Parrot band file")
    root = ElementTree.fromstring(text[start:text.index("</x:xmpmeta>") + len("</x:xmpmeta>")])
    fields: dict[str, str] = {}
    for element in root.iter():
        for key, value in element.attrib.items():
            fields.setdefault(key.rsplit("}", 1)[-1], value)
        items = [li.text.strip() for li in element.iter() if li.tag.endswith("}li") and li.text]
        local = element.tag.rsplit("}", 1)[-1]
        if items and local not in ("Seq", "Bag", "Alt"):
            fields.setdefault(local, ",".join(items))
        elif element.text and element.text.strip():
            fields.setdefault(local, element.text.strip())
    return fields


def _numbers(text: str) -> np.ndarray:
    return np.array([float(v) for v in re.split(r"[,\s]+", text.strip()) if v])


def _rotation(degrees: np.ndarray) -> np.ndarray:
    """R = Rx(a) Ry(b) Rz(c), as the vendor library builds it from RigRelatives."""
    cx, cy, cz = np.cos(np.radians(degrees))
    sx, sy, sz = np.sin(np.radians(degrees))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rx @ ry @ rz


def _read_band(path: Path) -> _Band:
    fields = _xmp_fields(path)
    with tifffile.TiffFile(path) as tif:
        image = tif.pages[0].asarray().astype(np.float32)
        exif = tif.pages[0].tags["ExifTag"].value if "ExifTag" in tif.pages[0].tags else {}
    try:
        pixels_per_mm = exif["FocalPlaneXResolution"][0] / exif["FocalPlaneXResolution"][1]
        model = fields["ModelType"]
        if model == "perspective":
            focal_mm = float(fields["PerspectiveFocalLength"])
            distortion = _numbers(fields["PerspectiveDistortion"])[[0, 1, 3, 4, 2]]
        else:
            focal_mm = exif["FocalLength"][0] / exif["FocalLength"][1]
            distortion = np.concatenate([_numbers(fields["FisheyePolynomial"]),
                                         _numbers(fields["FisheyeAffineMatrix"])])
        cx, cy = _numbers(fields["PrincipalPoint"]) * pixels_per_mm
        focal = focal_mm * pixels_per_mm
        relatives = _numbers(fields.get("RigRelatives", "0, 0, 0"))
        band = _Band(path, fields.get("CaptureId", fields.get("CaptureUUID", path.stem.rsplit("_", 1)[0])),
                     fields["BandName"], int(fields["RigCameraIndex"]), image,
                     np.array([[focal, 0, cx], [0, focal, cy], [0, 0, 1]]), model, distortion, _rotation(relatives))
    except (KeyError, IndexError, ValueError) as error:
        raise CadeError(f"{path}: metadata field {error} missing or unreadable") from None
    return band
# --- end of the private reader


def find_captures(data_dir: Path) -> dict[str, list[_Band]]:
    """The captures under ``data_dir``: band files grouped by the capture id in their XMP
    (folder-qualified), each capture's bands in RigCameraIndex order."""
    grouped: dict[tuple[Path, str], list[_Band]] = {}
    for path in sorted(p for p in data_dir.rglob("*") if p.suffix.lower() in (".tif", ".tiff")):
        band = _read_band(path)
        grouped.setdefault((path.parent, band.capture), []).append(band)
    if not grouped:
        raise CadeError(f"no band files (*.tif) under {data_dir}; pass --data-dir the folder of the captures")
    captures = {}
    for (folder, _), bands in grouped.items():  # named by folder and the first file's name less its band suffix
        bands = sorted(bands, key=lambda b: b.index)
        captures[f"{folder.name}/{bands[0].path.stem.rsplit('_', 1)[0]}"] = bands
    return captures


def undistorted(band: _Band) -> tuple[np.ndarray, np.ndarray]:
    """The band on an ideal pinhole grid of its own size, NaN where it saw nothing, and that
    grid's K. Brown-Conrady: K_new = getOptimalNewCameraMatrix(alpha=1), as the vendor library."""
    height, width = band.image.shape
    if band.model == "perspective":
        new, _ = cv2.getOptimalNewCameraMatrix(band.camera, band.distortion, (width, height), 1)
        map_x, map_y = cv2.initUndistortRectifyMap(band.camera, band.distortion, np.eye(3), new, (width, height),
                                                   cv2.CV_32FC1)
    else:  # Parrot's fisheye: ray (X, Y, 1) -> theta = 2/pi atan(r) -> rho(theta) -> affine -> pixel
        new = band.camera
        cols, rows = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        x, y = (cols - new[0, 2]) / new[0, 0], (rows - new[1, 2]) / new[1, 1]
        r = np.maximum(np.hypot(x, y), 1e-12)
        theta = 2.0 / np.pi * np.arctan(r)
        p0, p1, p2, p3, c, d, e, f = band.distortion
        rho = p0 + p1 * theta + p2 * theta ** 2 + p3 * theta ** 3
        u, v = rho * x / r, rho * y / r
        map_x = (c * u + d * v + band.camera[0, 2]).astype(np.float32)
        map_y = (e * u + f * v + band.camera[1, 2]).astype(np.float32)
    image = cv2.remap(band.image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=np.nan)
    return image, new


def rotation_homography(band: _Band, camera: np.ndarray, reference: _Band, reference_camera: np.ndarray) -> np.ndarray:
    """Band pixels -> reference pixels (undistorted grids): K_ref R_ref^T R_band K_band^-1."""
    homography = reference_camera @ reference.rotation.T @ band.rotation @ np.linalg.inv(camera)
    return homography / homography[2, 2]


@dataclass
class Registered:
    """One method's result on one capture: the reference band and every other band on its grid."""

    reference: np.ndarray
    bands: dict[str, np.ndarray]
    seconds: float
    note: str = ""
    failures: dict[str, str] = field(default_factory=dict)
    """Bands the method could not register: why."""
    starts: dict[str, str] = field(default_factory=dict)
    """Where each band's ECC started: "rotations" or "features"."""


def register_plane(bands: list[_Band], reference: _Band, *, ecc: bool) -> Registered:
    """Undistort every band, then warp each onto the reference by its lens rotation, or (``ecc``)
    by the ECC homography started from it; where that fails (the rotations far off at close
    range), by the ECC homography started from feature matches (``homography*`` in the table)."""
    start = time.perf_counter()
    flat = {band.name: undistorted(band) for band in bands}
    reference_image, reference_camera = flat[reference.name]
    registered, failures, starts = {}, {}, {}
    for band in bands:
        if band is reference:
            continue
        image, camera = flat[band.name]
        homography = rotation_homography(band, camera, reference, reference_camera)
        try:
            if ecc:
                homography = _ecc_from_rotations_or_features(reference_image, image, homography)
                starts[band.name] = "rotations" if homography[1] is None else "features"
                homography = homography[0]
        except CadeError as error:
            failures[band.name] = f"failed: {error}"
            continue
        registered[band.name] = warp_band(image, homography, image.shape[::-1])
    return Registered(reference_image, registered, time.perf_counter() - start, failures=failures, starts=starts)


def _ecc_from_rotations_or_features(reference: np.ndarray, band: np.ndarray, rotations: np.ndarray
                                    ) -> tuple[np.ndarray, int | None]:
    """The ECC homography from the rotations, else from the feature homography (and its inliers)."""
    try:
        return ecc_homography(reference, band, init=rotations), None
    except CadeError as first:
        try:
            start, inliers = feature_homography(reference, band)
            return ecc_homography(reference, band, init=start), inliers
        except CadeError as second:
            raise CadeError(f"from the rotations: {first}; from feature matches: {second}") from None


def cade_available() -> bool:
    """Whether this checkout's ``cade`` has the ``register-capture`` command."""
    answer = subprocess.run([sys.executable, "-m", "cade_cli", "--help"], capture_output=True, text=True)
    return answer.returncode == 0 and "register-capture" in answer.stdout


def register_cade(bands: list[_Band], reference: _Band) -> Registered:
    """``python -m cade_cli register-capture`` on the capture's files; its cube's pages are the
    bands in capture order, registered onto the reference band's page."""
    with tempfile.TemporaryDirectory() as folder:
        cube_path = Path(folder) / "cube.tif"
        start = time.perf_counter()
        answer = subprocess.run([sys.executable, "-m", "cade_cli", "register-capture",
                                 *[str(b.path) for b in bands], "-o", str(cube_path)], capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if answer.returncode != 0:
            line = (answer.stderr.strip().splitlines() or ["no message"])[-1]
            return Registered(np.empty(0), {}, seconds, f"failed: {line}")
        cube = tifffile.imread(cube_path).astype(np.float32)
    pages = {band.name: cube[k] for k, band in enumerate(bands)}
    reference_page = pages.pop(reference.name)
    return Registered(reference_page, pages, seconds)


def register(bands: list[_Band], *, with_cade: bool) -> dict[str, Registered]:
    """Every method of :data:`METHODS` on one capture (``cade`` only ``with_cade``)."""
    reference = next((b for b in bands if b.name == REFERENCE_BAND), None)
    if reference is None:
        raise CadeError(f"{bands[0].path.parent}: no {REFERENCE_BAND} band in capture {bands[0].capture}")
    results = {"unaligned": Registered(reference.image, {b.name: b.image for b in bands if b is not reference}, 0.0),
               "rotations": register_plane(bands, reference, ecc=False),
               "homography": register_plane(bands, reference, ecc=True)}
    results["cade"] = register_cade(bands, reference) if with_cade else Registered(np.empty(0), {}, 0.0, "n/a")
    return results


def score(results: dict[str, Registered]) -> dict[str, dict[str, Alignment]]:
    """Per method, per band: its :class:`Alignment` with the method's reference band."""
    return {method: {name: alignment(result.reference, image, search=SEARCH) for name, image in result.bands.items()}
            for method, result in results.items()}


def _cell(value: float, scale: float = 1.0, digits: int = 2) -> str:
    return "n/a" if not np.isfinite(value) else f"{value * scale:.{digits}f}"


def table(scores: dict[str, dict[str, dict[str, Alignment]]], results: dict[str, dict[str, Registered]]) -> str:
    """Markdown: a row per capture x band x method, then a summary row per capture x method
    (the bands' means) with the method's time."""
    header = ["capture", "band", "method", "median px", "p90 px", "> 1 px %", "coverage %", "windows", "time s"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for capture, per_method in scores.items():
        for method in METHODS:
            note = results[capture][method].note
            for band, a in per_method.get(method, {}).items():
                shown = method + ("*" if results[capture][method].starts.get(band) == "features" else "")
                lines.append(f"| {capture} | {band} | {shown} | {_cell(a.median)} | {_cell(a.p90)} | "
                             f"{_cell(a.share_over_1px, 100, 1)} | {_cell(a.coverage, 100, 1)} | {a.windows} | |")
            for band, why in results[capture][method].failures.items():
                lines.append(f"| {capture} | {band} | {method} | {why} | | | | | |")
            if note:
                lines.append(f"| {capture} | all | {method} | {note} | | | | | |")
        for method in METHODS:
            rows = list(per_method.get(method, {}).values())
            if not rows:
                continue
            mean = lambda name: float(np.nanmean([getattr(a, name) for a in rows]))  # noqa: E731
            label = "mean" if not results[capture][method].failures else f"mean of {len(rows)}"
            lines.append(f"| **{capture}** | **{label}** | **{method}** | {_cell(mean('median'))} | {_cell(mean('p90'))} | "
                         f"{_cell(mean('share_over_1px'), 100, 1)} | {_cell(mean('coverage'), 100, 1)} | "
                         f"{sum(a.windows for a in rows)} | {results[capture][method].seconds:.1f} |")
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


def write_pictures(folder: Path, capture: str, results: dict[str, Registered]) -> list[Path]:
    """A crop (:data:`CROP` px) of each of unaligned / homography / cade where the
    homography leaves the largest residual shift, as ``<capture>-<band>-<method>.png``."""
    plane = results["homography"]
    if not plane.bands:
        return []
    band, row, column = worst_place(plane.reference, plane.bands)
    written = []
    for method in ("unaligned", "homography", "cade"):
        result = results[method]
        if band not in result.bands:
            continue
        height, width = result.reference.shape
        top = int(np.clip(row - CROP // 2, 0, height - CROP))
        left = int(np.clip(column - CROP // 2, 0, width - CROP))
        crop = (slice(top, top + CROP), slice(left, left + CROP))
        path = folder / f"{capture.replace('/', '-')}-{band.replace(' ', '')}-{method}.png"
        cv2.imwrite(str(path), overlay(result.reference[crop], result.bands[band][crop]),
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
        written.append(path)
    return written


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, required=True, help="folder of the captures' band files")
    parser.add_argument("--markdown", type=Path, help="write the table to this file")
    parser.add_argument("--pictures", type=Path, help="folder for the crops (before / homography / cade)")
    arguments = parser.parse_args()
    try:
        if not arguments.data_dir.is_dir():
            raise CadeError(f"--data-dir {arguments.data_dir} is not a folder")
        with atomic_outputs([arguments.markdown], folders=[arguments.pictures]) as staged:  # all or nothing
            text = run(arguments.data_dir, pictures=staged.get(arguments.pictures))
            print(text)
            if arguments.markdown is not None:
                staged[arguments.markdown].write_text(text + "\n")
    except CadeError as error:
        raise SystemExit(f"drone_alignment: error: {error}") from None


def run(data_dir: Path, *, pictures: Path | None) -> str:
    """Every capture under ``data_dir`` registered by every method and scored (the Markdown
    table is returned; each capture's times go to stderr as it ends); crops into ``pictures``."""
    with_cade = cade_available()
    scores, results = {}, {}
    for capture, bands in find_captures(data_dir).items():
        results[capture] = register(bands, with_cade=with_cade)
        scores[capture] = score(results[capture])
        times = ", ".join(f"{m} {r.seconds:.1f} s" + (f" ({len(r.failures)} bands failed)" if r.failures else "")
                          if not r.note else f"{m} {r.note}" for m, r in results[capture].items())
        print(f"{capture}: {len(bands)} bands; {times}", file=sys.stderr)
        if pictures is not None:
            write_pictures(pictures, capture, results[capture])
    return table(scores, results)


if __name__ == "__main__":
    main()
