"""heyoka adapter: build (once) and run the adaptive Taylor integrator of a Poisson system, in any precision.

Caching
-------
Compiling a heyoka integrator (LLVM) costs milliseconds to seconds; running a short orbit costs microseconds.
Integrators are therefore cached by (system structure, precision, tolerance, events, options). Model parameters
are heyoka runtime parameters, so two bodies with different inertia share one compiled integrator; only the
parameter values are set per run.

Guards
------
A run never hangs and never returns a silently wrong state. heyoka itself stops on a non-finite state
(status ``non_finite``). A per-step guard stops when the wall-time budget ``max_time`` runs out
(``time_budget``), when ``max_steps`` steps were taken (``step_budget``), and when the step size has collapsed
so far that finishing at the current step size would need more than the remaining step budget
(``step_collapse``: the symptom of a stiff problem for an explicit method, or of a singularity ahead). A run is
called stiff when its steps are tiny (finishing needs more than 1e5 steps with the default budget, or more than
``max_steps`` when given) while the state changes by less than 1e-3 per step: the step is then limited by
stability, not accuracy, and the run stops with ``step_collapse`` and a message that says so.
Terminal events of the model (e.g. the edge of a sphere chart) end the run with their own status.
"""

from __future__ import annotations

import time as _time
from fractions import Fraction

import heyoka as hy
import numpy as np

from .models.base import Model, state_fractions
from .poisson import as_poisson_system
from .precision import Precision, resolve_precision, to_fraction
from .solution import Solution, Stats
from .timegrid import parse_times

__all__ = ["integrate", "build_integrator", "clear_cache", "cache_info"]

_CACHE: dict = {}
_CACHE_MAX = 64
DEFAULT_MAX_STEPS = 50_000_000
#: With the default budget, a stiff run (module docstring) is stopped once it would need more steps than this.
STIFF_STEPS = 100_000


def clear_cache() -> None:
    """Forget every cached integrator."""
    _CACHE.clear()


def cache_info() -> dict:
    """Number of cached integrators."""
    return {"size": len(_CACHE)}


def _tol_value(tol, prec: Precision) -> Fraction:
    if tol is None:
        return Fraction(1, 2 ** (prec.bits - 1))
    f = to_fraction(tol, "tol")
    if f <= 0:
        raise ValueError(f"`tol` must be positive; got {float(f)}. Leave it out to use the precision's epsilon.")
    if f >= 1:
        raise ValueError(f"`tol` must be below 1 (it is a relative and absolute tolerance); got {float(f)}")
    return f


def build_integrator(system, precision="double", tol=None, *, events=True, compact_mode=None, high_accuracy=False):
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
    tolf = _tol_value(tol, prec)
    model = system if isinstance(system, Model) else None
    evs = model.events() if (model is not None and events) else []
    n = ps.dimension
    if compact_mode is None:
        # compact mode keeps compilation fast: LLVM is slow on unrolled long-double, quad and real code
        compact_mode = prec.name != "double" or n > 20
    key = (ps.key, prec.name, tolf, tuple(str(e[0]) for e in evs), bool(compact_mode), bool(high_accuracy))
    hit = _CACHE.get(key)
    if hit is not None:
        return hit[0], 0.0, True, hit[1]
    state = prec.array([0] * n)
    pars = prec.array(ps.parameter_values) if ps.parameter_values else None
    kwargs = dict(tol=prec.to_native(tolf), compact_mode=compact_mode, high_accuracy=high_accuracy)
    if prec.name != "double":
        kwargs["fp_type"] = prec.fp_type
    if prec.is_real:
        kwargs["prec"] = prec.bits
    if evs:
        kwargs["t_events"] = [
            hy.t_event(e[0], fp_type=prec.fp_type if prec.name != "double" else float) for e in evs
        ]
    if pars is not None:
        kwargs["pars"] = pars
    t0 = _time.perf_counter()
    ta = hy.taylor_adaptive(ps.ode_system, state, **kwargs)
    build = _time.perf_counter() - t0
    info = [(e[1], e[2]) for e in evs]
    if len(_CACHE) >= _CACHE_MAX:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = (ta, info)
    return ta, build, False, info


class _Guard:
    """Per-step callback: keeps the last good state, enforces the budgets, detects a collapsing step size.

    heyoka overwrites the state with NaN when a step goes non-finite, so the last accepted state is copied here
    (one ``copyto`` per step, about 15% of a double-precision step of the rigid body). The budget checks run
    every 8 steps.
    """

    def __init__(self, ta, t_end: float, max_steps: int, max_time, min_step, stiff_steps: int, progress=None):
        self.state = ta.state
        self.buf = np.array(ta.state, copy=True)
        self.t_good = ta.time
        self.t_end = t_end
        self.max_steps = max_steps
        self.max_time = max_time
        self.min_step = min_step
        self.stiff_steps = stiff_steps
        self.progress = progress
        self.t_start = float(ta.time)
        self.last_report = 0.0
        self.start = _time.perf_counter()
        self.steps = 0
        self.h_max = 0.0
        self.change = float("nan")
        self.reason = None

    def __call__(self, ta) -> bool:
        self.steps += 1
        if self.steps & 7 and self.steps > 1:
            np.copyto(self.buf, self.state)
            self.t_good = ta.time
            return True
        self.change = _relative_change(self.state, self.buf)
        np.copyto(self.buf, self.state)
        self.t_good = ta.time
        h = abs(float(ta.last_h))
        self.h_max = max(self.h_max, h)
        if self.progress is not None:
            now = _time.perf_counter()
            if now - self.last_report > 0.1:
                self.last_report = now
                span = self.t_end - self.t_start
                self.progress((float(ta.time) - self.t_start) / span if span else 1.0)
        if self.max_time is not None and _time.perf_counter() - self.start > self.max_time:
            self.reason = "time_budget"
            return False
        if self.min_step is not None and h < self.min_step:
            self.reason = "step_collapse"
            return False
        left = abs(self.t_end - float(ta.time))
        if self.steps <= 16 or h == 0:
            return True
        need = left / h
        if need > self.stiff_steps and h < 1e-2 * self.h_max:
            self.reason = "step_collapse"  # shrinking towards a singularity
            return False
        if need > self.stiff_steps and self.change < 1e-3 and h < 1e-2 * left:
            self.reason = "stiff"  # tiny steps over which the state hardly changes: stability-limited
            return False
        if need > (self.max_steps - self.steps):
            # finishing at this step size needs more steps than the budget has left
            self.reason = "step_collapse" if h < 1e-2 * self.h_max else "step_budget"
            return False
        return True


def integrate(
    system,
    y0,
    t,
    *,
    tol=None,
    precision="double",
    t0=0,
    dense: bool = False,
    max_steps: int | None = None,
    max_time: float | None = None,
    min_step: float | None = None,
    compact_mode: bool | None = None,
    high_accuracy: bool = False,
    atlas: bool = False,
    progress=None,
) -> Solution:
    """Integrate ``dz/dt = X_H(z)`` with heyoka's adaptive Taylor method.

    Parameters
    ----------
    system : model (EulerPoisson, Sphere, SphereDirac, ...) or PoissonSystem
    y0 : sequence of n numbers
        Initial state. Taken at its exact value (a float64 entry is its binary value; pass str/Fraction/mpf or an
        array from ``model.initial_state(..., precision=...)`` for exact high-precision data).
    t : float or increasing sequence
        Final time (negative: backward integration) or output times (see :func:`lieseries.timegrid.parse_times`).
    tol : float, optional
        Relative and absolute tolerance; default: the precision's epsilon.
    precision : "double" | "long double" | "quad" | int bits
    t0 : float
        Initial time.
    dense : bool
        Keep heyoka's continuous output so that ``sol(t)`` works anywhere in the interval. Off by default (as in
        scipy): it costs run time (building it took 5x the integration itself for a 48-step rigid-body run) and
        memory (order x n numbers per step).
    max_steps : int, optional
        Step budget (default 5e7). A run whose step size collapses so that it could not finish within the
        budget stops early with status ``step_collapse``; a stiff run (module docstring) stops once it would need
        more than 1e5 steps, or more than ``max_steps`` when you give it.
    max_time : float, optional
        Wall-time budget in seconds (status ``time_budget``).
    min_step : float, optional
        Stop with ``step_collapse`` when a step is smaller than this.
    atlas : bool
        For a model with charts (:class:`~lieseries.Sphere`): switch charts when the current one is ending and
        go on (:mod:`lieseries.atlas`); ``sol.charts`` tells the chart of each output row. Budgets apply to each
        chart segment.
    progress : callable, optional
        Called as ``progress(fraction_done)`` at most ten times a second during the run, for long runs
        (with a :class:`lieseries.progress.ProgressBar` ``bar``: ``progress=lambda f: bar(f, 1)``).

    Returns
    -------
    Solution
        ``sol.t``, ``sol.y`` (one row per output time reached), ``sol.stats``, ``sol.status``, ``sol.message``.
    """
    prec = resolve_precision(precision)
    if atlas:
        from .atlas import run_atlas

        return run_atlas(integrate, system, y0, t, t0=t0, bits=prec.bits, dense=dense, tol=tol,
                         precision=prec, max_steps=max_steps, max_time=max_time, min_step=min_step,
                         compact_mode=compact_mode, high_accuracy=high_accuracy, progress=progress)
    ps = as_poisson_system(system)
    model = system if isinstance(system, Model) else None
    z0 = model.check_state(y0, "y0") if model is not None else state_fractions(y0, ps.dimension, "y0")
    grid, direction, t0f = parse_times(t, t0)
    default_budget = max_steps is None
    if default_budget:
        max_steps = DEFAULT_MAX_STEPS
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"`max_steps` must be a positive integer; got {max_steps!r}")
    if max_time is not None and not (float(max_time) > 0):
        raise ValueError(f"`max_time` must be a positive number of seconds; got {max_time!r}")
    if min_step is not None and not (float(min_step) > 0):
        raise ValueError(f"`min_step` must be positive; got {min_step!r}")

    ta, build, cached, event_info = build_integrator(
        system, prec, tol, compact_mode=compact_mode, high_accuracy=high_accuracy
    )
    tolf = _tol_value(tol, prec)
    ta.time = prec.time(t0f)
    ta.state[:] = prec.array(z0)
    if ps.parameter_values:
        ta.pars[:] = prec.array(ps.parameter_values)
    if event_info:
        ta.reset_cooldowns()

    t_end = grid[-1]
    guard = _Guard(ta, float(t_end), int(max_steps), None if max_time is None else float(max_time),
                   None if min_step is None else float(min_step),
                   stiff_steps=min(int(max_steps), STIFF_STEPS) if default_budget else int(max_steps),
                   progress=progress)
    stats = Stats(method="taylor (heyoka)", precision=prec.name, tol=float(tolf), order=int(ta.order),
                  build_time=build, cached=cached)
    y0_native = prec.array(z0)
    c_out = outcome = out = None
    nsteps, min_h, max_h = 0, float("nan"), float("nan")
    start = _time.perf_counter()
    if direction != 0:
        if dense or grid == [t0f, t_end]:
            res = ta.propagate_until(prec.time(t_end), c_output=dense, callback=guard, max_steps=int(max_steps))
            outcome, min_h, max_h, nsteps, c_out = res[:5]
        else:
            # heyoka's grid propagation starts at the current time; t0 is added in front and dropped after
            lead = grid[0] != t0f
            res = ta.propagate_grid(prec.array([t0f] * lead + grid), callback=guard, max_steps=int(max_steps))
            outcome, min_h, max_h, nsteps, out = res[0], res[1], res[2], res[3], res[-1][int(lead):]
    stats.run_time = _time.perf_counter() - start
    stats.steps = int(guard.steps or nsteps)
    stats.min_step, stats.max_step = float(min_h), float(max_h)

    if direction == 0:
        t_reached, y_reached = to_fraction(prec.time(t0f)), y0_native
    elif str(outcome).endswith("err_nf_state"):  # heyoka has written NaN into the state: use the last good one
        t_reached, y_reached = to_fraction(guard.t_good), np.array(guard.buf, copy=True)
    else:
        t_reached, y_reached = to_fraction(ta.time), np.array(ta.state, copy=True)
    rows_t, rows_y = [], []
    # heyoka's clock runs in the working precision: compare output times as rounded there ("0.1" is not a double)
    t0n = to_fraction(prec.time(t0f))
    for k, tk in enumerate(grid):
        tk = to_fraction(prec.time(tk))
        if (tk - t0n) * direction > (t_reached - t0n) * direction:
            break
        if tk == t0n:
            yk = y0_native.copy()
        elif tk == t_reached:
            yk = y_reached.copy()
        elif out is not None:
            if k >= len(out):
                break
            yk = np.array(out[k], copy=True)
        else:
            yk = np.array(c_out(prec.time(tk)), copy=True)
        rows_t.append(tk)
        rows_y.append(yk)
    status, message = _status(outcome, guard, event_info, t_reached, t_end, ta, max_steps)
    y = np.stack(rows_y) if rows_y else np.empty((0, ps.dimension), dtype=prec.numpy_dtype)
    tarr = prec.array(rows_t) if rows_t else np.empty(0, dtype=prec.numpy_dtype)
    dense_fn = _dense_output(c_out, prec) if c_out is not None else None
    return Solution(tarr, y, stats, status, message, t_reached=t_reached, dense=dense_fn, t_requested=grid,
                    y_reached=y_reached)


def _relative_change(a, b) -> float:
    """max |a - b| / max(1, max |a|) in double (for the stiffness diagnosis)."""
    try:
        fa = np.asarray(a, dtype=np.float64)
        fb = np.asarray(b, dtype=np.float64)
    except (TypeError, ValueError):
        fa = np.array([float(v) for v in a])
        fb = np.array([float(v) for v in b])
    return float(np.max(np.abs(fa - fb)) / max(1.0, float(np.max(np.abs(fa)))))


def _finite(v) -> bool:
    try:
        return bool(np.isfinite(float(v)))
    except (TypeError, ValueError, OverflowError):
        return False


def _status(outcome, guard, event_info, t_reached, t_end, ta, max_steps):
    h = abs(float(ta.last_h)) if _finite(ta.last_h) else float("nan")
    where = f"t = {float(t_reached):.17g} (last step size {h:.3g})"
    left = abs(float(t_end - t_reached))
    need = f"{left:.3g} time units remain, about {left / h:.3g} steps at this step size" if h > 0 else ""
    if guard.reason == "time_budget":
        return "time_budget", f"The wall-time budget ran out at {where}; raise `max_time` or lower the accuracy."
    if guard.reason == "step_collapse":
        return "step_collapse", (
            f"The step size collapsed near {where}, from {guard.h_max:.3g} earlier: {need}, more than the "
            f"{guard.stiff_steps} steps allowed for it (pass `max_steps` to allow more). The problem is stiff or singular there; an explicit Taylor method "
            "cannot cross it efficiently."
        )
    if guard.reason == "stiff":
        return "step_collapse", (
            f"The problem is stiff: near {where} the step size is limited by stability, not accuracy -- the state "
            f"changes by only {guard.change:.1e} (relative) per step. {need}, more than the {guard.stiff_steps} steps "
            "allowed for a stiff run (pass `max_steps` to allow more). An explicit Taylor method cannot integrate this efficiently: reduce the stiffness "
            "(e.g. the damping) or use an implicit method for this part of the motion."
        )
    if guard.reason == "step_budget":
        return "step_budget", (
            f"Stopped early at {where}: {need}, more than the budget max_steps = {max_steps}. Raise `max_steps` "
            "(and consider `dense=False` for long runs)."
        )
    name = str(outcome)
    if name.endswith("time_limit"):
        return "success", f"Reached t = {float(t_end):.17g}."
    if name.endswith("step_limit"):
        return "step_budget", f"The step budget max_steps = {max_steps} ran out at {where}; raise `max_steps`."
    if name.endswith("err_nf_state"):
        return "non_finite", (
            f"The state became non-finite (NaN or infinity) in the step after t = {float(t_reached):.17g}; the "
            "solution blows up or leaves the domain of the equations there. The last finite state is kept."
        )
    # a terminal event: heyoka reports event i as outcome i, or -(i + 1) when it stopped the run
    try:
        idx = int(outcome.value)
    except (AttributeError, TypeError, ValueError):
        idx = len(event_info)
    if -len(event_info) <= idx < 0:
        idx = -idx - 1
    if 0 <= idx < len(event_info):
        status, msg = event_info[idx]
        return status, f"Stopped at {where}: {msg}."
    return "event", f"Stopped at {where} with heyoka outcome {name}."


def _dense_output(c_out, prec: Precision):
    lo, hi = sorted(float(b) for b in c_out.bounds)

    def dense(t):
        scalar = np.ndim(t) == 0
        ts = [t] if scalar else list(np.asarray(t, dtype=object).ravel())
        out = []
        for i, tk in enumerate(ts):
            tv = float(to_fraction(tk, "t"))
            if not (lo - 1e-15 * max(1.0, abs(lo)) <= tv <= hi + 1e-15 * max(1.0, abs(hi))):
                raise ValueError(f"`t` = {tv} is outside the integrated interval [{lo}, {hi}]")
            out.append(np.array(c_out(prec.time(to_fraction(tk, "t"))), copy=True))
        return out[0] if scalar else np.stack(out)

    return dense
