"""benchmarks/drone_alignment.py on the real captures (../shared/data/micasense; skipped where
absent): it finds the four captures and their bands with the product's reader as the data's
README lists them; on the nearly planar field capture the lens rotations (the anchors' start,
on the product's frame and grid) line the bands up far better than the raw files do; every
method is scored on one grid, and on the windows every method could score. Without the data:
the edge crops' rule (benchmarks/drone_edges.py) on windows of known residuals and on a
synthetic band with a patch misregistered by a known shift, and --models (cards become
cade:<card> methods; an unknown card is refused in one line before any work) and --near (factors
become cade@near<F> methods; a bad list is refused in one line, by one message)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from cade_cli.capture.alignment import alignment
from cade_cli.capture.anchors import register_anchor
from cade_cli.capture.model import load_capture

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "drone_alignment.py"


@pytest.fixture
def drone_alignment():
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        import drone_alignment
        yield drone_alignment
    finally:
        sys.path.remove(str(SCRIPT.parent))


@pytest.fixture
def micasense(shared_data) -> Path:
    folder = shared_data / "micasense"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    return folder


def test_the_captures_and_their_bands_are_found(drone_alignment, micasense):
    captures = drone_alignment.find_captures(micasense)
    first_delivery = {"rededge-m-bench/IMG_0001", "rededge-m-bench/IMG_0007", "rededge-m-field/IMG_0008",
                      "sequoia-tabletop/IMG_180413_080658_0000"}  # and the panel shots that came later
    assert first_delivery <= set(captures)
    rededge = ["Blue", "Green", "Red", "NIR", "Red edge"]  # RigCameraIndex order (README)
    for name, capture in captures.items():
        expected = (["Green", "Red", "Red edge", "NIR"] if name.startswith("sequoia") else
                    rededge + ["Blue-444", "Green-531", "Red-650", "Red edge-705", "Red edge-740"]
                    if name.startswith("rededge-mx-dual") else rededge)
        assert capture.names() == expected and capture.reference_band.name == "Green"
        assert [band.rig_index for band in capture.bands] == list(range(len(expected)))
        focal = [band.lens.focal for band in capture.bands]
        low, high = (1061, 1062) if name.startswith("sequoia") else (1440, 1460)
        assert all(low < f < high for f in focal)


def test_lens_rotations_line_up_the_field_capture(micasense):
    capture = load_capture(sorted((micasense / "rededge-m-field").glob("IMG_0008_*.tif")))
    rotated = register_anchor(capture, ecc=False)
    reference = rotated.bands["Green"]
    assert np.isfinite(reference).all()  # the reference band's raw grid: every pixel seen
    raw = tifffile.imread(capture.bands[2].path).astype(np.float32)  # Red: the largest raw offset (~40 px)
    before = alignment(reference, raw, search=48)
    after = alignment(reference, rotated.bands["Red"], search=48)
    assert before.median > 10 and after.median < 3 and after.windows > 50, (before, after)


def test_every_method_is_scored_on_one_grid_and_on_the_common_windows(drone_alignment, micasense):
    capture = load_capture(sorted((micasense / "rededge-m-field").glob("IMG_0008_*.tif")))
    results = {"unaligned": drone_alignment.Registered(
        {b.name: tifffile.imread(b.path).astype(np.float32) for b in capture.bands}, 0.0, 0.0),
        "rotations": drone_alignment.Registered(register_anchor(capture, ecc=False).bands, 0.0, 0.0)}
    scored = drone_alignment.score(capture, results)
    for band in ("Blue", "Red", "NIR", "Red edge"):
        own = {method: scored[method].own[band] for method in results}
        common = {method: scored[method].common[band] for method in results}
        assert len({a.windows for a in common.values()}) == 1  # the same windows for every method
        assert all(common[m].windows <= own[m].windows for m in results)
        assert common["rotations"].median < common["unaligned"].median


def test_a_folder_without_band_files_is_refused_in_one_line(tmp_path):
    done = subprocess.run([sys.executable, SCRIPT, "--data-dir", tmp_path], capture_output=True, text=True)
    assert done.returncode != 0 and done.stderr.strip().count("\n") == 0
    assert "no band files" in done.stderr


def _grid_shifts(magnitudes: np.ndarray, columns: int, window: int = 64):
    """WindowShifts on a grid of ``columns`` windows a row, each shifted along x by its magnitude."""
    from cade_cli.capture.alignment import WindowShifts
    k = np.arange(len(magnitudes))
    centres = np.stack([k // columns * window + 31.5, k % columns * window + 31.5], -1)
    shifts = np.stack([magnitudes, np.where(np.isfinite(magnitudes), 0.0, np.nan)], -1)
    return WindowShifts(centres, shifts, np.ones(len(magnitudes)), np.zeros(len(magnitudes), bool))


def test_edge_crops_go_where_the_worst_method_is_worst_on_strong_edges(drone_alignment):
    from drone_edges import pick_edge_windows
    columns = 10  # a 6 x 10 grid of 64 px windows
    rng = np.random.default_rng(7)
    edge = rng.uniform(1.0, 2.0, 60)
    edge[:30] = rng.uniform(0.0, 0.5, 30)  # the top half of the image has weak edges
    a, b = rng.uniform(0.0, 1.0, (2, 60))
    a[5], b[5] = 40.0, 0.1  # the largest residual of all, but on weak edges: never picked
    a[44], b[44] = 0.2, 9.0  # the worst strong-edge window, by method b
    a[45], b[45] = 8.0, 0.3  # next to it: its crop would overlap the first's, skipped
    a[57], b[57] = 7.0, np.nan  # scored by one method only: its residual counts
    a[33], b[33] = np.nan, np.nan  # scored by none: left out whatever its edges
    edge[33] = 5.0
    shifts = {"NIR": {"cade:a": _grid_shifts(a, columns), "cade:b": _grid_shifts(b, columns)}}
    picked = pick_edge_windows(edge, shifts, count=3, crop=176)
    assert [(p.row, p.column) for p in picked[:2]] == [(288, 288), (352, 480)]  # windows 44, then 57
    assert picked[0].residuals == pytest.approx({"cade:a": 0.2, "cade:b": 9.0})
    assert len(picked) == 3 and picked[2].edge >= 1.0  # the third: some other strong-edge window
    for p in picked:  # no two crops overlap
        others = [q for q in picked if q is not p]
        assert all(abs(p.row - q.row) >= 176 or abs(p.column - q.column) >= 176 for q in others)
    again = pick_edge_windows(edge, shifts, count=3, crop=176)  # deterministic
    assert [(p.band, p.row, p.column) for p in again] == [(p.band, p.row, p.column) for p in picked]


def test_edge_crops_find_a_displaced_patch_and_picture_every_method(drone_alignment, tmp_path):
    import drone_edges
    from cade_cli.capture.alignment import window_shifts
    rng = np.random.default_rng(11)
    reference = cv2.GaussianBlur(rng.random((384, 512)).astype(np.float32), (0, 0), 2.0)
    reference[192:] = 0.5 + 2.0 * (reference[192:] - 0.5)  # the lower half's edges are the strong ones
    good = reference.copy()
    bad = reference.copy()
    patch = (slice(192, 320), slice(320, 448))  # four 64 px windows of the grid, misregistered by 4 px
    bad[patch] = np.roll(reference, (0, 4), axis=(0, 1))[patch]
    registered = {"cade:good": {"NIR": good}, "cade:bad": {"NIR": bad}}
    shifts = {"NIR": {m: window_shifts(reference, images["NIR"], search=16) for m, images in registered.items()}}
    written = drone_alignment.write_edge_crops(tmp_path, "bench/IMG_1", reference, registered, shifts,
                                               drone_alignment.overlay, count=2)
    path, first = written[0]
    assert first.row in (224, 288) and first.column in (352, 416)
    assert first.residuals["cade:bad"] == pytest.approx(4.0, abs=0.3) and first.residuals["cade:good"] < 0.1
    picture = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert path.name == "bench-IMG_1-edges-1-NIR.png" and picture.dtype == np.uint8
    crop, label = drone_edges.EDGE_CROP, drone_edges.LABEL
    assert picture.shape == (crop + label, 3 * crop + 2 * 2, 3)  # reference, then one overlay per method
    table = drone_alignment.edge_table({"bench/IMG_1": written}, list(registered))
    assert "| bench/IMG_1 | bench-IMG_1-edges-1-NIR.png | NIR |" in table
    holed = np.where(good > np.quantile(good, 0.9), np.float32(np.nan), good)  # NaN equals NaN
    alike = {"cade:a": {"NIR": holed}, "cade:b": {"NIR": holed.copy()}}
    assert drone_edges.same_registration(alike) and not drone_edges.same_registration(registered)


def test_models_become_cade_methods_and_an_unknown_card_is_refused_in_one_line(drone_alignment, tmp_path):
    repo_models = Path(__file__).resolve().parents[1] / "models"
    assert drone_alignment.parse_models(None) is None
    assert drone_alignment.parse_models(f"cade-v13, {repo_models / 'cade-v13-accurate.json'}") == {
        "cade:cade-v13": "cade-v13", "cade:cade-v13-accurate": str(repo_models / "cade-v13-accurate.json")}
    markdown = tmp_path / "table.md"
    done = subprocess.run([sys.executable, SCRIPT, "--data-dir", tmp_path, "--models", "cade-v13,no-such-card",
                           "--markdown", markdown], capture_output=True, text=True)
    assert done.returncode != 0 and done.stderr.strip().count("\n") == 0
    assert "no-such-card" in done.stderr and not markdown.exists()


def test_near_factors_become_cade_methods_and_a_bad_list_is_refused_in_one_line(drone_alignment, tmp_path):
    from cade_cli.capture.register import NEAR_FACTOR
    from cade_cli.errors import CadeError

    assert drone_alignment.parse_near(None) is None
    assert drone_alignment.parse_near("1,4") == (1.0, 4.0) and drone_alignment.parse_near(" 2.5 ") == (2.5,)
    assert drone_alignment.cade_methods(None, None) == {"cade": (None, NEAR_FACTOR)}
    assert drone_alignment.cade_methods(None, (1.0, 4.0)) == {"cade@near1": (None, 1.0), "cade@near4": (None, 4.0)}
    assert list(drone_alignment.cade_methods({"cade:a": "a", "cade:b": "b"}, (1.0, 2.5))) == [
        "cade:a@near1", "cade:a@near2.5", "cade:b@near1", "cade:b@near2.5"]
    messages = set()
    for text in ("", "1,", "0.5,4", "4,4", "far", "nan", "inf"):
        with pytest.raises(CadeError) as refused:
            drone_alignment.parse_near(text)
        messages.add(str(refused.value).replace(repr(text), "TEXT"))
    assert messages == {"--near TEXT: give factors of at least 1, comma-separated, each once (e.g. 1,4)"}
    markdown = tmp_path / "table.md"
    done = subprocess.run([sys.executable, SCRIPT, "--data-dir", tmp_path, "--near", "1,0.5", "--markdown", markdown],
                          capture_output=True, text=True)
    assert done.returncode != 0 and done.stderr.strip().count("\n") == 0
    assert "--near '1,0.5'" in done.stderr and not markdown.exists()
