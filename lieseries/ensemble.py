"""Ensembles: one system from k initial conditions (and per-member parameters), locally or on a Dask cluster.

Paths
-----
``"double"``
    heyoka's batch mode (:class:`heyoka.taylor_adaptive_batch`): ``batch_size`` members (default
    ``heyoka.recommended_simd_size()``) advance together in the SIMD lanes, each lane with its own step size, so
    every member takes the same steps as its single run. Batches are spread over ``workers`` threads (heyoka
    releases the GIL while it integrates). Each thread works on its own copy of the cached compiled integrator
    (integrators are not thread-safe); one copy per thread, not per batch, because copying an integrator costs
    about as much as integrating eight rigid bodies to T = 20.
``"long double"``, ``"quad"``
    heyoka has no batch mode in these types: the members run one by one on the scalar integrator a single run
    uses (same compiled code and the same steps as the single run; its output rows may differ from the single
    run's in the last place), over ``workers`` threads, each with its own copy.
``events=``
    every member is a single run (heyoka's batch mode keeps no per-lane record of crossings), in any precision,
    over ``workers`` threads; ``sol.events[i]`` holds member i's crossings.
bits (arbitrary precision)
    every member is a single run (``single_run``, normally :func:`lieseries.integrate`), one after another, or over
    ``workers`` threads when ``workers`` > 1 (each with its own copy of the cached integrator).

Statuses and the guards
-----------------------
Every member ends with the status its single run would end with. In batch mode heyoka stops the whole batch when
one lane becomes non-finite or hits a terminal event (e.g. a sphere chart's edge). Lanes stopped by a terminal
event keep their state at the event (status from the model's event, as in a single run). For a final time, the
lanes the stop interrupted go on in the batch (the stopped lane is parked at the final time): heyoka's step size
depends on the current state alone, so they take the steps they would have taken anyway. For an output grid they
are run again as single runs. A lane that became non-finite is run again as a single run from its initial
condition, which keeps the last finite state and applies the single run's guards (step collapse, stiffness,
budgets). A lane may take at most ``max_steps`` steps in a batch (default :data:`BATCH_STEPS`, the single run's
threshold for a stiff run): the batch runs in chunks of steps, and a lane that at its current step size would need
more is handed to a single run early, which decides between success, ``step_collapse`` and ``step_budget`` exactly
as for one run (a healthy run longer than :data:`BATCH_STEPS` steps thus runs as a single run unless ``max_steps``
is given). With ``max_time`` (a per-member wall-time budget) or ``min_step``, every member runs as a single
run.

A member that stops early has NaN in the output rows after its stop; ``t_reached``/``y_reached`` give the last
time and state it reached.

Dask
----
``client=`` a :class:`dask.distributed.Client`: the members are cut into chunks (``chunk_size``), and each chunk is
one task that receives the system (pickled: the model or PoissonSystem with its heyoka expressions, never a
compiled integrator), the chunk's initial conditions already rounded to the working precision, and the options;
the worker runs :func:`integrate_ensemble` on its chunk, compiling the integrator once per worker process (module
cache). The chunks are gathered into one :class:`~lieseries.solution.EnsembleSolution`, equal to the local one.
A chunk whose worker dies is rerun (``DASK_RETRIES`` times: on another worker, or on the same one restarted by its
nanny); a closed client, or a chunk that cannot be rerun (a single worker without a nanny), raises a RuntimeError
naming ``client`` with the cause and what to do.
"""

from __future__ import annotations

import copy
import numbers
import os
import re
import threading
import time as _time
from concurrent.futures import ThreadPoolExecutor

import heyoka as hy
import numpy as np

from .energy import drift_message, energy_check, energy_drift
from .events import resolve_events
from .models.base import Model, state_fractions
from .poisson import PoissonSystem, as_poisson_system
from .precision import (Precision, check_flag, check_tolerance, data_bits, precision_of_dtype, resolve_precision, to_fraction,
                        warn_if_coarse)
from .solution import EnsembleSolution
from .timegrid import parse_times

__all__ = ["integrate_ensemble", "build_batch_integrator", "build_scalar_integrator", "clear_batch_cache",
           "BATCH_STEPS"]

#: Steps a lane may take inside a batch (with the default ``max_steps``) before it is handed to a single run, which
#: decides whether the run is healthy and long, stiff, or collapsing (see the module docstring).
BATCH_STEPS = 100_000
#: A batch runs in chunks of steps (growing 4x from this many); between chunks, a lane that at its current step
#: size would need more than the step cap is handed to a single run early.
CHUNK_STEPS = 2048
DEFAULT_MAX_STEPS = 50_000_000

_CACHE: dict = {}
_CACHE_MAX = 16
_CACHE_LOCK = threading.Lock()


def clear_batch_cache() -> None:
    """Forget every cached batch integrator (of this process)."""
    with _CACHE_LOCK:
        _CACHE.clear()
        _SPARE.clear()


def build_batch_integrator(system, tol=None, batch_size=None, *, compact_mode=None, high_accuracy=False):
    """heyoka's ``taylor_adaptive_batch`` (double) for ``system``, from this process's cache when possible.

    The cache key is (system structure, precision, tolerance, terminal events, batch size, compact mode, high
    accuracy); model parameters are runtime parameters, so bodies of different inertia share one compiled integrator. The
    returned object is the cached one: copy it (``copy.deepcopy``) before integrating in more than one thread.

    Returns
    -------
    ta : heyoka.taylor_adaptive_batch
    build_time : float   seconds spent compiling (0.0 on a cache hit)
    event_info : list of (status, message), one per terminal event of the model, in heyoka's order
    """
    ps = as_poisson_system(system)
    prec = resolve_precision("double")
    tolf = check_tolerance(tol, prec)
    B = _check_batch_size(batch_size)
    check_flag(compact_mode, "compact_mode")
    evs = system.events() if isinstance(system, Model) else []
    n = ps.dimension
    if compact_mode is None:
        compact_mode = n > 20
    key = (ps.key, prec.name, tolf, tuple(str(e[0]) for e in evs), B, bool(compact_mode), bool(high_accuracy))

    def make():
        kwargs = dict(tol=float(tolf), compact_mode=bool(compact_mode), high_accuracy=bool(high_accuracy))
        if evs:
            kwargs["t_events"] = [hy.t_event_batch(e[0]) for e in evs]
        npar = len(ps.parameter_values)
        if npar:
            kwargs["pars"] = np.repeat(np.array([float(v) for v in ps.parameter_values]), B).reshape(npar, B)
        return hy.taylor_adaptive_batch(ps.ode_system, np.zeros((n, B)), **kwargs)

    return _cached(key, evs, make)


def build_scalar_integrator(system, precision, tol=None, *, compact_mode=None, high_accuracy=False):
    """heyoka's scalar ``taylor_adaptive`` in ``precision`` ("long double" or "quad") with the options of a single
    run (same compiled code, hence the same steps), from this process's cache; copy it before use in a thread.

    Returns (ta, build_time, event_info) as :func:`build_batch_integrator`.
    """
    ps = as_poisson_system(system)
    prec = resolve_precision(precision)
    if prec.name not in ("long double", "quad"):
        raise ValueError(f"`precision` must be 'long double' or 'quad' here; got {prec.name!r}")
    tolf = check_tolerance(tol, prec)
    evs = system.events() if isinstance(system, Model) else []
    if compact_mode is None:
        compact_mode = True  # as a single run: LLVM is slow on unrolled long-double and quad code
    key = ("scalar", ps.key, prec.name, tolf, tuple(str(e[0]) for e in evs), bool(compact_mode),
           bool(high_accuracy))

    def make():
        kwargs = dict(tol=prec.to_native(tolf), compact_mode=bool(compact_mode), high_accuracy=bool(high_accuracy),
                      fp_type=prec.fp_type)
        if evs:
            kwargs["t_events"] = [hy.t_event(e[0], fp_type=prec.fp_type) for e in evs]
        if ps.parameter_values:
            kwargs["pars"] = prec.array(ps.parameter_values)
        return hy.taylor_adaptive(ps.ode_system, prec.array([0] * ps.dimension), **kwargs)

    return _cached(key, evs, make)


def _cached(key, evs, make):
    """(integrator, build time, event info) from this process's cache, built by ``make()`` on a miss."""
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            return hit[0], 0.0, hit[1]
        start = _time.perf_counter()
        ta = make()
        build = _time.perf_counter() - start
        info = [(e[1], e[2]) for e in evs]
        if len(_CACHE) >= _CACHE_MAX:
            old = _CACHE.pop(next(iter(_CACHE)))
            _SPARE.pop(id(old[0]), None)
        _CACHE[key] = (ta, info)
        return ta, build, info


# -- input checks ------------------------------------------------------------------------------------------------
#: The most SIMD lanes per batch: heyoka compiles one function of ``batch_size`` lanes, and its compilation time
#: grows fast with the lanes (rigid body: 9 s at 8, 29 s at 16, 79 s at 64) while lanes beyond the CPU's SIMD width
#: (``heyoka.recommended_simd_size()``, 2 to 8) bring no speed.
MAX_BATCH_SIZE = 16


def _check_batch_size(batch_size) -> int:
    if batch_size is None:
        return min(int(hy.recommended_simd_size()), MAX_BATCH_SIZE)
    if isinstance(batch_size, bool) or not isinstance(batch_size, numbers.Integral) or batch_size < 1:
        raise ValueError(f"`batch_size` must be a positive integer; got {batch_size!r}")
    if batch_size > MAX_BATCH_SIZE:
        raise ValueError(
            f"`batch_size` must be at most {MAX_BATCH_SIZE}; got {batch_size}: heyoka compiles one function of "
            f"`batch_size` lanes, which takes minutes beyond that (79 s at 64 for the rigid body), and lanes beyond "
            f"the CPU's SIMD width ({int(hy.recommended_simd_size())} here) bring no speed. Leave it out for the "
            "recommended size")
    return int(batch_size)


def _check_count(value, argname):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ValueError(f"`{argname}` must be a positive integer; got {value!r}")
    return int(value)


def _structure(system):
    """(structure system, list of per-member systems or None) from a model/PoissonSystem or a list of them."""
    if isinstance(system, (list, tuple)):
        if not system:
            raise ValueError("`system` as a list must hold at least one model")
        pss = [as_poisson_system(s, f"system[{i}]") for i, s in enumerate(system)]
        key = pss[0].key
        for i, p in enumerate(pss):
            if p.key != key:
                raise ValueError(
                    f"`system[{i}]` has another structure than `system[0]` ({p.name} vs {pss[0].name}): every "
                    "member of an ensemble must be the same model with other parameter values (e.g. inertia)"
                )
            if type(system[i]) is not type(system[0]):
                raise ValueError(f"`system[{i}]` is a {type(system[i]).__name__}, `system[0]` a "
                                 f"{type(system[0]).__name__}: pass models of one kind")
        ev0 = [str(e[0]) for e in system[0].events()] if isinstance(system[0], Model) else []
        for i, s in enumerate(system):
            evi = [str(e[0]) for e in s.events()] if isinstance(s, Model) else []
            if evi != ev0:
                raise ValueError(f"`system[{i}]` watches other events than `system[0]`; pass models of one kind")
        return system[0], list(system)
    as_poisson_system(system)
    return system, None


def _states(model, ps, Y0, prec: Precision, foreign=frozenset()):
    """Y0 checked and rounded once to the working precision: a native array (k, n). Rows in ``foreign`` (members
    with parameters of their own) get the plain check here and their constraints in _check_member_constraints."""
    n = ps.dimension
    if isinstance(Y0, np.ndarray) and Y0.dtype != object:
        arr = Y0
    else:
        if isinstance(Y0, (list, tuple)) and Y0:
            # ragged rows: name the first whose length differs from the first row's
            lens = [len(r) if hasattr(r, "__len__") and not isinstance(r, (str, bytes)) else None for r in Y0]
            for i, ln in enumerate(lens):
                if ln != lens[0]:
                    what = f"has {ln} numbers" if ln is not None else "is not a row of numbers"
                    raise ValueError(f"`Y0[{i}]` {what}, `Y0[0]` has {lens[0]}: every row of `Y0` must be one initial state of {n} numbers "
                                     f"(shape (k, {n}))")
        if isinstance(Y0, (str, bytes)) or np.ndim(Y0) == 0:
            raise ValueError(f"`Y0` must have shape (k, {n}): one initial state per row; got {type(Y0).__name__}")
        try:
            arr = np.asarray(Y0, dtype=object)
        except ValueError:
            raise ValueError(f"`Y0` must have shape (k, {n}): rows of equal length {n}") from None
    if arr.ndim == 1 and arr.shape[0] == n:
        raise ValueError(f"`Y0` is one state of {n} numbers, but an ensemble (asked for by `params`, `workers`, "
                         "`client` or a list of models) needs one initial state per member, shape (k, n): repeat "
                         "the state, e.g. `[y0] * k`, or drop those arguments for a single run")
    if arr.ndim != 2 or arr.shape[1] != n or arr.shape[0] < 1:
        raise ValueError(f"`Y0` must have shape (k, {n}) with k >= 1: one initial state of {n} numbers per row; "
                         f"got shape {arr.shape}")
    plain_check = model is None or type(model).check_state is Model.check_state or hasattr(model, "check_rows")
    if plain_check and arr.dtype in (np.float64, np.longdouble) and prec.name in ("double", "long double"):
        bad = ~np.isfinite(arr)
        if bad.any():
            i, j = map(int, np.argwhere(bad)[0])
            raise ValueError(f"`Y0[{i}][{j}]` must be finite; got {arr[i, j]}: every entry of `Y0` must be a "
                             "finite number")
        if model is not None and hasattr(model, "check_rows"):
            model.check_rows(arr, "Y0")  # the model's warnings, at numpy speed
        return arr.astype(prec.numpy_dtype)  # exact (widening) or rounded once (long double -> double)
    rows = []
    for i in range(arr.shape[0]):
        if model is not None and i not in foreign:
            rows.append(model.check_state(arr[i], f"Y0[{i}]"))
        else:
            rows.append(state_fractions(arr[i], n, f"Y0[{i}]"))
    return np.stack([prec.array(r) for r in rows])


def _exact_rows(Y0):
    """A list of states that carry their exact values (``state.exact``) as rows of those exact values."""
    if isinstance(Y0, (list, tuple)) and Y0 and all(getattr(r, "exact", None) is not None for r in Y0):
        return [list(r.exact) for r in Y0]
    return Y0


def _infer_precision(precision, Y0) -> Precision:
    """``precision``, or when it is None the precision of the data (as a single run): the dtype of a numeric
    array, the type of heyoka.real / real128 / long double entries, else double."""
    if precision is not None:
        return resolve_precision(precision)
    if isinstance(Y0, np.ndarray) and Y0.dtype != object:
        return precision_of_dtype(Y0.dtype) or resolve_precision("double")
    try:
        first = np.asarray(Y0, dtype=object).ravel()[0]
    except (ValueError, IndexError):
        return resolve_precision("double")
    if isinstance(first, hy.real):
        return resolve_precision(int(first.prec))
    if isinstance(first, hy.real128):
        return resolve_precision("quad")
    if isinstance(first, np.longdouble) and np.finfo(np.longdouble).nmant > 52:
        return resolve_precision("long double")
    return resolve_precision("double")


def _warn_coarse(prec: Precision, inputs, systems) -> None:
    """One :class:`~lieseries.precision.PrecisionWarning` per input (``(name, values)``: Y0, params, t, t0) or
    model parameter that carries fewer bits than the run (binary doubles in a run of more bits), as a single run
    gives."""
    narrow = any(isinstance(v, np.ndarray) and v.dtype in (np.float16, np.float32)
                 for _, v in inputs)  # float32 / float16 data carry fewer bits than even a double run
    if prec.bits <= 53 and not narrow:
        return
    for name, values in inputs:
        if values is not None:
            # a numeric array keeps its dtype (a float32 0.1 carries 24 bits, the double it widens to looks exact)
            arr = values if isinstance(values, np.ndarray) and values.dtype != object else np.asarray(values,
                                                                                                     dtype=object)
            warn_if_coarse(data_bits(arr), prec.bits, name, stacklevel=5)
    seen = set()
    for s in systems:
        for name, bits in as_poisson_system(s).coarse_data().items():
            if name not in seen and bits is not None and bits < prec.bits:
                seen.add(name)
                warn_if_coarse(bits, prec.bits, name, stacklevel=5)


def _parameters(model, ps, params, members, k):
    """Per-member parameter values (exact Fractions, (k, npar)) or None when every member uses the system's own."""
    npar = len(ps.parameter_values)
    if members is not None:
        if len(members) != k:
            raise ValueError(f"`system` as a list must give one model per row of `Y0` ({k}); got {len(members)}")
        if params is not None:
            raise ValueError("pass either `params` or a list of models as `system`, not both")
        return [list(as_poisson_system(m).parameter_values) for m in members]
    if params is None:
        return None
    arr = params if isinstance(params, np.ndarray) else np.asarray(params, dtype=object)
    if arr.ndim != 2 or arr.shape != (k, npar):
        raise ValueError(
            f"`params` must have shape (k, npar) = ({k}, {npar}): one row per member with the values of "
            f"{list(ps.parameter_names)} in that order; got shape {arr.shape}"
        )
    rows = [[to_fraction(arr[i, j], f"params[{i}][{j}]") for j in range(npar)] for i in range(k)]
    if model is not None:
        for i, row in enumerate(rows):
            model.check_parameters(row, f"params[{i}]")
    return rows


def _check_member_constraints(ps, Y0, Ynat, pars, prec, from_models):
    """Refuse a row that is off the constraint surface of its own member: a pendulum's state given for one length
    and run with another (``params``, or a list of models) keeps G = |x|^2 - l^2 != 0 as a Casimir, and its run
    would succeed on a motion that is no pendulum's. The constraint Casimirs (``G1..``, ``Phi1..``) are evaluated
    with the member's parameters, relative to 1 + |y|^2, and refused above the square root of the precision."""
    if pars is None or not _constrained(ps):
        return
    exact = isinstance(Y0, list) and all(isinstance(r, list) for r in Y0)
    tol = 2.0 ** -max(1, (prec.bits - 4) // 2)
    for i, values in enumerate(pars):
        if tuple(values) == tuple(ps.parameter_values):
            continue
        row = Y0[i] if exact else Ynat[i]
        inv = ps.with_parameters(values).invariants(row)
        scale = 1 + sum(float(v) ** 2 for v in (row if exact else np.asarray(row, dtype=float)))
        for name, value in inv.items():
            if _CONSTRAINT_NAME.match(name) and abs(float(value)) > tol * scale:
                source = f"the model `system[{i}]`" if from_models else f"`params[{i}]`"
                raise ValueError(
                    f"`Y0[{i}]` is off the constraint surface of its member: with the parameters of {source} "
                    f"({dict(zip(ps.parameter_names, (float(v) for v in values)))}), {name} = {float(value):.3g} "
                    "at it instead of 0 (the state was made for other parameters). Build each member's state with "
                    "its own parameters (a model with those parameters, then `initial_state`)")


_CONSTRAINT_NAME = re.compile(r"^(G|Phi)\d+$")


def _constrained(ps) -> bool:
    """Whether the system's Casimirs include constraints G1.., Phi1.. (a model derived from constraints)."""
    return any(_CONSTRAINT_NAME.match(name) for name in ps.casimirs)


def _member_system(system, ps, values):
    """The system with the parameter values of one member (the system itself when they are its own)."""
    if values is None or tuple(values) == tuple(ps.parameter_values):
        return system
    # same structure, other runtime parameter values: no recompilation
    ps2 = ps.with_parameters(values)
    if isinstance(system, PoissonSystem):
        return ps2
    model = copy.copy(system)
    model.poisson = ps2
    model.__dict__.pop("_charts", None)
    return model


# -- the driver ----------------------------------------------------------------------------------------------------
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
    single_run=None,
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
    tol, t0, max_steps, max_time
        As for :func:`lieseries.integrate`, per member.
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
    single_run : callable, optional
        The single-run driver (``lieseries.integrate``, which passes itself): runs the members of the other
        precisions and the members handed over by the batch path. Without it, every member must be decided in
        batch mode, or a RuntimeError says which member needed a single run.
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
    structure, members = _structure(system)
    ps = as_poisson_system(structure)
    model = structure if isinstance(structure, Model) else None
    Y0 = _exact_rows(Y0)
    prec = _infer_precision(precision, Y0)
    # the output: k members x n values per time (hy.real: an object of ~48 bytes plus its limbs)
    members_k = len(Y0) if hasattr(Y0, "__len__") else 1
    grid, direction, t0f = parse_times(t, t0, values_per_time=max(1, members_k) * ps.dimension,
                                       bytes_per_value=48 + prec.bits // 8 if prec.is_real else np.dtype(prec.numpy_dtype).itemsize,
                                       max_time=max_time)
    tolf = check_tolerance(tol, prec)
    workers = _check_count(workers, "workers")
    chunk_size = _check_count(chunk_size, "chunk_size")
    check_flag(compact_mode, "compact_mode")
    check_flag(high_accuracy, "high_accuracy", allow_none=False)
    B = _check_batch_size(batch_size)
    if max_steps is not None:
        _check_count(max_steps, "max_steps")
    if max_time is not None and not (isinstance(max_time, numbers.Real) and max_time > 0):
        raise ValueError(f"`max_time` must be a positive number of seconds; got {max_time!r}")
    if progress is not None and not callable(progress):
        raise TypeError(f"`progress` must be a callable progress(fraction_done); got {type(progress).__name__}")
    if dense:
        raise ValueError("`dense=True` is not available for an ensemble (`Y0` of shape (k, n)); run the members you "
                         "need it for one by one with lieseries.integrate")
    if atlas is None:
        atlas = bool(getattr(structure, "atlas", False))  # as a single run: a model may switch charts by default
    atlas = bool(atlas)
    if atlas and not (hasattr(structure, "for_chart") and hasattr(structure, "ATLAS_SWITCH")):
        raise ValueError(f"`atlas` needs a model with an atlas of charts (Sphere); {type(structure).__name__} has "
                         "one global chart")
    if events is not None:
        resolve_events(events, structure, ps)  # refuse a bad event here, naming it, before any member runs
    if min_step is not None and not (isinstance(min_step, numbers.Real) and min_step > 0):
        raise ValueError(f"`min_step` must be positive; got {min_step!r}")
    progress = None if progress is None else _Monotone(progress)
    # rows of members with parameters of their own are checked against their own constraint surface, not the
    # model's (a pendulum's state for another length is no state of this one)
    foreign = set()
    if (params is not None or members is not None) and hasattr(Y0, "__len__") and len(Y0) and _constrained(ps):
        own = tuple(ps.parameter_values)
        foreign = {i for i, v in enumerate(_parameters(model, ps, params, members, len(Y0))) if tuple(v) != own}
    Ynat = _states(model, ps, Y0, prec, foreign)
    k = Ynat.shape[0]
    pars = _parameters(model, ps, params, members, k)
    _check_member_constraints(ps, Y0, Ynat, pars, prec, members is not None)
    _warn_coarse(prec, [("Y0", Y0), ("params", params), ("t", t), ("t0", t0)], members or [structure])

    if client is not None:
        return _run_dask(client, structure, Ynat, pars, t, t0, dict(
            tol=tol, precision=prec, max_steps=max_steps, max_time=max_time, batch_size=batch_size,
            single_run=single_run, min_step=min_step, compact_mode=compact_mode, high_accuracy=high_accuracy,
            atlas=atlas, events=events), chunk_size, progress, k)

    opts = dict(tol=tol, precision=prec, t0=t0, max_steps=max_steps, max_time=max_time, atlas=atlas)
    if events is not None:
        opts["events"] = events
    # With an atlas, the batch runs the model with the atlas's switching edge as its terminal event: a member that
    # starts in the model's chart and never reaches that edge is exactly the atlas run's first (and only) segment;
    # the others run as single runs across the atlas.
    run_system = structure
    if atlas:
        run_system = structure.for_chart(structure.chart, edge=structure.ATLAS_SWITCH)
    ps_run = as_poisson_system(run_system)
    for name, value in (("min_step", min_step), ("compact_mode", compact_mode)):
        if value is not None:
            opts[name] = value
    if high_accuracy:
        opts["high_accuracy"] = True
    # heyoka's clock runs in the working precision: output times as rounded there (as in a single run)
    tgrid = [to_fraction(prec.time(g)) for g in grid]
    t0n = to_fraction(prec.time(t0f))
    # across an atlas, every state knows its chart: the batch's members stay in the model's chart
    res = _Result(k, len(grid), ps.dimension, prec, chart=structure.chart if atlas else None)
    start = _time.perf_counter()
    build = 0.0
    handed = []
    if events is not None:
        handed = list(range(k))  # events: every member is a single run, which records its crossings
        used_workers, path, order = (workers or 1), "single", 0
    elif direction == 0:
        for i in range(k):
            res.rows[i] = len(grid)
            res.y[i, :] = Ynat[i]
            res.finish(i, "success", f"Reached t = {float(t0f):.17g}.", t0n, Ynat[i], 0)
        used_workers, path, order = 1, "none", 0
    elif atlas and pars is not None:
        handed = list(range(k))  # per-member parameters across an atlas: single runs
        used_workers, path, order = 1, "single", 0
    elif prec.name == "double" and max_time is None and min_step is None:
        ta, build, event_info = build_batch_integrator(run_system, tolf, B, compact_mode=compact_mode,
                                                       high_accuracy=high_accuracy)
        order = int(ta.order)
        n_batches = -(-k // B)
        # a thread pool costs about half a millisecond to start: by default, threads only for two batches each
        used_workers = min(workers, n_batches) if workers else max(1, min(os.cpu_count() or 1, n_batches // 2))
        cap = BATCH_STEPS if max_steps is None else int(max_steps)
        handed = _run_batches(ta, event_info, Ynat, pars, ps_run, tgrid, t0n, direction, B, cap, used_workers,
                              res, progress)
        path = "batch"
    elif prec.name in ("long double", "quad") and max_time is None and min_step is None:
        ta, build, event_info = build_scalar_integrator(run_system, prec, tolf, compact_mode=compact_mode,
                                                        high_accuracy=high_accuracy)
        order = int(ta.order)
        used_workers = min(workers, k) if workers else max(1, min(os.cpu_count() or 1, k // 2))
        cap = BATCH_STEPS if max_steps is None else int(max_steps)
        handed = _run_scalar(ta, event_info, Ynat, pars, ps_run, prec, tgrid, t0n, direction, cap, used_workers,
                             res, progress)
        path = "threads"
    else:
        handed = list(range(k))
        used_workers, path, order = (workers or 1), "single", 0
    if atlas and path in ("batch", "threads"):
        # members that reached the switching edge, or that an atlas run would start in another chart
        x = np.abs(np.asarray(Ynat[:, :3], dtype=np.float64))
        other_chart = np.argmax(x, axis=1) != structure.chart
        switch_status = {info[0] for info in event_info}
        handed = sorted(set(handed) | {i for i in range(k) if other_chart[i] or res.status[i] in switch_status})
    if handed:
        if single_run is None:
            why = f"precision {prec.name}" if path == "single" else "batch mode could not decide it"
            raise RuntimeError(
                f"member {handed[0]} (of {len(handed)}) needs a single run ({why}): call "
                "lieseries.integrate(system, Y0, ...), or pass `single_run=lieseries.integrate`"
            )
        systems = [_member_system(members[i] if members else structure, ps, None if pars is None else pars[i])
                   for i in handed]
        sols = _run_singles(single_run, systems, [Ynat[i] for i in handed], t, opts,
                            workers if path == "single" else 1, progress, k, k - len(handed))
        for i, sol in zip(handed, sols):
            res.take(i, sol, tgrid)
            order = max(order, int(sol.stats.order))
            build += float(sol.stats.build_time)
    if path in ("batch", "threads") and ps.is_hamiltonian:
        # the single run's energy check, for the members the batch or the scalar threads finished
        handed_set = set(handed)
        done_here = [i for i in range(k) if i not in handed_set and res.status[i] == "success"]
        if path == "batch":  # double: all members in one vectorised call
            drifted, low = energy_drift(ps, tolf, Ynat[done_here], res.y_reached[done_here],
                                        None if pars is None else [pars[i] for i in done_here],
                                        steps=[res.steps[i] for i in done_here])
            for j, (e0, e1) in drifted.items():
                i = done_here[j]
                res.status[i] = "invariant_drift"
                res.message[i] = drift_message(res.message[i], e0, e1, res.steps[i])
            for j in low:  # an energy below double's range: the single run's check, with the exact energy
                i = done_here[j]
                res.status[i], res.message[i] = energy_check(ps, prec, tolf, Ynat[i], res.y_reached[i], res.steps[i],
                                                             "success", res.message[i],
                                                             None if pars is None else pars[i])
        else:
            for i in done_here:
                res.status[i], res.message[i] = energy_check(ps, prec, tolf, Ynat[i], res.y_reached[i], res.steps[i],
                                                             "success", res.message[i],
                                                             None if pars is None else pars[i])
    run_time = _time.perf_counter() - start
    stats = dict(method="taylor (heyoka)", precision=prec.name, tol=float(tolf), order=order,
                 steps=res.steps, build_time=build, run_time=run_time, workers=used_workers,
                 batch_size=B if path == "batch" else 1, path=path, single_runs=len(handed))
    tarr = prec.array(tgrid)
    return EnsembleSolution(tarr, res.y, res.status, res.message, res.t_reached, res.y_reached, stats,
                            rows=res.rows, method="taylor (heyoka)", events=res.events, charts=res.charts,
                            chart_reached=res.chart_reached)


class _Monotone:
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


class _Result:
    """Per-member outputs being filled in (NaN rows where a member did not get to)."""

    def __init__(self, k, m, n, prec: Precision, chart=None):
        self.prec = prec
        # the chart of each state (runs across an atlas), else None
        self.charts = None if chart is None else np.full((k, m), chart, dtype=int)
        self.chart_reached = None if chart is None else np.full(k, chart, dtype=int)
        self.y = _nan_array((k, m, n), prec)
        self.y_reached = _nan_array((k, n), prec)
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
        self.y[i] = _nan_array(self.y.shape[1:], self.prec)
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


def _nan_array(shape, prec: Precision):
    if prec.is_real:
        out = np.empty(shape, dtype=hy.real)
        out[...] = hy.real(float("nan"), prec.bits)
        return out
    return np.full(shape, np.nan, dtype=prec.numpy_dtype)


def _outcome_kind(outcome, n_events):
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


_TIME_LIMIT = hy.taylor_outcome.time_limit
#: Copies of the cached batch integrators that no thread is using, by id of the cached original.
_SPARE: dict = {}


def _borrow(ta0):
    """A private copy of the cached integrator ``ta0`` for one thread (a spare one when there is one)."""
    with _CACHE_LOCK:
        spares = _SPARE.get(id(ta0))
        if spares:
            return spares.pop()
    return copy.deepcopy(ta0)


def _give_back(ta0, ta):
    with _CACHE_LOCK:
        if any(entry[0] is ta0 for entry in _CACHE.values()):  # still cached: keep the copy for the next call
            _SPARE.setdefault(id(ta0), []).append(ta)


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
        res.finish(i, status, f"Stopped at t = {float(t_r):.17g} (last step size {h:.3g}): {msg}.", t_r, y_r, nsteps)


def _continue_batch(ta, prs, idx, nl, res, lo, Ynat, tgrid, t0n, direction, event_info, cap, t_end, success_msg):
    """Finish a batch (final-time run) that did not finish in one go.

    Either a lane stopped the batch (a terminal event, a non-finite state) or the batch used up its chunk of
    :data:`CHUNK_STEPS` steps. Lanes that finished or met a terminal event are recorded and parked at the final time
    on a finite state (they take no more steps); the others go on. heyoka's step size depends on the current state
    alone, so a lane that goes on takes the steps it would have taken without the stop. Returned (for single runs):
    the lanes that became non-finite, and those that at their current step size would need more than ``cap``
    steps in all (a long, stiff or collapsing run: the single run's guard decides which).
    """
    B = len(idx)
    decided = np.zeros(B, dtype=bool)
    steps = np.zeros(B, dtype=np.int64)
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
            kind = _outcome_kind(outcome, n_events)
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
                if decided[lane] and lane != live and prs[lane][0] != _TIME_LIMIT:
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


def _run_batches(ta0, event_info, Ynat, pars, ps, tgrid, t0n, direction, B, cap, n_threads, res, progress):
    """Integrate every member in batches of B lanes over ``n_threads`` threads; return the members to hand over."""
    k, n = Ynat.shape
    npar = len(ps.parameter_values)
    par_rows = None
    if npar:
        base = np.array([float(v) for v in ps.parameter_values])
        par_rows = np.tile(base, (k, 1)) if pars is None else np.array([[float(v) for v in r] for r in pars])
    simple = len(tgrid) == 2 and tgrid[0] == t0n
    t_end = float(tgrid[-1])
    if not simple:
        lead = tgrid[0] != t0n
        times = [float(t0n)] * lead + [float(g) for g in tgrid]
        grid = np.repeat(np.array(times), B).reshape(-1, B)
    success_msg = f"Reached t = {float(tgrid[-1]):.17g}."
    n_batches = -(-k // B)
    counter = iter(range(n_batches))
    lock = threading.Lock()
    handed = []
    done = [0]

    def work(_):
        ta = _borrow(ta0)
        try:
            _work(ta)
        finally:
            _give_back(ta0, ta)

    def _work(ta):
        state, t0f = ta.state, float(t0n)
        if npar and pars is None:
            ta.pars[:] = par_rows[:B].T if k >= B else par_rows[[0] * B].T  # the same for every member
        while True:
            with lock:
                b = next(counter, None)
            if b is None:
                return
            lo, hi = b * B, min(k, b * B + B)
            if hi - lo == B:
                idx = range(lo, hi)
                state[:] = Ynat[lo:hi].T
            else:
                idx = list(range(lo, hi)) + [lo] * (B - (hi - lo))  # pad the last batch with copies of its first
                state[:] = Ynat[idx].T
            ta.set_time(t0f)
            if npar and pars is not None:
                ta.pars[:] = par_rows[list(idx)].T
            if event_info:
                ta.reset_cooldowns()
            if simple:
                ta.propagate_until(t_end, max_steps=min(cap, CHUNK_STEPS))
                out = None
            else:
                out = ta.propagate_grid(grid, max_steps=cap)[-1]
                if lead:
                    out = out[1:]
            prs = ta.propagate_res
            nl = hi - lo
            outcomes = [prs[lane][0] for lane in range(nl)]
            mine = []
            if all(o == _TIME_LIMIT for o in outcomes):  # the common case, in bulk
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
                res.steps[lo:hi] = [prs[lane][3] for lane in range(nl)]
            elif not simple:
                # a grid run that one lane stopped: the lanes it interrupted run again as single runs
                for lane in range(nl):
                    i = lo + lane
                    kind = _outcome_kind(outcomes[lane], len(event_info))
                    if kind == "interrupted" and ta.time[lane] == t_end:
                        kind = "done"  # finished while the batch ran out of steps
                    if kind in ("interrupted", "non_finite"):
                        mine.append(i)
                        continue
                    _record_lane(res, i, lane, kind, ta, out, Ynat, tgrid, t0n, direction, simple, event_info,
                                 prs[lane][3], success_msg)
            else:
                mine = _continue_batch(ta, prs, idx, nl, res, lo, Ynat, tgrid, t0n, direction, event_info, cap,
                                       t_end, success_msg)
            with lock:
                handed.extend(mine)
                done[0] += hi - lo - len(mine)
                if progress is not None:
                    progress(done[0], k)

    if n_threads <= 1:
        work(0)
    else:
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            list(pool.map(work, range(n_threads)))
    return sorted(handed)


def _run_scalar(ta0, event_info, Ynat, pars, ps, prec, tgrid, t0n, direction, cap, n_threads, res, progress):
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
                kind = _outcome_kind(outcome, n_events)
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
            kind = _outcome_kind(outcome, n_events)
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
        ta = _borrow(ta0)
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
            _give_back(ta0, ta)

    if n_threads <= 1:
        work(0)
    else:
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            list(pool.map(work, range(n_threads)))
    return sorted(handed)


def _run_singles(single_run, systems, rows, t, opts, workers, progress, k, done0):
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


# -- Dask ------------------------------------------------------------------------------------------------------------
def _dask_client_class():
    try:
        from distributed import Client
    except ImportError as err:
        raise ImportError(
            "`client=` needs Dask distributed, which is not installed: pip install 'lieseries[distributed]'"
        ) from err
    return Client


def _chunk_task(system, rows, pars, t, t0, opts):
    """One Dask task: an ensemble of a chunk of members, run on the worker (its own integrator cache)."""
    return integrate_ensemble(system, rows, t, t0=t0, params=pars, workers=1, **opts)


#: Times Dask may rerun a chunk whose worker died (on another worker, or on the same one restarted by its nanny).
DASK_RETRIES = 2


def _dask_failure(err, what):
    """A RuntimeError naming `client`, saying what happened and what to do."""
    name = type(err).__name__
    if "Cancelled" in name or "KilledWorker" in name:
        cause = (f"a chunk was cancelled or its worker died ({name}: {err}) and could not be rerun "
                 f"({DASK_RETRIES} retries): with a single worker there is nowhere to rerun it")
        todo = "give the cluster more than one worker, or workers with nannies (processes=True) that restart them"
    else:
        cause = f"{name}: {err}"
        todo = "check that the cluster is running and reachable, or pass a new Client"
    return RuntimeError(f"`client`: the Dask run failed while {what} ({cause}); {todo}. Or leave `client` out to "
                        "run the members here.")


def _is_dask_error(err) -> bool:
    """An error of Dask's machinery (a cancelled future, a killed worker, a lost connection), not of the run."""
    import asyncio
    import concurrent.futures

    from distributed.comm.core import CommClosedError
    from distributed.scheduler import KilledWorker

    return isinstance(err, (concurrent.futures.CancelledError, asyncio.CancelledError, KilledWorker, CommClosedError,
                            OSError))


def _run_dask(client, system, Ynat, pars, t, t0, opts, chunk_size, progress, k):
    Client = _dask_client_class()
    if not isinstance(client, Client):
        raise TypeError(f"`client` must be a dask.distributed.Client; got {type(client).__name__}")
    status = str(getattr(client, "status", "running"))
    if status in ("closed", "closing", "failed"):
        raise RuntimeError(f"`client` is {status} (client.status = {status!r}): it can no longer send work to a "
                           "cluster. Create a new dask.distributed.Client (or call client.restart() before closing), "
                           "or leave `client` out to run the members here.")
    if chunk_size is None:
        try:
            threads = sum(client.nthreads().values())
        except Exception:  # pragma: no cover - scheduler unreachable: let submit raise the real error
            threads = 1
        B = _check_batch_size(opts.get("batch_size"))
        chunk_size = max(B, -(-k // max(1, 4 * threads)))
        chunk_size = -(-chunk_size // B) * B
    from distributed import as_completed

    start = _time.perf_counter()
    futures = {}
    # the system travels with every task (not scattered once): data scattered to a worker that dies is lost, and
    # every task depending on it would be cancelled; a task that carries its inputs can be rerun elsewhere
    try:
        for lo in range(0, k, chunk_size):
            hi = min(k, lo + chunk_size)
            p = None if pars is None else [list(r) for r in pars[lo:hi]]
            f = client.submit(_chunk_task, system, Ynat[lo:hi], p, t, t0, opts, pure=False, retries=DASK_RETRIES)
            futures[f] = lo
    except Exception as err:
        raise _dask_failure(err, "sending the chunks") from err
    parts = {}
    done = 0
    try:
        for f in as_completed(list(futures)):
            part = f.result()
            parts[futures[f]] = part
            done += len(part.status)
            if progress is not None:
                progress(done, k)
    except Exception as err:
        if not _is_dask_error(err):
            raise  # an error of the run itself (raised on the worker): as a local run would raise it
        raise _dask_failure(err, f"collecting the chunks ({done} of {k} members back)") from err
    ordered = [parts[lo] for lo in sorted(parts)]
    es = EnsembleSolution.concatenate(ordered)
    es.stats["run_time"] = _time.perf_counter() - start
    es.stats["workers"] = len(client.nthreads())
    es.stats["chunks"] = len(ordered)
    es.stats["chunk_size"] = chunk_size
    return es
