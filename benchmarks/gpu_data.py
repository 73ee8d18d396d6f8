"""The GPU recipe's training data, packed to travel inside a device call's 64 MiB (docs/gpu-recipe.md).

The training data (``train-real`` and three texture sets, about 51 MB as PNG and PFM) and the tracked tree
(about 33 MB) do not fit one call together. Packed losslessly -- 8-bit PNGs as lossless WebP (kept only
where the decoded pixels are identical and the file is smaller), PFMs through xz -- they take about 29 MB;
``unpack`` on the device writes the same pixels and floats back as PNG and PFM:

    .venv/bin/python benchmarks/gpu_data.py pack ../shared/data .gpu-pack/data.tar     # here (make gpu-data)
    python3 benchmarks/gpu_data.py unpack .gpu-pack/data.tar .gpu-data                 # there

Only numpy and OpenCV: both machines have them.
"""

from __future__ import annotations

import argparse
import io
import lzma
import tarfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

#: What the GPU recipe trains on, relative to the data folder.
FOLDERS = ("train-real", "textures/CBSD68", "textures/Kodak24", "textures/skimage_cc0")


def packed(path: Path) -> tuple[str, bytes]:
    """The suffix added to ``path``'s name in the pack ('' when kept as it is) and the bytes stored."""
    data = path.read_bytes()
    if path.suffix.lower() == ".pfm":
        return ".xz", lzma.compress(data, preset=9)
    if path.suffix.lower() == ".png":
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is not None and image.dtype == np.uint8:
            ok, webp = cv2.imencode(".webp", image, [cv2.IMWRITE_WEBP_QUALITY, 101])  # 101: lossless
            back = cv2.imdecode(webp, cv2.IMREAD_UNCHANGED) if ok else None
            if back is not None and back.shape == image.shape and np.array_equal(back, image) and webp.size < len(data):
                return ".webp", webp.tobytes()
    return "", data


def unpacked(name: str, data: bytes) -> tuple[str, bytes]:
    """The inverse of :func:`packed`: the original name and bytes of the same pixels or floats."""
    if name.endswith(".webp"):
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        return name.removesuffix(".webp"), cv2.imencode(".png", image)[1].tobytes()
    if name.endswith(".xz"):
        return name.removesuffix(".xz"), lzma.decompress(data)
    return name, data


def pack(data_dir: Path, target: Path) -> None:
    files = [path for folder in FOLDERS for path in sorted((data_dir / folder).rglob("*")) if path.is_file()]
    target.parent.mkdir(parents=True, exist_ok=True)
    with tarfile.open(target, "w") as tar, ProcessPoolExecutor() as pool:
        for path, (suffix, data) in zip(files, pool.map(packed, files, chunksize=4)):
            info = tarfile.TarInfo(str(path.relative_to(data_dir)) + suffix)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    print(f"{target}: {len(files)} files, {target.stat().st_size / 1e6:.1f} MB")


def _write(root: Path, name: str, data: bytes) -> None:
    name, data = unpacked(name, data)
    path = root / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def unpack(source: Path, root: Path) -> None:
    with tarfile.open(source) as tar:
        members = [(m.name, tar.extractfile(m).read()) for m in tar.getmembers() if m.isfile()]
    with ProcessPoolExecutor() as pool:
        list(pool.map(_write, [root] * len(members), *zip(*members)))
    print(f"{root}: {len(members)} files")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    verb = verbs.add_parser("pack", help="DATA_DIR's training folders into TAR")
    verb.add_argument("data_dir", type=Path)
    verb.add_argument("tar", type=Path)
    verb = verbs.add_parser("unpack", help="TAR into ROOT")
    verb.add_argument("tar", type=Path)
    verb.add_argument("root", type=Path)
    args = parser.parse_args()
    if args.verb == "pack":
        pack(args.data_dir, args.tar)
    else:
        unpack(args.tar, args.root)


if __name__ == "__main__":
    main()
