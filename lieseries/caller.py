"""The user's line for a warning: the first frame outside lieseries.

A fixed ``stacklevel`` is right for one call path only (``ls.integrate`` reaches a check through a different
number of frames than a scene run or an ensemble does), and a warning that names a line of lieseries cannot be
filtered by the user's module nor found in the user's code. :func:`stacklevel` counts the frames instead.
"""

from __future__ import annotations

import sys

__all__ = ["stacklevel"]

_PACKAGE = __name__.split(".")[0]


def stacklevel() -> int:
    """The ``stacklevel`` that makes a warning raised by the calling function name the first frame outside the
    package (the caller's own code), or the outermost frame when every frame is inside it."""
    frame = sys._getframe(1)  # the function about to call warnings.warn: stacklevel 1
    level = 1
    while frame.f_back is not None:
        name = frame.f_globals.get("__name__", "")
        if name != _PACKAGE and not name.startswith(_PACKAGE + "."):
            break
        frame = frame.f_back
        level += 1
    return level
