"""Runs across an atlas of charts: integrate in one chart, switch when it is ending, continue.

The sphere's intermediate coordinates (x1, x2, x3, pi_a, pi_b) hold only in a chart x_k != 0, and almost every
great circle crosses each equator. An atlas run uses the chart of the largest coordinate; a terminal event (heyoka)
or an end-of-step check (Lie series) fires when |x_k| falls to half of |x|, the point is rewritten exactly in the
chart of the now-largest coordinate (|x_j| >= |x| / sqrt 3) and the run continues from there. Output rows carry
the chart they are written in: ``sol.charts``.

Both integrators share it: the driver loop (:mod:`lieseries.driver`) calls the integrator on each chart segment
with ``atlas=False``, and the run's budgets ``max_steps`` and ``max_time`` bound the whole run, not each segment.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import replace

import heyoka as hy
import mpmath
import numpy as np

from .driver import Outcome, StepResult, Stop, drive
from .energy import drift_threshold, energy_exact
from .events import resolve_events
from .precision import to_fraction
from .solution import ChartRows, Solution, Stats
from .timegrid import parse_times

__all__ = ["run_atlas", "check_atlas_events", "MAX_SWITCHES"]

#: A run that switches charts this many times without finishing stops (it would be cycling).
MAX_SWITCHES = 100_000


def run_atlas(integrator, model, y0, t, *, t0=0, bits: int, dense=False, energy_tol=None, **kwargs) -> Solution:
    """Integrate ``model`` (a chart-aware model such as :class:`lieseries.Sphere`) across its atlas: the driver
    loop (:func:`lieseries.driver.drive`) with a whole run of ``integrator`` in one chart as its step.

    Parameters
    ----------
    integrator : callable
        :func:`lieseries.integrate` or :func:`lieseries.lie_integrate`.
    model : Sphere
        ``y0`` is written in ``model.chart``.
    bits : int
        Precision of the run, for the exact chart changes.
    energy_tol : number, optional
        The run's tolerance. A run that reached its final time is checked like a single run (the energy guard of
        :mod:`lieseries.energy`): the Hamiltonian at the end, in the final chart, against its value at ``y0``, in
        the first chart (not against the last switch's: each segment's drift stays small while the run's adds
        up); a change beyond :func:`lieseries.energy.drift_threshold` times the energy scale turns ``success``
        into ``invariant_drift``.
    kwargs :
        Passed to the integrator on every segment, except the budgets ``max_steps`` and ``max_time``: they bound
        the whole run (each segment gets what the ones before it left).
    """
    if not hasattr(model, "for_chart"):
        raise ValueError(
            f"`atlas` needs a model with an atlas of charts (Sphere); {type(model).__name__} has one global chart"
        )
    if dense:
        raise ValueError("`dense` output is not available with `atlas=True`; pass the output times as `t` instead")
    z0 = model.check_state(y0, "y0")
    check_atlas_events(model, kwargs.get("events"))
    max_steps, max_time = kwargs.pop("max_steps", None), kwargs.pop("max_time", None)
    grid, direction, t0f = parse_times(t, t0, max_time=max_time)
    start = _time.perf_counter()
    # start in the best chart for y0
    chart = model.best_chart(z0)
    z = model.change_chart(z0, chart, bits) if chart != model.chart else list(z0)
    engine = _Segments(integrator, model, chart, grid, t if direction == 0 else None, direction, bits, max_steps,
                       max_time, start, kwargs)
    if direction == 0:  # nothing to integrate: one segment gives the row (and says so)
        res = engine.step(t0f, z, t0f)
        out = Outcome(res.stop.status if res.stop is not None else "success", "", res.t, res.z, res.steps,
                      rows_t=[g for g, _ in res.rows], rows_y=[y for _, y in res.rows],
                      rows_chart=[engine.chart] * len(res.rows))
        out.message = (res.stop.message if res.stop is not None else engine.sol.message) + " (0 chart switches)"
    else:
        def guard(out):
            if energy_tol is not None:
                out.status, out.message = _energy_guard(model, z0, engine.current, out.z, bits, energy_tol,
                                                        out.steps, out.switches, out.status, out.message)

        out = drive(engine, t0f, z, [(g, g) for g in grid], direction=direction,
                    max_steps=max_steps if max_steps is not None else math.inf, max_time=max_time, start=start,
                    atlas=True, max_switches=MAX_SWITCHES + 1, guard=guard)
    sol = engine.sol
    stats = replace(engine.stats, extra={**engine.stats.extra, "chart_switches": out.switches})
    y = np.stack(out.rows_y) if out.rows_y else np.empty((0, model.dimension), dtype=sol.y.dtype)
    tarr = np.array([float(v) for v in out.rows_t])
    return Solution(tarr, ChartRows(y, out.rows_chart), stats, out.status, out.message,
                    t_reached=sol.t_reached, t_requested=grid, y_reached=ChartRows(sol.y_reached, engine.chart),
                    charts=np.array(out.rows_chart, dtype=int), chart_reached=engine.chart, events=engine.events)


def check_atlas_events(model, events):
    """Refuse an event of an atlas run that uses a chart's momenta: pi_c = p_c - x_c p_k / x_k is another function
    in each chart (and pi2 no variable of the chart x2), so its crossings would change meaning at a switch (a
    callable is built again from each chart's model). The position's coordinates are the same in every chart."""
    common = set.intersection(*(set(model.for_chart(c).poisson.names) for c in range(3)))
    for i, (name, expr, _, _) in enumerate(resolve_events(events, model, model.poisson)):
        own = sorted(set(hy.get_variables(expr)) - common)
        if own:
            raise ValueError(
                f"`events[{i}]` ({name!r}) uses {own}, momenta of the chart x{model.chart + 1}, which every chart of "
                f"the atlas defines differently (pi_c = p_c - x_c p_k / x_k): across a chart switch its crossings "
                f"would be those of another function. Write the event in the position {sorted(common)}, run one "
                "chart (`atlas=False`), or use SphereDirac, whose momenta are global")
    return events


class _Segments:
    """The step of an atlas run for the driver: a whole run of the integrator in one chart, up to the chart's edge
    (or the end), within what the budgets have left; its rows come evaluated (``emits_rows``)."""

    emits_rows = True

    def __init__(self, integrator, model, chart, grid, t_arg, direction, bits, max_steps, max_time, start, kwargs):
        self.integrator, self.model, self.grid, self.t_arg, self.direction, self.bits = (
            integrator, model, grid, t_arg, direction, bits)
        self.max_steps, self.max_time, self.start, self.kwargs = max_steps, max_time, start, kwargs
        self.current = model.for_chart(chart, edge=model.ATLAS_SWITCH)
        self.chart = chart
        self.first = True
        self.steps = 0
        self.switches = 0
        self.stats = self.events = self.sol = None

    def step(self, t, z, t_end):
        if self.t_arg is not None:
            remaining = self.t_arg
        else:
            remaining = [g for g in self.grid if (g - t) * self.direction > 0 or (self.first and g == t)]
        budget = {}
        if self.max_steps is not None:
            budget["max_steps"] = self.max_steps - self.steps
        if self.max_time is not None:
            budget["max_time"] = max(self.max_time - (_time.perf_counter() - self.start), 1e-6)
        sol = self.integrator(self.current, z, t=remaining, t0=t, atlas=False, **budget, **self.kwargs)
        self.first = False
        self.sol = sol
        self.steps += sol.stats.steps
        self.stats = _merge(self.stats, sol.stats)
        self.events = _merge_events(self.events, sol.events, self.chart)
        times = remaining if isinstance(remaining, list) else [to_fraction(v) for v in sol.t]
        rows = list(zip(times, sol.y))
        stop = None
        if sol.status == "chart_edge" and len(sol.y) == len(times) and self.t_arg is None:
            # the edge at the final time as the segment's numbers hold it (a Lie run's times, 40 digits: -2.1 to
            # 2e-41): every row is given, and the run is done there, as when it succeeds
            stop = Stop("success")
        elif sol.status == "chart_edge":
            if sol.t_reached == t:
                stop = Stop("event", message=f"The atlas run made no progress at t = {float(t):.17g} after "
                            f"{self.switches} chart switches.")
            elif self.switches >= MAX_SWITCHES:  # a run that was advancing, stopped by the guard against cycling
                stop = Stop("event", message=f"The atlas run stopped at t = {float(sol.t_reached):.17g} after its "
                            f"limit of {MAX_SWITCHES} chart switches (a guard against a run cycling between charts); "
                            "it was advancing: go on from sol.t_reached and sol.y_reached, or split the run.")
            else:
                stop = Stop("chart_edge", message=sol.message)
        elif (sol.status == "step_budget" and self.max_steps is not None
              or sol.status == "time_budget" and self.max_time is not None):
            stop = Stop(sol.status)  # the run's budget ran out: the table's message, with the budget as given
        elif sol.status != "success":
            stop = Stop(sol.status, message=sol.message)
        else:  # the run is done (heyoka reaches the final time as rounded in its format: t_reached may differ)
            stop = Stop("success")
        return StepResult(sol.t_reached, sol.y_reached, rows=rows, steps=sol.stats.steps, stop=stop)

    def switch_chart(self, t, z):
        """The state at the chart's edge written exactly in the chart of its largest coordinate."""
        chart = self.model.best_chart(z)
        z = self.current.change_chart(z, chart, self.bits)
        self.current = self.model.for_chart(chart, edge=self.model.ATLAS_SWITCH)
        self.chart = chart
        self.switches += 1
        return z


def _energy_guard(model, z0, last, y_end, bits, tol, steps, switches, status, message):
    """``invariant_drift`` when H at the end (chart of ``last``) differs from H(z0) (the model's chart) by more
    than :func:`~lieseries.energy.drift_threshold` times the energy scale."""
    if not model.poisson.is_hamiltonian:
        return status, message
    e0, scale = energy_exact(model.poisson, z0, bits)
    e1, _ = energy_exact(last.poisson, y_end, bits)
    if not (e0 == e0 and e1 == e1):
        return status, message
    if abs(e1 - e0) <= drift_threshold(to_fraction(tol), steps) * max(abs(e0), abs(e1), scale):
        return status, message
    rel = abs(e1 - e0) / max(abs(e0), abs(e1), scale)
    return "invariant_drift", (
        f"{message[:-1]}, but the result is wrong: the energy H, which the equations conserve, went from "
        f"{mpmath.nstr(e0, 10)} to {mpmath.nstr(e1, 10)} (relative change {mpmath.nstr(rel, 2)}, more than {steps} "
        "steps at the "
        f"tolerance allow) over {steps} steps and {switches} chart switches. Each chart's error control is "
        "relative to the state's largest component: on a sphere whose radius is far from 1 (positions ~ radius, "
        "momenta ~ mass |v|) the momenta keep fewer digits than the tolerance asks. Rescale lengths (and time) so "
        "that the radius and the speed are of order one."
    )


def _merge_events(total, part, chart):
    """Crossings of every segment, in order; ``charts`` tells the chart each state is written in."""
    if part is None:
        return total
    part = {k: {"t": v["t"], "y": v["y"], "charts": np.full(len(v["t"]), chart, dtype=int)}
            for k, v in part.items()}
    if total is None:
        return part
    return {k: {f: np.concatenate([total[k][f], part[k][f]]) for f in ("t", "y", "charts")} for k in total}


def _merge(total: Stats | None, part: Stats) -> Stats:
    if total is None:
        return replace(part, extra=dict(part.extra))
    extra = dict(total.extra)
    for k, v in part.extra.items():
        if isinstance(v, (int, float)) and isinstance(extra.get(k), (int, float)):
            extra[k] = max(extra[k], v)
        else:
            extra.setdefault(k, v)
    return replace(
        total, steps=total.steps + part.steps, order=max(total.order, part.order),
        build_time=total.build_time + part.build_time, run_time=total.run_time + part.run_time,
        cached=total.cached and part.cached, min_step=float(np.nanmin([total.min_step, part.min_step])),
        max_step=float(np.nanmax([total.max_step, part.max_step])),
        error_estimates=total.error_estimates + part.error_estimates, extra=extra,
    )
