"""The chunk engine of a heyoka run: a chunk of heyoka steps per step of the driver loop (:mod:`lieseries.driver`).

A run never hangs and never returns a silently wrong state, and pays no Python call per step for it: heyoka
integrates in chunks of steps (the first of 64 steps in double; later ones sized so that a chunk takes about 0.1 s;
a short run is a single chunk), and the checks run between chunks. A chunk is one step of the driver loop
(:class:`Chunks`), which owns the budgets, the output rows, the statuses and their messages (heyoka's advice in its
table: how many steps finishing would take):

- ``time_budget``: the wall-time budget ``max_time`` ran out (it bounds the integration, not the compilation of a
  new integrator, which happens once per structure and precision);
- ``step_budget``: ``max_steps`` steps were taken;
- ``step_collapse``: the step size has collapsed so far that finishing would need more than the step budget (a
  singularity ahead: the steps went on shrinking over as many steps again as the run had taken, at least 64; a
  close approach's steps grow back), or the problem is stiff: its steps are tiny (finishing needs more than 1e5 steps
  with the default budget, or more than ``max_steps`` when given) while no component of the state changes by more
  than 1e-2 of its own size (at least 1/100 of the state's max-norm) per step -- the step is then limited by
  stability, not accuracy;
- ``non_finite``: heyoka stopped on a non-finite state (it overwrites the state with NaN); the last chunk is run
  again from its start with a per-step copy of the state, so the last finite state is kept;
- missed crossings: with non-terminal events, the event functions are evaluated at every step's end; a step
  whose signs disagree with the crossings heyoka reported in it, or that starts or ends on a zero, is searched
  again on its Taylor polynomial and the missing crossings are added (:class:`lieseries.heyoka_build.CrossingGuard`);
- terminal events of the model (e.g. the edge of a sphere chart) end the run with their own status; a user's
  terminal event that stops the run again where it went on from (t0, a touch), without a step, ends it
  ``step_collapse`` (heyoka's cooldown is 0 where the expression's rate vanishes too); one whose zero is at
  exactly the final time (heyoka's root finding leaves out a step's very end) ends the run ``event`` there
  (:meth:`Chunks.end_crossing`), as in ``lie_integrate``;
- a first step heyoka's rule cannot size (the last two orders of the series at y0 vanish in every component, or
  give a radius well above the lower orders': :func:`lieseries.heyoka_build.sparse_first_step`) is the first
  chunk, alone, bounded. The series is read from the run's own first step (its Taylor coefficients, the series at
  y0, by a step callback of the first chunk), so it costs no step of its own: a step within the bound is kept
  (the first chunk then goes on when there is no bound), one beyond it is taken back (time, state, cooldowns,
  crossings, rows, output) and taken again bounded. The bound is kept on the call for its repeated runs;
- ``invariant_drift``: after a run that reached its final time, the Hamiltonian (conserved by every Hamiltonian
  system) is evaluated at both ends; a change beyond min(sqrt(tol), 10 tol per step; 1000 below 2^-112) of its energy scale
  (:func:`lieseries.energy.drift_threshold`) means the result is wrong, whatever the error control believed --
  typically a motion much slower or faster than its time span (Taylor coefficients underflow), fixed by
  rescaling time, or components of very different sizes (the tolerance is relative to the largest), fixed by
  rescaling units. A plain repeated run first asks a cheaper check (:mod:`lieseries.taylor.plain`).
"""

from __future__ import annotations

import math
import time as _time
from fractions import Fraction

import heyoka as hy
import numpy as np

from ..driver import Stop, StepResult, format_time, run_message
from ..heyoka_build import Both, first_step_bound
from ..precision import short_decimal, to_fraction
from .dense import DenseOutput
from .plan import CHUNK_SECONDS, STIFF_CHANGE

_OUTCOME = hy.taylor_outcome
#: The outcomes that are not a terminal event (the others are an event's index i, or -i - 1).
_NOT_EVENTS = frozenset(_OUTCOME.__members__.values())


#: The fewest steps a run takes on after its steps seem to collapse before it is stopped ``step_collapse``
#: (:meth:`Chunks._still_shrinking`).
SHRINK_STEPS = 64


def step_range(steps, lo, hi, t_end, t_start):
    """(smallest, largest) step of a chunk of ``steps`` steps from heyoka's answer (as :meth:`Chunks._account`)."""
    if not steps:
        return math.inf, 0.0
    lo, hi = float(lo), float(hi)
    if not lo <= hi:  # heyoka leaves out a step cut short at the final time: the chunk's mean step
        lo = hi = abs(float(t_end) - float(t_start)) / steps
    return lo, hi


def _reached(res, time, t_end):
    """Where a chunk with heyoka's answer ``res`` ended: ``t_end`` when heyoka says it reached it (its double-length
    time can end an ulp beside it: from t0 = 2.3 back to 0.1, at 0.09999999999999998, past the final time, whose row
    then had no chunk), else heyoka's time."""
    return t_end if res[0] == _OUTCOME.time_limit else time


class Chunks:
    """The step of a heyoka run for the driver loop (:func:`lieseries.driver.drive`): a chunk of steps run inside
    heyoka (module docstring), and before it, when the last chunk used up its steps, the checks that need more than
    heyoka's answer: ``min_step``, then one probe step that measures the step size and the change it makes (a
    collapsing or stiff run, a budget that cannot suffice). The integrator holds the time and state; ``t_at`` and
    ``z_at`` are where the last chunk (or probe) ended."""

    free_first_step = True  # a run is at least one chunk: the budgets are read between chunks

    def __init__(self, ta, call, event_info, recorders=(), guard=None, first=None):
        plan = call.plan
        self.ta, self.direction, self.event_info = ta, plan["direction"], event_info
        self.recorders, self.guard, self.dense = recorders, guard, call.dense
        self.max_steps, self.stiff_steps, self.min_step = call.max_steps, call.stiff_steps, call.min_step
        self.chunk = call.first_chunk
        # a bound on the first step (heyoka_build.sparse_first_step): the first chunk is that one step. Not yet
        # known (the call's first run): read from the first step (_read_first), and kept on the call
        self.first_h = call.first_h
        self.call = None if call.first_known else call
        # (heyoka's answer, seconds) of a first chunk already run from t0; with the time and state it reached
        # when the integrator has gone back to the pool
        self.first = first
        grid = plan["grid_native"]
        self.t0, self.t_end = plan["t0_native"], grid[-1]
        self.t_at, self.z_at = self.t0, call.y0_native
        self.steps, self.min_h, self.max_h = 0, math.inf, 0.0
        self.outcome = None
        self.change = self.h_last = math.nan
        self.suspect = None  # (steps, step size) at the first probe that found the steps collapsing (_still_shrinking)
        self.since_max, self.since_min = 0.0, math.inf  # the largest and smallest steps since then
        self.between = False  # the last chunk used up its steps: the checks run before the next one
        self.user_terminal, self.terminal_check, self.touches = frozenset(), None, 0
        self.passed_at = None  # the time of the last user's terminal stop the run went on from (t0 or a touch)
        self.end_fired = None  # the name of a user's terminal event that crossed at the final time (end_crossing)
        self.c_outs = []  # heyoka's continuous outputs, one per chunk (dense)
        self.queue = []  # (time, row) at the output times the steps so far covered, not yet taken by the driver
        self.chunk_start = self.t0
        self.chunk_dtime = None  # heyoka's double-length time (hi, lo) at the last chunk's start
        self.format = call.prec.name
        # the output times after t0 whose rows come from the steps (None: only t0 and the final time); the driver
        # gives the rows at t0 (y0)
        self.pending = None
        if not self.dense and not (len(grid) == 2 and grid[0] == self.t0):
            self.pending = [g for g in grid if g != self.t0]

    def step(self, t, z, t_end):
        before = self.steps
        self.t_at, self.z_at = t, z
        if self.between:
            self.between = False
            stuck = self._stuck()
            if stuck is not None:
                raise stuck
            if self.min_step is not None and self.min_h < self.min_step:
                raise Stop("step_collapse", f"a step of {self.min_h:.3g} was taken, below `min_step` = "
                           f"{self.min_step:.3g}", note=self._note())
            outcome = self._probe(t_end)
            if outcome != _OUTCOME.step_limit:
                return self._result(before, self._end(outcome))
            stop = self._too_slow(t_end)
            if stop is not None:
                return self._result(before, stop)
            if self.chunk <= 1:  # steps slower than a chunk's time: the probe's step is this one's work (max_time)
                return self._result(before, self._end(outcome))
        return self._result(before, self._end(self._chunk(t_end)))

    def _result(self, before, stop):
        t, z = self.t_at, self.z_at
        queue, dense, pending = self.queue, self.dense, self.pending

        def row(tk):
            if queue and queue[0][0] == tk:
                y = queue.pop(0)[1]
                return z if tk == t else y
            if tk == t:
                # heyoka's time is double length: a chunk may end on tk's high part with a negative low part, short
                # of tk for the step rows; the row is the state there, as at the run's end, and tk is taken
                if pending and pending[0] == tk:
                    pending.pop(0)
                return z
            if dense:
                return DenseOutput(self.c_outs, None).at_native(tk)
            raise RuntimeError(f"no row at t = {format_time(tk)} in a heyoka chunk")  # pragma: no cover

        return StepResult(t, z, row=row, stop=stop, steps=self.steps - before)

    def _chunk(self, t_end):
        """Run one chunk of steps (or take the one already run) and return heyoka's outcome."""
        ta = self.ta
        budget = min(self.chunk, self.max_steps - self.steps)
        cap, self.first_h = self.first_h, None
        if cap is not None:
            budget = 1
        marks = [len(r.sink) for r in self.recorders]
        if self.first is not None:
            (res, elapsed, *reached), self.first = self.first, None
            self.chunk_start = self.t0
        else:
            tic = _time.perf_counter()
            if self.call is None:
                res = self._propagate(t_end, budget, None, cap)
            else:  # the first step reads the series at y0, and is taken back when it goes beyond the bound
                res, cap = self._read_first(t_end, budget, marks)
                if cap is not None:
                    budget = 1
                    tic = _time.perf_counter()
                    res = self._propagate(t_end, budget, None, cap)
            elapsed = _time.perf_counter() - tic
            reached = ()
        if res[0] == _OUTCOME.err_nf_state:
            # run the failed chunk again, keeping a copy of every accepted state
            ta.time, ta.state[:] = self.t_at, self.z_at
            for rec, mark in zip(self.recorders, marks):
                del rec.sink[mark:]  # the chunk runs again: its crossings are recorded again
            if self.guard is not None:
                self.guard.start(ta)
            keeper = _Keeper(ta)
            res = self._propagate(t_end, budget, keeper, cap)
            self._account(res, ta.time)
            self.t_at, self.z_at = keeper.t, keeper.state
            return res[0]
        if reached:  # a plain run's first chunk that reached the final time
            self._account(res, reached[0])
            self.t_at, self.z_at = reached
            return res[0]
        self._account(res, ta.time)
        self.t_at, self.z_at = _reached(res, ta.time, t_end), np.array(ta.state, copy=True)
        if res[0] == _OUTCOME.step_limit:  # the next chunk: about CHUNK_SECONDS of work
            per_step = elapsed / max(int(res[3]), 1)
            self.chunk = int(min(4 * self.chunk, max(1, CHUNK_SECONDS / max(per_step, 1e-9)), 1 << 20))
        return res[0]

    def _read_first(self, t_end, budget, marks):
        """The run's first chunk when the bound on its first step is not known (the call's first run): the
        series at y0 is read from the first step (:class:`FirstStep`). Returns heyoka's answer and None, or (None,
        the bound) when the first step went beyond the bound and has been taken back (time, state, cooldowns, the
        crossings recorded and the guard's marks; its rows and output are dropped with the answer, its step not
        counted): the first chunk is then that one step, bounded, as on the call's later runs."""
        ta, call = self.ta, self.call
        first = FirstStep(ta.order)
        res = self._propagate(t_end, budget, first, None, write_tc=True)
        self.call = None
        res, cap = first.settle(call, ta, res, bool(self.event_info))
        if res is None:
            ta.time, ta.state[:] = self.t_at, self.z_at
            if self.event_info or self.recorders:  # (the integrator has events)
                ta.reset_cooldowns()
            for rec, mark in zip(self.recorders, marks):
                del rec.sink[mark:]
            if self.guard is not None:
                self.guard.start(ta)
        return res, cap

    def _probe(self, t_end):
        """Take one step as part of the run; record its size and the relative change it made."""
        ta = self.ta
        before_t, before = self.t_at, self.z_at
        res = self._propagate(t_end, 1, None)
        if res[0] == _OUTCOME.err_nf_state:
            self.steps += int(res[3])
            return res[0]
        self._account(res, ta.time)
        # heyoka's own step size: the difference of the times reads 0 once the step is below the time's ulp
        self.h_last = abs(float(ta.last_h)) if _finite(ta.last_h) else abs(float(ta.time) - float(before_t))
        self.change = _relative_change(ta.state, before)
        self.t_at, self.z_at = _reached(res, ta.time, t_end), np.array(ta.state, copy=True)
        return res[0]

    def _end(self, outcome):
        """How the chunk (or probe) with ``outcome`` ended the step: None to go on, or a :class:`Stop`."""
        self.outcome = outcome
        if outcome == _OUTCOME.step_limit:
            self.between = True
            return None
        if outcome == _OUTCOME.time_limit:
            return None
        if outcome == _OUTCOME.err_nf_state:
            return Stop("non_finite", reason="non_finite.taylor")
        where = self._note()
        idx = int(outcome.value) if outcome not in _NOT_EVENTS else None
        info = self.event_info
        if idx is not None and -len(info) <= idx < 0:
            idx = -idx - 1
        if self.user_terminal and self._at_user_event(outcome) and (self.t_at == self.t0 or self._touch(outcome)):
            if self.passed_at is not None and self.passed_at == self.t_at:
                # stopped again where the run went on from, without a step: heyoka's cooldown is 0 where the
                # expression's rate vanishes too (from rest on the surface), and it would stop there for ever
                name = info[idx][1].replace("the event", "the terminal event").replace(" fired", "")
                return Stop("step_collapse", name, note=where, reason="step_collapse.touch")
            self.passed_at = self.t_at
            return None  # the run starts on the event's surface, or touches it: go on (heyoka's cooldown)
        # a terminal event: heyoka reports event i as outcome i, or -(i + 1) when it stopped the run
        if idx is not None and 0 <= idx < len(info):
            status, msg = info[idx]
            return Stop(status, message=run_message("event", t=self.t_at, note=where, detail=msg))
        return Stop("event", message=run_message("event", t=self.t_at, note=where,
                                                 detail=f"heyoka stopped with outcome {outcome}"))

    def _too_slow(self, t_end):
        """After a probe: a Stop when finishing at this step size is out of reach (module docstring)."""
        h = self.h_last
        h_first = self.max_h  # the largest step of the run so far
        left = abs(float(t_end) - float(self.t_at))
        need = left / h if h > 0 else math.inf
        shrunk = h < 1e-2 * h_first
        if need > self.stiff_steps and shrunk:
            # shrinking towards a singularity, once the steps went on shrinking (a close approach: they grow back)
            return self._collapse("step_collapse.taylor") if self._still_shrinking(h) else None
        if need > self.stiff_steps and self.change < STIFF_CHANGE and h < 1e-2 * left:
            return self._collapse("step_collapse.stiff")  # tiny steps over which no component changes
        if need > self.max_steps - self.steps:
            if not shrunk:
                return self.explain("step_budget")
            return self._collapse("step_collapse.taylor") if self._still_shrinking(h) else None
        self.suspect = None
        return None

    def _still_shrinking(self, h) -> bool:
        """Whether a step below 1/100 of the run's largest, too small to finish within the budget, is a collapse:
        the steps that followed the first such probe (as many as the run had taken before it, at least
        :data:`SHRINK_STEPS`) shrank it further, none of them growing back above 4 times it in between. A comet at
        its pericentre (a Kepler orbit of eccentricity 0.9992) shrinks the steps 10^4-fold for a moment and they
        grow back: stopped at its first such probe, the run was told it was singular or stiff (and a probe that
        read the step sizes at chunks' ends alone took the next pericentre for the same approach)."""
        if self.suspect is None or not self._collapsing(h):
            self.suspect = (self.steps, h)  # (the first such probe, or the steps grew back: wait again from here)
            self.since_max = self.since_min = h
            return False
        return self.steps - self.suspect[0] >= max(self.suspect[0], SHRINK_STEPS)

    def _stuck(self):
        """A Stop when the last chunk's steps left heyoka's time where it was (t + h rounds to t: 2 or 3 bits at
        t ~ 1 stepped on for ever, the default budget being 5e7 steps), else None."""
        if self.chunk_dtime is None or self.ta is None or tuple(self.ta.dtime) != self.chunk_dtime:
            return None
        return Stop("step_collapse", f"the time does not advance: a whole chunk of steps left it there, because "
                    f"t + h rounds to t in {self.format} numbers; use more bits", note=self._note())

    def explain(self, status, t=None):
        """A budget stop at the last chunk's end, with the steps finishing would take (:data:`MESSAGES`)."""
        stuck = self._stuck() if status == "step_budget" else None
        if stuck is not None:
            return stuck  # raising the budget would not help
        if status != "step_budget":
            return Stop(status, note=self._note())
        if self._collapsing():  # (the budget ran out while the steps went on shrinking: more would not help)
            return self._collapse("step_collapse.taylor")
        need, hopeless = self._need()
        return Stop(status, need, note=self._note(), reason="step_budget.hopeless" if hopeless else "step_budget.ahead")

    def _collapsing(self, h=None) -> bool:
        """Whether the steps have gone on shrinking since a probe found them collapsing (:meth:`_still_shrinking`):
        the last step ``h`` (default heyoka's) at most the one then and at most 4 times the smallest since (a
        pericentre passed inside a chunk: the smallest step 1.3e-7, the next probe's 6.6e-4, below the 7.4e-4
        of the probe before it), none growing back above 4 times it in between."""
        if h is None:
            if self.ta is None or not _finite(self.ta.last_h):
                return False
            h = abs(float(self.ta.last_h))
        if self.suspect is None:
            return False
        h0 = self.suspect[1]
        return h <= h0 and h <= 4 * self.since_min and self.since_max <= 4 * h0

    def _collapse(self, reason):
        need, _ = self._need()
        return Stop("step_collapse", need, note=self._note(), reason=reason,
                    fields={"h_first": self.max_h, "allowed": self.stiff_steps, "change": self.change})

    def _note(self) -> str:
        last = self.ta.last_h if self.ta is not None else math.nan
        return f" (last step size {abs(float(last)) if _finite(last) else math.nan:.3g})"

    def _need(self):
        """The time left and the steps it takes at the last step size (exactly: the time left may be beyond the
        double range, t = 1e400 in quad), and whether that is beyond any step budget."""
        left = abs(to_fraction(self.t_end) - to_fraction(self.t_at))
        last = self.ta.last_h if self.ta is not None else math.nan  # (the step the note names, not an older probe's)
        hh = abs(float(last)) if _finite(last) and float(last) else self.h_last
        if not 0 < hh < math.inf:
            return f"{short_decimal(left)} time units remain", False
        steps = left / Fraction(hh)
        return (f"{short_decimal(left)} time units remain, about {short_decimal(steps)} steps at this step size",
                steps > 10**15)

    def user_stop(self) -> bool:
        """The run stopped on a user's terminal event (at a root inside a step: not :meth:`end_crossing`)."""
        return self.outcome is not None and self._at_user_event(self.outcome)

    def _at_user_event(self, outcome) -> bool:
        if outcome in _NOT_EVENTS:
            return False
        idx = int(outcome.value)
        return (idx if idx >= 0 else -idx - 1) in self.user_terminal

    def _touch(self, outcome) -> bool:
        """True when heyoka stopped on a user's terminal event where its expression does not change sign (just
        before and just after the stop have the same sign): a tangency, not a crossing (what lie_integrate
        finds); or where it crosses the other way than the event's direction (at arbitrary precision heyoka stops
        at every crossing: :func:`lieseries.heyoka_build.build_integrator`)."""
        if self.terminal_check is None:
            return False
        fn, uses_pars, base, bits, directions = self.terminal_check
        idx = int(outcome.value)
        j = (idx if idx >= 0 else -idx - 1) - base
        ta = self.ta
        t = ta.time
        delta = abs(ta.last_h) * 2.0 ** (-bits / 4)

        def sign(tt):
            ta.update_d_output(tt)
            v = (fn(ta.d_output, pars=ta.pars) if uses_pars else fn(ta.d_output))[j]
            return int(v > 0) - int(v < 0)

        before, after = sign(t - delta), sign(t + delta)
        if before * after > 0:
            self.touches += 1
            return True
        return bool(directions[j]) and (after - before) * directions[j] < 0  # (in time: t - delta is before t)

    def end_crossing(self, directions):
        """(index among the user's terminal events, note on the last step) of one whose expression is zero at the
        final time, arrived at the way its ``direction`` allows (``directions``: theirs, in order), or None. heyoka's root finding
        does not report a zero at the very end of a step that reached the final time; ``lie_integrate`` does, and
        a crossing at exactly t_end is the user's: the run ends there ``event`` in every engine."""
        if self.terminal_check is None or self.ta is None or not _finite(self.ta.last_h):
            return None
        fn, uses_pars, _base, bits, _ = self.terminal_check
        ta = self.ta
        at_end = fn(ta.state, pars=ta.pars) if uses_pars else fn(ta.state)
        forward = self.direction
        ta.update_d_output(ta.time - forward * abs(ta.last_h) * 2.0 ** (-bits / 4))
        before = fn(ta.d_output, pars=ta.pars) if uses_pars else fn(ta.d_output)
        for j, (v, b, d) in enumerate(zip(at_end, before, directions)):
            if v == 0 and b != 0 and (not d or (-b if forward > 0 else b) * d > 0):
                return j, self._note()
        return None

    def _propagate(self, t_end, budget, callback, cap=None, write_tc=False):
        """A chunk of at most ``budget`` steps towards ``t_end``, each at most ``cap`` long when given."""
        ta = self.ta
        limit = {} if cap is None else {"max_delta_t": cap}
        self.chunk_start, self.chunk_dtime = ta.time, tuple(ta.dtime)
        if self.guard is not None:
            callback = self.guard if callback is None else Both(self.guard, callback)
        if self.pending is not None:
            # Not propagate_grid: it needs the current time as its first grid point, and heyoka's time is double
            # length (ta.time is its high part), so each chunk would first step back by the low part and the
            # result would depend on where the chunks (sized by wall time) end. propagate_until continues exactly;
            # a step callback takes the rows from each step's Taylor polynomial, as propagate_grid does (rows[0]
            # stands for the chunk's start, as in propagate_grid's answer).
            rows = _GridRows(self.pending, self.direction)
            res = ta.propagate_until(t_end, max_steps=budget, write_tc=True,
                                     callback=rows if callback is None else Both(rows, callback), **limit)
            return (res[0], res[1], res[2], res[3], None, rows.rows)
        return ta.propagate_until(t_end, max_steps=budget, c_output=self.dense, callback=callback, write_tc=write_tc,
                                  **limit)

    def _account(self, res, t_end):
        """The steps, step sizes and output rows of a chunk from ``self.chunk_start`` to ``t_end``."""
        n = int(res[3])
        self.steps += n
        if n:
            lo, hi = step_range(n, res[1], res[2], t_end, self.chunk_start)
            self.min_h = min(self.min_h, lo)
            self.max_h = max(self.max_h, hi)
            self.since_max = max(self.since_max, hi)
            self.since_min = min(self.since_min, lo)
        pending = self.pending
        if pending is not None:
            out = res[-1][1:]  # the first row is the chunk's start
            self.queue.extend(zip(pending[:len(out)], (np.array(r, copy=True) for r in out)))
            del pending[: len(out)]
        elif self.dense and res[4] is not None:
            self.c_outs.append(res[4])


class _GridRows:
    """Step callback of a run with output times: the state at each output time the step covered, from the step's
    Taylor polynomial (heyoka's dense output).

    A time is taken in the first step whose end reaches it, the end read as heyoka's double-length time (hi, lo):
    t < hi, or t == hi and lo >= 0 (forward; mirrored backward). This is propagate_grid's own rule, so the rows
    are the same whether a chunk ran through propagate_grid (a plain run's first chunk) or through this callback."""

    def __init__(self, pending, direction):
        self.pending = pending
        self.direction = direction
        self.next = 0
        self.rows = [None]

    def __call__(self, ta) -> bool:
        pending, k = self.pending, self.next
        if k < len(pending):
            now, d = ta.time, self.direction
            while k < len(pending):
                p = pending[k]
                if not ((p - now) * d < 0 or (p == now and ta.dtime[1] * d >= 0)):
                    break
                self.rows.append(np.array(ta.update_d_output(p), copy=True))
                k += 1
            self.next = k
        return True


class FirstStep:
    """Step callback of a run's first chunk while the bound on the call's first step is not known (its first run):
    after the first step, the bound from that step's Taylor coefficients (``ta.tc``, the series at y0:
    :func:`lieseries.heyoka_build.first_step_bound`); the chunk goes on only when there is none. The chunk must
    write the coefficients (``write_tc=True``; propagate_grid does)."""

    def __init__(self, order):
        self.order = order
        self.read = False
        self.bound = None

    def __call__(self, ta) -> bool:
        if self.read:
            return True
        self.read = True
        self.bound = first_step_bound(ta.tc, self.order)
        return self.bound is None

    def settle(self, call, ta, res, terminal: bool):
        """After the chunk (heyoka's answer ``res``): the bound, in the run's format, kept on the call (which is
        then not plain: its runs take the bounded step). Returns (``res``, None) when the chunk stands: no bound,
        or the first step within it (``res`` then reads as that one step's: heyoka stopped the chunk after it);
        (None, the bound) when the step must be taken back and taken again bounded. ``terminal``: the run has
        terminal events (a step one of them cut short is taken back: the bounded step's event search runs on
        another interval)."""
        if self.read:
            bound = self.bound
        elif res[0] == _OUTCOME.err_nf_state and not res[3]:
            # the first step's state is not finite (heyoka skips the callback then): its coefficients are the
            # series at y0 all the same, and a bounded step may be finite
            bound = first_step_bound(ta.tc, self.order)
        else:  # pragma: no cover - heyoka calls the callback after every step it takes
            raise RuntimeError("the first step of a heyoka run did not report its Taylor coefficients")
        cap = None if bound is None else call.prec.time(bound)
        call.first_h, call.first_known = cap, True
        if cap is None:
            return res, None
        call.plain = False
        # kept when within the bound: the very step a bounded one is (heyoka clamps only a longer one)
        h = ta.last_h
        if res[0] == _OUTCOME.cb_stop and abs(h) < cap and not terminal:
            t0, t_end = call.plan["t0_native"], call.plan["grid_native"][-1]
            outcome = _OUTCOME.time_limit if h == t_end - t0 else _OUTCOME.step_limit
            return (outcome,) + tuple(res[1:]), None
        return None, cap


class _Keeper:
    """Per-step callback of a re-run chunk: keeps the last accepted (finite) state."""

    def __init__(self, ta):
        self.state = np.array(ta.state, copy=True)
        self.t = ta.time

    def __call__(self, ta) -> bool:
        np.copyto(self.state, ta.state)
        self.t = ta.time
        return True


def _relative_change(a, b) -> float:
    """Largest change of one component relative to its own size: max_i |a_i - b_i| / max(|a_i|, |b_i|, s / 100),
    s the max-norm of the state.

    Measured per component, so that a large conserved variable beside a small oscillating one does not hide the
    oscillation (what a norm of the whole state would do); the floor s / 100 keeps components passing through
    zero from looking fast."""
    try:
        fa = np.asarray(a, dtype=np.float64)
        fb = np.asarray(b, dtype=np.float64)
    except (TypeError, ValueError):
        fa = np.array([float(v) for v in a])
        fb = np.array([float(v) for v in b])
    scale = np.maximum(np.maximum(np.abs(fa), np.abs(fb)), 1e-2 * float(np.max(np.abs(fa))))
    moving = scale > 0
    if not moving.any():
        return 0.0
    return float(np.max(np.abs(fa - fb)[moving] / scale[moving]))


def _finite(v) -> bool:
    try:
        return bool(np.isfinite(float(v)))
    except (TypeError, ValueError, OverflowError):
        return False
