"""The built-in methods (taylor, lie, scipy, mpmath, validated): their adapters and registrations."""

from __future__ import annotations

import math
import time as _time
from fractions import Fraction

import numpy as np

from .. import cache
from .. import fields as F
from ..api import integrate
from ..expr import compile_expressions
from ..lie.integrator import default_order, lie_integrate
from ..lie.operator import GUARD_DIGITS
from ..models.base import state_fractions
from ..poisson import as_poisson_system
from ..precision import (LIE_GUARD_DIGITS, MAX_DPS, MAX_ORDER, MIN_DPS, VALIDATED_GUARD_BITS, Precision, bits_to_dps,
                         check_dps, check_tolerance, data_bits, dps_to_bits, export_mpf, mp_context, resolve_precision,
                         short_decimal, to_fraction, warn_if_coarse)
from ..precision import thread_mp as mp
from ..validated import certified_digits, midpoints, validated_integrate
from .registry import Method, RunRecord, best_of, register_method, run_precision, setting, setting_number, thin

__all__ = ["MAX_ODEFUN_DPS", "clear_rhs_cache", "odefun_digits"]


# -- compiled right-hand sides (cached per system structure) ---------------------------------------------------
_RHS_CACHE = cache.region("methods.rhs", 64)


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
    return _RHS_CACHE.put(key, rhs, cost=build), build


def _mpmath_rhs(system):
    """F(values, pars) -> list of mpf at this thread's current mpmath precision (:func:`mp_context`)."""
    ps = as_poisson_system(system)
    key = ("mpmath", ps.key)
    hit = _RHS_CACHE.get(key)
    if hit is not None:
        return hit

    prog = compile_expressions(ps.variables, ps.vector_field, len(ps.parameter_values))

    def fn(values, pars, _prog=prog):
        ctx = mp_context()
        return list(_prog.evaluate(values, pars, ctx.dps, ctx=ctx))

    return _RHS_CACHE.put(key, fn)


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
    prec = resolve_precision(spec["precision"])
    tol = spec["tol"]
    t_arg = grid if grid is not None else tf
    sol, walls = best_of(lambda: integrate(system, y0, t=t_arg, tol=tol, precision=prec), repeat)
    build = sol.stats.build_time
    # the first call includes the build (unless the integrator was cached): take it out of the run time
    run_times = [walls[0] - build] + walls[1:]
    times, states = _rows_with_reached(sol)
    return RunRecord(
        "taylor", label, prec, setting(spec), float(times[-1]), float(tf), t_exact=times[-1],
        times=[float(v) for v in times], states=states, steps=int(sol.stats.steps), nfev=None,
        order=int(sol.stats.order), build_time=float(build), run_time=float(min(run_times)),
        core_time=float(sol.stats.run_time), status=sol.status, message=sol.message,
    )


def _check_double_tolerance(value, argname: str, *, below_one: bool = True) -> float:
    """A scipy tolerance: a positive number (below 1 for ``rtol``) that is a positive, finite double (scipy computes
    in double: 1e-400 would become 0)."""
    f = to_fraction(value, argname)
    if f <= 0 or (below_one and f >= 1):
        raise ValueError(f"`{argname}` must be a number {'in (0, 1)' if below_one else '> 0'}; got {value!r}")
    x = float(f) if f < 2**1000 else math.inf
    if not (0 < x < math.inf):
        raise ValueError(f"`{argname}` = {value!r} is not a positive finite double (scipy computes in double)")
    return x


def _run_scipy(system, y0, tf, grid, spec, label, repeat):
    from scipy.integrate import solve_ivp

    ps = as_poisson_system(system)
    rhs, build = _scipy_rhs(system)
    y0f = resolve_precision("double").array([to_fraction(v, "y0") for v in np.asarray(y0, dtype=object)])
    y0f = np.asarray(y0f, dtype=float)
    if len(y0f) != ps.dimension:
        raise ValueError(f"`y0` must have {ps.dimension} entries; got {len(y0f)}")
    rtol = _check_double_tolerance(spec["rtol"], "rtol")
    atol = rtol if spec["atol"] is None else _check_double_tolerance(spec["atol"], "atol", below_one=False)
    t_eval = None if grid is None else np.array([float(v) for v in grid])
    span = (0.0, float(tf))
    res, walls = best_of(
        lambda: solve_ivp(rhs, span, y0f, method="DOP853", rtol=rtol, atol=atol, t_eval=t_eval), repeat
    )
    ok = res.status == 0
    states = [res.y[:, k].copy() for k in range(res.y.shape[1])]
    times = [float(v) for v in res.t]
    return RunRecord(
        "scipy", label, resolve_precision("double"), setting(spec), times[-1] if times else 0.0, float(tf),
        t_exact=tf if ok else (to_fraction(times[-1]) if times else Fraction(0)), times=times,
        states=states, steps=None if t_eval is not None else int(len(res.t) - 1), nfev=int(res.nfev), order=8,
        build_time=float(build), run_time=float(min(walls)), status="success" if ok else "failed",
        message=str(res.message),
    )


def _run_lie(system, y0, tf, grid, spec, label, repeat):
    kwargs = _lie_kwargs(spec)
    t_arg = grid if grid is not None else tf
    sol, walls = best_of(lambda: lie_integrate(system, y0, t_arg, **kwargs), repeat)
    st = sol.stats
    times, states = _rows_with_reached(sol)
    return RunRecord(
        "lie", label, run_precision(spec), setting(spec), float(times[-1]), float(tf), t_exact=times[-1],
        times=[float(v) for v in times], states=states, steps=int(st.steps), nfev=None,
        order=int(st.order) if st.order else None, build_time=None, run_time=float(min(walls)),
        core_time=float(st.run_time) if st.run_time else None, status=sol.status, message=sol.message,
    )


def _run_validated(system, y0, tf, grid, spec, label, repeat):
    kwargs = {"dps": spec["dps"]}
    if spec.get("order") is not None:
        kwargs["order"] = spec["order"]
    t_arg = grid if grid is not None else tf
    sol, walls = best_of(lambda: validated_integrate(system, y0, t_arg, **kwargs), repeat)
    times = [to_fraction(v) for v in sol.t]
    states = [list(row) for row in midpoints(sol, as_mpf=True)]
    digits = [float(d) for d in certified_digits(sol)] if len(sol.y) else []
    return RunRecord(
        "validated", label, run_precision(spec), setting(spec), float(times[-1]) if times else 0.0, float(tf),
        t_exact=times[-1] if times else None, times=[float(v) for v in times], states=states,
        steps=int(sol.stats.steps), order=int(sol.stats.order), build_time=None, run_time=float(min(walls)),
        core_time=float(sol.stats.run_time), status=sol.status, message=sol.message,
        extra={"certified_digits": digits, "max_radius": float(sol.stats.extra.get("max_width", 0.0))},
    )


def _check_t_max(value, argname: str) -> Fraction:
    f = to_fraction(value, argname)
    if f <= 0:
        raise ValueError(f"`{argname}` must be a positive time (the run is capped at |t| <= t_max); got {value!r}")
    return f


def odefun_digits(dps: int) -> int:
    """Digits at which mpmath.odefun evaluates the right-hand side of a run at ``dps`` digits: its Taylor method
    works at (1 + degree) times the precision, with degree 3 + 1.5 dps."""
    return bits_to_dps(dps_to_bits(dps) * (4 + int(3 * dps / 2)))


#: Most digits of the mpmath method: above them odefun's own working digits pass MAX_DPS.
MAX_ODEFUN_DPS = next(d for d in range(MIN_DPS, MAX_DPS) if odefun_digits(d + 1) > MAX_DPS)


def _check_odefun_dps(dps, argname: str = "dps") -> int:
    dps = check_dps(dps, argname)
    if dps > MAX_ODEFUN_DPS:
        raise ValueError(f"`{argname}` must be at most {MAX_ODEFUN_DPS} for mpmath.odefun, which works internally "
                         f"at about 1.5 dps^2 digits ({odefun_digits(dps)} for {dps}, above {MAX_DPS}); got {dps}. "
                         "Use the Lie-series method for more digits.")
    return dps


def _run_mpmath(system, y0, tf, grid, spec, label, repeat):
    ps = as_poisson_system(system)
    dps = _check_odefun_dps(spec["dps"])
    t_max = _check_t_max(spec["t_max"], "t_max")
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
        "mpmath", label, run_precision(spec), setting(spec), float(t_run), float(tf), t_exact=t_run,
        times=[float(v) for v in out_times], states=states, steps=None, nfev=nfev, order=None, build_time=None,
        run_time=float(min(walls)), status="success", message=msg,
    )


# -- the built-in methods --------------------------------------------------------------------------------------
def _taylor_precision(spec) -> Precision:
    return resolve_precision(spec["precision"])


def _taylor_setting(spec) -> str:
    if spec["tol"] is None:
        try:
            return f"tol=eps ({resolve_precision(spec['precision']).eps:.3g})"
        except (TypeError, ValueError):  # refused by the run, which names `precision`
            return "tol=eps"
    return f"tol={setting_number(spec['tol'])}"


def _taylor_digits(spec) -> int:
    try:
        return bits_to_dps(resolve_precision(spec["precision"]).bits)
    except (TypeError, ValueError):
        return 16


def _taylor_atlas(model, y0, t_arg, spec):
    prec = resolve_precision(spec["precision"])
    return lambda: integrate(model, y0, t=t_arg, tol=spec["tol"], precision=prec, atlas=True)


def _lie_kwargs(spec) -> dict:
    kwargs = {"dps": spec["dps"]}
    if spec.get("tol") is not None:
        kwargs["tol"] = spec["tol"]
    if spec.get("order") is not None:
        kwargs["order"] = spec["order"]
    return kwargs


def _lie_check(spec) -> None:
    """What lie_integrate refuses of a specification before it runs: a tolerance below what ``dps`` digits (plus
    the engine's guard digits) resolve, and an automatic series order above MAX_ORDER."""

    ctx = mp_context()
    dps = spec["dps"]
    tol = Fraction(1, 10**dps) if spec.get("tol") is None else to_fraction(spec["tol"], "tol")
    if tol < Fraction(1, 10 ** (dps + GUARD_DIGITS)):
        raise ValueError(f"`tol` = {short_decimal(tol)} is below what {dps} digits (+{GUARD_DIGITS} guard) can "
                         f"resolve; raise `dps`")
    if spec.get("order") is None:
        n_auto = default_order(ctx.mpf(tol.numerator) / tol.denominator)
        if n_auto > MAX_ORDER:
            raise ValueError(f"`{'tol' if spec.get('tol') is not None else 'dps'}` asks for the automatic series "
                             f"order {n_auto}, above the largest order {MAX_ORDER}: give `order` (at most "
                             f"{MAX_ORDER}), or ask for fewer digits")


def _taylor_check(spec) -> None:
    check_tolerance(spec["tol"], resolve_precision(spec["precision"]))


def _lie_atlas(model, y0, t_arg, spec):
    kwargs = _lie_kwargs(spec)
    return lambda: lie_integrate(model, y0, t_arg, atlas=True, **kwargs)


def _dps_setting(spec) -> str:
    parts = [f"dps={spec['dps']}"]
    if spec.get("tol") is not None:
        parts.append(f"tol={setting_number(spec['tol'])}")
    if spec.get("order") is not None:
        parts.append(f"order={spec['order']}")
    return ", ".join(parts)


def _scipy_setting(spec) -> str:
    atol = spec["atol"]
    return f"rtol={setting_number(spec['rtol'])}" + ("" if atol is None else f", atol={setting_number(atol)}")


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
    list_keys=("precision", "tol"), check=_taylor_check,
))
register_method(Method(
    "lie",
    fields={"dps": (F.dps, 30), "tol": (F.tolerance, None), "order": (F.order, None)},
    docs={"dps": ("integer", "decimal digits of lie_integrate (a list in work_precision)"),
          "tol": ("number in (0, 1)", "the per-step tolerance (default 10^-dps)"),
          "order": ("integer", "a fixed series order (default: the automatic one)")},
    label=lambda spec: f"Lie series {spec['dps']} dps",
    precision=lambda spec: Precision.of(dps=spec["dps"], guard_digits=LIE_GUARD_DIGITS),
    setting=_dps_setting, digits=_dps_digits, run=_run_lie, bits=lambda spec: dps_to_bits(spec["dps"]),
    state_digits=_dps_digits, atlas=_lie_atlas, quick_study=_thin_lists, list_keys=("tol", "dps"), check=_lie_check,
))
register_method(Method(
    "scipy",
    fields={"rtol": (F.api(_check_double_tolerance), 1e-10),
            "atol": (F.api(_check_double_tolerance, below_one=False), None)},
    docs={"rtol": ("number in (0, 1)", "DOP853's relative tolerance (a list in work_precision)"),
          "atol": ("positive number", "its absolute tolerance (default rtol)")},
    label=lambda spec: "scipy DOP853", precision=lambda spec: resolve_precision("double"), setting=_scipy_setting,
    digits=lambda spec: 16, run=_run_scipy, quick_study=_thin_lists, list_keys=("rtol",),
))
register_method(Method(
    "mpmath",
    fields={"dps": (F.api(_check_odefun_dps), 15), "t_max": (F.api(_check_t_max), 2.0)},
    docs={"dps": (f"integer {MIN_DPS}..{MAX_ODEFUN_DPS}", "digits of mpmath.odefun"),
          "t_max": ("positive number", "the run is capped at |t| <= t_max (odefun is slow)")},
    label=lambda spec: f"mpmath odefun {spec['dps']} dps", precision=lambda spec: Precision.of(dps=spec["dps"]),
    setting=lambda spec: f"dps={spec['dps']}", digits=_dps_digits, run=_run_mpmath,
    bits=lambda spec: dps_to_bits(spec["dps"]), state_digits=_dps_digits, quick_run=_mpmath_quick_run,
    quick_study=_mpmath_quick_study, list_keys=("dps",),
))
register_method(Method(
    "validated",
    fields={"dps": (F.dps, 30), "order": (F.order, None)},
    docs={"dps": ("integer", "digits of validated_integrate's ball arithmetic (certified enclosures)"),
          "order": ("integer", "a fixed series order (default: the automatic one)")},
    label=lambda spec: f"validated (Arb) {spec['dps']} dps",
    precision=lambda spec: Precision.of(dps=spec["dps"], guard_bits=VALIDATED_GUARD_BITS),
    setting=_dps_setting, digits=_dps_digits, run=_run_validated, state_digits=_dps_digits,
    quick_run=_validated_quick_run, quick_study=_thin_lists, list_keys=("dps",),
))
