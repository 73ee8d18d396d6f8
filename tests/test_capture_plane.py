"""register-capture's cheap path: how far the plane is off beyond the sparse matches' own noise
(parallax.off_plane) and the ECC refinement of the cheap path's plane (register.refined_plane);
and the parallax direction the matches' spread shows (parallax.across_slope): each against a
truth built here."""

from __future__ import annotations

import cv2
import numpy as np

from cade_cli.capture.parallax import CHEAP_PARALLAX, across_slope, fit_direction, measure_parallax, off_plane
from cade_cli.capture.register import refined_plane


def test_match_noise_alone_is_not_parallax(rng):
    noise = 0.2  # px, each axis: about what the cross-spectral matches of a planar field show
    along, across = rng.normal(0, noise, 1000), rng.normal(0, noise, 1000)
    assert (np.percentile(along, 97.5) - np.percentile(along, 2.5)) / 2 > CHEAP_PARALLAX  # the plain spread would
    assert off_plane(along, across) < 0.15
    bump = np.where(rng.random(1000) < 0.2, 3.0, 0.0)  # a fifth of the matches on a near object, 3 px off
    assert off_plane(along + bump, across) > 1.0
    assert off_plane(along + rng.normal(0, 1.0, 1000), across) > 1.5  # a relief spread +-1 px along the baseline


def _texture(rng, size=(240, 320)):
    return cv2.GaussianBlur(rng.random(size).astype(np.float32), (0, 0), 2.0)


def test_the_cheap_paths_plane_is_refined_to_the_true_homography(rng):
    reference = _texture(rng)
    truth = np.array([[1.01, 0.004, 3.2], [-0.003, 0.995, -2.1], [1e-5, -2e-5, 1.0]])  # reference px -> band px
    height, width = reference.shape
    band = cv2.warpPerspective(reference, truth, (width, height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    band = 1.0 - band  # another band's response: inverted contrast
    start = np.array([[1, 0, 0.6], [0, 1, -0.5], [0, 0, 1]]) @ truth  # the sparse plane, half a pixel off
    refined = refined_plane(reference, band, start)
    corners = np.float64([[[40, 40]], [[280, 40]], [[40, 200]], [[280, 200]], [[160, 120]]])

    def error(homography):
        return np.abs(cv2.perspectiveTransform(corners, homography) - cv2.perspectiveTransform(corners, truth)).max()
    assert error(start) > 0.5 and error(refined) < 0.2, (error(start), error(refined))  # 10 iterations
    flat = np.full_like(reference, 0.5)  # nothing to align: the plane it was given
    assert np.array_equal(refined_plane(reference, flat, start), start)


def _bench_matches(rng, *, low, high, count=1200, angle=35.0):
    """Matches (reference points, band points) of a scene with parallax ``low``-``high`` px along
    ``angle`` degrees, plus an across field of 1.5 px at the centre (what the lens rotations
    leave), 0.12 px of noise: the bench capture's Red edge (7-12 px)."""
    points = rng.uniform([0, 0], [1280, 960], (count, 2))
    baseline = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    normal = np.array([-baseline[1], baseline[0]])
    d = rng.uniform(low, high, count)
    offset = 1.5 + 1e-3 * (points[:, 0] - 640) - 5e-4 * (points[:, 1] - 480)
    raw = -d[:, None] * baseline + offset[:, None] * normal + rng.normal(0, 0.12, (count, 2))
    return points, points + raw, baseline


def test_the_parallax_direction_is_the_one_the_matches_spread_shows(rng):
    points, band, truth = _bench_matches(rng, low=7.0, high=12.0)
    # the across field absorbs a turned direction at the matches' own parallax: the smallest
    # offset of the directions that fit as well is ~9 degrees off (1.5 px / 9.5 px of parallax) ...
    chosen, _, _ = fit_direction(points, band - points)
    assert abs(chosen @ truth) < np.cos(np.radians(5))
    # ... which shows as an across residual rising with the parallax: the direction is turned
    parallax = measure_parallax(points, band, np.eye(3))
    assert parallax.baseline @ truth > np.cos(np.radians(0.5))
    assert abs(np.median(parallax.across_at(points[:, 0], points[:, 1])) - 1.5) < 0.1
    assert across_slope(points, band - points, parallax.baseline, parallax.across) == 0.0


def test_a_scene_at_one_depth_keeps_the_chosen_direction(rng):
    points, band, _ = _bench_matches(rng, low=9.0, high=9.0)  # no spread: the slope is undecided
    chosen, across, _ = fit_direction(points, band - points)
    assert across_slope(points, band - points, chosen, across) == 0.0
    parallax = measure_parallax(points, band, np.eye(3))
    assert abs(abs(parallax.baseline @ chosen) - 1) < 1e-9 and parallax.negligible
