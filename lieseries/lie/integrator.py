"""Adaptive Lie-series integration: the flow as a composition of truncated operators exp(h_n X_H).

Step and order rules
--------------------
Order. When not given, N = ceil(-ln(tol) / 2) + 1 (Jorba & Zou, Exp. Math. 14 (2005) 99): with a step of about
rho / e^2 the truncation error of an order-N step is then near tol, and this N minimises the work per unit time
for a Taylor method whose cost grows like N^2. For 50 digits N = 59, for 100 digits N = 117. A step of this engine
also costs a N (the Python work around the big-integer products), and (a N + b N^2) e^(L/N) is least some orders
above L / 2 (L = -ln tol): 8-14 orders more made 30- and 50-digit runs 10-20% faster (``benchmarks/lie_order.py``),
but their steps approach e^(-1.6) rho, each step's error comes closer to tol, and the errors grew with it (the heavy
top of the `heavy-top` scene to t = 10 at 30 digits: 2.9e-31 at order 36, 1.4e-30 at order 44): the order stays
Jorba and Zou's.

Step. At each step the coefficients c_0..c_N of the series at the current state are computed (jets, O(N^2) per node
of the vector field). The step is the largest h with |c_k,i| h^k <= tol * s_i for every component i and the last
two orders k = N-1, N (the tail of a converging series is governed by its last terms; using two of them tolerates a
coefficient that vanishes by symmetry; a component whose last two both vanish, by a symmetry of period 4, is held
by its last nonzero order), where s_i is the component's own scale: the larger of its size over the step, sum_k
|c_k,i| h^k (below 1 its terms k = 0, 1, which bound it from below), and its largest |value| at the steps' starts
so far (a component passing through zero keeps the scale of its swing). The tolerance is relative for every
component, in any units: relative to the largest component, a momentum of size 1 beside positions of size 1e6 kept
only tol * 1e6 of its digits; absolute below 1, a momentum of size 1e-5 kept only tol / 1e-5 of them, and when the
velocity is the momentum over 1e-5 its error went into the positions at once (3.5 digits lost at 30 digits, the
estimates saying 2e-32). A component that is zero so far and over the step asks nothing; no component is asked for
less than what the jets' own roundings put into it (their bound, where they measure one: a sphere's momentum along
x1 in the intermediate form, zero along a great circle but for the roundings, 1e-45 against 1.5: held to its own
noise, it took 1048 steps to the chart's edge where 21 serve). The step is capped at half
the radius of convergence estimated from the coefficients, so that a step never reaches the singularity where the
series diverges. The last step is shortened to land on the final time; output times inside a step are evaluated
from that step's polynomial (dense output of the same accuracy).

Error estimate. Every step records the geometric-tail estimate of its truncation error
(:func:`lieseries.lie.operator.tail_estimate`: the last two terms carried on at the ratio h / rho), per component
and relative to its scale s_i, the largest over the components; where the last eight orders'
terms decay more slowly than h / rho says (a radius fitted too long), also each component's own last terms carried
on at their own rate (``_envelope_tail``: the pendulum in a chart had steps whose error was 227x the estimate);
``sol.stats.error_estimates`` holds them all. They are local: the error of the result is their sum carried along by
the flow (for a rotation, a momentum's error turns into a phase error that grows with the angle covered).

All work is done with ``guard`` extra digits (default 10) and results are rounded to ``dps``.
"""

from __future__ import annotations

import math
import time as _time
import warnings
from fractions import Fraction

import numpy as np
from mpmath.libmp import from_man_exp

from ..caller import stacklevel
from ..driver import StepResult, Stop, drive, energy_guard
from ..events import resolve_events
from ..poisson import as_poisson_system
from ..precision import (
    MAX_ORDER,
    Precision,
    check_progress,
    check_count,
    check_dps,
    check_order,
    check_seconds,
    data_bits,
    dps_to_bits,
    export_mpf,
    float_or_mpf,
    mp_context,
    to_fraction,
    to_mpf,
    warn_if_coarse,
)
from ..precision import thread_mp as mp
from ..solution import Solution, Stats
from ..timegrid import parse_times, time_rows, warn_span_loss
from .crossings import UserEvents
from .plan import radius_from_logs
from .operator import (
    GUARD_DIGITS,
    coarse_bits,
    horner,
    prepare,
)

__all__ = ["lie_integrate", "default_order", "jorba_zou_order"]


def jorba_zou_order(tol) -> int:
    """The Jorba-Zou order for a tolerance: ceil(-ln(tol) / 2) + 1, at least 4 (heyoka's order too)."""
    return max(4, math.ceil(-float(mp.log(tol)) / 2) + 1)


def default_order(tol) -> int:
    """The automatic order for a tolerance: the Jorba-Zou order (module docstring)."""
    return jorba_zou_order(tol)


def lie_integrate(
    system,
    y0,
    t,
    *,
    dps: int = 30,
    tol=None,
    order: int | None = None,
    t0=0,
    dense: bool = False,
    max_steps: int = 100_000,
    max_time: float | None = None,
    guard: int = GUARD_DIGITS,
    progress=None,
    atlas: bool | None = None,
    events=None,
) -> Solution:
    """Integrate with composed truncated Lie series exp(h X_H), in mpmath at ``dps`` digits.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers (exact values are used)
    t : float or monotonic sequence
        Final time or output times (same rules as :func:`lieseries.integrate`).
    dps : int
        Decimal digits of the arithmetic and of the results.
    tol : float, optional
        Local error tolerance per step, relative to each component's own scale (its size over the step, or its
        largest value so far when that is larger: module docstring). Default 10**-dps.
    order : int, optional
        Series order; default from ``tol`` (module docstring).
    dense : bool
        Keep every step's polynomial so that ``sol(t)`` works anywhere in the interval.
    events : list of :class:`lieseries.Event`, optional
        Zero crossings to record (``sol.events[name]``) or stop at (terminal: status ``event``): each event
        expression is resolved on each step's polynomial (Chebyshev samples until its interpolant is, on halves of
        the step where 65 do not: :mod:`lieseries.lie.crossings`), and every crossing is solved for in mpmath at the
        working precision (a bracketed secant method on the step's polynomial).
    max_steps, max_time :
        Budgets; the run stops with status ``step_budget`` / ``time_budget`` and keeps what it computed. After 64
        steps (or 1% of ``max_steps``), a run that at its step size and at its average step would need more than
        10 times the steps left stops at once, saying so (``step_collapse`` where its steps have shrunk below
        1/100 of its longest).
    progress : callable or True, optional
        Called as ``progress(fraction_done)`` after each step; True shows a bar (on a terminal).
    atlas : bool, optional
        For a model with charts (Sphere), on by default: switch charts at the end of the step where the current
        one is ending and go on (:mod:`lieseries.atlas`); ``sol.charts`` tells the chart of each output row.
        ``atlas=False`` stays in one chart and stops at its edge (``chart_edge``).

    Returns
    -------
    Solution
        ``y`` rows are numpy object arrays of mpf; ``stats.error_estimates`` has one estimate per step (its
        truncation error relative to each component's scale; the largest over the components; never below the
        round-off of the working digits, 10^-(dps + guard));
        ``stats.extra["max_step_over_radius"]`` is the largest step over the estimated radius of convergence
        (at most 1/2 by construction). When the data carry fewer bits than the run (binary floats), every
        per-step estimate is at least the relative uncertainty of the data (``stats.extra["data_bits"]``), and
        one :class:`~lieseries.precision.PrecisionWarning` says so.
    """
    from .fixed import FixedStepper

    prec = _precision(dps, guard)
    dps = prec.dps
    user_events_arg = events
    max_steps = check_count(max_steps, "max_steps")
    max_time = check_seconds(max_time, "max_time")
    progress = check_progress(progress, title="lie_integrate")
    if atlas is None:
        atlas = bool(getattr(system, "atlas", False))  # a Sphere says (True unless built with atlas=False)
    if atlas:
        from ..atlas import run_atlas

        coarse_bits(as_poisson_system(system), y0, prec.bits, times=[t, t0])
        return run_atlas(lie_integrate, system, y0, t, t0=t0, bits=prec.working_bits, dense=dense,
                         energy_tol=tol if tol is not None else Fraction(1, 10**dps),
                         dps=dps, tol=tol, order=order, max_steps=max_steps, max_time=max_time, guard=guard,
                         progress=progress, events=events)
    ps, model, z0, pars = prepare(system, y0)
    tic = _time.perf_counter()
    grid, direction, t0f = parse_times(t, t0, max_time=max_time, values_per_time=ps.dimension,
                                       bytes_per_value=64 + prec.working_bits // 8)  # rows of mpf
    if direction:  # a step's length is rounded to |t| 2^-working_bits as it is added to the time
        big, span = max(abs(t0f), abs(grid[-1])), abs(grid[-1] - t0f)
        warn_span_loss((big / span / 2**prec.working_bits, len(grid) - 1), grid, t0f, prec.bits,
                       f"the times are carried with {prec.working_dps} digits, so each step's length is rounded to "
                       f"{float(big):.3g} x 10^-{prec.working_dps}")
    tolm = _tolerance(tol, prec)
    N, N_auto = _series_order(order, tolm, tol, prec)
    bits = coarse_bits(ps, y0, prec.bits, times=[t, t0])

    built = _time.perf_counter()
    stepper = FixedStepper(ps.program, pars, N, prec)  # the jets in fixed-point big integers
    # max_time bounds the call from the output times' conversion and checks on, but for the stepper's build
    start = tic + (_time.perf_counter() - built)
    user_events = resolve_events(user_events_arg, system, ps, prec.bits)
    wdps = prec.working_dps
    with mp.workdps(wdps):
        engine = _LieEngine(stepper, N, N_auto if order is not None else None, tolm, wdps, bits, max_steps,
                            1 if direction >= 0 else -1, _event_checks(model, ps),
                            UserEvents(user_events, ps, pars) if user_events else None,
                            None if max_time is None else start + max_time, dense)
        z = [to_mpf(v, ctx=mp_context()) for v in z0]
        tstart = to_mpf(t0f, ctx=mp_context())
        _check_events(engine.events, z)  # records the signs at the start
        out = drive(engine, tstart, z, [(to_mpf(tk, ctx=mp_context()), tk) for tk in grid], direction=direction,
                    max_steps=max_steps, max_time=max_time, start=start, progress=progress,
                    kept="The rows up to this time are kept.",
                    # the energy guard of every run: H at the end against H(y0) (lieseries.energy.drift_threshold)
                    guard=lambda out: energy_guard(out, ps, z0, export_mpf(list(out.z)), prec.working_bits, tolm))
        return _solution(out, engine, prec, tolm, N, bits, grid, ps.dimension, dense)


def _solution(out, engine, prec, tolm, N, bits, grid, n, dense) -> Solution:
    """The run's :class:`Solution` from the driver's outcome (in the working precision's context): rows rounded
    to ``prec``'s digits, the reached state with its guard digits (a run continued from it, an atlas chart change,
    loses nothing)."""
    y_reached = export_mpf(np.array(list(out.z), dtype=object))
    y_rows = [export_mpf(np.array(row, dtype=object), prec.bits) for row in out.rows_y]
    extra = {"data_bits": bits}
    if engine.max_ratio is not None:
        extra["max_step_over_radius"] = engine.max_ratio
    nsteps = out.steps
    stats = Stats(method="lie series (mpmath)", precision=f"{prec.dps} dps", tol=float_or_mpf(tolm), order=N, steps=nsteps,
                  run_time=out.run_time, min_step=float(out.hmin) if nsteps else float("nan"),
                  max_step=float(out.hmax) if nsteps else float("nan"), error_estimates=tuple(out.estimates),
                  extra=extra)
    y = np.stack(y_rows) if y_rows else np.empty((0, n), dtype=object)
    tarr = time_rows(out.rows_t, prec.bits)
    dense_fn = _Dense(engine.segments, prec.dps, engine.sgn) if dense else None
    user = engine.user
    if user is not None and user.unresolved:
        extra["events_unresolved"] = dict(user.unresolved)
        warnings.warn(
            "event expressions not resolved on some steps (" + ", ".join(f"{name!r}: {k}" for name, k in
                                                             user.unresolved.items()) +
            ") by 65 samples even on 1/4096 of a step: a pole (a sign change through it is no crossing), or a "
            "function faster than the steps; there, crossings closer together than 1/64 of the step may be missed "
            "in pairs (`stats.extra['events_unresolved']`). Give an expression whose zeros are the crossings and "
            "that is smooth near them (the numerator of 1/M2: none)", RuntimeWarning, stacklevel=stacklevel())
    return Solution(tarr, y, stats, out.status, out.message, t_reached=to_fraction(out.t), dense=dense_fn,
                    t_requested=grid, y_reached=y_reached,
                    events=user.records(prec.bits, n) if user is not None else None)


def _precision(dps, guard) -> Precision:
    """The run's precision: ``dps`` digits and ``guard`` guard digits, checked."""
    dps = check_dps(dps)
    if isinstance(guard, bool) or not isinstance(guard, int) or guard < 0:
        raise ValueError(f"`guard` must be a non-negative number of digits; got {guard!r}")
    return Precision.of(dps=dps, guard_digits=guard)


def _tolerance(tol, prec):
    """The step tolerance as an mpf at the working digits: 10**-dps by default, else ``tol`` checked (in (0, 1),
    and within what the working digits resolve)."""
    dps, guard = prec.dps, prec.guard_digits
    with mp.workdps(prec.working_dps):
        if tol is None:
            return mp.mpf(10) ** (-dps)
        tf = to_fraction(tol, "tol")
        if tf <= 0:
            raise ValueError(f"`tol` must be positive; got {float(tf)}")
        if tf >= 1:
            raise ValueError(f"`tol` must be below 1; got {tol!r}")
        tolm = to_mpf(tf, ctx=mp_context())
        if tolm < mp.mpf(10) ** (-(dps + guard)):
            raise ValueError(
                f"`tol` = {mp.nstr(tolm, 3)} is below what {dps} digits (+{guard} guard) can resolve; "
                f"raise `dps` to at least {int(-mp.log10(tolm)) + 1}"
            )
        return tolm


def _series_order(order, tolm, tol, prec):
    """(the order of the steps, the automatic order for ``tolm`` at ``prec``'s working bits): ``order`` checked,
    or the automatic one (at most MAX_ORDER)."""
    N_auto = default_order(tolm)
    if order is None and N_auto > MAX_ORDER:
        source = f"`tol` = {mp.nstr(tolm, 3)}" if tol is not None else f"`dps` = {prec.dps}"
        raise ValueError(
            f"{source} asks for the automatic series order {N_auto} (about -ln(tol) / 2), above the largest "
            f"order {MAX_ORDER}: pass `order` (at most {MAX_ORDER}: shorter steps reach the same accuracy), or "
            f"ask for fewer digits (the automatic order stays within {MAX_ORDER} up to `dps` = "
            f"{_largest_auto_dps()})"
        )
    return (N_auto if order is None else check_order(order)), N_auto


class _LieEngine:
    """One Lie-series step for :func:`lieseries.driver.drive` (module docstring: order, step and error rules)."""

    def __init__(self, stepper, N, N_auto, tolm, wdps, bits, max_steps, sgn, events, user, deadline, dense):
        self.stepper, self.N, self.N_auto, self.tolm, self.wdps = stepper, N, N_auto, tolm, wdps
        self.max_steps, self.steps, self.max_h, self.t_first = max_steps, 0, None, None  # (_ahead)
        # every estimate is at least the data's own relative uncertainty and the round-off of the numbers a step
        # carries (10^-wdps: an order far above the automatic one gave estimates of 1e-60, or 0.0, at 40 working
        # digits); an mpf below a float's range
        rounding = 10.0 ** -wdps if wdps < 300 else mp.mpf(10) ** -wdps
        self.floor = rounding if bits is None else max(
            rounding, math.ldexp(1.0, -bits) if bits < 1000 else mp.ldexp(mp.mpf(1), -bits))
        self.log2_tol = _log2(tolm)
        self.collapse = mp.mpf(10) ** (-wdps + 2)  # a step below |t| * collapse has collapsed
        self.sgn, self.events, self.user, self.deadline = sgn, events, user, deadline
        self.segments = [] if dense else None
        self.max_ratio = None  # the largest step over the estimated radius of convergence
        self.first = True
        self.lpeak = None  # log2 of each component's largest |value| at the steps' starts so far

    def _log2_scales(self, jet, h):
        """log2 of each component's scale for a step of length ``h``: the larger of its size over the step (the
        sum of |c_k,i| h^k) and its largest |value| at the steps' starts so far; ``-inf`` for a component that is
        zero so far and over the step. ``jet.log2_scales`` reads the size at 1 and above (0 below): below 1 the
        size is bounded below by its terms k = 0, 1 (and by every term, for a component zero so far whose first
        two terms vanish). No scale lies below the jets' bound on their roundings over tol (``jet.noise``)."""
        out = []
        col1 = None
        lh = _log2(h)
        for i, (lsize, lpeak) in enumerate(zip(jet.log2_scales(h), self.lpeak)):
            if lsize <= 0:  # a size of at most 1: its largest value so far and its first term
                if col1 is None:
                    col1 = jet.log2_column(1)
                lsize = col1[i] + lh
                if lsize == -math.inf and lpeak == -math.inf:  # zero so far, with no first-order term
                    lsize = max((jet.log2_column(k)[i] + k * lh for k in range(2, self.N + 1)), default=-math.inf)
            out.append(max(lsize, lpeak))
        # no scale that would ask a component for less than what the expansion's own roundings put into it (the
        # jets' bound, where they measure it): such a component's digits are the roundings' (a sphere's momentum
        # along x1 in the intermediate form, zero along a great circle through the x2 axis but for them, at 1e-45
        # against 1.5: its own scale took 1048 steps to the chart's edge at 20 digits, the local chart 21)
        noise = jet.noise
        if noise is not None:
            ltol = self.log2_tol
            out = [x if e is None or x >= e - ltol else e - ltol for x, e in zip(out, noise)]
        return out

    def step(self, tcur, z, tend):
        N, tolm, sgn = self.N, self.tolm, self.sgn
        span = abs(tend - tcur)
        jet = self._expand(z, span)
        rho, lrho = jet.rho, jet.log2_rho  # estimate_radius of the norms, computed once by the stepper
        h, lscales, last, quiet = self._step_size(jet, z, span)
        if h <= abs(tcur) * self.collapse or h == 0:
            raise self._collapsed(h, rho)
        self._ahead(h, span, rho, tcur)
        lh = _log2(h)
        hs = h * sgn
        err = self._estimate(jet, lh, lscales, last, quiet)
        if self.first and self.N_auto is not None and N < self.N_auto:
            nrm = jet.norms
            _warn_slow_order(N, self.N_auto, nrm, tolm * max(mp.mpf(1), nrm[0]), rho, span)
        self.first = False
        znew = jet.horner(hs)
        tnew = tcur + hs if span != h else tend
        coeffs = jet.coefficients
        try:
            stop = self.user.step(jet.evaluate, tcur, hs, sgn) if self.user is not None else None
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            raise Stop("non_finite", f"an event expression cannot be evaluated in the step ({exc}): the state "
                       "leaves its domain there") from None
        if stop is not None:  # a terminal event inside the step: the step ends there
            hs = stop - tcur
            h = abs(hs)
            znew, tnew = horner(coeffs, hs), stop
            lh = _log2(h) if h else -math.inf
        if self.segments is not None:  # (exported here, inside the time budget: as long as the step itself)
            self.segments.append((export_mpf(tcur), export_mpf(tnew), export_mpf(coeffs)))
        ratio = 2.0 ** (lh - lrho) if lrho != math.inf else 0.0
        self.max_ratio = ratio if self.max_ratio is None else max(self.max_ratio, ratio)
        if stop is not None:
            end = ("event", self.user.fired, "")
        else:
            hit = _check_events(self.events, znew)
            end = None if hit is None else (hit[0], hit[1], " (end of the step that crossed it)")
        # output times inside the step: the step's polynomial evaluated in integers, as the step's end (which is
        # that evaluation at hs: a row there is the end reused)
        def row(tk):
            tau = tk - tcur
            return list(znew) if stop is None and tau == hs else jet.evaluate(tau)

        return StepResult(tnew, znew, h=h, row=row, error=err, stop=end)

    @staticmethod
    def _collapsed(h, rho):
        return Stop("step_collapse", f"it fell to {mp.nstr(h, 3)}, and the series' radius of convergence there is "
                    f"~{mp.nstr(rho, 3)}: the solution is singular nearby, or at this precision its series there is "
                    "the roundings' (a run with more digits tells)")

    def _ahead(self, h, span, rho, tcur):
        """A stop when, after :data:`AHEAD_AFTER` steps (or a hundredth of the budget, if more), finishing would
        take more than :data:`AHEAD_MARGIN` times the steps the budget has left, at the larger of this step and the
        run's average step (a run that slows down for a while, as Kepler's through its pericentre, is judged by the
        steps of its whole way): it would spend its budget and stop anyway (the field of tests/test_fixed_jets.py
        at x = 1e60, whose steps stay below 1e-12 of a span of 1, took 100000 steps and two minutes to say so).
        ``step_collapse`` where the steps have shrunk below 1/100 of the longest so far (as heyoka's runs say),
        else ``step_budget``."""
        if self.t_first is None:
            self.t_first = tcur
        self.steps += 1
        self.max_h = h if self.max_h is None or h > self.max_h else self.max_h
        left = self.max_steps - self.steps
        if self.steps < max(AHEAD_AFTER, self.max_steps // 100) or h >= span or left <= 0:
            return
        need = span / max(h, abs(tcur - self.t_first) / (self.steps - 1))
        if need <= AHEAD_MARGIN * left:
            return
        if h < self.max_h / 100:
            raise self._collapsed(h, rho)
        detail = f"{mp.nstr(span, 3)} time units remain, about {mp.nstr(need, 3)} steps at the run's step size so far"
        if self.stepper.extra:  # the field cancels: its roundings at this precision may be what the steps follow
            detail += (f" (the vector field's expression cancels: its jets needed {self.stepper.extra} working bits "
                       "more, and what its roundings leave at this precision may be what the steps follow; a run "
                       "with more digits tells)")
        raise Stop("step_budget", detail, reason="step_budget.hopeless" if need > AHEAD_HOPELESS else
                   "step_budget.ahead")

    def _expand(self, z, span):
        """The jets at ``z`` (:class:`~lieseries.lie.fixed.FixedJets`); a budget or a domain stop as a Stop."""
        from .plan import DeadlineExceeded

        try:
            return self.stepper.expand(z, span, deadline=self.deadline)
        except DeadlineExceeded:  # the budget ran out inside the step's expansion
            raise Stop("time_budget", note=" (inside a step's expansion)") from None
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            raise Stop("non_finite", f"the series coefficients cannot be computed ({exc}): the state has left the "
                       "domain of the equations (or the vector field is singular there)") from None

    def _step_size(self, jet, z, span):
        """(h, log2 scales, the last two orders' columns, the quiet components) of the step rule (module
        docstring). It reads magnitudes only: base-2 logarithms in floating point (a few digits of numbers of any
        size); the step itself is an exact mpf (a 53-bit mantissa, or the exact time left)."""
        N, ltol, lrho = self.N, self.log2_tol, jet.log2_rho
        ltol_abs = ltol + max(0.0, jet.log2_norm(0))  # tol * max(1, ||c_0||)
        lh = math.inf
        for k in (N - 1, N):
            if k >= 1:
                lk = jet.log2_norm(k)
                if lk != -math.inf:
                    lh = min(lh, (ltol_abs - lk) / k)
        lh = min(lh, lrho - 1)  # rho / 2
        h = span if lh == math.inf else min(_pow2(lh), span)  # a polynomial of degree < N - 1: one step to the end
        h = min(h, jet.max_step)  # the jets hold what steps up to max_step need
        # per component: the tolerance is relative to the component's own scale (module docstring), not to the
        # largest component nor absolute below 1 -- a momentum of size 1 beside positions of size 1e6 would keep
        # only tol * 1e6 of its digits, one of size 1e-5 only tol / 1e-5 of them, and its error grows into the
        # positions over the run (when the velocity is the momentum over 1e-5, at once)
        lz = [_log2(v) for v in z]
        self.lpeak = lz if self.lpeak is None else [max(a, b) for a, b in zip(self.lpeak, lz)]
        lscales = self._log2_scales(jet, h)
        last = {k: jet.log2_column(k) for k in (N - 1, N) if k >= 1}
        # a component whose last two orders both vanish (a symmetry of period 4: from rest at q = 0, q'' = 1 - q^2
        # has q in the orders 2, 6, 10, ... only, p in 1, 5, 9, ...) is held by its last nonzero order
        quiet = _last_nonzero(jet, N, last) if lrho != math.inf else {}
        lmin = math.inf
        for k, col in last.items():
            for lc, lsc in zip(col, lscales):
                if lc != -math.inf:
                    lmin = min(lmin, (ltol + lsc - lc) / k)
        for i, (k, lc) in quiet.items():
            lmin = min(lmin, (ltol + lscales[i] - lc) / k)
        if lmin < _log2(h):
            h = _pow2(lmin)  # (a few percent shorter: the sizes over it, which the estimate reads, barely change)
        return h, lscales, last, quiet

    def _estimate(self, jet, lh, lscales, last, quiet):
        """The step's error estimate: the geometric tail (operator.tail_estimate) of the last two orders, per
        component, relative to its scale, the largest; a float where one holds it, an mpf below a float's range
        (above ~300 digits 2.0 ** -1100 is 0.0, an estimate that would claim every digit)."""
        N, lrho = self.N, jet.log2_rho
        lq = lh - lrho if lrho != math.inf else None
        tails = _slow_tails(jet, N, lq, lh, last)
        lerr = -math.inf
        for i, lsc in enumerate(lscales):
            la_last = last[N][i] + N * lh
            la_prev = last[N - 1][i] + (N - 1) * lh if N >= 2 else -math.inf
            if lq is None:
                lnxt = la_last
            else:
                lnxt = max(la_prev + lq, la_last) + lq - math.log2(1 - 2.0 ** lq)
                if tails is not None:
                    lnxt = max(lnxt, _envelope_tail([(k, col[i] + k * lh) for k, col in tails.items()]))
                if i in quiet:
                    k, lc = quiet[i]
                    lnxt = max(lnxt, lc + k * lh + lq * (N + 1 - k) - math.log2(1 - 2.0 ** lq))
            lerr = max(lerr, lnxt - lsc)
        err = math.inf if lerr >= 1024 else 2.0 ** lerr if lerr > -1000 else mp.mpf(2) ** lerr
        return max(err, self.floor)


#: Steps a run takes before it judges whether its step budget can suffice (:meth:`_LieEngine._ahead`), and how many
#: times the steps left finishing at the current step size must exceed for the run to stop early (steps can grow)
AHEAD_AFTER = 64
AHEAD_MARGIN = 10
#: Steps beyond any budget of a Lie run (a step takes 0.1 ms or more: a day's work)
AHEAD_HOPELESS = 10**9

#: The last orders whose terms the error estimate reads when they decay more slowly than h / rho says.
TAIL_WINDOW = 8

_LN2 = math.log(2)


def _slow_tails(jet, N, lq, lh, last):
    """{k: log2 |c_k,i| of every component} for the last TAIL_WINDOW orders when their terms |c_k| h^k decay more
    slowly than ``lq`` = log2(h / rho) says (by more than half a bit an order), else None. The radius is fitted over
    the orders N/2..N; where the early ones grow more slowly than the last (a pendulum's momentum in a chart), it
    came out 3x too long and the geometric tail 100x too small, so those steps' tails are read from their own last
    terms (:func:`_envelope_tail`). One fit of the norms decides: a step whose radius is right pays nothing more."""
    if lq is None:
        return None
    window = range(max(1, N - TAIL_WINDOW + 1), N + 1)
    pts = [(k, (v + k * lh) * _LN2) for k, v in zip(window, jet.log2_norms(window[0], N + 1)) if v != -math.inf]
    if len(pts) < 2:
        return None
    r = radius_from_logs(pts)  # in units of h: the decay of the terms per order is 1 / r
    if r == math.inf or (r > 0 and -math.log2(r) <= lq + 0.5):
        return None
    return {k: (last[k] if k in last else jet.log2_column(k)) for k in window}


def _last_nonzero(jet, N, last):
    """{i: (k, log2 |c_k,i|)}: for each component whose orders in ``last`` (N-1, N) all vanish, its last nonzero
    order k from N/2 on (components zero there too are left out)."""
    quiet = [i for i in range(len(last[N])) if all(col[i] == -math.inf for col in last.values())]
    out = {}
    for k in range(min(last) - 1, max(1, N // 2) - 1, -1):
        if len(out) == len(quiet):
            break
        col = jet.log2_column(k)
        for i in quiet:
            if i not in out and col[i] != -math.inf:
                out[i] = (k, col[i])
    return out


def _envelope_tail(terms):
    """log2 of the tail beyond the last order from one component's last terms [(k, log2 |c_k| h^k)]: their decay
    rate q per order fitted to their upper envelope (:func:`~lieseries.lie.plan.radius_from_logs`: a term that
    nearly vanishes does not count), the envelope's value one order on, over 1 - q; ``inf`` when they do not decay,
    ``-inf`` for fewer than two nonzero terms."""
    nxt = max(k for k, _ in terms) + 1
    pts = [(k, la) for k, la in terms if la != -math.inf]
    if len(pts) < 2:
        return -math.inf
    r = radius_from_logs([(k, la * _LN2) for k, la in pts])
    lqe = -math.log2(r) if r > 0 else math.inf
    if lqe >= 0:
        return math.inf
    return max(la + lqe * (nxt - k) for k, la in pts) - math.log2(1 - 2.0 ** lqe)


def _log2(x):
    """log2 |x| of a nonzero mpf, in floating point (``-inf`` for zero)."""
    _, man, exp, bc = x._mpf_
    if not man:
        return -math.inf
    shift = max(bc - 64, 0)  # the leading 64 bits of a mantissa of any length
    return math.log2(int(man >> shift)) + exp + shift


def _pow2(r):
    """2**r as an mpf with a 53-bit mantissa, for a float r of any size (a step length: the step taken is exactly
    the number returned)."""
    if r == -math.inf:
        return mp.mpf(0)
    n = math.floor(r)
    m, e = math.frexp(2.0 ** (r - n))  # (the double's 53-bit mantissa, exactly)
    return mp_context().make_mpf(from_man_exp(int(m * _TWO53), e - 53 + n))


_TWO53 = float(2**53)


def _largest_auto_dps() -> int:
    """The largest ``dps`` whose automatic order (tol = 10^-dps) is at most MAX_ORDER."""
    dps = int(2 * (MAX_ORDER - 1) / math.log(10))
    while dps > 1 and default_order(mp.mpf(10) ** -dps) > MAX_ORDER:
        dps -= 1
    return dps


def _warn_slow_order(N, N_auto, nrm, tol_abs, rho, span):
    """Warn when a fixed order forces far more steps than the automatic order would (geometric model of the
    coefficients: ||c_k|| ~ A / rho^k gives steps rho (tol / A)^(1/N), capped at rho / 2)."""
    if rho == mp.inf or nrm[0] == 0:
        return
    A = max(nrm[0], mp.mpf(1))

    def step(n):
        return min(rho * (tol_abs / A) ** (mp.mpf(1) / n), rho / 2)

    fixed, auto = step(N), step(N_auto)
    steps_fixed, steps_auto = span / fixed, span / auto
    if steps_fixed > 10 * max(steps_auto, 1) and steps_fixed > 100:
        warnings.warn(
            f"`order` = {N} is far below the automatic order {N_auto} for this tolerance: the run will take about "
            f"{mp.nstr(steps_fixed, 2)} steps instead of about {mp.nstr(steps_auto, 2)}. Leave `order` out unless "
            "you study the order itself.",
            UserWarning,
            stacklevel=stacklevel(),
        )


class _Dense:
    """``sol(t)`` of a Lie-series run: every step's polynomial (picklable)."""

    def __init__(self, segments, dps, sgn):
        self.segments = segments  # (start, end, coefficients), plain mpmath numbers
        self.dps = dps
        self.sgn = sgn

    def __call__(self, t):
        scalar = np.ndim(t) == 0
        ts = [t] if scalar else list(np.asarray(t, dtype=object).ravel())
        rows = []
        sgn, segments = self.sgn, self.segments
        warn_if_coarse(data_bits(ts), dps_to_bits(self.dps), "t")  # the double 0.3: 0.29999999999999998889...
        with mp.workdps(self.dps + GUARD_DIGITS):
            lo = segments[0][0] if segments else None
            hi = segments[-1][1] if segments else None
            for tk in ts:
                tv = to_mpf(tk, "t", ctx=mp_context())
                seg = next((s for s in segments if (tv - s[0]) * sgn >= 0 and (s[1] - tv) * sgn >= 0), None)
                if seg is None:
                    raise ValueError(f"`t` = {tk} is outside the integrated interval [{lo}, {hi}]")
                coeffs = [[mp.make_mpf(c._mpf_) for c in ck] for ck in seg[2]]
                vals = horner(coeffs, tv - mp.make_mpf(seg[0]._mpf_))
                rows.append(export_mpf(np.array(vals, dtype=object), dps_to_bits(self.dps)))
        return rows[0] if scalar else np.stack(rows)


def _event_checks(model, ps):
    """The model's terminal events as (program, initial-sign placeholder, status, message)."""
    if model is None:
        return []
    evs = model.events()
    if not evs:
        return []
    from ..expr import compile_expressions

    prog = compile_expressions(ps.variables, [e[0] for e in evs], len(ps.parameter_values))
    return [(prog, [e[1] for e in evs], [e[2] for e in evs], list(ps.parameter_values), [None])]


def _check_events(events, z):
    """(status, message) when an event expression changed sign over the last step, else None."""
    for prog, statuses, messages, pars, signs in events:
        vals = prog.evaluate(z, pars, mp.dps, mp_context())
        cur = [mp.sign(v) for v in vals]
        if signs[0] is None:
            signs[0] = cur
            continue
        for i, (a, b) in enumerate(zip(signs[0], cur)):
            if a != b:
                return statuses[i], messages[i]
        signs[0] = cur
    return None
