"""heyoka adapter: build (once) and run the adaptive Taylor integrator of a Poisson system, in any precision.

:func:`integrate` validates a call's arguments and hands it on. The jobs live in the package's modules:

- :mod:`~lieseries.taylor.plan`: the precision a call runs in, coarse-input warnings, budgets and chunk sizes, the
  memoised plan of a run (output grid, tolerance, compiled integrator);
- :mod:`~lieseries.taylor.call`: the memo of calls (:class:`~lieseries.taylor.call.Call`, keyed by
  :func:`~lieseries.taylor.call.call_key`): a repeated call goes straight to its run;
- :mod:`~lieseries.taylor.plain`: the fast path of a plain repeated call (its first chunk is one heyoka call);
- :mod:`~lieseries.taylor.general`: the general path on the driver loop, events, the energy guard, the Solution;
- :mod:`~lieseries.taylor.chunks`: the chunk engine (a chunk of heyoka steps per driver step, the probe and
  stiffness checks, the statuses and messages of a heyoka run);
- :mod:`~lieseries.taylor.dense`: ``sol(t)`` from heyoka's continuous output.
"""

from __future__ import annotations

import inspect
import time as _time

import numpy as np

from .. import cache
from ..atlas import run_atlas
from ..energy import clear_energy_cache
from ..events import resolve_events
from ..heyoka_build import build_integrator, integrator_count
from ..models.base import ExactState, Model, state_fractions
from ..poisson import as_poisson_system
from ..timegrid import warn_span_loss
from ..precision import (check_callable, check_count, check_flag, check_progress, check_seconds, check_tolerance,
                         infer_precision, to_fraction)
from .call import CALLS, DEFAULT_KEY_TAIL, KEY_SCALARS, Call, call_key
from .dense import DenseOutput  # noqa: F401 - pickles made before the split name it here
from .general import execute_general
from .plain import execute, execute_plain, plain_setup
from .plan import (
    DEFAULT_MAX_STEPS,
    FIRST_CHUNK,
    FIRST_CHUNK_REAL,
    STIFF_STEPS,
    make_plan,
    repeat_chunk,
    warn_cancelling_field,
    warn_coarse_inputs,
)

__all__ = ["integrate", "build_integrator", "clear_cache", "cache_info"]


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


def integrate(system, y0, t, **options):
    """One heyoka run of ``system`` from the state ``y0``: the single runs of :func:`lieseries.integrate`, whose
    docstring gives the options (this function takes all of them but the ensemble's: ``params``, ``workers``,
    ``client``, ``chunk_size``, ``batch_size``)."""
    if not options and type(y0) is ExactState and type(t) in KEY_SCALARS:
        # a repeated call with every option at its default, an exact state and a scalar time (the usual case):
        # keyed as call_key keys it, straight to the run on a hit (no options to bind, compare or key)
        call = CALLS.get((id(system), id(y0), t, type(t)) + DEFAULT_KEY_TAIL)
        if call is not None and call.system is system:
            return execute_plain(call) if call.plain else execute_general(call, None, None)
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
):
    """:func:`integrate` with its options bound (its signature)."""
    if progress is None and events is None and atlas is not True:
        # a repeated call (the same system, exact state and options as a memoised one): straight to the run. An
        # exact state and a scalar time are keyed here as call_key does (a function call less)
        ty = type(y0)
        if ty is ExactState and type(t) in KEY_SCALARS:
            options = (t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode, high_accuracy)
            types = tuple(map(type, options))
            key = (id(system), id(y0), t, type(t)) + options + types if KEY_SCALARS.issuperset(types) else None
        else:
            key = call_key(system, y0, t, t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode,
                           high_accuracy)
        call = CALLS.get(key) if key is not None else None
        if call is not None and call.system is system:
            return execute_plain(call) if call.plain else execute_general(call, None, None)
    progress = check_progress(progress, title="integrate")  # True: show a bar
    check_flag(compact_mode, "compact_mode")
    check_flag(high_accuracy, "high_accuracy", allow_none=False)
    key = call_key(system, y0, t, t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode,
                   high_accuracy) if events is None and progress is None and atlas is not True else None
    call = CALLS.get(key) if key is not None else None
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

            warn_coarse_inputs(ps, y0, [t, t0], prec.bits)
            return run_atlas(integrate, system, y0, t, t0=t0, bits=prec.bits, dense=dense, tol=tol,
                             energy_tol=check_tolerance(tol, prec),
                             precision=prec, max_steps=None if default_budget else max_steps, max_time=max_time,
                             min_step=min_step, compact_mode=compact_mode, high_accuracy=high_accuracy,
                             progress=progress, events=events)
        model = system if isinstance(system, Model) else None
        z0 = model.check_state(y0, "y0") if model is not None else state_fractions(y0, ps.dimension, "y0")
        warned = warn_coarse_inputs(ps, y0, [t, t0], prec.bits)
        cancels = warn_cancelling_field(ps, [z0], prec.bits)
        warned = cancels or warned
        call = _new_call(system, ps, prec, y0, z0, t, t0, tol, events, dense, compact_mode, high_accuracy,
                         max_steps=max_steps, stiff_steps=min(max_steps, STIFF_STEPS) if default_budget else max_steps,
                         max_time=max_time, min_step=min_step)
        call.end_check = not cancels
        plan = call.plan
        warned = warn_span_loss(plan["span_loss"], plan["grid"], plan["t0f"], prec.bits,
                                f"the run's times are {prec.name} numbers") or warned
        if key is not None and not warned:
            CALLS.put(key, call)
    return execute(call, progress)


def _new_call(system, ps, prec, y0, z0, t, t0, tol, events, dense, compact_mode, high_accuracy, *, max_steps,
              stiff_steps, max_time, min_step):
    """A new :class:`~lieseries.taylor.call.Call` of checked arguments (``z0``: the exact state, the budgets
    checked), with its plan and its plain path set up."""
    user_events = resolve_events(events, system, ps, prec.bits)
    tic = _time.perf_counter()
    plan = make_plan(system, ps, prec, tol, t, t0, compact_mode, high_accuracy, user_events, max_time)
    # the grid's conversion (a memoised plan's took place before: the time make_plan took bounds it) is part of
    # the first run's wall-time budget
    converted = min(plan["convert_seconds"], _time.perf_counter() - tic)
    call = Call(
        system=system, y0=y0, ps=ps, prec=prec, plan=plan, user_events=user_events,
        y0_native=y0.native(prec) if type(y0) is ExactState else prec.array(z0, "y0"),
        pars_native=ps.native_parameters(prec) if ps.parameter_values else None,
        max_steps=max_steps, stiff_steps=stiff_steps, max_time=max_time, min_step=min_step, dense=dense,
        dtype=prec.numpy_dtype, first_chunk=FIRST_CHUNK.get(prec.name, FIRST_CHUNK_REAL),
    )
    call.convert_seconds = converted
    call.repeat_chunk = repeat_chunk(prec, plan["build"][0], call.first_chunk)
    plain_setup(call)
    return call


integrate.__signature__ = inspect.signature(_integrate)  # help() and introspection see the options
_integrate.__qualname__ = "integrate"  # and a misspelt option is reported against integrate
