"""benchmarks/gpu_data.py, the GPU recipe's data pack: a pack of a small data folder unpacks to the same
pixels (8-bit colour and grey PNGs, a 16-bit PNG left as it is) and the same PFM bytes, under the same names."""

from __future__ import annotations

import subprocess
import sys
import tarfile
from pathlib import Path

import cv2
import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "gpu_data.py"


def test_a_pack_unpacks_to_the_same_pixels_and_floats(tmp_path):
    rng = np.random.default_rng(0)
    data = tmp_path / "data"
    scene = data / "train-real" / "scene"
    scene.mkdir(parents=True)
    smooth = cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), (5, 5), 0)  # compresses well
    cv2.imwrite(str(scene / "im0.png"), smooth)
    cv2.imwrite(str(scene / "mask0nocc.png"), (rng.random((48, 64)) > 0.5).astype(np.uint8) * 255)
    cv2.imwrite(str(scene / "depth16.png"), rng.integers(0, 65536, (48, 64), dtype=np.uint16))
    pfm = b"Pf\n64 48\n-1.0\n" + rng.random((48, 64), dtype=np.float32).tobytes()
    (scene / "disp0GT.pfm").write_bytes(pfm)
    texture = data / "textures" / "Kodak24"
    texture.mkdir(parents=True)
    cv2.imwrite(str(texture / "kodim01.png"), smooth[::-1])
    (data / "textures" / "McMaster").mkdir()
    cv2.imwrite(str(data / "textures" / "McMaster" / "left_out.png"), smooth)  # not a folder the recipe trains on

    packed = tmp_path / "pack" / "data.tar"
    subprocess.run([sys.executable, str(SCRIPT), "pack", str(data), str(packed)], check=True, capture_output=True)
    with tarfile.open(packed) as tar:
        names = set(tar.getnames())
    assert "train-real/scene/disp0GT.pfm.xz" in names and "train-real/scene/im0.png.webp" in names
    assert not any("McMaster" in name for name in names)

    root = tmp_path / "gpu-data"
    subprocess.run([sys.executable, str(SCRIPT), "unpack", str(packed), str(root)], check=True, capture_output=True)
    originals = sorted(path.relative_to(data) for path in data.rglob("*") if path.is_file() and "McMaster" not in str(path))
    assert sorted(path.relative_to(root) for path in root.rglob("*") if path.is_file()) == originals
    for name in originals:
        if name.suffix == ".png":
            before, after = (cv2.imread(str(folder / name), cv2.IMREAD_UNCHANGED) for folder in (data, root))
            assert after.dtype == before.dtype and np.array_equal(after, before), name
        else:
            assert (root / name).read_bytes() == (data / name).read_bytes(), name
