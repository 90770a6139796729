"""The fast path of a plain repeated call of :func:`lieseries.taylor.integrate`.

A repeated call that succeeded before (the same steps again) runs a first chunk of up to 1024 steps in double
(:data:`lieseries.taylor.plan.REPEAT_CHUNK`), so that such a run is one heyoka call; a new call keeps the short
first chunk, so that a collapse or a blow-up is seen early, between chunks. A plain run -- no events of the
user's, no dense output, no ``progress``, no ``min_step``, output times in double -- runs that chunk directly
(``propagate_until``, or ``propagate_grid`` from t0 for output times) and, when it reached the final time with a
sound energy, returns a :class:`~lieseries.solution.Solution` whose rows and statistics are made when first read;
anything else continues on the general path (:func:`lieseries.taylor.general.execute_general`) from where the
chunk ended, with the same steps, states and statuses. A double run first asks a plain Python function of floats
(cheaper than a compiled-function call) whether its energy is sound; only when it is not sure does the compiled
check decide. A call's first run also reads the series at y0 from its first step
(:class:`~lieseries.taylor.chunks.FirstStep`): when that step needs a bound the call is no longer plain, and a
step beyond the bound starts the run again on the general path, its first step bounded.
"""

from __future__ import annotations

import copy
import time as _time

import heyoka as hy
import numpy as np

from .. import cache
from ..energy import energy_function, energy_verdict, quick_check
from ..solution import Solution, Stats
from .call import next_report, succeeded
from .chunks import FirstStep, step_range
from .general import end_cancellation, execute_general
from .plan import time_array

_OUTCOME = hy.taylor_outcome


def plain_setup(call) -> None:
    """Whether a new call is plain (no events of the user's, no dense output, no min_step, no bound on its first
    step -- not known before its first run has read the series at y0, which then makes it not plain when there is
    one; output times only in double), and what its short path (:func:`execute_plain`) needs."""
    plan, prec = call.plan, call.prec
    grid = plan["grid"]
    one_time = len(grid) == 2 and plan["grid_native"][0] == plan["t0_native"]
    call.plain = (not call.dense and not call.user_events and plan["direction"] != 0 and call.min_step is None
                  and call.first_h is None and (one_time or prec.name == "double"))
    if call.plain:  # (may still turn False below)
        # output times: one propagate_grid over [t0, grid...] (heyoka's own grid, rows from each step's Taylor
        # polynomial; _GridRows continues it exactly when the run is longer than the chunk)
        rest = plan["grid_native"][1:] if plan["grid_native"][0] == plan["t0_native"] else plan["grid_native"]
        call.grid = None if one_time else np.array([plan["t0_native"]] + list(rest), dtype=np.float64)
        if call.grid is not None and not np.all(np.diff(call.grid) * plan["direction"] > 0):
            # exact times that round to one double (0.1 and 0.1 + 1e-20, or two times within a double of t0):
            # propagate_grid refuses them; the general path gives each its row
            call.plain = False
        call.t_out = time_array(plan["grid_native"], prec)
        call.t_out.setflags(write=False)
        call.t_requested = tuple(grid)
        call.t0_native, call.t_end_native = plan["t0_native"], plan["grid_native"][-1]
        call.sqrt_tol, call.reached, call.t_exact = plan["sqrt_tol"], plan["reached"], plan["grid_exact"][-1]
        call.budget = min(call.first_chunk, call.max_steps)  # the first chunk's steps
        call.free = cache.free_copies(plan["build"][0])
        call.events = plan["build"][3]
        # a successful plain run's Solution fields that do not depend on the run
        call.head = {"status": "success", "message": call.reached, "t_reached": call.t_exact,
                     "t_requested": call.t_requested}


def execute(call, progress):
    """Run a prepared call: one integration and its checks, into a :class:`Solution`."""
    if call.plain and progress is None:
        return execute_plain(call)
    return execute_general(call, progress, None)


_TIME_LIMIT = _OUTCOME.time_limit
_perf_counter = _time.perf_counter
_MAX_FREE = cache.MAX_FREE
_FLOAT64 = np.dtype(np.float64)


def execute_plain(call):
    """A plain run (no events of the user's, no dense output, no progress, no ``min_step``; output times only in
    double): its first chunk is one heyoka call;
    a run that ends within it and passes the cheap energy check (:func:`lieseries.energy.quick_check`) returns a
    :class:`Solution` whose rows and statistics are made when read. Anything else -- a longer run, a non-finite
    state, a step budget, a doubtful energy -- goes on through the general path from where the chunk ended, so
    both give the same steps, states and statuses. (The hot path of a repeated call: each line here costs.)"""
    report = call.report
    if report is None:
        report = next_report(call)
    free = call.free
    try:
        ta = free.pop()  # as _checkout: a free copy of the template, or a new one
    except IndexError:
        ta = copy.deepcopy(call.plan["build"][0])
    try:
        views = call.views
        if views[0] is not ta:
            # numpy views of the integrator's state and parameters (its own buffers, never reallocated), kept for
            # the integrator this call last ran on: each read of ta.state makes a new view (~1-2 us)
            views = call.views = (ta, ta.state, ta.pars if call.pars_native is not None else None)
        ta.time = call.t0_native
        state = views[1]
        state[:] = call.y0_native
        if views[2] is not None:
            views[2][:] = call.pars_native
        if call.events:  # the model's terminal events (a chart's edge)
            ta.reset_cooldowns()
        grid = call.grid
        tic = _perf_counter()
        if call.first_known:
            # max_steps passed by position (as a keyword: 1.5 us more)
            res = ta.propagate_until(call.t_end_native, call.budget) if grid is None else \
                ta.propagate_grid(grid, call.budget)
        else:  # the call's first run: its first step reads the series at y0 (chunks.FirstStep)
            first = FirstStep(ta.order)
            if grid is None:  # (heyoka answers the callback last, where a plain run's answer has None)
                res = ta.propagate_until(call.t_end_native, call.budget, write_tc=True, callback=first)[:5] + (None,)
            else:
                res = ta.propagate_grid(grid, call.budget, callback=first)
            res = first.settle(call, ta, res, bool(call.events))[0]
            if res is None:  # beyond the bound: the run starts again (on this integrator), its first step bounded
                if len(free) < _MAX_FREE:
                    free.append(ta)
                ta = None
                return execute_general(call, None, None)
        run_time = _perf_counter() - tic
        t_end = ta.time
        if grid is not None:  # as Chunks._propagate answers: the rows last, the first standing for t0
            res = (res[0], res[1], res[2], res[3], None, res[5])
        if res[0] == _TIME_LIMIT and t_end == call.t_end_native:
            y_end = state.copy()
        else:
            return execute_general(call, None, (ta, res, run_time, report))
    finally:
        if ta is not None and len(free) < _MAX_FREE:  # as _release (inline: the plain path is the fast one)
            free.append(ta)
    passed = call.passed
    if passed is None or passed[1] != res[3] or passed[0] != y_end.tobytes():
        # the energy check. It is a function of the end state and the step count alone (the call's constants
        # fixed), so a run that ends on the very bits and step count of a run that passed it passes it: that is
        # the comparison above (bytes: -0.0 is not 0.0, and a NaN never passed)
        check = call.quick
        if check is None:
            check = call.quick = quick_energy(call)
        try:
            sure = check(y_end.tolist(), res[3])
        except Exception:  # noqa: BLE001 - overflow, a domain error: the compiled check decides
            sure = False
        if not sure:
            status, _ = energy_verdict(call.energy, call.sqrt_tol, y_end, res[3], "success", call.reached)
            if status != "success":
                return execute_general(call, None, (None, res, run_time, report, t_end, y_end))
        if call.dtype == _FLOAT64:  # (other formats' bytes may hold padding or pointers)
            call.passed = (y_end.tobytes(), res[3])
        if call.budget < call.repeat_chunk:  # the call's first success (a run that skips the check comes after one)
            succeeded(call)
    return Solution.deferred(call.head, _plain_fields, (call, y_end, res, t_end, report, run_time))


def _not_sure(y, steps) -> bool:
    return False  # no cheap opinion: the compiled check decides


def quick_energy(call):
    """The energy check of a plain call's runs, made on its first run: ``check(y_end as a list, steps)``, True
    when the run surely passes the energy guard (:func:`lieseries.energy.quick_check`); False sends the run to the
    compiled check (:func:`lieseries.energy.energy_verdict`)."""
    ps = call.ps
    if not ps.is_hamiltonian:
        # nothing to check but the field's cancellation at the end (as execute_general's runs)
        def check(y, steps, ps=ps, bits=call.prec.bits, end_check=call.end_check):
            if end_check:
                end_cancellation(ps, y, bits)
            return True
        return check
    if call.energy is None:
        call.energy = energy_function(ps, call.prec, call.y0_native)
    return quick_check(call.energy, call.sqrt_tol) or _not_sure


def _plain_rows(call, y_end, rows):
    """The output rows of a plain run that reached its final time: y0 at t0, heyoka's grid rows (``rows``, the
    first standing for t0) between, the final state at the final time (as :func:`execute_general` takes them)."""
    n = len(y_end)
    if rows is None:
        y = np.empty((2, n), dtype=call.dtype)
        y[0] = call.y0_native
    else:
        m = len(call.t_out)
        y = np.empty((m, n), dtype=call.dtype)
        if call.grid[0] == call.t_out[0]:  # the first output time is t0
            y[:-1] = rows[:m - 1]
            y[0] = call.y0_native
        else:
            y[:-1] = rows[1:m]
    y[-1] = y_end
    return y


def _plain_fields(call, y_end, res, t_end, report, run_time) -> dict:
    """The fields of a plain run's :class:`Solution` (:func:`execute_plain`; ``res`` heyoka's answer), when first
    read."""
    steps, rows = res[3], res[5]
    lo, hi = step_range(steps, res[1], res[2], t_end, call.t0_native)
    stats = Stats(method="taylor (heyoka)", precision=call.prec.name, tol=call.plan["tol_float"],
                  order=call.plan["build"][0].order, build_time=report[0], cached=report[1], run_time=run_time,
                  steps=steps,
                  min_step=lo, max_step=hi)
    # t: the solution's own copy (a read-only array can be made writable again by its owner)
    return {"t": call.t_out.copy(), "y": _plain_rows(call, y_end, rows), "stats": stats, "y_reached": y_end}
