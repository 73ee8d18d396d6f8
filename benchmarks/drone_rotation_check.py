"""Whether a capture's lens rotations (RigRelatives) are read in the right sense, checked
against its own images where parallax is large (close range): after the rotations, a scene
point moves from the reference band to another only along the baseline (plus the small across
field the product fits), so the right rotations let the most sparse matches fit one direction.

    python benchmarks/drone_rotation_check.py ../shared/data/micasense/sequoia-tabletop/*.TIF

Prints, per band, the share of its cross-spectral matches that fit one baseline direction
(cade_cli.capture.parallax) with the rotations as read, with none, and transposed.
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np

from cade_cli.capture.model import Capture, band_pixels, load_capture
from cade_cli.capture.parallax import band_features, cross_spectral_matches, fit_direction, refine_matches
from cade_cli.capture.register import read_raw, sample_bilinear

CONVENTIONS = {"as read": lambda r: r, "none": lambda r: np.eye(3), "transposed": lambda r: r.T}


def supported_shares(capture: Capture) -> dict[str, dict[str, float]]:
    """Per convention, per band: the share of its matches that fit one baseline direction."""
    raw = read_raw(capture)
    width, height = capture.frame[1]
    x, y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    signal = [r.astype(np.float32) - np.float32(b.black_level) for r, b in zip(raw, capture.bands)]
    shares = {}
    for label, turn in CONVENTIONS.items():
        turned = Capture(tuple(replace(b, rotation=turn(b.rotation)) for b in capture.bands), capture.reference)
        reference, _ = sample_bilinear(signal[turned.reference], *band_pixels(turned, turned.reference, x, y))
        features = band_features(reference)
        shares[label] = {}
        for index, band in enumerate(turned.bands):
            if index == turned.reference:
                continue
            image, _ = sample_bilinear(signal[index], *band_pixels(turned, index, x, y))
            on_reference, on_band = refine_matches(reference, image, *cross_spectral_matches(features, image))
            _, _, supporting = fit_direction(on_reference, on_band - on_reference)
            shares[label][band.name] = float(supporting.mean())
    return shares


def main() -> None:
    capture = load_capture(sys.argv[1:])
    for label, per_band in supported_shares(capture).items():
        print(f"{label:10s} " + "  ".join(f"{name} {share:.0%}" for name, share in per_band.items()))


if __name__ == "__main__":
    main()
