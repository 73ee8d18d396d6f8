"""Commands on camera rigs: ``cade calibrate``, ``cade rectify``, ``cade register-array`` and
``cade array-score`` (docs/rigs.md).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli.cli.options import (
    DEFAULT_METHOD, MethodOption, ModelOption, PreprocessOption, StepBar, check_output, print_note, print_warning,
    report_misalignment,
)


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

    from cade_cli.errors import CadeError
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.image_files import SUPPORTED_IMAGE_SUFFIXES
    from cade_cli.io.images import read_band
    from cade_cli.rigs.boards import draw_detection, parse_board
    from cade_cli.rigs.calibration import CameraImages, calibrate_rig, implausible_scale, widest_baseline
    from cade_cli.rigs.rig_file import save_rig

    check_output(output, suffixes=(".json",), inputs=())
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
            print_note(note)
        if vis is not None:
            for key, files in found.views:
                for name, path in files.items():
                    picture = draw_detection(read_band(path)[0], chosen, found.detections[name].get(key),
                                             left_out=key in found.left_out[name])
                    cv2.imwrite(str(staged[vis] / f"{name}_{key}.png"), picture)
        save_rig(rig, staged[output])
    warning = implausible_scale(square, widest_baseline(rig))
    if warning is not None:
        print_warning(warning)
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


def rectify(
    rig_file: Annotated[Path, typer.Argument(metavar="[RIG]", help="Rig file (`cade calibrate` writes one); none "
                                             "with --uncalibrated.", show_default=False)],
    left: Annotated[Path, typer.Argument(help="Image of the rig's reference camera.", show_default=False)],
    output: Annotated[tuple[Path, Path], typer.Option("--output", "-o", help="The rectified left and right image: "
                                                      ".png (8 bits) or .tif (float32).", show_default=False)],
    right: Annotated[Optional[Path], typer.Argument(help="Image of the other camera.", show_default=False)] = None,
    camera: Annotated[Optional[str], typer.Option("--camera", help="The rig's camera that took RIGHT (default: the "
                                                  "one in the rig's rectification, else the first other camera).")] = None,
    epipolar: Annotated[Optional[Path], typer.Option("--epipolar", help="Also write the pair side by side with "
                                                     "horizontal lines (PNG).")] = None,
    fix_vertical: Annotated[bool, typer.Option("--fix-vertical", help="Correct the vertical offset and roll the "
                                               "self-check measures in the rectified right image.")] = False,
    uncalibrated: Annotated[bool, typer.Option("--uncalibrated", help="No rig: `cade rectify --uncalibrated LEFT "
                                               "RIGHT -o L R` estimates the warp from feature matches between the "
                                               "bands (a vertical offset and rotation, or a full uncalibrated "
                                               "rectification where the matches support it) and writes it beside "
                                               "L as L.rectification.json.")] = False,
) -> None:
    """Rectify a pair of a rig's cameras (reference = left), or with --uncalibrated a pair alone, and check the result's
    vertical alignment."""
    import cv2

    from cade_cli.errors import CadeError
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.images import load_image
    from cade_cli.rigs.outputs import RECTIFIED_IMAGE_SUFFIXES, epipolar_picture, luminance_of, write_rectified_image
    from cade_cli.rigs.rectification import check_image_size, needs_mirroring, rectification_of, rectify_pair
    from cade_cli.rigs.rig_file import load_rig
    from cade_cli.rigs.self_check import MIN_CORRECTION_PX, correct_vertical_misalignment, measure_vertical_misalignment

    if uncalibrated:
        from cade_cli.cli.uncalibrated import rectify_uncalibrated

        if right is not None or camera is not None or fix_vertical:
            extra = "rig file" if right is not None else "--camera" if camera is not None else "--fix-vertical"
            raise CadeError(f"--uncalibrated rectifies LEFT RIGHT from the pair alone and takes no {extra}: write "
                            "cade rectify --uncalibrated LEFT RIGHT -o L_RECT R_RECT")
        rectify_uncalibrated(rig_file, left, output, epipolar)  # the two files given: LEFT RIGHT
        return
    if right is None:
        raise CadeError("cade rectify takes RIG LEFT RIGHT; without a rig file, add --uncalibrated (the warp from the "
                        "pair alone)")
    for path in output:
        check_output(path, suffixes=RECTIFIED_IMAGE_SUFFIXES, inputs=(left, right, rig_file))
    if epipolar is not None:
        check_output(epipolar, suffixes=(".png",), inputs=(left, right, rig_file))
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
        print_warning(f"self-check skipped: {str(error).split(';')[0]}")
    if found is not None:
        corrected = fix_vertical and found.worst(left_rect.shape[1]) >= MIN_CORRECTION_PX  # as align_vertically
        report_misalignment(found, left_rect.shape[1], fixed=fix_vertical, corrected=corrected)
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
    min_disp: Annotated[str, typer.Option("--min-disp", metavar="<float|auto>", help="Smallest disparity searched, "
                                          "px per unit baseline (the rig's shortest); negative: behind the rig's "
                                          "plane; auto: each camera's own, from a coarse match.")] = "-16",
    max_disp: Annotated[str, typer.Option("--max-disp", metavar="<float|auto>", help="Largest disparity searched, px "
                                          "per unit baseline; each camera searches the range times its baseline "
                                          "ratio; auto: each camera's own, from a coarse match.")] = "16",
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
    from cade_cli.errors import CadeError
    from cade_cli.matching import get_matcher
    from cade_cli.rigs.array import register_array as register_cameras
    from cade_cli.rigs.array_cube import array_cube
    from cade_cli.rigs.array_geometry import array_geometry
    from cade_cli.rigs.rig_file import load_rig
    from cade_cli.scale.range import AUTO

    check_output(output, suffixes=(".tif", ".tiff"), inputs=(rig_file, *images))
    search = _array_search(min_disp, max_disp, plane_only)
    if disparity_file is not None:
        if plane_only:
            raise CadeError("--disparity needs the parallax estimated; drop it or --plane-only")
        check_output(disparity_file, suffixes=(".pfm", ".tif", ".tiff", ".npy"), inputs=(rig_file, *images))
    if vis is not None:
        check_output(vis, suffixes=(".png",), inputs=(rig_file, *images))
    if not plane_only:
        get_matcher(method).resolve_preprocess(preprocess)  # refuse unknown names before reading anything
    rig = load_rig(rig_file)
    geometry = array_geometry(rig)
    order = (geometry.reference, *geometry.cameras)
    channels = None if vis is None else _false_colour_cameras(rig, vis_bands)
    paths = _image_of_each_camera(rig, images)
    bands = _read_camera_bands(order, paths)
    started = time.perf_counter()
    with StepBar(len(geometry.cameras), "matching cameras" if not plane_only else "warping cameras", plain=True,
                 noun="cameras") as bar:
        registration = register_cameras(
            bands, geometry, parallax=not plane_only, method=method, search=search, scale=match_scale,
            preprocess=preprocess, model=model,
            on_camera=lambda name: bar.advance(f"{name} done"),
        )
    seconds = time.perf_counter() - started
    details = {"rig": str(rig_file), "images": [str(paths[c.name]) for c in order], "plane_only": plane_only}
    if not plane_only:
        details.update(method=method, preprocess=get_matcher(method).resolve_preprocess(preprocess),
                       search=[AUTO if bound is None else bound for bound in search], match_scale=match_scale)
    cube = array_cube(registration, details=details)
    _write_array_outputs(output, cube, registration, disparity_file=disparity_file, vis=vis, channels=channels)
    width, height = geometry.size
    searched = ", ".join(AUTO if bound is None else f"{bound:g}" for bound in search)
    source = "the rig's plane only" if plane_only else (
        f"{details['method']}+{details['preprocess']} over [{searched}] px per "
        f"{1000 * geometry.unit:g} mm of baseline at scale {match_scale:g}")
    seen = ", ".join(f"{c.name} {100 * v.mean():.0f}%" for c, v in zip(geometry.cameras, registration.valid))
    print(f"{output}: {width}x{height}, {len(order)} cameras onto {geometry.reference.name}, {source}; valid: {seen}; "
          f"{seconds:.1f} s")


def _read_camera_bands(order, paths: dict[str, Path]) -> list:
    """The band of each camera of ``order`` (reference first), read from its image in ``paths``
    (camera name -> file); a note when a colour image is reduced to one band."""
    from cade_cli.io.images import read_band

    bands = []
    for camera in order:
        band, note = read_band(paths[camera.name])
        if note:
            print_note(f"{note}; camera {camera.name} uses it")
        bands.append(band)
    return bands


def _write_array_outputs(output: Path, cube, registration, *, disparity_file: Path | None, vis: Path | None,
                         channels: list[str] | None) -> None:
    """Write register-array's cube, and the fused disparity (NaN where no camera voted) and the
    false-colour picture of ``channels`` when asked: all outputs appear together, or none."""
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.disparity import write_disparity
    from cade_cli.rigs.array_cube import false_colour, write_array_cube

    with atomic_outputs([output, disparity_file, vis]) as staged:
        write_array_cube(staged[output], cube)
        if disparity_file is not None:
            import numpy as np

            fused = np.where(registration.disparity_valid, registration.disparity, np.float32(np.nan))
            write_disparity(staged[disparity_file], fused)
        if vis is not None:
            import cv2

            cv2.imwrite(str(staged[vis]), false_colour(cube, channels))


def _array_search(min_disp: str, max_disp: str, plane_only: bool) -> tuple[float | None, float | None]:
    """register-array's range, px per unit baseline (None: ``auto``), refused when empty before
    any image is read."""
    from cade_cli.errors import CadeError

    search = (_array_bound(min_disp, "min-disp"), _array_bound(max_disp, "max-disp"))
    if not plane_only and None not in search and not search[0] < search[1]:
        raise CadeError(f"--max-disp {max_disp} is not above --min-disp {min_disp}: nothing to search; "
                        f"give a --max-disp above --min-disp (px per unit baseline)")
    return search


def _array_bound(text: str, option: str) -> float | None:
    """A bound of register-array's range: px per unit baseline, or None for ``auto``."""
    from cade_cli.errors import CadeError
    from cade_cli.scale.range import AUTO

    if text.strip().lower() == AUTO:
        return None
    try:
        return float(text)
    except ValueError:
        raise CadeError(f"--{option} {text!r} is not a number of px per unit baseline or 'auto'") from None


def _false_colour_cameras(rig, vis_bands: str | None) -> list[str]:
    """The three cameras ``--vis`` shows as red, green, blue: ``--vis-bands`` or (default) the
    first camera, the reference, the last."""
    from cade_cli.errors import CadeError

    channels = ([name.strip() for name in vis_bands.split(",")] if vis_bands is not None
                else [rig.cameras[0].name, rig.reference, rig.cameras[-1].name])
    if len(channels) != 3 or any(name not in rig.names for name in channels):
        raise CadeError(f"--vis-bands must name three cameras of the rig ({', '.join(rig.names)}), got {vis_bands!r}")
    return channels


def _image_of_each_camera(rig, images: list[Path]) -> dict[str, Path]:
    """Camera name -> its image: by file stem when the stems are the camera names, else in the rig's order."""
    from cade_cli.errors import CadeError

    if len(images) != len(rig.cameras):
        raise CadeError(f"the rig has {len(rig.cameras)} cameras ({', '.join(rig.names)}) but {len(images)} images "
                        "were given; give one image per camera")
    by_stem = {path.stem: path for path in images}
    if set(by_stem) == set(rig.names):
        return {name: by_stem[name] for name in rig.names}
    return dict(zip(rig.names, images))


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

    from cade_cli.rigs.array_cube import read_array_cube
    from cade_cli.rigs.array_score import score_cubes

    loaded = [read_array_cube(path) for path in cubes]
    scores = score_cubes(loaded, window=window, names=[str(path) for path in cubes])
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
