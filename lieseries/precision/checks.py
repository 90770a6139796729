"""The checks of the package's arguments: digits, orders, counts, tolerances, times, seconds, callables, progress
and switches, each returning the checked value (or raising, naming the argument and its bounds)."""

from __future__ import annotations

import math
import numbers
from fractions import Fraction

import numpy as np

from ..progress import ProgressBar
from .bounds import MAX_DPS, MAX_ORDER, MAX_TIME_MAGNITUDE, MIN_DPS
from .conversions import short_decimal, to_fraction


def check_dps(dps, argname: str = "dps") -> int:
    """Validate a number of decimal digits (an integer in [MIN_DPS, MAX_DPS]) and return it as an int."""
    if isinstance(dps, bool) or not isinstance(dps, numbers.Integral):
        raise TypeError(
            f"`{argname}` must be an integer number of decimal digits in [{MIN_DPS}, {MAX_DPS}]; got {dps!r}"
        )
    if dps < MIN_DPS:
        raise ValueError(
            f"`{argname}` must be at least {MIN_DPS} decimal digits; got {dps}. For fewer digits use "
            "`lieseries.integrate` in double."
        )
    if dps > MAX_DPS:
        raise ValueError(f"`{argname}` must be at most {MAX_DPS} decimal digits; got {dps}")
    return int(dps)


def check_order(order, argname: str = "order") -> int:
    """Validate a series order (an integer in [1, MAX_ORDER]) and return it as an int."""
    if isinstance(order, bool) or not isinstance(order, numbers.Integral):
        raise TypeError(f"`{argname}` must be an integer >= 1; got {type(order).__name__} {order!r}")
    if order < 1:
        raise ValueError(f"`{argname}` must be an integer >= 1; got {order}")
    if order > MAX_ORDER:
        raise ValueError(
            f"`{argname}` must be at most {MAX_ORDER} (the cost grows like order^2); got {order}. Shorter steps "
            "with a lower order reach the same accuracy."
        )
    return int(order)


def check_count(value, argname: str, *, low: int = 1, high: int | None = None) -> int:
    """Validate an integer count (numpy integers accepted) in [low, high] and return it as an int."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"`{argname}` must be an integer >= {low}; got {type(value).__name__} {value!r}")
    value = int(value)
    if value < low or (high is not None and value > high):
        bound = f"in [{low}, {high}]" if high is not None else f">= {low}"
        raise ValueError(f"`{argname}` must be an integer {bound}; got {value}")
    return value


def check_tolerance(tol, prec) -> Fraction:
    """A tolerance in (0, 1), at least the epsilon of ``prec`` (a :class:`~lieseries.precision.formats.Precision`;
    default: that epsilon), as an exact Fraction."""
    eps = Fraction(1, 2 ** (prec.bits - 1))
    if tol is None:
        return eps
    f = to_fraction(tol, "tol")
    if f <= 0:
        raise ValueError(f"`tol` must be positive; got {short_decimal(f)}. Leave it out to use the precision's "
                         "epsilon.")
    if f >= 1:
        raise ValueError(f"`tol` must be below 1 (it is a relative and absolute tolerance); got {short_decimal(f)}")
    if f < eps:
        raise ValueError(
            f"`tol` = {float(f):.3g} is below the epsilon of {prec.name} ({float(eps):.3g}): no run in that "
            "precision can reach it. Raise `tol`, or choose a higher `precision`."
        )
    return f


def check_time(value, argname: str = "t", *, positive: bool = False) -> Fraction:
    """A nonzero (``positive``: positive) time within 1e-MAX_TIME_MAGNITUDE .. 1eMAX_TIME_MAGNITUDE in magnitude,
    as an exact Fraction."""
    f = to_fraction(value, argname)
    if f == 0 or (positive and f < 0):
        raise ValueError(f"`{argname}` must be a {'positive' if positive else 'nonzero'} time; got {value!r}")
    if not Fraction(1, 10**MAX_TIME_MAGNITUDE) <= abs(f) <= 10**MAX_TIME_MAGNITUDE:
        raise ValueError(f"`{argname}` = {short_decimal(f)} must lie within 1e-{MAX_TIME_MAGNITUDE} .. "
                         f"1e{MAX_TIME_MAGNITUDE} in magnitude (runs report their times as doubles)")
    return f


def check_seconds(value, argname: str):
    """Validate an optional positive, finite number of seconds (None passes through) and return a float."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"`{argname}` must be a positive number of seconds; got {type(value).__name__} {value!r}")
    v = float(value)
    if not (v > 0 and math.isfinite(v)):
        raise ValueError(f"`{argname}` must be a positive, finite number of seconds; got {value!r}")
    return v


def check_callable(value, argname: str):
    """Validate an optional callable (None passes through)."""
    if value is not None and not callable(value):
        raise TypeError(f"`{argname}` must be callable (or None); got {type(value).__name__} {value!r}")
    return value


class _FractionBar:
    """``progress(fraction_done)`` drawn as a bar of 1000 steps (closed when the run is done or forgotten)."""

    def __init__(self, title):

        self._bar = ProgressBar(title)

    def __call__(self, fraction) -> None:
        done = min(1000, max(0, int(round(1000 * float(fraction)))))
        self._bar(done, 1000)
        if done >= 1000:
            self._bar.close()

    def __del__(self):
        try:
            self._bar.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass


def check_progress(value, argname: str = "progress", title: str = "run"):
    """A run's ``progress`` argument as a callable ``progress(fraction_done)`` or None: a callable passes through,
    True shows a bar (:class:`lieseries.progress.ProgressBar`: drawn on a terminal, silent in CI), None and False
    show nothing."""
    if value is True:
        return _FractionBar(title)
    if value is None or value is False:
        return None
    if not callable(value):
        raise TypeError(f"`{argname}` must be callable (progress(fraction_done)), True (show a bar) or None; got "
                        f"{type(value).__name__} {value!r}")
    return value


def check_flag(value, argname, allow_none=True):
    """A switch must be True or False (or None for the default): 'yes' or 0 would silently pick one."""
    if (value is None and allow_none) or isinstance(value, (bool, np.bool_)):
        return
    raise TypeError(f"`{argname}` must be True or False{' (or None for the default)' if allow_none else ''}; got "
                    f"{type(value).__name__} {value!r}")
