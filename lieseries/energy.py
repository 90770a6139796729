"""The energy guard of a run: a Hamiltonian run whose energy H changed far beyond its tolerance is not a success.

heyoka's error control can be fooled (a motion much slower than the time span makes the Taylor coefficients
underflow, and one huge step "succeeds"; components whose sizes differ by orders of magnitude keep only tol times
the largest one, so the small ones lose digits); the equations conserve H, so a run that changed H by more than
:func:`drift_threshold` (:func:`drift_per_step` tol per step, at most sqrt(tol)) times the motion's energy scale is
reported as ``invariant_drift``. Single runs (:mod:`lieseries.taylor`) and the
members of an ensemble's batches (:mod:`lieseries.ensemble`) both end through :func:`energy_check`.
"""

from __future__ import annotations

import math
import threading
import weakref
from fractions import Fraction

import heyoka as hy
import mpmath
import numpy as np

from . import cache
from .expr import compile_expressions
from .precision import bits_to_dps, resolve_precision, to_fraction

__all__ = ["drift_threshold", "drift_per_step", "guard_tolerance", "DRIFT_PER_STEP", "DRIFT_PER_STEP_HIGH_ORDER", "energy_check", "energy_drift", "energy_function", "energy_verdict",
           "energy_quick", "quick_check",
           "drift_message", "clear_energy_cache", "energy_exact", "exact_energy_verdict"]

_LOCK = threading.Lock()

#: A sound run changes H by a few tol per step at most (measured: below 0.05 tol per step for the rigid body,
#: the quartic oscillator and the unit sphere in double, below 1 from long double to 200 bits); the guard allows
#: this many tol per step, and never more than sqrt(tol) in all. (1000 let a sphere of radius 1e3 at speed 1 end
#: ``success`` in double 226 eps off its great circle over 3 radians: its energy moved 90 tol per step.)
DRIFT_PER_STEP = 10
#: Below quad's epsilon (2^-112: heyoka's reals, orders above ~40) the per-step allowance: the error estimate of
#: such orders is looser (the harmonic oscillator over 30 time units at 512 bits, 4 steps of order 179, moved H
#: 244 tol per step, its orbit off by ~1700 units of 2^-512).
DRIFT_PER_STEP_HIGH_ORDER = 1000


def drift_per_step(tol):
    """How many ``tol`` per step the energy guard lets H move (relative to its scale) at tolerance ``tol``."""
    return DRIFT_PER_STEP if float(tol) >= 2.0 ** -112 else DRIFT_PER_STEP_HIGH_ORDER


def drift_threshold(tol, steps):
    """The largest relative change of H a run of ``steps`` steps at tolerance ``tol`` may make:
    min(sqrt(tol), :func:`drift_per_step` * tol * steps). A float, or an mpf for a tolerance below a float's range (a
    Lie-series run above ~300 digits: a threshold of 0.0 called every such run ``invariant_drift``)."""
    n = max(int(steps), 1)
    f = float(tol)
    if f > 1e-280 or isinstance(tol, float):
        # a float stays a float (heyoka's reals multiply with floats, not with mpf): the square of a 1024-bit
        # run's sqrt(tol) is 5.6e-309, and its threshold, at least 1000 times that (the allowance below 2^-112),
        # is a normal double
        return min(math.sqrt(f), drift_per_step(f) * f * n)
    t = mpmath.mpf(tol) if hasattr(tol, "_mpf_") else mpmath.mpf(tol.numerator) / tol.denominator
    return min(mpmath.sqrt(t), drift_per_step(f) * t * n)

def guard_tolerance(ps, tol, work_bits: int):
    """The tolerance the energy guard reads for a run of ``ps`` at ``tol`` and ``work_bits``: ``tol``, or
    2^-b when a constant written in the expressions carries only b < ``work_bits`` bits (heyoka stores 1/3 as the
    nearest double and folds the constants of the derivatives in double: the field is then the gradient of H to
    b bits only, and a 30-digit run right to 1e-33 changed H by 2e-18: "the result is wrong", because of the
    constant the PrecisionWarning already named). Parameters and states given as binary floats are exact for
    their binary values in the field and in H alike: they do not loosen it. (A double run needs no look: its
    constants carry its own 53 bits, and the look walks every expression once.)"""
    if work_bits <= 53:
        return tol
    bits = [b for name, b in ps.coarse_data().items() if name.startswith("the constant") and b < work_bits]
    if not bits:
        return tol
    floor = Fraction(1, 2 ** min(bits))
    if hasattr(tol, "_mpf_"):
        return max(tol, mpmath.mpf(floor.numerator) / floor.denominator)
    return max(tol, floor) if isinstance(tol, Fraction) else max(tol, float(floor))


_ENERGY = cache.region("energy.functions", 64)  # compiled energy checks, in the one cache
#: Energies (H and the Casimirs) printed longer than this get no plain Python check (:func:`quick_check`): the
#: compiled function's per-call cost matters little beside their own.
PYTHON_CHECK_CHARS = 4000


def _compiled(ps, prec):
    """(H alone, H and its gradient, number of parameters H reads), compiled once per structure and precision."""
    key = (ps.invariants_key, prec.name)
    entry = _ENERGY.get(key)
    if entry is None:
        kwargs = {} if prec.name == "double" else {"fp_type": prec.fp_type}
        if prec.is_real:
            kwargs["prec"] = prec.bits
        cas = list(ps.casimirs.values())
        npar = 1 + max((int(str(p)[1:]) for p in hy.get_params([ps.hamiltonian] + cas)), default=-1)
        compact = prec.name != "double"
        # H and the declared Casimirs for the check at the end of every run; with their gradients once per
        # initial state: [H, dH/dy..., C_1, dC_1/dy..., ...]. Beyond double the end check reads H and the
        # Casimirs from the gradient function (one compilation, not two: at 256 bits the second costs as much as
        # a small integrator; one call per run evaluates the gradients in vain)
        grad = [e for f in [ps.hamiltonian] + cas for e in [f] + [hy.diff(f, v) for v in ps.variables]]
        scale_fn = hy.cfunc(grad, ps.variables, compact_mode=compact, **kwargs)
        if compact:
            h_fn = _Values(scale_fn, len(ps.variables) + 1)
        else:  # compiled when first called: a double run whose plain Python check decides never needs it
            exprs, variables = [ps.hamiltonian] + cas, ps.variables  # (the expressions, not the system, are kept)
            h_fn = _OnFirstCall(lambda: hy.cfunc(exprs, variables, compact_mode=False))
        quick = _python_function(ps, [ps.hamiltonian] + cas, npar) if prec.name == "double" else None
        with _LOCK:
            entry = _ENERGY.setdefault(key, (h_fn, scale_fn, npar, quick))
    return entry


class _OnFirstCall:
    """A compiled function made by ``make()`` when it is first called (once, whichever thread calls first)."""

    __slots__ = ("make", "fn", "lock")

    def __init__(self, make):
        self.make, self.fn, self.lock = make, None, threading.Lock()

    def __call__(self, *args, **kwargs):
        fn = self.fn
        if fn is None:
            with self.lock:
                if self.fn is None:
                    self.fn = self.make()
                fn = self.fn
        return fn(*args, **kwargs)


class _Values:
    """H and the Casimirs (every ``stride``-th output, from the first) of the compiled function of H, the Casimirs
    and their gradients: called as the compiled function of H and the Casimirs alone would be."""

    __slots__ = ("fn", "stride")

    def __init__(self, fn, stride):
        self.fn, self.stride = fn, stride

    def __call__(self, y, **kwargs):
        return self.fn(y, **kwargs)[::self.stride]


def _python_function(ps, exprs, npar):
    """(values, make): ``exprs`` (H, then the Casimirs) as plain Python functions of floats, or None when they do
    not translate (a function the ``math`` module lacks). ``values(*state, *parameters)`` is their list;
    ``make(*parameters, *ref, per_step, most)`` returns ``check(state, steps)`` (the state a list of floats), True
    when ``|H - ref[0]| <= half * ref[1]`` and ``|C_j - ref[2 + 2j]| <= half * ref[3 + 2j]`` for every Casimir, with
    ``half = min(most, per_step * max(steps, 1))``; the constants are the closure's own cells (no subscripts).
    Calling a compiled ``hy.cfunc`` costs several microseconds of argument handling, many times the few float
    operations of an energy: these give :func:`quick_check` its cheap first opinion on a double run."""
    if sum(len(str(e)) for e in exprs) > PYTHON_CHECK_CHARS:
        return None  # a large energy: sympy's translation would cost more than the calls it saves
    try:
        import sympy
        from sympy.printing.pycode import PythonCodePrinter

        class Printer(PythonCodePrinter):
            def _print_Float(self, e):  # heyoka's constants are doubles: every digit of each (sympy prints 15)
                return repr(float(e))

            def _print_Pow(self, e, rational=False):  # x**2 as x*x: one rounding either way, and no pow call
                if e.exp == 2:
                    b = self.parenthesize(e.base, 1000)
                    return f"({b}*{b})"
                return super()._print_Pow(e, rational=rational)

        names = [hy.to_sympy(v) for v in ps.variables]
        pars = [sympy.Symbol(f"par[{i}]", real=True) for i in range(npar)]
        args = [sympy.Symbol(f"v{i}", real=True) for i in range(len(names))]
        args += [sympy.Symbol(f"p{i}", real=True) for i in range(npar)]
        exprs = [hy.to_sympy(e).xreplace(dict(zip(names + pars, args))) for e in exprs]
        common, reduced = sympy.cse(exprs, symbols=sympy.numbered_symbols("w"))
        pr = Printer()
        head = ", ".join(str(a) for a in args)
        unpack = [f"    {''.join(f'v{i}, ' for i in range(len(names)))}= y"]
        body = [f"    {w} = {pr.doprint(e)}" for w, e in common]
        outs = [pr.doprint(e) for e in reduced]
        test = [f"abs({c} - r{2 + 2 * j}) <= half * r{3 + 2 * j}" for j, c in enumerate(outs[1:])]
        consts = [f"p{i}" for i in range(npar)] + [f"r{k}" for k in range(2 * len(outs))]
        code = "\n".join(
            [f"def values({head}):"] + body + [f"    return [{', '.join(outs)}]",
             f"def make({''.join(c + ', ' for c in consts)}per_step, most):",
             "  def check(y, steps):"]
            + ["  " + line for line in unpack + body + [
                "    half = per_step * steps if steps > 1 else per_step", "    if half > most:", "        half = most",
                f"    h = {outs[0]}", "    if not abs(h - r0) <= half * r1:", "        return False",
                f"    return {' and '.join(test) if test else 'True'}"]]
            + ["  return check"])
        namespace = {"math": math}
        exec(compile(code, "<lieseries energy check>", "exec"), namespace)  # noqa: S102 - code printed by sympy
        return namespace["values"], namespace["make"]
    except Exception:  # noqa: BLE001 - no translation: the compiled function alone decides
        return None


def _quick_start(quick, y0, pars, out, n, scale, casimirs):
    """(make, its constants: the parameters as floats, ref) for :func:`quick_check` when the Python functions agree
    with the compiled one at y0 to 2^-40 of each value's scale; else None (the compiled function alone decides)."""
    values, make = quick
    args = [float(v) for v in y0] + ([float(v) for v in pars] if pars is not None else [])
    try:
        vals = [float(v) for v in values(*args)]
    except Exception:  # noqa: BLE001 - a domain error, overflow, a name math lacks: no cheap opinion
        return None
    ref = [float(out[j]) for j in range(0, len(out), n + 1)]
    sizes = [float(scale)] + [float(sc) for _, sc, _ in casimirs]  # (never above energy_verdict's)
    if len(vals) != len(ref) or len(sizes) != len(ref):
        return None
    for v, r, sz in zip(vals, ref, sizes):
        if not (math.isfinite(v) and math.isfinite(sz) and abs(v - r) <= 2.0**-40 * max(abs(r), sz)):
            return None
    # the changes are measured against the scales at y0 alone (not also |H(y_end)|, |C(y_end)|): stricter
    limits = [vals[0], max(abs(vals[0]), sizes[0])] + [x for pair in zip(vals[1:], sizes[1:]) for x in pair]
    return make, tuple(args[len(y0):]) + tuple(limits)


def energy_function(ps, prec, y0, parameters=None):
    """(compiled H, the system's parameters in the working format, H(y0), the energy scale of y0, ..., the compiled
    H and gradient that give the scale at another state) for the energy check of a call. The scale
    sum_i |dH/dy_i(y0) y_i0| is the size of H's terms at y0 (2|H| for a kinetic energy), so the check is relative
    to the motion's own energy whatever its units, and does not vanish where H does by cancellation."""
    h_fn, scale_fn, npar, quick = _compiled(ps, prec)
    if not npar:
        pars = None
    elif parameters is None:
        pars = ps.native_parameters(prec)[:npar]
    else:
        pars = prec.array(list(parameters)[:npar])
    out = scale_fn(y0) if pars is None else scale_fn(y0, pars=pars)
    n = len(y0)
    h0 = out[0]
    scale = sum((abs(g * v) for g, v in zip(out[1:n + 1], y0)), h0 * 0)  # in the working format: no float underflow
    # the declared Casimirs (R R^T of the rigid body, |x|^2 of the sphere) with the size of their terms; one that
    # vanishes at y0 with its terms (an off-diagonal entry of R R^T at R = 1; x . p from x = (0.6, 0, 0.8),
    # p = (0, 1, 0)) is measured on the largest scale, and by energy_verdict on its terms at the end too (flagged)
    cas = [(out[j], sum((abs(g * v) for g, v in zip(out[j + 1:j + n + 1], y0)), h0 * 0))
           for j in range(n + 1, len(out), n + 1)]
    top = max((max(abs(c), sc) for c, sc in cas), default=h0 * 0)
    casimirs = [(c, max(abs(c), sc, top), True) if not (abs(c) > 0 or sc > 0) else (c, max(abs(c), sc), False)
                for c, sc in cas]
    tiny = _smallest_normal(prec)
    beyond = None
    if tiny is not None and not abs(h0) >= tiny and not abs(scale) >= tiny:
        # H(y0) is zero or subnormal in this format: the motion's energy (and with it the Taylor coefficients the
        # step-size control reads) may lie beyond the format's range; the exact energy tells
        h_exact, _ = energy_exact(ps, y0, 64)
        if h_exact != 0 and abs(h_exact) < tiny:
            beyond = (prec.name, tiny, h_exact)
    if quick is not None and beyond is None:
        quick = _quick_start(quick, y0, pars, out, n, scale, casimirs)
    else:
        quick = None
    return h_fn, pars, h0, scale, beyond, casimirs, quick, scale_fn


def _smallest_normal(prec):
    """The smallest normal number of a fixed format, in that format (None for heyoka.real: its exponent range is
    vast)."""
    if prec.is_real:
        return None
    if prec.name == "quad":
        return hy.real128("3.36210314311209350626267781732175260e-4932")  # 2^-16382
    return np.finfo(prec.numpy_dtype).tiny


def energy_drift(ps, tol, Y0, Y1, parameters=None, steps=None) -> dict:
    """The energy check of many double-precision runs at once (an ensemble's batch members): ``({i: (H(Y0[i]),
    H(Y1[i]))}, low)`` for the rows i whose Hamiltonian changed beyond :func:`drift_threshold` (with ``steps[i]``, the
    rows' step counts; sqrt(tol) when not given) times its scale, as :func:`energy_verdict` decides for one run.
    ``Y0``, ``Y1``: float64 arrays (k, n); ``parameters``: per-row exact parameter values (k rows), or None for
    the system's own. One vectorised call of the compiled functions for all rows."""

    prec = resolve_precision("double")
    h_fn, scale_fn, npar, _ = _compiled(ps, prec)
    k = len(Y0)
    if k == 0:
        return {}, []
    X0 = np.ascontiguousarray(np.asarray(Y0, dtype=np.float64).T)
    X1 = np.ascontiguousarray(np.asarray(Y1, dtype=np.float64).T)
    kw = {}
    if npar:
        if parameters is None:
            base = np.asarray(ps.native_parameters(prec)[:npar], dtype=np.float64)
            kw["pars"] = np.ascontiguousarray(np.repeat(base[:, None], k, axis=1))
        else:
            kw["pars"] = np.ascontiguousarray(np.array([[float(v) for v in row[:npar]] for row in parameters]).T)
    out0 = scale_fn(X0, **kw)
    n = X0.shape[0]
    e0, scale = out0[0], np.abs(out0[1:n + 1] * X0).sum(axis=0)
    e1 = h_fn(X1, **kw)[0]
    with np.errstate(invalid="ignore"):
        rel = (np.full(k, math.sqrt(float(tol))) if steps is None
               else np.array([drift_threshold(tol, s) for s in steps], dtype=np.float64))
        thr = rel * np.maximum(np.maximum(np.abs(e0), np.abs(e1)), scale)
        bad = np.isfinite(e0) & np.isfinite(e1) & (np.abs(e1 - e0) > thr)
        if bad.any():  # the scale at the end too (energy_verdict)
            scale1 = np.abs(scale_fn(X1, **kw)[1:n + 1] * X1).sum(axis=0)
            bad &= np.abs(e1 - e0) > rel * scale1
        # H(y0) zero or subnormal in double: the energy may lie below the format's range (the single run's check
        # with the exact energy decides those rows)
        tiny = np.finfo(np.float64).tiny
        low = ~(np.abs(e0) >= tiny) & ~(scale >= tiny) & ~bad
    return {int(i): (float(e0[i]), float(e1[i])) for i in np.flatnonzero(bad)}, [int(i) for i in np.flatnonzero(low)]


def drift_message(message, e0, e1, steps) -> str:
    """The message of a run that reached its final time with H changed from ``e0`` to ``e1``."""
    return (
        f"{message[:-1]}, but the result is wrong: the energy H, which the equations conserve, went from "
        f"{_short(e0)} to {_short(e1)} (a change of {_change(e0, e1)}) in {steps} steps. The error control was "
        "fooled, usually because the motion is much slower (or faster) than the time span, so that the Taylor "
        "coefficients underflow, or because the state's components differ in size by orders of magnitude (heyoka's "
        "tolerance is relative to the largest, so the small ones lose digits): rescale time and units so that the motion and the components are of order one."
    )


def energy_check(ps, prec, tol, y0, y_end, steps, status, message, parameters=None):
    """(status, message) of a run from ``y0`` that ended at ``y_end`` with ``status``: ``invariant_drift`` when a
    ``success`` changed the Hamiltonian of ``ps`` beyond sqrt(tol) times its scale (what a single run checks; the
    ensemble applies it to its batch members). ``parameters``: the run's exact parameter values (default the
    system's). The tolerance is the single run's, :func:`guard_tolerance`'s: loosened to the bits of the constants
    written in the expressions."""
    if status != "success" or not ps.is_hamiltonian:
        return status, message
    energy = energy_function(ps, prec, y0, parameters)
    return energy_verdict(energy, math.sqrt(float(guard_tolerance(ps, tol, prec.bits))), y_end, steps, status,
                          message)


def energy_verdict(energy, sqrt_tol, y_end, steps, status, message):
    """``invariant_drift`` when the Hamiltonian changed beyond :func:`drift_threshold` * max(|H(y0)|, |H(y_end)|,
    the energy scale of y0 or of y_end, the larger) over a successful run of ``steps`` steps
    (:func:`energy_function`)."""
    fn, pars, h0, scale, beyond, casimirs, _, scale_fn = energy
    if beyond is not None:
        name, tiny, h_exact = beyond
        return "invariant_drift", (
            f"{message[:-1]}, but the result cannot be trusted: the energy H(y0) = {mpmath.nstr(h_exact, 3)} lies "
            f"below the smallest normal number of {name} ({_short(tiny)}), so the Taylor coefficients underflow, the "
            f"step-size control cannot see the motion ({steps} steps) and the energy check cannot either. Rescale "
            "time and units so that the motion is of order one, or use a format of wider range (quad, or a number "
            "of bits).")
    out = fn(y_end) if pars is None else fn(y_end, pars=pars)
    h1 = out[0]
    if not (_finite(h0) and _finite(h1)):
        return status, message
    # compared in the working format (quad's 1e-400 is a double's 0; two 237-bit energies on a double's midpoint
    # round apart), only the threshold is a float
    thr = drift_threshold(sqrt_tol * sqrt_tol, steps)
    if abs(h1 - h0) > thr * max(abs(h0), abs(h1), scale) and abs(h1 - h0) > thr * _end_scale(scale_fn, pars, y_end):
        # (the scale at the end too, as the driver's guard reads it: from rest at q = 0 under a force, H = p^2/2 -
        # q + q^3, H and its terms vanish at y0, and a run right to 1e-35 ended invariant_drift on a threshold of 0)
        return "invariant_drift", drift_message(message, h0, h1, steps)
    ends = None
    for j, ((c0, sc, vanished), c1) in enumerate(zip(casimirs, out[1:])):
        if _finite(c1) and abs(c1 - c0) > thr * max(sc, abs(c1)) and vanished:
            # no size of its own at y0: its terms at the end give it (x . p at speed 1e6 measured against |x|^2 = 1
            # called runs right to eps wrong)
            ends = (scale_fn(y_end) if pars is None else scale_fn(y_end, pars=pars)) if ends is None else ends
            k, n = (j + 1) * (len(y_end) + 1), len(y_end)
            sc = max(sc, sum((abs(g * v) for g, v in zip(ends[k + 1:k + n + 1], y_end)), ends[0] * 0))
        if _finite(c1) and abs(c1 - c0) > thr * max(sc, abs(c1)):
            return "invariant_drift", (
                f"{message[:-1]}, but the result is wrong: a Casimir of the bracket, which every motion conserves, "
                f"went from {_short(c0)} to {_short(c1)} in {steps} steps (the energy did not show it). The error "
                "control was fooled, usually because the motion is much slower than the time span (its Taylor "
                "coefficients underflow): rescale time and units so that the motion is of order one.")
    return status, message


def _end_scale(scale_fn, pars, y):
    """The energy scale sum_i |dH/dy_i y_i| at ``y`` (in the working format)."""
    out = scale_fn(y) if pars is None else scale_fn(y, pars=pars)
    return sum((abs(g * v) for g, v in zip(out[1:len(y) + 1], y)), out[0] * 0)


def quick_check(energy, sqrt_tol):
    """The cheap first opinion on the energy of a successful double run at tolerance ``sqrt_tol**2``, or None when
    there is none (not double, a large or untranslatable energy, disagreement at y0): ``check(y_end, steps)``
    (``y_end`` a list of floats) is True when the run that ended there after ``steps`` steps surely passes
    :func:`energy_verdict`: H and every declared Casimir changed by at most half of the allowed amount
    (:func:`drift_threshold`), measured with the plain Python function of :func:`energy_function` (a few float
    operations, several times cheaper than a compiled-function call). False, or an exception (overflow, a domain
    error), means "ask :func:`energy_verdict`", which alone reports a drift: the half margin exceeds the rounding
    differences of the two evaluations (a few ulps against at least 5 tol), so the cheap opinion never passes a
    run the compiled check would stop. Made once per call and called on each of its runs."""
    quick = energy[6]
    if quick is None:
        return None
    make, consts = quick
    tol = sqrt_tol * sqrt_tol
    return make(*consts, 0.5 * drift_per_step(tol) * tol, 0.5 * sqrt_tol)


def energy_quick(energy, sqrt_tol, y_end, steps) -> bool:
    """:func:`quick_check`'s opinion on one end state ``y_end`` (a float64 array): False when it has none."""
    check = quick_check(energy, sqrt_tol)
    if check is None:
        return False
    try:
        return check(y_end.tolist(), steps)
    except Exception:  # noqa: BLE001 - overflow, a domain error: the compiled check decides
        return False


def _finite(x) -> bool:
    return x - x == 0  # in any format: inf - inf and nan are not 0


def _short(x) -> str:
    """A number of any format (double, long double, real128, heyoka.real) to 10 significant digits."""
    return mpmath.nstr(mpmath.mpf(str(x)), 10)


def _change(e0, e1) -> str:
    """``e1 - e0`` of numbers of any format, to 3 digits (the two may agree to the 10 digits shown)."""
    ctx = mpmath.MPContext()
    ctx.dps = 60
    return ctx.nstr(ctx.mpf(str(e1)) - ctx.mpf(str(e0)), 3)


def clear_energy_cache() -> None:
    """Forget the compiled energy functions."""
    with _LOCK:
        _ENERGY.clear()
        _EXACT_PROGRAMS.clear()
        _EXACT_BY_STRUCTURE.clear()
        _EXACT_VALUES.clear()


_EXACT_PROGRAMS = weakref.WeakKeyDictionary()  # system -> the program of H and its gradient (energy_exact)
_EXACT_BY_STRUCTURE = cache.region("energy.exact_programs", 64)  # (structure key, H) -> the same program


#: system -> {(exact state, parameters, bits): (H, scale)} for the states asked with ``remember`` (a run's
#: initial state: the same call repeated evaluates H there once); at most _REMEMBERED states per system.
_EXACT_VALUES = weakref.WeakKeyDictionary()
_REMEMBERED = 16


def energy_exact(ps, y, bits: int, remember: bool = False):
    """(H(y), the energy scale sum_i |dH/dy_i y_i|) of ``ps`` at the exact value of ``y``, H in mpmath at ``bits``
    bits (the scale an mpf of 64 bits): the energy check of the mpmath engine and of atlas runs, whose states are not in
    one heyoka format or one chart. ``remember``: keep the result for this state and precision (an initial state,
    which repeated calls share)."""

    prog = _EXACT_PROGRAMS.get(ps)
    if prog is None:  # (the gradient and the compiled-program lookup cost a third of a call: once per system)
        skey = ps.invariants_key  # and compiled once per structure and H (0.25 s for a heavy top's
        prog = _EXACT_BY_STRUCTURE.get(skey)  # intermediate form: a model built again, or with other parameters)
        if prog is None:
            exprs = [ps.hamiltonian] + [hy.diff(ps.hamiltonian, v) for v in ps.variables]
            prog = _EXACT_BY_STRUCTURE.put(skey, compile_expressions(ps.variables, exprs, len(ps.parameter_values)))
        with _LOCK:
            _EXACT_PROGRAMS[ps] = prog
    exact = getattr(y, "exact", None)  # an ExactState: its exact values, not their doubles
    z = list(exact) if exact is not None else [to_fraction(v) for v in np.asarray(y, dtype=object)]
    if remember:
        known = _EXACT_VALUES.get(ps)
        key = (tuple(z), tuple(ps.parameter_values), bits)
        got = known.get(key) if known is not None else None
        if got is None:
            got = energy_exact(ps, z, bits)
            with _LOCK:
                known = _EXACT_VALUES.setdefault(ps, {})
                if len(known) >= _REMEMBERED:
                    known.clear()
                known[key] = got
        return got
    out = prog.evaluate(z, list(ps.parameter_values), max(bits_to_dps(bits), 15))
    # the scale in mpf (64 bits, explicit): a state or an energy beyond a double's range (momenta of 1e400, an
    # energy of 1e-400) overflowed to an OverflowError or underflowed to a scale of 0.0 (a right run then ended
    # ``invariant_drift``)
    return out[0], mpmath.fsum([abs(mpmath.fmul(g, mpmath.fdiv(v.numerator, v.denominator, prec=64), prec=64))
                                for g, v in zip(out[1:], z)])


def exact_energy_verdict(e0, e1, scale, tol, status, message, steps):
    """``invariant_drift`` (with :func:`drift_message`) when H went from ``e0`` to ``e1`` (mpf) by more than
    :func:`drift_threshold` * max(|e0|, |e1|, scale); else ``(status, message)``."""
    if status != "success" or not (e0 == e0 and e1 == e1):
        return status, message
    if abs(e1 - e0) <= drift_threshold(tol, steps) * max(abs(e0), abs(e1), scale):
        return status, message
    return "invariant_drift", drift_message(message, e0, e1, steps)
