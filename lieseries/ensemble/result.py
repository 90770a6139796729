"""An ensemble's outputs as they are filled in (per member: rows, status, message, time and state reached), how a
heyoka outcome reads, and the final :class:`~lieseries.solution.EnsembleSolution`."""

from __future__ import annotations

import heyoka as hy
import numpy as np

from ..precision import Precision
from ..solution import EnsembleSolution

__all__ = ["Monotone", "Result", "nan_array", "no_crossings", "outcome_kind", "TIME_LIMIT", "STEP_LIMIT", "assemble"]

TIME_LIMIT = hy.taylor_outcome.time_limit
STEP_LIMIT = hy.taylor_outcome.step_limit


class Monotone:
    """``progress(done, total)`` -> the user's ``progress(fraction)``, never going back (members handed from the
    batch to single runs are counted once)."""

    def __init__(self, fn):
        self.fn = fn
        self.best = -1.0

    def __call__(self, done, total):
        f = done / total
        if f > self.best:
            self.best = f
            self.fn(f)


class Result:
    """Per-member outputs being filled in (NaN rows where a member did not get to)."""

    def __init__(self, k, m, n, prec: Precision, chart=None):
        self.prec = prec
        # the chart of each state (runs across an atlas), else None
        self.charts = None if chart is None else np.full((k, m), chart, dtype=int)
        self.chart_reached = None if chart is None else np.full(k, chart, dtype=int)
        self.y = nan_array((k, m, n), prec)
        self.y_reached = nan_array((k, n), prec)
        self.status = np.array([""] * k, dtype=object)
        self.message = [""] * k
        self.t_reached = np.empty(k, dtype=object)
        self.steps = np.zeros(k, dtype=np.int64)
        self.rows = np.zeros(k, dtype=np.int64)
        self.events = None  # per member, when the members record events

    def finish(self, i, status, message, t_reached, y_reached, steps):
        self.status[i] = status
        self.message[i] = message
        self.t_reached[i] = t_reached
        self.y_reached[i] = y_reached
        self.steps[i] = steps

    def take(self, i, sol, tgrid):
        m = len(sol.t)
        self.y[i] = nan_array(self.y.shape[1:], self.prec)
        self.y[i, :m] = np.asarray(sol.y)
        self.rows[i] = m
        if self.charts is not None and sol.charts is not None:
            self.chart_reached[i] = sol.chart_reached
            self.charts[i] = sol.chart_reached  # the rows after a stop (NaN) in the chart the member stopped in
            self.charts[i, :m] = sol.charts
        if sol.events is not None:
            if self.events is None:
                self.events = [None] * len(self.status)
            self.events[i] = sol.events
        self.finish(i, sol.status, sol.message, sol.t_reached, sol.y_reached, sol.stats.steps)


def no_crossings(events, n, prec: Precision) -> dict:
    """A member's ``events`` record when it recorded nothing (not run): ``{name: {"t": [], "y": [] x n}}`` in the
    run's format, the names as a single run gives them (``event0``, ``event1``, ... by position)."""
    dtype = hy.real if prec.is_real else prec.numpy_dtype
    return {ev.name if ev.name is not None else f"event{i}": {"t": np.empty(0, dtype=dtype),
                                                              "y": np.empty((0, n), dtype=dtype)}
            for i, ev in enumerate(events)}


def nan_array(shape, prec: Precision):
    if prec.is_real:
        out = np.empty(shape, dtype=hy.real)
        out[...] = hy.real(float("nan"), prec.bits)
        return out
    return np.full(shape, np.nan, dtype=prec.numpy_dtype)


def outcome_kind(outcome, n_events):
    """'done', 'interrupted', 'non_finite', or an event index."""
    name = str(outcome)
    if name.endswith("time_limit"):
        return "done"
    if name.endswith("err_nf_state"):
        return "non_finite"
    if name.endswith(".success") or name.endswith("step_limit") or name.endswith("cb_stop"):
        return "interrupted"
    try:
        idx = int(outcome.value)
    except (AttributeError, TypeError, ValueError):
        return "interrupted"
    if -n_events <= idx < 0:
        return -idx - 1
    if 0 <= idx < n_events:
        return idx
    return "interrupted"


def assemble(plan, res, path, run_time) -> EnsembleSolution:
    """The :class:`~lieseries.solution.EnsembleSolution` of a local run: ``res`` filled by ``path`` (a
    :class:`~lieseries.ensemble.propagate.PathRun`)."""
    stats = dict(method="taylor (heyoka)", precision=plan.prec.name, tol=float(plan.tolf), order=path.order,
                 steps=res.steps, build_time=path.build, run_time=run_time, workers=path.workers,
                 batch_size=plan.B if path.name == "batch" else 1, path=path.name, single_runs=len(path.handed))
    return EnsembleSolution(plan.prec.array(plan.tgrid), res.y, res.status, res.message, res.t_reached, res.y_reached,
                            stats, rows=res.rows, method="taylor (heyoka)", events=res.events, charts=res.charts,
                            chart_reached=res.chart_reached)
