"""The wheel's package list and the model folder it carries (the wheel itself is built and
run from a fresh venv by `make wheel-check`, which CI runs)."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_wheel_lists_every_package_and_carries_the_models():
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {"cade_cli", *(f"cade_cli.{path.parent.name}" for path in (ROOT / "cade_cli").glob("*/__init__.py"))}
    assert set(setuptools["packages"]) == folders | {"cade_cli.models"}
    assert setuptools["package-dir"]["cade_cli.models"] == "models"
    patterns = setuptools["package-data"]["cade_cli.models"]
    shipped = [path for path in (ROOT / "models").iterdir() if path.suffix in (".onnx", ".json")]
    assert shipped and all(any(path.match(pattern) for pattern in patterns) for path in shipped)


def test_an_installed_package_finds_its_own_models(tmp_path, monkeypatch):
    """In a wheel the models lie in cade_cli/models; model_dir must look there first."""
    from cade_cli import model_card

    monkeypatch.delenv(model_card.MODEL_DIR_ENV, raising=False)
    assert model_card.model_dir() == ROOT / "models"  # a checkout: the top-level folder
    package = tmp_path / "cade_cli"
    (package / "models").mkdir(parents=True)
    monkeypatch.setattr(model_card, "__file__", str(package / "model_card.py"))
    assert model_card.model_dir() == package / "models"
