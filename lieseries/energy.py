"""The energy guard of a run: a Hamiltonian run whose energy H changed far beyond its tolerance is not a success.

heyoka's error control can be fooled (a motion much slower than the time span makes the Taylor coefficients
underflow, and one huge step "succeeds"); the equations conserve H, so a run that changed H by more than sqrt(tol)
times the motion's energy scale is reported as ``invariant_drift``. Single runs (:mod:`lieseries.taylor`) and the
members of an ensemble's batches (:mod:`lieseries.ensemble`) both end through :func:`energy_check`.
"""

from __future__ import annotations

import math
import threading

import heyoka as hy

__all__ = ["energy_check", "energy_function", "energy_verdict", "clear_energy_cache"]

_LOCK = threading.Lock()

_ENERGY: dict = {}


def energy_function(ps, prec, y0, parameters=None):
    """(compiled H, the system's parameters in the working format, H(y0), the energy scale of y0) for the energy
    check of a call. The scale sum_i |dH/dy_i(y0) y_i0| is the size of H's terms at y0 (2|H| for a kinetic
    energy), so the check is relative to the motion's own energy whatever its units, and does not vanish where H
    does by cancellation."""
    key = (ps.key, prec.name)
    entry = _ENERGY.get(key)
    if entry is None:
        kwargs = {} if prec.name == "double" else {"fp_type": prec.fp_type}
        if prec.is_real:
            kwargs["prec"] = prec.bits
        npar = 1 + max((int(str(p)[1:]) for p in hy.get_params([ps.hamiltonian])), default=-1)
        compact = prec.name != "double"
        # H alone for the check at the end of every run; H and its gradient once per initial state
        h_fn = hy.cfunc([ps.hamiltonian], ps.variables, compact_mode=compact, **kwargs)
        grad = [ps.hamiltonian] + [hy.diff(ps.hamiltonian, v) for v in ps.variables]
        scale_fn = hy.cfunc(grad, ps.variables, compact_mode=compact, **kwargs)
        with _LOCK:
            entry = _ENERGY.setdefault(key, (h_fn, scale_fn, npar))
    h_fn, scale_fn, npar = entry
    if not npar:
        pars = None
    elif parameters is None:
        pars = ps.native_parameters(prec)[:npar]
    else:
        pars = prec.array(list(parameters)[:npar])
    out = scale_fn(y0) if pars is None else scale_fn(y0, pars=pars)
    scale = math.fsum(abs(float(g) * float(v)) for g, v in zip(out[1:], y0))
    return h_fn, pars, float(out[0]), scale


def energy_check(ps, prec, tol, y0, y_end, steps, status, message, parameters=None):
    """(status, message) of a run from ``y0`` that ended at ``y_end`` with ``status``: ``invariant_drift`` when a
    ``success`` changed the Hamiltonian of ``ps`` beyond sqrt(tol) times its scale (what a single run checks; the
    ensemble applies it to its batch members). ``parameters``: the run's exact parameter values (default the
    system's)."""
    if status != "success" or not ps.is_hamiltonian:
        return status, message
    energy = energy_function(ps, prec, y0, parameters)
    return energy_verdict(energy, math.sqrt(float(tol)), y_end, steps, status, message)


def energy_verdict(energy, sqrt_tol, y_end, steps, status, message):
    """``invariant_drift`` when the Hamiltonian changed beyond sqrt(tol) * max(|H(y0)|, |H(y_end)|, the energy
    scale of y0) over a successful run (:func:`energy_function`)."""
    fn, pars, e0, scale = energy
    e1 = float((fn(y_end) if pars is None else fn(y_end, pars=pars))[0])
    if not (math.isfinite(e0) and math.isfinite(e1)):
        return status, message
    if abs(e1 - e0) <= sqrt_tol * max(abs(e0), abs(e1), scale):
        return status, message
    return "invariant_drift", (
        f"{message[:-1]}, but the result is wrong: the energy H, which the equations conserve, went from "
        f"{e0:.6g} to {e1:.6g} in {steps} steps. The error control was fooled, usually because the motion is much "
        "slower (or faster) than the time span, so that the Taylor coefficients underflow: rescale time so that "
        "the motion is of order one per unit time."
    )


def clear_energy_cache() -> None:
    """Forget the compiled energy functions."""
    with _LOCK:
        _ENERGY.clear()
