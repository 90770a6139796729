"""What a call of :func:`lieseries.taylor.integrate` fixes before it runs: the precision it runs in, the warnings
about coarse inputs, the budgets and chunk sizes, and the plan of a run (output grid, tolerance, the compiled
integrator's cache entry), memoised for its hashable arguments.

Caching
-------
Compiling a heyoka integrator (LLVM) costs milliseconds to seconds; running a short orbit costs microseconds.
Integrators are therefore cached by (system structure, precision, tolerance, events, options)
(:mod:`lieseries.heyoka_build`). Model parameters are heyoka runtime parameters, so two bodies with different
inertia share one compiled integrator; only the parameter values are set per run.
"""

from __future__ import annotations

import math
import time
import warnings
from fractions import Fraction

import heyoka as hy
import numpy as np

from .. import cache
from ..driver import run_message
from ..energy import guard_tolerance
from ..expr import rounding
from ..caller import stacklevel
from ..heyoka_build import build_integrator
from ..precision import (
    PrecisionWarning,
    Precision,
    check_tolerance,
    data_bits,
    to_fraction,
    warn_if_coarse,
)
from ..timegrid import parse_times, span_loss

#: The default step budget (``max_steps``).
DEFAULT_MAX_STEPS = 50_000_000
#: With the default budget, a stiff run (:mod:`lieseries.taylor.chunks`) is stopped once it would need more steps
#: than this.
STIFF_STEPS = 100_000
#: A step that changes no component by more than this fraction of its size (:mod:`lieseries.taylor.chunks`) is
#: stability-limited: an accuracy-limited step of order ~20 at tol = eps moves the state by ~15% of its time scale.
STIFF_CHANGE = 1e-2


#: Steps in the first chunk of a run, by precision (later chunks grow fourfold, up to about CHUNK_SECONDS of work
#: each, down to one step where a step takes longer): a step of the rigid body costs ~2 us in double and ~0.3 s at
#: 1024 bits. heyoka cannot stop inside a step: ``max_time`` is read between chunks, so that a run overruns it by
#: at most about one step beyond CHUNK_SECONDS.
FIRST_CHUNK = {"double": 64, "long double": 32, "quad": 8}
FIRST_CHUNK_REAL = 1
CHUNK_SECONDS = 0.1
#: The first chunk in double of a call repeated after it succeeded (the same system, exact state and options: the
#: same steps again): a run of up to 1024 steps is then one heyoka call (a few ms for the rigid body). A larger
#: system gets fewer, about REPEAT_CHUNK_WORK / D steps for a decomposition of D nodes (the rigid body's has 81),
#: and never fewer than the first chunk of a new call. A new call keeps the short first chunk, so that a run
#: that collapses or overflows is seen between chunks early (what its status and message say).
REPEAT_CHUNK = 1024
REPEAT_CHUNK_WORK = 200_000


def repeat_chunk(prec, template, first: int) -> int:
    if prec.name != "double":
        return first
    return max(first, min(REPEAT_CHUNK, REPEAT_CHUNK_WORK // max(len(template.decomposition), 1)))


_PLANS = cache.region("taylor.plans", 256)


def make_plan(system, ps, prec, tol, t, t0, compact_mode, high_accuracy, user_events=(), max_time=None):
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
    tic = time.perf_counter()
    grid, direction, t0f = parse_times(t, t0, max_time=max_time, values_per_time=ps.dimension,
                                       bytes_per_value=48 + prec.bits // 8 if prec.is_real
                                       else np.dtype(prec.numpy_dtype).itemsize)
    tolf = check_tolerance(tol, prec)
    grid_native = [prec.time(g) for g in grid]
    grid_exact, t0_native = [to_fraction(g) for g in grid_native], prec.time(t0f)
    converted = time.perf_counter() - tic  # (the grid's conversion: counted by the run's max_time)
    plan = dict(
        convert_seconds=converted,
        grid=grid, direction=direction, t0f=t0f, tolf=tolf, grid_native=grid_native,
        grid_exact=grid_exact, t0_native=t0_native,
        span_loss=span_loss(grid, t0f, grid_exact, to_fraction(t0_native)),
        reached=run_message("success", t=grid_native[-1]),
        tol_float=float(tolf), sqrt_tol=math.sqrt(float(guard_tolerance(ps, tolf, prec.bits))),
        build=build_integrator(system, prec, tolf, user_events=user_events, compact_mode=compact_mode,
                               high_accuracy=high_accuracy),
    )
    if key is not None:
        _PLANS.put(key, (system, plan))
    return plan


def warn_coarse_inputs(ps, y0, times, work_bits: int) -> bool:
    """One :class:`~lieseries.precision.PrecisionWarning` per input that carries fewer bits than the run uses
    (``times`` is ``(t, t0)``, each named on its own). True when there was one."""
    t, t0 = times
    narrow = any(isinstance(v, (np.ndarray, np.generic)) and v.dtype in (np.float16, np.float32) for v in times)
    if work_bits <= 53 and data_bits(y0) is None and not narrow:  # (a float32 t carries 24 bits in double too)
        return False
    coarse = [(data_bits(y0), "y0"), (data_bits(t), "t"), (data_bits(t0), "t0")]
    if work_bits > 53:
        coarse += [(bits, name) for name, bits in ps.coarse_data().items()]
    coarse = [(bits, name) for bits, name in coarse if bits is not None and bits < work_bits]
    for bits, name in coarse:
        warn_if_coarse(bits, work_bits, name)
    return bool(coarse)


#: Bits a state's rate may lose to the vector field's own roundings at y0 (the bound of
#: :func:`lieseries.expr.rounding.lost_bits`, or :func:`lieseries.lie.fixed.cancelling_bits` where floats cannot
#: take it; up to ~14 bits above what is lost) before a run warns
CANCELLING_BITS = 32


def warn_cancelling_field(ps, rows, work_bits: int, pars=None, members=None, where: str = "`y0`") -> bool:
    """A :class:`~lieseries.precision.PrecisionWarning` when, rounded to ``work_bits`` as heyoka rounds, the vector
    field's expression cancels far below its terms (:data:`CANCELLING_BITS`) at one of the exact states ``rows``
    (a single run's ``y0``, or an ensemble's members when ``members`` gives their indices, one per row: ``pars``
    their parameter rows, or None for the system's own), one warning naming those
    it concerns (``where`` names the states: the end state(s) of a run that no energy check guards, whose field may
    come to cancel only on the way); True when there was one. The bound is taken in floats (a
    generated function per program, ~25 us a state, ~3-4 ms for 4096 at once); where a value leaves a float's range,
    by the Lie engine's fixed-point jets (which compile the field once per system, ~0.7 s for a heavy top's
    intermediate form)."""
    from ..lie.fixed import cancelling_bits

    own = list(ps.parameter_values)
    # the bound in floats, each operation rounded relative to its value as heyoka's are; the fixed-point jets' where
    # floats cannot hold it (a value beyond their range, a singular derivative)
    got = rounding.lost_bits(ps.written_program, rows, own if pars is None else pars, work_bits)
    lost = [(i, b if b is not None else cancelling_bits(ps.program, list(r), own if pars is None else list(pars[i]),
                                                        work_bits))
            for i, (r, b) in enumerate(zip(rows, got))]
    lost = [(i, b) for i, b in lost if b > CANCELLING_BITS]
    if not lost:
        return False
    worst = max(b for _, b in lost)
    if members is not None:
        name = "`Y0[{}]`" if where == "`y0`" else "{}"
        shown = ", ".join(name.format(members[i]) for i, _ in lost[:6]) + (", ..." if len(lost) > 6 else "")
        at = (f"{shown} ({len(lost)} of the {len(rows)} members)" if where == "`y0`"
              else f"{where} of the members {shown} ({len(lost)} of the {len(rows)} checked)")
    else:
        at = where
    warnings.warn(PrecisionWarning(
        f"the vector field's expression cancels at {at}: rounded to {work_bits} bits, as heyoka computes it, its "
        f"terms may leave a state's rate off by up to 2^{worst - work_bits} of the state per unit time (a bound; "
        f"{worst} of the {work_bits} bits) -- heyoka's arithmetic cannot hold more, and the run's error estimate "
        "does not see it. `lie_integrate` evaluates such a field at the bits it needs; or write the expression "
        "without the terms that cancel."), stacklevel=stacklevel())
    return True


def time_array(natives, prec: Precision) -> np.ndarray:
    if prec.is_real:
        out = np.empty(len(natives), dtype=hy.real)
        for i, v in enumerate(natives):
            out[i] = v
        return out
    return np.array(natives, dtype=prec.numpy_dtype)
