"""The memo of :func:`lieseries.taylor.integrate`'s calls: a :class:`Call` holds everything about a call that
depends only on its validated arguments, kept for repeated calls with the same system, exact state (or float64
array), times and options (:func:`call_key`); a hit is one dict lookup."""

from __future__ import annotations

import numpy as np

from .. import cache
from ..models.base import ExactState


class Call:
    """Everything about a call of :func:`lieseries.taylor.integrate` that depends only on its (validated)
    arguments: computed once and memoised for repeated calls with the same system, exact state and options (see
    :func:`call_key`)."""

    __slots__ = ("system", "y0", "ps", "prec", "plan", "user_events", "y0_native", "pars_native", "max_steps",
                 "stiff_steps", "max_time", "min_step", "dense", "energy", "dtype", "first_chunk", "plain", "t_out",
                 "t_requested", "t0_native", "t_end_native", "budget", "free", "repeat_chunk", "grid", "sqrt_tol",
                 "reached", "t_exact", "views", "quick", "report", "events", "head", "passed", "first_h",
                 "first_known", "convert_seconds", "end_check")

    def __init__(self, **kw):
        self.energy = None  # (compiled H, parameters, H(y0)) once a run needs the energy check
        self.plain = False
        # a bound on the first step, in the run's format (heyoka_build.sparse_first_step), known once a run has read
        # the series at y0 from its first step (taylor.chunks)
        self.first_h = None
        self.first_known = False
        self.quick = None  # the plain path's energy check (quick_energy), made on its first run
        self.passed = None  # (end state's bytes, steps) of its last double run that passed the energy check
        self.report = None  # (build time, cached) its next run reports, once known (next_report)
        self.convert_seconds = 0.0  # the grid's conversion, counted by the first run's max_time
        # a run no energy check guards checks its field's cancellation at its end state, unless y0's check warned
        self.end_check = True
        self.views = (None, None, None)  # (integrator, its state's view, its parameters' view) of the last plain run
        for k, v in kw.items():
            setattr(self, k, v)


#: Memoised calls (:class:`Call`) of :func:`lieseries.taylor.integrate`; a hit is one dict lookup (``CALLS.get``).
CALLS = cache.region("taylor.calls", 256)
KEY_SCALARS = frozenset((type(None), int, float, str, bool))
#: (t0, tol, precision, dense, max_steps, max_time, min_step, compact_mode, high_accuracy) at their defaults
_DEFAULT_OPTIONS = (0, None, None, False, None, None, None, None, False)
DEFAULT_KEY_TAIL = _DEFAULT_OPTIONS + tuple(map(type, _DEFAULT_OPTIONS))


def call_key(system, y0, t, *options):
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
    elif type(t) not in KEY_SCALARS:
        return None
    types = tuple(map(type, options))
    if not KEY_SCALARS.issuperset(types):
        return None
    # the types too: 1 == True == 1.0, and a fresh call refuses some of them (`high_accuracy=1`, `t=True`)
    return (id(system), ykey, t, type(t)) + options + types


def next_report(call) -> tuple:
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


def succeeded(call) -> None:
    """The call succeeded: when it is repeated, its first chunk is the longer one
    (:data:`lieseries.taylor.plan.REPEAT_CHUNK`)."""
    call.first_chunk = max(call.first_chunk, call.repeat_chunk)
    call.budget = min(call.first_chunk, call.max_steps)
