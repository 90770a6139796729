"""The scalar paths: members one by one on the scalar integrator (long double, quad) over threads, each thread on
its own pooled copy of the cached integrator; and single runs (any precision, events, members handed over by the
batch), one after another or over threads."""

from __future__ import annotations

import math
import threading
import time as _time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .. import cache
from ..driver import Stop, StepResult, drive, run_message
from ..heyoka_build import first_step_bound, sparse_first_step
from ..precision import to_fraction
from .batch import CHUNK_STEPS, over_threads
from .result import STEP_LIMIT, outcome_kind

__all__ = ["run_scalar", "run_singles"]


def run_scalar(ta0, event_info, Ynat, pars, ps, prec, tgrid, t0n, direction, cap, n_threads, res, progress):
    """Every member with the scalar integrator ``ta0`` (a private copy per thread) on the driver loop
    (:func:`lieseries.driver.drive`, :class:`_Member`); return the members to hand over.

    The same decisions as a batch lane: finished or stopped by a terminal event is recorded; non-finite, or more
    than ``cap`` steps ahead at the current step size (checked between chunks of steps), goes to a single run; so
    does a member whose first step heyoka's step rule could not size (the series at y0 has its last two orders
    vanish or far below the lower ones: :func:`lieseries.heyoka_build.sparse_first_step`; from q = 1e-6,
    q'' = 1 - 3 q^2 in quad one step was 8e-32 off, success): the single run bounds it.
    """
    k, n = Ynat.shape
    npar = len(ps.parameter_values)
    par_native = None
    if npar:
        par_native = [prec.array(ps.parameter_values if pars is None else pars[i]) for i in range(k)] \
            if pars is not None else [prec.array(ps.parameter_values)] * k
    simple = len(tgrid) == 2 and tgrid[0] == t0n
    t0_nat, zero = prec.time(t0n), prec.time(0)
    lead = int(tgrid[0] != t0n)  # propagate_grid starts at t0
    grid = None if simple else prec.array([t0n] * lead + list(tgrid))
    # the output times as heyoka's clock has them (tgrid holds their exact values), each with its row's index
    pending = [(prec.time(tj), j) for j, tj in enumerate(tgrid)]
    reached = run_message("success", t=tgrid[-1])
    counter = iter(range(k))
    lock = threading.Lock()
    handed = []
    done = [0]

    def one(ta, i):
        ta.time = t0_nat
        ta.state[:] = Ynat[i]
        if npar:
            ta.pars[:] = par_native[i]
        if event_info:
            ta.reset_cooldowns()
        member = _Member(ta, pending[-1][0], grid, event_info, cap)
        try:
            out = drive(member, t0_nat, Ynat[i], pending, direction=direction, max_steps=math.inf,
                        reached_message=reached)
        except _HandOver:
            return False
        if grid is not None:
            # propagate_grid's steps cannot be split without moving its rows, and a step callback costs more than
            # a step in long double: the series at y0 from a zero-length step that writes it (the first chunk
            # towards a final time reads it from its own first step: _Member._until)
            ta.time = t0_nat
            ta.state[:] = Ynat[i]
            if sparse_first_step(ta, zero) is not None:
                return False
        for j, y in zip(out.rows_t, out.rows_y):
            res.y[i, j] = y
        res.rows[i] = len(out.rows_t)
        res.finish(i, out.status, out.message, to_fraction(out.t), out.z, out.steps)
        return True

    def work(_):
        ta, free = cache.checkout(ta0)
        try:
            while True:
                with lock:
                    i = next(counter, None)
                if i is None:
                    return
                ok = one(ta, i)
                with lock:
                    if ok:
                        done[0] += 1
                    else:
                        handed.append(i)
                    if progress is not None and ok:
                        progress(done[0], k)
        finally:
            cache.release(ta, free)

    over_threads(work, n_threads)
    return sorted(handed)


class _HandOver(Exception):
    """The member goes to a single run, which decides it (non-finite, or too many steps ahead)."""


class _Member:
    """One member on the scalar integrator as the driver's engine: a chunk of steps per step (growing 4x from
    :data:`~lieseries.ensemble.batch.CHUNK_STEPS`) towards the final time, or one ``propagate_grid`` over the
    output times (the rows in their order: the first one the driver asks for is the grid's second). What the batch
    would hand to a single run raises :class:`_HandOver`."""

    free_first_step = True

    def __init__(self, ta, t_end, grid, event_info, cap):
        self.ta, self.t_end, self.grid, self.event_info, self.cap = ta, t_end, grid, event_info, cap
        self.chunk = CHUNK_STEPS
        self.steps = 0
        self.next_row = 1  # propagate_grid's row 0 is t0 (the driver gives the row at t0 itself)
        self.first = True  # the first chunk (towards the final time) is still to run

    def step(self, t, z, t_end):
        ta, cap = self.ta, self.cap
        rows = None
        if self.grid is None:
            outcome, nsteps = self._until(min(cap - self.steps, self.chunk))
        else:
            r = ta.propagate_grid(self.grid, max_steps=cap)
            outcome, nsteps, rows = r[0], int(r[3]), r[-1]
        self.steps += nsteps
        kind = outcome_kind(outcome, len(self.event_info))
        if kind == "non_finite" or (kind == "interrupted" and self.grid is not None):
            raise _HandOver
        if kind == "interrupted":
            h = abs(float(ta.last_h))
            left = abs(float(self.t_end) - float(ta.time))
            if (not str(outcome).endswith("step_limit") or self.steps >= cap or not h > 0
                    or self.steps + left / h > cap):
                raise _HandOver
            self.chunk = min(4 * self.chunk, 1 << 20)
        # a member that heyoka says finished ends at the final time: its double-length time can end beside it (from
        # t0 = 2.3 back to 0.1 in long double, 0.10000000000000000002), where no row is and the grid would run again
        t_r = self.t_end if kind == "done" else ta.time
        y_r = np.array(ta.state, copy=True)
        stop = None
        if isinstance(kind, int):
            status, msg = self.event_info[kind]
            note = f" (last step size {abs(float(ta.last_h)):.3g})"
            stop = Stop(status, message=run_message("event", t=t_r, note=note, detail=msg))

        def row(tk):
            k = self.next_row
            self.next_row += 1
            return y_r if tk == t_r else rows[k]

        return StepResult(t_r, y_r, row=row, stop=stop, steps=nsteps)

    def _until(self, budget):
        """(outcome, steps) of at most ``budget`` steps towards the final time. The first chunk runs in two calls,
        as one call would run it (a call sizes each step from the state alone): its first step writes the series
        at y0 (a member whose first step needs a bound is handed over), then the rest."""
        ta = self.ta
        if not self.first:
            return tuple(ta.propagate_until(self.t_end, max_steps=budget)[i] for i in (0, 3))
        self.first = False
        outcome, _hmin, _hmax, nsteps = ta.propagate_until(self.t_end, max_steps=1, write_tc=True)[:4]
        if first_step_bound(ta.tc, ta.order) is not None:
            raise _HandOver
        if budget > 1 and outcome == STEP_LIMIT:
            outcome, _hmin, _hmax, more = ta.propagate_until(self.t_end, max_steps=budget - 1)[:4]
            nsteps += more
        return outcome, nsteps


def run_singles(single_run, systems, rows, t, opts, workers, progress, k, done0, deadline=None):
    """Single runs, one after another or over ``workers`` threads (a single run is thread-safe: each takes its
    own copy of the cached integrator, and heyoka releases the GIL while it integrates).  With ``deadline`` (a
    ``time.perf_counter()`` reading: the ensemble's ``max_time`` bounds all its members together) each run gets the
    time left when it starts as its ``max_time``, and a member not started before the deadline is not run: its
    entry is None. What a run that compiled its integrator spends outside its integration (the one-off
    compilation of the integrator and of its checks, which ``max_time`` does not bound) moves the deadline on by as
    much.  Returns (solutions, the budget each run was given: None without a deadline)."""
    budgets = [None] * len(rows)
    limit = [deadline]
    moved = threading.Lock()

    def one(j):
        if deadline is None:
            return single_run(systems[j], rows[j], t, **opts)
        start = _time.perf_counter()
        left = limit[0] - start
        if left <= 0:
            return None
        budgets[j] = left
        sol = single_run(systems[j], rows[j], t, **dict(opts, max_time=left))
        besides = _time.perf_counter() - start - float(sol.stats.run_time or 0.0)
        if besides > 0 and not sol.stats.cached:  # (a run of an integrator built earlier pays no one-off cost)
            with moved:
                limit[0] += besides
        return sol

    if workers is None or workers <= 1 or len(rows) <= 1:
        out = []
        for j in range(len(rows)):
            out.append(one(j))
            if progress is not None:
                progress(done0 + j + 1, k)
        return out, budgets
    out = [None] * len(rows)
    lock = threading.Lock()
    done = [0]

    def run(j):
        out[j] = one(j)
        with lock:
            done[0] += 1
            if progress is not None:
                progress(done0 + done[0], k)

    with ThreadPoolExecutor(max_workers=min(workers, len(rows))) as pool:
        list(pool.map(run, range(len(rows))))
    return out, budgets
