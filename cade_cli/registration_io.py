"""Writing a :class:`~cade_cli.registration.Registration` as one multi-band TIFF."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import tifffile

from cade_cli.atomic import atomic_output
from cade_cli.registration import Registration

BAND_ORDER: tuple[str, ...] = ("reference", "registered", "valid")


def write_registration(path: Path, registration: Registration) -> None:
    """Write ``registration`` to ``path`` atomically as a planar float32 TIFF.

    Bands, in order: the reference band, the registered (moving) band (NaN where unknown
    with ``fill="none"``), and validity (1.0 = trusted correspondence, 0.0 = occluded,
    rejected or out of view). The band names are stored as JSON in the description.
    """
    stack = np.stack(
        [registration.reference, registration.registered, registration.valid.astype(np.float32)]
    ).astype(np.float32)
    with atomic_output(Path(path)) as temporary:
        tifffile.imwrite(
            temporary, stack, photometric="minisblack", planarconfig="separate",
            description=json.dumps({"bands": list(BAND_ORDER)}), metadata=None,
        )
