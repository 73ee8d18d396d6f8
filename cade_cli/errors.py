"""The one exception type that means "the user gave us something we cannot use".

Library functions raise :class:`CadeError` for bad input; the CLI turns it into a
single line on stderr and a non-zero exit. Anything else escaping is a bug.
"""

from __future__ import annotations

from typing import Mapping, TypeVar

T = TypeVar("T")


class CadeError(ValueError):
    """Bad input or an impossible request; the message names the problem and the fix."""


def lookup(registry: Mapping[str, T], name: str, *, kind: str) -> T:
    """``registry[name]``, or a :class:`CadeError` naming the ``kind`` and listing the choices."""
    try:
        return registry[name]
    except KeyError:
        raise CadeError(f"unknown {kind} {name!r}; choose one of {', '.join(registry)}") from None
