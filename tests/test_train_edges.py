"""The training-data levers that teach depth edges (issue 51 item 3): thin structures, floating
objects over a real background, one view changed, and the loss weight at edges. Each is off by
default and then draws no random number, so earlier runs' batches reproduce byte for byte."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from typer.testing import CliRunner  # noqa: E402

from cade_cli.errors import CadeError  # noqa: E402
from cade_cli.train import floating  # noqa: E402
from cade_cli.train.__main__ import app  # noqa: E402
from cade_cli.train.asymmetric import EFFECTS, _apply, one_view_changed  # noqa: E402
from cade_cli.train.batches import GeneratedBatches  # noqa: E402
from cade_cli.train.config import TrainConfig  # noqa: E402
from cade_cli.train.fit import edge_weights, loss_terms  # noqa: E402
from cade_cli.train.real import RealScenes  # noqa: E402
from cade_cli.train.scenes import NO_PHOTOMETRIC, render_scene  # noqa: E402
from cade_cli.train.textures import TexturePool  # noqa: E402
from synthetic import write_real_scene  # noqa: E402
from test_train_scenes import depth_edges, warp_right_to_left  # noqa: E402

BEFORE_THE_LEVERS = "a947ca984db0fb1f903c9cec6da037e6c99cc79e2058452b272bb9129592a70d"
"""SHA-256 of :func:`batches_digest`'s batches, recorded with the generator as it was before these
levers existed (2026-11-28; numpy 2.4 and OpenCV 5.0, numpy's SIMD at AVX2: :data:`NUMPY_AT_AVX2`):
a change of it means earlier runs' data no longer reproduces (or, after a library upgrade, must be
recorded again)."""

NUMPY_AT_AVX2 = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}
"""The digest depends on the CPU: numpy's AVX-512 kernels round some functions differently from its
AVX2 ones (on 2026-12-06 an AVX-512 machine made 12bc8236... of the same code and libraries, and
the recorded digest with these kernels turned off). So it is computed in a child process with numpy
held to AVX2, as the machine that recorded it ran (a CPU without AVX2 would need its own record)."""


def digest_at_avx2(folder: Path) -> str:
    """:func:`batches_digest` of the levers-off recipe on :func:`write_sources`'s sources in
    ``folder``, computed by a child Python with :data:`NUMPY_AT_AVX2` (set before numpy loads)."""
    code = ("import sys; from pathlib import Path; sys.path[:0] = sys.argv[1:3]\n"
            "from test_train_edges import batches_digest, recipe, write_sources\n"
            "folder = Path(sys.argv[3]); print(batches_digest(recipe(folder, *write_sources(folder, smooth=False))))")
    tests = Path(__file__).parent
    done = subprocess.run([sys.executable, "-c", code, str(tests), str(tests.parent), str(folder)],
                          env={**os.environ, **NUMPY_AT_AVX2}, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.split()[-1]


def write_sources(folder: Path, *, smooth: bool) -> tuple[Path, Path]:
    """A folder with one texture photo (pixel noise, or blurred like a photo's detail: bilinear
    resampling at the two views' sub-pixel phases then agrees) and a folder with one real scene
    (MiddEval3 layout)."""
    write_real_scene(folder / "real" / "scene", np.random.default_rng(3), shift=5)
    (folder / "tex").mkdir()
    photo = np.random.default_rng(4).integers(0, 256, (90, 120, 3), dtype=np.uint8)
    if smooth:
        photo = cv2.normalize(cv2.GaussianBlur(photo.astype(np.float32), (0, 0), 2.0), None, 0, 255,
                              cv2.NORM_MINMAX).astype(np.uint8)
    cv2.imwrite(str(folder / "tex" / "photo.png"), photo)
    return folder / "tex", folder / "real"


@pytest.fixture
def sources(tmp_path) -> tuple[Path, Path]:
    """The sources the batches of :data:`BEFORE_THE_LEVERS` were drawn from."""
    return write_sources(tmp_path, smooth=False)


@pytest.fixture
def smooth_sources(tmp_path) -> tuple[Path, Path]:
    return write_sources(tmp_path, smooth=True)


def batches_digest(config: TrainConfig, steps: int = 4) -> str:
    digest = hashlib.sha256()
    for step in range(steps):
        batch = GeneratedBatches(config)[step]
        for key in sorted(batch):
            digest.update(key.encode())
            digest.update(batch[key].numpy().tobytes())
    return digest.hexdigest()


def recipe(tmp_path: Path, textures: Path, real: Path, **levers) -> TrainConfig:
    """The bake-off's data recipe (every earlier lever on) at a tiny size."""
    return TrainConfig(out=str(tmp_path / "run"), textures=[str(textures)], steps=4, batch=3, height=64, width=96,
                       levels=32, seed=51, real_dir=str(real), real_share=0.3, misaligned=0.3, ground=0.3,
                       shadows=0.3, eraser=0.3, scene_range=0.5, network_input="cade-floor", **levers)


def test_levers_off_reproduce_the_batches_of_before(tmp_path, sources):
    """Every lever at 0 (explicitly or by default): the batches are byte-identical to those the
    generator made before the levers existed; each lever on changes them (it is wired in)."""
    assert digest_at_avx2(tmp_path / "child") == BEFORE_THE_LEVERS
    off = recipe(tmp_path, *sources)
    assert batches_digest(replace(off, thin=0.0, floating=0.0, asymmetric=0.0, edge_weight=0.0)) == batches_digest(off)
    for lever in ("thin", "floating", "asymmetric"):
        assert batches_digest(replace(off, **{lever: 0.5}), steps=2) != batches_digest(off, steps=2), lever


def test_loss_without_edge_weight_is_the_plain_mean_as_before():
    rng = np.random.default_rng(0)
    target = torch.from_numpy(rng.uniform(-2, 20, (2, 1, 24, 32)).astype(np.float32))
    out = {key: target + torch.from_numpy(rng.normal(0, 2, target.shape).astype(np.float32))
           for key in ("disparity", "coarse")}
    loss, mask = loss_terms(out, target, 16, 0.5)
    expected = sum(weight * torch.nn.functional.smooth_l1_loss(out[key][mask], target[mask])
                   for key, weight in (("disparity", 1.0), ("coarse", 0.5)))
    assert torch.equal(loss, expected)


def warp_check(scene) -> tuple[np.ndarray, np.ndarray]:
    """The right view warped by the GT against the left (max over channels), and the pixels
    where they must agree (non-occluded, off depth edges and off occlusion borders), checked."""
    error = np.abs(warp_right_to_left(scene.right, scene.disparity) - scene.left).max(axis=2)
    checked = scene.nonoccluded & ~depth_edges(scene.disparity) & ~depth_edges(
        np.where(scene.nonoccluded, 0.0, 1.0).astype(np.float32))
    assert checked.mean() > 0.2
    assert np.median(error[checked]) < 0.01 and (error[checked] < 0.05).mean() > 0.95
    return error, checked


def thin_pixels(seed: int, **levers):
    """A scene without and with thin structures (the same draws up to them: they come last)."""
    def scene(thin: float):
        return render_scene(np.random.default_rng(seed), 96, 160, limit=48, textures=TexturePool(),
                            photometric=NO_PHOTOMETRIC, thin=thin, **levers)
    return scene(0.0), scene(1.0)


@pytest.mark.parametrize("seed", range(4))
def test_thin_structures_stand_in_front_in_the_ground_truth(seed):
    """The pixels thin structures take are a few px wide (a 7x7 erosion leaves almost none of them)
    and nearer than what they hide; both views agree where the ground truth says."""
    without, scene = thin_pixels(seed)
    taken = scene.disparity != without.disparity
    assert taken.mean() > 0.005
    wide = cv2.erode(taken.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    assert wide.sum() < 0.05 * taken.sum()  # crossings and overlaps only
    jump = (scene.disparity - without.disparity)[taken]
    assert (jump > 0).all() and np.median(jump) > 2.0
    error, checked = warp_check(scene)
    # the thin structures themselves: their visible pixels, warped by their own disparity
    inner = taken & scene.nonoccluded & ~depth_edges(np.where(taken, 0.0, 1.0).astype(np.float32), radius=0)
    assert inner.sum() > 100 and np.median(error[inner]) < 0.01


def test_thin_off_draws_nothing():
    rng = np.random.default_rng(5)
    render_scene(rng, 48, 64, limit=20, textures=TexturePool(), thin=0.0)
    after = rng.random()
    rng = np.random.default_rng(5)
    render_scene(rng, 48, 64, limit=20, textures=TexturePool())
    assert rng.random() == after


def is_real_image(image: np.ndarray, textures: Path, scenes: RealScenes) -> bool:
    """``image`` is the real scene's left view, or the texture photo or a crop of it."""
    if image.shape == scenes.scenes[0].left.shape and np.array_equal(image, scenes.scenes[0].left):
        return True
    photo = np.ascontiguousarray(cv2.imread(str(textures / "photo.png"))[..., ::-1]).astype(np.float32) / 255.0
    rows, cols = image.shape[:2]
    if rows > photo.shape[0] or cols > photo.shape[1]:
        return False
    top, left = np.unravel_index(np.argmin(cv2.matchTemplate(photo, np.ascontiguousarray(image), cv2.TM_SQDIFF)),
                                 (photo.shape[0] - rows + 1, photo.shape[1] - cols + 1))
    return np.array_equal(photo[top:top + rows, left:left + cols], image)


@pytest.mark.parametrize("seed", range(3))
def test_floating_objects_over_a_real_background_have_exact_ground_truth(seed, smooth_sources, monkeypatch):
    """10-40 objects in front of a photo or a real scene's left view (on a plane of its own); the
    right view warped by the ground truth reproduces the left where both see the surface."""
    textures, real = smooth_sources
    layers_drawn = []

    def recording(rng, layers, **kwargs):
        layers_drawn.append(layers)
        return render_layers(rng, layers, **kwargs)

    render_layers = floating.render_layers
    monkeypatch.setattr(floating, "render_layers", recording)
    pool, scenes = TexturePool([textures]), RealScenes(real)
    scene = floating.render_floating(np.random.default_rng(seed), 96, 160, limit=40, textures=pool, real=scenes,
                                     photometric=NO_PHOTOMETRIC)
    layers = layers_drawn[-1]
    assert 11 <= len(layers) <= 41 and layers[0].shape is None
    assert is_real_image(layers[0].texture, textures, scenes)
    assert np.isfinite(scene.disparity).all() and 0 <= scene.disparity.min() and scene.disparity.max() < 40
    error, checked = warp_check(scene)
    unshifted = np.abs(scene.right - scene.left).max(axis=2)
    assert (unshifted[checked] < 0.05).mean() < 0.9


def test_floating_backgrounds_come_from_photos_and_real_scenes(sources):
    textures, real = sources
    pool, scenes = TexturePool([textures]), RealScenes(real)
    drawn = [floating.real_background(np.random.default_rng(i), pool, scenes) for i in range(12)]
    from_real = [np.array_equal(image, scenes.scenes[0].left) for image in drawn]
    assert any(from_real) and not all(from_real)
    assert all(is_real_image(image, textures, scenes) for image in drawn)
    with pytest.raises(CadeError, match="real background"):
        floating.real_background(np.random.default_rng(0), TexturePool(), None)


@pytest.mark.parametrize("seed", range(4))
def test_one_view_changed_leaves_the_other_and_the_ground_truth(seed):
    scene = render_scene(np.random.default_rng(seed), 64, 96, limit=20, textures=TexturePool())
    changed = one_view_changed(scene, np.random.default_rng(seed), 1.0)
    left_same, right_same = np.array_equal(changed.left, scene.left), np.array_equal(changed.right, scene.right)
    assert left_same != right_same  # exactly one view changed
    assert changed.disparity is scene.disparity and changed.nonoccluded is scene.nonoccluded
    image = changed.right if left_same else changed.left
    assert image.dtype == np.float32 and image.shape == scene.left.shape and 0 <= image.min() and image.max() <= 1


def test_one_view_changed_picks_either_view_and_draws_nothing_when_off():
    scene = render_scene(np.random.default_rng(0), 48, 64, limit=20, textures=TexturePool())
    which = {np.array_equal(one_view_changed(scene, np.random.default_rng(i), 1.0).left, scene.left)
             for i in range(12)}
    assert which == {True, False}
    rng = np.random.default_rng(1)
    assert one_view_changed(scene, rng, 0.0) is scene
    assert rng.random() == np.random.default_rng(1).random()


@pytest.mark.parametrize("effect", EFFECTS)
def test_every_effect_changes_a_view_and_keeps_it_in_range(effect):
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.random((48, 64, 3)).astype(np.float32), (0, 0), 1.5)
    out = np.clip(_apply(effect, image, rng), 0, 1)
    assert out.shape == image.shape and np.abs(out - image).mean() > 1e-3


def test_edge_weights_are_one_plus_w_near_a_jump_and_one_elsewhere():
    """A 5 px step between columns 19 and 20 is an edge; a 1.5 px step between rows 9 and 10 is not,
    nor is the border of the unknown (NaN) corner."""
    target = np.full((1, 1, 24, 40), 10.0, np.float32)
    target[..., 20:] = 15.0
    target[..., 10:, :] += 1.5
    target[..., :4, 34:] = np.nan
    target = torch.from_numpy(target)
    valid = torch.isfinite(target)
    weights = edge_weights(target, valid, 3.0)[0, 0].numpy()
    columns = np.arange(40)[None, :].repeat(24, 0)
    near = (columns >= 16) & (columns <= 23)  # within 3 px of column 19 or 20
    assert np.array_equal(weights[near], np.full(near.sum(), 4.0, np.float32))
    assert np.array_equal(weights[~near], np.ones((~near).sum(), np.float32))


@pytest.mark.parametrize("seed", range(2))
def test_edge_weights_weigh_up_the_benchmarks_edge_region(seed):
    """On a rendered scene's ground truth (some of it unknown) the weighed-up pixels with ground truth
    are exactly those the benchmark scores as edge pixels (:mod:`cade_cli.evaluation.regions`) where
    it has no occlusion information."""
    from cade_cli.evaluation.regions import region_masks

    scene = render_scene(np.random.default_rng(seed), 64, 96, limit=30, textures=TexturePool(), thin=1.0)
    truth = scene.disparity.copy()
    truth[:10, :20] = np.nan
    target = torch.from_numpy(truth)[None, None]
    weights = edge_weights(target, torch.isfinite(target), 0.5)[0, 0].numpy()
    edge = region_masks(truth, nonocc=None)["edge"]  # no occlusion information: every pixel with GT
    assert edge.any() and np.array_equal((weights > 1) & np.isfinite(truth), edge)


def test_an_error_at_an_edge_costs_more_with_edge_weight_and_one_elsewhere_less():
    target = torch.full((1, 1, 32, 48), 8.0)
    target[..., 24:] = 20.0
    columns = torch.arange(48)
    at_edge, far = (columns >= 22) & (columns <= 25), (columns <= 5)

    def loss(error_columns, weight):
        estimate = target + 4.0 * error_columns.float()
        return float(loss_terms({"disparity": estimate, "coarse": estimate}, target, 32, 0.5, weight)[0])

    assert loss(at_edge, 2.0) > loss(at_edge, 0.0) > 0
    assert 0 < loss(far, 2.0) < loss(far, 0.0)


def test_preview_draws_every_lever_and_fit_refuses_floating_without_a_background(tmp_path, sources):
    textures, real = sources
    runner = CliRunner()
    picture = tmp_path / "levers.png"
    result = runner.invoke(app, ["preview", "-o", str(picture), "--textures", str(textures), "--real-dir", str(real),
                                 "--count", "1", "--height", "48", "--width", "64"])
    assert result.exit_code == 0, result.output
    image = cv2.imread(str(picture))
    assert image.shape == (4 * 48 + 3 * 2, 4 * 64 + 3 * 2, 3)
    result = runner.invoke(app, ["preview", "-o", str(tmp_path / "x.jpg")])
    assert result.exit_code != 0 and not (tmp_path / "x.jpg").exists()
    result = runner.invoke(app, ["fit", "--out", str(tmp_path / "run"), "--floating", "0.5"])
    assert result.exit_code != 0 and "--floating" in result.output and not (tmp_path / "run").exists()
