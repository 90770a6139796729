"""Validation of output times, shared by every integrator."""

from __future__ import annotations

import decimal
import math
import os
import time
import warnings

from fractions import Fraction

import mpmath
import numpy as np

from .caller import stacklevel
from .precision import PrecisionWarning, check_seconds, short_decimal, to_fraction, to_raw

__all__ = ["parse_times", "time_rows", "output_bytes", "MAX_OUTPUT_BYTES", "span_loss", "warn_span_loss",
           "refuse_lost_span", "MIN_SPAN_BITS"]


def _half_the_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2
    except (AttributeError, ValueError, OSError):  # pragma: no cover - no sysconf: a fixed 4 GiB
        return 4 << 30


#: The largest output a run may ask for, in bytes: half the machine's physical memory (4 GiB where it cannot be
#: read). Requests beyond it are refused before any integration, naming ``t`` and the estimate.
MAX_OUTPUT_BYTES = _half_the_memory()
#: Bytes per output time besides its row: the exact time (a Fraction), the float time, the list and array slots.
PER_TIME_BYTES = 400


def output_bytes(n_times: int, values_per_time: int, bytes_per_value: int) -> int:
    """An estimate of the memory ``n_times`` output rows take: each row's values (twice: the rows are assembled,
    then stacked) and the time's own bookkeeping."""
    return int(n_times) * (2 * int(values_per_time) * int(bytes_per_value) + PER_TIME_BYTES)


def _check_size(n_times, values_per_time, bytes_per_value, argname):
    est = output_bytes(n_times, values_per_time, bytes_per_value)
    if est > MAX_OUTPUT_BYTES:
        raise ValueError(
            f"`{argname}` asks for {n_times} output times: about {est / 2**30:.3g} GiB of output "
            f"({values_per_time} values of ~{bytes_per_value} bytes per time), more than the "
            f"{MAX_OUTPUT_BYTES / 2**30:.3g} GiB allowed (half the physical memory); ask for fewer output times, "
            "or split the run and keep what you need of each part"
        )


#: Output times converted between two readings of the clock (a few milliseconds of work).
CHUNK = 4096


class _ConversionBudget:
    """The clock of a grid's conversion: refuses, naming the grid's argument, a conversion that cannot finish
    within ``max_time``."""

    def __init__(self, max_time, n, argname):
        self.max_time = check_seconds(max_time, "max_time")
        self.n, self.argname = n, argname
        self.start = time.perf_counter()

    def check(self, done):
        if self.max_time is None or done >= self.n:
            return
        elapsed = time.perf_counter() - self.start
        projected = elapsed * self.n / done
        if projected > self.max_time:
            raise ValueError(
                f"`{self.argname}` asks for {self.n} output times; converting them exactly takes about "
                f"{projected:.3g} s ({done} converted in {elapsed:.3g} s), more than `max_time` = "
                f"{self.max_time:g} s: ask for fewer output times (a float64 array, e.g. np.linspace, converts "
                "fastest), or raise `max_time`"
            )


def parse_times(t, t0=0, argname: str = "t", *, values_per_time: int = 1, bytes_per_value: int = 8,
                max_time: float | None = None):
    """Validate output times.

    A scalar ``t`` asks for the state at ``t`` (before ``t0`` integrates backward); the outputs are then
    ``[t0, t]`` (just ``[t0]`` when t equals t0). A sequence is a grid of output times: strictly increasing and not before ``t0`` (forward), or
    strictly decreasing and not after ``t0`` (backward).

    Returns
    -------
    grid : list of Fraction
        Output times (exact).
    direction : int
        +1 forward, -1 backward, 0 when nothing is to be integrated.
    t0 : Fraction

    ``values_per_time`` and ``bytes_per_value`` (the caller's row: state size, members, bytes per number) size the
    estimate of the output's memory: a grid whose output would not fit in :data:`MAX_OUTPUT_BYTES` is refused,
    naming ``t``, before anything is converted or integrated.

    ``max_time`` (the run's wall-time budget, seconds) bounds the exact conversion of a grid: the clock is read
    every :data:`CHUNK` values, and a grid whose conversion would not finish within the budget (projected from the
    values converted so far) or did not is refused, naming ``t`` and the estimate -- never cut short.
    """
    t0 = to_fraction(t0, "t0")
    if isinstance(t, (str, bytes)) or np.ndim(t) == 0:
        tf = to_fraction(t.item() if isinstance(t, np.ndarray) else t, argname)
        if tf == t0:
            return [t0], 0, t0
        return [t0, tf], (tf > t0) - (tf < t0), t0
    _check_size(np.size(t) if isinstance(t, np.ndarray) else len(t) if hasattr(t, "__len__") else 0,
                values_per_time, bytes_per_value, argname)
    arr = np.asarray(t, dtype=object)
    if arr.ndim != 1:
        raise ValueError(f"`{argname}` must be a final time or a 1-d sequence of output times; got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"`{argname}` must not be an empty sequence of output times")
    budget = _ConversionBudget(max_time, arr.size, argname)
    if isinstance(t, np.ndarray) and t.dtype == np.float64:
        # a grid of doubles (np.linspace): every finite double is in range and exact as p/2^k, so the values are
        # checked at once and converted without the general path's per-number work
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise ValueError(f"`{argname}[{int(bad[0])}]` must be finite; got {t[bad[0]]}")
        grid = []
        for lo in range(0, t.size, CHUNK):
            grid.extend(Fraction(*x.as_integer_ratio()) for x in t[lo:lo + CHUNK].tolist())
            budget.check(len(grid))
        step = np.diff(t)
        inc, dec = bool(np.all(step > 0)), bool(np.all(step < 0))
    else:
        grid = []
        inc = dec = True
        for lo in range(0, arr.size, CHUNK):
            part = [to_fraction(v, f"{argname}[{i}]") for i, v in enumerate(arr[lo:lo + CHUNK], lo)]
            joined = grid[-1:] + part
            inc = inc and all(b > a for a, b in zip(joined, joined[1:]))
            dec = dec and all(b < a for a, b in zip(joined, joined[1:]))
            grid.extend(part)
            budget.check(len(grid))
    if len(grid) == 1:
        return grid, (grid[0] > t0) - (grid[0] < t0), t0
    if not (inc or dec):
        i = next(i for i, (a, b) in enumerate(zip(grid, grid[1:])) if (b - a) * (grid[1] - grid[0]) <= 0)
        raise ValueError(
            f"`{argname}` must be strictly increasing (or strictly decreasing, for backward integration); "
            f"t[{i}] = {float(grid[i])} is followed by t[{i + 1}] = {float(grid[i + 1])}"
        )
    if inc and grid[0] < t0:
        raise ValueError(
            f"`{argname}` is an increasing grid but starts before t0 = {float(t0)} (t[0] = {float(grid[0])}); "
            "output times must not cross t0: give a decreasing grid for backward integration, or set `t0`"
        )
    if dec and grid[0] > t0:
        raise ValueError(
            f"`{argname}` is a decreasing grid (backward integration) but starts after t0 = {float(t0)} "
            f"(t[0] = {float(grid[0])}); output times must not cross t0"
        )
    return grid, (1 if inc else -1), t0


def span_loss(grid, t0, rounded, rounded_t0):
    """``(loss, k)``: the largest change that rounding the times (``grid`` to ``rounded``, ``t0`` to ``rounded_t0``,
    exact values) made to an output time's span t_k - t0, relative to the run's whole span, and its index;
    ``(0, None)`` when t0 is 0 (each time then keeps its own relative precision, and so does its span)."""
    whole = abs(grid[-1] - t0) if grid else 0
    if (t0 == 0 and rounded_t0 == 0) or not whole:
        return Fraction(0), None
    worst, at = Fraction(0), None
    d0 = rounded_t0 - t0
    for k, (g, r) in enumerate(zip(grid, rounded)):
        if r == g and not d0:
            continue  # (a time the format holds: a grid of doubles in double)
        loss = abs((r - g) - d0)
        if loss > worst:
            worst, at = loss, k
    return worst / whole, at


def _shown(x: Fraction) -> str:
    """``x`` to 25 significant digits (1e20 + 100 is not 1e+20 here), trailing zeros dropped."""
    if not x or abs(x) >= 10**300 or abs(x) < Fraction(1, 10**300):
        return short_decimal(x)
    d = decimal.Context(prec=25).divide(decimal.Decimal(x.numerator), decimal.Decimal(x.denominator))
    return format(d.normalize(decimal.Context(prec=25)), "f" if abs(d) < 10**25 else "g")


def warn_span_loss(loss, grid, t0, bits: int, where: str) -> bool:
    """One :class:`~lieseries.precision.PrecisionWarning` when the run keeps an output time's span t - t0 only to
    ``loss`` relative to the run's whole span (a pair from :func:`span_loss`), above 2^-(``bits`` - 8): more than
    the roundings of t and t0 at the run's precision (an atlas run's segments start at times of their own).
    ``where`` says how the times are held. A run of autonomous equations depends on t - t0 alone, and t0 = 1e6
    with t = '1000000.1' in double ran 0.0999999999767 time units, its state 2e-11 from the one asked for. True
    when it warned (:func:`refuse_lost_span` refuses the calls that would keep almost nothing)."""
    worst, k = loss
    if k is None or worst <= Fraction(1, 2 ** (bits - 8)):
        return False
    span = grid[k] - t0
    kept = max(0, math.floor(-math.log2(worst))) if worst < 1 else 0
    warnings.warn(
        f"`t` - `t0` = {_shown(span)} (t = {_shown(grid[k])}, t0 = {_shown(t0)}) is kept only "
        f"to {float(worst):.2g} of the run's span (about {kept} bits of its {bits}): {where}. The equations do "
        "not depend on time itself, only on t - t0: start from t0 = 0 and pass t - t0 as the times (add t0 back to "
        "sol.t).",
        PrecisionWarning,
        stacklevel=stacklevel(),
    )
    return True


#: A call that would keep fewer bits than this of its span t - t0 is refused (its result would be wrong from its first
#: digits) rather than run with a warning.
MIN_SPAN_BITS = 8


def refuse_lost_span(t, t0, prec, atlas: bool = False) -> None:
    """A ValueError naming `t0` when the times of a run at the precision ``prec`` (a
    :class:`~lieseries.precision.Precision`) would keep its span t - t0 to fewer than :data:`MIN_SPAN_BITS` bits: from
    t0 = 10^20 to t = 10^20 + 1 in double the times round to one value, and the run took no step and ended `success`
    at its initial state. For the caller's own times (an atlas run's segments start at times of their own, where
    :func:`warn_span_loss` speaks). ``atlas``: a run across charts, which restarts at every chart switch from the time
    the last segment reached, rounded to the run's numbers: refused as well when their spacing near t0 is more than
    2^-(bits - 8) of the span, since those roundings add up (a Sphere from t0 = 10^15 to t0 + 100 in double ended
    `success` 0.48 off, from 10^12 2e-4 off, with no warning)."""
    grid, direction, t0f = parse_times(t, t0)
    if not direction or t0f == 0:
        return
    worst, k = span_loss(grid, t0f, [to_fraction(prec.time(g)) for g in grid], to_fraction(prec.time(t0f)))
    if k is not None and worst >= Fraction(1, 2 ** MIN_SPAN_BITS):
        span = grid[k] - t0f
        what = (f"(t = {_shown(grid[k])}): the run's times are {prec.name} numbers, which would keep t - t0 only to "
                f"{float(worst):.2g} of the run's span, and the result would be wrong from its first digits")
    elif atlas:
        big, span = max(abs(t0f), abs(grid[-1])), abs(grid[-1] - t0f)
        loss = big / span / 2 ** (prec.bits - 1)
        if loss <= Fraction(1, 2 ** (prec.bits - 8)):
            return
        what = (f"for a run across charts: it restarts at each chart switch from the time reached, rounded to "
                f"{prec.name} numbers, which near t0 are {float(big / 2 ** (prec.bits - 1)):.2g} apart "
                f"({float(loss):.2g} of the span at each switch, adding up)")
    else:
        return
    raise ValueError(
        f"`t0` = {_shown(t0f)} is too large beside `t` - `t0` = {_shown(span)} {what}. The equations do not depend on "
        "time itself, only on t - t0: start from t0 = 0 and pass t - t0 as the times (add t0 back to sol.t).")


def time_rows(times, bits: int) -> np.ndarray:
    """The output times of an mpmath engine's rows (exact values) as an object array of mpf rounded once to ``bits``
    (its rows' precision): float64 labels made distinct times beside t0 = 1e20 one (1e20 + 1, + 2 and + 3 all
    1e20) and put the double 0.1 beside the row at 0.1."""
    out = np.empty(len(times), dtype=object)
    for i, v in enumerate(times):
        out[i] = mpmath.make_mpf(to_raw(v, bits, "t"))
    return out
