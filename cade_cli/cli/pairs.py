"""``cade disparity``: the disparity of one pair of bands, with or without a rig (``cade register``: its own module).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli.cli.options import (
    DEFAULT_METHOD, MaxDispAutoOption, MemoryLimitOption, MethodOption, MinDispAutoOption, ModelOption,
    PreprocessOption, StepBar, VisRangeOption, band_option, check_output, parse_memory_limit, parse_range_options,
    parse_vis_range, print_note, print_warning, read_pair, report_misalignment, resolve_max_disp, resolve_range_options,
    warn_if_textureless,
)


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
    left_band: Annotated[Optional[int], band_option("left")] = None,
    right_band: Annotated[Optional[int], band_option("right")] = None,
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
    strict: Annotated[bool, typer.Option("--strict", help="Refuse a pair the pair check finds unrectified, swapped "
                                         "or outside the range searched (exit 1, nothing written) instead of "
                                         "warning.")] = False,
    # the options of rigs and unrectified pairs come last in --help, apart from the everyday ones
    rig_file: Annotated[
        Optional[Path], typer.Option("--rig", help="Rig file (`cade calibrate`): LEFT is its reference camera's "
                                     "image, RIGHT another camera's; the pair is rectified first (docs/rigs.md).")
    ] = None,
    camera: Annotated[Optional[str], typer.Option("--camera", help="With --rig: the camera that took RIGHT (default: "
                                                  "the rig's rectified pair, else the first other camera).")] = None,
    frame: Annotated[
        str, typer.Option("--frame", help="With --rig or --fix-vertical: outputs on the 'rectified' reference image, "
                          "or resampled onto the 'original' one (disparity stays in rectified px).")
    ] = "rectified",
    depth: Annotated[Optional[Path], typer.Option("--depth", help="With --rig: also write depth, float32 TIFF, "
                                                  "metres, NaN unknown.")] = None,
    points: Annotated[Optional[Path], typer.Option("--points", help="With --rig: also write a point cloud (binary "
                                                   "PLY, metres, reference camera frame, grey from LEFT).")] = None,
    fix_vertical: Annotated[bool, typer.Option("--fix-vertical", help="Correct the vertical offset and roll before "
                                               "matching: with --rig, what the rectification self-check measures; "
                                               "without, the warp estimated from the pair alone (as cade rectify "
                                               "--uncalibrated; recorded in OUTPUT.rectification.json).")] = False,
) -> None:
    """Disparity of LEFT against RIGHT, written to OUTPUT."""
    from cade_cli.errors import CadeError
    from cade_cli.io.disparity import DISPARITY_SUFFIXES

    if fill not in ("row", "none"):
        raise CadeError(f"unknown --fill {fill!r}; choose row or none")
    min_disp, max_disp = parse_range_options(min_disp, max_disp)
    colour_range = parse_vis_range(vis_range, vis)
    budget = parse_memory_limit(memory_limit)
    check_output(output, suffixes=DISPARITY_SUFFIXES, inputs=(left, right))
    _check_side_outputs(output, (left, right), vis=vis, validity=validity, confidence=confidence)
    if rig_file is not None:
        _disparity_with_rig(
            rig_file, left, right, output=output, camera=camera, frame=frame, depth=depth, points=points,
            fix_vertical=fix_vertical, method=method, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess,
            model=model, memory_limit=budget, vis=vis, left_band=left_band, right_band=right_band, fill=fill,
            validity=validity, confidence=confidence, vis_range=colour_range, strict=strict)
        return
    _refuse_rig_options(camera=camera, depth=depth, points=points, frame=frame, fix_vertical=fix_vertical)
    left_image, right_image = read_pair(left, right, left_band, right_band)
    started = time.perf_counter()
    warp, warp_record = None, None
    if fix_vertical:  # no rig: the warp from the pair alone
        warp, warp_record, left_image, right_image = _fix_vertical_alone(output, (left, right), frame, left_image,
                                                                         right_image)
    _match_and_write(left, right, left_image, right_image, output=output, vis=vis, validity=validity,
                     confidence=confidence, warp=warp, warp_record=warp_record, frame=frame, method=method,
                     min_disp=min_disp, max_disp=max_disp, preprocess=preprocess, model=model, memory_limit=budget,
                     fill=fill, vis_range=colour_range, strict=strict, started=started)


def _refuse_rig_options(*, camera, depth, points, frame: str, fix_vertical: bool) -> None:
    """Without ``--rig``: refuse the options only a rig gives a meaning to."""
    from cade_cli.errors import CadeError

    rig_only = [option for option, given in (("--camera", camera is not None), ("--depth", depth is not None),
                ("--points", points is not None), ("--frame", frame != "rectified" and not fix_vertical)) if given]
    if rig_only:
        raise CadeError(f"{rig_only[0]} needs --rig (the rig file that says how to rectify the pair); add --rig "
                        f"RIG.json or drop {rig_only[0]}")


def _fix_vertical_alone(output: Path, inputs: tuple[Path, ...], frame: str, left_image, right_image):
    """``cade disparity --fix-vertical`` without a rig: ``--frame`` checked, then
    :func:`cade_cli.cli.uncalibrated.fix_vertical_alone` (returns the warp, its record's path, the rectified pair)."""
    from cade_cli.cli.uncalibrated import fix_vertical_alone
    from cade_cli.errors import CadeError
    from cade_cli.rigs.outputs import FRAMES

    if frame not in FRAMES:
        raise CadeError(f"unknown --frame {frame!r}; choose rectified or original")
    return fix_vertical_alone(output, inputs, left_image, right_image)


def _check_side_outputs(output: Path, inputs: tuple[Path, ...], *, vis: Path | None, validity: Path | None,
                        confidence: Path | None) -> None:
    """Refuse a side output of ``cade disparity`` (--vis, --validity, --confidence) of the wrong
    kind, or named as the disparity or as another side output, before reading anything."""
    from cade_cli.errors import CadeError
    from cade_cli.io.disparity import VALIDITY_SUFFIXES

    if confidence is not None and confidence.suffix.lower() not in (".tif", ".tiff"):
        raise CadeError(f"cannot write --confidence {confidence}: the confidence is a float32 TIFF; "
                        f"name it .tif or .tiff")
    for option, side_output, suffixes in (("--vis", vis, (".png",)), ("--validity", validity, VALIDITY_SUFFIXES),
                                          ("--confidence", confidence, (".tif", ".tiff"))):
        if side_output is not None:
            check_output(side_output, suffixes=suffixes, inputs=inputs)
            if side_output.resolve() == output.resolve():
                raise CadeError(f"{option} {side_output} is the same file as --output; give it another name")
    if vis is not None and validity is not None and vis.resolve() == validity.resolve():
        raise CadeError(f"--vis and --validity both name {vis}; give them different names")
    if confidence is not None and validity is not None and confidence.resolve() == validity.resolve():
        raise CadeError(f"--confidence and --validity both name {confidence}; give them different names")


def _match_and_write(left: Path, right: Path, left_image, right_image, *, output: Path, vis, validity, confidence,
                     warp, warp_record, frame: str, method: str, min_disp: int | str, max_disp: int | str | None,
                     preprocess: str,
                     model: str | None, memory_limit: int, fill: str, vis_range, strict: bool, started: float) -> None:
    """`cade disparity` without a rig, once the pair is read (and rectified by ``warp`` with
    --fix-vertical): resolve the range on the pair (``min_disp``/``max_disp`` as parsed: px or 'auto'),
    check the pair, match it, write the disparity and the side outputs asked for (all together, or
    none) and print the one-line summary; ``started``: when the work began."""
    from cade_cli.errors import CadeError
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.disparity import check_disparity_range
    from cade_cli.io.match_outputs import write_match_outputs
    from cade_cli.matching import densify, get_matcher

    min_disp, max_disp = resolve_range_options(min_disp, max_disp, left_image, right_image)
    check_disparity_range(output, min_disp, max_disp)  # before any matching: a 16-bit PNG holds [0, 256) px
    with StepBar(3, "checking the pair") as bar:  # check, match (or one step per tile), write
        pair_check = check_pair_before_matching(left_image, right_image, min_disp=min_disp, max_disp=max_disp,
                                                strict=strict)
        bar.advance("matching")
        result = _match_pair(bar, left_image, right_image, method=method, min_disp=min_disp, max_disp=max_disp,
                             preprocess=preprocess, model=model, memory_limit=memory_limit)
        seconds = time.perf_counter() - started
        preprocess = get_matcher(method).resolve_preprocess(preprocess)
        dense = densify(result.disparity, result.valid)
        warn_if_textureless(left, right, left_image, right_image)
        if confidence is not None and result.confidence is None:
            raise CadeError(f"method {method} gives no confidence; drop --confidence")
        unfilled, valid, trust = result.disparity, result.valid, result.confidence
        if warp is not None and frame == "original":
            from cade_cli.rigs.uncalibrated import match_in_original_frame

            unfilled, valid, dense, trust = match_in_original_frame(warp, unfilled, valid, dense, trust)
        with atomic_outputs([output, vis, validity, confidence, warp_record]) as staged:  # all appear, or none
            roles = {"disparity": output, "vis": vis, "validity": validity, "confidence": confidence}
            write_match_outputs({role: staged[path] for role, path in roles.items() if path is not None}, dense=dense,
                                disparity=unfilled, valid=valid, confidence=trust, fill=fill, vis_range=vis_range)
            if warp is not None:
                from cade_cli.cli.uncalibrated import write_warp_record

                write_warp_record(staged[warp_record], warp, left=str(left), right=str(right), frame=frame)
    height, width = dense.shape
    print(
        f"{output}: {width}x{height}, {method}+{preprocess}, searched [{min_disp}, {max_disp}], "
        f"disparity {float(dense.min()):.2f}..{float(dense.max()):.2f} px, "
        f"valid {100.0 * valid.mean():.1f}%, fill {fill}, {pair_check.summary()}, {seconds:.2f} s"
        + (f"; {frame} frame of the uncalibrated {warp.model} rectification ({warp_record})" if warp else "")
    )


def _match_pair(bar: StepBar, left_image, right_image, *, method: str, min_disp: int, max_disp: int, preprocess: str,
                model: str | None, memory_limit: int):
    """Match a pair (no rig) whole, or as tiles when it does not fit ``memory_limit`` (bytes; the
    plan announced), advancing ``bar`` one step for the whole pair or one per tile."""
    from cade_cli.scale.tiling import estimate_disparity_tiled, plan_tiles

    plan = plan_tiles(left_image, right_image, method=method, min_disp=min_disp, max_disp=max_disp,
                      memory_limit=memory_limit, model=model)
    if plan.tiled:
        print_note(plan.describe())
        bar.advance(f"matching {len(plan.tiles)} tiles", steps=0, more=len(plan.tiles) - 1)
    result, _ = estimate_disparity_tiled(
        left_image, right_image, method=method, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess,
        model=model, memory_limit=memory_limit, plan=plan,
        on_tile=lambda done, total: bar.advance(f"matching: tile {done} of {total} done"),
    )
    bar.advance("writing", steps=0 if plan.tiled else 1)
    return result


def check_pair_before_matching(left_image, right_image, *, min_disp: int, max_disp: int, strict: bool, roles: str | None = None):
    """Run the pair check (:func:`cade_cli.pair_check.check_pair`) before matching: a
    problem found is a warning, or with ``strict`` an error; returns the check (None for
    a pair the matcher refuses anyway, with its own message: sizes that differ, an
    impossible range). ``roles``: how a swapped pair is undone (default: the reference image first)."""
    from cade_cli.errors import CadeError
    from cade_cli.pair_check import check_pair

    if left_image.shape != right_image.shape or max_disp < min_disp:
        return None
    found = check_pair(left_image, right_image, min_disp=min_disp, max_disp=max_disp)
    described = found.describe() if roles is None else found.describe(swap_fix=roles)
    if found.problems and strict:
        raise CadeError(f"{described} (--strict)")
    if found.problems:
        print_warning(described)
    return found


def _disparity_with_rig(rig_file: Path, left: Path, right: Path, *, output: Path, camera, frame, depth, points,
                        fix_vertical, method, max_disp, min_disp, preprocess, model, memory_limit, vis, left_band,
                        right_band, fill, validity, confidence, vis_range=None, strict=False) -> None:
    """`cade disparity --rig`: rectify LEFT/RIGHT through the rig, check, match (the range
    resolved on the rectified pair, whole or as tiles within ``memory_limit``, bytes), write
    in the chosen frame."""
    import numpy as np

    from cade_cli.errors import CadeError
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.disparity import check_disparity_range
    from cade_cli.matching import get_matcher
    from cade_cli.rigs.outputs import FRAMES
    from cade_cli.rigs.pair import check_rig_pair, match_rig_pair, rig_pair_rectification, write_rig_outputs
    from cade_cli.rigs.rig_file import load_rig
    from cade_cli.rigs.self_check import VERTICAL_TOLERANCE_PX
    from cade_cli.scale.range import AUTO

    if frame not in FRAMES:
        raise CadeError(f"unknown --frame {frame!r}; choose rectified or original")
    inputs = (left, right, rig_file)
    for option, path, suffixes in (("--depth", depth, (".tif", ".tiff")), ("--points", points, (".ply",))):
        if path is not None:
            check_output(path, suffixes=suffixes, inputs=inputs)
    get_matcher(method).resolve_preprocess(preprocess)  # refuse unknown names before any work
    rig = load_rig(rig_file)
    other, rectification = rig_pair_rectification(rig, camera)
    left_image, right_image = read_pair(left, right, left_band, right_band)
    check_rig_pair(rig, rectification, left_image, right_image, paths=(left, right))
    started = time.perf_counter()
    width = rectification.image_size[0]
    if AUTO not in (min_disp, max_disp):
        max_disp = resolve_max_disp(max_disp, width)
        check_disparity_range(output, min_disp, max_disp)  # before any work: a 16-bit PNG holds [0, 256) px
    # An auto range is known once estimated on the rectified pair: checked then, still before matching.
    with StepBar(1, "rectifying and matching the pair"):
        found, framed = match_rig_pair(
            rig, left_image, right_image, other=other, frame=frame, fill=fill, fix_vertical=fix_vertical,
            method=method, max_disp=max_disp, min_disp=min_disp, preprocess=preprocess, model=model,
            memory_limit=memory_limit,
            on_range=lambda searched: check_disparity_range(output, searched.minimum, searched.maximum))
    seconds = time.perf_counter() - started
    if found.range_estimate is not None:
        print_note(found.range_estimate.describe(estimated=(min_disp == AUTO, max_disp == AUTO)))
    if found.plan.tiled:
        print_note(found.plan.describe())
    if found.misalignment is not None:
        if strict and not fix_vertical and found.misalignment.worst(width) > VERTICAL_TOLERANCE_PX:
            raise CadeError(f"rectification self-check: vertical misalignment up to "
                            f"{found.misalignment.worst(width):.2f} px, above {VERTICAL_TOLERANCE_PX} px; add "
                            "--fix-vertical or recalibrate (--strict)")
        report_misalignment(found.misalignment, width, fixed=fix_vertical, corrected=found.corrected)
    else:
        print_warning(f"rectification self-check skipped: {found.self_check_problem}")
    warn_if_textureless(left, right, found.left, found.right)
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
