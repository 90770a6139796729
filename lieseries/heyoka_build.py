"""Compiling heyoka's integrator for a system (:func:`build_integrator`), cached by structure, precision,
tolerance, events and options, and the event machinery its runs use: the recorder of non-terminal crossings, the
compiled event functions and the per-step guard that finds the crossings heyoka misses."""

from __future__ import annotations

import math
import os
import re
import time as _time
from fractions import Fraction
from pathlib import Path

import heyoka as hy
import numpy as np

from . import cache
from .models.base import Model
from .expr import expressions_digest
from .poisson import as_poisson_system
from .precision import check_tolerance, resolve_precision, to_fraction

__all__ = ["build_integrator", "compact_by_default", "integrator_count", "event_function", "Recorder", "CrossingGuard",
           "Both", "sparse_first_step", "first_step_bound", "top_orders", "norm_bounds", "use_own_disk_cache",
           "OWN_CACHE_BYTES"]

#: Compiled integrators (the templates runs copy, :func:`lieseries.cache.checkout`) by structure, precision,
#: tolerance, events and options, in the shared cache (:mod:`lieseries.cache`); an evicted template takes its pooled
#: copies with it.
INTEGRATORS = cache.region("taylor.integrators", 64, on_evict=cache.drop_template)


#: Above this many elementary operations in its Taylor decomposition a field is compiled in compact mode in double
#: too. Unrolled, LLVM's time grows about as the square of it (heyoka 7.13 on the 2-core machine: 57 operations, the
#: rigid body, 0.5 s; 110, a spherical pendulum's reduced form, 2.5 s; 247 12.7 s; 1377, a torus in a local chart,
#: 248 s; 2380, the heavy top's Dirac form, 575 s), compact 0.02-0.9 s; a compact run in double takes ~1.5 times as
#: long (the 110-operation field).
UNROLLED_OPERATIONS = 150
#: A function call in heyoka's printed form (``sin(``, ``atan(``; a variable is never followed by a parenthesis).
_CALL = re.compile(r"[A-Za-z_]\w*\(")
#: A negative exponent of a printed number (``1.0e-05``): not a negation.
_EXPONENT = re.compile(r"\de-\d")


def operations_bound(text: str) -> int:
    """An estimate, from above, of the elementary operations in the Taylor decomposition of an expression printed
    whole as ``text`` (heyoka's ``str`` of what is compiled, not cut short): every binary operator of the printed
    tree counts one, every negation one, every power three and every function call four (a sine brings its cosine,
    an arctangent its 1 + x^2). The printed tree repeats what the expression shares, so it is loose (the rigid body:
    120 against 57, the sphere 247 against 57); what decides is what the text holds, not its length (120 nested
    sines and cosines print in ~1250 characters and decompose into ~480 operations). :func:`compact_by_default`
    counts a field whose estimate exceeds :data:`SURE_SMALL`."""
    negations = text.count("-") - text.count(" - ") - len(_EXPONENT.findall(text))
    return (sum(text.count(o) for o in (" * ", " + ", " - ", " / ")) + negations + 3 * text.count("**")
            + 4 * len(_CALL.findall(text)))


#: A field whose :func:`operations_bound` is at most this is compiled unrolled without counting (a margin below
#: :data:`UNROLLED_OPERATIONS` for what the printed form does not show: a constant such as pi, a product heyoka
#: splits).
SURE_SMALL = 100


#: Whether a field's decomposition is above :data:`UNROLLED_OPERATIONS` (counted or not), by structure.
_LARGE_DECOMPOSITION = cache.region("taylor.decomposition_size", 256)


def compact_by_default(system, precision) -> bool:
    """Whether heyoka compiles ``system`` in compact mode when the caller does not say: always above double
    (LLVM is slow on unrolled long-double, quad and real code), above 20 variables, for a model that knows its
    field is large, and for a field whose Taylor decomposition has more than :data:`UNROLLED_OPERATIONS`
    elementary operations (counted once per structure on a compact build, which costs a fraction of a second, for
    a field that prints cut short or whose printed form may hold more than :data:`SURE_SMALL`:
    :func:`operations_bound`)."""
    ps = as_poisson_system(system)
    if resolve_precision(precision).name != "double" or ps.dimension > 20:
        return True
    if getattr(system, "large_field", False):
        return True
    large = _LARGE_DECOMPOSITION.get(ps.key)
    if large is None:  # once per structure (every build asks, the cached ones too)
        start = _time.perf_counter()
        text = [str(e) for _, e in ps.ode_system]  # (what heyoka compiles: integer powers written as products)
        large = False
        # (heyoka prints ~1000 characters of an expression at most, and "..." where it stops)
        if any("..." in t for t in text) or sum(map(operations_bound, text)) > SURE_SMALL:
            pars = [0.0] * len(ps.parameter_values)  # (an order-3 build: the decomposition is the same, quicker)
            probe = hy.taylor_adaptive(ps.ode_system, [0.0] * ps.dimension, pars=pars, compact_mode=True, tol=0.1)
            large = len(probe.decomposition) - 2 * ps.dimension > UNROLLED_OPERATIONS
        large = _LARGE_DECOMPOSITION.put(ps.key, large, cost=_time.perf_counter() - start)
    return large


#: What the command line's own heyoka disk cache keeps (its most recently used code; a run of the suite uses ~130 MiB).
OWN_CACHE_BYTES = 2**29


def use_own_disk_cache() -> str | None:
    """For a program that owns its process (the command line, the validation scripts): heyoka's disk cache in
    ``~/.cache/lieseries/heyoka`` (under ``$XDG_CACHE_HOME`` when set), bounded to :data:`OWN_CACHE_BYTES`, unless
    ``HEYOKA_CACHE_DIR`` says where it is. heyoka's default is one cache for every program of the user, up to 20
    GiB, read whole the first time a process compiles: at 11 GB the default scene's first build took 26 s instead
    of 0.03. Call it before anything is compiled; a library never changes it for its caller's process. Returns the
    path now used, or None when heyoka's is kept."""
    if os.environ.get("HEYOKA_CACHE_DIR"):
        return None
    path = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "lieseries" / "heyoka"
    try:
        path.mkdir(parents=True, exist_ok=True)
        hy.llvm_state.set_diskcache_path(str(path))
        hy.llvm_state.set_diskcache_limit(OWN_CACHE_BYTES)
    except (OSError, RuntimeError, ValueError):  # an unwritable home: heyoka's own cache stays
        return None
    os.environ["HEYOKA_CACHE_DIR"] = str(path)  # and the processes this one starts (a local Dask cluster)
    return str(path)


def integrator_count() -> int:
    """Number of compiled integrators in the cache."""
    return len(INTEGRATORS)


class Recorder:
    """Callback of a non-terminal heyoka event: records the time and the state of every crossing after the run's
    start ``t0`` (a zero at the start is where the run begins, not a crossing: lie_integrate agrees)."""

    def __init__(self):
        self.sink = []
        self.t0 = None
        self.at_t0 = 0  # zeros reported at t0 (dropped); heyoka may report one twice and miss the next one

    def __call__(self, ta, t, d_sgn):
        if t == self.t0:
            self.at_t0 += 1
            return
        ta.update_d_output(t)
        self.sink.append((t, np.array(ta.d_output, copy=True)))


EVENT_FUNCTIONS = cache.region("taylor.event_functions", 64)


def event_function(ps, prec, exprs):
    """The non-terminal events' expressions as one compiled function of the state (and parameters), in the run's
    format: the sign checks of :class:`CrossingGuard`."""
    key = (ps.key, prec.name, expressions_digest(exprs))  # (not their text: heyoka prints ~1000 characters)
    hit = EVENT_FUNCTIONS.get(key)
    if hit is None:
        kwargs = {} if prec.name == "double" else {"fp_type": prec.fp_type}
        if prec.is_real:
            kwargs["prec"] = prec.bits
        uses_pars = any(hy.get_params(e) for e in exprs)
        start = _time.perf_counter()
        fn = hy.cfunc(list(exprs), ps.variables, compact_mode=prec.name != "double", **kwargs)
        hit = EVENT_FUNCTIONS.put(key, (fn, uses_pars), cost=_time.perf_counter() - start)
    return hit


class CrossingGuard:
    """Per-step check of heyoka's non-terminal events, so that a missed crossing is found rather than lost.

    After every step the event functions are evaluated at the step's end. A step whose ends have opposite signs
    must hold an odd number of crossings (for a one-way event: at least one when the ends go that way), and one that
    starts or ends on a zero (a run starting on a Poincare section) is where heyoka's root finding is known to
    fail (heyoka 7.13 at >= 180 bits reports the zero at the start twice and misses the next crossing). Such a
    step is searched again on its Taylor polynomial (heyoka's dense output of the step): the function is sampled at
    ``SAMPLES`` points and each sign change is solved by bisection to the run's precision; crossings heyoka did not
    report are added. ``recovered`` counts them (``stats.extra["events_recovered"]``).
    """

    SAMPLES = 16

    def __init__(self, fn, uses_pars, directions, recorders, bits):
        self.fn, self.uses_pars = fn, uses_pars
        self.directions = directions
        self.recorders = recorders
        self.bits = bits
        self.recovered = 0
        self.touches = 0  # zeros heyoka reported where the function does not change sign (dropped)
        self.t_a = self.s_a = None
        self.marks = ()

    def _signs(self, ta, state):
        vals = self.fn(state, pars=ta.pars) if self.uses_pars else self.fn(state)
        return [int(v > 0) - int(v < 0) for v in vals]

    def start(self, ta):
        """The run (or a chunk run again) starts from the integrator's current time and state."""
        self.t_a, self.s_a = ta.time, self._signs(ta, ta.state)
        self.marks = [len(r.sink) for r in self.recorders]
        for r in self.recorders:
            r.at_t0 = 0

    def __call__(self, ta) -> bool:
        t_a, t_b = self.t_a, ta.time
        s_a, s_b = self.s_a, self._signs(ta, ta.state)
        for i, rec in enumerate(self.recorders):
            mark = self.marks[i]
            if len(rec.sink) > mark:
                self._crossings_only(ta, i, rec, mark, t_a, t_b)
            found = len(rec.sink) - mark
            a, b, d = s_a[i], s_b[i], self.directions[i]
            if a == 0 or b == 0 or rec.at_t0:
                suspect = True
            elif d == 0:
                suspect = (found % 2 == 1) != (a != b)
            else:
                forward = t_b > t_a
                suspect = found == 0 and (b - a) * d * (1 if forward else -1) > 0
            if suspect:
                self._search(ta, i, rec, mark, t_a, t_b)
            rec.at_t0 = 0
        self.t_a, self.s_a = t_b, s_b
        self.marks = [len(r.sink) for r in self.recorders]
        return True

    def _crossings_only(self, ta, i, rec, mark, t_a, t_b):
        """Keep, of heyoka's zeros in this step, the crossings: the function has opposite signs just before and
        just after (a tangency, such as a double zero of M2**2, is reported by heyoka once, twice or not at all;
        both engines report none). Duplicates (the same zero twice) are kept once."""
        h = abs(t_b - t_a)
        width = float(h) * 2.0 ** (-self.bits / 2)
        kept = []
        for t, y in rec.sink[mark:]:
            if kept and abs(float(t - kept[-1][0])) <= width:
                continue
            kept.append((t, y))
        times = [t for t, _ in kept]
        out = []
        for j, (t, y) in enumerate(kept):
            gaps = [abs(t - u) for u in times[:j] + times[j + 1:]]
            delta = min([h * 2.0 ** (-self.bits / 4)] + [g / 2 for g in gaps])
            before, after = self._g(ta, t - delta, i), self._g(ta, t + delta, i)
            if before * after < 0 or before == 0 or after == 0:
                out.append((t, y))
        if len(out) != len(rec.sink) - mark:
            self.touches += len(rec.sink) - mark - len(out)
            rec.sink[mark:] = out

    def _g(self, ta, t, i):
        ta.update_d_output(t)
        v = (self.fn(ta.d_output, pars=ta.pars) if self.uses_pars else self.fn(ta.d_output))[i]
        return int(v > 0) - int(v < 0)

    def _search(self, ta, i, rec, mark, t_a, t_b):
        """Crossings of event ``i`` in (t_a, t_b] from the step's polynomial; the ones heyoka missed are added."""
        n = self.SAMPLES
        h = t_b - t_a
        taus = [t_a + h * k / n for k in range(n)] + [t_b]
        signs = [self._g(ta, t, i) for t in taus]
        d = self.directions[i]
        forward = t_b > t_a
        roots = []
        for k in range(n):
            ga, gb = signs[k], signs[k + 1]
            if not (ga * gb < 0 or (gb == 0 and ga != 0)):
                continue  # a zero at the step's start is the previous step's crossing (or the run's start)
            rising = (gb > ga) == forward
            if d and rising != (d > 0):
                continue
            lo, hi = taus[k], taus[k + 1]
            if gb != 0:
                for _ in range(self.bits + 8):  # bisection to the last bit of the run's format
                    mid = lo + (hi - lo) / 2
                    if mid == lo or mid == hi:
                        break
                    gm = self._g(ta, mid, i)
                    if gm == 0:
                        lo = hi = mid
                        break
                    if gm == ga:
                        lo = mid
                    else:
                        hi = mid
            roots.append(hi)
        have = [t for t, _ in rec.sink[mark:]]
        width = abs(float(h)) * 2.0 ** (-self.bits / 2)
        added = [t for t in roots if all(abs(float(t - u)) > width for u in have)]
        if not added:
            return
        for t in added:
            ta.update_d_output(t)
            rec.sink.append((t, np.array(ta.d_output, copy=True)))
        rec.sink[mark:] = sorted(rec.sink[mark:], key=lambda r: float(r[0] - t_a) * (1 if forward else -1))
        self.recovered += len(added)

    def at_stop(self, ta, forward: bool):
        """After a terminal event stopped the run at ``ta.time``: the crossings that happen at that very time --
        within ``2^(-3 bits / 4)`` of the last step after it, where the roots of two expressions crossing together
        fall on either side by rounding -- are recorded as well (heyoka's step ended at the terminal root, and
        lie_integrate records them too)."""
        h = abs(float(ta.last_h)) if np.isfinite(float(ta.last_h)) else 0.0
        t_s = ta.time
        width = h * 2.0 ** (-3 * self.bits / 4)
        if not width:
            return
        t_b = t_s + (width if forward else -width)
        for i, rec in enumerate(self.recorders):
            if any(abs(float(t - t_s)) <= width for t, _ in rec.sink):
                continue
            mark = len(rec.sink)
            before = self.recovered
            self._search(ta, i, rec, mark, t_s, t_b)
            self.recovered = before  # (not missed by heyoka: beyond its step)


class Both:
    """Two step callbacks in turn."""

    def __init__(self, first, second):
        self.first, self.second = first, second

    def __call__(self, ta) -> bool:
        return bool(self.first(ta)) & bool(self.second(ta))


_HY_DIRECTION = {0: hy.event_direction.any, 1: hy.event_direction.positive, -1: hy.event_direction.negative}


def build_integrator(system, precision="double", tol=None, *, events=True, user_events=(), compact_mode=None,
                     high_accuracy=False):
    """The heyoka ``taylor_adaptive`` object for ``system`` (from the cache when possible).

    Returns
    -------
    ta : heyoka taylor_adaptive
    build_time : float
        Seconds spent building (0.0 on a cache hit).
    cached : bool
    event_info : list of (status, message) for the terminal events, in heyoka's event order.
    """
    ps = as_poisson_system(system)
    prec = resolve_precision(precision)
    tolf = check_tolerance(tol, prec)
    model = system if isinstance(system, Model) else None
    evs = model.events() if (model is not None and events) else []
    n = ps.dimension
    if compact_mode is None:
        compact_mode = compact_by_default(system, prec)
    # the events by the digests of their expressions: not their text (cut short past ~1000 characters), nor the
    # expressions (heyoka's == walks a shared subexpression once per path: 1.2 s for a Chebyshev polynomial of degree
    # 34 built by its recurrence, doubling every two degrees)
    user = (expressions_digest([e[1] for e in user_events]), tuple((e[2], e[3]) for e in user_events))
    key = (ps.key, prec.name, tolf, expressions_digest([e[0] for e in evs]), user, bool(compact_mode),
           bool(high_accuracy))
    info = [(e[1], e[2]) for e in evs]  # messages from this model, never from the cached one
    info += [("event", f"the event {e[0]!r} fired") for e in user_events if e[3]]
    hit = INTEGRATORS.get(key)
    if hit is not None:
        INTEGRATORS.touch(key)
        return hit, 0.0, True, info
    state = prec.array([0] * n)
    pars = prec.array(ps.parameter_values) if ps.parameter_values else None
    kwargs = dict(tol=prec.to_native(tolf), compact_mode=compact_mode, high_accuracy=high_accuracy)
    if prec.name != "double":
        kwargs["fp_type"] = prec.fp_type
    if prec.is_real:
        kwargs["prec"] = prec.bits
    fp = prec.fp_type if prec.name != "double" else float
    t_events = [hy.t_event(e[0], fp_type=fp) for e in evs]
    # at arbitrary precision heyoka's root finding misses the crossing in a step that starts on a zero (a run
    # starting on the surface): a one-way terminal event stopped at 3 pi for pi. It stops at every crossing, where
    # it stopped at t0 too, and the run goes on from those of the other way (lieseries.taylor.chunks)
    t_events += [hy.t_event(e[1], direction=_HY_DIRECTION[0 if prec.is_real else e[2]], fp_type=fp)
                 for e in user_events if e[3]]
    nt_events = [hy.nt_event(e[1], Recorder(), direction=_HY_DIRECTION[e[2]], fp_type=fp)
                 for e in user_events if not e[3]]
    if t_events:
        kwargs["t_events"] = t_events
    if nt_events:
        kwargs["nt_events"] = nt_events
    if pars is not None:
        kwargs["pars"] = pars
    t0 = _time.perf_counter()
    ta = hy.taylor_adaptive(ps.ode_system, state, **kwargs)
    build = _time.perf_counter() - t0
    cache.add_template(ta, copies=1)
    cached = INTEGRATORS.put(key, ta, cost=build)
    if cached is not ta:  # another thread built it at the same time: use the cached one
        cache.drop_template(ta)
    return cached, build, False, info


def sparse_first_step(ta, zero):
    """The largest sound first step from the state ``ta`` holds when heyoka's step rule cannot see the series
    there, else None.

    heyoka sizes a step from the last two orders of the Taylor series alone (Jorba and Zou: rho from the max-norms
    over the components of orders p - 1 and p, the step rho e^-2 exp(-0.7 / (p - 1))). A series with gaps -- at a
    point of symmetry, as ``q'' = 1 - 3 q^2`` from rest at the origin, whose q has only the orders 2, 6, 10, ...
    and p only 1, 5, 9, ... -- may have both orders zero in every component: rho is then infinite, heyoka takes
    one step as long as it is allowed (to the final time), and the result is wrong (off by 3.5e-7 in double).
    Near such a point the two orders are not zero but small (from q = 1e-6 instead of 0 they give a radius twice
    the true one: a first step off by 6e-14 in double, 270 of its units, ended `success`).
    Here the series at the state ``ta`` holds is computed (a step of length ``zero``, which moves nothing and
    fires no event, with its Taylor coefficients written; a run that takes its first step anyway reads them from
    that step: :func:`first_step_bound`). When orders p - 1 and p vanish in every component while
    a lower order (>= 1) does not, rho is taken from each component's last two nonzero orders by heyoka's own
    formula; when heyoka's rho exceeds :data:`ENVELOPE_RATIO` times the smallest one the orders p - K .. p give
    (K = max(4, p // 5): the gaps of period up to K + 1), the bound is heyoka's step at that smaller rho. A series
    without gaps reads nearly the same rho from each of its last orders (1.00-1.04 for the rigid body, the sphere,
    a heavy top, a pendulum, Kepler; 1.17 for the entire series of an oscillator); from q = 1e-3 the ratio is 1.32,
    from 1e-6 1.9. The bound is a Fraction. Only the series at a run's start is read: a state on the way is
    generic. An ensemble's batch reads its lanes' series at once (:func:`norm_bounds`)."""
    ta.step(zero, write_tc=True)
    return first_step_bound(ta.tc, ta.order)


#: heyoka's radius (from its last two orders) against the smallest from its last K + 1 orders beyond which the
#: first step is bounded (:func:`sparse_first_step`)
ENVELOPE_RATIO = 1.25


def first_step_bound(tc, p):
    """:func:`sparse_first_step` for the Taylor coefficients ``tc`` (variables x orders 0..p) of one state: what a
    step taken from that state with ``write_tc=True`` leaves in ``ta.tc`` (``p``: ``ta.order``); its numbers in
    any of heyoka's formats (their logarithms exact beyond the double range)."""
    logs0 = [_log_abs(v) for v in tc[:, 0]]
    log_x0 = max([-math.inf] + [x for x in logs0 if x is not None])
    if not (tc[:, p - 1:] != 0).any():
        return _gap_bound(tc, p, max(0.0, log_x0))  # (heyoka's scale: max(1, |x0|_inf))
    log_top = []
    for k in top_orders(p):
        logs = [_log_abs(v) for v in tc[:, k] if v != 0]
        if None in logs:  # a non-finite coefficient: heyoka's own checks see the run's trouble
            return None
        log_top.append(max(logs, default=-math.inf))
    return _log_bounds(np.array([log_x0]), np.array(log_top)[:, None], p)[0]


def top_orders(p):
    """The orders p - K .. p (K = max(4, p // 5)) of a series of order ``p`` that the rule of
    :func:`sparse_first_step` reads (with order 0)."""
    return range(p - max(4, p // 5), p + 1)


def norm_bounds(x0, top, p):
    """:func:`first_step_bound` of lanes from the max-norms over the components of their double Taylor
    coefficients: of order 0 (``x0``, per lane) and of the orders :func:`top_orders` (``top``, orders x lanes); None
    for a lane whose last two orders vanish (:func:`_gap_bound` needs its whole series) or with a non-finite
    coefficient (heyoka's own checks see the run's trouble)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return _log_bounds(np.log(x0), np.log(top), p)


def _log_bounds(log_x0, log_top, p):
    """The rule of :func:`sparse_first_step` for lanes given the logarithms of the max-norms of their order 0
    (``log_x0``, per lane) and of their orders p - K .. p (``log_top``, orders x lanes; -inf for a zero order, NaN or
    inf for a non-finite one: no bound)."""
    K = log_top.shape[0] - 1
    with np.errstate(invalid="ignore"):
        log_scale = np.fmax(0.0, log_x0)  # heyoka's: max(1, |x0|_inf)
        lr = np.where(log_top > -np.inf, (log_scale - log_top) / np.arange(p - K, p + 1)[:, None], np.inf)
        smallest = lr.min(axis=0)
        finite = (log_top < np.inf).all(axis=0)  # (NaN compares False)
        bounded = finite & (lr[-2:].min(axis=0) - smallest > math.log(ENVELOPE_RATIO))
    out = [None] * log_top.shape[1]
    for j in np.flatnonzero(bounded):
        out[j] = _step_at(float(smallest[j]), p)
    return out


def _log_abs(v):
    """log |v| of a nonzero finite number in any of heyoka's formats (None for zero or non-finite): from its double
    when that is a normal number well inside the range (rounded by 1e-16 at most: the log moves by as much), else
    from its exact value (a coefficient beyond the double range, at high precision)."""
    try:
        d = abs(float(v))
    except (TypeError, ValueError, OverflowError):
        d = math.nan
    if 1e-300 < d < 1e300:
        return math.log(d)
    if d == 0 and v == 0:
        return None
    try:
        f = abs(to_fraction(v))
    except (TypeError, ValueError, OverflowError):
        return None
    if f == 0:
        return None
    return math.log(f.numerator) - math.log(f.denominator)


def _gap_bound(tc, p, log_scale):
    """The bound of :func:`sparse_first_step` where orders p - 1 and p vanish in every component of ``tc``
    (``log_scale``: log max(1, |x0|_inf))."""
    log_rho = None
    for row in tc:
        found = []
        for k in range(p - 2, 0, -1):
            if row[k] != 0:
                lk = _log_abs(row[k])
                if lk is None:  # a non-finite coefficient: heyoka's own checks see the run's trouble
                    return None
                found.append((log_scale - lk) / k)
                if len(found) == 2:
                    break
        if found:
            r = min(found)
            log_rho = r if log_rho is None else min(log_rho, r)
    if log_rho is None:
        return None
    return _step_at(log_rho, p)


def _step_at(log_rho, p):
    """heyoka's step at the radius exp(``log_rho``), as a Fraction (None beyond any time span)."""
    log_h = log_rho - 2.0 - 0.7 / (p - 1)  # heyoka's safety factor e^-2 exp(-0.7 / (p - 1))
    if log_h > 700:
        return None  # no time span reaches it
    if log_h < -700:
        return Fraction(2) ** math.floor(log_h / math.log(2))
    return Fraction(math.exp(log_h))
