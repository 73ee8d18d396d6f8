"""The training-data generator's ground truth is exact (no torch needed)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cade_cli import spectral
from cade_cli.errors import CadeError
from cade_cli.train import pairs
from cade_cli.train.pairs import cade_pair
from cade_cli.train.scenes import (NO_MISALIGNMENT, NO_PHOTOMETRIC, Misalignment, Photometric, render_scene,
                                   textured_surface)
from cade_cli.train.shapes import random_shape
from cade_cli.train.textures import TexturePool, procedural_texture
from synthetic import write_real_scene


def warp_right_to_left(right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    height, width = disparity.shape
    rows, columns = np.mgrid[0:height, 0:width].astype(np.float32)
    return cv2.remap(right, columns - disparity, rows, cv2.INTER_LINEAR)


def depth_edges(disparity: np.ndarray, radius: int = 2) -> np.ndarray:
    """Pixels within ``radius`` of a disparity jump (> 0.5 px between neighbours)."""
    jump = np.zeros(disparity.shape, bool)
    jump[:, 1:] |= np.abs(np.diff(disparity, axis=1)) > 0.5
    jump[1:, :] |= np.abs(np.diff(disparity, axis=0)) > 0.5
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(jump.astype(np.uint8), kernel).astype(bool)


@pytest.mark.parametrize("seed", range(6))
def test_warping_right_with_ground_truth_reproduces_left(seed):
    scene = render_scene(np.random.default_rng(seed), 96, 160, limit=48, textures=TexturePool(),
                         photometric=NO_PHOTOMETRIC)
    warped = warp_right_to_left(scene.right, scene.disparity)
    error = np.abs(warped - scene.left).max(axis=2)
    # Object outlines are aliased (hard masks), so their rims differ by up to a pixel; and
    # stripes of a 3-4 px period, resampled bilinearly at other sub-pixel phases, differ a little.
    checked = scene.nonoccluded & ~depth_edges(scene.disparity) & ~depth_edges(
        np.where(scene.nonoccluded, 0.0, 1.0).astype(np.float32))
    assert checked.mean() > 0.3
    assert np.median(error[checked]) < 0.01
    assert (error[checked] < 0.05).mean() > 0.95
    # The check has teeth: the same warp without the disparity does not reproduce it.
    unshifted = np.abs(scene.right - scene.left).max(axis=2)
    assert (unshifted[checked] < 0.05).mean() < 0.9


def best_row_offset(scene, offsets: np.ndarray) -> tuple[float, np.ndarray]:
    """The vertical offset o for which right(x - d, y - o) best reproduces left(x, y)."""
    height, width = scene.disparity.shape
    rows, columns = np.mgrid[0:height, 0:width].astype(np.float32)
    checked = scene.nonoccluded & ~depth_edges(scene.disparity, radius=3)
    checked[:3], checked[-3:] = False, False
    errors = np.array([np.median(np.abs(cv2.remap(scene.right, columns - scene.disparity, rows - np.float32(o),
                                                  cv2.INTER_LINEAR)
                                        - scene.left).max(axis=2)[checked]) for o in offsets])
    return float(offsets[np.argmin(errors)]), errors


@pytest.mark.parametrize("seed", range(3))
def test_misaligned_right_view_is_offset_rows_of_an_exact_pair(seed):
    """Misalignment moves the right view's rows only: the left view and its disparity stay
    exact, and warping with the disparity and the drawn row offset reproduces the left."""
    args = dict(limit=48, textures=TexturePool(), photometric=NO_PHOTOMETRIC)
    rectified = render_scene(np.random.default_rng(seed), 96, 160, **args)
    misaligned = render_scene(np.random.default_rng(seed), 96, 160, **args,
                              misalignment=Misalignment(share=1.0, offset=1.0, roll=0.0, zoom=0.0))
    assert np.array_equal(rectified.left, misaligned.left)
    assert np.array_equal(rectified.disparity, misaligned.disparity)
    offsets = np.round(np.arange(-1.0, 1.0001, 0.05), 2)
    assert best_row_offset(rectified, offsets)[0] == 0.0
    offset, errors = best_row_offset(misaligned, offsets)
    assert abs(offset) >= 0.3  # these seeds draw offsets of 0.35 .. 0.8 px
    assert errors.min() < 0.01  # as exact as a rectified pair at its own offset ...
    assert errors[offsets == 0.0][0] > 3 * errors.min()  # ... and clearly worse without it


def test_misalignment_rows_follow_offset_roll_and_zoom():
    y, x = np.mgrid[0:50, 0:80].astype(np.float32)
    rows = Misalignment(share=1.0, offset=1.0, roll=0.01, zoom=0.01).rows(np.random.default_rng(0), x, y)
    shift = rows - y
    assert 0 < np.abs(shift).max() <= 1.0 + 0.01 * 40 + 0.01 * 25 + 1e-5
    # An affine field: constant steps along columns and along rows.
    assert np.allclose(np.diff(shift, axis=1), np.diff(shift, axis=1)[0, 0], atol=1e-5)
    assert np.allclose(np.diff(shift, axis=0), np.diff(shift, axis=0)[0, 0], atol=1e-5)


def test_misalignment_off_draws_nothing_and_changes_nothing():
    """share=0 (the default) leaves the random stream, so earlier runs' scenes, unchanged."""
    y, x = np.mgrid[0:8, 0:8].astype(np.float32)
    rng, untouched = np.random.default_rng(5), np.random.default_rng(5)
    assert Misalignment(share=0.0, offset=5.0).rows(rng, x, y) is y
    assert rng.random() == untouched.random()
    a = render_scene(np.random.default_rng(2), 64, 96, limit=32, textures=TexturePool())
    b = render_scene(np.random.default_rng(2), 64, 96, limit=32, textures=TexturePool(),
                     misalignment=NO_MISALIGNMENT)
    assert np.array_equal(a.right, b.right)


def test_occluded_pixels_are_not_seen_by_the_right_view():
    scene = render_scene(np.random.default_rng(3), 96, 160, limit=48, textures=TexturePool(),
                         photometric=NO_PHOTOMETRIC)
    occluded = ~scene.nonoccluded & ~depth_edges(scene.disparity)
    assert occluded.any()
    error = np.abs(warp_right_to_left(scene.right, scene.disparity) - scene.left).max(axis=2)
    # The right view shows another surface there, so the warp mostly disagrees.
    assert np.median(error[occluded]) > np.median(error[scene.nonoccluded & ~depth_edges(scene.disparity)])


@pytest.mark.parametrize("seed", range(4))
def test_disparities_cover_the_range_and_stay_inside_it(seed):
    rng = np.random.default_rng(seed)
    values = np.concatenate([render_scene(rng, 64, 128, limit=40, textures=TexturePool()).disparity.ravel()
                             for _ in range(5)])
    assert values.min() >= 0 and values.max() < 40
    assert values.max() - values.min() > 10


def test_same_seed_same_scene_and_views_differ_photometrically():
    a = render_scene(np.random.default_rng(7), 64, 96, limit=32, textures=TexturePool())
    b = render_scene(np.random.default_rng(7), 64, 96, limit=32, textures=TexturePool())
    assert np.array_equal(a.left, b.left) and np.array_equal(a.disparity, b.disparity)
    assert a.left.dtype == np.float32 and a.left.shape == (64, 96, 3)
    assert 0.0 <= a.left.min() and a.left.max() <= 1.0


@pytest.mark.parametrize("share", [0.0, 1.0])
def test_views_are_stored_with_8_bits_as_camera_images_are(share):
    """With ``quantized_share`` 1 every view holds only 8-bit levels; with 0 the same noisy
    camera keeps its float values (the check can fail both ways)."""
    camera = Photometric(noise_sigma=(0.01, 0.02), quantized_share=share)
    scene = render_scene(np.random.default_rng(5), 48, 64, limit=16, textures=TexturePool(), photometric=camera)
    for view in (scene.left, scene.right):
        on_levels = np.abs(view * 255 - np.rint(view * 255)) < 1e-3
        assert on_levels.all() if share == 1.0 else on_levels.mean() < 0.1


def test_some_surfaces_are_dark_or_nearly_textureless():
    """Real scenes have black cloth, shadows and blank walls: about a tenth of the surfaces
    are dark (brightest value <= 0.1) and about a tenth have little contrast (each channel
    spans <= 0.15)."""
    rng = np.random.default_rng(0)
    textures = [textured_surface(rng, TexturePool(), 64, 64)[0] for _ in range(300)]
    dark = np.mean([texture.max() <= 0.1 for texture in textures])
    flat = np.mean([texture.max() > 0.1 and np.ptp(texture, axis=(0, 1)).max() <= 0.15 for texture in textures])
    assert 0.05 < dark < 0.15 and 0.05 < flat < 0.2


def test_texture_pool_reads_image_folders(tmp_path: Path):
    image = (np.random.default_rng(0).random((40, 50, 3)) * 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "t.png"), image)
    pool = TexturePool([tmp_path], procedural_share=0.0)
    texture = pool.draw(np.random.default_rng(0))
    assert texture.dtype == np.float32 and texture.ndim == 3 and texture.max() <= 1.0
    with pytest.raises(CadeError, match="not found"):
        TexturePool([tmp_path / "missing"])


@pytest.mark.parametrize("seed", range(10))
def test_procedural_textures_are_rgb_in_unit_range(seed):
    texture = procedural_texture(np.random.default_rng(seed), 64)
    assert texture.shape == (64, 64, 3) and texture.dtype == np.float32
    assert 0.0 <= texture.min() and texture.max() <= 1.0


def test_cade_pairs_use_the_runtime_transform_and_band_synthesis():
    assert pairs.network_input is spectral.network_input
    assert pairs.synthesize_bands is spectral.synthesize_bands
    scene = render_scene(np.random.default_rng(1), 64, 96, limit=32, textures=TexturePool())
    pair = cade_pair(scene, np.random.default_rng(2))
    assert set(pair.bands) <= set(spectral.BAND_NAMES)
    # Recompute: same seed draw, same bands, same transform.
    rng = np.random.default_rng(2)
    seed = int(rng.integers(2**63))
    left_name, right_name = pair.bands
    expected = spectral.color_agnostic(spectral.synthesize_bands(scene.left, np.random.default_rng(seed))[left_name])
    np.testing.assert_array_equal(pair.left, expected)
    assert pair.left.dtype == np.float32 and 0.0 <= pair.right.min() and pair.right.max() <= 1.0


def test_cade_pairs_draw_left_and_right_bands_independently():
    scene = render_scene(np.random.default_rng(1), 32, 48, limit=16, textures=TexturePool())
    drawn = [cade_pair(scene, np.random.default_rng(i)).bands for i in range(60)]
    assert len({left for left, _ in drawn}) > 5 and len({right for _, right in drawn}) > 5
    assert sum(left != right for left, right in drawn) > 40


def test_shapes_include_thin_structures_and_holes():
    """Real scenes have stems, cables and fences, not only blobs: among many outlines some are
    mostly thinner than 5 px (an opening with a 5x5 square removes most of them) and some
    have holes (pixels outside the shape enclosed by it)."""
    y, x = np.mgrid[0:192, 0:320].astype(np.float32)
    rng = np.random.default_rng(0)
    thin = holed = 0
    for _ in range(200):
        mask = random_shape(rng, 192, 320)(x, y).astype(np.uint8)
        if mask.sum() < 50 or mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any():
            continue
        opened = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
        thin += opened.sum() < 0.5 * mask.sum()
        outside = 1 - mask
        count, _ = cv2.connectedComponents(outside, connectivity=4)
        holed += count > 2  # the background plus at least one enclosed hole
    assert thin >= 10 and holed >= 2


def test_an_outline_evaluated_in_its_box_is_the_outline_evaluated_everywhere():
    """The renderer evaluates an outline only in the box of the grid its reach bound allows
    (shapes.within); evaluated point by point (1-D, no box) it must give the same mask, on
    the left view's grid and on a right view's sheared, misaligned one, for every kind of
    outline, including those that reach past the view's edge."""
    y, x = np.mgrid[0:96, 0:160].astype(np.float32)
    sheared = (x + 7.5 + 0.2 * y) / 0.9
    rows = y + 0.6 * np.sin(x / 23.0)
    rng = np.random.default_rng(4)
    covered = 0
    for _ in range(300):
        shape = random_shape(rng, 96, 160)
        for grid_x, grid_y in ((x, y), (sheared, rows)):
            boxed = shape(grid_x, grid_y)
            everywhere = shape(grid_x.ravel(), grid_y.ravel()).reshape(grid_x.shape)
            np.testing.assert_array_equal(boxed, everywhere)
            covered += bool(everywhere.any()) and not everywhere.all()
    assert covered > 300  # most outlines show, and none covers everything


def test_real_scenes_are_cropped_zoomed_and_flipped_with_their_ground_truth(tmp_path):
    """A real scene in the MiddEval3 layout (a texture shifted by 5 px) comes out at the
    training size with its disparity scaled by the zoom, and the right view warped by it
    reproduces the left view (rows flipped or not)."""
    import cv2

    from cade_cli.train.real import RealScenes

    rng = np.random.default_rng(0)
    write_real_scene(tmp_path / "scene", rng, shift=5)
    pool = RealScenes(tmp_path, zoom=(0.8, 1.6))
    zooms = set()
    for _ in range(6):
        scene = pool.draw(rng, 64, 128, limit=40, photometric=NO_PHOTOMETRIC)
        assert scene.left.shape == (64, 128, 3) and scene.disparity.shape == (64, 128)
        zoom = float(np.nanmedian(scene.disparity)) / 5.0
        zooms.add(round(zoom, 2))
        assert 0.8 <= zoom <= 1.6 and np.allclose(scene.disparity, 5.0 * zoom, atol=0.05)
        columns = (np.arange(128)[None, :] - scene.disparity).astype(np.float32)
        rows = np.repeat(np.arange(64, dtype=np.float32)[:, None], 128, axis=1)
        warped = cv2.remap(scene.right, columns, rows, cv2.INTER_LINEAR)
        inside = columns > 1
        assert np.abs(warped - scene.left)[inside].mean() < 0.02
    assert len(zooms) > 1
    with pytest.raises(Exception, match="no real training scenes|no middeval3 scenes"):
        RealScenes(tmp_path / "scene")


def test_held_out_real_scenes_are_never_drawn(tmp_path):
    """Two real scenes (disparity 3 and 7 px at zoom 1): with the 7 px one held out every draw
    comes from the other; a name the folder lacks, or holding out every scene, is an error."""
    from cade_cli.train.real import RealScenes

    rng = np.random.default_rng(1)
    write_real_scene(tmp_path / "near", rng, shift=3)
    write_real_scene(tmp_path / "far", rng, shift=7)
    both, kept = RealScenes(tmp_path, zoom=(1.0, 1.0)), RealScenes(tmp_path, zoom=(1.0, 1.0), hold_out=["far"])
    assert [scene.name for scene in kept.scenes] == ["near"] and len(both.scenes) == 2

    def drawn(pool: RealScenes) -> set[int]:
        draws = (pool.draw(rng, 64, 128, limit=40, photometric=NO_PHOTOMETRIC) for _ in range(12))
        return {round(float(np.nanmedian(scene.disparity))) for scene in draws}

    assert drawn(both) == {3, 7} and drawn(kept) == {3}
    with pytest.raises(CadeError, match="not in .*: nowhere"):
        RealScenes(tmp_path, hold_out=["near", "nowhere"])
    with pytest.raises(CadeError, match="all held out"):
        RealScenes(tmp_path, hold_out=["near", "far"])


def test_learning_curves_chain_runs_by_their_init_and_draw_one_picture(tmp_path):
    """Each run is drawn from the step its ancestors ended at; the PNG is written."""
    import json

    from cade_cli.train.curves import plot, read_run

    runs = {}
    for name, init, steps in (("a", None, 100), ("b", "a", 50)):
        folder = tmp_path / name
        folder.mkdir()
        config = {"steps": steps, "init": str(tmp_path / init / "last.pt") if init else None}
        (folder / "config.json").write_text(json.dumps(config))
        (folder / "log.csv").write_text(
            "step,elapsed_s,lr,loss,train_epe,set,val_epe,val_bad3\n"
            f"50,1,,,,middlebury05-cs,3.5,30\n{steps},2,,,,middlebury05-cs,3.0,25\n{steps},2,,,,synthetic,9,40\n")
        runs[name] = read_run(folder, runs)
    assert [p[0] for p in runs["a"].points["middlebury05-cs"]] == [50, 100]
    assert [p[0] for p in runs["b"].points["middlebury05-cs"]] == [150, 150]
    assert "synthetic" not in runs["b"].points
    assert runs["a"].points["middlebury05-cs"][0][3] is None  # a log from before the cpu_s column
    folder = tmp_path / "c"
    folder.mkdir()
    (folder / "config.json").write_text(json.dumps({"steps": 100, "init": None}))
    (folder / "log.csv").write_text("step,elapsed_s,lr,loss,train_epe,set,val_epe,val_bad3,cpu_s\n"
                                    "100,9,,,,middlebury14Q-rgb,2.0,12,7200\n")
    runs["c"] = read_run(folder, runs)
    assert runs["c"].points["middlebury14Q-rgb"] == [(100, 2.0, 12.0, 2.0)]  # CPU-hours
    # a run stopped at step 60 of its 1,000 hands step 60 and its CPU-hours on to its child
    for name, init, log in (("d", "c", "60,9,1e-3,1,1,train,,,3600\n"), ("e", "d", "40,9,,,,middlebury05-cs,3,20,1800\n")):
        folder = tmp_path / name
        folder.mkdir()
        (folder / "config.json").write_text(json.dumps({"steps": 1000, "init": str(tmp_path / init / "last.pt")}))
        (folder / "log.csv").write_text("step,elapsed_s,lr,loss,train_epe,set,val_epe,val_bad3,cpu_s\n" + log)
        runs[name] = read_run(folder, runs)
    assert (runs["d"].start, runs["d"].steps, runs["d"].cpu_hours) == (100, 60, 3.0)
    assert runs["e"].points["middlebury05-cs"] == [(200, 3.0, 20.0, 3.5)]
    pytest.importorskip("matplotlib")
    plot(list(runs.values()), tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 10_000


def test_the_eraser_paints_the_right_view_and_unmarks_the_pixels_that_matched_there():
    from cade_cli.train.scenes import StereoScene, erased

    rng = np.random.default_rng(0)
    height, width = 120, 160
    disparity = np.full((height, width), 10.0, np.float32)
    scene = StereoScene(rng.random((height, width, 3), dtype=np.float32), rng.random((height, width, 3), dtype=np.float32),
                        disparity, np.ones((height, width), bool))
    assert erased(scene, rng, 0.0) is scene
    out = erased(scene, np.random.default_rng(1), 1.0)
    painted = np.any(out.right != scene.right, axis=2)
    assert 400 <= painted.sum() <= 2 * 100 * 100
    assert np.allclose(out.right[painted], scene.right.reshape(-1, 3).mean(axis=0), atol=1e-6)  # the mean colour
    matched_painted = np.zeros_like(painted)
    matched_painted[:, 10:] = painted[:, :-10]  # left (y, x) matches right (y, x - 10)
    np.testing.assert_array_equal(out.nonoccluded, ~matched_painted)
    np.testing.assert_array_equal(out.left, scene.left)
    np.testing.assert_array_equal(out.disparity, scene.disparity)


def test_ground_off_draws_nothing_and_changes_nothing():
    a = render_scene(np.random.default_rng(4), 64, 96, limit=32, textures=TexturePool())
    b = render_scene(np.random.default_rng(4), 64, 96, limit=32, textures=TexturePool(), ground=0.0)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.disparity, b.disparity)


@pytest.mark.parametrize("seed", range(4))
def test_a_ground_rises_from_its_horizon_to_the_bottom_and_its_views_agree(seed):
    """With ground=1 every scene has a ground layer: where it shows (no object in front), the
    disparity grows down each column, reaches more than 40 % of the limit at the bottom, stays
    inside [0, limit); and warping the right view by the ground truth reproduces the left there."""
    from cade_cli.train.scenes import ground_layer

    height, width, limit = 96, 160, 48.0
    layer = ground_layer(np.random.default_rng(seed), height, width, near=2.0, limit=limit, textures=TexturePool())
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    covered, d = layer.covers(x, y), layer.disparity(x, y)
    assert covered[-1].all() and not covered[0].any()  # below a horizon 10-60 % down the view
    assert (np.diff(np.where(covered, d, np.nan), axis=0)[covered[1:] & covered[:-1]] > 0).all()
    assert 0.4 * limit - 1e-3 <= d[-1].max() < limit and d[covered].min() >= 2.0 - 1e-3
    scene = render_scene(np.random.default_rng(seed), height, width, limit=limit, textures=TexturePool(),
                         photometric=NO_PHOTOMETRIC, objects=(0, 1), ground=1.0)
    bottom = scene.disparity[-4:]
    assert bottom.mean() > scene.disparity[:4].mean() + 2.0  # near at the bottom, far at the top
    assert scene.disparity.max() < limit
    warped = warp_right_to_left(scene.right, scene.disparity)
    error = np.abs(warped - scene.left).max(axis=2)
    checked = scene.nonoccluded & ~depth_edges(scene.disparity)
    checked[: height // 2] = False  # the ground's part of the view
    assert checked.mean() > 0.2
    assert np.median(error[checked]) < 0.01


@pytest.mark.parametrize("seed", range(6))
def test_a_cast_shadow_darkens_part_of_a_surface_and_leaves_the_rest_lit(seed):
    from cade_cli.train.scenes import cast_shadow

    texture = np.random.default_rng(100 + seed).uniform(0.4, 0.9, (120, 160, 3)).astype(np.float32)
    shaded = cast_shadow(np.random.default_rng(seed), texture)
    assert shaded.shape == texture.shape and shaded.dtype == np.float32
    factors = shaded / texture
    assert np.allclose(factors, factors[..., :1], atol=1e-5)  # one factor per pixel, for all channels
    ratio = factors[..., 0]
    assert (ratio <= 1 + 1e-5).all() and ratio.min() >= 0.03 - 1e-5
    assert 0.1 < (ratio < 0.5).mean() < 0.8  # part of the surface in shade (20-70 %, less a soft edge)
    assert (ratio > 0.9).mean() > 0.15  # and part of it in (nearly) full light


@pytest.mark.parametrize("seed", range(3))
def test_a_shadow_lies_on_the_surface_so_both_views_see_it_where_the_ground_truth_says(seed):
    """With every surface shadowed the views still warp onto each other by the ground truth,
    and there are dark patches to see: the shade is part of the texture, not of one view."""
    scene = render_scene(np.random.default_rng(seed), 96, 160, limit=48, textures=TexturePool(),
                         photometric=NO_PHOTOMETRIC, shadows=1.0, objects=(0, 2))
    plain = render_scene(np.random.default_rng(seed), 96, 160, limit=48, textures=TexturePool(),
                         photometric=NO_PHOTOMETRIC, objects=(0, 2))
    assert scene.left.mean() < 0.9 * plain.left.mean()  # the shadowed scene is darker
    warped = warp_right_to_left(scene.right, scene.disparity)
    error = np.abs(warped - scene.left).max(axis=2)
    checked = scene.nonoccluded & ~depth_edges(scene.disparity)
    assert checked.mean() > 0.3
    assert np.median(error[checked]) < 0.01 and (error[checked] < 0.05).mean() > 0.95


def test_the_z_buffer_textures_each_layer_only_where_it_shows_with_the_values_of_a_whole_view():
    from cade_cli.train.scenes import Layer, _composite

    rng = np.random.default_rng(3)
    height, width = 40, 64
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    texture = rng.random((50, 70, 3)).astype(np.float32)
    mapping = np.array([[0.9, -0.2, 3.0], [0.2, 0.9, 5.0]])
    layers = [Layer((5.0, 0.0, 0.0), None, texture, mapping),
              Layer((12.0, 0.01, 0.0), lambda u, v: (u - 20) ** 2 + (v - 15) ** 2 < 80, texture[::-1].copy(), mapping),
              Layer((9.0, 0.0, 0.02), lambda u, v: (u > 40) & (v > 25), texture[:, ::-1].copy(), mapping)]
    columns = [x + layer.plane[0] * 0.1 for layer in layers]  # each layer sampled at its own columns
    image, best, index = _composite(layers, columns, y)
    assert set(np.unique(index)) == {0, 1, 2}
    expected = np.stack([layer.colour(column, y) for layer, column in zip(layers, columns)])[index, y.astype(int),
                                                                                         x.astype(int)]
    assert np.array_equal(image, expected)
