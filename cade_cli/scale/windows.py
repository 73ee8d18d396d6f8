"""What a tile's window must hold beyond its core: the collar a matcher's context needs
(:func:`method_collar`), the grid a network samples the image on (:func:`window_alignment`) and
how far a search reaches to the left (:func:`search_reach`).
"""

from __future__ import annotations

import math

from cade_cli.matching import DisparityRange
from cade_cli.matching.network import choose_variant
from cade_cli.matching.refinement import SIGN_STEP
from cade_cli.scale.memory import learned_kernel


COLLAR = 32
"""Px added on every side of a core and dropped after matching: the context a classical
matcher's windows, SGM paths and checks use near the core's edge."""

def method_collar(method: str, model: str | None = None) -> int:
    """The collar ``method``'s windows get, px: its network card's context
    (:attr:`cade_cli.model_card.ModelCard.context`) for a learned method, :data:`COLLAR` for
    the classical ones."""
    kernel = learned_kernel(method, model)
    return COLLAR if kernel is None else kernel.network.card().context


def window_alignment(method: str, span: int, model: str | None = None) -> int:
    """Px that a window's first row and column must be multiples of for ``method``, searching
    ``span`` px (max - min), to sample the image on the grid it uses when matching the pair
    whole; 1 for a classical matcher.

    A learned method's network samples its input on a grid whose pitch is the card's
    divisor times the pyramid factor of the search (features at 1/4 resolution, padded to
    the divisor; a downscaled pass for wide ranges): a window starting off that grid is
    sampled at other points, and its map differs everywhere (on Adirondack 95-97 % of the
    pixels by more than 0.01 px for a window 1, 2 or 4 px off; 1 % for one 8 px off). Its
    refinement reads every :data:`~cade_cli.matching.refinement.SIGN_STEP`-th row and
    column to judge contrast inversion. Seeded tiles search at most ``span``, so their
    pyramid factor divides this one's."""
    kernel = learned_kernel(method, model)
    if kernel is None:
        return 1
    card = kernel.network.card()
    pitch = card.divisor * choose_variant(card, span)[1]
    return pitch if kernel.refinement is None else math.lcm(pitch, SIGN_STEP)


def search_reach(method: str, disparity_range: DisparityRange, model: str | None = None) -> int:
    """The largest disparity (px) whose cost ``method`` computes when asked for
    ``disparity_range``: its maximum for a classical matcher; for a learned one the top
    level of the network variant it runs (the minimum plus the pyramid factor times
    ``levels - 1``), usually above it. The network aggregates all its levels, so a window
    must hold that many columns left of a pixel for its estimate to be the untiled one (on
    Playtable, range [0, 72], variant of 96 levels, 128 px cores: 1.9 % of the network's
    pixels 8-32 px from a seam move by more than 0.01 px with windows widened by 72 px,
    0.02 % with 95 px)."""
    kernel = learned_kernel(method, model)
    if kernel is None:
        return disparity_range.maximum
    variant, factor = choose_variant(kernel.network.card(), disparity_range.span)
    return max(disparity_range.maximum, disparity_range.minimum + factor * (variant.levels - 1))
