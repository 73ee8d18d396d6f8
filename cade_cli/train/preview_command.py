"""``python -m cade_cli.train preview``: a picture of generated training scenes, lever by lever
(:mod:`cade_cli.train.preview`), to look at a lever's data before a run trains on it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def preview(
    output: Annotated[Path, typer.Option("--output", "-o", help="PNG to write.")]
    = Path("docs/img/training-levers.png"),
    textures: Annotated[list[Path], typer.Option(help="Folder of texture images (repeatable).")] = [],
    real_dir: Annotated[Path | None, typer.Option(exists=True, file_okay=False, help="Real training scenes "
                                                  "(floating objects' backgrounds).")] = None,
    lever: Annotated[list[str], typer.Option(help="none, thin, floating or asymmetric (repeatable; default all).")]
    = [],
    count: Annotated[int, typer.Option(min=1, max=8, help="Scenes per lever.")] = 2,
    height: Annotated[int, typer.Option(min=32)] = 128,
    width: Annotated[int, typer.Option(min=32)] = 224,
    levels: Annotated[int, typer.Option(min=16)] = 128,
    seed: int = 0,
) -> None:
    """Draw generated scenes with each lever on (left, right, ground truth, edge-weighted pixels) into one PNG."""
    import cv2

    from cade_cli.errors import CadeError
    from cade_cli.io.atomic import atomic_output
    from cade_cli.train.preview import PREVIEW_LEVERS, lever_scenes, lever_sheet, scene_row
    from cade_cli.train.real import RealScenes
    from cade_cli.train.textures import TexturePool

    if output.suffix.lower() != ".png":
        raise typer.BadParameter(f"must end in .png, not {output.name}", param_hint="--output")
    unknown = [name for name in lever if name not in PREVIEW_LEVERS]
    if unknown:
        raise typer.BadParameter(f"must be among {', '.join(PREVIEW_LEVERS)}, not {', '.join(unknown)}",
                                 param_hint="--lever")
    try:
        pool = TexturePool(textures)
        real = RealScenes(real_dir) if real_dir else None
        rows = [scene_row(scene, label=name, levels=levels)
                for name in (lever or PREVIEW_LEVERS)
                for scene in lever_scenes(name, count=count, height=height, width=width, levels=levels, seed=seed,
                                          pool=pool, real=real)]
        with atomic_output(output) as staged:
            if not cv2.imwrite(str(staged), lever_sheet(rows), [cv2.IMWRITE_PNG_COMPRESSION, 9]):
                raise CadeError(f"cannot write {output}")
    except CadeError as error:
        typer.echo(f"error: {error}", err=True)
        raise typer.Exit(1) from None
    print(f"wrote {output}")
