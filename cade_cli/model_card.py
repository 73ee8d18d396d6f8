"""The model card: what `cade_cli.train` export writes beside its ONNX files and what the
runtime (:mod:`cade_cli.matching.network`) reads. No torch and no onnxruntime here.

A card is a JSON file ``<name>.json`` in the model folder::

    {"format": 2, "name": "cade-v4", "divisor": 8, "trained_levels": 128,
     "variants": [{"levels": 96, "file": "cade-v4-96.onnx", "sha256": "..."}, ...],
     ... free descriptive fields (architecture, training command, figures) ...}

Each variant is the same weights exported with another search width: ``levels`` is the
number of disparities the network's cost volume spans, so it searches
0 .. ``levels`` - 1 px (inclusive bound ``levels - 1``). Only ``format``, ``divisor``,
``variants``, ``input``, the optional ``chooser`` (weights of the learned choice between the
network and the refinement's match, written by ``python -m cade_cli.train chooser``),
``runtime_refinement``, ``context_px``, ``test_time_augmentation`` and ``runtime_edge_filter`` are
read back; the other fields document the model.
"""

from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass
from pathlib import Path

from cade_cli.errors import CadeError

CARD_FORMAT = 2
"""Version of the card layout; format 1 (2026-11-22) named ``levels`` ``max_disp``."""
MODEL_DIR_ENV = "CADE_MODEL_DIR"
"""Environment variable naming another folder of models and cards."""
DEFAULT_MODEL = "cade-v13"
TIERS = {"fast": DEFAULT_MODEL, "accurate": "cade-v13-accurate-synthetic"}
"""``--model fast`` and ``--model accurate``: the shipped card each tier names. fast: cade-v13 since
2026-11-28 (the fast design's campaign, step 48,750 annealed, with the two-scale refinement; it
passed Accuracy IV's shipping rule against cade-v12, models/cade-v13.md), before it the same day
cade-v12 (step 40,250; passed against cade-v11), cade-v11 from 2026-11-25 to 2026-11-28, cade-v10 on
2026-11-25 (docs/research/models.md). accurate: cade-v13-accurate-synthetic since the evening of 2026-12-07,
cade-v13-accurate-context with its chooser fitted on rendered pairs too, which passed the rule against it, better on
every set (models/cade-v13-accurate-synthetic.md); before it, from earlier that day, cade-v13-accurate-context
(still shipped), cade-v13-accurate-edges with the convolutional chooser (``chooser.kind: network``, cade_cli/matching/chooser_net.py), which passed the rule
against it, level or better on every set (models/cade-v13-accurate-context.md); before it cade-v13-accurate-edges
(2026-11-29, still shipped: cade-v13's network with a second pass on the pair enlarged 1.5x fused in and the edge
filter last, ``runtime_edge_filter: weighted-median``), cade-v13-accurate (2026-11-28, still shipped: the same
without the filter), cade-v12-accurate, and cade-v11-accurate from 2026-11-27 to 2026-11-28."""


def model_dir() -> Path:
    """Where model files and cards are looked up: $CADE_MODEL_DIR, else the models shipped
    with the package: ``cade_cli/models`` in an installed wheel, the repository's top-level
    ``models/`` in a checkout (an editable install)."""
    configured = os.environ.get(MODEL_DIR_ENV)
    if configured:
        return Path(configured)
    package = Path(__file__).resolve().parent
    installed = package / "models"
    return installed if installed.is_dir() else package.parent / "models"


DEFAULT_CONTEXT_PX = 64
"""The context of a card without ``context_px``, px: one pixel of either input moves the 3D
CadeNet's disparity by more than 0.01 px up to about 40 rows and 50 columns away (by 1e-4 px up
to about 70; Adirondack, models/cade-v4). A 2D U-Net down to 1/16 sees further (its card says so)."""


@dataclass(frozen=True)
class ModelVariant:
    """One ONNX export of the weights, searching disparities 0 .. ``levels`` - 1 px."""

    path: Path
    sha256: str
    levels: int


@dataclass(frozen=True)
class ModelCard:
    """The part of a card the runtime needs."""

    name: str
    variants: tuple[ModelVariant, ...]
    divisor: int
    chooser: dict | None = None
    """The learned choice between the network and the refinement's match
    (:class:`cade_cli.matching.chooser.Chooser`'s weights), when the card has one; without
    it the refinement's fixed agreement rule decides."""
    input: str = "cade"
    """How each band is given to the network (:data:`cade_cli.spectral.NETWORK_INPUTS`): its
    color agnostic transform (every shipped model, and cards without the field), or rescaled
    to [0, 1] (the training ablation's pristine and CSDL models)."""
    refinement: str = "rank-sgbm"
    """What the ``cade`` matcher does after the network (:data:`RUNTIME_REFINEMENTS`, the
    card's ``runtime_refinement``): SGBM of the rank-transformed raw bands (every card
    before Accuracy III, and cards without the field), the same search narrowed to the
    network's own range (``rank-sgbm-network-range``: fewer disparities, less time;
    :attr:`cade_cli.matching.refinement.RankSgbmRefinement.network_range`), the whole-range
    search with its rejected pixels offered a second SGBM's match on the bands at half size
    (``rank-sgbm-two-scales``: weakly textured regions; about a tenth more of SGBM's time;
    :attr:`cade_cli.matching.refinement.RankSgbmRefinement.half_size`), or nothing
    (``none``: the network's map is the answer, at the network's speed)."""
    context: int = DEFAULT_CONTEXT_PX
    """Px of image around a pixel that move the network's estimate there (the card's
    ``context_px``; :data:`DEFAULT_CONTEXT_PX` for cards without it): the collar of a tiled
    window (:func:`cade_cli.scale.windows.method_collar`)."""
    test_time: tuple[str, ...] = ()
    """Extra network passes fused with the plain one (:data:`TEST_TIME_AUGMENTATIONS`, the card's
    ``test_time_augmentation``): ``vertical-flip`` matches the pair turned upside down, which keeps
    its rows and disparities but gives the network other context above and below each pixel
    (:meth:`cade_cli.matching.network.NetworkStage.estimate`); ``upscaled-x1.5`` and ``upscaled-x2`` match
    the pair enlarged (a second scale); ``mirrored`` checks the estimate against the right view's
    (:mod:`cade_cli.matching.augmentation`). Applied in the card's order. Empty: one pass."""
    edge_filter: str = "none"
    """What the ``cade`` matcher does last (:data:`EDGE_FILTERS`, the card's
    ``runtime_edge_filter``): nothing (cards without the field), or ``weighted-median``: the map's
    weighted median guided by the left band puts depth edges where the image has them
    (:func:`cade_cli.matching.edges.snap_to_edges`)."""


RUNTIME_REFINEMENTS = ("rank-sgbm", "rank-sgbm-network-range", "rank-sgbm-two-scales", "none")
TEST_TIME_AUGMENTATIONS = ("vertical-flip", "upscaled-x1.5", "upscaled-x2", "mirrored")
EDGE_FILTERS = ("none", "weighted-median")
"""The values of a card's ``runtime_edge_filter`` (:attr:`ModelCard.edge_filter`)."""


RETIRED_MODELS = {name: "85fb266" for name in
                  ("cade-v6", "cade-v11", "cade-v11-accurate", "cade-v12", "cade-v12-accurate")}
"""Cards that left models/ (and the wheel), by name, and the commit that still has them with their
ONNX files (``git show 85fb266:models/cade-v11.onnx``); their findings are in docs/research/."""


def card_path(model: str | Path = DEFAULT_MODEL, folder: Path | None = None) -> Path:
    """The card of ``model``: a path to a card file (``.../cade-v6.json``), the name of a
    card in ``folder`` (default :func:`model_dir`), or a tier of :data:`TIERS`."""
    if str(model).endswith(".json"):
        return Path(model)
    model = TIERS.get(str(model), model)
    return (model_dir() if folder is None else Path(folder)) / f"{model}.json"


def read_card(model: str | Path = DEFAULT_MODEL, folder: Path | None = None) -> ModelCard:
    """Load the card of ``model`` (see :func:`card_path`); variant files are looked up beside it.

    Raises:
        CadeError: the card is missing or malformed (the message names the file and the fix).
    """
    path = card_path(model, folder)
    if not path.is_file() and folder is None and str(model) in RETIRED_MODELS:
        commit = RETIRED_MODELS[str(model)]
        raise CadeError(f"model {model} is retired and no longer shipped; commit {commit} has it: "
                        f"`git show {commit}:models/{model}.json` and its .onnx files into a folder, then "
                        f"give that card's path or set {MODEL_DIR_ENV} to the folder")
    if not path.is_file():
        raise CadeError(f"model card {path} not found; give the path of a model's .json card, or set "
                        f"{MODEL_DIR_ENV} to the folder holding {path.stem}.json")
    stat = path.stat()
    return _parse_card(path, stat.st_mtime_ns, stat.st_size)


def network_fingerprint(model: str | Path | None = None) -> dict:
    """What of the card of ``model`` (default: the shipped one) decides a learned method's output,
    as a batch record stores it, so that a changed card re-runs its pairs: the sha256 of every
    network file it names, sorted; its test-time passes, its refinement and its edge filter where they
    are not the defaults, and its convolutional chooser's file where it has one (left out otherwise, so records
    written before they existed still match)."""
    card = read_card(model or DEFAULT_MODEL)
    fingerprint: dict = {"model_sha256": sorted(variant.sha256 for variant in card.variants)}
    if card.chooser is not None and "sha256" in card.chooser:
        fingerprint["chooser_sha256"] = card.chooser["sha256"]
    if card.test_time:
        fingerprint["test_time_augmentation"] = list(card.test_time)
    if card.refinement != ModelCard.refinement:
        fingerprint["runtime_refinement"] = card.refinement
    if card.edge_filter != ModelCard.edge_filter:
        fingerprint["runtime_edge_filter"] = card.edge_filter
    return fingerprint


@functools.lru_cache(maxsize=16)
def _parse_card(path: Path, mtime_ns: int, size: int) -> ModelCard:
    """The card at ``path``, parsed once per version of the file (``mtime_ns`` and ``size``
    key the cache): the matcher asks for it on every pair and every tile."""
    name = path.stem
    try:
        card = json.loads(path.read_text())
        if card.get("format", 1) != CARD_FORMAT:
            raise ValueError(f"format {card.get('format', 1)}, this version reads format {CARD_FORMAT}")
        variants = tuple(ModelVariant(path.parent / v["file"], v["sha256"], int(v["levels"]))
                         for v in card["variants"])
        if not variants:
            raise ValueError("no variants")
        chooser = card.get("chooser")
        if chooser is not None and not isinstance(chooser, dict):
            raise ValueError("chooser is not an object")
        from cade_cli.spectral import NETWORK_INPUTS

        network_input = card.get("input", "cade")
        if network_input not in NETWORK_INPUTS:
            raise ValueError(f"input {network_input!r} is not one of {', '.join(NETWORK_INPUTS)}")
        refinement = card.get("runtime_refinement", "rank-sgbm")
        if refinement not in RUNTIME_REFINEMENTS:
            raise ValueError(f"runtime_refinement {refinement!r} is not one of {', '.join(RUNTIME_REFINEMENTS)}")
        context = int(card.get("context_px", DEFAULT_CONTEXT_PX))
        if context < 0:
            raise ValueError(f"context_px {context} is negative")
        test_time = tuple(card.get("test_time_augmentation", ()))
        unknown = [name for name in test_time if name not in TEST_TIME_AUGMENTATIONS]
        if unknown:
            raise ValueError(f"test_time_augmentation {unknown[0]!r} is not one of {', '.join(TEST_TIME_AUGMENTATIONS)}")
        edge_filter = card.get("runtime_edge_filter", "none")
        if edge_filter not in EDGE_FILTERS:
            raise ValueError(f"runtime_edge_filter {edge_filter!r} is not one of {', '.join(EDGE_FILTERS)}")
        return ModelCard(name, variants, int(card["divisor"]), chooser, network_input, refinement, context, test_time,
                         edge_filter)
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise CadeError(f"model card {path} is malformed ({error}); re-export it with python -m cade_cli.train export")


def describe_model(model: str | Path = DEFAULT_MODEL, folder: Path | None = None) -> dict:
    """What a run records of the network it used: ``name``, ``card`` (its path), ``sha256``
    of the card file, and each variant's ``levels``, ``file`` and ``sha256`` as the card pins
    them (the runtime checks each variant file against it when it loads one).

    Raises:
        CadeError: the card is missing or malformed (:func:`read_card`).
    """
    from cade_cli.io.checksum import file_sha256

    path = card_path(model, folder)
    card = read_card(model, folder)
    return {"name": card.name, "card": str(path), "sha256": file_sha256(path),
            "variants": [{"levels": v.levels, "file": v.path.name, "sha256": v.sha256} for v in card.variants]}


def write_card(path: Path, *, name: str, divisor: int, trained_levels: int, variants: list[dict], **fields) -> dict:
    """Write a card (``variants``: dicts with ``levels``, ``file``, ``sha256``); returns it."""
    card = {"format": CARD_FORMAT, "name": name, "divisor": divisor, "trained_levels": trained_levels,
            "variants": sorted(variants, key=lambda v: v["levels"]), **fields}
    Path(path).write_text(json.dumps(card, indent=2) + "\n")
    return card
