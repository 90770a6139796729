"""The public entry point of heyoka runs: :func:`integrate` runs one state (:mod:`lieseries.taylor`) or an
ensemble (:mod:`lieseries.ensemble`). The choice lives here, above both engines, so that neither needs the other:
the ensemble's members that need a single run call :func:`lieseries.taylor.integrate` directly."""

from __future__ import annotations

import inspect

import numpy as np

from .ensemble import integrate_ensemble
from .models.base import ExactState
from .precision import check_flag, check_progress, infer_precision
from .taylor import integrate as run_single
from .timegrid import refuse_lost_span

__all__ = ["integrate"]

#: Options only an ensemble reads (a single run is given them as None, or not at all).
ENSEMBLE_OPTIONS = ("params", "workers", "client", "chunk_size", "batch_size")


def integrate(system, y0, t, **options):
    """Integrate ``dz/dt = X_H(z)`` with heyoka's adaptive Taylor method.

    Parameters
    ----------
    system : model (EulerPoisson, Sphere, SphereDirac, ...) or PoissonSystem
    y0 : sequence of n numbers
        Initial state, taken at its exact value and rounded once to the working precision: a state from
        ``model.initial_state(...)`` keeps the exact input it was built from; str, int, Fraction and mpf entries
        are exact; a binary float entry is its own binary value. Binary data that carry fewer bits than the run
        (0.1 as a double in a 237-bit run) give one :class:`~lieseries.precision.PrecisionWarning`.
    t : float or increasing sequence
        Final time (negative: backward integration) or output times (see :func:`lieseries.timegrid.parse_times`).
    tol : float, optional
        Relative and absolute tolerance; default and smallest allowed: the precision's epsilon.
    precision : "double" | "long double" | "quad" | int bits (at most ``precision.MAX_BITS``), optional
        Default: the precision of ``y0`` (double for exact states and Python numbers; a long double, real128 or
        heyoka.real array runs in its own precision).
    t0 : float
        Initial time.
    dense : bool
        Keep heyoka's continuous output so that ``sol(t)`` works anywhere in the interval. Off by default (as in
        scipy): it costs run time and memory (order x n numbers per step).
    max_steps : int, optional
        Step budget (default 5e7). A run whose step size collapses so that it could not finish within the
        budget stops early with status ``step_collapse``; a stiff run (:mod:`lieseries.taylor.chunks`) stops once
        it would need more than 1e5 steps, or more than ``max_steps`` when you give it.
    max_time : float, optional
        Wall-time budget in seconds for the integration (status ``time_budget``), checked between chunks of steps
        that take about 0.1 s each, or one step where a step takes longer (heyoka cannot stop inside a step: a run
        overruns it by at most about that). It does not bound the one-off compilation of a new integrator. For an
        ensemble it bounds the call, all the members together: members not started when it runs out end
        ``time_budget`` without running.
    min_step : float, optional
        Stop with ``step_collapse`` when a step smaller than this was taken (checked between chunks of steps).
    atlas : bool, optional
        For a model with charts (:class:`~lieseries.Sphere`), on by default (the model's ``atlas``): switch charts
        when the current one is ending and go on (:mod:`lieseries.atlas`); ``sol.charts`` tells the chart of each
        output row. With ``atlas=False`` the run stays in one chart and stops at its edge (``chart_edge``).
    progress : callable or True, optional
        Called as ``progress(fraction_done)`` between chunks of steps (about ten times a second) during long runs;
        True shows a bar (on a terminal).
    events : list of :class:`lieseries.Event`, optional
        Zero crossings to record (``sol.events[name]``: times and states) or, for a terminal event, to stop at
        (status ``event``), found by heyoka's polynomial root finding on every step.
    params, workers, client, chunk_size, batch_size :
        For an ensemble: ``y0`` of shape (k, n) (or ``system`` a list of models of one structure, or ``params``
        of shape (k, npar)) integrates k members and returns an :class:`~lieseries.solution.EnsembleSolution`
        (:func:`lieseries.ensemble.integrate_ensemble`: heyoka's batch mode in double over ``workers`` threads;
        ``client`` a ``dask.distributed.Client`` to run on a cluster; with ``events``, single runs per member).
        ``chunk_size`` and ``batch_size`` are read by ensembles only.

    Returns
    -------
    Solution
        ``sol.t``, ``sol.y`` (one row per output time reached), ``sol.stats``, ``sol.status``, ``sol.message``.
    """
    if not options and type(y0) is ExactState and type(system) is not list and type(system) is not tuple:
        return run_single(system, y0, t)  # the usual call: one exact state, the options at their defaults
    t0 = options.get("t0")
    if t0 is not None and not (type(t0) in (int, float) and t0 == 0):
        atlas = options.get("atlas")
        members = system if isinstance(system, (list, tuple)) else [system]
        refuse_lost_span(t, t0, infer_precision(options.get("precision"), y0),
                         atlas=bool(atlas or (atlas is None and any(getattr(m, "atlas", False) for m in members))))
    if _is_ensemble(system, y0, options):
        return _ensemble(system, y0, t, **options)
    if options:
        options = {k: v for k, v in options.items() if k not in ENSEMBLE_OPTIONS}
    return run_single(system, y0, t, **options)


def _is_ensemble(system, y0, options) -> bool:
    """k members: a list of models, ``params``, ``workers`` or ``client`` given, or rows of states."""
    if isinstance(system, (list, tuple)) or any(options.get(k) is not None for k in ("params", "workers", "client")):
        return True
    if type(y0) is ExactState:
        return False
    if isinstance(y0, np.ndarray):
        return y0.ndim == 2
    return isinstance(y0, (list, tuple)) and len(y0) > 0 and np.ndim(y0[0]) == 1


def _ensemble(system, y0, t, *, tol=None, precision=None, t0=0, dense: bool = False, max_steps: int | None = None,
              max_time: float | None = None, min_step: float | None = None, compact_mode: bool | None = None,
              high_accuracy: bool = False, atlas: bool | None = None, progress=None, events=None, params=None,
              workers: int | None = None, client=None, chunk_size: int | None = None,
              batch_size: int | None = None):
    """:func:`integrate` of an ensemble, its options bound (a misspelt one is reported against ``integrate``)."""
    progress = check_progress(progress, title="integrate")  # True: show a bar
    check_flag(compact_mode, "compact_mode")
    check_flag(high_accuracy, "high_accuracy", allow_none=False)
    return integrate_ensemble(system, y0, t, tol=tol, precision=precision, t0=t0, params=params, workers=workers,
                              client=client, max_steps=max_steps, max_time=max_time, chunk_size=chunk_size,
                              batch_size=batch_size, progress=progress, min_step=min_step, compact_mode=compact_mode,
                              high_accuracy=high_accuracy, dense=dense, atlas=atlas, events=events)


integrate.__signature__ = inspect.signature(_ensemble)  # help() and introspection see every option
_ensemble.__qualname__ = "integrate"
