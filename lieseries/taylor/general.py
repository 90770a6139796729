"""The general path of :func:`lieseries.taylor.integrate`: a prepared call run on the driver loop
(:func:`lieseries.driver.drive`), a chunk of heyoka steps per driver step (:class:`~lieseries.taylor.chunks.Chunks`),
with its events, the energy guard and the :class:`~lieseries.solution.Solution` it returns.

Compiled integrators are cached once per key and handed out one per concurrent run (a copy is made only when two
runs of the same key overlap), so ``integrate`` may be called from many threads at once. A run's result does not
depend on the integrator that served it nor on where its chunks end (they are sized by wall time): each run sets
the time, state and parameters, and chunks continue heyoka's double-length time exactly (``propagate_until``; the
rows at output times come from each step's Taylor polynomial, each time from the step propagate_grid takes it in:
a plain run's first chunk may be one propagate_grid from t0), so a call gives the same bits serially and from
threads.
"""

from __future__ import annotations

import time as _time

import numpy as np

from .. import cache
from ..driver import KEPT_ROWS, drive, run_message
from ..energy import energy_function, energy_verdict
from ..heyoka_build import CrossingGuard, event_function
from ..precision import to_fraction
from ..solution import Solution, Stats
from .call import next_report, succeeded
from .chunks import Chunks
from .dense import DenseOutput
from .plan import time_array, warn_cancelling_field

#: An integrator of the same key as ``template`` that no other run is using, and the list to return it to (the
#: shared pool, :func:`lieseries.cache.checkout`). The template itself (what :func:`build_integrator` returns) is
#: never run, so a caller holding it cannot disturb a run; a copy is made only when more runs of one key overlap
#: than there are free copies.
_checkout = cache.checkout
_release = cache.release


def execute_general(call, progress, started):
    """Run a prepared call in full generality on the driver loop (:func:`lieseries.driver.drive`), a chunk of steps
    per driver step (:class:`Chunks`); ``started``: the first chunk :func:`execute_plain` ran."""
    ps, prec, plan, user_events = call.ps, call.prec, call.plan, call.user_events
    direction, grid_native, t0_native, y0_native = plan["direction"], plan["grid_native"], plan["t0_native"], \
        call.y0_native
    template, _, _, event_info = plan["build"]
    build, cached = started[3] if started is not None else (call.report or next_report(call))
    ta = free = None
    sinks = [[] for ev in user_events if not ev[3]]  # no step: no crossing
    if started is not None:
        # a plain run's first chunk ran in execute_plain (which returns the integrator to the pool); when it
        # reached the final time (ta None) only the energy check is left
        ta = started[0]
        first = started[1:3] if ta is not None else (started[1], started[2], started[4], started[5])
        engine = Chunks(ta, call, event_info, first=first)
    elif direction != 0:
        ta, free = _checkout(template)
        try:
            engine, sinks = _start(ta, call, event_info)
        except BaseException:
            _release(ta, free)
            raise
    else:
        engine = Chunks(None, call, event_info)

    def energy(out):
        # a terminal event's crossing at the final time ends the run `event` there (Chunks.end_crossing); else
        # the energy guard of a run that reached its final time (lieseries.energy)
        terminal = [e for e in user_events if e[3]]
        hit = engine.end_crossing([e[2] for e in terminal]) if terminal else None
        if hit is not None:
            engine.end_fired = terminal[hit[0]][0]
            out.status = "event"
            out.message = run_message("event", t=out.t, note=hit[1],
                                      detail=f"the event {engine.end_fired!r} fired")
            return
        if ps.is_hamiltonian:
            if call.energy is None:
                call.energy = energy_function(ps, prec, y0_native)
            out.status, out.message = energy_verdict(call.energy, plan["sqrt_tol"], out.z, out.steps, out.status,
                                                     out.message)
        elif out.status == "success" and call.end_check:
            end_cancellation(ps, out.z, prec.bits)

    converted, call.convert_seconds = call.convert_seconds, 0.0  # (the first run's: max_time counts it)
    try:
        out = drive(engine, t0_native, y0_native, [(g, g) for g in grid_native], direction=direction,
                    max_steps=call.max_steps, max_time=call.max_time, progress=progress, kept=KEPT_ROWS,
                    start=_time.perf_counter() - converted - (started[2] if started is not None else 0.0),
                    guard=energy)
        if out.status == "event" and engine.guard is not None and engine.user_stop():
            engine.guard.at_stop(ta, direction > 0)
    finally:
        if free is not None:
            _release(ta, free)
    if out.status == "success" and call.first_chunk < call.repeat_chunk:
        succeeded(call)
    return _solution(call, engine, out, sinks, build, cached)


def end_cancellation(ps, y_end, bits) -> None:
    """The cancellation check of ``y0`` (:func:`~lieseries.taylor.plan.warn_cancelling_field`) at the end state of
    a run no energy check guards (a non-Hamiltonian ``extra_field``): a field that cancels only once the state has
    grown (w' = (u^2 + 1) - u^2 while u' = u) left w off by 0.7 at t = 20 in double, ``success`` and silent."""
    warn_cancelling_field(ps, [[to_fraction(v) for v in y_end]], bits, where="the end state")


def _solution(call, engine, out, sinks, build, cached):
    """The :class:`~lieseries.solution.Solution` of a run on the driver loop (``out``: the driver's answer;
    ``engine``: the run's :class:`Chunks`; ``sinks``: the crossings of its non-terminal events)."""
    ps, prec, plan, user_events = call.ps, call.prec, call.plan, call.user_events
    grid, direction, grid_native = plan["grid"], plan["direction"], plan["grid_native"]
    template, _, _, event_info = plan["build"]
    stats = Stats(method="taylor (heyoka)", precision=prec.name, tol=plan["tol_float"], order=template.order,
                  build_time=build, cached=cached, run_time=out.run_time, steps=out.steps, min_step=engine.min_h,
                  max_step=engine.max_h,
                  extra={"events_recovered": engine.guard.recovered if engine.guard else 0,
                         "event_touches_dropped": (engine.guard.touches if engine.guard else 0) + engine.touches}
                  if user_events and direction != 0 else None)
    # the exact value of the time reached (the exact grid's when the run got to the end)
    t_reached = plan["grid_exact"][-1] if out.t == grid_native[-1] else to_fraction(out.t)
    # np.array copies the rows (the run's own arrays, y0's read-only cache)
    rows_y = out.rows_y
    y = np.array(rows_y, dtype=call.dtype) if rows_y else np.empty((0, ps.dimension), dtype=call.dtype)
    tarr = time_array(out.rows_t, prec) if prec.is_real else np.array(out.rows_t, dtype=call.dtype)
    dense_fn = DenseOutput(engine.c_outs, prec, plan["t0f"], plan["t0_native"]) if engine.c_outs else None
    return Solution(tarr, y, stats, out.status, out.message, t_reached=t_reached, dense=dense_fn, t_requested=grid,
                    y_reached=np.array(out.z, copy=True) if out.z is call.y0_native else out.z,
                    events=_event_records(user_events, sinks, engine, out, event_info, prec, ps.dimension)
                    if user_events else None)


def _start(ta, call, event_info):
    """The chunk engine of a new run on the integrator ``ta`` (set to the call's start), and the lists its
    non-terminal events' crossings go to."""
    ps, prec, user_events = call.ps, call.prec, call.user_events
    t0_native = call.plan["t0_native"]
    ta.time = t0_native
    ta.state[:] = call.y0_native
    if call.pars_native is not None:
        ta.pars[:] = call.pars_native
    if event_info or user_events:
        ta.reset_cooldowns()
    recorders = [ev.callback for ev in ta.nt_events] if user_events else []
    for rec in recorders:
        rec.sink, rec.t0 = [], t0_native
    # this run's crossings: the lists, taken before the integrator goes back to the pool (another thread may
    # check it out at once and give its recorders new lists)
    sinks = [rec.sink for rec in recorders]
    guard = None
    if recorders:
        nt = [e for e in user_events if not e[3]]
        fn, uses_pars = event_function(ps, prec, [e[1] for e in nt])
        guard = CrossingGuard(fn, uses_pars, [e[2] for e in nt], recorders, prec.bits)
        guard.start(ta)
    engine = Chunks(ta, call, event_info, recorders, guard)
    if user_events:
        # the user's terminal events (after the model's in heyoka's order): a zero at t0 does not stop the run
        n_user = sum(1 for e in user_events if e[3])
        engine.user_terminal = frozenset(range(len(event_info) - n_user, len(event_info)))
        if n_user:
            # a stop where the expression does not change sign (a tangency) is not a crossing: go on
            fn, uses_pars = event_function(ps, prec, [e[1] for e in user_events if e[3]])
            # (and, at arbitrary precision, where heyoka stops at every crossing, one the other way)
            engine.terminal_check = (fn, uses_pars, len(event_info) - n_user, prec.bits,
                                     [e[2] if prec.is_real else 0 for e in user_events if e[3]])
    return engine, sinks


def _event_records(user_events, sinks, engine, out, event_info, prec, n) -> dict:
    """``{name: {"t": times, "y": states}}`` from the recorders' lists (non-terminal events, in order) and the stop
    (terminal)."""
    result = {}
    rec_iter = iter(sinks)
    fired = None
    if out.status == "event" and engine.outcome is not None:
        idx = int(engine.outcome.value)
        idx = -idx - 1 if idx < 0 else idx
        fired = event_info[idx][1] if 0 <= idx < len(event_info) else None
    if out.status == "event" and engine.end_fired is not None:
        fired = f"the event {engine.end_fired!r} fired"
    for name, _expr, _direction, terminal in user_events:
        if terminal:
            hit = fired == f"the event {name!r} fired"
            times, states = ([out.t], [out.z]) if hit else ([], [])
        else:
            sink = next(rec_iter)
            times, states = [t for t, _ in sink], [y for _, y in sink]
        result[name] = {
            "t": time_array(times, prec),
            "y": np.stack(states) if states else np.empty((0, n), dtype=prec.numpy_dtype),
        }
    return result
