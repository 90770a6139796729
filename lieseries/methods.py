"""The one registry of integration methods and their adapters: each method is run from a specification dict and
gives one :class:`MethodRun` (the one row record of a run, used by studies, scenes and reports).

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

from .poisson import as_poisson_system
from .models.base import state_fractions
from .precision import (bits_to_dps, data_bits, dps_to_bits, export_mpf, mp_context, resolve_precision,
                        to_fraction, warn_if_coarse)
from .precision import thread_mp as mp

__all__ = [
    "METHODS",
    "MethodRun",
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

#: Method name -> accepted keys (besides ``method`` and ``label``) and their defaults.
METHODS = {
    "taylor": {"precision": "double", "tol": None},
    "lie": {"dps": 30, "tol": None, "order": None},
    "scipy": {"rtol": 1e-10, "atol": None},
    "mpmath": {"dps": 15, "t_max": 2.0},
    "validated": {"dps": 30, "order": None},
}

#: Keys that may be lists in :func:`work_precision` (one run per value).
LIST_KEYS = ("precision", "tol", "rtol", "dps")

#: Repeats of a run stop once it has used this many seconds in total.
REPEAT_BUDGET = 2.0


@dataclass
class MethodRun:
    """One run of one method with one setting.

    Attributes
    ----------
    method : str                 "taylor", "lie", "scipy" or "mpmath"
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

    @property
    def y_final(self):
        return self.states[-1] if self.states else None

    @property
    def ok(self) -> bool:
        return bool(self.states)


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
    if name not in METHODS:
        raise ValueError(f"`{where}.method` must be one of {sorted(METHODS)}; got {name!r}")
    known = set(METHODS[name]) | {"method", "label"}
    for k in spec:
        if k not in known:
            raise ValueError(f"unknown field `{where}.{k}` for method {name!r}; known: {sorted(known)}")
    out = dict(METHODS[name])
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
        for key in LIST_KEYS:
            if isinstance(s.get(key), (list, tuple)):
                runs = [dict(r, **{key: v}) for r in runs for v in s[key]]
        out.extend(runs)
    return out


def method_label(spec: dict) -> str:
    """A short label for a method: "heyoka double", "Lie series 30 dps", "scipy DOP853", "mpmath odefun 15 dps"."""
    if spec.get("label"):
        return str(spec["label"])
    m = spec["method"]
    if m == "taylor":
        return f"heyoka {resolve_precision(spec['precision']).name}"
    if m == "lie":
        return f"Lie series {spec['dps']} dps"
    if m == "scipy":
        return "scipy DOP853"
    if m == "validated":
        return f"validated (Arb) {spec['dps']} dps"
    return f"mpmath odefun {spec['dps']} dps"


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


def run_method(system, y0, t, spec: dict, *, times=None, repeat: int = 1) -> MethodRun:
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
    MethodRun
        With ``status = "error"`` (and the exception text) when the method raised, ``"skipped"`` when it is not
        available.
    """
    spec = normalize_method(spec)
    m = spec["method"]
    tf, grid = _grid(t, times)
    label = method_label(spec)
    try:
        if m == "taylor":
            return _run_taylor(system, y0, tf, grid, spec, label, repeat)
        if m == "scipy":
            return _run_scipy(system, y0, tf, grid, spec, label, repeat)
        if m == "lie":
            return _run_lie(system, y0, tf, grid, spec, label, repeat)
        if m == "validated":
            return _run_validated(system, y0, tf, grid, spec, label, repeat)
        return _run_mpmath(system, y0, tf, grid, spec, label, repeat)
    except Exception as err:  # a failing method is a row of the study, not the end of it
        return MethodRun(m, label, precision_name(spec), setting(spec), float(tf), float(tf), status="error",
                         message=f"{type(err).__name__}: {err}")


def precision_name(spec) -> str:
    m = spec["method"]
    if m == "taylor":
        try:
            return resolve_precision(spec["precision"]).name
        except (TypeError, ValueError):
            return str(spec["precision"])
    if m == "scipy":
        return "double"
    return f"{spec['dps']} dps"


def setting(spec) -> str:
    m = spec["method"]
    if m == "taylor":
        if spec["tol"] is None:
            return f"tol=eps ({resolve_precision(spec['precision']).eps:.3g})"
        return f"tol={_fmt_num(spec['tol'])}"
    if m == "scipy":
        atol = spec["atol"]
        return f"rtol={_fmt_num(spec['rtol'])}" + ("" if atol is None else f", atol={_fmt_num(atol)}")
    if m in ("lie", "validated"):
        parts = [f"dps={spec['dps']}"]
        if spec.get("tol") is not None:
            parts.append(f"tol={_fmt_num(spec['tol'])}")
        if spec.get("order") is not None:
            parts.append(f"order={spec['order']}")
        return ", ".join(parts)
    return f"dps={spec['dps']}"


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
    return MethodRun(
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
    return MethodRun(
        "scipy", label, "double", setting(spec), times[-1] if times else 0.0, float(tf),
        t_exact=tf if ok else (to_fraction(times[-1]) if times else Fraction(0)), times=times,
        states=states, steps=None if t_eval is not None else int(len(res.t) - 1), nfev=int(res.nfev), order=8,
        build_time=float(build), run_time=float(min(walls)), status="success" if ok else "failed",
        message=str(res.message),
    )


def _run_lie(system, y0, tf, grid, spec, label, repeat):
    from .lie.integrator import lie_integrate

    kwargs = {"dps": int(spec["dps"])}
    if spec.get("tol") is not None:
        kwargs["tol"] = spec["tol"]
    if spec.get("order") is not None:
        kwargs["order"] = int(spec["order"])
    t_arg = grid if grid is not None else tf
    sol, walls = best_of(lambda: lie_integrate(system, y0, t_arg, **kwargs), repeat)
    st = sol.stats
    times, states = _rows_with_reached(sol)
    return MethodRun(
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
    return MethodRun(
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
    return MethodRun(
        "mpmath", label, f"{dps} dps", setting(spec), float(t_run), float(tf), t_exact=t_run,
        times=[float(v) for v in out_times], states=states, steps=None, nfev=nfev, order=None, build_time=None,
        run_time=float(min(walls)), status="success", message=msg,
    )


# -- the study ------------------------------------------------------------------------------------------------
def _digits_needed(spec) -> int:
    m = spec["method"]
    if m == "taylor":
        try:
            return bits_to_dps(resolve_precision(spec["precision"]).bits)
        except (TypeError, ValueError):
            return 16
    if m in ("lie", "mpmath", "validated"):
        return int(spec["dps"])
    return 16


def reference_dps(specs) -> int:
    """Digits for a reference that resolves the errors of every run in ``specs``."""
    return max([30] + [_digits_needed(s) + 12 for s in specs])


