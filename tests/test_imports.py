"""The package's layering (docs/architecture.md), checked on the code itself: which module
may import which, no reaching into another module's private names, and the runtime never
pulls in torch."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "cade_cli"

LAYERS: dict[str, int] = {
    # 0: foundations (no cade_cli import but each other): errors, reading and writing, the transform
    "cade_cli.errors": 0, "cade_cli.allocator": 0, "cade_cli.spectral": 0, "cade_cli.model_card": 0,
    "cade_cli.io": 0,
    # 1: matchers
    "cade_cli.matching": 1,
    # 2: the library's entry points: one pair, rigs, scale (range, tiles)
    "cade_cli.stereo": 2, "cade_cli.registration": 2, "cade_cli.io.registered": 2, "cade_cli.pair_check": 2,
    "cade_cli.pair_features": 2,
    "cade_cli.rigs": 2, "cade_cli.scale": 2, "cade_cli.capture": 2,
    # 3: data sets, then the evaluation built on them
    "cade_cli.data": 3,
    "cade_cli.evaluation": 4,
    # 4: many pairs (uses the evaluation's thread setting; engines: processes, Dask)
    "cade_cli.scale.batch": 4,
    # 5: the command line and the package root
    "cade_cli.cli": 5, "cade_cli.__main__": 5, "cade_cli": 5,
    # training: may use everything below the CLI; nothing but itself imports it
    "cade_cli.train": 6,
}
"""Layer of each module or package (a package's modules share its layer); a module may
import its own layer and the layers below it."""


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer_of(name: str) -> tuple[str, int]:
    for candidate in sorted(LAYERS, key=len, reverse=True):
        if name == candidate or name.startswith(candidate + "."):
            return candidate, LAYERS[candidate]
    raise KeyError(name)


def imports_of(path: Path) -> list[tuple[str, list[str], int]]:
    """(imported module, names imported from it, line) for every import in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(alias.name, [], node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.module, [alias.name for alias in node.names], node.lineno))
    return found


SOURCES = sorted(PACKAGE.rglob("*.py"))
RUNTIME_MODULES = [module_name(path) for path in SOURCES
                   if not module_name(path).startswith("cade_cli.train") and module_name(path) != "cade_cli.__main__"]


def test_every_module_has_a_layer():
    for path in SOURCES:
        layer_of(module_name(path))  # raises for a module docs/architecture.md does not place


@pytest.mark.parametrize("path", SOURCES, ids=lambda path: module_name(path))
def test_imports_go_down_the_layers(path):
    own, own_layer = layer_of(module_name(path))
    for imported, names, line in imports_of(path):
        if imported == "cade_cli" and names == ["__version__"]:
            continue  # the version string, defined before the root imports anything
        if imported.split(".")[0] in ("torch", "onnx") and not own.startswith("cade_cli.train"):
            pytest.fail(f"{path.name}:{line} imports {imported}: only cade_cli.train may")
        if not imported.startswith("cade_cli"):
            continue
        target, target_layer = layer_of(imported)
        allowed = target_layer <= own_layer or own == "cade_cli"  # the root re-exports the public API
        assert allowed, f"{module_name(path)}:{line} (layer {own_layer}) imports {imported} (layer {target_layer})"


@pytest.mark.parametrize("path", SOURCES + sorted((ROOT / "benchmarks").glob("*.py")),
                         ids=lambda path: str(path.relative_to(ROOT)))
def test_no_module_reaches_into_another_modules_private_names(path):
    """``from cade_cli.x import _name`` or ``x._name`` from outside module x."""
    tree = ast.parse(path.read_text())
    imported_modules = {alias.asname or alias.name.split(".")[-1]
                        for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("cade_cli")
                        for alias in node.names}
    for imported, names, line in imports_of(path):
        private = [name for name in names if name.startswith("_") and not name.startswith("__")]
        assert not (imported.startswith("cade_cli") and private), f"{path.name}:{line} imports {private} from {imported}"
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in imported_modules
                and node.attr.startswith("_") and not node.attr.startswith("__")):
            pytest.fail(f"{path.name}:{node.lineno} reads {node.value.id}.{node.attr}")


def test_runtime_modules_do_not_import_torch():
    probe = (
        "import importlib, sys\n"
        f"for name in {RUNTIME_MODULES!r}: importlib.import_module(name)\n"
        "from cade_cli import estimate_disparity, register, color_agnostic, synthesize_bands\n"
        "print('torch' in sys.modules)"
    )
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "False"


def test_public_api_is_importable_from_the_package():
    import cade_cli

    assert callable(cade_cli.estimate_disparity) and callable(cade_cli.register)
    assert callable(cade_cli.color_agnostic) and callable(cade_cli.synthesize_bands)
    assert cade_cli.estimate_disparity.__doc__ and "(H, W)" in cade_cli.estimate_disparity.__doc__
