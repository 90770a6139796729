"""The one registry of integration methods and their adapters: each method is run from a specification dict and
gives one :class:`RunRecord` (the one record of a run, used by studies, scenes and reports; ``MethodRun``,
``RunRow`` and ``WorkPrecisionRow`` are its other names).

Each method is a :class:`Method` (its scene fields, label, precision, setting, digits, run, atlas run and quick-mode
scaling) registered with :func:`register_method`; scenes, studies and the scene runner read the registry, so a new
method is one :class:`Method` and one registration.

Methods
-------
``{"method": "taylor", "precision": P, "tol": T}``
    heyoka's adaptive Taylor method through :func:`lieseries.integrate`, P = "double" | "long double" | "quad" |
    int bits; T a tolerance (default: the precision's epsilon).
``{"method": "lie", "dps": D, "tol": T, "order": N}``
    the Lie-series integrator :func:`lieseries.lie_integrate` (mpmath); ``tol`` and ``order`` optional.
``{"method": "scipy", "rtol": R, "atol": A}``
    scipy's ``solve_ivp(method="DOP853")`` on a right-hand side compiled from the system's heyoka vector field
    with ``heyoka.cfunc`` (parameters in double). ``atol`` defaults to ``rtol``.
``{"method": "validated", "dps": D, "order": N}``
    certified enclosures in Arb ball arithmetic, :func:`lieseries.validated_integrate`: the states are the balls'
    midpoints (as mpf) and ``extra`` holds ``certified_digits`` (at each output time) and ``max_radius``; the
    enclosures provably contain the exact solution, which the run's error against the reference confirms.
``{"method": "mpmath", "dps": D, "t_max": S}``
    ``mpmath.odefun`` (a Taylor method in pure mpmath) on a pure-mpmath right-hand side. It is slow: the run is
    capped at ``|t| <= t_max`` (default 2) and its error is measured at the time it reached.

Any of ``tol``, ``rtol``, ``dps`` (and ``precision``) may be a list in :func:`expand_methods`: one run per value.

Timing: ``run_time`` is the wall time of the call, best of ``repeat`` (repeats stop once a method has used two
seconds); heyoka's compile time (and the scipy right-hand side's) is kept apart in ``build_time``. Times are
measured in this one run on a shared machine: compare them with each other, not with other runs.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from typing import Callable

from . import fields as F
from .poisson import as_poisson_system
from .models.base import state_fractions
from .precision import (bits_to_dps, data_bits, dps_to_bits, export_mpf, mp_context, resolve_precision,
                        to_fraction, warn_if_coarse)
from .precision import thread_mp as mp

__all__ = [
    "METHODS",
    "Method",
    "MethodRun",
    "RunRecord",
    "register_method",
    "unregister_method",
    "scene_methods",
    "method_plugin",
    "methods_registry",
    "best_of",
    "clear_rhs_cache",
    "default_methods",
    "expand_methods",
    "method_label",
    "normalize_method",
    "precision_name",
    "reference_dps",
    "run_method",
    "setting",
]

#: Keys that may be lists in :func:`work_precision` (one run per value).
LIST_KEYS = ("precision", "tol", "rtol", "dps")

#: Repeats of a run stop once it has used this many seconds in total.
REPEAT_BUDGET = 2.0


@dataclass
class RunRecord:
    """One run of one method with one setting, and what it is measured to be (the one run record).

    Attributes
    ----------
    method : str                 "taylor", "lie", "scipy", "mpmath", "validated" (a registered method's name)
    label : str                  e.g. "heyoka double", "scipy DOP853"
    precision : str              "double", "quad", "real256", "30 dps", ...
    setting : str                e.g. "tol=1e-12", "rtol=1e-10", "dps=30"
    t : float                    the time the run reached
    t_requested : float          the final time asked for (mpmath runs are capped)
    t_exact : Fraction           ``t`` exactly
    times : list of float        output times reached
    states : list                the state at each output time, in the run's own number type
    steps, nfev, order : int or None
    build_time : float or None   compile time (heyoka integrator, or the scipy right-hand side)
    run_time : float             wall time of the call without the build, best of the repeats
    core_time : float or None    heyoka's own propagation time (Taylor runs)
    status : str                 "success", a heyoka/Lie status, "failed", "skipped" or "error"
    message : str
    extra : dict                 method-specific figures (validated runs: certified digits, widest radius)

    Measured (filled in by :meth:`measured`, which keeps only the final state):

    model : str                  the model's label in a scene ("" elsewhere)
    error : float or None        max-abs error of the final state against the reference
    max_error : float or None    the largest over the output times (a scene's trajectory)
    scaled_error : float or None the final error relative to the natural scale of each quantity
    drift : dict                 invariant -> max |I(t) - I(0)| over the output times
    final_state : list or None   the final state as floats
    """

    method: str
    label: str
    precision: str
    setting: str
    t: float
    t_requested: float
    t_exact: Fraction | None = None
    times: list = field(default_factory=list)
    states: list = field(default_factory=list)
    steps: int | None = None
    nfev: int | None = None
    order: int | None = None
    build_time: float | None = None
    run_time: float | None = None
    core_time: float | None = None
    status: str = "success"
    message: str = ""
    extra: dict = field(default_factory=dict)
    model: str = ""
    error: float | None = None
    max_error: float | None = None
    scaled_error: float | None = None
    drift: dict = field(default_factory=dict)
    final_state: list | None = None

    @property
    def y_final(self):
        return self.states[-1] if self.states else None

    @property
    def ok(self) -> bool:
        return bool(self.states)

    @property
    def max_drift(self) -> float | None:
        vals = [v for v in self.drift.values() if v is not None]
        return max(vals) if vals else None

    def measured(self, **figures) -> "RunRecord":
        """A copy with the measured ``figures`` (error, drift, ...) set, the final state as floats, and only the
        final state kept of the run's states."""
        from dataclasses import replace

        final = self.y_final
        out = replace(self, times=self.times[-1:], states=self.states[-1:], **figures)
        if "final_state" not in figures:
            out.final_state = [float(to_fraction(v)) for v in final] if final is not None else None
        return out

    def to_dict(self) -> dict:
        return {
            "model": self.model, "method": self.method, "label": self.label, "precision": self.precision,
            "setting": self.setting, "t": self.t, "t_requested": self.t_requested, "error": self.error,
            "max_error": self.max_error, "drift": dict(self.drift), "max_drift": self.max_drift, "steps": self.steps,
            "nfev": self.nfev, "order": self.order, "build_time": self.build_time, "run_time": self.run_time,
            "status": self.status, "message": self.message, "scaled_error": self.scaled_error,
            "extra": dict(self.extra),
        }


#: The earlier names of the run record.
MethodRun = RunRecord


def _fmt_num(v) -> str:
    if v is None:
        return "default"
    if isinstance(v, str):
        return v
    if isinstance(v, int):
        return str(v)
    return f"{float(v):.3g}"


def normalize_method(spec, where: str = "method") -> dict:
    """Check a method specification and fill in its defaults.

    Raises
    ------
    ValueError
        Naming ``where`` and the offending key.
    """
    if not isinstance(spec, dict):
        raise ValueError(f"`{where}` must be a table such as {{method = \"taylor\", precision = \"double\"}}; "
                         f"got {spec!r}")
    name = spec.get("method")
    if name not in _METHODS:
        raise ValueError(f"`{where}.method` must be one of {sorted(_METHODS)}; got {name!r}")
    defaults = _METHODS[name].defaults
    known = set(defaults) | {"method", "label"}
    for k in spec:
        if k not in known:
            raise ValueError(f"unknown field `{where}.{k}` for method {name!r}; known: {sorted(known)}")
    out = dict(defaults)
    out.update(spec)
    return out


def expand_methods(methods, where: str = "methods") -> list:
    """Normalised specifications, one per setting (list-valued keys expanded)."""
    if isinstance(methods, dict) or not hasattr(methods, "__iter__"):
        raise ValueError(f"`{where}` must be a list of method tables; got {methods!r}")
    out = []
    for i, spec in enumerate(methods):
        s = normalize_method(spec, f"{where}[{i}]")
        runs = [s]
        for key in _METHODS[s["method"]].list_keys:
            if isinstance(s.get(key), (list, tuple)):
                runs = [dict(r, **{key: v}) for r in runs for v in s[key]]
        out.extend(runs)
    return out


def method_label(spec: dict) -> str:
    """A short label for a method: "heyoka double", "Lie series 30 dps", "scipy DOP853", "mpmath odefun 15 dps"."""
    if spec.get("label"):
        return str(spec["label"])
    return _METHODS[spec["method"]].label(spec)


def default_methods(quick: bool = False) -> list:
    """A default set of methods and settings for :func:`work_precision`."""
    if quick:
        return [
            {"method": "taylor", "precision": "double", "tol": [1e-6, 1e-10, 1e-14]},
            {"method": "taylor", "precision": "quad", "tol": [1e-16, 1e-28]},
            {"method": "scipy", "rtol": [1e-6, 1e-10]},
            {"method": "lie", "dps": 30, "tol": [1e-20]},
        ]
    return [
        {"method": "taylor", "precision": "double", "tol": [1e-6, 1e-8, 1e-10, 1e-12, 1e-14, 2.0**-52]},
        {"method": "taylor", "precision": "long double", "tol": [1e-10, 1e-14, 1e-18]},
        {"method": "taylor", "precision": "quad", "tol": [1e-12, 1e-18, 1e-24, 1e-30, 2.0**-112]},
        {"method": "scipy", "rtol": [1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 1e-13]},
        {"method": "lie", "dps": 30, "tol": [1e-10, 1e-20, 1e-28]},
        {"method": "mpmath", "dps": [15, 25], "t_max": 1.0},
    ]


# -- compiled right-hand sides (cached per system structure) ---------------------------------------------------
_RHS_CACHE: dict = {}


def clear_rhs_cache() -> None:
    """Forget the compiled right-hand sides of the scipy and mpmath methods."""
    _RHS_CACHE.clear()


def _scipy_rhs(system):
    """(rhs(t, y) -> ndarray, build_time, cached) from heyoka's cfunc of the vector field, in double."""
    import heyoka as hy

    ps = as_poisson_system(system)
    key = ("cfunc", ps.key, tuple(ps.parameter_values))
    hit = _RHS_CACHE.get(key)
    if hit is not None:
        return hit, 0.0
    field_ = ps.vector_field
    used = hy.get_params(field_)
    npar = 1 + max((int(str(p)[1:]) for p in used), default=-1)
    pars = np.array([float(v) for v in ps.parameter_values[:npar]], dtype=float)
    t0 = _time.perf_counter()
    cf = hy.cfunc(field_, vars=ps.variables)
    build = _time.perf_counter() - t0
    if npar:
        def rhs(t, y, _cf=cf, _p=pars):
            return _cf(y, pars=_p)
    else:
        def rhs(t, y, _cf=cf):
            return _cf(y)
    _RHS_CACHE[key] = rhs
    return rhs, build


def _mpmath_rhs(system):
    """F(values, pars) -> list of mpf at this thread's current mpmath precision (:func:`mp_context`)."""
    ps = as_poisson_system(system)
    key = ("mpmath", ps.key)
    hit = _RHS_CACHE.get(key)
    if hit is not None:
        return hit
    from .expr import compile_expressions  # the engine's own mpmath evaluator

    prog = compile_expressions(ps.variables, ps.vector_field, len(ps.parameter_values))

    def fn(values, pars, _prog=prog):
        ctx = mp_context()
        return list(_prog.evaluate(values, pars, ctx.dps, ctx=ctx))

    _RHS_CACHE[key] = fn
    return fn


# -- running one method ----------------------------------------------------------------------------------------
def best_of(call, repeat: int):
    """Run ``call()`` up to ``repeat`` times (stopping once REPEAT_BUDGET seconds are used); the first result
    and the per-call wall times."""
    times, first = [], None
    spent = 0.0
    for i in range(max(1, int(repeat))):
        t0 = _time.perf_counter()
        res = call()
        dt = _time.perf_counter() - t0
        times.append(dt)
        if i == 0:
            first = res
        spent += dt
        if spent > REPEAT_BUDGET:
            break
    return first, times


def _grid(t, times):
    tf = to_fraction(t, "t")
    if times is None:
        return tf, None
    grid = [to_fraction(v, "times") for v in times]
    return tf, grid


def run_method(system, y0, t, spec: dict, *, times=None, repeat: int = 1) -> RunRecord:
    """Run one method (a normalised specification, see :func:`normalize_method`) from ``y0`` to ``t``.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Initial state; its exact value is rounded once to each method's precision.
    t : number
        Final time.
    spec : dict
        One method with scalar settings.
    times : sequence of numbers, optional
        Output times (increasing, ending at ``t``); default: only ``t``.
    repeat : int
        Best-of repeats for the timing.

    Returns
    -------
    RunRecord
        With ``status = "error"`` (and the exception text) when the method raised, ``"skipped"`` when it is not
        available.
    """
    spec = normalize_method(spec)
    m = spec["method"]
    tf, grid = _grid(t, times)
    label = method_label(spec)
    try:
        return _METHODS[m].run(system, y0, tf, grid, spec, label, repeat)
    except Exception as err:  # a failing method is a row of the study, not the end of it
        return RunRecord(m, label, precision_name(spec), setting(spec), float(tf), float(tf), status="error",
                         message=f"{type(err).__name__}: {err}")


def precision_name(spec) -> str:
    """The name of a method's working precision ("double", "quad", "30 dps", ...)."""
    return _METHODS[spec["method"]].precision(spec)


def setting(spec) -> str:
    """A method's settings in one line ("tol=1e-12", "dps=30, order=20")."""
    return _METHODS[spec["method"]].setting(spec)


def _rows_with_reached(sol):
    """Output times and states of a Solution, with the state where a run that stopped early ended."""
    times = [to_fraction(v) for v in sol.t]
    states = list(sol.y)
    reached = to_fraction(sol.t_reached) if sol.t_reached is not None else None
    if reached is not None and sol.y_reached is not None and (not times or times[-1] != reached):
        times.append(reached)
        states.append(sol.y_reached)
    return times, states


def _run_taylor(system, y0, tf, grid, spec, label, repeat):
    from .taylor import integrate

    prec = resolve_precision(spec["precision"])
    tol = spec["tol"]
    t_arg = grid if grid is not None else tf
    sol, walls = best_of(lambda: integrate(system, y0, t=t_arg, tol=tol, precision=prec), repeat)
    build = sol.stats.build_time
    # the first call includes the build (unless the integrator was cached): take it out of the run time
    run_times = [walls[0] - build] + walls[1:]
    times, states = _rows_with_reached(sol)
    return RunRecord(
        "taylor", label, prec.name, setting(spec), float(times[-1]), float(tf), t_exact=times[-1],
        times=[float(v) for v in times], states=states, steps=int(sol.stats.steps), nfev=None,
        order=int(sol.stats.order), build_time=float(build), run_time=float(min(run_times)),
        core_time=float(sol.stats.run_time), status=sol.status, message=sol.message,
    )


def _run_scipy(system, y0, tf, grid, spec, label, repeat):
    from scipy.integrate import solve_ivp

    ps = as_poisson_system(system)
    rhs, build = _scipy_rhs(system)
    y0f = resolve_precision("double").array([to_fraction(v, "y0") for v in np.asarray(y0, dtype=object)])
    y0f = np.asarray(y0f, dtype=float)
    if len(y0f) != ps.dimension:
        raise ValueError(f"`y0` must have {ps.dimension} entries; got {len(y0f)}")
    rtol = float(spec["rtol"])
    atol = rtol if spec["atol"] is None else float(spec["atol"])
    t_eval = None if grid is None else np.array([float(v) for v in grid])
    span = (0.0, float(tf))
    res, walls = best_of(
        lambda: solve_ivp(rhs, span, y0f, method="DOP853", rtol=rtol, atol=atol, t_eval=t_eval), repeat
    )
    ok = res.status == 0
    states = [res.y[:, k].copy() for k in range(res.y.shape[1])]
    times = [float(v) for v in res.t]
    return RunRecord(
        "scipy", label, "double", setting(spec), times[-1] if times else 0.0, float(tf),
        t_exact=tf if ok else (to_fraction(times[-1]) if times else Fraction(0)), times=times,
        states=states, steps=None if t_eval is not None else int(len(res.t) - 1), nfev=int(res.nfev), order=8,
        build_time=float(build), run_time=float(min(walls)), status="success" if ok else "failed",
        message=str(res.message),
    )


def _run_lie(system, y0, tf, grid, spec, label, repeat):
    from .lie.integrator import lie_integrate

    kwargs = _lie_kwargs(spec)
    t_arg = grid if grid is not None else tf
    sol, walls = best_of(lambda: lie_integrate(system, y0, t_arg, **kwargs), repeat)
    st = sol.stats
    times, states = _rows_with_reached(sol)
    return RunRecord(
        "lie", label, precision_name(spec), setting(spec), float(times[-1]), float(tf), t_exact=times[-1],
        times=[float(v) for v in times], states=states, steps=int(st.steps), nfev=None,
        order=int(st.order) if st.order else None, build_time=None, run_time=float(min(walls)),
        core_time=float(st.run_time) if st.run_time else None, status=sol.status, message=sol.message,
    )


def _run_validated(system, y0, tf, grid, spec, label, repeat):
    from .validated import certified_digits, midpoints, validated_integrate

    kwargs = {"dps": int(spec["dps"])}
    if spec.get("order") is not None:
        kwargs["order"] = int(spec["order"])
    t_arg = grid if grid is not None else tf
    sol, walls = best_of(lambda: validated_integrate(system, y0, t_arg, **kwargs), repeat)
    times = [to_fraction(v) for v in sol.t]
    states = [list(row) for row in midpoints(sol, as_mpf=True)]
    digits = [float(d) for d in certified_digits(sol)] if len(sol.y) else []
    return RunRecord(
        "validated", label, precision_name(spec), setting(spec), float(times[-1]) if times else 0.0, float(tf),
        t_exact=times[-1] if times else None, times=[float(v) for v in times], states=states,
        steps=int(sol.stats.steps), order=int(sol.stats.order), build_time=None, run_time=float(min(walls)),
        core_time=float(sol.stats.run_time), status=sol.status, message=sol.message,
        extra={"certified_digits": digits, "max_radius": float(sol.stats.extra.get("max_width", 0.0))},
    )


def _run_mpmath(system, y0, tf, grid, spec, label, repeat):
    ps = as_poisson_system(system)
    dps = int(spec["dps"])
    t_max = to_fraction(spec["t_max"], "t_max")
    t_run = tf if abs(tf) <= t_max else (t_max if tf > 0 else -t_max)
    fn = _mpmath_rhs(system)
    # the exact values of a model state (its float entries are roundings: 0.2 as a double cost 1e-17 here)
    y0q = state_fractions(y0, ps.dimension, "y0")
    warn_if_coarse(data_bits(y0), dps_to_bits(dps), "y0")
    out_times = [t_run] if grid is None else [g for g in grid if abs(g) <= abs(t_run)]
    if not out_times or out_times[-1] != t_run:
        out_times.append(t_run)
    counter = [0]

    def call():
        with mp.workdps(dps):
            pv = [mp.mpf(q.numerator) / q.denominator for q in ps.parameter_values]
            z0 = [mp.mpf(q.numerator) / q.denominator for q in y0q]

            def F(x, y):
                counter[0] += 1
                return fn(y, pv)

            f = mp.odefun(F, 0, z0)
            return export_mpf([[+v for v in f(mp.mpf(q.numerator) / q.denominator)] for q in out_times])

    states, walls = best_of(call, repeat)
    nfev = counter[0] // max(1, len(walls))
    capped = t_run != tf
    msg = (f"capped at t = {float(t_run):g} (t_max = {float(t_max):g}; mpmath.odefun is slow)" if capped
           else f"Reached t = {float(tf):g}.")
    return RunRecord(
        "mpmath", label, f"{dps} dps", setting(spec), float(t_run), float(tf), t_exact=t_run,
        times=[float(v) for v in out_times], states=states, steps=None, nfev=nfev, order=None, build_time=None,
        run_time=float(min(walls)), status="success", message=msg,
    )


# -- the study ------------------------------------------------------------------------------------------------
def _digits_needed(spec) -> int:
    return _METHODS[spec["method"]].digits(spec)


def reference_dps(specs) -> int:
    """Digits for a reference that resolves the errors of every run in ``specs``."""
    return max([30] + [_digits_needed(s) + 12 for s in specs])




# -- the registry ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Method:
    """An integration method as a plug-in.

    Attributes
    ----------
    name : str                   the ``method`` of a specification
    fields : dict                its scene fields ``{key: (checker, default)}`` (:mod:`lieseries.fields`); the
                                 defaults are the specification's
    docs : dict                  ``{key: (type, meaning)}`` for docs/scenes.md
    label, precision, setting : spec -> str
    digits : spec -> int         decimal digits a reference must carry to resolve the method's errors
    run : (system, y0, tf, grid, spec, label, repeat) -> RunRecord
    bits : spec -> int or None   bits the run carries (references and conversions stay 64 bits above)
    state_digits : spec -> int   digits its mpf states are evaluated with (invariants)
    atlas : (model, y0, grid, spec) -> call, or None: a call running it across a model's charts (None: no atlas)
    quick_run, quick_study : spec -> None, optional: scale the specification down in quick mode (in a scene's
                                 [run], in a work-precision study), in place
    list_keys : tuple            keys that may be lists in work-precision studies (one run per value)
    """

    name: str
    fields: dict
    docs: dict
    label: Callable
    precision: Callable
    setting: Callable
    digits: Callable
    run: Callable
    bits: Callable = lambda spec: None
    state_digits: Callable = lambda spec: 40
    atlas: Callable | None = None
    quick_run: Callable | None = None
    quick_study: Callable | None = None
    list_keys: tuple = ()

    @property
    def defaults(self) -> dict:
        return {k: d for k, (_check, d) in self.fields.items()}


_METHODS: dict = {}

#: Method name -> accepted keys (besides ``method`` and ``label``) and their defaults (kept in step with the registry).
METHODS: dict = {}


def register_method(method: Method) -> Method:
    """Make ``method`` available to :func:`run_method`, scenes and studies (a later registration of the same name
    replaces the earlier one)."""
    if not isinstance(method, Method):
        raise TypeError(f"`method` must be a Method; got {type(method).__name__}")
    if set(method.fields) != set(method.docs):
        raise ValueError(f"method {method.name!r}: `docs` must describe exactly its fields {sorted(method.fields)}")
    _METHODS[method.name] = method
    METHODS[method.name] = method.defaults
    return method


def unregister_method(name: str) -> None:
    """Forget the method ``name`` (a plug-in's tests clean up with it)."""
    _METHODS.pop(name, None)
    METHODS.pop(name, None)


def method_plugin(name: str) -> Method:
    """The registered :class:`Method` called ``name``."""
    return _METHODS[name]


def methods_registry() -> dict:
    """{name: Method} in registration order."""
    return dict(_METHODS)


def scene_methods(lists: bool):
    """The scene checker of a list of method tables (``lists``: settings may be lists, as in work-precision
    studies): each table's fields are its method's, with their defaults."""

    def one(data, path):
        if not isinstance(data, dict):
            raise F.SceneError(f"`{path}` must be a table such as {{ method = \"taylor\", precision = \"double\" }}; "
                               f"got {F.show(data)}")
        if "method" not in data:
            raise F.SceneError(f"missing required field `{path}.method` (one of {', '.join(_METHODS)})")
        name = data["method"]
        if name not in _METHODS:
            raise F.SceneError(f"`{path}.method`: unknown method {F.show(name)}; known: {', '.join(_METHODS)}")
        plugin = _METHODS[name]
        spec = {"method": (None, F.REQUIRED), "label": (F.string, None)}
        spec.update({k: (F.list_of(c) if lists and k in plugin.list_keys else c, d)
                     for k, (c, d) in plugin.fields.items()})
        out = F.table(data, path, spec)
        if out["label"] is None:
            del out["label"]
        return out

    def check(value, path):
        if not isinstance(value, list) or not value:
            F.fail(path, "a non-empty list of method tables", value)
        return [one(m, f"{path}[{i}]") for i, m in enumerate(value)]

    return check


def thin(values, keep: int = 3):
    """At most ``keep`` (3 or 2) values of a list: its ends and (for 3) its middle."""
    if not isinstance(values, list) or len(values) <= keep:
        return values
    idx = sorted({0, len(values) // 2, len(values) - 1}) if keep >= 3 else [0, len(values) - 1]
    return [values[i] for i in idx]


def run_atlas_method(model, y0, t, spec, *, times, repeat: int = 1, bits: int = 256):
    """One method across a model's charts (its ``runs_on_atlas``): (RunRecord, extra) whose states are those of
    ``model.atlas_twin()`` at each output row (the rows of an atlas run are written in different charts,
    converted with ``bits`` bits), with the chart of each row and the number of switches in ``extra``."""
    spec = normalize_method(spec)
    m = spec["method"]
    label = method_label(spec)
    tf, grid = _grid(t, times)
    plugin = _METHODS[m]
    if plugin.atlas is None:
        return RunRecord(m, label, precision_name(spec), setting(spec), float(tf), float(tf), status="skipped",
                         message=f"method {m!r} has no atlas runs (use taylor or lie)"), None
    call = plugin.atlas(model, y0, grid if grid is not None else tf, spec)
    try:
        sol, walls = best_of(call, repeat)
    except Exception as err:  # a failing method is a row, not the end of the run
        return RunRecord(m, label, precision_name(spec), setting(spec), float(tf), float(tf), status="error",
                         message=f"{type(err).__name__}: {err}"), None
    times_ = [to_fraction(v) for v in sol.t]
    rows = list(sol.y)
    charts = [int(c) for c in sol.charts]
    if sol.y_reached is not None and (not times_ or times_[-1] != to_fraction(sol.t_reached)):
        times_.append(to_fraction(sol.t_reached))
        rows.append(sol.y_reached)
        charts.append(int(getattr(sol, "chart_reached", charts[-1] if charts else model.chart)))
    states = [model.atlas_state(r, c, bits) for r, c in zip(rows, charts)]
    st = sol.stats
    build = float(st.build_time or 0.0)
    run = RunRecord(
        m, label, precision_name(spec), setting(spec), float(times_[-1]), float(tf), t_exact=times_[-1],
        times=[float(v) for v in times_], states=states, steps=int(st.steps),
        order=int(st.order) if st.order else None, build_time=build if m == "taylor" else None,
        run_time=float(min([walls[0] - build] + walls[1:])), core_time=float(st.run_time), status=sol.status,
        message=sol.message,
    )
    extra = {"chart_switches": int(st.extra.get("chart_switches", 0)), "charts": charts}
    if "max_step_over_radius" in st.extra:
        extra["max_step_over_radius"] = float(st.extra["max_step_over_radius"])
    return run, extra


# -- the built-in methods --------------------------------------------------------------------------------------
def _taylor_precision(spec) -> str:
    try:
        return resolve_precision(spec["precision"]).name
    except (TypeError, ValueError):
        return str(spec["precision"])


def _taylor_setting(spec) -> str:
    if spec["tol"] is None:
        return f"tol=eps ({resolve_precision(spec['precision']).eps:.3g})"
    return f"tol={_fmt_num(spec['tol'])}"


def _taylor_digits(spec) -> int:
    try:
        return bits_to_dps(resolve_precision(spec["precision"]).bits)
    except (TypeError, ValueError):
        return 16


def _taylor_atlas(model, y0, t_arg, spec):
    from .taylor import integrate

    prec = resolve_precision(spec["precision"])
    return lambda: integrate(model, y0, t=t_arg, tol=spec["tol"], precision=prec, atlas=True)


def _lie_kwargs(spec) -> dict:
    kwargs = {"dps": int(spec["dps"])}
    if spec.get("tol") is not None:
        kwargs["tol"] = spec["tol"]
    if spec.get("order") is not None:
        kwargs["order"] = int(spec["order"])
    return kwargs


def _lie_atlas(model, y0, t_arg, spec):
    from .lie.integrator import lie_integrate

    kwargs = _lie_kwargs(spec)
    return lambda: lie_integrate(model, y0, t_arg, atlas=True, **kwargs)


def _dps_setting(spec) -> str:
    parts = [f"dps={spec['dps']}"]
    if spec.get("tol") is not None:
        parts.append(f"tol={_fmt_num(spec['tol'])}")
    if spec.get("order") is not None:
        parts.append(f"order={spec['order']}")
    return ", ".join(parts)


def _scipy_setting(spec) -> str:
    atol = spec["atol"]
    return f"rtol={_fmt_num(spec['rtol'])}" + ("" if atol is None else f", atol={_fmt_num(atol)}")


def _thin_lists(spec) -> None:
    for k in ("tol", "rtol", "precision"):
        if isinstance(spec.get(k), list):
            spec[k] = thin(spec[k])


def _mpmath_quick_run(spec) -> None:
    spec["t_max"] = min(float(to_fraction(spec["t_max"])), 0.5)


def _mpmath_quick_study(spec) -> None:
    _thin_lists(spec)
    _mpmath_quick_run(spec)
    if isinstance(spec.get("dps"), list):
        spec["dps"] = spec["dps"][:1]


def _validated_quick_run(spec) -> None:
    spec["dps"] = min(spec["dps"], 30)


def _dps_digits(spec) -> int:
    return int(spec["dps"])


register_method(Method(
    "taylor",
    fields={"precision": (F.precision, "double"), "tol": (F.tolerance, None)},
    docs={"precision": ("'double' | 'long double' | 'quad' | bits", "heyoka's precision (a list in work_precision)"),
          "tol": ("number in (0, 1)", "the tolerance (default: the precision's epsilon)")},
    label=lambda spec: f"heyoka {resolve_precision(spec['precision']).name}",
    precision=_taylor_precision, setting=_taylor_setting, digits=_taylor_digits, run=_run_taylor,
    bits=lambda spec: resolve_precision(spec["precision"]).bits, atlas=_taylor_atlas, quick_study=_thin_lists,
    list_keys=("precision", "tol"),
))
register_method(Method(
    "lie",
    fields={"dps": (F.integer(10, 10_000), 30), "tol": (F.positive, None), "order": (F.integer(1, 10_000), None)},
    docs={"dps": ("integer", "decimal digits of lie_integrate (a list in work_precision)"),
          "tol": ("positive number", "the per-step tolerance (default 10^-dps)"),
          "order": ("integer", "a fixed series order (default: the automatic one)")},
    label=lambda spec: f"Lie series {spec['dps']} dps", precision=lambda spec: f"{spec['dps']} dps",
    setting=_dps_setting, digits=_dps_digits, run=_run_lie, bits=lambda spec: dps_to_bits(spec["dps"]),
    state_digits=_dps_digits, atlas=_lie_atlas, quick_study=_thin_lists, list_keys=("tol", "dps"),
))
register_method(Method(
    "scipy",
    fields={"rtol": (F.tolerance, 1e-10), "atol": (F.positive, None)},
    docs={"rtol": ("number in (0, 1)", "DOP853's relative tolerance (a list in work_precision)"),
          "atol": ("positive number", "its absolute tolerance (default rtol)")},
    label=lambda spec: "scipy DOP853", precision=lambda spec: "double", setting=_scipy_setting,
    digits=lambda spec: 16, run=_run_scipy, quick_study=_thin_lists, list_keys=("rtol",),
))
register_method(Method(
    "mpmath",
    fields={"dps": (F.integer(5, 10_000), 15), "t_max": (F.positive, 2.0)},
    docs={"dps": ("integer", "digits of mpmath.odefun"),
          "t_max": ("positive number", "the run is capped at |t| <= t_max (odefun is slow)")},
    label=lambda spec: f"mpmath odefun {spec['dps']} dps", precision=lambda spec: f"{spec['dps']} dps",
    setting=lambda spec: f"dps={spec['dps']}", digits=_dps_digits, run=_run_mpmath,
    bits=lambda spec: dps_to_bits(spec["dps"]), state_digits=_dps_digits, quick_run=_mpmath_quick_run,
    quick_study=_mpmath_quick_study, list_keys=("dps",),
))
register_method(Method(
    "validated",
    fields={"dps": (F.integer(5, 10_000), 30), "order": (F.integer(1, 10_000), None)},
    docs={"dps": ("integer", "digits of validated_integrate's ball arithmetic (certified enclosures)"),
          "order": ("integer", "a fixed series order (default: the automatic one)")},
    label=lambda spec: f"validated (Arb) {spec['dps']} dps", precision=lambda spec: f"{spec['dps']} dps",
    setting=_dps_setting, digits=_dps_digits, run=_run_validated, state_digits=_dps_digits,
    quick_run=_validated_quick_run, quick_study=_thin_lists, list_keys=("dps",),
))
