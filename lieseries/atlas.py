"""Runs across an atlas of charts: integrate in one chart, switch when it is ending, continue.

The sphere's intermediate coordinates (x1, x2, x3, pi_a, pi_b) hold only in a chart x_k != 0, and almost every
great circle crosses each equator. An atlas run uses the chart of the largest coordinate; a terminal event (heyoka)
or an end-of-step check (Lie series) fires when |x_k| falls to half of |x|, the point is rewritten exactly in the
chart of the now-largest coordinate (|x_j| >= |x| / sqrt 3) and the run continues from there. Output rows carry
the chart they are written in: ``sol.charts``.

The driver is shared by both integrators: it calls the integrator on each chart segment with ``atlas=False``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .energy import drift_threshold, energy_exact
from .precision import to_fraction
from .solution import ChartRows, Solution, Stats
from .timegrid import parse_times

__all__ = ["run_atlas", "MAX_SWITCHES"]

#: A run that switches charts this many times without finishing stops (it would be cycling).
MAX_SWITCHES = 100_000


def run_atlas(integrator, model, y0, t, *, t0=0, bits: int, dense=False, energy_tol=None, **kwargs) -> Solution:
    """Integrate ``model`` (a chart-aware model such as :class:`lieseries.Sphere`) across its atlas.

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
        Passed to the integrator on every segment.
    """
    if not hasattr(model, "for_chart"):
        raise ValueError(
            f"`atlas` needs a model with an atlas of charts (Sphere); {type(model).__name__} has one global chart"
        )
    if dense:
        raise ValueError("`dense` output is not available with `atlas=True`; pass the output times as `t` instead")
    z0 = model.check_state(y0, "y0")
    grid, direction, t0f = parse_times(t, t0, max_time=kwargs.get("max_time"))
    switch = model.ATLAS_SWITCH
    # start in the best chart for y0
    chart = model.best_chart(z0)
    z = model.change_chart(z0, chart, bits) if chart != model.chart else list(z0)
    current = model.for_chart(chart, edge=switch)

    rows_t, rows_y, rows_c = [], [], []
    tcur = t0f
    stats = None
    switches = 0
    events = None
    sol = None
    first = True
    while True:
        if direction == 0:
            remaining = t
        else:
            remaining = [g for g in grid if (g - tcur) * direction > 0 or (first and g == tcur)]
        if direction != 0 and not remaining:
            status, message = "success", f"Reached t = {float(grid[-1]):.17g}."
            break
        sol = integrator(current, z, t=remaining, t0=tcur, atlas=False, **kwargs)
        first = False
        stats = _merge(stats, sol.stats)
        events = _merge_events(events, sol.events, current.chart)
        rows_t.extend(to_fraction(v) for v in sol.t)
        rows_y.extend(sol.y)
        rows_c.extend([current.chart] * len(sol.t))
        if sol.status != "chart_edge":
            status, message = sol.status, sol.message
            break
        if sol.t_reached == tcur or switches >= MAX_SWITCHES:
            status = "event"
            message = f"The atlas run made no progress at t = {float(tcur):.17g} after {switches} chart switches."
            break
        tcur = sol.t_reached
        chart = model.best_chart(sol.y_reached)
        z = current.change_chart(sol.y_reached, chart, bits)
        current = model.for_chart(chart, edge=switch)
        switches += 1
    if status == "success" and direction != 0 and energy_tol is not None:
        status, message = _energy_guard(model, z0, current, sol.y_reached, bits, energy_tol, stats.steps,
                                        switches, status, message)
    stats = replace(stats, extra={**stats.extra, "chart_switches": switches})
    y = np.stack(rows_y) if rows_y else np.empty((0, model.dimension), dtype=sol.y.dtype)
    tarr = np.array([float(v) for v in rows_t])
    return Solution(tarr, ChartRows(y, rows_c), stats, status, f"{message} ({switches} chart switches)",
                    t_reached=sol.t_reached, t_requested=grid, y_reached=ChartRows(sol.y_reached, current.chart),
                    charts=np.array(rows_c, dtype=int), chart_reached=current.chart, events=events)


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
        f"{float(e0):.10g} to {float(e1):.10g} (relative change {float(rel):.2g}, more than {steps} steps at the "
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
