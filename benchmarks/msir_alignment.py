"""MSIR outdoor (a real 3x3 multispectral array, ../shared/data/msir-outdoor): its rig file,
and the alignment of the affine-only registration against cade's, without ground truth.

    python benchmarks/msir_alignment.py rig ../shared/data/msir-outdoor -o msir-rig.json
    cade register-array msir-rig.json ../shared/data/msir-outdoor/scene/Cam-?.png --plane-only -o msir-affine.tif
    cade register-array msir-rig.json ../shared/data/msir-outdoor/scene/Cam-?.png -o msir-cade.tif
    cade array-score msir-affine.tif msir-cade.tif
    python benchmarks/msir_alignment.py report msir-affine.tif msir-cade.tif --pictures docs/rigs

The rig is :func:`cade_cli.data.msir.msir_rig` (the msir-outdoor benchmark dataset builds it
too): bands "cam0" .. "cam8" (the data set documents none); each camera's ``to_reference`` is
the least-squares affine from its 8 hand-picked façade points (calibration/corners.npy) onto
Cam-4's, as the MSIR code fits it (there with RANSAC; all 8 points are inliers); positions from
camera_array.json (mm, X = +40 to the image's right, Y = +40 the top row), in the rig's image
axes: [X, -Y] / 1000 m.
The MSIR data is for development and tests only: nothing of it is written to the
repository but small derived pictures.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from cade_cli.data.msir import msir_rig
from cade_cli.errors import CadeError
from cade_cli.io.atomic import atomic_outputs
from cade_cli.rigs.array_cube import false_colour, read_array_cube
from cade_cli.rigs.array_score import score_cubes
from cade_cli.rigs.rig_file import save_rig

PICTURE_WIDTH = 512
FALSE_COLOUR = ("Cam-0", "Cam-4", "Cam-8")
"""Red, green, blue: a near-infrared-looking top-left camera, the reference and the
bottom-right camera: two diagonal baselines, so parallax left over shows in both axes."""
CROP = (slice(170, 330), slice(560, 920))
"""Rows, columns of the zoom (shown 2x): the forest behind the façade plane and the tower on
the roof, where the parallax left by the affine registration is largest."""


def _small(picture: np.ndarray) -> np.ndarray:
    height, width = picture.shape[:2]
    if width <= PICTURE_WIDTH:
        return picture
    return cv2.resize(picture, (PICTURE_WIDTH, round(height * PICTURE_WIDTH / width)), interpolation=cv2.INTER_AREA)


def report(cubes: list[Path], *, pictures: Path | None) -> str:
    """Score the cubes on their common valid pixels (the Markdown table is returned); write
    each cube's false-colour picture, at most 512 px wide, and a 2x zoom as
    ``<pictures>/<cube stem>.png`` and ``<cube stem>-zoom.png``."""
    loaded = [read_array_cube(path) for path in cubes]
    scores = score_cubes(loaded)
    names = [path.stem for path in cubes]
    header = ["camera", "band", "scored %"] + [f"NGC {n}" for n in names] + [f"MI {n} (bits)" for n in names]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for k in range(len(loaded[0].cameras)):
        row = [scores[0][k].camera, scores[0][k].band, f"{100 * scores[0][k].scored_share:.1f}"]
        row += [f"{s[k].gradient_correlation:.3f}" for s in scores] + [f"{s[k].mutual_information:.3f}" for s in scores]
        lines.append("| " + " | ".join(row) + " |")
    means = ["**mean**", "", ""] + [f"**{np.mean([x.gradient_correlation for x in s]):.3f}**" for s in scores]
    means += [f"**{np.mean([x.mutual_information for x in s]):.3f}**" for s in scores]
    lines.append("| " + " | ".join(means) + " |")
    table = "\n".join(lines)
    outputs = []
    if pictures is not None:
        outputs = [pictures / f"{name}{suffix}.png" for name in names for suffix in ("", "-zoom")]
    with atomic_outputs(outputs) as staged:
        for i, cube in enumerate(loaded):
            if pictures is None:
                break
            picture = false_colour(cube, FALSE_COLOUR)
            cv2.imwrite(str(staged[outputs[2 * i]]), _small(picture))
            zoom = picture[CROP]
            cv2.imwrite(str(staged[outputs[2 * i + 1]]), cv2.resize(zoom, None, fx=2, fy=2,
                                                                      interpolation=cv2.INTER_NEAREST))
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    rig = commands.add_parser("rig", help="write the rig file of an MSIR scene folder")
    rig.add_argument("folder", type=Path)
    rig.add_argument("-o", "--output", type=Path, required=True)
    scored = commands.add_parser("report", help="score cubes of one array (a Markdown table); write pictures")
    scored.add_argument("cubes", type=Path, nargs="+")
    scored.add_argument("--pictures", type=Path, help="folder for the false-colour pictures")
    arguments = parser.parse_args()
    try:
        if arguments.command == "rig":
            made, residuals = msir_rig(arguments.folder)
            save_rig(made, arguments.output)
            print(f"{arguments.output}: {len(made.cameras)} cameras, reference {made.reference}, affine RMS "
                  + ", ".join(f"{c.name} {r:.2f}" for c, r in zip(made.cameras, residuals)) + " px")
        elif arguments.command == "report":
            print(report(arguments.cubes, pictures=arguments.pictures))
        else:
            raise AssertionError(arguments.command)
    except CadeError as error:
        raise SystemExit(f"msir_alignment: error: {error}") from None


if __name__ == "__main__":
    main()
