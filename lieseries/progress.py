"""Progress bars (tqdm) for scenes and studies, silent in CI and when stderr is not a terminal.

Studies report progress through a plain callable ``progress(done, total, label)``; :class:`ProgressBar` is such a
callable, drawn by tqdm (rate limited, at most ten redraws a second). It draws only on a terminal and not in CI
(the ``CI`` environment variable), so it never fills a log; ``LIESERIES_PROGRESS=1`` draws it anyway,
``LIESERIES_PROGRESS=0`` silences it everywhere.

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

from tqdm import tqdm

__all__ = ["ProgressBar", "null_progress", "progress_enabled"]


def null_progress(done, total, label="") -> None:
    """A progress callable that does nothing."""


def progress_enabled(stream=None, force: bool = False) -> bool:
    """Whether a bar should be drawn on ``stream`` (default stderr): ``LIESERIES_PROGRESS`` decides when set;
    otherwise on a terminal, and not in CI."""
    env = os.environ.get("LIESERIES_PROGRESS", "").strip().lower()
    if env in ("0", "no", "false", "off"):
        return False
    if force or env in ("1", "yes", "true", "on"):
        return True
    if os.environ.get("CI"):
        return False
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except (ValueError, OSError):  # closed stream
        return False


class ProgressBar:
    """``bar(done, total, label)``: a tqdm bar titled ``title`` showing done/total, the label and the rate.

    Parameters
    ----------
    title : str
    stream : file, optional
        Default ``sys.stderr``.
    enabled : bool, optional
        Force on/off; default: :func:`progress_enabled`.
    min_interval : float
        Seconds between redraws (tqdm's ``mininterval``; the final state is always drawn).
    """

    def __init__(self, title: str = "", stream=None, enabled: bool | None = None, min_interval: float = 0.1):
        self.stream = sys.stderr if stream is None else stream
        self.enabled = progress_enabled(self.stream) if enabled is None else bool(enabled)
        self._bar = tqdm(desc=title, file=self.stream, disable=not self.enabled, mininterval=float(min_interval),
                         leave=False, dynamic_ncols=True, total=0)

    def __call__(self, done, total, label: str = "") -> None:
        if not self.enabled:
            return
        bar = self._bar
        if total and bar.total != total:
            bar.total = total
        if label:
            bar.set_postfix_str(str(label)[:60], refresh=False)
        step = done - bar.n
        if step:
            bar.update(step)
        if total and done >= total:
            bar.refresh()

    def close(self) -> None:
        """Clear the bar's line (the bar leaves nothing behind in the terminal)."""
        self._bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
