"""The one exception type that means "the user gave us something we cannot use".

Library functions raise :class:`CadeError` for bad input; the CLI turns it into a
single line on stderr and a non-zero exit. Anything else escaping is a bug.
"""

from __future__ import annotations


class CadeError(ValueError):
    """Bad input or an impossible request; the message names the problem and the fix."""
