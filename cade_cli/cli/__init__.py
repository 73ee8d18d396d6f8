"""The ``cade`` command: a thin layer over the library that parses, validates and prints.

Heavy modules (NumPy, OpenCV, the matchers) are imported inside the commands, so
``cade --help`` and ``cade --version`` answer at once. Any user error ends as one line
on stderr and a non-zero exit; outputs are written atomically and only at the end.
"""

from __future__ import annotations

import os
import sys

import typer

from cade_cli.cli import batch, benchmark, capture, pairs, register, rigs
from cade_cli.cli.app import app
from cade_cli.cli.options import DEFAULT_METHOD, METHOD_NAMES

__all__ = ["app", "main", "DEFAULT_METHOD", "METHOD_NAMES"]

# the commands, in the order `cade --help` lists them
app.command()(pairs.disparity)
app.command()(register.register)
app.command()(rigs.calibrate)
app.command()(rigs.rectify)
app.command()(benchmark.benchmark)
app.add_typer(benchmark.datasets_app, name="datasets")
app.command("register-array")(rigs.register_array)
app.command("array-score")(rigs.array_score)
app.command("register-capture")(capture.register_capture)
app.command()(batch.batch)


EXIT_INPUT_ERROR = 1

EXIT_USAGE_ERROR = 2


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
