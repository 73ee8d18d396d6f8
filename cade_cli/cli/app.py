"""The ``cade`` Typer application and its root options (--version); the commands are registered on it
by :mod:`cade_cli.cli`.
"""

from __future__ import annotations

from typing import Annotated

import typer

from cade_cli.version import __version__


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
