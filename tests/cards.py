"""Model cards for tests: a shipped card copied with some fields changed, its ONNX files linked."""

from __future__ import annotations

import json
from pathlib import Path

from cade_cli.model_card import card_path


def card_copy(folder: Path, name: str, *, source: str | None = None, **fields) -> Path:
    """``folder/name.json``: the card of ``source`` (default: the shipped one) with ``fields``
    set, its variants' files linked beside it."""
    shipped = card_path() if source is None else card_path(source)
    card = json.loads(shipped.read_text())
    for variant in card["variants"]:
        link = folder / variant["file"]
        if not link.exists():
            link.symlink_to(shipped.parent / variant["file"])
    card.update(fields)
    path = folder / f"{name}.json"
    path.write_text(json.dumps(card))
    return path
