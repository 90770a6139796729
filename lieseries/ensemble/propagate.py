"""The ensemble entry point: :func:`integrate_ensemble` checks the inputs once (:mod:`.plan`), runs the members on a
Dask cluster (:mod:`.cluster`) or here on one path -- batch (:mod:`.batch`), scalar threads or single runs
(:mod:`.threads`) --, hands what a path cannot decide to single runs, applies the single run's energy check, and
assembles the result (:mod:`.result`)."""

from __future__ import annotations

import os
import time as _time

import numpy as np

from ..driver import run_message
from ..energy import drift_message, energy_check, energy_drift
from ..solution import EnsembleSolution
from ..taylor import integrate as run_single
from ..taylor.plan import warn_cancelling_field
from .batch import BATCH_STEPS, run_batches
from .build import build_batch_integrator, build_scalar_integrator
from .cluster import run_dask
from .plan import member_system, plan_ensemble
from .result import Monotone, Result, assemble, no_crossings
from .threads import run_scalar, run_singles

__all__ = ["integrate_ensemble", "PathRun"]


def integrate_ensemble(
    system,
    Y0,
    t,
    *,
    tol=None,
    precision=None,
    t0=0,
    params=None,
    workers=None,
    client=None,
    max_steps=None,
    max_time=None,
    chunk_size=None,
    batch_size=None,
    progress=None,
    min_step=None,
    compact_mode=None,
    high_accuracy: bool = False,
    dense: bool = False,
    atlas: bool | None = None,
    events=None,
) -> EnsembleSolution:
    """Integrate ``system`` from each row of ``Y0``; every member as its single run would.

    Parameters
    ----------
    system : model or PoissonSystem, or a list of k models of one kind
        A list gives each member its own parameter values (e.g. bodies of different inertia).
    Y0 : array-like, shape (k, n)
        Initial states, one per row. Exact entries (str, Fraction, mpf, int) are rounded once to the working
        precision; float64 entries are their binary values.
    t : float or sequence
        Final time or output times, as for :func:`lieseries.integrate` (the same for every member).
    tol, t0, max_steps
        As for :func:`lieseries.integrate`, per member.
    max_time : float, optional
        Wall-time budget in seconds of the call (the inputs' checks and every member, on every worker): each member
        runs as a single run with the time left when it starts as its budget, and the members not started when it
        runs out end ``time_budget`` at their initial state, not run. As for a single run, it does not bound the
        one-off compilation of the integrator and its checks: what the run that compiled spends outside its
        integration moves it on.
    precision : "double" | "long double" | "quad" | int bits, optional
        Default: the precision of ``Y0`` (the dtype of a numeric array; double for exact input and floats).
    params : array-like, shape (k, npar), optional
        Per-member values of the system's runtime parameters, in the order of
        ``system.poisson.parameter_names`` (for EulerPoisson the entries of I^-1).
    workers : int, optional
        Threads for double (default: the number of CPUs, with at least two batches per thread), long double and
        quad (default: the CPUs, at least two members per thread); processes for arbitrary precision (default 1:
        one after another in this process).
    client : dask.distributed.Client, optional
        Run the chunks on a Dask cluster (module docstring).
    chunk_size : int, optional
        Members per Dask task (default: about four tasks per worker thread of the cluster, at least one batch).
    batch_size : int, optional
        SIMD lanes per batch (double; default ``heyoka.recommended_simd_size()``).
    progress : callable, optional
        Called as ``progress(fraction_done)`` (the fraction of members finished) as batches, single runs and
        chunks finish, as for :func:`lieseries.integrate`.
    min_step, compact_mode, high_accuracy
        As for :func:`lieseries.integrate` (with ``min_step`` every member runs as a single run).
    atlas : bool, optional
        As for :func:`lieseries.integrate` (default: the model's own ``atlas`` attribute, off when it has none).
        Members that start in their best chart and never come near its edge run in the batch; the others (those
        that would switch charts) run as single runs across the atlas.
    dense
        Not available for ensembles: a ValueError says what to do instead.
    events : list of :class:`lieseries.Event`, optional
        As for a single run: every member then runs as a single run (heyoka's batch mode has no per-lane event
        records), and ``sol.events[i]`` holds member i's crossings; a terminal event ends that member with
        status ``event``.

    Returns
    -------
    EnsembleSolution
    """
    called = _time.perf_counter()
    plan = plan_ensemble(system, Y0, t, tol=tol, precision=precision, t0=t0, params=params, workers=workers,
                         client=client, max_steps=max_steps, max_time=max_time, chunk_size=chunk_size,
                         batch_size=batch_size, progress=progress, min_step=min_step,
                         compact_mode=compact_mode, high_accuracy=high_accuracy, dense=dense, atlas=atlas,
                         events=events)
    progress = None if progress is None else Monotone(progress)
    # (the budget counts the checks and exact conversions of the inputs, as a single run's counts its grid's)
    left = None if max_time is None else max_time - (_time.perf_counter() - called)
    if client is not None:
        return _on_cluster(client, plan, progress, None if left is None else _time.time() + left)
    return _run_here(plan, progress, left)


def _run_here(plan, progress, budget) -> EnsembleSolution:
    """The members here, on the path their precision and options allow, with ``budget`` seconds (or None) for all
    of them together from now."""
    res = Result(plan.k, len(plan.grid), plan.ps.dimension, plan.prec,
                 chart=plan.structure.chart if plan.atlas else None)  # across an atlas every state knows its chart
    start = _time.perf_counter()
    deadline = None if budget is None else start + budget
    path = _run_path(plan, res, progress)
    _hand_over(plan, res, path, progress, deadline)
    _check_energy(plan, res, path)
    _check_end_cancellation(plan, res, path)
    return assemble(plan, res, path, _time.perf_counter() - start)


class PathRun:
    """How the members ran here: the path's ``name`` ("batch", "threads", "single", "none"), its ``workers``,
    the Taylor ``order``, the ``build`` time, the members ``handed`` to single runs, the model's terminal
    events (``event_info``) and whether the field's cancellation check at ``Y0`` warned (``cancels``)."""

    def __init__(self, name, workers, order=0, build=0.0, handed=(), event_info=(), cancels=False):
        self.name, self.workers, self.order, self.build = name, workers, order, build
        self.handed, self.event_info, self.cancels = list(handed), list(event_info), cancels


def _run_path(plan, res, progress) -> PathRun:
    """Run the members on the path their precision and options allow (the others are handed to single runs)."""
    k, prec = plan.k, plan.prec
    cap = BATCH_STEPS if plan.max_steps is None else int(plan.max_steps)
    scalar_ok = plan.max_time is None and plan.min_step is None
    if plan.events is not None:  # events: every member is a single run, which records its crossings
        return PathRun("single", plan.workers or 1, handed=range(k))
    if plan.direction == 0:
        for i in range(k):
            res.rows[i] = len(plan.grid)
            res.y[i, :] = plan.Ynat[i]
            res.finish(i, "success", run_message("success", t=plan.t0f), plan.t0n, plan.Ynat[i], 0)
        return PathRun("none", 1)
    if plan.atlas and plan.pars is not None:  # per-member parameters across an atlas: single runs
        return PathRun("single", 1, handed=range(k))
    cancels = False
    if prec.name == "double" and scalar_ok:
        if plan.members is None:  # (single runs warn themselves; models of their own each are not checked here)
            cancels = warn_cancelling_field(plan.ps, plan.Ynat, prec.bits, plan.pars, members=range(k))
        ta, build, event_info = build_batch_integrator(plan.run_system, plan.tolf, plan.B,
                                                       compact_mode=plan.compact_mode,
                                                       high_accuracy=plan.high_accuracy)
        n_batches = -(-k // plan.B)
        # a thread pool costs about half a millisecond to start: by default, threads only for two batches each
        workers = (min(plan.workers, n_batches) if plan.workers
                   else max(1, min(os.cpu_count() or 1, n_batches // 2)))
        handed = run_batches(ta, event_info, plan.Ynat, plan.pars, plan.ps_run, plan.tgrid, plan.t0n,
                             plan.direction, plan.B, cap, workers, res, progress)
        path = PathRun("batch", workers, int(ta.order), build, handed, event_info, cancels)
    elif prec.name in ("long double", "quad") and scalar_ok:
        if plan.members is None:  # (single runs warn themselves; models of their own each are not checked here)
            cancels = warn_cancelling_field(plan.ps, plan.Ynat, prec.bits, plan.pars, members=range(k))
        ta, build, event_info = build_scalar_integrator(plan.run_system, prec, plan.tolf,
                                                        compact_mode=plan.compact_mode,
                                                        high_accuracy=plan.high_accuracy)
        workers = min(plan.workers, k) if plan.workers else max(1, min(os.cpu_count() or 1, k // 2))
        handed = run_scalar(ta, event_info, plan.Ynat, plan.pars, plan.ps_run, prec, plan.tgrid, plan.t0n,
                            plan.direction, cap, workers, res, progress)
        path = PathRun("threads", workers, int(ta.order), build, handed, event_info, cancels)
    else:
        return PathRun("single", plan.workers or 1, handed=range(k))
    if plan.atlas:
        # members that reached the switching edge, or that an atlas run would start in another chart
        x = np.abs(np.asarray(plan.Ynat[:, :3], dtype=np.float64))
        other_chart = np.argmax(x, axis=1) != plan.structure.chart
        switch_status = {info[0] for info in path.event_info}
        path.handed = sorted(set(path.handed) | {i for i in range(k) if other_chart[i] or res.status[i] in switch_status})
    return path


def _hand_over(plan, res, path, progress, deadline) -> None:
    """The members the path handed over, each as its single run (:func:`lieseries.taylor.integrate`), each with the
    time left before ``deadline`` as its ``max_time``; a member not started before it ends ``time_budget`` at its
    initial state (its rows at times up to t0 are that state, the others NaN)."""
    handed = path.handed
    if not handed:
        return
    members, pars = plan.members, plan.pars
    systems = [member_system(members[i] if members else plan.structure, plan.ps, None if pars is None else pars[i])
               for i in handed]
    sols, budgets = run_singles(run_single, systems, [plan.Ynat[i] for i in handed], plan.t, plan.opts,
                                plan.workers if path.name == "single" else 1, progress, plan.k,
                                plan.k - len(handed), deadline)
    whole = (f"`max_time` = {plan.max_time:g} s bounds the ensemble's members together" if plan.max_time is not None
             else "")
    for i, sol, left in zip(handed, sols, budgets):
        if sol is None:
            at_t0 = sum(1 for g in plan.tgrid if (g - plan.t0n) * plan.direction <= 0)
            res.y[i, :at_t0] = plan.Ynat[i]
            res.rows[i] = at_t0
            res.finish(i, "time_budget", f"{whole} and ran out before this member started: it was not run. Raise "
                       "`max_time`, or run fewer members per call.", plan.t0n, plan.Ynat[i], 0)
            if plan.events is not None:
                if res.events is None:
                    res.events = [None] * plan.k
                res.events[i] = no_crossings(plan.events, plan.ps.dimension, plan.prec)
            continue
        res.take(i, sol, plan.tgrid)
        if sol.status == "time_budget" and left is not None:
            res.message[i] = f"{sol.message} ({whole}: this member started with {left:.3g} s of it left)"
        path.order = max(path.order, int(sol.stats.order))
        path.build += float(sol.stats.build_time)


def _check_end_cancellation(plan, res, path) -> None:
    """For a field no energy check guards (a non-Hamiltonian ``extra_field``), the single run's cancellation check at
    the end states of the members the batch or the scalar threads finished (u' = u, w' = (u^2 + 1) - u^2 to t = 20:
    w 0.685 off, ``success`` and silent), unless the check at their ``Y0`` warned (single runs check their own)."""
    if path.name not in ("batch", "threads") or plan.ps.is_hamiltonian or plan.members is not None or path.cancels:
        return
    handed = set(path.handed)
    done = [i for i in range(plan.k) if i not in handed and res.status[i] == "success"]
    if done:
        warn_cancelling_field(plan.ps, res.y_reached[done], plan.prec.bits,
                              None if plan.pars is None else [plan.pars[i] for i in done], members=done,
                              where="the end states")


def _check_energy(plan, res, path) -> None:
    """The single run's energy check, for the members the batch or the scalar threads finished."""
    ps, prec, tolf, pars, Ynat = plan.ps, plan.prec, plan.tolf, plan.pars, plan.Ynat
    if path.name not in ("batch", "threads") or not ps.is_hamiltonian:
        return
    handed_set = set(path.handed)
    done_here = [i for i in range(plan.k) if i not in handed_set and res.status[i] == "success"]

    def single_check(i):
        res.status[i], res.message[i] = energy_check(ps, prec, tolf, Ynat[i], res.y_reached[i], res.steps[i],
                                                     "success", res.message[i], None if pars is None else pars[i])

    if path.name == "threads":
        for i in done_here:
            single_check(i)
        return
    # double: all members in one vectorised call
    drifted, low = energy_drift(ps, tolf, Ynat[done_here], res.y_reached[done_here],
                                None if pars is None else [pars[i] for i in done_here],
                                steps=[res.steps[i] for i in done_here])
    for j, (e0, e1) in drifted.items():
        i = done_here[j]
        res.status[i] = "invariant_drift"
        res.message[i] = drift_message(res.message[i], e0, e1, res.steps[i])
    for j in low:  # an energy below double's range: the single run's check, with the exact energy
        single_check(done_here[j])


def _on_cluster(client, plan, progress, until) -> EnsembleSolution:
    opts = dict(tol=plan.tol, precision=plan.prec, max_steps=plan.max_steps, max_time=plan.max_time,
                batch_size=plan.batch_size, min_step=plan.min_step,
                compact_mode=plan.compact_mode, high_accuracy=plan.high_accuracy, atlas=plan.atlas,
                events=plan.events)
    return run_dask(client, chunk_task, plan.structure, plan.Ynat, plan.pars, plan.t, plan.t0, opts,
                    plan.chunk_size, progress, plan.k, until)


def chunk_task(system, rows, pars, t, t0, opts, until=None):
    """One Dask task: an ensemble of a chunk of members, run on the worker (its own integrator cache); ``until``
    (a ``time.time()`` reading, or None) is the deadline of the whole ensemble's ``max_time``."""
    plan = plan_ensemble(system, rows, t, t0=t0, params=pars, workers=1, client=None, chunk_size=None,
                         progress=None, dense=False, **opts)
    return _run_here(plan, None, None if until is None else until - _time.time())
