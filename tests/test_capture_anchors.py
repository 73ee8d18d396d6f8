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


def test_the_ecc_anchor_starts_from_the_sparse_plane_when_the_rotations_and_features_fail(tmp_path, rng, monkeypatch):
    """The third start: ECC from register-capture's own cross-spectral plane, taken only when ECC
    from the rotations and the feature homography both fail; it must still find the ground."""
    import cade_cli.capture.anchors as anchors
    from cade_cli.errors import CadeError

    scene = write_capture(tmp_path / "flat", rng, depth=1.5, hill=0.0)
    capture = load_capture(scene.paths)
    real_ecc = anchors.ecc_homography

    def ecc_refusing_the_identity(reference, band, init=None):
        if init is None:
            raise CadeError("did not converge")
        return real_ecc(reference, band, init=init)

    def no_features(reference, band):
        raise CadeError("too few feature matches")

    monkeypatch.setattr(anchors, "ecc_homography", ecc_refusing_the_identity)
    monkeypatch.setattr(anchors, "feature_homography", no_features)
    ecc = register_anchor(capture, ecc=True)
    assert not ecc.failures and set(ecc.starts.values()) == {"plane"}
    for name, errors in _errors(capture, ecc, scene.truth).items():
        assert np.mean(errors < 0.5) > 0.95 and np.median(errors) < 0.25, (name, np.median(errors))

    monkeypatch.setattr(anchors, "plane_homography", lambda reference, band: (_ for _ in ()).throw(
        CadeError("too few cross-spectral matches")))
    failed = register_anchor(capture, ecc=True)
    assert sorted(failed.failures) == sorted(set(capture.names()) - {capture.reference_band.name})
    reasons = next(iter(failed.failures.values()))
    assert "from the rotations: did not converge" in reasons and "from the features: too few" in reasons
    assert "from the plane: too few cross-spectral matches" in reasons and "\n" not in reasons
