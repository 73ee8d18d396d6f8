"""The ``cade`` command: a thin layer over the library that parses, validates and prints.

Heavy modules (NumPy, OpenCV, the matchers) are imported inside the commands, so
``cade --help`` and ``cade --version`` answer at once. Any user error ends as one line
on stderr and a non-zero exit; outputs are written atomically and only at the end.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli import __version__

METHOD_NAMES = ("census-sgm", "zncc-sgm", "sgbm", "cade", "cade-network", "dasc-sgm")
"""Registered matchers, listed here so that --help needs no heavy import (a test keeps
this in step with :data:`cade_cli.matching.MATCHERS`)."""
BENCHMARK_METHODS = METHOD_NAMES[:4] + ("dasc-sgm",)
"""What ``cade benchmark`` compares by default: the matchers of the paper's Table 1 that we
have (cade-network is cade's first stage, there to analyse the network; name it with --methods)."""
DEFAULT_METHOD = "cade"
"""The default matcher, here so that --help needs no heavy import (a test keeps it equal
to :data:`cade_cli.stereo.DEFAULT_METHOD`)."""

EXIT_INPUT_ERROR = 1
EXIT_USAGE_ERROR = 2

app = typer.Typer(
    name="cade",
    help="Cross-spectral stereo: disparity between bands seen through different filters, and band registration.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        print(f"cade {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """Cross-spectral stereo toolkit (CADE, ICASSP 2024)."""


MethodOption = Annotated[
    str,
    typer.Option(
        "--method",
        "-m",
        help=f"Matcher: {', '.join(METHOD_NAMES)}. The default, cade (the CADE network), has the lowest error "
        "of the four on the cross-spectral benchmark and is about 3x faster than census-sgm, the best "
        "classical one (docs/results.md).",
    ),
]
MaxDispOption = Annotated[
    Optional[int],
    typer.Option("--max-disp", min=1, help="Largest disparity searched, px (default: a quarter of the width)."),
]
MinDispOption = Annotated[
    int, typer.Option("--min-disp", help="Smallest disparity searched, px; negative for pairs registered to a plane.")
]
MaxDispAutoOption = Annotated[
    Optional[str],
    typer.Option("--max-disp", help="Largest disparity searched, px, or 'auto': estimated from a coarse match of the "
                 "pair, with a margin (docs/scale.md). Default: a quarter of the width."),
]
MinDispAutoOption = Annotated[
    str, typer.Option("--min-disp", help="Smallest disparity searched, px (negative for pairs registered to a plane), "
                      "or 'auto': estimated like --max-disp auto, and possibly negative.")
]
ModelOption = Annotated[
    Optional[str],
    typer.Option("--model", help="Network of the learned methods: a tier, fast (the default, cade-v4) or accurate "
                 "(cade-v6: fewer gross errors on most benchmark sets, same speed; models/README.md), the path of a "
                 "model card (.json, its ONNX files beside it, as `python -m cade_cli.train export` writes them) or "
                 "a card name in the model folder ($CADE_MODEL_DIR, default the shipped models/)."),
]
MemoryLimitOption = Annotated[
    Optional[str],
    typer.Option("--memory-limit", help="Memory budget, like 4GB or 512MB (default: half the memory available). A "
                 "pair that does not fit it whole is matched as overlapping tiles, each with a range seeded from a "
                 "coarse pass (docs/scale.md, \"Tiling\").", show_default=False),
]
PreprocessOption = Annotated[
    str,
    typer.Option(
        "--preprocess",
        help="'cade' (color agnostic transform on both bands), 'none', or 'auto': the matcher's more "
        "accurate choice on cross-spectral pairs (census-sgm, zncc-sgm: none; sgbm, cade: cade).",
    ),
]


VisRangeOption = Annotated[
    Optional[str],
    typer.Option("--vis-range", help="With --vis: disparities MIN:MAX (px, e.g. 0:80) given the two end colours of "
                 "the picture, values beyond clipped to them, so that pictures of two runs compare (default: the "
                 "1st-99th percentile of the map's valid disparities).", show_default=False),
]


def _band_option(side: str) -> object:
    return typer.Option(f"--{side}-band", min=0, help=f"0-based band of a multi-band {side} file (default: luminance of colour images).")


@app.command()
def disparity(
    left: Annotated[Path, typer.Argument(help="Reference (left) image.", show_default=False)],
    right: Annotated[Path, typer.Argument(help="Other (right) image, possibly another band.", show_default=False)],
    output: Annotated[Path, typer.Option("--output", "-o", help="Disparity file: .pfm, .tif, .png (KITTI uint16) or .npy.")],
    method: MethodOption = DEFAULT_METHOD,
    max_disp: MaxDispAutoOption = None,
    min_disp: MinDispAutoOption = "0",
    preprocess: PreprocessOption = "auto",
    model: ModelOption = None,
    memory_limit: MemoryLimitOption = None,
    vis: Annotated[Optional[Path], typer.Option("--vis", help="Also write a colourised PNG with a colour bar in px "
                                                "(invalid = black).")] = None,
    vis_range: VisRangeOption = None,
    left_band: Annotated[Optional[int], _band_option("left")] = None,
    right_band: Annotated[Optional[int], _band_option("right")] = None,
    fill: Annotated[
        str, typer.Option("--fill", help="Pixels the matcher rejected: 'row' (filled from the background side "
                          "along the row; dense output) or 'none' (written as the format's invalid marker).")
    ] = "row",
    validity: Annotated[
        Optional[Path], typer.Option("--validity", help="Also write the validity mask: PNG (255 = valid, 0 = rejected) "
                                     "or TIFF (uint8 1/0).")
    ] = None,
    confidence: Annotated[
        Optional[Path], typer.Option("--confidence", help="Also write the matcher's confidence: float32 TIFF in [0, 1], "
                                     "higher = more trusted, 0 = rejected; keep pixels above a threshold to mask what "
                                     "the matcher is unsure of (README: what each method measures).")
    ] = None,
    rig_file: Annotated[
        Optional[Path], typer.Option("--rig", help="Rig file (`cade calibrate`): LEFT is its reference camera's "
                                     "image, RIGHT another camera's; the pair is rectified first (docs/rigs.md).")
    ] = None,
    camera: Annotated[Optional[str], typer.Option("--camera", help="With --rig: the camera that took RIGHT (default: "
                                                  "the rig's rectified pair, else the first other camera).")] = None,
    frame: Annotated[
        str, typer.Option("--frame", help="With --rig: outputs on the 'rectified' reference image, or resampled onto "
                          "the 'original' one (disparity stays in rectified px).")
    ] = "rectified",
    depth: Annotated[Optional[Path], typer.Option("--depth", help="With --rig: also write depth, float32 TIFF, "
                                                  "metres, NaN unknown.")] = None,
    points: Annotated[Optional[Path], typer.Option("--points", help="With --rig: also write a point cloud (binary "
                                                   "PLY, metres, reference camera frame, grey from LEFT).")] = None,
    fix_vertical: Annotated[bool, typer.Option("--fix-vertical", help="With --rig: correct the vertical offset and "
                                               "roll the rectification self-check measures before matching.")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Refuse a pair the pair check finds unrectified, swapped "
                                         "or outside the range searched (exit 1, nothing written) instead of "
                                         "warning.")] = False,
) -> None:
    """Disparity of LEFT against RIGHT, written to OUTPUT."""
    from cade_cli.disparity_io import DISPARITY_SUFFIXES, VALIDITY_SUFFIXES, write_match_outputs
    from cade_cli.atomic import atomic_outputs
    from cade_cli.errors import CadeError
    from cade_cli.matching import densify, get_matcher
    from cade_cli.tiling import estimate_disparity_tiled, plan_tiles

    if fill not in ("row", "none"):
        raise CadeError(f"unknown --fill {fill!r}; choose row or none")
    min_disp, max_disp = _parse_range_options(min_disp, max_disp)
    colour_range = _parse_vis_range(vis_range, vis)
    budget = _parse_memory_limit(memory_limit)
    _check_output(output, suffixes=DISPARITY_SUFFIXES, inputs=(left, right))
    if confidence is not None and confidence.suffix.lower() not in (".tif", ".tiff"):
        raise CadeError(f"cannot write --confidence {confidence}: the confidence is a float32 TIFF; "
                        f"name it .tif or .tiff")
    for option, side_output, suffixes in (("--vis", vis, (".png",)), ("--validity", validity, VALIDITY_SUFFIXES),
                                          ("--confidence", confidence, (".tif", ".tiff"))):
        if side_output is not None:
            _check_output(side_output, suffixes=suffixes, inputs=(left, right))
            if side_output.resolve() == output.resolve():
                raise CadeError(f"{option} {side_output} is the same file as --output; give it another name")
    if vis is not None and validity is not None and vis.resolve() == validity.resolve():
        raise CadeError(f"--vis and --validity both name {vis}; give them different names")
    if confidence is not None and validity is not None and confidence.resolve() == validity.resolve():
        raise CadeError(f"--confidence and --validity both name {confidence}; give them different names")
    rig_only = [option for option, given in (("--camera", camera is not None), ("--frame", frame != "rectified"),
                ("--depth", depth is not None), ("--points", points is not None), ("--fix-vertical", fix_vertical))
                if given]
    if rig_file is not None:
        _disparity_with_rig(
            rig_file, left, right, output=output, camera=camera, frame=frame, depth=depth, points=points,
            fix_vertical=fix_vertical, method=method, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess,
            model=model, memory_limit=budget, vis=vis, left_band=left_band, right_band=right_band, fill=fill,
            validity=validity, confidence=confidence, vis_range=colour_range, strict=strict)
        return
    if rig_only:
        raise CadeError(f"{rig_only[0]} needs --rig (the rig file that says how to rectify the pair); add --rig "
                        f"RIG.json or drop {rig_only[0]}")
    left_image, right_image = _read_pair(left, right, left_band, right_band)
    started = time.perf_counter()
    min_disp, max_disp = _resolve_range_options(min_disp, max_disp, left_image, right_image)
    pair_check = _check_pair(left_image, right_image, min_disp=min_disp, max_disp=max_disp, strict=strict)
    plan = plan_tiles(left_image, right_image, method=method, min_disp=min_disp, max_disp=max_disp,
                      memory_limit=budget, model=model)
    if plan.tiled:
        _note(plan.describe())
    result, _ = estimate_disparity_tiled(
        left_image, right_image, method=method, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess,
        model=model, memory_limit=budget, plan=plan,
    )
    seconds = time.perf_counter() - started
    preprocess = get_matcher(method).resolve_preprocess(preprocess)
    dense = densify(result.disparity, result.valid)
    _warn_if_textureless(left, right, left_image, right_image)
    if confidence is not None and result.confidence is None:
        raise CadeError(f"method {method} gives no confidence; drop --confidence")
    with atomic_outputs([output, vis, validity, confidence]) as staged:  # all outputs appear together, or none
        roles = {"disparity": output, "vis": vis, "validity": validity, "confidence": confidence}
        write_match_outputs({role: staged[path] for role, path in roles.items() if path is not None}, dense=dense,
                            disparity=result.disparity, valid=result.valid, confidence=result.confidence, fill=fill,
                            vis_range=colour_range)
    height, width = dense.shape
    print(
        f"{output}: {width}x{height}, {method}+{preprocess}, searched [{min_disp}, {max_disp}], "
        f"disparity {float(dense.min()):.2f}..{float(dense.max()):.2f} px, "
        f"valid {100.0 * result.valid.mean():.1f}%, fill {fill}, {pair_check.summary()}, {seconds:.2f} s"
    )


def _check_pair(left_image, right_image, *, min_disp: int, max_disp: int, strict: bool):
    """Run the pair check (:func:`cade_cli.pair_check.check_pair`) before matching: a
    problem found is a warning, or with ``strict`` an error; returns the check (None for
    a pair the matcher refuses anyway, with its own message: sizes that differ, an
    impossible range)."""
    from cade_cli.errors import CadeError
    from cade_cli.pair_check import check_pair

    if left_image.shape != right_image.shape or max_disp < min_disp:
        return None
    found = check_pair(left_image, right_image, min_disp=min_disp, max_disp=max_disp)
    if found.problems and strict:
        raise CadeError(f"{found.describe()} (--strict)")
    if found.problems:
        _warn(found.describe())
    return found


def _disparity_with_rig(rig_file: Path, left: Path, right: Path, *, output: Path, camera, frame, depth, points,
                        fix_vertical, method, max_disp, min_disp, preprocess, model, memory_limit, vis, left_band,
                        right_band, fill, validity, confidence, vis_range=None, strict=False) -> None:
    """`cade disparity --rig`: rectify LEFT/RIGHT through the rig, check, match (the range
    resolved on the rectified pair, whole or as tiles within ``memory_limit``, bytes), write
    in the chosen frame."""
    import numpy as np

    from cade_cli.atomic import atomic_outputs
    from cade_cli.errors import CadeError
    from cade_cli.matching import get_matcher
    from cade_cli.range import AUTO
    from cade_cli.rectification import FRAMES, VERTICAL_TOLERANCE_PX
    from cade_cli.rig import load_rig
    from cade_cli.rig_pair import check_rig_pair, match_rig_pair, rig_pair_rectification, write_rig_outputs

    if frame not in FRAMES:
        raise CadeError(f"unknown --frame {frame!r}; choose rectified or original")
    inputs = (left, right, rig_file)
    for option, path, suffixes in (("--depth", depth, (".tif", ".tiff")), ("--points", points, (".ply",))):
        if path is not None:
            _check_output(path, suffixes=suffixes, inputs=inputs)
    get_matcher(method).resolve_preprocess(preprocess)  # refuse unknown names before any work
    rig = load_rig(rig_file)
    other, rectification = rig_pair_rectification(rig, camera)
    left_image, right_image = _read_pair(left, right, left_band, right_band)
    check_rig_pair(rig, rectification, left_image, right_image, paths=(left, right))
    started = time.perf_counter()
    width = rectification.image_size[0]
    if AUTO not in (min_disp, max_disp):
        max_disp = _resolve_max_disp(max_disp, width)
    found, framed = match_rig_pair(rig, left_image, right_image, other=other, frame=frame, fill=fill,
                                   fix_vertical=fix_vertical, method=method, max_disp=max_disp, min_disp=min_disp,
                                   preprocess=preprocess, model=model, memory_limit=memory_limit)
    seconds = time.perf_counter() - started
    if found.range_estimate is not None:
        _note(found.range_estimate.describe(estimated=(min_disp == AUTO, max_disp == AUTO)))
    if found.plan.tiled:
        _note(found.plan.describe())
    if found.misalignment is not None:
        if strict and not fix_vertical and found.misalignment.worst(width) > VERTICAL_TOLERANCE_PX:
            raise CadeError(f"rectification self-check: vertical misalignment up to "
                            f"{found.misalignment.worst(width):.2f} px, above {VERTICAL_TOLERANCE_PX} px; add "
                            "--fix-vertical or recalibrate (--strict)")
        _report_misalignment(found.misalignment, width, fixed=fix_vertical, corrected=found.corrected)
    else:
        _warn(f"rectification self-check skipped: {found.self_check_problem}")
    _warn_if_textureless(left, right, found.left, found.right)
    files = {"disparity": output, "vis": vis, "validity": validity, "confidence": confidence, "depth": depth,
             "points": points}
    with atomic_outputs(list(files.values())) as staged:  # all outputs appear together, or none
        written = write_rig_outputs({role: None if path is None else staged[path] for role, path in files.items()},
                                    framed, fill=fill, method=method, vis_range=vis_range)
    height, width = framed.dense.shape
    known = framed.dense[framed.valid] if framed.valid.any() else framed.dense[:1] * 0
    print(f"{output}: {width}x{height} ({frame} frame of {rectification.cameras[0]}; rectified "
          f"{rectification.cameras[0]}-{rectification.cameras[1]}, focal {rectification.focal:.1f} px, baseline "
          f"{rectification.baseline:.4g} m), {method}+{get_matcher(method).resolve_preprocess(preprocess)}, searched "
          f"[{found.range.minimum}, {found.range.maximum}], "
          f"disparity {float(np.nanmin(known)):.2f}..{float(np.nanmax(known)):.2f} px, "
          f"valid {100.0 * framed.valid.mean():.1f}%, fill {fill}, {seconds:.2f} s"
          + (f"; {written} points in {points}" if points is not None else ""))


@app.command()
def register(
    context: typer.Context,
    moving: Annotated[Path, typer.Argument(help="Band to warp (right view).", show_default=False)],
    reference: Annotated[Path, typer.Argument(help="Reference band (left view).", show_default=False)],
    output: Annotated[Path, typer.Option("--output", "-o", help="Float32 TIFF: reference, registered, validity bands.")],
    disparity_file: Annotated[
        Optional[Path], typer.Option("--disparity", help="Use this reference-view disparity instead of estimating it "
                                     "(its invalid markers -- inf, NaN, 0 in PNG -- are not trusted).")
    ] = None,
    validity_file: Annotated[
        Optional[Path], typer.Option("--validity", help="With --disparity: the validity mask `cade disparity "
                                     "--validity` wrote; only its valid pixels are trusted.")
    ] = None,
    method: MethodOption = DEFAULT_METHOD,
    max_disp: MaxDispOption = None,
    min_disp: MinDispOption = 0,
    preprocess: PreprocessOption = "auto",
    model: ModelOption = None,
    fill: Annotated[
        str, typer.Option("--fill", help="Occluded pixels: 'row' (background along the row) or 'none' (NaN).")
    ] = "row",
    moving_band: Annotated[Optional[int], typer.Option("--moving-band", min=0, help="0-based band of the moving file.")] = None,
    reference_band: Annotated[
        Optional[int], typer.Option("--reference-band", min=0, help="0-based band of the reference file.")
    ] = None,
    vis: Annotated[Optional[Path], typer.Option("--vis", help="Also write a PNG to judge the registration by: the "
                                                "reference in magenta, the registered band in green (aligned = grey), "
                                                "no valid registration tinted blue.")] = None,
    vis_mode: Annotated[str, typer.Option("--vis-mode", help="With --vis: 'overlay' (magenta / green) or 'checker' "
                                          "(a checkerboard of the two bands' tiles).")] = "overlay",
) -> None:
    """Warp MOVING into the view of REFERENCE and write both as one multi-band TIFF."""
    from cade_cli.atomic import atomic_outputs
    from cade_cli.disparity_io import read_disparity
    from cade_cli.registration import register as register_band
    from cade_cli.registration_io import REGISTRATION_VIS_MODES, write_registration, write_registration_picture

    from cade_cli.errors import CadeError

    inputs = tuple(p for p in (moving, reference, disparity_file, validity_file) if p is not None)
    _check_output(output, suffixes=(".tif", ".tiff"), inputs=inputs)
    if vis is not None:
        _check_output(vis, suffixes=(".png",), inputs=inputs)
    if vis_mode not in REGISTRATION_VIS_MODES:
        raise CadeError(f"unknown --vis-mode {vis_mode!r}; choose {' or '.join(REGISTRATION_VIS_MODES)}")
    if vis is None and context.get_parameter_source("vis_mode").name != "DEFAULT":
        raise CadeError("--vis-mode says how --vis draws the registration; add --vis PICTURE.png or drop --vis-mode")
    if validity_file is not None and disparity_file is None:
        raise CadeError("--validity needs --disparity (it masks that map); drop it or give the disparity file")
    if fill not in ("row", "none"):
        raise CadeError(f"unknown --fill {fill!r}; choose row or none")
    if disparity_file is not None:
        estimation = [f"--{name.replace('_', '-')}" for name in ("method", "max_disp", "min_disp", "preprocess", "model")
                      if context.get_parameter_source(name).name != "DEFAULT"]
        if estimation:
            named = " and ".join([", ".join(estimation[:-1]), estimation[-1]] if len(estimation) > 1 else estimation)
            verb, pronoun = ("apply", "them") if len(estimation) > 1 else ("applies", "it")
            raise CadeError(f"{named} only {verb} when the disparity is estimated, but --disparity gives it; drop "
                            f"{pronoun} or --disparity")
    else:
        from cade_cli.matching import get_matcher

        get_matcher(method).resolve_preprocess(preprocess)  # refuse unknown names before reading anything
    reference_image, moving_image = _read_pair(
        reference, moving, reference_band, moving_band, names=("--reference-band", "--moving-band")
    )
    started = time.perf_counter()
    if disparity_file is not None:
        from cade_cli.disparity_io import read_validity

        trusted = read_validity(validity_file) if validity_file is not None else None
        result = register_band(moving_image, reference_image, disparity=read_disparity(disparity_file),
                               disparity_valid=trusted, fill=fill, disparity_name=str(disparity_file))
        source = f"disparity from {disparity_file}" + (f", validity from {validity_file}" if trusted is not None else "")
    else:
        max_disp = _resolve_max_disp(max_disp, reference_image.shape[1])
        result = register_band(
            moving_image, reference_image, method=method, max_disp=max_disp, min_disp=min_disp,
            preprocess=preprocess, fill=fill, model=model,
        )
        from cade_cli.matching import get_matcher

        source = f"{method}+{get_matcher(method).resolve_preprocess(preprocess)} over [{min_disp}, {max_disp}]"
        _warn_if_textureless(reference, moving, reference_image, moving_image)
    seconds = time.perf_counter() - started
    with atomic_outputs([output, vis]) as staged:  # all outputs appear together, or none
        write_registration(staged[output], result)
        if vis is not None:
            write_registration_picture(staged[vis], result, mode=vis_mode)
    height, width = result.reference.shape
    print(f"{output}: {width}x{height}, {source}, fill {fill}, valid {100.0 * result.valid.mean():.1f}%, {seconds:.2f} s")


@app.command()
def calibrate(
    camera: Annotated[
        list[str], typer.Option("--camera", "-c", help="NAME:BAND:PATTERN, once per camera, e.g. "
                                "--camera 'left:bp400:calib/left*.png' (quote the pattern). The first camera is the "
                                "reference unless --reference names another. Views are paired across cameras by the "
                                "last number in the file names (left07 with right07); names without numbers pair by "
                                "sorted order.", show_default=False)
    ],
    board: Annotated[str, typer.Option("--board", help="chessboard:COLSxROWS (inner corners, e.g. chessboard:9x6) or "
                                       "charuco:COLSxROWS (squares, e.g. charuco:11x8).", show_default=False)],
    square: Annotated[float, typer.Option("--square", help="Side of a board square, metres (the unit of every "
                                          "translation and depth that follows).", show_default=False)],
    output: Annotated[Path, typer.Option("--output", "-o", help="Rig file to write (.json).")],
    marker: Annotated[Optional[float], typer.Option("--marker", help="ChArUco: side of a marker, metres (default "
                                                    "0.75 x --square).")] = None,
    dictionary: Annotated[str, typer.Option("--dictionary", help="ChArUco: the ArUco dictionary.")] = "DICT_5X5_100",
    reference: Annotated[Optional[str], typer.Option("--reference", help="Reference camera (default: the first).")] = None,
    vis: Annotated[Optional[Path], typer.Option("--vis", help="Also write a picture of the detections of each view "
                                                "to this folder (CAMERA_VIEW.png; a red frame: board not found, "
                                                "orange: found but the view was left out).")] = None,
) -> None:
    """Calibrate two or more cameras from pictures of a chessboard or ChArUco board and write a rig file."""
    import glob

    import cv2

    from cade_cli.atomic import atomic_outputs
    from cade_cli.calibration import CameraImages, calibrate_rig, draw_detection, parse_board
    from cade_cli.errors import CadeError
    from cade_cli.imageio import SUPPORTED_IMAGE_SUFFIXES, read_band
    from cade_cli.rig import save_rig

    _check_output(output, suffixes=(".json",), inputs=())
    chosen = parse_board(board, square=square, marker=marker, dictionary=dictionary)
    cameras = []
    for spec in camera:
        parts = spec.split(":", 2)
        if len(parts) != 3 or not all(parts):
            raise CadeError(f"--camera {spec!r} not understood; write NAME:BAND:PATTERN, e.g. 'left:bp400:left*.png'")
        name, band, pattern = parts
        files = tuple(Path(p) for p in sorted(glob.glob(pattern))
                      if Path(p).suffix.lower() in SUPPORTED_IMAGE_SUFFIXES and Path(p).is_file())
        if not files:
            raise CadeError(f"camera {name}: {pattern!r} matches no image file; check the pattern (relative to "
                            f"{Path.cwd()})")
        cameras.append(CameraImages(name, band, files))
    with atomic_outputs([output], folders=[vis]) as staged:
        found = calibrate_rig(cameras, chosen, reference=reference)
        rig = found.rig
        for note in found.notes:
            _note(note)
        if vis is not None:
            for key, files in found.views:
                for name, path in files.items():
                    picture = draw_detection(read_band(path)[0], chosen, found.detections[name].get(key),
                                             left_out=key in found.left_out[name])
                    cv2.imwrite(str(staged[vis] / f"{name}_{key}.png"), picture)
        save_rig(rig, staged[output])
    names = rig.names
    print("view  " + "  ".join(f"{name:>12}" for name in names) + "   (reprojection error, px)")
    for view in rig.calibration.views:
        print(f"{view['view']:<5} " + "  ".join(f"{view['errors'][n]:12.3f}" if n in view["errors"] else f"{'-':>12}"
                                                 for n in names))
    rectification = rig.rectification
    print(f"{output}: {len(names)} cameras ({', '.join(f'{c.name} {c.band}' for c in rig.cameras)}), reference "
          f"{rig.reference}; {len(rig.calibration.views)} views used, {len(rig.calibration.rejected)} left out; "
          f"RMS {rig.calibration.rms:.3f} px (cameras: "
          + ", ".join(f"{n} {v:.3f}" for n, v in rig.calibration.camera_rms.items())
          + f"); rectified {rectification.cameras[0]}-{rectification.cameras[1]}: focal {rectification.focal:.1f} px, "
          f"baseline {rectification.baseline:.4g} m")


@app.command()
def rectify(
    rig_file: Annotated[Path, typer.Argument(metavar="RIG", help="Rig file (`cade calibrate` writes one).", show_default=False)],
    left: Annotated[Path, typer.Argument(help="Image of the rig's reference camera.", show_default=False)],
    right: Annotated[Path, typer.Argument(help="Image of the other camera.", show_default=False)],
    output: Annotated[tuple[Path, Path], typer.Option("--output", "-o", help="The rectified left and right image: "
                                                      ".png (8 bits) or .tif (float32).", show_default=False)],
    camera: Annotated[Optional[str], typer.Option("--camera", help="The rig's camera that took RIGHT (default: the "
                                                  "one in the rig's rectification, else the first other camera).")] = None,
    epipolar: Annotated[Optional[Path], typer.Option("--epipolar", help="Also write the pair side by side with "
                                                     "horizontal lines (PNG).")] = None,
    fix_vertical: Annotated[bool, typer.Option("--fix-vertical", help="Correct the vertical offset and roll the "
                                               "self-check measures in the rectified right image.")] = False,
) -> None:
    """Rectify a pair of a rig's cameras (reference = left) and check the result's vertical alignment."""
    import cv2

    from cade_cli.atomic import atomic_outputs
    from cade_cli.imageio import load_image
    from cade_cli.rectification import (
        MIN_CORRECTION_PX, RECTIFIED_IMAGE_SUFFIXES, check_image_size, correct_vertical_misalignment,
        epipolar_picture, luminance_of, measure_vertical_misalignment, needs_mirroring, rectification_of,
        rectify_pair, write_rectified_image,
    )
    from cade_cli.errors import CadeError
    from cade_cli.rig import load_rig

    for path in output:
        _check_output(path, suffixes=RECTIFIED_IMAGE_SUFFIXES, inputs=(left, right, rig_file))
    if epipolar is not None:
        _check_output(epipolar, suffixes=(".png",), inputs=(left, right, rig_file))
    rig = load_rig(rig_file)
    other = camera if camera is not None or rig.rectification is None else rig.rectification.cameras[1]
    rectification = rectification_of(rig, other)
    images = [load_image(path) for path in (left, right)]
    for name, image, path in zip(rectification.cameras, images, (left, right)):
        check_image_size(rig, name, image, path=path)
    left_rect, right_rect = rectify_pair(rig, *images, rectification=rectification)
    try:
        found = measure_vertical_misalignment(luminance_of(left_rect), luminance_of(right_rect),
                                              mirrored=needs_mirroring(rectification))
    except CadeError as error:
        if fix_vertical:
            raise
        found = None
        _warn(f"self-check skipped: {str(error).split(';')[0]}")
    if found is not None:
        corrected = fix_vertical and found.worst(left_rect.shape[1]) >= MIN_CORRECTION_PX  # as align_vertically
        _report_misalignment(found, left_rect.shape[1], fixed=fix_vertical, corrected=corrected)
        if corrected:
            right_rect = correct_vertical_misalignment(right_rect, found)
    with atomic_outputs([*output, epipolar]) as staged:
        write_rectified_image(staged[output[0]], left_rect)
        write_rectified_image(staged[output[1]], right_rect)
        if epipolar is not None:
            cv2.imwrite(str(staged[epipolar]), epipolar_picture(left_rect, right_rect))
    width, height = rectification.image_size
    print(f"{output[0]}, {output[1]}: {rectification.cameras[0]}-{rectification.cameras[1]} rectified to "
          f"{width}x{height}, focal {rectification.focal:.1f} px, baseline {rectification.baseline:.4g} m")


def _report_misalignment(found, width: int, *, fixed: bool, corrected: bool) -> None:
    """Tell the user what the rectification self-check measured (a warning above the tolerance)."""
    import math

    from cade_cli.rectification import MIN_CORRECTION_PX, VERTICAL_TOLERANCE_PX

    worst = found.worst(width)
    measured = (f"offset {found.offset:+.2f} px, roll {math.degrees(found.roll):+.3f} deg (up to {worst:.2f} px at "
                f"the edges), from {found.matches} matches")
    if corrected:
        _note(f"rectification self-check: {measured}; corrected (--fix-vertical)")
    elif fixed:
        _note(f"rectification self-check: {measured}; below {MIN_CORRECTION_PX} px, left as is (--fix-vertical)")
    elif worst > VERTICAL_TOLERANCE_PX:
        _warn(f"rectification self-check: vertical misalignment {measured}, above {VERTICAL_TOLERANCE_PX} px; "
              "add --fix-vertical or recalibrate")
    else:
        _note(f"rectification self-check: {measured}")


@app.command()
def benchmark(
    dataset: Annotated[str, typer.Option("--dataset", "-d", help="middlebury05, middlebury06, middlebury14, flyingthings3d, kitti2012, kitti2015 or folder.")],
    data_dir: Annotated[Path, typer.Option("--data-dir", help="Folder holding the dataset in its official layout.")],
    methods: Annotated[str, typer.Option("--methods", help="Comma-separated matchers.")] = ",".join(BENCHMARK_METHODS),
    protocol: Annotated[str, typer.Option("--protocol", help="Comma-separated: cs (six band pairs), rgb (median of R/G/B), native (grey pair).")] = "cs,rgb",
    preprocess: Annotated[str, typer.Option("--preprocess", help="Comma-separated: none, cade, auto.")] = "none,cade",
    scenes: Annotated[Optional[str], typer.Option("--scenes", help="Comma-separated scene names (default: all).")] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", min=1, help="Worker processes.")] = 1,
    json_file: Annotated[Optional[Path], typer.Option("--json", help="Write every number as JSON.")] = None,
    report: Annotated[Optional[Path], typer.Option("--report", help="Write a Markdown report.")] = None,
    save_dir: Annotated[Optional[Path], typer.Option("--save-dir", help="Write each disparity (PFM) and error map (PNG) here.")] = None,
    model: Annotated[Optional[str], typer.Option("--model", help="Network(s) of the learned methods, as for `cade "
                                                 "disparity --model`; several, comma-separated, score each learned "
                                                 "method once per model in the same run (rows METHOD:MODEL, e.g. "
                                                 "cade:cade-v4, cade:runs/x.json -> cade:x).")] = None,
) -> None:
    """Score matchers on a dataset with the paper's protocols (CS, RGB) and print a Table-1-style summary."""
    import shlex

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from cade_cli.atomic import atomic_outputs
    from cade_cli.evaluation.loop import run_benchmark
    from cade_cli.evaluation.report import confidence_table, confidence_title, markdown, pixel_sets, table, title
    from cade_cli.errors import CadeError
    from cade_cli.matching import LEARNED_METHODS, MATCHERS, get_matcher

    for path, suffix in ((json_file, ".json"), (report, ".md")):
        if path is not None:
            _check_output(path, suffixes=(suffix,), inputs=())
    split = lambda text: [item.strip() for item in text.split(",") if item.strip()]  # noqa: E731
    for option, value in (("--methods", methods), ("--protocol", protocol), ("--preprocess", preprocess),
                          ("--scenes", scenes)):
        if value is not None and not split(value):
            raise CadeError(f"{option} {value!r} names nothing; give comma-separated names, or leave it out for the default")
    console = Console(stderr=True)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    # Every output is checked before the run and staged during it; all appear at the end, or none.
    with atomic_outputs([json_file, report], folders=[save_dir]) as staged:
        with Progress(*columns, console=console, transient=True, disable=not console.is_terminal) as progress:
            bar = progress.add_task(f"benchmark {dataset}", total=None)

            def advance(scene: str, records: list) -> None:
                progress.update(bar, advance=1, description=f"{dataset} {scene} done")

            learned = [name for name in split(methods) if name in LEARNED_METHODS]
            if model is not None and not learned:
                raise CadeError(f"--model applies to {', '.join(LEARNED_METHODS)}; add one to --methods")
            models = split(model) if model is not None else []
            if model is not None and not models:
                raise CadeError(f"--model {model!r} names nothing; give a model, or leave it out for the shipped one")
            chosen, matchers = split(methods), dict(MATCHERS)
            if len(models) == 1:
                matchers.update({name: get_matcher(name, model=models[0]) for name in learned})
            elif models:  # one row per learned method and model: METHOD:MODEL
                labels = [Path(name).stem if name.endswith(".json") else name for name in models]
                if len(set(labels)) != len(labels):
                    raise CadeError(f"--model names two models called the same ({', '.join(labels)}); rename a card")
                chosen = [f"{name}:{label}" if name in learned else name
                          for name in chosen for label in (labels if name in learned else [None])]
                matchers.update({f"{name}:{label}": get_matcher(name, model=path)
                                 for name in learned for label, path in zip(labels, models)})
            run = run_benchmark(
                dataset=dataset, data_dir=data_dir, methods=chosen, protocols=split(protocol),
                preprocess=split(preprocess), scenes=None if scenes is None else split(scenes), jobs=jobs,
                save_dir=None if save_dir is None else staged[save_dir], on_scene_done=advance, matchers=matchers,
                on_start=lambda total: progress.update(bar, total=total),
            )
        out = Console()
        tables = [(title(run, pixels), *table(run, pixels)) for pixels in pixel_sets(run)]
        confidence = confidence_table(run)  # how well each matcher's confidence ranks its errors
        if confidence is not None:
            tables.append((confidence_title(run), *confidence))
        for heading, header, rows in tables:
            rich_table = Table(title=heading, title_justify="left")
            for i, name in enumerate(header):
                rich_table.add_column(name, justify="left" if i == 0 else "right", no_wrap=i == 0)
            for row in rows:
                rich_table.add_row(*row)
            out.print(rich_table)
        command = shlex.join(["cade", *sys.argv[1:]]) if sys.argv[1:2] == ["benchmark"] else None
        if json_file is not None:
            staged[json_file].write_text(run.to_json())
        if report is not None:
            staged[report].write_text(markdown(run, command=command))


datasets_app = typer.Typer(
    help="List the benchmark datasets and download them from their official hosts.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
app.add_typer(datasets_app, name="datasets")


@datasets_app.command("list")
def datasets_list() -> None:
    """Each dataset: what a download holds, its approximate size and where it comes from."""
    from cade_cli.data import SOURCES

    width = max(len(name) for name in SOURCES) + 2
    for source in SOURCES.values():
        sizes = ", ".join(f"{key} {size}" if key else size for key, size in source.sizes.items())
        print(f"{source.name:<{width}}{source.contents} [{sizes}]")
        print(f"{'':<{width}}{source.source}")
    print("download with: cade datasets download NAME --to DIR (Middlebury: --resolution Q|H|F); read with --data-dir DIR")


@datasets_app.command("download")
def datasets_download(
    name: Annotated[str, typer.Argument(help="middlebury05, middlebury06, middlebury14, kitti2012 or kitti2015.", show_default=False)],
    to: Annotated[Path, typer.Option("--to", help="Data folder; the dataset lands in its usual subfolder, read with --data-dir DIR.")],
    resolution: Annotated[
        Optional[str],
        typer.Option("--resolution", help="Middlebury only: Q, H or F (default Q; 2005/2006: Q = ThirdSize).", show_default=False),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Download and unpack again even if the files are in place.")] = False,
) -> None:
    """Download dataset NAME into DIR (resuming an interrupted download) and check its files."""
    from contextlib import nullcontext

    from rich.console import Console

    from cade_cli.data import download_dataset, download_progress, get_source

    resolution = resolution.upper() if resolution else None
    get_source(name).archives(resolution)  # refuse a bad request before any output
    console = Console(stderr=True)
    progress = download_progress(console) if console.is_terminal else None  # no bars in logs
    with progress if progress is not None else nullcontext():
        report = download_dataset(name, to, resolution=resolution, force=force, progress=progress)
    at = f" ({report.resolution})" if report.resolution else ""
    if report.already_present:
        print(f"{name}{at}: already present in {report.folder}; use --data-dir {to}")
    else:
        print(
            f"{name}{at}: {len(report.downloaded)} archive(s) downloaded ({report.bytes_downloaded / 1e6:.1f} MB), "
            f"{len(report.extracted)} unpacked, {len(report.present)} already present, in {report.folder}; "
            f"use --data-dir {to}"
        )


# --- camera arrays (cade_cli.array; docs/rigs.md, "Camera arrays") ---------------------------------------------------


@app.command("register-array")
def register_array(
    rig_file: Annotated[Path, typer.Argument(metavar="RIG", help="Rig file of the array (docs/rigs.md).",
                                             show_default=False)],
    images: Annotated[list[Path], typer.Argument(metavar="IMAGE...", help="One image per camera, in the rig's camera "
                                                 "order, or each named after its camera (file stem = camera name).",
                                                 show_default=False)],
    output: Annotated[Path, typer.Option("--output", "-o", help="Cube: planar float32 TIFF, the reference band, each "
                                         "registered band, then one validity band per camera; band names in the "
                                         "description.")],
    method: MethodOption = DEFAULT_METHOD,
    min_disp: Annotated[float, typer.Option("--min-disp", help="Smallest disparity searched, px per unit baseline "
                                            "(the rig's shortest); negative: behind the rig's plane.")] = -16.0,
    max_disp: Annotated[float, typer.Option("--max-disp", help="Largest disparity searched, px per unit baseline; "
                                            "each camera searches the range times its baseline ratio.")] = 16.0,
    match_scale: Annotated[float, typer.Option("--match-scale", min=0.05, max=1.0, help="Match at this fraction of "
                                               "the resolution (faster; the disparity is brought back to full "
                                               "size).")] = 1.0,
    plane_only: Annotated[bool, typer.Option("--plane-only", help="Register on the rig's plane alone (its "
                                             "to_reference mappings, or the rotation of a calibrated rig), no "
                                             "parallax: the baseline `cade array-score` compares against.")] = False,
    preprocess: PreprocessOption = "auto",
    model: ModelOption = None,
    disparity_file: Annotated[Optional[Path], typer.Option("--disparity", help="Also write the fused disparity of the "
                                                           "reference view, px per unit baseline (.pfm, .tif, .npy; "
                                                           "invalid where no camera voted).")] = None,
    vis: Annotated[Optional[Path], typer.Option("--vis", help="Also write a false-colour PNG of three bands (colour "
                                                "fringes along edges = misregistration).")] = None,
    vis_bands: Annotated[Optional[str], typer.Option("--vis-bands", help="Cameras shown as red,green,blue in --vis "
                                                     "(default: the first camera, the reference, the last).")] = None,
) -> None:
    """Register every camera of the array in RIG onto its reference camera: one multi-band cube."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from cade_cli.array import array_cube, array_geometry, false_colour, write_array_cube
    from cade_cli.array import register_array as register_cameras
    from cade_cli.atomic import atomic_outputs
    from cade_cli.disparity_io import write_disparity
    from cade_cli.errors import CadeError
    from cade_cli.imageio import read_band
    from cade_cli.matching import get_matcher
    from cade_cli.rig import load_rig

    _check_output(output, suffixes=(".tif", ".tiff"), inputs=(rig_file, *images))
    if disparity_file is not None:
        if plane_only:
            raise CadeError("--disparity needs the parallax estimated; drop it or --plane-only")
        _check_output(disparity_file, suffixes=(".pfm", ".tif", ".tiff", ".npy"), inputs=(rig_file, *images))
    if vis is not None:
        _check_output(vis, suffixes=(".png",), inputs=(rig_file, *images))
    if not plane_only:
        get_matcher(method).resolve_preprocess(preprocess)  # refuse unknown names before reading anything
    rig = load_rig(rig_file)
    geometry = array_geometry(rig)
    order = (geometry.reference, *geometry.cameras)
    channels = None
    if vis is not None:
        channels = ([name.strip() for name in vis_bands.split(",")] if vis_bands is not None
                    else [rig.cameras[0].name, rig.reference, rig.cameras[-1].name])
        unknown = [name for name in channels if name not in rig.names]
        if len(channels) != 3 or unknown:
            raise CadeError(f"--vis-bands must name three cameras of the rig ({', '.join(rig.names)}), "
                            f"got {vis_bands!r}")
    if len(images) != len(rig.cameras):
        raise CadeError(f"the rig has {len(rig.cameras)} cameras ({', '.join(rig.names)}) but {len(images)} images "
                        "were given; give one image per camera")
    by_stem = {path.stem: path for path in images}
    if set(by_stem) == set(rig.names):
        paths = {name: by_stem[name] for name in rig.names}
    else:
        paths = dict(zip(rig.names, images))
    bands = []
    for camera in order:
        band, note = read_band(paths[camera.name])
        if note:
            _note(f"{note}; camera {camera.name} uses it")
        bands.append(band)
    console = Console(stderr=True)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    started = time.perf_counter()
    with Progress(*columns, console=console, transient=True, disable=not console.is_terminal) as progress:
        task = "matching cameras" if not plane_only else "warping cameras"
        bar = progress.add_task(task, total=len(geometry.cameras))
        registration = register_cameras(
            bands, geometry, parallax=not plane_only, method=method, search=(min_disp, max_disp), scale=match_scale,
            preprocess=preprocess, model=model,
            on_camera=lambda name: progress.update(bar, advance=1, description=f"{name} done"),
        )
    seconds = time.perf_counter() - started
    details = {"rig": str(rig_file), "images": [str(paths[c.name]) for c in order], "plane_only": plane_only}
    if not plane_only:
        details.update(method=method, preprocess=get_matcher(method).resolve_preprocess(preprocess),
                       search=[min_disp, max_disp], match_scale=match_scale)
    cube = array_cube(registration, details=details)
    with atomic_outputs([output, disparity_file, vis]) as staged:  # all outputs appear together, or none
        write_array_cube(staged[output], cube)
        if disparity_file is not None:
            import numpy as np

            fused = np.where(registration.disparity_valid, registration.disparity, np.float32(np.nan))
            write_disparity(staged[disparity_file], fused)
        if vis is not None:
            import cv2

            cv2.imwrite(str(staged[vis]), false_colour(cube, channels))
    width, height = geometry.size
    source = "the rig's plane only" if plane_only else (
        f"{details['method']}+{details['preprocess']} over [{min_disp:g}, {max_disp:g}] px per "
        f"{1000 * geometry.unit:g} mm of baseline at scale {match_scale:g}")
    seen = ", ".join(f"{c.name} {100 * v.mean():.0f}%" for c, v in zip(geometry.cameras, registration.valid))
    print(f"{output}: {width}x{height}, {len(order)} cameras onto {geometry.reference.name}, {source}; valid: {seen}; "
          f"{seconds:.1f} s")


@app.command("array-score")
def array_score(
    cubes: Annotated[list[Path], typer.Argument(metavar="CUBE...", help="Cubes of one array (`cade register-array`), "
                                                "e.g. a --plane-only one and cade's.", show_default=False)],
    window: Annotated[int, typer.Option("--window", min=3, max=101, help="Side of the windows gradients are "
                                        "correlated in, px.")] = 15,
) -> None:
    """Alignment of each registered band with the reference band, without ground truth.

    For every camera: the mean local normalised gradient correlation (NGC, 1 = every edge
    where the reference has it, whatever the contrast) and the mutual information (bits),
    over the pixels valid in every cube given, so cubes are compared on the same pixels.
    """
    from rich.console import Console
    from rich.table import Table

    from cade_cli.array import read_array_cube, score_cubes

    loaded = [read_array_cube(path) for path in cubes]
    scores = score_cubes(loaded, window=window)
    table = Table(title=f"alignment with {loaded[0].reference_name} (NGC: window {window} px; MI: 64 bins)",
                  title_justify="left")
    for name in ["camera", "band", "scored %", *(f"NGC {p.name}" for p in cubes), *(f"MI {p.name}" for p in cubes)]:
        table.add_column(name, justify="left" if name in ("camera", "band") else "right")
    for k in range(len(loaded[0].cameras)):
        table.add_row(scores[0][k].camera, scores[0][k].band, f"{100 * scores[0][k].scored_share:.1f}",
                      *(f"{s[k].gradient_correlation:.3f}" for s in scores),
                      *(f"{s[k].mutual_information:.3f}" for s in scores))
    table.add_row("mean", "", "", *(f"{sum(x.gradient_correlation for x in s) / len(s):.3f}" for s in scores),
                  *(f"{sum(x.mutual_information for x in s) / len(s):.3f}" for s in scores))
    Console(width=200).print(table)


# --- many pairs (cade_cli.batch; docs/scale.md) ----------------------------------------------------------------------


@app.command()
def batch(
    left: Annotated[Optional[str], typer.Option("--left", help="Glob pattern of the left images, quoted (e.g. "
                                                "'cam0/*.png'); paired with --right by file name (or, without "
                                                "shared names, by the last number in the names).")] = None,
    right: Annotated[Optional[str], typer.Option("--right", help="Glob pattern of the right images, quoted.")] = None,
    output_dir: Annotated[Optional[Path], typer.Option("--output-dir", "-o", help="With --left/--right: folder for "
                                                       "the outputs, <left name>.<format> (created if missing).")] = None,
    manifest: Annotated[Optional[Path], typer.Option("--manifest", help="CSV with a header row: left,right,output "
                                                     "and optionally min_disp,max_disp,left_band,right_band (empty = "
                                                     "the option's value); relative paths start at its folder.")] = None,
    output_format: Annotated[str, typer.Option("--format", help="With --left/--right: disparity format, pfm, tif, "
                                               "png (KITTI uint16) or npy.")] = "pfm",
    method: MethodOption = DEFAULT_METHOD,
    max_disp: MaxDispAutoOption = None,
    min_disp: MinDispAutoOption = "0",
    preprocess: PreprocessOption = "auto",
    model: ModelOption = None,
    fill: Annotated[str, typer.Option("--fill", help="As `cade disparity --fill`: 'row' (dense) or 'none'.")] = "row",
    left_band: Annotated[Optional[int], _band_option("left")] = None,
    right_band: Annotated[Optional[int], _band_option("right")] = None,
    vis: Annotated[bool, typer.Option("--vis", help="Also write <name>_vis.png (colourised, with a colour bar in px; "
                                      "invalid = black).")] = False,
    vis_range: VisRangeOption = None,
    validity: Annotated[bool, typer.Option("--validity", help="Also write <name>_validity.png (255 = valid).")] = False,
    confidence: Annotated[bool, typer.Option("--confidence", help="Also write <name>_confidence.tif (float32, "
                                             "[0, 1]).")] = False,
    memory_limit: Annotated[
        Optional[str], typer.Option("--memory-limit", help="Memory budget of each job, like 4GB or 512MB (default: "
                                    "half the memory available): a pair that does not fit it whole is matched as "
                                    "tiles, as by `cade disparity --memory-limit`; --jobs is lowered so that the "
                                    "jobs fit.", show_default=False)
    ] = None,
    rig_file: Annotated[
        Optional[Path], typer.Option("--rig", help="Rig file (`cade calibrate`): each LEFT is its reference camera's "
                                     "image, each RIGHT another camera's; every pair is rectified first, as by "
                                     "`cade disparity --rig` (docs/rigs.md).")
    ] = None,
    camera: Annotated[Optional[str], typer.Option("--camera", help="With --rig: the camera that took the RIGHT images "
                                                  "(default: the rig's rectified pair, else the first other "
                                                  "camera).")] = None,
    frame: Annotated[
        str, typer.Option("--frame", help="With --rig: outputs on the 'rectified' reference image, or resampled onto "
                          "the 'original' one (disparity stays in rectified px).")
    ] = "rectified",
    depth: Annotated[bool, typer.Option("--depth", help="With --rig: also write <name>_depth.tif (float32, metres, "
                                        "NaN unknown).")] = False,
    points: Annotated[bool, typer.Option("--points", help="With --rig: also write <name>_points.ply (binary PLY, "
                                         "metres, reference camera frame).")] = False,
    fix_vertical: Annotated[bool, typer.Option("--fix-vertical", help="With --rig: correct the vertical offset and "
                                               "roll the rectification self-check measures before matching.")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="A pair the pair check finds unrectified, swapped or "
                                         "outside the range searched fails (nothing written for it) instead of "
                                         "warning.")] = False,
    jobs: Annotated[int, typer.Option("--jobs", "-j", min=1, help="Worker processes on this machine, each loading "
                                      "the model once; lowered if their memory would not fit.")] = 1,
    threads: Annotated[Optional[int], typer.Option("--threads", min=1, help="Threads of each worker (default: the "
                                                   "cores shared among --jobs; on a cluster, the workers' own).")] = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Run on a Dask cluster: its scheduler, "
                                                     "tcp://host:8786 (needs the 'distributed' extra; docs/scale.md).")] = None,
    scheduler_file: Annotated[Optional[Path], typer.Option("--scheduler-file", help="Run on the Dask cluster whose "
                                                           "scheduler wrote this file.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Redo every pair, even those verified as finished.")] = False,
    log: Annotated[Optional[Path], typer.Option("--log", help="JSON log of the run (default: cade-batch-log.json in "
                                                "--output-dir, or <manifest>.log.json).")] = None,
) -> None:
    """Disparity of many pairs: resumable, one pair failing does not stop the others, on N processes or a Dask cluster.

    A rerun skips every pair whose outputs are verified (sha256 and options in the record
    beside each output, <output>.cade.json); --force redoes them. The exit status is 1 if
    any pair failed.
    """
    from contextlib import nullcontext

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeRemainingColumn
    from rich.text import Text

    from cade_cli.atomic import atomic_output
    from cade_cli.batch import (
        BatchSummary, PairOptions, available_memory_bytes, cap_jobs, is_finished, job_memory_bytes, log_document,
        pairs_from_manifest, pairs_from_patterns, remove_stale_temporaries, run_dask, run_local, skipped_result,
    )
    from cade_cli.errors import CadeError

    by_pattern = (left, right, output_dir)
    if manifest is not None and any(value is not None for value in by_pattern):
        raise CadeError("give either --manifest or --left, --right and --output-dir, not both")
    if manifest is None and any(value is None for value in by_pattern):
        missing = [name for name, value in zip(("--left", "--right", "--output-dir"), by_pattern) if value is None]
        raise CadeError(f"missing {', '.join(missing)}: give --left 'A/*.png' --right 'B/*.png' --output-dir OUT, or "
                        "--manifest pairs.csv")
    if scheduler is not None and scheduler_file is not None:
        raise CadeError("give --scheduler or --scheduler-file, not both")
    cluster = scheduler is not None or scheduler_file is not None
    if cluster and jobs != 1:
        raise CadeError("--jobs sets processes on this machine; on a cluster the workers' own --nworkers do; drop --jobs")
    min_disp, max_disp = _parse_range_options(min_disp, max_disp)
    options = PairOptions(method=method, min_disp=min_disp, max_disp=max_disp, preprocess=preprocess, model=model,
                          fill=fill, left_band=left_band, right_band=right_band,
                          memory_limit=None if memory_limit is None else _parse_memory_limit(memory_limit),
                          rig=None if rig_file is None else str(rig_file.absolute()), camera=camera, frame=frame,
                          fix_vertical=fix_vertical, vis=vis, validity=validity, confidence=confidence, depth=depth,
                          points=points, vis_range=_parse_vis_range(vis_range, vis), strict=strict)
    options.check()
    if manifest is not None:
        pairs = pairs_from_manifest(manifest, options=options)
        log = log if log is not None else manifest.with_name(manifest.stem + ".log.json")
    else:
        pairs = pairs_from_patterns(left, right, output_dir, options=options, suffix="." + output_format.lower().lstrip("."))
        if output_dir.exists() and not output_dir.is_dir():
            raise CadeError(f"--output-dir {output_dir} is a file; give a folder")
        output_dir.mkdir(parents=True, exist_ok=True)
        log = log if log is not None else output_dir / "cade-batch-log.json"
    _check_output(log, suffixes=(".json",), inputs=())
    remove_stale_temporaries(pairs)  # left by a run that was killed
    results = [] if force else [skipped_result(pair) for pair in pairs if is_finished(pair)]
    finished = {result.output for result in results}
    todo = [pair for pair in pairs if str(pair.output) not in finished]
    engine_name = f"dask {scheduler or scheduler_file}" if cluster else f"{jobs} local job(s)"
    if todo and not cluster and jobs > 1:
        width, height, per_job = job_memory_bytes(todo)  # the largest pair, or the memory limit
        allowed = cap_jobs(jobs, per_job)
        if allowed < jobs:
            _note(f"--jobs {jobs} lowered to {allowed}: the largest pair, {width}x{height}, may take "
                  f"{per_job / 2**30:.1f} GB per job (within its memory limit) and "
                  f"{available_memory_bytes() / 2**30:.1f} GB are available")
            jobs, engine_name = allowed, f"{allowed} local job(s)"
    if threads is None and not cluster and jobs > 1:
        threads = max(1, (os.cpu_count() or 1) // jobs)
    engine = (run_dask(todo, address=scheduler, scheduler_file=scheduler_file, threads=threads) if cluster
              else run_local(todo, jobs=jobs, threads=threads))
    summary = BatchSummary(total=len(pairs), skipped=len(results))
    config = {"command": ["cade", *sys.argv[1:]] if sys.argv[1:2] == ["batch"] else None, "engine": engine_name,
              "manifest": None if manifest is None else str(manifest), "left": left, "right": right,
              "output_dir": None if output_dir is None else str(output_dir), "force": force,
              "rig": None if rig_file is None else str(rig_file),
              "options": {key: value for key, value in options.fingerprint().items()}}

    class PairRate(ProgressColumn):
        def render(self, task) -> Text:
            rate = task.completed / task.elapsed if task.elapsed else 0.0
            return Text(f"{rate:.2f} pairs/s")

    console = Console(stderr=True, soft_wrap=True)
    progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), PairRate(),
                        TextColumn("ETA"), TimeRemainingColumn(), console=console, transient=True,
                        disable=not console.is_terminal)
    if summary.skipped:
        _note(f"{summary.skipped} of {len(pairs)} pairs already finished (outputs verified); --force redoes them")
    started = time.perf_counter()
    shown_notes: set[str] = set()
    try:
        with progress if todo else nullcontext():
            bar = progress.add_task(f"batch ({engine_name})", total=len(todo))
            for result in engine:
                results.append(result)
                summary.add(result)
                for note in result.notes:
                    if note not in shown_notes:
                        shown_notes.add(note)
                        progress.console.print(f"note: {note}", highlight=False, markup=False)
                for warning in result.warnings:  # the pair check's findings
                    progress.console.print(f"warning: {result.output}: {warning}", highlight=False, markup=False)
                if result.status == "failed":
                    progress.console.print(f"warning: pair {result.left}, {result.right} failed: {result.error}",
                                           highlight=False, markup=False)
                elif result.range_note is not None:
                    progress.console.print(f"note: {result.output}: {result.range_note}", highlight=False, markup=False)
                progress.update(bar, advance=1)
    except KeyboardInterrupt:
        summary.interrupted = True
        _warn(f"interrupted: {summary.done} pair(s) finished in this run, their outputs complete; rerun the same "
              f"command to go on (finished pairs are skipped); log {log}")
        raise
    finally:
        summary.seconds = time.perf_counter() - started
        remove_stale_temporaries(todo)
        with atomic_output(log) as temporary:
            temporary.write_text(log_document(results, summary, config=config))
    print(f"{summary.done} done, {summary.skipped} already finished, {summary.failed} failed, of {summary.total} pairs; "
          f"{summary.seconds:.1f} s ({summary.pairs_per_minute:.1f} pairs/min, {engine_name}); log {log}")
    if summary.failed:
        raise CadeError(f"{summary.failed} of {summary.total} pairs failed (each named above and in {log})")


def _read_pair(
    left: Path, right: Path, left_band: int | None, right_band: int | None,
    names: tuple[str, str] = ("--left-band", "--right-band"),
):
    from cade_cli.imageio import read_band

    images = []
    for path, band, option in ((left, left_band, names[0]), (right, right_band, names[1])):
        image, note = read_band(path, band)
        if note:
            _note(f"{note}; pick a band with {option} N")
        images.append(image)
    return images


def _warn_if_textureless(left: Path, right: Path, left_image, right_image) -> None:
    """Warn when much of the pair is flat (:func:`cade_cli.stereo.textureless`): no disparity there."""
    from cade_cli.stereo import TEXTURE_WINDOW, textureless

    flat = textureless(left_image) | textureless(right_image)
    share = float(flat.mean())
    if share == 1.0:
        _warn(f"{left} and {right} have no texture at all (constant images?): there is no disparity to find and "
              "every pixel is marked invalid; check that these are the right, correctly exposed images")
    elif share >= 0.5:
        _warn(f"{100 * share:.0f}% of {left} / {right} is flat (one value over {TEXTURE_WINDOW}x{TEXTURE_WINDOW} px "
              "in a band: blank, saturated or underexposed); disparity there is marked invalid")


def _resolve_max_disp(max_disp: int | None, width: int) -> int:
    from cade_cli.stereo import default_max_disparity

    if max_disp is not None:
        return max_disp
    chosen = default_max_disparity(width)
    _note(f"--max-disp not given: searching up to {chosen} px (a quarter of the width); "
          "set it to your scene's largest disparity for speed and accuracy")
    return chosen


def _parse_range_options(min_disp: str | int, max_disp: str | int | None) -> tuple[int | str, int | str | None]:
    """--min-disp and --max-disp as given: whole pixels or 'auto' (:func:`cade_cli.range.parse_bound`)."""
    from cade_cli.range import parse_bound

    return (parse_bound(min_disp, option="min-disp"),
            None if max_disp is None else parse_bound(max_disp, option="max-disp", minimum=1))


def _resolve_range_options(min_disp: int | str, max_disp: int | str | None, left_image, right_image) -> tuple[int, int]:
    """The searched (min, max), px: 'auto' bounds estimated and announced on stderr, a
    missing --max-disp defaulted (:func:`_resolve_max_disp`)."""
    from cade_cli.range import AUTO, resolve_range

    if AUTO not in (min_disp, max_disp):
        return int(min_disp), _resolve_max_disp(max_disp, left_image.shape[1])
    searched, estimate = resolve_range(left_image, right_image, min_disp=min_disp, max_disp=max_disp)
    _note(estimate.describe(estimated=(min_disp == AUTO, max_disp == AUTO)))
    return searched.minimum, searched.maximum


def _parse_vis_range(vis_range: str | None, vis: object) -> tuple[float, float] | None:
    """--vis-range MIN:MAX as (min, max) px (:func:`cade_cli.pictures.parse_value_range`),
    refused without --vis (``vis``: its value, None or False when not given)."""
    from cade_cli.errors import CadeError
    from cade_cli.pictures import parse_value_range

    if vis_range is None:
        return None
    if vis is None or vis is False:
        raise CadeError("--vis-range sets the colours of the --vis picture; add --vis PICTURE.png or drop --vis-range")
    return parse_value_range(vis_range, option="--vis-range")


def _parse_memory_limit(memory_limit: str | None) -> int:
    """--memory-limit in bytes (:func:`cade_cli.tiling.parse_memory`); None: the default budget."""
    from cade_cli.tiling import default_memory_limit, parse_memory

    return default_memory_limit() if memory_limit is None else parse_memory(memory_limit)


def _check_output(path: Path, *, suffixes: tuple[str, ...], inputs: tuple[Path, ...]) -> None:
    """Refuse, before any work, outputs we could not write or must not overwrite."""
    from cade_cli.atomic import check_writable
    from cade_cli.errors import CadeError

    if path.suffix.lower() not in suffixes:
        raise CadeError(f"cannot write {path}: unsupported extension {path.suffix or '(none)'}; use one of {', '.join(suffixes)}")
    check_writable(path)  # the folder exists, is one, and takes new files; path is not a folder
    for source in inputs:
        if source.exists() and path.exists() and path.resolve() == source.resolve():
            raise CadeError(f"output {path} is also an input; choose another output name")


def _note(message: str) -> None:
    print(f"note: {message}", file=sys.stderr)


def _warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, turning every user error into one stderr line."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")  # decoders would print their own warnings
    from cade_cli.allocator import retain_freed_memory
    from cade_cli.errors import CadeError

    retain_freed_memory()

    argv = sys.argv[1:] if argv is None else argv
    try:
        code = app(args=argv or ["--help"], standalone_mode=False)
    except CadeError as error:
        _fail(str(error), EXIT_INPUT_ERROR)
    except typer.TyperException as error:  # usage errors: unknown option, bad value, ...
        _fail(f"{error.format_message().rstrip('.')}; see 'cade --help'", getattr(error, "exit_code", EXIT_USAGE_ERROR))
    except (typer.Abort, KeyboardInterrupt):
        _fail("interrupted", 130)
    except MemoryError:
        _fail("out of memory; lower --max-disp or downscale the images", EXIT_INPUT_ERROR)
    sys.exit(code if isinstance(code, int) else 0)


def _fail(message: str, code: int) -> None:
    print(f"cade: error: {message.splitlines()[0] if message else 'failed'}", file=sys.stderr)
    sys.exit(code)
