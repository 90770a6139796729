"""Ctrl-C at moments that must not be cut in two: while the package imports, and while a report moves into place.

Ctrl-C while a C extension initialises (heyoka, sympy and mpmath take a second or two to import) does not arrive
as KeyboardInterrupt: the half-initialised extension fails with an unrelated ImportError or AttributeError.
:func:`hold_while_importing` (called first thing by ``lieseries/__init__.py``) holds Ctrl-C back until
:func:`release_after_import` (its last thing), which then raises KeyboardInterrupt -- or, when the process is
the command line (``lieseries ...`` or ``python -m lieseries ...``), says ``lieseries: interrupted`` and exits
with status 130, without a traceback. :func:`held` does the same for a block of code.

Only the main thread receives signals; elsewhere, and when someone else already handles SIGINT, nothing is held.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from pathlib import Path

__all__ = ["held", "hold_while_importing", "release_after_import", "is_command_line", "ignore_from_now"]

_HOLDING = {}  # package -> (handler, previous handler, list of held signals)


def _can_hold() -> bool:
    return threading.current_thread() is threading.main_thread()


def is_command_line() -> bool:
    """True when this process is lieseries' command line (the console script, or ``python -m lieseries``)."""
    argv = list(getattr(sys, "orig_argv", []))
    if "-m" in argv[:-1] and argv[argv.index("-m") + 1] == "lieseries":
        return True
    return bool(sys.argv) and Path(sys.argv[0]).stem == "lieseries"


def hold_while_importing(package: str) -> None:
    """Hold Ctrl-C back while ``package`` imports (until :func:`release_after_import`). If the import fails
    half way, the handler lets Ctrl-C through again as soon as the package has left ``sys.modules``."""
    if not _can_hold() or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return
    got = []
    previous = signal.default_int_handler

    def handler(signum, frame):
        if package in sys.modules:  # still importing
            got.append(signum)
            return
        signal.signal(signal.SIGINT, previous)  # the import failed: Ctrl-C is itself again
        previous(signum, frame)

    signal.signal(signal.SIGINT, handler)
    _HOLDING[package] = (handler, previous, got)


def release_after_import(package: str) -> None:
    """End :func:`hold_while_importing`; a Ctrl-C that came meanwhile is raised now (KeyboardInterrupt), or on
    the command line ends the process with status 130."""
    entry = _HOLDING.pop(package, None)
    if entry is None:
        return
    handler, previous, got = entry
    if signal.getsignal(signal.SIGINT) is handler:
        signal.signal(signal.SIGINT, previous)
    if got:
        if is_command_line():
            print("lieseries: interrupted", file=sys.stderr)
            raise SystemExit(130)
        raise KeyboardInterrupt


@contextlib.contextmanager
def held():
    """Hold Ctrl-C back while the block runs (main thread only), then raise KeyboardInterrupt if it came.

    On the command line (:func:`is_command_line`) the process ends on that interrupt: Ctrl-C then stays ignored
    (:func:`ignore_from_now`), so that pressing it again cannot cut the way out -- the cleanup, the message and
    the exit status 130 -- and kill the process by the signal instead."""
    if not _can_hold():
        yield
        return
    got = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    try:
        yield
    finally:
        if got and is_command_line():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        else:
            signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)
    if got:
        raise KeyboardInterrupt


def ignore_from_now() -> None:
    """Ignore Ctrl-C from now on (main thread only): the command line calls it once it is ending on an interrupt."""
    if _can_hold():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
