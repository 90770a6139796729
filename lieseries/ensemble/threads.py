"""The scalar paths: members one by one on the scalar integrator (long double, quad) over threads, each thread on
its own pooled copy of the cached integrator; and single runs (any precision, events, members handed over by the
batch), one after another or over threads."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .. import cache
from ..precision import to_fraction
from .batch import CHUNK_STEPS, over_threads
from .result import outcome_kind

__all__ = ["run_scalar", "run_singles"]


def run_scalar(ta0, event_info, Ynat, pars, ps, prec, tgrid, t0n, direction, cap, n_threads, res, progress):
    """Every member with the scalar integrator ``ta0`` (a private copy per thread); return the members to hand over.

    The same decisions as a batch lane: finished or stopped by a terminal event is recorded; non-finite, or more
    than ``cap`` steps ahead at the current step size (checked between chunks of steps), goes to a single run.
    """
    k, n = Ynat.shape
    npar = len(ps.parameter_values)
    par_native = None
    if npar:
        par_native = [prec.array(ps.parameter_values if pars is None else pars[i]) for i in range(k)] \
            if pars is not None else [prec.array(ps.parameter_values)] * k
    simple = len(tgrid) == 2 and tgrid[0] == t0n
    t0_nat = prec.time(t0n)
    t_end = prec.time(tgrid[-1])
    if not simple:
        lead = tgrid[0] != t0n
        grid = prec.array([t0n] * lead + list(tgrid))
    success_msg = f"Reached t = {float(tgrid[-1]):.17g}."
    counter = iter(range(k))
    lock = threading.Lock()
    handed = []
    done = [0]
    n_events = len(event_info)

    def one(ta, i):
        ta.time = t0_nat
        ta.state[:] = Ynat[i]
        if npar:
            ta.pars[:] = par_native[i]
        if n_events:
            ta.reset_cooldowns()
        steps = 0
        out = None
        if simple:
            chunk = CHUNK_STEPS
            while True:
                outcome, _hmin, _hmax, nsteps = ta.propagate_until(t_end, max_steps=min(cap - steps, chunk))[:4]
                steps += nsteps
                kind = outcome_kind(outcome, n_events)
                if kind != "interrupted":
                    break
                h = abs(float(ta.last_h))
                left = abs(float(t_end) - float(ta.time))
                if not str(outcome).endswith("step_limit") or steps >= cap or not h > 0 or steps + left / h > cap:
                    return False
                chunk = min(4 * chunk, 1 << 20)
        else:
            r = ta.propagate_grid(grid, max_steps=cap)
            outcome, steps, out = r[0], int(r[3]), r[-1][int(lead):]
            kind = outcome_kind(outcome, n_events)
        if kind in ("interrupted", "non_finite"):
            return False
        t_r = to_fraction(ta.time)
        y_r = np.array(ta.state, copy=True)
        m = 0
        for j, tj in enumerate(tgrid):
            if (tj - t0n) * direction > (t_r - t0n) * direction:
                break
            res.y[i, j] = Ynat[i] if tj == t0n else (y_r if tj == t_r else out[j])
            m = j + 1
        res.rows[i] = m
        if kind == "done":
            res.finish(i, "success", success_msg, t_r, y_r, steps)
        else:
            status, msg = event_info[kind]
            h = abs(float(ta.last_h))
            res.finish(i, status, f"Stopped at t = {float(t_r):.17g} (last step size {h:.3g}): {msg}.", t_r, y_r,
                       steps)
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


def run_singles(single_run, systems, rows, t, opts, workers, progress, k, done0):
    """Single runs, one after another or over ``workers`` threads (a single run is thread-safe: each takes its
    own copy of the cached integrator, and heyoka releases the GIL while it integrates)."""
    if workers is None or workers <= 1 or len(rows) <= 1:
        out = []
        for j, (s, y0) in enumerate(zip(systems, rows)):
            out.append(single_run(s, y0, t, **opts))
            if progress is not None:
                progress(done0 + j + 1, k)
        return out
    out = [None] * len(rows)
    lock = threading.Lock()
    done = [0]

    def one(j):
        out[j] = single_run(systems[j], rows[j], t, **opts)
        with lock:
            done[0] += 1
            if progress is not None:
                progress(done0 + done[0], k)

    with ThreadPoolExecutor(max_workers=min(workers, len(rows))) as pool:
        list(pool.map(one, range(len(rows))))
    return out
