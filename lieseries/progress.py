"""A small progress bar on stderr (no dependency), silent when stderr is not a terminal.

Studies report progress through a plain callable ``progress(done, total, label)``; :class:`ProgressBar` is
such a callable. It redraws one line in place (carriage return), at most ten times a second, and only when the
stream is a TTY, so it never fills a CI log; ``force=True`` (or the environment variable
``LIESERIES_PROGRESS=1``) draws it anyway, ``LIESERIES_PROGRESS=0`` silences it everywhere.

Example::

    from lieseries.progress import ProgressBar

    with ProgressBar("drift") as bar:
        for i in range(n):
            ...
            bar(i + 1, n, f"run {i + 1}")
"""

from __future__ import annotations

import os
import sys
import time

__all__ = ["ProgressBar", "null_progress", "progress_enabled"]


def null_progress(done, total, label="") -> None:
    """A progress callable that does nothing."""


def progress_enabled(stream=None, force: bool = False) -> bool:
    """Whether a bar should be drawn on ``stream`` (default stderr)."""
    env = os.environ.get("LIESERIES_PROGRESS", "").strip().lower()
    if env in ("0", "no", "false", "off"):
        return False
    if force or env in ("1", "yes", "true", "on"):
        return True
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except (ValueError, OSError):  # closed stream
        return False


class ProgressBar:
    """``bar(done, total, label)`` draws ``title [#####-----] done/total label  elapsed``.

    Parameters
    ----------
    title : str
        Printed in front of the bar.
    stream : file, optional
        Default ``sys.stderr``.
    enabled : bool, optional
        Force on/off; default: on only when ``stream`` is a TTY (see :func:`progress_enabled`).
    width : int
        Bar width in characters.
    min_interval : float
        Seconds between redraws (the final state is always drawn).
    """

    def __init__(self, title: str = "", stream=None, enabled: bool | None = None, width: int = 24,
                 min_interval: float = 0.1):
        self.title = title
        self.stream = sys.stderr if stream is None else stream
        self.enabled = progress_enabled(self.stream) if enabled is None else bool(enabled)
        self.width = int(width)
        self.min_interval = float(min_interval)
        self.start = time.perf_counter()
        self._last = -1.0
        self._drawn = False
        self._len = 0

    def __call__(self, done, total, label: str = "") -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        final = total and done >= total
        if not final and now - self._last < self.min_interval:
            return
        self._last = now
        frac = 0.0 if not total else max(0.0, min(1.0, done / total))
        fill = int(round(frac * self.width))
        bar = "#" * fill + "-" * (self.width - fill)
        text = f"{self.title} [{bar}] {done}/{total} {label}"[:100] + f"  {now - self.start:5.1f}s"
        pad = " " * max(0, self._len - len(text))
        try:
            self.stream.write("\r" + text + pad)
            self.stream.flush()
        except (ValueError, OSError):  # the stream went away: stop drawing
            self.enabled = False
            return
        self._len = len(text)
        self._drawn = True

    def close(self) -> None:
        """Clear the bar's line (the bar leaves nothing behind in the terminal)."""
        if self.enabled and self._drawn:
            try:
                self.stream.write("\r" + " " * self._len + "\r")
                self.stream.flush()
            except (ValueError, OSError):
                pass
        self._drawn = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
