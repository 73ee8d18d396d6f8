"""``cade register``: warp one band (the moving one) into the view of another (the reference), after the pair check.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from cade_cli.cli.options import (
    DEFAULT_METHOD, MaxDispAutoOption, MethodOption, MinDispAutoOption, ModelOption, PreprocessOption, StepBar,
    check_output, parse_range_options, print_warning, read_pair, resolve_range_options, warn_if_textureless,
)
from cade_cli.cli.pairs import check_pair_before_matching

REGISTER_ROLES = "give the reference band as --reference and the moving one as --moving"
"""How ``register`` says to undo a swapped pair (``disparity``: give the reference image first)."""


def register(
    context: typer.Context,
    output: Annotated[Path, typer.Option("--output", "-o", help="Float32 TIFF: reference, registered, validity bands.")],
    reference: Annotated[Optional[Path], typer.Option("--reference", help="Reference band (left view, the LEFT of "
                                                      "`cade disparity`): the view the result is in.",
                                                      show_default=False)] = None,
    moving: Annotated[Optional[Path], typer.Option("--moving", help="Band to warp into the reference view (right "
                                                   "view, the RIGHT of `cade disparity`).", show_default=False)] = None,
    old_order: Annotated[Optional[list[Path]], typer.Argument(
        help="Deprecated: MOVING REFERENCE as two positional files (the old order, kept for one release); write "
             "--reference REFERENCE --moving MOVING.", show_default=False, metavar="[MOVING REFERENCE]")] = None,
    disparity_file: Annotated[
        Optional[Path], typer.Option("--disparity", help="Use this reference-view disparity instead of estimating it "
                                     "(its invalid markers -- inf, NaN, 0 in PNG -- are not trusted).")
    ] = None,
    validity_file: Annotated[
        Optional[Path], typer.Option("--validity", help="With --disparity: the validity mask `cade disparity "
                                     "--validity` wrote; only its valid pixels are trusted.")
    ] = None,
    method: MethodOption = DEFAULT_METHOD,
    max_disp: MaxDispAutoOption = None,
    min_disp: MinDispAutoOption = "0",
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
    fix_vertical: Annotated[bool, typer.Option("--fix-vertical", help="Correct the vertical offset and rotation of "
                                               "the pair before matching, with the warp estimated from the pair alone "
                                               "(as cade rectify --uncalibrated; recorded in "
                                               "OUTPUT.rectification.json); the result stays in the reference band's "
                                               "own view.")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Refuse a pair the pair check finds unrectified, swapped "
                                         "or outside the range searched (exit 1, nothing written) instead of "
                                         "warning.")] = False,
) -> None:
    """Warp the MOVING band into the view of the REFERENCE band; write both as one multi-band TIFF.

    Name the bands: cade register --reference LEFT --moving RIGHT -o OUT.tif (LEFT and RIGHT as in cade disparity).
    """
    reference, moving = _register_bands(reference, moving, old_order)
    inputs = tuple(p for p in (moving, reference, disparity_file, validity_file) if p is not None)
    min_disp, max_disp = parse_range_options(min_disp, max_disp)
    _check_register_options(context, output, inputs, vis=vis, vis_mode=vis_mode, disparity_file=disparity_file,
                            validity_file=validity_file, fill=fill, fix_vertical=fix_vertical)
    _check_estimation_options(context, disparity_file=disparity_file, method=method, preprocess=preprocess)
    reference_image, moving_image = read_pair(
        reference, moving, reference_band, moving_band, names=("--reference-band", "--moving-band")
    )
    started = time.perf_counter()
    warp, warp_record, original_reference = None, None, reference_image
    if fix_vertical:  # the warp from the pair alone
        from cade_cli.cli.uncalibrated import fix_vertical_alone

        warp, warp_record, reference_image, moving_image = fix_vertical_alone(output, inputs, reference_image, moving_image)
    result, source, pair_check = _register_pair(
        reference, moving, reference_image, moving_image, disparity_file=disparity_file, validity_file=validity_file,
        method=method, min_disp=min_disp, max_disp=max_disp, preprocess=preprocess, fill=fill, model=model,
        strict=strict)
    if warp is not None:
        from cade_cli.cli.uncalibrated import registration_in_original_frame

        result = registration_in_original_frame(warp, result, original_reference)
    seconds = time.perf_counter() - started
    _write_register_outputs(output, result, vis=vis, vis_mode=vis_mode, warp=warp, warp_record=warp_record,
                            reference=reference, moving=moving)
    height, width = result.reference.shape
    checked = "" if pair_check is None else f", {pair_check.summary()}"
    print(f"{output}: {width}x{height}, {source}, fill {fill}, valid {100.0 * result.valid.mean():.1f}%{checked}, "
          f"{seconds:.2f} s")


def _check_register_options(context: typer.Context, output: Path, inputs: tuple[Path, ...], *, vis: Path | None,
                            vis_mode: str, disparity_file: Path | None, validity_file: Path | None, fill: str,
                            fix_vertical: bool) -> None:
    """Refuse ``cade register``'s outputs and options that do not go together, before reading anything."""
    from cade_cli.io.registered import REGISTRATION_VIS_MODES

    from cade_cli.errors import CadeError

    check_output(output, suffixes=(".tif", ".tiff"), inputs=inputs)
    if vis is not None:
        check_output(vis, suffixes=(".png",), inputs=inputs)
    if vis_mode not in REGISTRATION_VIS_MODES:
        raise CadeError(f"unknown --vis-mode {vis_mode!r}; choose {' or '.join(REGISTRATION_VIS_MODES)}")
    if vis is None and context.get_parameter_source("vis_mode").name != "DEFAULT":
        raise CadeError("--vis-mode says how --vis draws the registration; add --vis PICTURE.png or drop --vis-mode")
    if validity_file is not None and disparity_file is None:
        raise CadeError("--validity needs --disparity (it masks that map); drop it or give the disparity file")
    if fill not in ("row", "none"):
        raise CadeError(f"unknown --fill {fill!r}; choose row or none")
    if fix_vertical and disparity_file is not None:
        raise CadeError("--fix-vertical rectifies the pair before its disparity is estimated, but --disparity gives "
                        "it; drop one")


def _check_estimation_options(context: typer.Context, *, disparity_file: Path | None, method: str,
                              preprocess: str) -> None:
    """With ``--disparity``, refuse the options that only apply when the disparity is estimated;
    without it, refuse an unknown ``--method`` or ``--preprocess`` before reading anything."""
    from cade_cli.errors import CadeError

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


def _write_register_outputs(output: Path, result, *, vis: Path | None, vis_mode: str, warp, warp_record: Path | None,
                            reference: Path, moving: Path) -> None:
    """Write the registration TIFF, and the --vis picture and the --fix-vertical warp record when
    asked: all together, or none (:func:`~cade_cli.io.atomic.atomic_outputs`)."""
    from cade_cli.io.atomic import atomic_outputs
    from cade_cli.io.registered import write_registration, write_registration_picture

    with atomic_outputs([output, vis, warp_record]) as staged:
        write_registration(staged[output], result)
        if vis is not None:
            write_registration_picture(staged[vis], result, mode=vis_mode)
        if warp is not None:
            from cade_cli.cli.uncalibrated import write_warp_record

            write_warp_record(staged[warp_record], warp, reference=str(reference), moving=str(moving))


def _register_bands(reference: Path | None, moving: Path | None, old_order: list[Path] | None) -> tuple[Path, Path]:
    """The (reference, moving) files of ``cade register``: named by ``--reference``/``--moving``, or
    the deprecated positional MOVING REFERENCE (kept for one release, with a warning)."""
    from cade_cli.errors import CadeError

    named = "--reference REFERENCE --moving MOVING"
    if old_order:
        if reference is not None or moving is not None:
            raise CadeError(f"give the bands either as {named} or as the deprecated positional MOVING REFERENCE, "
                            "not both")
        if len(old_order) != 2:
            raise CadeError(f"register takes two bands: write cade register {named} -o OUT.tif")
        moving, reference = old_order
        print_warning(f"`cade register MOVING REFERENCE` (moving band first) is deprecated and goes in the next "
                      f"release; write `cade register --reference {reference} --moving {moving}`")
        return reference, moving
    missing = [option for option, path in (("--reference", reference), ("--moving", moving)) if path is None]
    if missing:
        raise CadeError(f"missing {' and '.join(missing)}: write cade register {named} -o OUT.tif (REFERENCE is the "
                        "left view, as LEFT of cade disparity; MOVING is warped onto it)")
    return reference, moving


def _register_pair(reference: Path, moving: Path, reference_image, moving_image, *, disparity_file, validity_file,
                   method, min_disp, max_disp, preprocess, fill, model, strict):
    """Check the pair (:func:`_check_pair`; with a given disparity, against that map's range),
    then register MOVING onto REFERENCE: returns (registration, where the disparity came from, the check)."""
    import math

    import numpy as np

    from cade_cli.io.disparity import read_disparity
    from cade_cli.registration import register as register_band

    if disparity_file is not None:
        from cade_cli.io.disparity import read_validity

        given = read_disparity(disparity_file)
        trusted = read_validity(validity_file) if validity_file is not None else None
        finite = given[np.isfinite(given)]
        pair_check = None
        if finite.size and given.shape == reference_image.shape:
            low, high = min(0, math.floor(float(finite.min()))), math.ceil(float(finite.max()))
            pair_check = check_pair_before_matching(reference_image, moving_image, min_disp=low, max_disp=high,
                                                    strict=strict, roles=REGISTER_ROLES)
        result = register_band(moving_image, reference_image, disparity=given, disparity_valid=trusted, fill=fill,
                               disparity_name=str(disparity_file))
        source = f"disparity from {disparity_file}" + (f", validity from {validity_file}" if trusted is not None else "")
        return result, source, pair_check
    from cade_cli.matching import get_matcher

    min_disp, max_disp = resolve_range_options(min_disp, max_disp, reference_image, moving_image)
    pair_check = check_pair_before_matching(reference_image, moving_image, min_disp=min_disp, max_disp=max_disp,
                                            strict=strict, roles=REGISTER_ROLES)
    with StepBar(1, "matching and warping"):
        result = register_band(moving_image, reference_image, method=method, max_disp=max_disp,
                               min_disp=min_disp, preprocess=preprocess, fill=fill, model=model)
    source = f"{method}+{get_matcher(method).resolve_preprocess(preprocess)} over [{min_disp}, {max_disp}]"
    warn_if_textureless(reference, moving, reference_image, moving_image)
    return result, source, pair_check
