"""Certified digits: a validated Lie-series integrator in Arb ball arithmetic (python-flint).

``validated_integrate(system, y0, t, dps=...)`` returns a :class:`~lieseries.solution.Solution` whose rows are
enclosures: every component at every output time is an Arb ball (``flint.arb``: midpoint and radius) that provably
contains the exact solution of the exact problem (initial data and parameters taken exactly, or as balls when the
user gives uncertainties). The argument is in ``docs/theory.md`` ("Certified enclosures"); in short, the set of
states is carried in Lohner's form m + A r (a centre point, an orthogonal matrix, a box around 0), and each step

1. computes the Taylor polynomial p of order N of the flow from m (the Lie engine's fixed-point jets, as exact
   binary numbers: nothing about them needs proving) and its defect g = f(p) - p' at the step's start (exact for
   a polynomial field);
2. takes the box R around p's range over [0, h], widened by a margin delta, and L = |Df(R)| entrywise;
3. encloses the centre's solution x as p plus a bound of x - p, which solves e' = g + A(s) e with A(s) in Df(R)
   while x stays in R: |x(tau) - p(tau)| <= exp(|tau| L) int_0^tau |g|, the defect bounded from its Taylor
   coefficients at the step's start and a Lagrange term over the whole step -- a few times the true truncation
   error, so the steps are about as long as lie_integrate's; a solution from y in Z = m + A r stays within
   exp(|tau| L) |y - m| of x. When their sum at h is below delta, no solution from Z can leave R during the step
   (a first exit would contradict the bound that holds up to it): every solution exists over [0, h] and stays in R;
4. encloses the Jacobian of the flow over the step (the variational equation over 3 to 24 pieces of the step,
   each in its own narrow box around p) and moves the set by the mean-value theorem and a QR step.

Steps 1-4 but the set's update live in :mod:`lieseries.validated_step` (the proof of one step); this module runs
them: the initial balls, the set m + A r, the step-size control, chart switches, the driver engine.

Nothing else is assumed: when no step down to the smallest is proved, or the widths grow beyond ``max_width``,
the run stops with status ``validation_failed`` and keeps only what it has proved.
``sol.stats.extra["widths"]`` records the widest ball at every output time so the growth can be measured.

python-flint's working precision and series cap (``flint.ctx``) are process-wide: a validated run sets them under
a lock (:func:`~lieseries.ball_series.working_precision`) around each stretch of its ball arithmetic -- its set-up,
each step, each output row -- and restores them after it, so runs from several threads take turns step by step.
"""

from __future__ import annotations

import functools
import math
import time as _time
from fractions import Fraction

import mpmath
import numpy as np

from . import cache
from .models.base import Model
from .poisson import as_poisson_system
from .precision import (
    VALIDATED_GUARD_BITS,
    check_count,
    check_dps,
    check_order,
    check_seconds,
    data_bits,
    float_or_mpf,
    dps_to_bits,
    to_fraction,
    warn_if_coarse,
)
from .ball_series import (SUPPORTED_OPS, Singular, ball_constant, check_ops, evaluate,
                          taylor_coefficients, working_precision)
from .driver import StepResult, Stop, drive
from .formatting import fmt_sci
from .lie.plan import DeadlineExceeded
from .solution import ChartRows, Solution, Stats
from .timegrid import parse_times, time_rows
from .validated_step import (DEFECT_EXTRA, centre_polynomial, defect_coefficients, defect_terms,
                             exact_data, flow_jacobian, jacobian_pieces, jacobian_program, jet_stepper, nth_root,
                             prove_step, step_estimate)

__all__ = ["validated_integrate", "ball_taylor_coefficients", "centre_coefficients", "SUPPORTED_OPS", "midpoints",
           "radii", "certified_digits", "working_precision"]

#: Guard bits above the requested digits (:data:`precision.VALIDATED_GUARD_BITS`).
GUARD_BITS = VALIDATED_GUARD_BITS
#: Each step's remainder bound, relative to the state's size, is at most this times 10^-dps.
REMAINDER_FACTOR = 1e-4

#: The default order is the Jorba-Zou choice, ceil(ln(10) dps / 2) + 1, plus this: a validated step has costs that
#: do not grow with the order (the a priori enclosure, the flow's Jacobian, the set's update), so longer steps of a
#: higher order pay (the rigid body to T = 10: 25 -> 20 steps at 50 digits, 27 -> 17 at 20 digits, 24 -> 22 at 100
#: digits, as many certified digits or more; benchmarks/validated_vs_lie.py).
EXTRA_ORDER = 8

#: A step whose remainder bound exceeds the tolerance is retried at this fraction of the length the bound's
#: power law (h^(N+1)) points to; the next steps' estimates are scaled by what the last one needed, and grow back
#: by STEP_GROWTH a step while their first attempt is proved. Efficiency only: every step is proved.
RETRY_MARGIN = 0.97
STEP_GROWTH = 1.02
#: A step whose a priori enclosure (or Jacobian) is not proved is retried at this fraction of its length.
UNPROVED_SHRINK = 0.5

#: The precision (bits) at which radii and certified digits are read from the balls (python-flint's default).
READING_BITS = 53

#: A run that switches charts this many times stops (it would be cycling).
MAX_SWITCHES = 10_000
_CHART_MAPS = cache.region("validated.chart_maps", 64)


def _chart_context(model, flint):
    """What a run needs of one chart's model, in the current ball precision: (PoissonSystem, program of the field,
    parameter balls, constant balls, terminal events, their constants, Jacobian program, its constants)."""
    ps = as_poisson_system(model)
    prog = ps.program
    pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
    consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
    events = _model_events(model, ps)
    ev_consts = [(slot, ball_constant(c, flint)) for slot, c in events[0].constants] if events else []
    jprog = jacobian_program(ps)
    jconsts = [(slot, ball_constant(c, flint)) for slot, c in jprog.constants]
    return ps, prog, pars, consts, events, ev_consts, jprog, jconsts


def _lohner_set(z, flint):
    """The box z as a Lohner set m + A r: its centre, the identity, the box around 0."""
    m = [flint.arb(zi.mid()) for zi in z]
    n = len(z)
    A = flint.arb_mat([[1 if i == j else 0 for j in range(n)] for i in range(n)])
    return m, A, flint.arb_mat([[zi - mi] for zi, mi in zip(z, m)])


def _switch_chart(model, current, chart, z, flint):
    """The balls z (a state in ``current``'s chart) rewritten in chart ``chart``: the model's chart-change map
    evaluated in ball arithmetic, so the result contains the image of every point of z."""
    ps = as_poisson_system(current)
    key = (ps.key, current.chart, chart)
    prog = _CHART_MAPS.get(key)
    if prog is None:
        from .expr import compile_expressions

        prog = compile_expressions(ps.variables, current.chart_change_expressions(chart), len(ps.parameter_values))
        _CHART_MAPS[key] = prog
    pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
    consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
    out = evaluate(prog, z, pars, consts, flint.arb(1))
    return [v if isinstance(v, flint.arb) else flint.arb(v) for v in out]


def _model_events(system, ps):
    """The model's terminal events (e.g. a sphere chart's edge) as (program, statuses, messages), or None."""
    evs = system.events() if isinstance(system, Model) else []
    if not evs:
        return None
    from .expr import compile_expressions

    prog = compile_expressions(ps.variables, [e[0] for e in evs], len(ps.parameter_values))
    check_ops(prog)
    return prog, [e[1] for e in evs], [e[2] for e in evs]


def _event_in(events, B, pars, consts, one):
    """(status, message) of the first event whose expression may vanish somewhere in the box B, else None: a
    step whose box reaches an event is not taken (the run stops before it, every row proved)."""
    prog, statuses, messages = events
    values = evaluate(prog, B, pars, consts, one)
    for v, status, message in zip(values, statuses, messages):
        if not (v > 0 or v < 0):
            return status, message
    return None


def _check_regular(prog, z, pars, consts, flint):
    """Refuse initial data whose centre is a singular point of the field (a pole, a root at 0): no step from there
    can be proved. A ball around a regular centre that reaches a singularity is left to the run (it ends with
    ``validation_failed`` at t0)."""
    arb = flint.arb
    centre = [arb(v.mid()) for v in z]
    try:
        values = evaluate(prog, centre, pars, consts, arb(1))
        ok = all((v if isinstance(v, arb) else arb(v)).is_finite() for v in values)
    except Singular:
        ok = False
    if not ok:
        raise ValueError(f"`y0` = {[float(v.mid()) for v in centre]} is a singular point of the vector field (it "
                         "cannot be evaluated there: a division by 0, or a root or logarithm at its branch point); "
                         "start from a regular point")


# -- the driver ------------------------------------------------------------------------------------------------------
def _initial_balls(system, y0, n, flint):
    """Balls of the initial state: exact values (rounded outward once), or the user's (value, radius) / arb."""
    arb = flint.arb
    if getattr(y0, "exact", None) is not None:
        entries = list(y0.exact)
    elif isinstance(y0, (list, tuple)):
        entries = list(y0)
    elif np.ndim(y0) == 1:
        entries = list(np.asarray(y0))  # numpy's own scalars: a float32 entry carries its 24 bits
    else:
        raise ValueError(f"`y0` must be a sequence of {n} entries (numbers, (value, radius) pairs or arb balls); "
                         f"got {type(y0).__name__} {y0!r:.60}")
    if len(entries) != n:
        raise ValueError(f"`y0` must have {n} entries; got {len(entries)}")
    # binary data (0.1 as a double) are enclosed at their binary values: say so when the run has more digits
    plain = [v for v in entries if not isinstance(v, (tuple, flint.arb))]
    warn_if_coarse(data_bits(plain), flint.ctx.prec - GUARD_BITS, "y0")
    balls, mids = [], []
    for i, v in enumerate(entries):
        if isinstance(v, arb):
            if not v.is_finite():
                raise ValueError(f"`y0[{i}]` must be a finite ball; got {v}")
            balls.append(+v)
            mids.append(_exact_mid(v))
            continue
        if isinstance(v, tuple):
            if len(v) != 2:
                raise ValueError(f"`y0[{i}]` as an uncertain value must be (value, radius); got {v!r}")
            val, rad = to_fraction(v[0], f"y0[{i}]"), to_fraction(v[1], f"y0[{i}] radius")
            if rad < 0:
                raise ValueError(f"`y0[{i}]` radius must be >= 0; got {float(rad)}")
            ball = arb(flint.fmpq(val.numerator, val.denominator))
            balls.append(ball + arb(0, arb(flint.fmpq(rad.numerator, rad.denominator)).abs_upper()))
            mids.append(val)
            continue
        q = to_fraction(v, f"y0[{i}]")
        balls.append(arb(flint.fmpq(q.numerator, q.denominator)))
        mids.append(q)
    if isinstance(system, Model) and all(m is not None for m in mids):
        system.check_state(mids, "y0")  # the model's physical checks on the centre
    return balls


def ball_taylor_coefficients(system, y0, order: int, dps: int = 30) -> list:
    """The normalised Taylor coefficients c_0..c_order of the flow from ``y0`` as Arb balls that contain the
    exact ones: ``out[i][k]`` for component i (``y0`` entries as in :func:`validated_integrate`)."""
    dps = check_dps(dps)
    order = check_order(order)
    ps = as_poisson_system(system)
    prog = ps.program
    check_ops(prog)
    with working_precision(dps_to_bits(dps) + GUARD_BITS, cap=order + 4) as flint:
        z = _initial_balls(system, y0, ps.dimension, flint)
        pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
        consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
        return taylor_coefficients(prog, z, pars, consts, order, flint)


def centre_coefficients(system, y0, order: int, dps: int = 30, step=None) -> list:
    """The centre polynomial a validated step from ``y0`` takes (from the midpoints of its balls: exact values are
    rounded to the run's precision), as the run computes it: ``out[i][k]``,
    exact binary Arb balls (radius 0), close to the Taylor coefficients c_k of the flow (nothing about them is
    proved: each step bounds the distance of the solution from this polynomial). ``step``: the length of the run's
    previous step (the fixed-point jets then hold c_k to ``dps`` digits of the state relative to
    ``2^(ceil(log2 step) + 1)^-k``, what a step of about that length needs); none: a first step."""
    dps = check_dps(dps)
    order = check_order(order)
    ps = as_poisson_system(system)
    prog = ps.program
    check_ops(prog)
    with working_precision(dps_to_bits(dps) + GUARD_BITS, cap=order + 4) as flint:
        z = [flint.arb(v.mid()) for v in _initial_balls(system, y0, ps.dimension, flint)]
        pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
        consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
        stepper = jet_stepper(ps, order, dps)
        if step is not None:
            stepper.h_last = float(to_fraction(step, "step"))
            if not stepper.h_last > 0:
                raise ValueError(f"`step` must be a positive step length; got {step!r}")
            stepper.s = 0  # not a first expansion: the time scale follows the step
        return centre_polynomial(stepper, prog, z, pars, consts, order, flint, mpmath.mpf(1))[0].unscaled()


def validated_integrate(system, y0, t, *, dps: int = 30, order: int | None = None, t0=0, max_steps: int = 100_000,
                        max_time: float | None = None, max_width=None, atlas: bool | None = None) -> Solution:
    """Enclose the solution of ``dz/dt = X_H(z)`` in Arb balls that provably contain it (module docstring).

    Parameters
    ----------
    system : model or PoissonSystem
        Its vector field may use the operations in :data:`SUPPORTED_OPS`; others are refused by name.
    y0 : sequence of n entries
        Exact values (a model state, ints, strings, Fractions, floats as their binary values), or uncertain
        values as ``(value, radius)`` tuples or ``flint.arb`` balls: the enclosures then contain the solutions
        from every point of the initial box.
    t : number or sequence
        Final time or output times (as for :func:`lieseries.integrate`).
    dps : int
        Digits of the ball arithmetic (32 guard bits above); the enclosures aim at widths near 10^-dps.
    order : int, optional
        Series order (default ceil(ln(10) dps / 2) + 1 + :data:`EXTRA_ORDER`: the Jorba-Zou choice plus 8).
    max_steps, max_time :
        Budgets (statuses ``step_budget``, ``time_budget``); the clock is read between steps and after every order
        of a step's series, so a long step stops within about one order's work of ``max_time``.
    max_width : number, optional
        Stop with ``validation_failed`` when a ball grows wider than this (default 1e-3 x max(1, |z|)).
    atlas : bool, optional
        For a model with charts (:class:`~lieseries.Sphere`; on by default, the model's ``atlas``): switch to the
        chart of the largest coordinate when the current one is ending, mapping the enclosure in ball
        arithmetic; ``sol.charts`` gives each row's chart. With ``atlas=False`` the run stops at the chart's edge
        (``chart_edge``).

    Returns
    -------
    Solution
        ``sol.y``: object array of ``flint.arb`` (one row per output time reached); ``midpoints(sol)``,
        ``radii(sol)``, ``certified_digits(sol)`` read them. ``sol.stats.extra["widths"]``: the widest ball at each
        output time; ``["tail_bounds"]``: the remainder bound added at each step.
    """
    dps = check_dps(dps)
    max_steps = check_count(max_steps, "max_steps")
    max_time = check_seconds(max_time, "max_time")
    if max_width is not None and not to_fraction(max_width, "max_width") > 0:
        raise ValueError(f"`max_width` must be a positive radius (the widest ball the run may carry); got "
                         f"{max_width!r}. Leave it out for the default, 1e-3 x max(1, |z|)")
    N = check_order(order) if order is not None else max(8, math.ceil(math.log(10) * dps / 2) + 1) + EXTRA_ORDER
    ps = as_poisson_system(system)
    check_ops(ps.program)
    atlas = _check_atlas(system, atlas)
    bits = dps_to_bits(dps) + GUARD_BITS
    # the rows: n balls per time (an arb object, its midpoint's limbs and its radius)
    tic = _time.perf_counter()
    grid, direction, t0f = parse_times(t, t0, values_per_time=ps.dimension, bytes_per_value=64 + bits // 8,
                                        max_time=max_time)
    # binary model data (inertia 1.1 as a double) or times (t = 0.1 as a double) in a longer run: the enclosures
    # are proven for those binary values, not for the decimals they round
    for name, b in list(ps.coarse_data().items()) + [("t", data_bits(t)), ("t0", data_bits(t0))]:
        warn_if_coarse(b, dps_to_bits(dps), name)
    start = tic  # max_time bounds the call from the output times' conversion and checks on
    deadline = None if max_time is None else start + max_time

    with _run_precision(dps, N) as flint:
        arb = flint.arb
        z = _initial_balls(system, y0, ps.dimension, flint)
        width_cap = None if max_width is None else arb(flint.fmpq(*to_fraction(max_width, "max_width").as_integer_ratio()))
        _check_start_width(z, width_cap, flint)
        z, current = _start_chart(system, z, flint) if atlas else (z, system)
        # the shortest step tried: 2^-40 of the run's time span (a time, whatever the size of the state)
        engine = _ValidatedEngine(system, current, z, N, dps, flint, width_cap, deadline,
                                  abs(to_fraction(grid[-1]) - to_fraction(t0f)) / 2**40, direction, atlas)
    # the engine holds the run's precision around each step and row: other threads take turns in between
    out = drive(engine, t0f, z, [(g, g) for g in grid], direction=direction, max_steps=max_steps,
                max_time=max_time, start=start, kept="Every row up to here is a proven enclosure.",
                atlas=atlas, max_switches=MAX_SWITCHES, reached="; every row is a proven enclosure")
    with _run_precision(dps, N):
        stats = _run_stats(out, engine, N, dps)
        y, y_reached = _ball_arrays(out.rows_y, out.z, engine.ps.dimension)
    tarr = time_rows(out.rows_t, dps_to_bits(dps))
    if atlas:
        return Solution(tarr, ChartRows(y, out.rows_chart), stats, out.status, out.message, t_reached=out.t,
                        t_requested=grid, y_reached=ChartRows(y_reached, engine.chart),
                        charts=np.array(out.rows_chart, dtype=int), chart_reached=engine.chart)
    return Solution(tarr, y, stats, out.status, out.message, t_reached=out.t, t_requested=grid, y_reached=y_reached)


def _run_precision(dps: int, N: int):
    """The ball precision (bits) and series cap of a run of ``dps`` digits and order ``N``, held (under the lock of
    :func:`~lieseries.ball_series.working_precision`) around each stretch of the run's ball arithmetic."""
    return working_precision(dps_to_bits(dps) + GUARD_BITS, cap=N + DEFECT_EXTRA + 4)


def _check_atlas(system, atlas) -> bool:
    """Whether the run switches charts: the model's own choice by default; refused for a model without charts."""
    if atlas is None:
        atlas = bool(getattr(system, "atlas", False))  # a Sphere says (True unless built with atlas=False)
    if atlas and not hasattr(system, "chart_change_expressions"):
        raise ValueError(f"`atlas` needs a model with an atlas of charts (Sphere); {type(system).__name__} has one "
                         "global chart")
    return atlas


def _check_start_width(z, width_cap, flint):
    """Refuse initial balls already wider than the run's width cap (it would stop at once)."""
    widest0 = max(z, key=lambda v: float(v.rad()))
    cap0 = width_cap if width_cap is not None else flint.arb(max([1.0] + [abs(float(v.mid())) for v in z])) / 1000
    if widest0.rad() > cap0:
        raise ValueError(
            f"`y0` has a ball of radius {float(widest0.rad()):.3g}, already wider than `max_width` = "
            f"{float(cap0):.3g} ({'given' if width_cap is not None else 'the default, 1e-3 x max(1, |z|)'}): "
            "the run would stop at once with validation_failed. Pass a larger `max_width` to follow so wide a "
            "set (its enclosures widen fast and the steps shrink), or give a narrower uncertainty"
        )


def _start_chart(system, z, flint):
    """An atlas run's start: the balls z and the model of the chart of the largest coordinate (z rewritten there
    when that is not the model's own chart)."""
    current = system.for_chart(system.chart, edge=system.ATLAS_SWITCH)
    best = system.best_chart([_exact_mid(v) for v in z])
    if best != system.chart:
        z, current = _switch_chart(system, current, best, z, flint), system.for_chart(best, edge=system.ATLAS_SWITCH)
    return z, current


def _run_stats(out, engine, N, dps) -> Stats:
    """A validated run's statistics: its steps and time, and in ``extra`` the widest ball at each output time, the
    remainder bound of each step and the chart switches."""
    widths = [max(_float_up(v.rad()) for v in row) for row in out.rows_y]
    return Stats(method="validated lie series (arb)", precision=f"{dps} dps", tol=_tolerance(dps), order=N,
                 steps=out.steps, run_time=out.run_time,
                 extra={"widths": widths, "tail_bounds": engine.tails,
                        "max_width": max(widths) if widths else 0.0, "chart_switches": out.switches})


def _ball_arrays(rows, z_end, n):
    """The rows and the state reached as object arrays of balls, filled entry by entry."""
    y = np.empty((len(rows), n), dtype=object)
    for i, row in enumerate(rows):
        for j, v in enumerate(row):
            y[i, j] = v
    y_reached = np.empty(n, dtype=object)
    for j, v in enumerate(z_end):
        y_reached[j] = v
    return y, y_reached


class _ValidatedEngine:
    """One validated step for :func:`lieseries.driver.drive`: the a priori enclosure and remainder bound of the
    step (shortened until proved), the rows inside it, Lohner's QR update of the set m + A r."""

    def __init__(self, system, current, z, N, dps, flint, width_cap, deadline, h_min, direction, atlas):
        self.system, self.N, self.dps, self.flint = system, N, dps, flint
        self.width_cap, self.deadline, self.h_min, self.direction, self.atlas = (
            width_cap, deadline, h_min, direction, atlas)
        self.tails = []
        self.h_scale = 1.0  # the step estimate's correction (efficiency only)
        arb = flint.arb
        self.unit = arb(10) ** -dps
        # per-step remainder bound, relative: far below 10^-dps, because every step's remainder is then carried
        # (and widened by the wrapping effect) to the end of the run (a ball: 10^-dps underflows a float)
        self.rem_tol = arb(REMAINDER_FACTOR) * self.unit
        self._enter(current, z)
        _check_regular(self.prog, z, self.pars, self.consts, flint)

    def _enter(self, current, z):
        """Work in the chart of ``current`` from the balls ``z``."""
        self.current = current
        self.chart = getattr(current, "chart", None)
        (self.ps, self.prog, self.pars, self.consts, self.events, self.ev_consts, self.jprog,
         self.jconsts) = _chart_context(current, self.flint)
        self.stepper = jet_stepper(self.ps, self.N, self.dps)
        self.exact = exact_data(self.ps, self.prog, self.flint)
        # the set of states is m + A r: a centre point, a matrix (the identity to start) and a box around 0
        self.m, self.A, self.r = _lohner_set(z, self.flint)

    def switch_chart(self, t, z):
        """The chart is ending: the enclosure rewritten in the chart of the largest coordinate (in ball
        arithmetic: the box of the map's values over the box), or None when that is the current chart."""
        system = self.system
        best = system.best_chart([_exact_mid(v) for v in z])
        if best == self.current.chart:
            return None
        with _run_precision(self.dps, self.N):
            z = _switch_chart(system, self.current, best, z, self.flint)
            self._enter(system.for_chart(best, edge=system.ATLAS_SWITCH), z)
        return z

    def step(self, tcur, z, t_end):
        """One step at the run's precision (held for the step alone: other threads take turns between steps)."""
        with _run_precision(self.dps, self.N):
            return self._step(tcur, z, t_end)

    def _step(self, tcur, z, t_end):
        flint = self.flint
        arb = flint.arb
        jprog, pars, jconsts = self.jprog, self.pars, self.jconsts
        n = len(z)
        scale = max([1.0] + [abs(float(zi.mid())) for zi in z])
        tol = self.rem_tol * scale
        wide = any(zi.rad() > self.unit * scale for zi in z)  # wider than 10^-dps of the state's size
        pieces = jacobian_pieces(jprog, wide)
        C, jets, g = self._expand(tcur, z, t_end, tol)
        h, hs, tail, reach, L, J, bounds_h = self._prove(z, abs(t_end - tcur), C, jets, g, tol, pieces)
        tnew = tcur + hs
        A, r = self.A, self.r

        def point(tau: Fraction):
            """Enclosure at tcur + tau of the solution from the centre m: its polynomial plus the bound of
            their difference."""
            ta = arb(flint.fmpq(tau.numerator, tau.denominator))
            bounds = bounds_h if tau == hs else tail(ta)  # the step's own end: bounded when it was proved
            out = [p + arb(0, e) for p, e in zip(C.at(ta), bounds)]
            return out, max(float(e) for e in bounds), ta

        def whole(phi, JA):
            """The box of phi + JA r: every solution from the set m + A r (mean-value theorem)."""
            spread = JA * r
            return [phi[i] + spread[i, 0] for i in range(n)]

        def row(tk):
            """The enclosure at the output time tk inside the step (the driver asks after the step: at the run's
            precision again)."""
            with _run_precision(self.dps, self.N):
                phi_k, _, ta = point(tk - tcur)
                Jk = J if tk == tnew else flow_jacobian(jprog, C, reach, L, pars, jconsts, ta, flint, pieces)
                if Jk is None:  # the field's Jacobian cannot be bounded over the shorter span: stop here
                    raise Stop("validation_failed", f"the flow's Jacobian up to the output time {float(tk):.17g} "
                               "cannot be bounded (the field is singular or too steep near the enclosure)")
                return whole(phi_k, Jk * A)

        phi, tail_h, _ = point(hs)
        JA = J * A
        znew = whole(phi, JA)
        self._lohner_update(phi, JA)
        self.tails.append(tail_h)
        return StepResult(tnew, znew, h=h, row=row, stop=self._width_stop(znew, scale))

    def _expand(self, tcur, z, t_end, tol):
        """The step's series: the centre's polynomial C (and its jets, or None) and its defect g in the centre's
        scaled time; the field must be finite on the enclosure z of the state. The defect's bounds below order N
        are taken per order where one bound for all would not lie far below ``tol`` (on a step of the jets' time
        scale)."""
        flint, prog, pars, consts = self.flint, self.prog, self.pars, self.consts
        try:
            evaluate(prog, z, pars, consts, flint.arb(1))  # raises Singular on a singularity of the field
            C, jets = centre_polynomial(self.stepper, prog, self.m, pars, consts, self.N, flint,
                                         mpmath.mpf(float(abs(t_end - tcur))), self.deadline)  # centre
            g = defect_coefficients(prog, C, pars, consts, flint, self.exact,  # in the centre's scaled time
                                    fine=tol * C.down * 2.0**-10)
        except DeadlineExceeded:
            raise Stop("time_budget", note=" (inside a step)") from None
        except Singular as e:
            # the enclosure of the state itself reaches a singularity of the field: nothing beyond is proved
            raise Stop("validation_failed", f"the vector field cannot be evaluated on the enclosure of the state "
                       f"({e}): the solution is at or near a singularity of the field (widest ball "
                       f"{max(float(zi.rad()) for zi in z):.3g})") from None
        return C, jets, g

    def _prove(self, z, left, C, jets, g, tol, pieces):
        """The longest step up to ``left`` that is proved (its a priori enclosure, a remainder bound within ``tol``, the
        flow's Jacobian), from the estimate the defect gives, shortened until proved: (h, h signed, the remainder
        bound as a function of the time, that of every solution from the set, the bounds of |Df| over the step, the
        flow's Jacobian, the bound at h). Learns the next
        estimate's scale; stops the run at an event ahead, or when no step down to ``h_min`` is proved."""
        flint, N, direction = self.flint, self.N, self.direction
        arb = flint.arb
        prog, pars, consts, jprog, jconsts = self.prog, self.pars, self.consts, self.jprog, self.jconsts
        # the estimate reads the defect at the step's start only: scaled by what the last steps learnt
        h_est = step_estimate(g, N, tol * C.down, flint) * 2.0 ** C.s
        h_f = min(h_est * self.h_scale, float(left))
        first, evented, unproved = True, False, False
        terms = defect_terms(g, N, flint)
        # per component, an upper bound of |y - m| over the set (its box z around the centre m)
        with working_precision(64):
            spread = [abs(zi - mi).upper() for zi, mi in zip(z, self.m)]
        proved = None
        event_hit = None
        h_event_start = h_f
        for _attempt in range(60):
            if not (h_f > self.h_min or h_f >= float(left)):
                break
            if self.deadline is not None and _time.perf_counter() > self.deadline:
                raise Stop("time_budget", note=" (inside a step)")
            # 50 bits of h_f, rounded down (relative to its size: a step below 2^-50 is a step too)
            h = left if h_f >= float(left) else _binary_down(h_f, 50)
            if h <= 0:
                break
            hs = h * direction
            hb = arb(flint.fmpq(hs.numerator, hs.denominator))
            got = prove_step(prog, jprog, C, terms, pars, consts, jconsts, hb, spread, flint,
                              majorant=(jets, h, self.ps.parameter_values) if jets is not None else None)
            tail, B, reach, L = got if got is not None else (None, None, None, None)
            hit = (_event_in(self.events, B, pars, self.ev_consts, arb(1)) if self.events and got is not None
                   else None)
            if hit is not None:
                # the step's box may reach the event: shorten the step towards it, and stop when that no
                # longer helps (the event is closer than 1/1000 of the step)
                event_hit = hit
                if float(h) < 1e-3 * h_event_start:
                    break
                h_f = float(h) / 2
                evented = True
                continue
            bounds_h = tail(hb) if got is not None else None
            worst = max(bounds_h, key=float) if got is not None else None
            J = (flow_jacobian(jprog, C, reach, L, pars, jconsts, hb, flint, pieces)
                 if got is not None and worst <= tol else None)
            if J is not None:
                proved = (h, hs, tail, reach, L, J, bounds_h)
                break
            # the remainder scales like h^(N+1): aim just below the tolerance (halve when unproved)
            if worst is None or not worst.is_finite() or worst <= tol:  # no enclosure, or no Jacobian: shorter
                shrink, unproved = UNPROVED_SHRINK, True
            else:
                shrink = min(RETRY_MARGIN * nth_root(tol / worst, N + 1), RETRY_MARGIN)
            h_f = float(h) * shrink
            first = False
        if proved is None and event_hit is not None:
            # the driver switches charts (atlas) or stops here
            raise Stop(event_hit[0], f"{event_hit[1]} within the next step (every row up to here is a proven "
                       "enclosure; `atlas=True` switches charts instead)")
        if proved is None:
            raise Stop("validation_failed", f"no step down to {fmt_sci(self.h_min)} has an a priori enclosure with a "
                       "small enough remainder (the field is singular near the enclosure, or the enclosure is too "
                       f"wide: widest ball {max(float(zi.rad()) for zi in z):.3g})")
        h = proved[0]
        self.stepper.h_last = float(h)  # the next centre's jets hold what a step of about this length needs
        if h != left and not evented and not unproved and 0 < h_est < math.inf:
            # a step cut short by its remainder bound alone: the next estimate is scaled alike
            self.h_scale = min(1.0, self.h_scale * STEP_GROWTH) if first else float(h) / h_est
        return proved

    def _lohner_update(self, phi, JA):
        """Lohner's QR step: the new set is m' + A' r' with m' the centre of phi, A' the orthogonal factor of
        mid(J A) (exact floats) and r' = (A'^-1 J A) r + A'^-1 (phi - m'), A'^-1 enclosed in ball arithmetic."""
        flint, n, r = self.flint, len(phi), self.r
        self.m = [flint.arb(v.mid()) for v in phi]
        Q, _ = np.linalg.qr(np.array([float(x) for x in JA.mid().entries()]).reshape(n, n))
        self.A = flint.arb_mat(Q.tolist())
        spread = flint.arb_mat([[phi[i] - self.m[i]] for i in range(n)])
        with working_precision(64):  # r is far below the state's size: 64 bits of it are plenty (and rigorous)
            Ainv = self.A.inv()
            self.r = (Ainv * JA) * r + Ainv * spread

    def _width_stop(self, znew, scale):
        """The driver's stop when a ball of the new state is not finite or wider than ``max_width``, else None."""
        cap = self.width_cap if self.width_cap is not None else self.flint.arb(scale) / 1000
        widest = max(znew, key=lambda v: float(v.rad()))
        if not all(v.is_finite() for v in znew) or widest.rad() > cap:
            return ("validation_failed", f"the widest ball has radius {float(widest.rad()):.3g}, beyond max_width "
                    f"({float(cap):.3g}): the enclosure grows faster than the steps can follow (the field is singular "
                    "or too steep near the solution, or the set of initial data too wide)", "")
        return None


def midpoints(sol, as_mpf: bool = False) -> np.ndarray:
    """The midpoints of a validated solution's balls (an object array shaped like ``sol.y``): exact Fractions, or
    with ``as_mpf`` mpmath numbers of the same (binary) values, exactly."""
    if as_mpf:
        return np.vectorize(_mid_mpf, otypes=[object])(sol.y)
    return np.vectorize(_exact_mid, otypes=[object])(sol.y)


def _mid_mpf(ball):
    man, exp = (int(v) for v in ball.mid().man_exp())
    return mpmath.make_mpf(mpmath.libmp.from_man_exp(man, exp))


def _exact_mid(ball) -> Fraction:
    """The midpoint of an arb ball (a binary number), exactly."""
    man, exp = (int(v) for v in ball.mid().man_exp())
    return Fraction(man << exp) if exp >= 0 else Fraction(man, 1 << -exp)


def _binary_down(x: float, bits: int) -> Fraction:
    """The positive float x rounded down to ``bits`` significant bits, exactly (0 for x <= 0)."""
    if not x > 0:
        return Fraction(0)
    man, exp = math.frexp(x)
    return Fraction(math.floor(math.ldexp(man, bits))) * Fraction(2) ** (exp - bits)


def _float_up(x) -> float:
    """An upper bound of the nonnegative ball ``x`` as a float (the smallest positive float for a radius too small
    for a float, never 0 for a nonzero ball)."""
    if x.is_zero():
        return 0.0
    return math.nextafter(float(x.upper()), math.inf)


def radii(sol) -> np.ndarray:
    """The radii of a validated solution's balls (float64 upper bounds, shaped like ``sol.y``)."""
    with working_precision(READING_BITS):
        return np.vectorize(lambda v: _float_up(v.rad()), otypes=[float])(sol.y)


def certified_digits(sol) -> np.ndarray:
    """Per output time: -log10 of the widest ball's radius relative to max(1, |z|): the digits every component is
    certified to (computed from the balls, so beyond a float's range too; inf for a row of exact values)."""
    with working_precision(READING_BITS) as flint:
        out = []
        for row in np.atleast_2d(sol.y):
            widest = functools.reduce(lambda a, b: b if b > a else a, [v.rad() for v in row])  # exact values
            if widest.is_zero():
                out.append(math.inf)
                continue
            scale = functools.reduce(lambda a, b: b if b > a else a, [abs(v.mid()) for v in row], flint.arb(1))
            # a float below the ball of the digits (its midpoint, rounded to nearest, claimed a part in 10^16 more)
            out.append(math.nextafter(float((-(flint.arb(widest) / scale).log() / flint.arb(10).log()).lower()),
                                      -math.inf))
        return np.array(out, dtype=float)


def _tolerance(dps: int):
    """10**-dps as the statistics give it: a float, an mpf below a float's range (10.0 ** -400 is 0.0)."""
    return float_or_mpf(mpmath.mpf(10) ** -dps if dps > 300 else 10.0 ** -dps)
