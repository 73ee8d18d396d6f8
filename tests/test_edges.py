"""The edge filter (a card's ``runtime_edge_filter: weighted-median``): the map's weighted median
guided by the left band puts a blurred depth edge back where the image has it, and leaves smooth
surfaces at their sub-pixel values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cade_cli.errors import CadeError
from cade_cli.matching import edges
from cade_cli.matching.base import DisparityRange
from cade_cli.matching.edges import guide_band, snap_to_edges
from cade_cli.matching.learned import LearnedPipeline
from cade_cli.matching.network import NetworkStage
from cade_cli.model_card import EDGE_FILTERS, card_path, network_fingerprint, read_card
from cards import card_copy
from synthetic import render_pair, smooth_texture

import cv2


def disk_scene(rng: np.random.Generator, shape=(120, 160), *, near=30.0, far=12.0):
    """A bright textured disk (disparity ``near``) in front of a dark textured background (``far``):
    the reference band, the true map, and the disk's mask."""
    rows, columns = np.mgrid[:shape[0], :shape[1]]
    disk = (rows - 60) ** 2 + (columns - 80) ** 2 < 35 ** 2
    texture = smooth_texture(rng, shape, 1.5)
    band = np.where(disk, 0.6 + 0.3 * texture, 0.1 + 0.3 * texture).astype(np.float32)
    truth = np.where(disk, near, far).astype(np.float32)
    return band, truth, disk


def band_around(mask: np.ndarray, radius: int) -> np.ndarray:
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    grown = cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)
    shrunk = cv2.erode(mask.astype(np.uint8), kernel).astype(bool)
    return grown & ~shrunk


def test_a_blurred_depth_edge_returns_to_the_images_edge():
    """The network's ¼-size map passes through in-between values over a few px at a depth edge;
    there the filter gives each pixel the surface its grey level belongs to."""
    band, truth, disk = disk_scene(np.random.default_rng(0))
    blurred = cv2.GaussianBlur(truth, (0, 0), 1.5)
    near_edge = band_around(disk, 4)
    before, after = np.abs(blurred - truth)[near_edge], np.abs(snap_to_edges(blurred, band) - truth)[near_edge]
    snapped = snap_to_edges(blurred, band)
    assert (before > 1).mean() > 0.4 and (before > 3).mean() > 0.2
    assert (after > 1).mean() < 0.15 * (before > 1).mean()
    assert (after > 3).mean() < 0.02
    assert np.array_equal(snapped[~band_around(disk, 12)], blurred[~band_around(disk, 12)])


def test_an_edge_the_band_does_not_show_is_left_to_the_plain_median():
    """With a constant band every neighbour weighs the same: the filter is a plain median, which
    leaves a symmetric blur's in-between values where they are; the band's edge is what moves them."""
    _, truth, disk = disk_scene(np.random.default_rng(1))
    blurred = cv2.GaussianBlur(truth, (0, 0), 1.5)
    snapped = snap_to_edges(blurred, np.full(truth.shape, 0.5, np.float32))
    guided = snap_to_edges(blurred, disk_scene(np.random.default_rng(1))[0])
    near_edge = band_around(disk, 4)
    assert (np.abs(guided - truth) > 1)[near_edge].mean() < 0.25 * (np.abs(snapped - truth) > 1)[near_edge].mean()


def noisy_plane(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    rows, columns = np.mgrid[:100, :200].astype(np.float32)
    plane = 5 + 0.037 * columns + 0.021 * rows
    return plane, (plane + rng.normal(0, 0.05, plane.shape)).astype(np.float32)


def test_a_smooth_surface_is_left_as_it_is():
    """Moves of at most a pixel are smoothing, not edges: a noisy slanted plane comes back
    unchanged, bit for bit."""
    rng = np.random.default_rng(2)
    _, noisy = noisy_plane(rng)
    assert np.array_equal(snap_to_edges(noisy, smooth_texture(rng, noisy.shape)), noisy)


def test_moved_pixels_keep_sub_pixel_values():
    """OpenCV's median works on 256 levels of the map's span; the filter must not hand those
    levels back. With every move taken (``min_move=0``) a noisy slanted plane comes out with
    sub-pixel values (far more distinct values than 256) about as close to the plane. (A weighted
    median leans a slope towards the pixels of like grey level, a few hundredths of a px here;
    near the border towards the inner side: why small moves are not taken by default.)"""
    rng = np.random.default_rng(2)
    plane, noisy = noisy_plane(rng)
    band = smooth_texture(rng, plane.shape)
    snapped = snap_to_edges(noisy, band, min_move=0)
    assert not np.array_equal(snapped, noisy)
    inner = (slice(edges.RADIUS, -edges.RADIUS),) * 2
    assert np.abs(snapped - plane)[inner].mean() <= np.abs(noisy - plane)[inner].mean() + 0.01
    assert np.abs(snapped - plane)[inner].max() < 0.5
    assert np.unique(snapped).size > 5000
    quantised = cv2.ximgproc.weightedMedianFilter(guide_band(band), noisy, edges.RADIUS, sigma=edges.SIGMA)
    assert np.unique(quantised).size <= 256  # what the filter corrects


def test_unknown_pixels_stay_unknown_and_do_not_vote():
    band, truth, disk = disk_scene(np.random.default_rng(3))
    blurred = cv2.GaussianBlur(truth, (0, 0), 2.5)
    holed = blurred.copy()
    holed[:, :20] = np.nan
    holed[50:70, 40:50] = np.inf
    snapped = snap_to_edges(holed, band)
    assert np.array_equal(np.isnan(snapped), np.isnan(holed))
    assert np.array_equal(np.isinf(snapped), np.isinf(holed))
    unknown_votes = snap_to_edges(np.where(np.isfinite(holed), holed, 1000.0).astype(np.float32), band)
    finite = np.isfinite(holed)
    assert np.abs(snapped[finite]).max() < 31  # no 1000 px value leaked in from the unknown pixels
    assert not np.array_equal(snapped[finite], unknown_votes[finite])


def test_a_map_without_known_values_and_a_constant_map_come_back_unchanged():
    band = np.random.default_rng(4).random((32, 48)).astype(np.float32)
    empty = np.full(band.shape, np.nan, np.float32)
    assert np.isnan(snap_to_edges(empty, band)).all()
    flat = np.full(band.shape, 7.25, np.float32)
    assert np.array_equal(snap_to_edges(flat, band), flat)


@pytest.mark.parametrize("band", [
    np.linspace(0, 65535, 64 * 80).reshape(64, 80),  # 16-bit counts
    np.linspace(-3, 3, 64 * 80).reshape(64, 80),     # a signed float band
])
def test_the_guide_is_the_band_stretched_to_its_percentiles_whatever_its_range(band):
    guide = guide_band(band)
    assert guide.dtype == np.uint8 and guide.shape == band.shape
    assert guide.min() == 0 and guide.max() == 255
    assert np.all(np.diff(guide.ravel().astype(int)) >= 0)  # order kept
    assert (guide_band(np.full((8, 8), 3.0)) == guide_band(np.full((8, 8), 3.0))[0, 0]).all()


def test_a_card_names_its_edge_filter_and_a_batch_record_keeps_it(tmp_path: Path):
    assert EDGE_FILTERS == ("none", "weighted-median")
    assert read_card(card_path("cade-v4")).edge_filter == "none"
    assert "runtime_edge_filter" not in network_fingerprint("cade-v4")
    path = card_copy(tmp_path, "edges", source="cade-v4", runtime_edge_filter="weighted-median")
    assert read_card(path).edge_filter == "weighted-median"
    assert network_fingerprint(path)["runtime_edge_filter"] == "weighted-median"
    bad = card_copy(tmp_path, "bad-edges", source="cade-v4", runtime_edge_filter="bilateral")
    with pytest.raises(CadeError, match="runtime_edge_filter 'bilateral' is not one of none, weighted-median"):
        read_card(bad)


def test_the_matcher_filters_its_map_last_with_the_left_band_when_the_card_asks(tmp_path: Path, monkeypatch):
    calls = []
    original = edges.snap_to_edges

    def spy(disparity, reference, **options):
        calls.append(reference)
        return original(disparity, reference, **options)

    monkeypatch.setattr("cade_cli.matching.learned.snap_to_edges", spy)
    pair = render_pair(np.random.default_rng(5), (64, 160), background=(10.0, 0.0), foreground=(20.0, 0.0))
    asks = card_copy(tmp_path, "edges", source="cade-v4", runtime_edge_filter="weighted-median")
    plain = LearnedPipeline(network=NetworkStage(model=str(card_path("cade-v4"))))(pair.left, pair.right,
                                                                                   DisparityRange(0, 40))
    assert calls == []
    filtered = LearnedPipeline(network=NetworkStage(model=str(asks)))(pair.left, pair.right, DisparityRange(0, 40))
    assert len(calls) == 1 and calls[0] is pair.left
    assert np.array_equal(filtered.valid, plain.valid)  # visibility is judged before, on the network's map
    network_alone = LearnedPipeline(network=NetworkStage(model=str(asks)), refinement=None)
    network_alone(pair.left, pair.right, DisparityRange(0, 40))
    assert len(calls) == 1  # the network alone (method cade-network) is not filtered


def test_the_map_does_not_depend_on_the_thread_count():
    """The median runs in fixed bands of rows spread over OpenCV's threads: one thread or two, the
    same map to the bit (a map taller than a band, so there are several)."""
    rng = np.random.default_rng(6)
    band, truth, _ = disk_scene(rng, shape=(edges.BAND_ROWS * 2 + 40, 160))
    blurred = cv2.GaussianBlur(truth, (0, 0), 1.5) + rng.normal(0, 0.3, truth.shape).astype(np.float32)
    threads = cv2.getNumThreads()
    try:
        cv2.setNumThreads(1)
        one = snap_to_edges(blurred, band)
        cv2.setNumThreads(2)
        two = snap_to_edges(blurred, band)
    finally:
        cv2.setNumThreads(threads)
    assert np.array_equal(one, two) and not np.array_equal(one, blurred)
