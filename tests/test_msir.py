"""The pseudo ground truth of an array camera (cade_cli.rigs.array_pseudo_gt) on a rendered mini
array with known disparity, and the msir-outdoor benchmark dataset (cade_cli.data.msir): its
framing of a pair (turn, sign, shift) on the real data, its wiring into ``cade benchmark``."""

from __future__ import annotations

import json
import math
import os

import cv2
import numpy as np
import pytest

from cade_cli.data import DATASETS, get_source
from cade_cli.data import msir
from cade_cli.errors import CadeError
from cade_cli.evaluation.loop import run_benchmark
from cade_cli.matching import MATCHERS
from cade_cli.rigs.array_pseudo_gt import agreeing_estimates, pseudo_ground_truth, rereferenced
from cade_cli.rigs.rig import Camera, PlaneMapping, Rig
from cli_runner import run_cade, write_png16
from synthetic import smooth_texture

SHAPE = (96, 128)
BACKGROUND, BOX = -1.5, 2.5
"""Disparity, px per unit baseline, of the background (behind the plane) and of a box in front."""
BOX_AT = (slice(30, 70), slice(40, 90))
POSITIONS = {"ref": (0.0, 0.0), "right": (1.0, 0.0), "left": (-1.0, 0.0), "down": (0.0, 1.0), "nir": (0.0, -1.0)}
"""Unit baselines in image axes (x right, y down); "nir" sees another band."""


def _render(textures, offset, box_disparity=BOX):
    """The scene seen from a camera at ``offset`` (unit baselines): camera pixel p shows the
    reference pixel q = p + delta(q) * offset of the nearest layer that covers q."""
    height, width = SHAPE
    x, y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    image = np.zeros(SHAPE, np.float32)
    depth = np.full(SHAPE, -np.inf, np.float32)
    for disparity, texture, box in ((BACKGROUND, textures[0], None), (box_disparity, textures[1], BOX_AT)):
        qx, qy = x + disparity * offset[0], y + disparity * offset[1]
        sampled = cv2.remap(texture, qx + 20, qy + 20, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        covered = np.ones(SHAPE, bool) if box is None else (
            (qy >= box[0].start) & (qy <= box[0].stop - 1) & (qx >= box[1].start) & (qx <= box[1].stop - 1))
        nearer = covered & (disparity > depth)
        image, depth = np.where(nearer, sampled, image), np.where(nearer, disparity, depth)
    return image


def _mini_array(seed: int = 3, *, wrong_box: str | None = None):
    """(rig, images, true disparity): every camera on the reference plane (identity mappings);
    ``wrong_box`` names a camera rendered with the box at another disparity (its estimates there
    disagree with the others')."""
    rng = np.random.default_rng(seed)
    textures = [smooth_texture(rng, (SHAPE[0] + 40, SHAPE[1] + 40), sigma=1.2) for _ in range(2)]
    images = {}
    for name, offset in POSITIONS.items():
        band = _render(textures, offset, BOX + 2.0 if name == wrong_box else BOX)
        images[name] = 1.0 - band**2 if name == "nir" else band  # another spectral response
    cameras = tuple(Camera(name=name, band=name, image_size=(SHAPE[1], SHAPE[0]),
                           to_reference=PlaneMapping("affine", np.array([[1.0, 0, 0], [0, 1.0, 0]])),
                           position=position) for name, position in POSITIONS.items())
    truth = np.full(SHAPE, BACKGROUND, np.float32)
    truth[BOX_AT] = BOX
    return Rig(reference="ref", cameras=cameras), images, truth


def _interior(truth: np.ndarray) -> np.ndarray:
    """Away from the box's edges (occlusions, edge fattening) and from the borders: a matcher
    searching 16 px (the default signed range) has no estimate within 16 px of the border on
    one side of a horizontal baseline."""
    edges = cv2.dilate((cv2.Laplacian(truth, cv2.CV_32F) != 0).astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    keep = ~edges
    keep[:8], keep[-8:], keep[:, :24], keep[:, -24:] = False, False, False, False
    return keep


def test_pseudo_truth_recovers_the_rendered_disparity_on_the_pixels_it_keeps():
    rig, images, truth = _mini_array()
    made = pseudo_ground_truth(rig, images, ["right", "left", "down"])
    kept = np.isfinite(made.disparity)
    inside = _interior(truth)
    assert (kept & inside).sum() / inside.sum() > 0.6, "most textured interior pixels are kept"
    error = np.abs(made.disparity - truth)[kept]
    assert np.median(error) < 0.15 and np.mean(error > 0.5) < 0.02
    assert made.partners == ("right", "left", "down") and len(made.estimates) == 3
    assert 0 < made.coverage < 1


def test_pseudo_truth_drops_pixels_where_the_partners_disagree():
    """Two partners; one sees the box 2 px nearer: the box has no pseudo ground truth, the
    background keeps its own."""
    rig, images, truth = _mini_array(wrong_box="left")
    made = pseudo_ground_truth(rig, images, ["right", "left"])
    box_inside, back_inside = _interior(truth) & (truth == BOX), _interior(truth) & (truth == BACKGROUND)
    assert np.isfinite(made.disparity[box_inside]).mean() < 0.05
    assert np.isfinite(made.disparity[back_inside]).mean() > 0.8
    assert np.nanmax(np.abs(made.disparity - truth)[back_inside]) < 0.5
    right, left = made.estimates
    assert np.nanmedian(np.abs(left - truth)[box_inside]) > 1.5  # the wrong partner's own estimate
    assert np.nanmedian(np.abs(right - truth)[box_inside]) < 0.25


def test_agreement_rule_on_single_pixels():
    nan = np.nan
    votes = [np.array([0.0, 0.0, nan, 1.0, 0.1]), np.array([0.3, 1.0, 1.0, 1.2, 0.3]),
             np.array([5.0, 2.0, 1.1, nan, 0.35])]
    got = agreeing_estimates(votes, 0.5)
    # closest pairs: (0, 0.3), 5 far; none within 0.5; (1.0, 1.1); (1.0, 1.2); (0.3, 0.35), whose
    # midpoint 0.325 has 0.1 within 0.25: all three count
    np.testing.assert_allclose(got, [0.15, nan, 1.05, 1.1, 0.25], atol=1e-6)
    assert np.isnan(agreeing_estimates(votes[:1], 0.5)).all()  # one partner is never enough


def test_pseudo_truth_refuses_the_learned_matcher_and_too_few_partners():
    rig, images, _ = _mini_array()
    with pytest.raises(CadeError, match="learned matcher"):
        pseudo_ground_truth(rig, images, ["right", "left"], methods=("sgbm", "cade"))
    with pytest.raises(CadeError, match="two or more partners"):
        pseudo_ground_truth(rig, images, ["right"])


def test_rereferenced_composes_the_plane_mappings():
    a = np.array([[1.01, 0.002, 5.0], [-0.003, 0.99, -7.0]])
    b = np.array([[0.98, -0.001, -3.0], [0.002, 1.02, 11.0]])
    cameras = tuple(Camera(name=n, band=n, image_size=(10, 10), to_reference=PlaneMapping("affine", m), position=p)
                    for n, m, p in (("c0", np.eye(3)[:2], (0, 0)), ("c1", a, (1, 0)), ("c2", b, (0, 1))))
    turned = rereferenced(Rig("c0", cameras), "c1")
    assert turned.reference == "c1"
    np.testing.assert_array_equal(turned.camera("c1").to_reference.matrix, np.eye(3)[:2])
    point = np.array([12.0, 34.0, 1.0])  # c2's pixel -> c0's -> c1's must be the composed map
    via = np.linalg.solve(np.vstack([a, [0, 0, 1]]), np.vstack([b, [0, 0, 1]]) @ point)
    np.testing.assert_allclose(turned.camera("c2").to_reference.homography @ point, via, atol=1e-9)


# --- msir-outdoor on a rendered miniature of its folder ----------------------------------


@pytest.fixture
def mini_msir(tmp_path, monkeypatch):
    """A folder in the msir-outdoor layout, 9 cameras rendered at the MSIR positions (40 mm =
    one unit baseline), every camera already on the façade plane (the same 8 corners in each),
    cameras 0-2 with another spectral response; the cache in ``tmp_path/cache``."""
    folder = tmp_path / "data" / "msir-outdoor"
    (folder / "scene").mkdir(parents=True)
    (folder / "calibration").mkdir()
    rng = np.random.default_rng(11)
    textures = [smooth_texture(rng, (SHAPE[0] + 40, SHAPE[1] + 40), sigma=1.2) for _ in range(2)]
    layout = {}
    for index in range(9):
        x_mm, y_mm = 40 - 40 * (index % 3), 40 - 40 * (index // 3)  # Cam-0 at X = Y = +40 (image right, top)
        band = _render(textures, (x_mm / 40, -y_mm / 40))
        write_png16(folder / "scene" / f"Cam-{index}.png", band**2 if index < 3 else band)  # census: monotone
        layout[f"Camera {index}"] = {"X": x_mm, "Y": y_mm, "image_width": SHAPE[1], "image_height": SHAPE[0]}
    (folder / "camera_array.json").write_text(json.dumps(layout))
    corners = np.array([[10, 10], [110, 12], [60, 50], [15, 85], [100, 80], [40, 30], [80, 60], [30, 70]], float)
    np.save(folder / "calibration" / "corners.npy", np.repeat(corners[None], 9, axis=0))
    monkeypatch.setenv(msir.CACHE_ENV, str(tmp_path / "cache"))
    return folder


def test_mini_msir_tasks_have_the_rendered_disparity_and_sign(mini_msir):
    """Each task's pseudo ground truth holds the rendered background and box disparities, times
    the baseline, plus the shift; a classical matcher on the task's own VIS/NIR pair (census:
    the NIR response differs) finds them, so the turn and the sign are the project's."""
    scenes = {scene.name: scene for scene in DATASETS["msir-outdoor"](mini_msir.parent)}
    assert list(scenes) == ["cam3-cam0", "cam4-cam1", "cam5-cam2", "cam6-cam0", "cam7-cam1", "cam8-cam2"]
    for name, ratio in (("cam4-cam1", 1), ("cam7-cam1", 2)):
        scene = scenes[name]
        shift = scene.metadata["shift"]
        assert scene.metadata["baseline_mm"] == 40 * ratio
        lowest = 1 - BACKGROUND * ratio  # the shift brings the background to 1 px, or a bit more (noise)
        assert math.ceil(lowest) <= shift <= math.ceil(lowest) + 1 and np.nanmin(scene.disparity) >= 1
        assert scene.left.shape == (SHAPE[1], SHAPE[0] - shift, 3)  # turned: the baseline is vertical
        kept = scene.disparity[np.isfinite(scene.disparity)]
        background, box = shift + BACKGROUND * ratio, shift + BOX * ratio
        near_background, near_box = np.abs(kept - background) < 0.3 * ratio, np.abs(kept - box) < 0.3 * ratio
        assert np.mean(near_background | near_box) > 0.97 and near_box.mean() > 0.05 and near_background.mean() > 0.5
        result = MATCHERS["census-sgm"](scene.left[..., 0], scene.right[..., 0], max_disp=scene.max_disp, min_disp=0,
                                        preprocess="none")
        both = result.valid & scene.nonocc
        assert np.mean(np.abs(result.disparity - scene.disparity)[both] < 0.5) > 0.9


def test_mini_msir_pseudo_truth_is_cached_and_the_cache_is_never_needed(mini_msir, monkeypatch, tmp_path):
    """Built once and read back while the data is unchanged; built again once a data file
    changes; built all the same, with the same result, when the cache cannot be written."""
    built, build = [], msir.pseudo_ground_truth

    def counted(*args, **kwargs):
        built.append(1)
        return build(*args, **kwargs)

    monkeypatch.setattr(msir, "pseudo_ground_truth", counted)
    first, unit = msir.reference_truth(mini_msir, 4)
    again, _ = msir.reference_truth(mini_msir, 4)
    assert len(built) == 1 and unit == 0.04 and np.isfinite(first).mean() > 0.3
    assert len(list((tmp_path / "cache" / "msir-outdoor").glob("pseudo-gt-cam4-*.npy"))) == 1
    np.testing.assert_array_equal(again, first)
    image = mini_msir / "scene" / "Cam-3.png"
    stat = image.stat()
    os.utime(image, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # a data file changed: another key
    msir.reference_truth(mini_msir, 4)
    assert len(built) == 2
    (tmp_path / "blocked").write_text("a file where the cache folder would be")
    monkeypatch.setenv(msir.CACHE_ENV, str(tmp_path / "blocked"))
    rebuilt, _ = msir.reference_truth(mini_msir, 4)
    assert len(built) == 3
    np.testing.assert_array_equal(rebuilt, first)


def test_mini_msir_bad_layout_is_one_clear_error(mini_msir):
    np.save(mini_msir / "calibration" / "corners.npy", np.zeros((9, 8)))
    with pytest.raises(CadeError, match=r"holds shape \(9, 8\), not \(9, N, 2\)"):
        msir.msir_rig(mini_msir)
    (mini_msir / "camera_array.json").write_text('{"Camera 0": {"X": 40}}')
    np.save(mini_msir / "calibration" / "corners.npy", np.zeros((9, 8, 2)))
    with pytest.raises(CadeError, match="no complete 'Camera 0'"):
        msir.msir_rig(mini_msir)


# --- msir-outdoor: the real data (skipped without it) ------------------------------------


@pytest.fixture
def msir_folder(shared_data):
    folder = shared_data / "msir-outdoor"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    return folder


def test_msir_is_listed_and_not_downloadable(msir_folder, shared_data):
    names = DATASETS["msir-outdoor"].scene_names(shared_data)
    assert names == sorted(msir.task_name(left, right) for left, right in msir.TASKS)
    assert DATASETS["msir-outdoor"].default_protocols == ("native",)
    with pytest.raises(CadeError, match="no licence"):
        get_source("msir-outdoor").archives()


def test_msir_pair_turns_with_the_projects_sign(msir_folder):
    """A visible/visible pair framed as a task (Cam-7 left, Cam-4 above it: the turn of the
    7>1 task): a classical matcher over [0, 16] finds nearly every pixel, the parking deck
    (bottom rows) nearer than the façade and the forest (top rows) farther, and agrees with a
    pseudo ground truth from Cam-7's horizontal partners alone (an independent direction)."""
    window = (60, 560, 1140, 320)  # rows 60-1200 of a column strip: forest, façade, deck
    truth, _ = msir.reference_truth(msir_folder, 7, partners=(6, 8), window=window, cache=False)
    pair = msir.task_frame(msir_folder, 7, 4, window=window)
    assert pair.frame.exact and pair.ratio == 1.0
    turned = pair.frame.to_frame(truth)
    shift = msir.shift_for(turned)
    left, right, disparity, nonocc = msir.shifted_pair(pair, turned, shift)
    assert left.shape == right.shape == disparity.shape == (320, 1140 - shift)  # baseline vertical: turned
    assert 2 <= shift <= 8 and np.nanmin(disparity) >= msir.SHIFT_MARGIN
    assert not (nonocc & ~np.isfinite(disparity)).any()
    rows = pair.frame.to_frame(np.repeat(np.arange(window[0], 1200, dtype=np.float32)[:, None], window[3], 1))
    result = MATCHERS["sgbm"](left, right, max_disp=16, min_disp=0, preprocess="none")
    found = np.where(result.valid, result.disparity, np.nan)
    assert np.isfinite(found).mean() > 0.8
    rows = rows[:, :left.shape[1]]
    forest, deck = np.nanmedian(found[rows < 320]), np.nanmedian(found[rows > 960])
    assert deck > shift + 0.5 and forest < shift - 0.5
    both = np.isfinite(found) & np.isfinite(disparity)
    assert np.isfinite(disparity).mean() > 0.15  # coverage floor of the two-partner truth
    assert np.corrcoef(found[both], disparity[both])[0, 1] > 0.6
    assert np.median(np.abs(found - disparity)[both]) < 0.3


def test_msir_benchmark_records_name_the_dataset(msir_folder, shared_data, monkeypatch, tmp_path, capsys):
    """The wiring, with a stand-in truth (the façade plane where a band is textured): one
    native record per task, named msir-outdoor; cs is refused; the CLI's default protocol is
    native. The real pseudo ground truth is built by the dataset (docs/msir-outdoor.md)."""
    def plane(folder, reference, **_):
        band = msir.read_camera(folder, reference)
        return np.where(cv2.Laplacian(band, cv2.CV_32F) != 0, np.float32(0), np.float32(np.nan)), 0.04

    monkeypatch.setattr(msir, "reference_truth", plane)
    with pytest.raises(CadeError, match="only protocol native applies"):
        run_benchmark(dataset="msir-outdoor", data_dir=shared_data, methods=["sgbm"], protocols=["cs"],
                      preprocess=["none"])
    out = tmp_path / "r.json"
    code, _, err = run_cade(["benchmark", "--dataset", "msir-outdoor", "--data-dir", shared_data, "--methods", "sgbm",
                             "--preprocess", "none", "--scenes", "cam5-cam2", "--json", out], capsys)
    assert code == 0, err
    saved = json.loads(out.read_text())  # what benchmarks/shipping_rule.py reads
    assert saved["config"]["dataset"] == "msir-outdoor" and saved["config"]["protocols"] == ["native"]
    (record,) = saved["records"]
    assert (record["dataset"], record["scene"], record["protocol"], record["task"]) == (
        "msir-outdoor", "cam5-cam2", "native", "grey")
    assert record["resolution"] == "1199x1600" and np.isfinite(record["scores"]["epe_all"])


def test_training_validates_on_the_real_check_when_the_data_dir_holds_it(mini_msir, tmp_path):
    """fit's validation rows gain ``msir-outdoor``: each task's VIS and NIR bands as the runtime
    gives them to the network, at the size it matches them, against the task's pseudo ground truth;
    a data dir without the array gives no such set."""
    pytest.importorskip("torch")
    from cade_cli.spectral import network_input
    from cade_cli.train.validation import real_cross_spectral_set

    pairs = real_cross_spectral_set(mini_msir.parent, "cade-floor", 184)
    scenes = list(DATASETS["msir-outdoor"](mini_msir.parent))
    assert len(pairs) == len(scenes) == 6
    for (left, right, truth), scene in zip(pairs, scenes):
        assert left.shape == right.shape == scene.left.shape[:2]
        np.testing.assert_array_equal(left, network_input(scene.left[..., 0], "cade-floor"))
        np.testing.assert_array_equal(right, network_input(scene.right[..., 0], "cade-floor"))
        np.testing.assert_array_equal(truth, scene.disparity)
    (tmp_path / "empty").mkdir()
    assert real_cross_spectral_set(tmp_path / "empty", "cade-floor", 184) == []
