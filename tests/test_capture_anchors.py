"""The anchors register-capture is measured against (cade_cli.capture.anchors), on a synthetic
capture with its own truth: a flat ground 1.5 m below a RedEdge-like rig is one plane, so the
ECC homography in the product's common frame must put every band within half a pixel of where
the ground point truly is, while the lens rotations alone leave the baselines' parallax."""

from __future__ import annotations

import numpy as np

from capture_scenes import write_capture
from cade_cli.capture.anchors import register_anchor
from cade_cli.capture.model import band_pixels, load_capture, reference_frame_pixels


def _errors(capture, result, truth, margin=12):
    """Per band: distance (px) between where the anchor sampled each reference pixel and the truth."""
    raw_x, raw_y = np.meshgrid(*(np.arange(n, dtype=np.float32) for n in capture.size))
    px, py = reference_frame_pixels(capture, raw_x, raw_y)
    errors = {}
    for index, band in enumerate(capture.bands):
        if band.name not in result.homographies:
            continue
        u, v = band_pixels(capture, index, px, py, result.homographies[band.name])
        true_u, true_v = truth[band.name]
        inner = (slice(margin, -margin), slice(margin, -margin))
        errors[band.name] = np.hypot(u - true_u, v - true_v)[inner]
    return errors


def test_the_ecc_anchor_follows_a_plane_that_the_rotations_alone_miss(tmp_path, rng):
    scene = write_capture(tmp_path / "flat", rng, depth=1.5, hill=0.0)
    capture = load_capture(scene.paths)
    rotations = register_anchor(capture, ecc=False)
    ecc = register_anchor(capture, ecc=True)
    assert not ecc.failures and set(ecc.starts.values()) <= {"rotations", "features"}
    assert sorted(ecc.bands) == sorted(capture.names())
    for name, errors in _errors(capture, rotations, scene.truth).items():
        assert np.median(errors) > 3, name  # 4 cm at 1.5 m: the parallax the rotations leave
    for name, errors in _errors(capture, ecc, scene.truth).items():
        assert np.mean(errors < 0.5) > 0.95 and np.median(errors) < 0.25, (name, np.median(errors))
    reference = capture.reference_band.name
    assert np.array_equal(ecc.bands[reference], rotations.bands[reference])  # the reference: its raw values
    for name, image in ecc.bands.items():
        assert image.shape == (capture.size[1], capture.size[0]) and image.dtype == np.float32
