"""The double path: heyoka's batch mode, ``B`` members in the SIMD lanes of one integrator, batches spread over
threads (each thread on its own pooled copy of the cached integrator); members the batch cannot decide are handed
to single runs (see the package docstring)."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .. import cache
from ..driver import run_message
from ..heyoka_build import norm_bounds, top_orders
from ..precision import to_fraction
from .result import STEP_LIMIT, TIME_LIMIT, outcome_kind

__all__ = ["run_batches", "over_threads", "BATCH_STEPS", "CHUNK_STEPS"]

#: Steps a lane may take inside a batch (with the default ``max_steps``) before it is handed to a single run, which
#: decides whether the run is healthy and long, stiff, or collapsing (see the package docstring).
BATCH_STEPS = 100_000
#: A batch runs in chunks of steps (growing 4x from this many); between chunks, a lane that at its current step
#: size would need more than the step cap is handed to a single run early.
CHUNK_STEPS = 2048


def _record_lane(res, i, lane, kind, ta, out, Ynat, tgrid, t0n, direction, simple, event_info, nsteps, success_msg):
    """Record one lane that finished (``kind`` "done") or stopped at a terminal event (``kind`` its index)."""
    t_r = to_fraction(ta.time[lane])
    y_r = np.array(ta.state[:, lane], copy=True)
    if simple:
        res.y[i, 0] = Ynat[i]
        res.y[i, 1] = y_r
        res.rows[i] = 1 + (kind == "done" or t_r == tgrid[-1])
    else:
        m = 0
        for j, tj in enumerate(tgrid):
            if (tj - t0n) * direction > (t_r - t0n) * direction:
                break
            res.y[i, j] = Ynat[i] if tj == t0n else (y_r if tj == t_r else out[j, :, lane])
            m = j + 1
        res.rows[i] = m
    if kind == "done":
        res.finish(i, "success", success_msg, t_r, y_r, nsteps)
    else:
        status, msg = event_info[kind]
        h = abs(float(ta.last_h[lane]))
        res.finish(i, status, run_message("event", t=t_r, note=f" (last step size {h:.3g})", detail=msg), t_r, y_r,
                   nsteps)


def _continue_batch(ta, prs, idx, nl, res, lo, Ynat, tgrid, t0n, direction, event_info, cap, t_end, success_msg,
                    before):
    """Finish a batch (final-time run) that did not finish in one go.

    Either a lane stopped the batch (a terminal event, a non-finite state) or the batch used up its chunk of
    :data:`CHUNK_STEPS` steps. Lanes that finished or met a terminal event are recorded and parked at the final time
    on a finite state (they take no more steps); the others go on. heyoka's step size depends on the current state
    alone, so a lane that goes on takes the steps it would have taken without the stop. Returned (for single runs):
    the lanes that became non-finite, and those that at their current step size would need more than ``cap``
    steps in all (a long, stiff or collapsing run: the single run's guard decides which). ``before``: the steps
    every lane took before ``prs``.
    """
    B = len(idx)
    decided = np.zeros(B, dtype=bool)
    steps = np.full(B, before, dtype=np.int64)
    handed = []
    n_events = len(event_info)
    chunk = CHUNK_STEPS
    while True:
        times = np.array(ta.time, copy=True)
        last_h = np.abs(np.array(ta.last_h, dtype=np.float64))
        parked = False
        for lane in range(B):
            if decided[lane]:
                continue
            outcome, _hmin, _hmax, nsteps = prs[lane]
            steps[lane] += nsteps
            kind = outcome_kind(outcome, n_events)
            if kind == "interrupted" and times[lane] == t_end:
                kind = "done"  # finished while the batch ran out of its chunk of steps
            if kind == "interrupted":
                if not str(outcome).endswith("step_limit"):
                    continue  # stopped by another lane: goes on
                left = abs(float(t_end) - float(times[lane]))
                if last_h[lane] > 0 and steps[lane] + left / last_h[lane] <= cap:
                    continue  # healthy: goes on in the next chunk
            decided[lane] = True
            if lane < nl:
                if kind == "done" or isinstance(kind, int):
                    _record_lane(res, lo + lane, lane, kind, ta, None, Ynat, tgrid, t0n, direction, True,
                                 event_info, int(steps[lane]), success_msg)
                else:  # non-finite, or too many steps ahead
                    handed.append(lo + lane)
            if kind != "done":
                times[lane] = t_end
                parked = True
        if decided.all():
            return handed
        if parked:
            # a parked lane takes zero-length steps, but heyoka still evaluates the field at its state: give it
            # the state of a lane that goes on (finite, and where the field is finite)
            live = int(np.flatnonzero(~decided)[0])
            for lane in np.flatnonzero(times == t_end):
                if decided[lane] and lane != live and prs[lane][0] != TIME_LIMIT:
                    ta.state[:, lane] = ta.state[:, live]
            ta.set_time(times)
        if n_events:
            ta.reset_cooldowns()
        left = cap - int(steps[~decided].max())
        if left <= 0:  # the cap is reached: what is left goes to single runs
            handed.extend(lo + lane for lane in range(nl) if not decided[lane])
            return handed
        chunk = min(4 * chunk, 1 << 20)
        ta.propagate_until(t_end, max_steps=min(left, chunk))
        prs = ta.propagate_res


def run_batches(ta0, event_info, Ynat, pars, ps, tgrid, t0n, direction, B, cap, n_threads, res, progress):
    """Integrate every member in batches of B lanes over ``n_threads`` threads; return the members to hand over."""
    k = Ynat.shape[0]
    batches = _Batches(event_info, Ynat, pars, ps, tgrid, t0n, direction, B, cap, res, ta0.order)
    counter = iter(range(-(-k // B)))
    lock = threading.Lock()
    handed = []
    done = [0]

    def work(_):
        ta, free = cache.checkout(ta0)
        try:
            batches.shared_parameters(ta)
            tops = ta.tc[:, batches.top:, :]  # the orders p - K .. p of the series ta writes (a live view)
            while True:
                with lock:
                    b = next(counter, None)
                if b is None:
                    return
                lo, hi = b * B, min(k, b * B + B)
                mine = batches.run(ta, tops, lo, hi)
                with lock:
                    handed.extend(mine)
                    done[0] += hi - lo - len(mine)
                    if progress is not None:
                        progress(done[0], k)
        finally:
            cache.release(ta, free)

    over_threads(work, n_threads)
    return sorted(set(handed) | set(batches.first_steps()))


class _Batches:
    """What the threads of one :func:`run_batches` share: the members' states and parameters, the output grid,
    where to record; :meth:`run` integrates one batch on a thread's integrator."""

    def __init__(self, event_info, Ynat, pars, ps, tgrid, t0n, direction, B, cap, res, order):
        self.event_info, self.Ynat, self.tgrid, self.t0n, self.direction = event_info, Ynat, tgrid, t0n, direction
        self.B, self.cap, self.res = B, cap, res
        k = Ynat.shape[0]
        self.par_rows = None  # per member, or None without runtime parameters
        if len(ps.parameter_values):
            base = np.array([float(v) for v in ps.parameter_values])
            self.par_rows = (np.tile(base, (k, 1)) if pars is None
                             else np.array([[float(v) for v in r] for r in pars]))
        self.per_member = pars is not None
        self.simple = len(tgrid) == 2 and tgrid[0] == t0n
        self.t0f, self.t_end = float(t0n), float(tgrid[-1])
        # a lane whose first step went the whole way (t_end - t0 rounded, as propagate_until clamps it) ended at
        # t_end exactly when that difference is a double (_until)
        span = self.t_end - self.t0f
        self.span, self.span_exact = span, to_fraction(self.t_end) - to_fraction(self.t0f) == to_fraction(span)
        if not self.simple:
            self.lead = tgrid[0] != t0n
            times = [float(t0n)] * self.lead + [float(g) for g in tgrid]
            self.grid = np.repeat(np.array(times), B).reshape(-1, B)
        self.success_msg = run_message("success", t=tgrid[-1])
        self.zeros = [0.0] * B
        # of every lane's series at its start, the orders p - K .. p (heyoka_build.top_orders), one column per
        # lane of every batch (the padding of the last one included): first_steps
        self.order, self.top = order, top_orders(order).start
        self.tops = np.empty((Ynat.shape[1], order + 1 - self.top, -(-k // B) * B))

    def shared_parameters(self, ta) -> None:
        """The parameters of the thread's integrator ``ta`` when they are the same for every member (set once)."""
        if self.par_rows is not None and not self.per_member:
            B = self.B
            ta.pars[:] = self.par_rows[:B].T if len(self.par_rows) >= B else self.par_rows[[0] * B].T

    def load(self, ta, lo, hi):
        """Members lo..hi-1 into the lanes of ``ta`` at the start time (the last batch padded with copies of its
        first member); returns the members of the lanes."""
        B, state = self.B, ta.state
        if hi - lo == B:
            idx = range(lo, hi)
            state[:] = self.Ynat[lo:hi].T
        else:
            idx = list(range(lo, hi)) + [lo] * (B - (hi - lo))
            state[:] = self.Ynat[idx].T
        ta.set_time(self.t0f)
        if self.par_rows is not None and self.per_member:
            ta.pars[:] = self.par_rows[list(idx)].T
        if self.event_info:
            ta.reset_cooldowns()
        return idx

    def run(self, ta, tops, lo, hi) -> list:
        """Integrate members lo..hi-1 on ``ta`` and record them; return those handed to single runs. ``tops``:
        ``ta.tc[:, self.top:, :]``, the orders of the series :meth:`first_steps` reads."""
        idx = self.load(ta, lo, hi)
        if self.simple:
            prs, before = self._until(ta, tops, lo, hi)
            return self._record(ta, lo, hi, idx, None, prs, before)
        out = ta.propagate_grid(self.grid, max_steps=self.cap)[-1]
        mine = self._record(ta, lo, hi, idx, out[1:] if self.lead else out, ta.propagate_res, 0)
        # propagate_grid cannot be split without moving its rows (its first grid time must be the current time):
        # the series at the lanes' start from a zero-length step that writes it
        ta.state[:] = self.Ynat[idx].T
        ta.set_time(self.t0f)
        ta.step(self.zeros, write_tc=True)
        self.tops[:, :, lo:lo + self.B] = tops
        return mine

    def _until(self, ta, tops, lo, hi):
        """The batch's first chunk towards the final time (at most :data:`CHUNK_STEPS` steps) as one
        ``propagate_until`` runs it, in two calls: its first step, which writes the series at the lanes' start (kept
        for :meth:`first_steps`), then the rest (heyoka sizes each step from the state alone). Returns heyoka's
        answer and the steps taken before it (1, or 0 when it is the whole chunk's): the chunk ended in its first
        step (every lane at the final time, an event, a non-finite state) or was that step. A lane that went the
        whole way in its first step takes zero-length steps in the second call as in the one -- unless t_end - t0
        is not a double (that step, the difference rounded, ended off t_end): the chunk then runs again in one
        call."""
        chunk, t_end = min(self.cap, CHUNK_STEPS), self.t_end
        ta.propagate_until(t_end, max_steps=1, write_tc=True)
        self.tops[:, :, lo:lo + self.B] = tops
        prs = ta.propagate_res
        if chunk == 1 or prs[0][0] != STEP_LIMIT:
            return prs, 0
        if not self.span_exact and (np.asarray(ta.last_h) == self.span).any():
            self.load(ta, lo, hi)
            ta.propagate_until(t_end, max_steps=chunk)
            return ta.propagate_res, 0
        ta.propagate_until(t_end, max_steps=chunk - 1)
        return ta.propagate_res, 1

    def first_steps(self) -> list:
        """The members whose first step heyoka's step rule could not size: their series at the start has its last
        two orders vanish or far below the lower ones (:func:`lieseries.heyoka_build.sparse_first_step`), and the
        step was too long whether the member went the whole way in it or not (from q = 1e-6, q'' = 1 - 3 q^2 in
        double: 6e-14 off, success); a single run bounds it. Every member's series read at once (its orders
        p - K .. p kept from its batch's first step, or for output times from a zero-length step; order 0 is y0);
        a member whose last two orders vanish is handed over too (its single run reads the whole series)."""
        k = self.Ynat.shape[0]
        x0 = np.abs(self.Ynat).max(axis=1)
        top = np.abs(self.tops[:, :, :k]).max(axis=0)
        bounds = norm_bounds(x0, top, self.order)
        gap = np.flatnonzero(top[-2:].max(axis=0) == 0)  # (their whole series would tell: the single run reads it)
        return [i for i, b in enumerate(bounds) if b is not None] + gap.tolist()

    def _record(self, ta, lo, hi, idx, out, prs, before) -> list:
        """Record the batch's members once ``ta`` has run them (a final-time run that did not finish goes on);
        return those handed to single runs. ``prs``: heyoka's answer, after ``before`` steps of every lane."""
        res, Ynat, tgrid, t0n, simple, success_msg = (self.res, self.Ynat, self.tgrid, self.t0n, self.simple,
                                                      self.success_msg)
        nl = hi - lo
        outcomes = [prs[lane][0] for lane in range(nl)]
        if all(o == TIME_LIMIT for o in outcomes):  # the common case, in bulk
            _record_batch(res, lo, hi, ta, out, prs, Ynat, tgrid, t0n, simple, success_msg, before)
            return []
        if not simple:
            return _record_grid_lanes(res, lo, nl, ta, out, outcomes, prs, Ynat, tgrid, t0n, self.direction,
                                      self.event_info, self.t_end, success_msg)
        return _continue_batch(ta, prs, idx, nl, res, lo, Ynat, tgrid, t0n, self.direction, self.event_info,
                               self.cap, self.t_end, success_msg, before)


def over_threads(work, n_threads) -> None:
    """``work(j)`` for j < ``n_threads``: in this thread when there is one, else over a pool of threads."""
    if n_threads <= 1:
        work(0)
    else:
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            list(pool.map(work, range(n_threads)))


def _record_batch(res, lo, hi, ta, out, prs, Ynat, tgrid, t0n, simple, success_msg, before) -> None:
    """Record members lo..hi-1, every lane of which reached the final time (``before`` steps, then ``prs``)."""
    nl = hi - lo
    state = ta.state
    res.y_reached[lo:hi] = state.T[:nl]
    if simple:
        res.y[lo:hi, 0] = Ynat[lo:hi]
        res.y[lo:hi, 1] = state.T[:nl]
    else:
        res.y[lo:hi] = np.transpose(out[:, :, :nl], (2, 0, 1))
        res.y[lo:hi, -1] = state.T[:nl]
        if tgrid[0] == t0n:
            res.y[lo:hi, 0] = Ynat[lo:hi]
    res.rows[lo:hi] = len(tgrid)
    res.status[lo:hi] = "success"
    res.message[lo:hi] = [success_msg] * nl
    res.t_reached[lo:hi] = [tgrid[-1]] * nl
    res.steps[lo:hi] = [prs[lane][3] + before for lane in range(nl)]


def _record_grid_lanes(res, lo, nl, ta, out, outcomes, prs, Ynat, tgrid, t0n, direction, event_info, t_end,
                       success_msg) -> list:
    """A grid run that one lane stopped: record the lanes that finished or met a terminal event; return the
    members it interrupted (or that became non-finite), to run again as single runs."""
    mine = []
    for lane in range(nl):
        i = lo + lane
        kind = outcome_kind(outcomes[lane], len(event_info))
        if kind == "interrupted" and ta.time[lane] == t_end:
            kind = "done"  # finished while the batch ran out of steps
        elif kind == "done" and ta.time[lane] != t_end:
            kind = "interrupted"  # stopped where another lane became non-finite, its outcome still a time limit
        if kind in ("interrupted", "non_finite"):
            mine.append(i)
            continue
        _record_lane(res, i, lane, kind, ta, out, Ynat, tgrid, t0n, direction, False, event_info, prs[lane][3],
                     success_msg)
    return mine
