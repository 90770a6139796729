"""heyoka adapter: build (once) and run the adaptive Taylor integrator of a Poisson system, in any precision.

Caching
-------
Compiling a heyoka integrator (LLVM) costs milliseconds to seconds; running a short orbit costs microseconds.
Integrators are therefore cached by (system structure, precision, tolerance, events, options). Model parameters
are heyoka runtime parameters, so two bodies with different inertia share one compiled integrator; only the
parameter values are set per run.

Guards
------
A run never hangs and never returns a silently wrong state, and pays no Python call per step for it: heyoka
integrates in chunks of steps (the first of 64 steps in double; later ones sized so that a chunk takes about 0.1 s;
a short run is a single chunk), and the checks run between chunks. A chunk is one step of the driver loop
(:mod:`lieseries.driver`: :class:`_Chunks`), which owns the budgets, the output rows, the statuses and their
messages (heyoka's advice in its table: how many steps finishing would take):

- ``time_budget``: the wall-time budget ``max_time`` ran out (it bounds the integration, not the compilation of a
  new integrator, which happens once per structure and precision);
- ``step_budget``: ``max_steps`` steps were taken;
- ``step_collapse``: the step size has collapsed so far that finishing would need more than the step budget (a
  singularity ahead), or the problem is stiff: its steps are tiny (finishing needs more than 1e5 steps with the
  default budget, or more than ``max_steps`` when given) while no component of the state changes by more than
  1e-2 of its own size (at least 1/100 of the state's max-norm) per step -- the step is then limited by
  stability, not accuracy;
- ``non_finite``: heyoka stopped on a non-finite state (it overwrites the state with NaN); the last chunk is run
  again from its start with a per-step copy of the state, so the last finite state is kept;
- missed crossings: with non-terminal events, the event functions are evaluated at every step's end; a step
  whose signs disagree with the crossings heyoka reported in it, or that starts or ends on a zero, is searched
  again on its Taylor polynomial and the missing crossings are added (:class:`_CrossingGuard`);
- terminal events of the model (e.g. the edge of a sphere chart) end the run with their own status;
- ``invariant_drift``: after a run that reached its final time, the Hamiltonian (conserved by every Hamiltonian
  system) is evaluated at both ends; a change beyond min(sqrt(tol), 1000 tol per step) of its energy scale
  (:func:`lieseries.energy.drift_threshold`) means the result is wrong, whatever the error control believed --
  typically a motion much slower or faster than its time span (Taylor coefficients underflow), fixed by
  rescaling time, or components of very different sizes (the tolerance is relative to the largest), fixed by
  rescaling units. A double run first asks a plain Python function of floats (cheaper than a compiled-function
  call); only when it is not sure that the change is within half the threshold does the compiled check decide.

Repeated calls
--------------
A call with the same system, exact state (or float64 array), times and options as an earlier one reuses its
validated arguments and plan. A repeated call that succeeded before (the same steps again) runs a first chunk of
up to 1024 steps in double (:data:`REPEAT_CHUNK`), so that such a run is one heyoka call; a new call keeps the
short first chunk, so that a collapse or a blow-up is seen early, between chunks. A plain run -- no events of the
user's, no dense output, no ``progress``, no ``min_step``, output times in double -- runs that chunk directly
(``propagate_until``, or ``propagate_grid`` from t0 for output times) and, when it reached the final time with a
sound energy, returns a :class:`Solution` whose rows and statistics are made when first read; anything else
continues on the general path from where the chunk ended, with the same steps, states and statuses.

Threads
-------
Compiled integrators are cached once per key and handed out one per concurrent run (a copy is made only when two
runs of the same key overlap), so ``integrate`` may be called from many threads at once. A run's result does not
depend on the integrator that served it nor on where its chunks end (they are sized by wall time): each run sets
the time, state and parameters, and chunks continue heyoka's double-length time exactly (``propagate_until``; the
rows at output times come from each step's Taylor polynomial, each time from the step propagate_grid takes it in:
a plain run's first chunk may be one propagate_grid from t0), so a call gives the same bits serially and from
threads.
"""

from __future__ import annotations

import copy
import inspect
import math
import time as _time
from fractions import Fraction

import heyoka as hy
import numpy as np

from . import cache
from .driver import KEPT_ROWS, Stop, StepResult, drive, format_time, run_message
from .energy import clear_energy_cache, energy_function, energy_verdict, quick_check
from .events import resolve_events
from .heyoka_build import Both, CrossingGuard, build_integrator, event_function, integrator_count
from .models.base import ExactState, Model, state_fractions
from .poisson import as_poisson_system
from .precision import (
    Precision,
    check_callable,
    check_flag,
    check_progress,
    check_count,
    check_seconds,
    check_tolerance,
    data_bits,
    precision_of_dtype,
    resolve_precision,
    short_decimal,
    to_fraction,
    warn_if_coarse,
)
from .solution import Solution, Stats
from .timegrid import parse_times

__all__ = ["integrate", "build_integrator", "clear_cache", "cache_info"]

_OUTCOME = hy.taylor_outcome
#: The outcomes that are not a terminal event (the others are an event's index i, or -i - 1).
_NOT_EVENTS = frozenset(_OUTCOME.__members__.values())
DEFAULT_MAX_STEPS = 50_000_000
#: With the default budget, a stiff run (module docstring) is stopped once it would need more steps than this.
STIFF_STEPS = 100_000
#: A step that changes no component by more than this fraction of its size (module docstring) is stability-limited:
#: an accuracy-limited step of order ~20 at tol = eps moves the state by ~15% of its time scale.
STIFF_CHANGE = 1e-2


def clear_cache() -> None:
    """Forget every cached integrator, plan, memoised call and compiled function: the whole shared cache
    (:func:`lieseries.cache.clear`, ensemble integrators and compiled programs included) and the energy
    functions."""
    cache.clear()
    clear_energy_cache()


def cache_info() -> dict:
    """Number of cached integrators (``"size"``), and the entries of every region of the shared cache
    (:func:`lieseries.cache.info`)."""
    return {"size": integrator_count(), **cache.info()}


#: An integrator of the same key as ``template`` that no other run is using, and the list to return it to (the
#: shared pool, :func:`lieseries.cache.checkout`). The template itself (what :func:`build_integrator` returns) is
#: never run, so a caller holding it cannot disturb a run; a copy is made only when more runs of one key overlap
#: than there are free copies.
_checkout = cache.checkout
_release = cache.release


#: Steps in the first chunk of a run, by precision (later chunks grow fourfold, up to about CHUNK_SECONDS of work
#: each): a step of the rigid body costs ~2 us in double and ~0.4 s at 1024 bits.
FIRST_CHUNK = {"double": 64, "long double": 32, "quad": 8}
FIRST_CHUNK_REAL = 2
CHUNK_SECONDS = 0.1
#: The first chunk in double of a call repeated after it succeeded (the same system, exact state and options: the
#: same steps again): a run of up to 1024 steps is then one heyoka call (a few ms for the rigid body). A larger
#: system gets fewer, about REPEAT_CHUNK_WORK / D steps for a decomposition of D nodes (the rigid body's has 81),
#: and never fewer than the first chunk of a new call. A new call keeps the short first chunk, so that a run
#: that collapses or overflows is seen between chunks early (what its status and message say).
REPEAT_CHUNK = 1024
REPEAT_CHUNK_WORK = 200_000


def _repeat_chunk(prec, template, first: int) -> int:
    if prec.name != "double":
        return first
    return max(first, min(REPEAT_CHUNK, REPEAT_CHUNK_WORK // max(len(template.decomposition), 1)))


_PLANS = cache.region("taylor.plans", 256)


def _plan(system, ps, prec, tol, t, t0, compact_mode, high_accuracy, user_events=(), max_time=None):
    """What a run needs that depends only on hashable call arguments, computed once and memoised: the output
    grid (exact and in the working format), the tolerance and the integrator's cache entry."""
    key = None
    scalar = (int, float, str, Fraction)
    tkey = (type(t), t) if isinstance(t, scalar) else (  # the type: True == 1, and `t` = True is refused
        ("grid", t.tobytes()) if type(t) is np.ndarray and t.dtype == np.float64 and t.ndim == 1 else None)
    if (not user_events and tkey is not None and isinstance(t0, scalar)
            and (tol is None or isinstance(tol, scalar))):
        key = (id(system), prec.name, type(tol), tol, tkey, type(t0), t0, compact_mode, high_accuracy)
        hit = _PLANS.get(key)
        if hit is not None and hit[0] is system:
            return hit[1]
    # a scalar t (the cached plans) has no grid; a grid's output is sized by its rows (n values per time)
    grid, direction, t0f = parse_times(t, t0, max_time=max_time, values_per_time=ps.dimension,
                                       bytes_per_value=48 + prec.bits // 8 if prec.is_real
                                       else np.dtype(prec.numpy_dtype).itemsize)
    tolf = check_tolerance(tol, prec)
    grid_native = [prec.time(g) for g in grid]
    plan = dict(
        grid=grid, direction=direction, t0f=t0f, tolf=tolf, grid_native=grid_native,
        grid_exact=[to_fraction(g) for g in grid_native], t0_native=prec.time(t0f),
        reached=run_message("success", t=grid_native[-1]),
        tol_float=float(tolf), sqrt_tol=math.sqrt(float(tolf)),
        build=build_integrator(system, prec, tolf, user_events=user_events, compact_mode=compact_mode,
                               high_accuracy=high_accuracy),
    )
    if key is not None:
        _PLANS.put(key, (system, plan))
    return plan


def infer_precision(precision, y0) -> Precision:
    """The run's precision: ``precision`` when given, else the precision of ``y0``'s format.

    A float64 array, an :class:`~lieseries.models.base.ExactState` or plain Python numbers run in double; a
    long double, real128 or heyoka.real array in its own precision. mpmath numbers carry no format: they need an
    explicit ``precision``.
    """
    if precision is not None:
        return resolve_precision(precision)
    if getattr(y0, "exact", None) is not None:
        return resolve_precision("double")
    arr = y0 if isinstance(y0, np.ndarray) else np.asarray(y0, dtype=object)
    prec = precision_of_dtype(arr.dtype) if arr.dtype != object else None
    if prec is not None:
        return prec
    flat = arr.ravel()
    if flat.size and isinstance(flat[0], hy.real):
        return resolve_precision(int(flat[0].prec), "y0")
    if flat.size and isinstance(flat[0], hy.real128):
        return resolve_precision("quad")
    if any(hasattr(v, "_mpf_") for v in flat):
        raise ValueError(
            "`y0` holds mpmath numbers, which carry no precision of their own: pass `precision=` ('double', "
            "'long double', 'quad' or a number of bits)"
        )
    return resolve_precision("double")


def warn_coarse_inputs(ps, y0, times, work_bits: int, *, stacklevel: int = 4) -> bool:
    """One :class:`~lieseries.precision.PrecisionWarning` per input that carries fewer bits than the run uses
    (``times`` is ``(t, t0)``, each named on its own). True when there was one."""
    if work_bits <= 53 and data_bits(y0) is None:
        return False
    t, t0 = times
    coarse = [(data_bits(y0), "y0"), (data_bits(t), "t"), (data_bits(t0), "t0")]
    if work_bits > 53:
        coarse += [(bits, name) for name, bits in ps.coarse_data().items()]
    coarse = [(bits, name) for bits, name in coarse if bits is not None and bits < work_bits]
    for bits, name in coarse:
        warn_if_coarse(bits, work_bits, name, stacklevel=stacklevel)
    return bool(coarse)


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
        budget stops early with status ``step_collapse``; a stiff run (module docstring) stops once it would need
        more than 1e5 steps, or more than ``max_steps`` when you give it.
    max_time : float, optional
        Wall-time budget in seconds for the integration (status ``time_budget``), checked between chunks of steps
        that take about 0.1 s each. It does not bound the one-off compilation of a new integrator.
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

    Returns
    -------
    Solution
        ``sol.t``, ``sol.y`` (one row per output time reached), ``sol.stats``, ``sol.status``, ``sol.message``.
    """
    if not options and type(y0) is ExactState and type(t) in _KEY_SCALARS:
        # a repeated call with every option at its default, an exact state and a scalar time (the usual case):
        # keyed as _call_key keys it, straight to the run on a hit (no options to bind, compare or key)
        call = _CALLS.get((id(system), id(y0), t, type(t)) + _DEFAULT_KEY_TAIL)
        if call is not None and call.system is system:
            return _execute_plain(call) if call.plain else _execute_general(call, None, None)
    return _integrate(system, y0, t, **options)


def _integrate(
    system,
    y0,
    t,
    *,
    tol=None,
    precision=None,
    t0=0,
    dense: bool = False,
    max_steps: int | None = None,
    max_time: float | None = None,
    min_step: float | None = None,
    compact_mode: bool | None = None,
    high_accuracy: bool = False,
    atlas: bool | None = None,
    progress=None,
    events=None,
    params=None,
    workers: int | None = None,
    client=None,
    chunk_size: int | None = None,
    batch_size: int | None = None,
):
    """:func:`integrate` with its options bound (its signature)."""
    if progress is None and events is None and atlas is not True and params is None and workers is None and \
            client is None:
        # a repeated call (the same system, exact state and options as a memoised one): straight to the run. An
        # exact state and a scalar time are keyed here as _call_key does (a function call less)
        ty = type(y0)
        if ty is ExactState and type(t) in _KEY_SCALARS:
            options = (t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode, high_accuracy)
            types = tuple(map(type, options))
            key = (id(system), id(y0), t, type(t)) + options + types if _KEY_SCALARS.issuperset(types) else None
        else:
            key = _call_key(system, y0, t, t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode,
                            high_accuracy)
        call = _CALLS.get(key) if key is not None else None
        if call is not None and call.system is system:
            return _execute_plain(call) if call.plain else _execute_general(call, None, None)
    progress = check_progress(progress, title="integrate")  # True: show a bar
    check_flag(compact_mode, "compact_mode")
    check_flag(high_accuracy, "high_accuracy", allow_none=False)
    if (client is not None or params is not None or workers is not None or isinstance(system, (list, tuple))
            or (y0.ndim == 2 if isinstance(y0, np.ndarray)
                else isinstance(y0, (list, tuple)) and len(y0) > 0 and np.ndim(y0[0]) == 1)):
        from .ensemble import integrate_ensemble

        return integrate_ensemble(system, y0, t, tol=tol, precision=precision, t0=t0, params=params,
                                  workers=workers, client=client, max_steps=max_steps, max_time=max_time,
                                  chunk_size=chunk_size, batch_size=batch_size, progress=progress,
                                  min_step=min_step, compact_mode=compact_mode, high_accuracy=high_accuracy,
                                  dense=dense, atlas=atlas, events=events, single_run=integrate)
    key = _call_key(system, y0, t, t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode,
                    high_accuracy) if events is None and progress is None and atlas is not True else None
    call = _CALLS.get(key) if key is not None else None
    if call is None or call.system is not system or (call.y0 is not y0 and type(y0) is ExactState):
        if atlas is None:
            atlas = bool(getattr(system, "atlas", False))  # a Sphere says (True unless built with atlas=False)
        prec = infer_precision(precision, y0)
        check_callable(progress, "progress")
        max_time = check_seconds(max_time, "max_time")
        default_budget = max_steps is None
        max_steps = DEFAULT_MAX_STEPS if default_budget else check_count(max_steps, "max_steps")
        if min_step is not None:
            min_step = float(to_fraction(min_step, "min_step"))
            if not min_step > 0:
                raise ValueError(f"`min_step` must be positive; got {min_step!r}")
        ps = as_poisson_system(system)
        if atlas:
            from .atlas import run_atlas

            warn_coarse_inputs(ps, y0, [t, t0], prec.bits)
            return run_atlas(integrate, system, y0, t, t0=t0, bits=prec.bits, dense=dense, tol=tol,
                             energy_tol=check_tolerance(tol, prec),
                             precision=prec, max_steps=None if default_budget else max_steps, max_time=max_time,
                             min_step=min_step, compact_mode=compact_mode, high_accuracy=high_accuracy,
                             progress=progress, events=events)
        model = system if isinstance(system, Model) else None
        z0 = model.check_state(y0, "y0") if model is not None else state_fractions(y0, ps.dimension, "y0")
        warned = warn_coarse_inputs(ps, y0, [t, t0], prec.bits)
        user_events = resolve_events(events, system, ps)
        plan = _plan(system, ps, prec, tol, t, t0, compact_mode, high_accuracy, user_events, max_time)
        call = _Call(
            system=system, y0=y0, ps=ps, prec=prec, plan=plan, user_events=user_events,
            y0_native=y0.native(prec) if type(y0) is ExactState else prec.array(z0, "y0"),
            pars_native=ps.native_parameters(prec) if ps.parameter_values else None,
            max_steps=max_steps, stiff_steps=min(max_steps, STIFF_STEPS) if default_budget else max_steps,
            max_time=max_time, min_step=min_step, dense=dense, dtype=prec.numpy_dtype,
            first_chunk=FIRST_CHUNK.get(prec.name, FIRST_CHUNK_REAL),
        )
        call.repeat_chunk = _repeat_chunk(prec, plan["build"][0], call.first_chunk)
        _plain_setup(call)
        if key is not None and not warned:
            _CALLS.put(key, call)
    return _execute(call, progress)


integrate.__signature__ = inspect.signature(_integrate)  # help() and introspection see the options
_integrate.__qualname__ = "integrate"  # and a misspelt option is reported against integrate


def _plain_setup(call) -> None:
    """Whether a new call is plain (no events of the user's, no dense output, no min_step; output times only in
    double), and what its short path (:func:`_execute_plain`) needs."""
    plan, prec = call.plan, call.prec
    grid = plan["grid"]
    one_time = len(grid) == 2 and plan["grid_native"][0] == plan["t0_native"]
    call.plain = (not call.dense and not call.user_events and plan["direction"] != 0 and call.min_step is None
                  and (one_time or prec.name == "double"))
    if call.plain:  # (may still turn False below)
        # output times: one propagate_grid over [t0, grid...] (heyoka's own grid, rows from each step's Taylor
        # polynomial; _GridRows continues it exactly when the run is longer than the chunk)
        rest = plan["grid_native"][1:] if plan["grid_native"][0] == plan["t0_native"] else plan["grid_native"]
        call.grid = None if one_time else np.array([plan["t0_native"]] + list(rest), dtype=np.float64)
        if call.grid is not None and not np.all(np.diff(call.grid) * plan["direction"] > 0):
            # exact times that round to one double (0.1 and 0.1 + 1e-20, or two times within a double of t0):
            # propagate_grid refuses them; the general path gives each its row
            call.plain = False
        call.t_out = _time_array(plan["grid_native"], prec)
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


class _Call:
    """Everything about a call of :func:`integrate` that depends only on its (validated) arguments: computed once
    and memoised for repeated calls with the same system, exact state and options (see :func:`_call_key`)."""

    __slots__ = ("system", "y0", "ps", "prec", "plan", "user_events", "y0_native", "pars_native", "max_steps",
                 "stiff_steps", "max_time", "min_step", "dense", "energy", "dtype", "first_chunk", "plain", "t_out",
                 "t_requested", "t0_native", "t_end_native", "budget", "free", "repeat_chunk", "grid", "sqrt_tol",
                 "reached", "t_exact", "views", "quick", "report", "events", "head", "passed")

    def __init__(self, **kw):
        self.energy = None  # (compiled H, parameters, H(y0)) once a run needs the energy check
        self.plain = False
        self.quick = None  # the plain path's energy check (_quick_energy), made on its first run
        self.passed = None  # (end state's bytes, steps) of its last double run that passed the energy check
        self.report = None  # (build time, cached) its next run reports, once known (_next_report)
        self.views = (None, None, None)  # (integrator, its state's view, its parameters' view) of the last plain run
        for k, v in kw.items():
            setattr(self, k, v)


#: Memoised calls (:class:`_Call`) of :func:`integrate`; a hit is one dict lookup (``_CALLS.get``).
_CALLS = cache.region("taylor.calls", 256)
_KEY_SCALARS = frozenset((type(None), int, float, str, bool))
#: (t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode, high_accuracy) at their defaults
_DEFAULT_OPTIONS = (0, None, None, False, None, None, None, None, False)
_DEFAULT_KEY_TAIL = _DEFAULT_OPTIONS + tuple(map(type, _DEFAULT_OPTIONS))


def _call_key(system, y0, t, *options):
    """The memo key of a call, or None when it cannot be memoised: ``y0`` must be an
    :class:`~lieseries.models.base.ExactState` (immutable; the memo keeps it, so its id cannot be reused) or a 1-d
    float64 array (keyed by its bytes), the first option (``t``) a plain scalar or a 1-d float64 array (keyed by
    its bytes), and every other option a plain scalar."""
    ty = type(y0)
    if ty is ExactState:
        ykey = id(y0)
    elif ty is np.ndarray and y0.dtype == np.float64 and y0.ndim == 1:
        ykey = y0.tobytes()
    else:
        return None
    if type(t) is np.ndarray:  # output times as a 1-d float64 array (np.linspace): keyed by their bytes
        if t.dtype != np.float64 or t.ndim != 1:
            return None
        t = ("grid", t.tobytes())
    elif type(t) not in _KEY_SCALARS:
        return None
    types = tuple(map(type, options))
    if not _KEY_SCALARS.issuperset(types):
        return None
    # the types too: 1 == True == 1.0, and a fresh call refuses some of them (`high_accuracy=1`, `t=True`)
    return (id(system), ykey, t, type(t)) + options + types


def _execute(call, progress):
    """Run a prepared call: one integration and its checks, into a :class:`Solution`."""
    if call.plain and progress is None:
        return _execute_plain(call)
    return _execute_general(call, progress, None)


_TIME_LIMIT = _OUTCOME.time_limit
_perf_counter = _time.perf_counter
_MAX_FREE = cache.MAX_FREE
_FLOAT64 = np.dtype(np.float64)


def _execute_plain(call):
    """A plain run (no events of the user's, no dense output, no progress, no ``min_step``; output times only in
    double): its first chunk is one heyoka call;
    a run that ends within it and passes the cheap energy check (:func:`lieseries.energy.quick_check`) returns a
    :class:`Solution` whose rows and statistics are made when read. Anything else -- a longer run, a non-finite
    state, a step budget, a doubtful energy -- goes on through the general path from where the chunk ended, so
    both give the same steps, states and statuses. (The hot path of a repeated call: each line here costs.)"""
    report = call.report
    if report is None:
        report = _next_report(call)
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
        # max_steps passed by position (as a keyword: 1.5 us more)
        res = ta.propagate_until(call.t_end_native, call.budget) if grid is None else \
            ta.propagate_grid(grid, call.budget)
        run_time = _perf_counter() - tic
        t_end = ta.time
        if grid is not None:  # as _Chunks._propagate answers: the rows last, the first standing for t0
            res = (res[0], res[1], res[2], res[3], None, res[5])
        if res[0] == _TIME_LIMIT and t_end == call.t_end_native:
            y_end = state.copy()
        else:
            return _execute_general(call, None, (ta, res, run_time, report))
    finally:
        if len(free) < _MAX_FREE:  # as _release (inline: the plain path is the fast one)
            free.append(ta)
    passed = call.passed
    if passed is None or passed[1] != res[3] or passed[0] != y_end.tobytes():
        # the energy check. It is a function of the end state and the step count alone (the call's constants
        # fixed), so a run that ends on the very bits and step count of a run that passed it passes it: that is
        # the comparison above (bytes: -0.0 is not 0.0, and a NaN never passed)
        check = call.quick
        if check is None:
            check = call.quick = _quick_energy(call)
        try:
            sure = check(y_end.tolist(), res[3])
        except Exception:  # noqa: BLE001 - overflow, a domain error: the compiled check decides
            sure = False
        if not sure:
            status, _ = energy_verdict(call.energy, call.sqrt_tol, y_end, res[3], "success", call.reached)
            if status != "success":
                return _execute_general(call, None, (None, res, run_time, report, t_end, y_end))
        if call.dtype == _FLOAT64:  # (other formats' bytes may hold padding or pointers)
            call.passed = (y_end.tobytes(), res[3])
        if call.budget < call.repeat_chunk:  # the call's first success (a run that skips the check comes after one)
            _succeeded(call)
    return Solution.deferred(call.head, _plain_fields, (call, y_end, res, t_end, report, run_time))


def _next_report(call) -> tuple:
    """(build time, cached) for the next run of ``call`` to report: only the first run of a new integrator (of any
    call on its plan) reports its build time; what later runs of the call report is kept on it."""
    plan = call.plan
    _, build, cached, _ = plan["build"]
    if not cached:
        if plan.get("used"):
            build, cached = 0.0, True
        plan["used"] = True
    call.report = (build, cached) if cached else (0.0, True)
    return build, cached


def _no_energy(y, steps) -> bool:
    return True  # a system without a Hamiltonian: nothing to check


def _not_sure(y, steps) -> bool:
    return False  # no cheap opinion: the compiled check decides


def _quick_energy(call):
    """The energy check of a plain call's runs, made on its first run: ``check(y_end as a list, steps)``, True
    when the run surely passes the energy guard (:func:`lieseries.energy.quick_check`); False sends the run to the
    compiled check (:func:`lieseries.energy.energy_verdict`)."""
    ps = call.ps
    if not ps.is_hamiltonian:
        return _no_energy
    if call.energy is None:
        call.energy = energy_function(ps, call.prec, call.y0_native)
    return quick_check(call.energy, call.sqrt_tol) or _not_sure


def _succeeded(call) -> None:
    """The call succeeded: when it is repeated, its first chunk is the longer one (:data:`REPEAT_CHUNK`)."""
    call.first_chunk = max(call.first_chunk, call.repeat_chunk)
    call.budget = min(call.first_chunk, call.max_steps)


def _step_range(steps, lo, hi, t_end, t_start):
    """(smallest, largest) step of a chunk of ``steps`` steps from heyoka's answer (as :meth:`_Chunks._account`)."""
    if not steps:
        return math.inf, 0.0
    lo, hi = float(lo), float(hi)
    if not lo <= hi:  # heyoka leaves out a step cut short at the final time: the chunk's mean step
        lo = hi = abs(float(t_end) - float(t_start)) / steps
    return lo, hi


def _plain_rows(call, y_end, rows):
    """The output rows of a plain run that reached its final time: y0 at t0, heyoka's grid rows (``rows``, the
    first standing for t0) between, the final state at the final time (as :func:`_execute_general` takes them)."""
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
    """The fields of a plain run's :class:`Solution` (:func:`_execute_plain`; ``res`` heyoka's answer), when first
    read."""
    steps, rows = res[3], res[5]
    lo, hi = _step_range(steps, res[1], res[2], t_end, call.t0_native)
    stats = Stats(method="taylor (heyoka)", precision=call.prec.name, tol=call.plan["tol_float"],
                  order=call.plan["build"][0].order, build_time=report[0], cached=report[1], run_time=run_time,
                  steps=steps,
                  min_step=lo, max_step=hi)
    # t: the solution's own copy (a read-only array can be made writable again by its owner)
    return {"t": call.t_out.copy(), "y": _plain_rows(call, y_end, rows), "stats": stats, "y_reached": y_end}


def _execute_general(call, progress, started):
    """Run a prepared call in full generality on the driver loop (:func:`lieseries.driver.drive`), a chunk of steps
    per driver step (:class:`_Chunks`); ``started``: the first chunk :func:`_execute_plain` ran."""
    ps, prec, plan, user_events = call.ps, call.prec, call.plan, call.user_events
    grid, direction = plan["grid"], plan["direction"]
    grid_native, t0_native, y0_native = plan["grid_native"], plan["t0_native"], call.y0_native
    template, _, _, event_info = plan["build"]
    build, cached = started[3] if started is not None else (call.report or _next_report(call))
    ta = free = None
    sinks = [[] for ev in user_events if not ev[3]]  # no step: no crossing
    if started is not None:
        # a plain run's first chunk ran in _execute_plain (which returns the integrator to the pool); when it
        # reached the final time (ta None) only the energy check is left
        ta = started[0]
        first = started[1:3] if ta is not None else (started[1], started[2], started[4], started[5])
        engine = _Chunks(ta, call, event_info, first=first)
    elif direction != 0:
        ta, free = _checkout(template)
        try:
            engine, sinks = _start(ta, call, event_info)
        except BaseException:
            _release(ta, free)
            raise
    else:
        engine = _Chunks(None, call, event_info)

    def energy(out):
        # the energy guard of a run that reached its final time (lieseries.energy)
        if ps.is_hamiltonian:
            if call.energy is None:
                call.energy = energy_function(ps, prec, y0_native)
            out.status, out.message = energy_verdict(call.energy, plan["sqrt_tol"], out.z, out.steps, out.status,
                                                     out.message)

    try:
        out = drive(engine, t0_native, y0_native, [(g, g) for g in grid_native], direction=direction,
                    max_steps=call.max_steps, max_time=call.max_time, progress=progress, kept=KEPT_ROWS,
                    start=_time.perf_counter() - (started[2] if started is not None else 0.0), guard=energy)
    finally:
        if free is not None:
            _release(ta, free)
    status = out.status
    stats = Stats(method="taylor (heyoka)", precision=prec.name, tol=plan["tol_float"], order=template.order,
                  build_time=build, cached=cached, run_time=out.run_time, steps=out.steps, min_step=engine.min_h,
                  max_step=engine.max_h,
                  extra={"events_recovered": engine.guard.recovered if engine.guard else 0,
                         "event_touches_dropped": (engine.guard.touches if engine.guard else 0) + engine.touches}
                  if user_events and direction != 0 else None)
    if status == "success" and call.first_chunk < call.repeat_chunk:
        _succeeded(call)
    # the exact value of the time reached (the exact grid's when the run got to the end)
    t_reached = plan["grid_exact"][-1] if out.t == grid_native[-1] else to_fraction(out.t)
    # np.array copies the rows (the run's own arrays, y0's read-only cache)
    rows_y = out.rows_y
    y = np.array(rows_y, dtype=call.dtype) if rows_y else np.empty((0, ps.dimension), dtype=call.dtype)
    tarr = _time_array(out.rows_t, prec) if prec.is_real else np.array(out.rows_t, dtype=call.dtype)
    dense_fn = DenseOutput(engine.c_outs, prec) if engine.c_outs else None
    return Solution(tarr, y, stats, status, out.message, t_reached=t_reached, dense=dense_fn, t_requested=grid,
                    y_reached=np.array(out.z, copy=True) if out.z is y0_native else out.z,
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
    engine = _Chunks(ta, call, event_info, recorders, guard)
    if user_events:
        # the user's terminal events (after the model's in heyoka's order): a zero at t0 does not stop the run
        n_user = sum(1 for e in user_events if e[3])
        engine.user_terminal = frozenset(range(len(event_info) - n_user, len(event_info)))
        if n_user:
            # a stop where the expression does not change sign (a tangency) is not a crossing: go on
            fn, uses_pars = event_function(ps, prec, [e[1] for e in user_events if e[3]])
            engine.terminal_check = (fn, uses_pars, len(event_info) - n_user, prec.bits)
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
    for name, _expr, _direction, terminal in user_events:
        if terminal:
            hit = fired == f"the event {name!r} fired"
            times, states = ([out.t], [out.z]) if hit else ([], [])
        else:
            sink = next(rec_iter)
            times, states = [t for t, _ in sink], [y for _, y in sink]
        result[name] = {
            "t": _time_array(times, prec),
            "y": np.stack(states) if states else np.empty((0, n), dtype=prec.numpy_dtype),
        }
    return result


def _time_array(natives, prec: Precision) -> np.ndarray:
    if prec.is_real:
        out = np.empty(len(natives), dtype=hy.real)
        for i, v in enumerate(natives):
            out[i] = v
        return out
    return np.array(natives, dtype=prec.numpy_dtype)


class _Chunks:
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
        # (heyoka's answer, seconds) of a first chunk already run from t0; with the time and state it reached
        # when the integrator has gone back to the pool
        self.first = first
        grid = plan["grid_native"]
        self.t0, self.t_end = plan["t0_native"], grid[-1]
        self.t_at, self.z_at = self.t0, call.y0_native
        self.steps, self.min_h, self.max_h = 0, math.inf, 0.0
        self.outcome = None
        self.change = self.h_last = math.nan
        self.between = False  # the last chunk used up its steps: the checks run before the next one
        self.user_terminal, self.terminal_check, self.touches = frozenset(), None, 0
        self.c_outs = []  # heyoka's continuous outputs, one per chunk (dense)
        self.queue = []  # (time, row) at the output times the steps so far covered, not yet taken by the driver
        self.chunk_start = self.t0
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
            if self.min_step is not None and self.min_h < self.min_step:
                raise Stop("step_collapse", f"a step of {self.min_h:.3g} was taken, below `min_step` = "
                           f"{self.min_step:.3g}", note=self._note())
            outcome = self._probe(t_end)
            if outcome != _OUTCOME.step_limit:
                return self._result(before, self._end(outcome))
            stop = self._too_slow(t_end)
            if stop is not None:
                return self._result(before, stop)
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
        marks = [len(r.sink) for r in self.recorders]
        if self.first is not None:
            (res, elapsed, *reached), self.first = self.first, None
            self.chunk_start = self.t0
        else:
            tic = _time.perf_counter()
            res = self._propagate(t_end, budget, None)
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
            res = self._propagate(t_end, budget, keeper)
            self._account(res, ta.time)
            self.t_at, self.z_at = keeper.t, keeper.state
            return res[0]
        if reached:  # a plain run's first chunk that reached the final time
            self._account(res, reached[0])
            self.t_at, self.z_at = reached
            return res[0]
        self._account(res, ta.time)
        self.t_at, self.z_at = ta.time, np.array(ta.state, copy=True)
        if res[0] == _OUTCOME.step_limit:  # the next chunk: about CHUNK_SECONDS of work
            per_step = elapsed / max(int(res[3]), 1)
            self.chunk = int(min(4 * self.chunk, max(16, CHUNK_SECONDS / max(per_step, 1e-9)), 1 << 20))
        return res[0]

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
        self.t_at, self.z_at = ta.time, np.array(ta.state, copy=True)
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
        if self.user_terminal and self._at_user_event(outcome) and (self.t_at == self.t0 or self._touch(outcome)):
            return None  # the run starts on the event's surface, or touches it: go on (heyoka's cooldown)
        # a terminal event: heyoka reports event i as outcome i, or -(i + 1) when it stopped the run
        where = self._note()
        idx = int(outcome.value) if outcome not in _NOT_EVENTS else None
        info = self.event_info
        if idx is not None and -len(info) <= idx < 0:
            idx = -idx - 1
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
        if need > self.stiff_steps and h < 1e-2 * h_first:
            return self._collapse("step_collapse.taylor")  # shrinking towards a singularity
        if need > self.stiff_steps and self.change < STIFF_CHANGE and h < 1e-2 * left:
            return self._collapse("step_collapse.stiff")  # tiny steps over which no component changes
        if need > self.max_steps - self.steps:
            return self._collapse("step_collapse.taylor") if h < 1e-2 * h_first else self.explain("step_budget")
        return None

    def explain(self, status, t=None):
        """A budget stop at the last chunk's end, with the steps finishing would take (:data:`MESSAGES`)."""
        if status != "step_budget":
            return Stop(status, note=self._note())
        need, hopeless = self._need()
        return Stop(status, need, note=self._note(), reason="step_budget.hopeless" if hopeless else "step_budget.ahead")

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
        hh = self.h_last
        if hh != hh:
            last = self.ta.last_h if self.ta is not None else math.nan
            hh = abs(float(last)) if _finite(last) else math.nan
        if not 0 < hh < math.inf:
            return f"{short_decimal(left)} time units remain", False
        steps = left / Fraction(hh)
        return (f"{short_decimal(left)} time units remain, about {short_decimal(steps)} steps at this step size",
                steps > 10**15)

    def _at_user_event(self, outcome) -> bool:
        if outcome in _NOT_EVENTS:
            return False
        idx = int(outcome.value)
        return (idx if idx >= 0 else -idx - 1) in self.user_terminal

    def _touch(self, outcome) -> bool:
        """True when heyoka stopped on a user's terminal event where its expression does not change sign (just
        before and just after the stop have the same sign): a tangency, not a crossing (what lie_integrate
        finds)."""
        if self.terminal_check is None:
            return False
        fn, uses_pars, base, bits = self.terminal_check
        idx = int(outcome.value)
        j = (idx if idx >= 0 else -idx - 1) - base
        ta = self.ta
        t = ta.time
        delta = abs(ta.last_h) * 2.0 ** (-bits / 4)

        def sign(tt):
            ta.update_d_output(tt)
            v = (fn(ta.d_output, pars=ta.pars) if uses_pars else fn(ta.d_output))[j]
            return int(v > 0) - int(v < 0)

        if sign(t - delta) * sign(t + delta) > 0:
            self.touches += 1
            return True
        return False

    def _propagate(self, t_end, budget, callback):
        ta = self.ta
        self.chunk_start = ta.time
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
                                     callback=rows if callback is None else Both(rows, callback))
            return (res[0], res[1], res[2], res[3], None, rows.rows)
        return ta.propagate_until(t_end, max_steps=budget, c_output=self.dense, callback=callback)

    def _account(self, res, t_end):
        """The steps, step sizes and output rows of a chunk from ``self.chunk_start`` to ``t_end``."""
        n = int(res[3])
        self.steps += n
        if n:
            lo, hi = _step_range(n, res[1], res[2], t_end, self.chunk_start)
            self.min_h = min(self.min_h, lo)
            self.max_h = max(self.max_h, hi)
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


class DenseOutput:
    """``sol(t)`` of a heyoka run: its continuous outputs (one per chunk of steps), picklable."""

    def __init__(self, c_outs, prec: Precision | None):
        self.c_outs = list(c_outs)
        self.prec = prec
        self.bounds = [tuple(sorted(float(b) for b in c.bounds)) for c in self.c_outs]

    def at_native(self, t):
        """The state at ``t`` (in the run's format) from the chunk that covers it."""
        tv = float(t)
        for (lo, hi), c in zip(self.bounds, self.c_outs):
            if lo <= tv <= hi:
                return np.array(c(t), copy=True)
        return np.array(self.c_outs[-1](t), copy=True)

    def __call__(self, t):
        lo = min(b[0] for b in self.bounds)
        hi = max(b[1] for b in self.bounds)
        scalar = np.ndim(t) == 0
        ts = [t] if scalar else list(np.asarray(t, dtype=object).ravel())
        out = []
        for tk in ts:
            tf = to_fraction(tk, "t")
            tv = float(tf)
            if not (lo - 1e-15 * max(1.0, abs(lo)) <= tv <= hi + 1e-15 * max(1.0, abs(hi))):
                raise ValueError(f"`t` = {tv} is outside the integrated interval [{lo}, {hi}]")
            out.append(self.at_native(self.prec.time(tf)))
        return out[0] if scalar else np.stack(out)
