"""The vendors' one-homography band alignment (cade_cli/capture/homography.py): a textured
band warped by a known homography, with another (inverted, non-linear) intensity response,
must be found again."""

from __future__ import annotations

import numpy as np
import pytest

from cade_cli.capture.homography import ecc_homography, feature_homography, gradient_magnitude, warp_band
from cade_cli.errors import CadeError
from synthetic import smooth_texture

SHAPE = (240, 320)
TRUE = np.array([[1.012, 0.018, 3.4], [-0.014, 0.991, -2.3], [2.5e-5, -1.5e-5, 1.0]])
"""Band pixels -> reference pixels: a few px of shift, ~1 % of scale and shear, some perspective."""


def mapped(homography: np.ndarray, points: np.ndarray) -> np.ndarray:
    projected = homography @ np.vstack([points, np.ones(points.shape[1])])
    return projected[:2] / projected[2]


def grid_points(margin: int = 10, step: int = 10) -> np.ndarray:
    rows, cols = np.mgrid[margin:SHAPE[0] - margin:step, margin:SHAPE[1] - margin:step]
    return np.vstack([cols.ravel(), rows.ravel()]).astype(np.float64)


def other_band(reference: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """The band a second lens sees: the reference scene at ``homography`` of each band pixel,
    through an inverted, non-linear response (dark where the reference is bright)."""
    import cv2
    seen = cv2.warpPerspective(reference, homography, SHAPE[::-1], flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_REFLECT)
    return (1.0 - 0.8 * seen ** 2).astype(np.float32)


@pytest.fixture
def reference(rng) -> np.ndarray:
    return smooth_texture(rng, SHAPE, sigma=2.0)


def test_a_known_homography_is_recovered_across_an_inverted_response(reference):
    found = ecc_homography(reference, other_band(reference, TRUE))
    error = np.abs(mapped(found, grid_points()) - mapped(TRUE, grid_points()))
    assert error.max() < 0.1
    assert found[2, 2] == pytest.approx(1.0)


def test_a_start_near_the_answer_is_refined_and_identity_is_kept(reference):
    start = TRUE.copy()
    start[:2, 2] += (1.5, -1.0)  # e.g. the lens rotations, off by the parallax
    found = ecc_homography(reference, other_band(reference, TRUE), init=start, levels=2)
    assert np.abs(mapped(found, grid_points()) - mapped(TRUE, grid_points())).max() < 0.1
    same = ecc_homography(reference, reference)
    assert np.abs(mapped(same, grid_points()) - grid_points()).max() < 0.01


def test_the_warped_band_lands_on_the_reference_and_marks_the_unseen(reference):
    band = other_band(reference, TRUE)
    warped = warp_band(band, TRUE, SHAPE[::-1])
    assert np.isnan(warped).any() and np.isfinite(warped).mean() > 0.9
    inner = np.isfinite(warped)
    inner[:12], inner[-12:], inner[:, :12], inner[:, -12:] = False, False, False, False
    expected = 1.0 - 0.8 * reference ** 2
    assert np.abs(warped[inner] - expected[inner]).max() < 0.02


def test_a_band_that_shares_no_structure_is_refused(rng, reference):
    noise = rng.random(SHAPE).astype(np.float32)
    with pytest.raises(CadeError, match="ECC"):
        ecc_homography(reference, noise)
    with pytest.raises(CadeError, match="feature matches"):
        feature_homography(reference, noise)


def test_feature_matches_start_ecc_where_the_start_is_far_off(reference):
    """40 px away (close range: the lens rotations say little) ECC alone does not find the
    band; from the feature-match homography it does."""
    far = TRUE.copy()
    far[:2, 2] += (40.0, -25.0)
    band = other_band(reference, far)
    with pytest.raises(CadeError, match=r"^ECC did not converge at pyramid level 2 \(Iterations do not converge\)"):
        ecc_homography(reference, band)
    start, inliers = feature_homography(reference, band)
    assert inliers >= 12
    assert np.median(np.abs(mapped(start, grid_points()) - mapped(far, grid_points()))) < 1.0
    found = ecc_homography(reference, band, init=start)
    assert np.abs(mapped(found, grid_points()) - mapped(far, grid_points())).max() < 0.1


def test_bad_inputs_are_refused_in_one_line(reference):
    with pytest.raises(CadeError, match="one size"):
        ecc_homography(reference, reference[:-1])
    with pytest.raises(CadeError, match="invertible"):
        ecc_homography(reference, reference, init=np.zeros((3, 3)))
    with pytest.raises(CadeError, match="pyramid levels"):
        ecc_homography(reference, reference, levels=6)
    with pytest.raises(CadeError, match="no finite value"):
        gradient_magnitude(np.full(SHAPE, np.nan))


def test_the_gradient_image_ignores_contrast_and_the_border_of_the_unseen(reference):
    assert np.allclose(gradient_magnitude(reference), gradient_magnitude(5.0 - 3.0 * reference), atol=1e-5)
    partial = reference.copy()
    partial[:, :100] = np.nan
    gradient = gradient_magnitude(partial)
    assert np.all(gradient[:, :104] == 0) and np.isfinite(gradient).all()


def test_a_faint_plane_wins_over_a_bright_near_object(reference):
    """The bench captures' case: a faint canopy (the plane) and a bright platform nearer the
    camera, displaced by parallax. The homography must follow the plane, as the vendor's
    locally equalised ECC does, not the near object's strong edges."""
    import cv2
    scene = 0.2 + 0.1 * reference  # faint texture
    near = np.zeros(SHAPE, np.float32)
    near[140:180, 60:260] = 1.0    # a bright bar over a tenth of the view
    reference_view = np.maximum(scene, near)
    band_scene = other_band(scene, TRUE)
    band_near = cv2.warpPerspective(near, TRUE, SHAPE[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    band_near = np.roll(band_near, 6, axis=1)  # 6 px of parallax more than the plane
    band = np.where(band_near > 0.5, 0.05, band_scene).astype(np.float32)  # dark in this band
    found = ecc_homography(reference_view, band)
    points = grid_points()
    on_plane = ~((points[1] >= 125) & (points[1] <= 195))
    error = np.abs(mapped(found, points[:, on_plane]) - mapped(TRUE, points[:, on_plane]))
    assert error.max() < 0.3 and np.median(error) < 0.1  # without the local standardisation ECC fails here


def test_unseen_corners_do_not_pull_the_homography(reference):
    """Undistorted bands have black (NaN) corners, each band its own."""
    band = other_band(reference, TRUE)
    band[:50, :70] = np.nan
    partial_reference = reference.copy()
    partial_reference[-50:, -70:] = np.nan
    found = ecc_homography(partial_reference, band)
    points = grid_points()
    seen = ~(((points[0] < 80) & (points[1] < 60)) | ((points[0] > SHAPE[1] - 80) & (points[1] > SHAPE[0] - 60)))
    error = np.abs(mapped(found, points) - mapped(TRUE, points))
    assert error[:, seen].max() < 0.1 and error.max() < 0.2  # extrapolated into the corners: a little more
