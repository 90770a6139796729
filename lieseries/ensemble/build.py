"""The compiled integrators of an ensemble: heyoka's batch integrator (double) and the scalar one (long double,
quad), from the shared cache (:mod:`lieseries.cache`, region ``"ensemble.integrators"``)."""

from __future__ import annotations

import numbers
import threading
import time as _time

import heyoka as hy
import numpy as np

from .. import cache
from ..expr import expressions_digest
from ..heyoka_build import compact_by_default
from ..models.base import Model
from ..poisson import as_poisson_system
from ..precision import check_flag, check_tolerance, resolve_precision

__all__ = ["build_batch_integrator", "build_scalar_integrator", "clear_batch_cache", "check_batch_size",
           "MAX_BATCH_SIZE"]

#: The most SIMD lanes per batch: heyoka compiles one function of ``batch_size`` lanes, and its compilation time
#: grows fast with the lanes (rigid body: 9 s at 8, 29 s at 16, 79 s at 64) while lanes beyond the CPU's SIMD width
#: (``heyoka.recommended_simd_size()``, 2 to 8) bring no speed.
MAX_BATCH_SIZE = 16

#: (integrator, event info) by (structure, precision, tolerance, events, batch size, compact mode, high accuracy);
#: an evicted integrator takes its pooled copies with it.
INTEGRATORS = cache.region("ensemble.integrators", 16, on_evict=lambda entry: cache.drop_template(entry[0]))


_BUILD_LOCK = threading.Lock()


def clear_batch_cache() -> None:
    """Forget every cached batch and scalar ensemble integrator (of this process) and their pooled copies."""
    INTEGRATORS.clear()


def check_batch_size(batch_size) -> int:
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
    B = check_batch_size(batch_size)
    check_flag(compact_mode, "compact_mode")
    evs = system.events() if isinstance(system, Model) else []
    n = ps.dimension
    if compact_mode is None:
        compact_mode = compact_by_default(system, prec)
    key = (ps.key, prec.name, tolf, expressions_digest([e[0] for e in evs]), B, bool(compact_mode),
           bool(high_accuracy))

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
    key = ("scalar", ps.key, prec.name, tolf, expressions_digest([e[0] for e in evs]), bool(compact_mode),
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
    """(integrator, build time, event info) from the cache, built by ``make()`` on a miss (one build at a time:
    threads that miss together wait for the first one's integrator rather than compile it again)."""
    hit = INTEGRATORS.get(key)
    if hit is None:
        with _BUILD_LOCK:
            hit = INTEGRATORS.get(key)
            if hit is None:
                start = _time.perf_counter()
                ta = make()
                build = _time.perf_counter() - start
                cache.add_template(ta)
                entry = INTEGRATORS.put(key, (ta, [(e[1], e[2]) for e in evs]), cost=build)
                return entry[0], build, entry[1]
    INTEGRATORS.touch(key)
    return hit[0], 0.0, hit[1]
