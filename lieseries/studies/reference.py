"""What the studies share: reference solutions, the quantities compared, the error measure.

What is compared
----------------
Rigid body (:class:`~lieseries.EulerPoisson`)
    The 12-number state (R row-major, then M), against the closed form of :func:`lieseries.exact.euler_poisson`.
    That formula starts from R(0) = 1; a general R0 is handled by R(t) = R0 R_id(t) (the equation
    dR/dt = R hat(Omega) is linear in R), M unchanged, with Omega(0) = I^-1 M0.
Particle on the sphere (:class:`~lieseries.Sphere`, :class:`~lieseries.SphereDirac`)
    Position and velocity (x1, x2, x3, v1, v2, v3), against the great circle of :func:`lieseries.exact.sphere`
    on the sphere of radius |x(0)| (|x|^2 is a Casimir: the motion stays on the leaf it starts on). Comparing
    (x, v) instead of the chart coordinates makes the 5-dimensional and the Dirac form directly comparable and
    needs no chart at the final time.
Any other system
    The state, against heyoka in 256-bit arithmetic with tolerance 2^-250, or more bits for more digits (the Lie
    series above heyoka's 1024 bits): a numerical reference, labelled so (:func:`numerical_reference`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from typing import Callable

from .. import exact
from ..api import integrate
from ..lie.integrator import lie_integrate
from ..models.base import as_model, state_fractions
from ..poisson import as_poisson_system
from ..precision import MAX_BITS, MAX_DPS, bits_to_dps, check_count, dps_to_bits, export_mpf, float_or_mpf, to_fraction
from ..precision import thread_mp as mp

__all__ = [
    "NUMERICAL_REFERENCE_BITS",
    "NUMERICAL_REFERENCE_TOL",
    "numerical_reference",
    "numerical_reference_label",
    "Reference",
    "reference_solution",
    "reference_solutions",
    "has_exact_solution",
    "observables",
    "observable_names",
    "state_error",
    "max_difference",
    "theoretical_radius",
    "loglog_slope",
    "ClosedForm",
    "register_closed_form",
    "unregister_closed_form",
]

#: Precision (bits) and tolerance of the numerical reference used when a system has no closed form: at least
#: these bits, and a tolerance 6 bits above the precision's last place (2^-250 at 256 bits).
NUMERICAL_REFERENCE_BITS = 256
NUMERICAL_REFERENCE_TOL = Fraction(1, 2**250)


def numerical_reference_label(bits: int) -> str:
    """What :func:`numerical_reference` runs at ``bits``."""
    bits = max(NUMERICAL_REFERENCE_BITS, int(bits))
    if bits <= MAX_BITS:
        return f"heyoka, {bits} bits, tol 2^-{bits - 6}"
    return f"the Lie series at dps {bits_to_dps(bits)}"


def numerical_reference(system, y0, times, bits: int):
    """(states at ``times``, label): the most precise run the engines give, for a system without a closed form:
    heyoka at ``bits`` (at least NUMERICAL_REFERENCE_BITS) with tol 2^-(bits - 6), or above heyoka's
    ``MAX_BITS`` the Lie series at that many digits. ``times``: a final time or a grid. (A tolerance fixed at
    2^-250 made a 464-bit reference right to 1e-77 only, and every run more precise than that was reported with
    the reference's error; a reference above 1024 bits was refused by heyoka with a traceback.) Raises
    RuntimeError when the reference does not reach the end."""
    bits = max(NUMERICAL_REFERENCE_BITS, int(bits))
    label = numerical_reference_label(bits)
    if bits <= MAX_BITS:

        sol = integrate(system, y0, t=times, precision=bits, tol=Fraction(1, 2 ** (bits - 6)))
    else:

        sol = lie_integrate(system, y0, t=times, dps=bits_to_dps(bits))
    if not sol.success:
        raise RuntimeError(f"the numerical reference ({label}) did not reach the end: {sol.message}")
    return sol.y, label


def _mpf(q: Fraction):
    """``q`` in this thread's mpmath context, at its current precision."""
    return mp.mpf(q.numerator) / q.denominator


# -- what is compared ------------------------------------------------------------------------------------------
def observable_names(system) -> tuple:
    """Names of the quantities :func:`observables` returns for ``system`` (the model's ``compared_names``)."""
    return as_model(system).compared_names


def observables(system, y, dps: int = 40) -> list:
    """The quantities compared against the reference, as mpf with ``dps`` digits.

    Parameters
    ----------
    system : model or PoissonSystem
    y : sequence of n numbers
        A state in any precision (float64, longdouble, real128, heyoka real, mpf, Fraction, str).
    dps : int
        Working digits of the conversion.

    Returns
    -------
    list of mpf
        The model's ``compared`` quantities: the state itself by default; for the sphere models position and
        velocity (see the module docstring).
    """
    dps = check_count(dps, "dps", low=5, high=MAX_DPS)
    model = as_model(system)
    fr = state_fractions(y, model.dimension, "y")
    chart = getattr(y, "charts", None)  # a row of an atlas run knows its chart
    vals = model.compared(fr, dps_to_bits(dps) + 16, chart if isinstance(chart, int) else None)
    with mp.workdps(dps):
        return export_mpf([_mpf(c) if isinstance(c, Fraction) else +c for c in vals])


@dataclass
class Reference:
    """A reference solution at one time.

    Attributes
    ----------
    t : float
        The time of the reference state.
    values : list of mpf
        The reference :func:`observables` at ``t``.
    names : tuple of str
        Their names.
    kind : str
        ``"exact"`` (closed form), ``"numerical"`` (heyoka at 256 bits) or ``"given"`` (passed by the user).
    label : str
        A description for reports.
    dps : int
        Digits carried by ``values``.
    """

    t: float
    values: list
    names: tuple
    kind: str
    label: str
    dps: int

    def to_dict(self) -> dict:
        return {"t": self.t, "kind": self.kind, "label": self.label, "dps": self.dps, "names": list(self.names),
                "values": [mp.nstr(v, min(self.dps, 30)) for v in self.values]}


# -- closed forms, by the name a model gives in its ``closed_form`` --------------------------------------------------
@dataclass(frozen=True)
class ClosedForm:
    """A closed-form solution of the models that name it (``model.closed_form == name``).

    ``at(model, fractions, t, dps)``: the model's compared quantities at ``t`` from the exact initial state (mpf,
    ``dps`` digits); ``many(model, fractions, times, dps)``: the same at several times (default: ``at`` per time);
    ``radius(model, fractions, dps)``: the radius of convergence of the Lie series at the initial state (mpf,
    None when unknown or infinite); ``label``: how reports name it.
    """

    name: str
    label: str
    at: Callable
    many: Callable | None = None
    radius: Callable | None = None


_CLOSED_FORMS: dict = {}


def register_closed_form(form: ClosedForm) -> ClosedForm:
    """Make ``form`` the reference of every model whose ``closed_form`` is ``form.name``."""
    if not isinstance(form, ClosedForm):
        raise TypeError(f"`form` must be a ClosedForm; got {type(form).__name__}")
    _CLOSED_FORMS[form.name] = form
    return form


def unregister_closed_form(name: str) -> None:
    """Forget the closed form ``name`` (a plug-in's tests clean up with it)."""
    _CLOSED_FORMS.pop(name, None)


def _closed_form(system):
    return _CLOSED_FORMS.get(getattr(as_model(system), "closed_form", None))


def has_exact_solution(system) -> bool:
    """True when :func:`reference_solution` uses a closed form for ``system``."""
    return _closed_form(system) is not None


def _body_data(body, fr):
    """(inertia as exact.euler_poisson takes it, Omega0 = I^-1 M0), exactly."""
    I = body.inertia_exact
    inertia = [I[i][i] for i in range(3)] if body.diagonal else I
    Iinv = body.inverse_inertia_exact
    omega = [sum(Iinv[i][j] * fr[9 + j] for j in range(3)) for i in range(3)]
    return inertia, omega


def _rigid_exact(body, fr, t, dps):
    inertia, omega = _body_data(body, fr)
    st = exact.euler_poisson(inertia, omega, to_fraction(t, "t"), dps=dps)
    with mp.workdps(dps + 10):
        R0 = [[_mpf(fr[3 * i + j]) for j in range(3)] for i in range(3)]
        Rid = [[st[3 * i + j] for j in range(3)] for i in range(3)]
        R = [mp.fsum(R0[i][k] * Rid[k][j] for k in range(3)) for i in range(3) for j in range(3)]
    with mp.workdps(dps):
        return export_mpf([+v for v in R] + [mp.mpf(v) for v in st[9:]])


def _rigid_many(body, fr, times, dps):
    inertia, omega = _body_data(body, fr)
    states = exact.euler_poisson_many(inertia, omega, times, dps=dps)
    out = []
    with mp.workdps(dps + 10):
        R0 = [[_mpf(fr[3 * i + j]) for j in range(3)] for i in range(3)]
        for st in states:
            R = [mp.fsum(R0[i][k] * st[3 * k + j] for k in range(3)) for i in range(3) for j in range(3)]
            out.append(R + list(st[9:]))
    with mp.workdps(dps):
        return export_mpf([[mp.mpf(v) for v in row] for row in out])


def _rigid_radius(body, fr, dps):
    inertia, omega = _body_data(body, fr)
    return exact.rigid_body_constants(inertia, omega, dps=dps).pole_distance


def _sphere_leaf(model, fr, dps):
    """Radius |x0|, x0 and the tangent part of v0 (mpf, at dps + 10) from an exact state."""
    bits = dps_to_bits(dps + 10) + 16
    xv0 = model.compared(fr, bits)
    x, v = xv0[:3], xv0[3:]
    with mp.workdps(dps + 10):
        r2 = mp.fsum(c * c for c in x)
        xv = mp.fsum(a * b for a, b in zip(x, v))
        v = [v[i] - x[i] * xv / r2 for i in range(3)]  # x.v = 0 up to the state's own rounding
        return mp.sqrt(r2), x, v


def _great_circle(model, fr, t, dps):
    r, x, v = _sphere_leaf(model, fr, dps)
    xt, vt = exact.sphere(r, x, v, t, dps=dps)
    return list(xt) + list(vt)


def _great_circle_radius(model, fr, dps):
    chart = getattr(model, "chart", None)  # the pole of the dependent coordinate; the Dirac form has none
    if chart is None:
        return None
    r, x, v = _sphere_leaf(model, fr, dps)
    return exact.sphere_pole_distance(r, x, v, axis=chart, dps=dps)


register_closed_form(ClosedForm("free_rigid_body", "closed form (Jacobi elliptic functions)", _rigid_exact,
                                many=_rigid_many, radius=_rigid_radius))
register_closed_form(ClosedForm("great_circle", "closed form (great circle)", _great_circle,
                                radius=_great_circle_radius))


def reference_solution(system, y0, t, dps: int = 40, reference=None) -> Reference:
    """The reference :func:`observables` at time ``t`` for a run from ``y0``.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Initial state (its exact value is used).
    t : number
        Final time.
    dps : int
        Digits of the reference (pick ~10 more than the most accurate run to be measured).
    reference : sequence of n numbers, optional
        A state at ``t`` supplied by the caller; used instead of computing one.

    Returns
    -------
    Reference
    """
    if isinstance(dps, bool) or not isinstance(dps, int) or dps < 5:
        raise ValueError(f"`dps` must be an integer >= 5; got {dps!r}")
    ps = as_poisson_system(system)
    fr = state_fractions(y0, ps.dimension, "y0")
    tf = to_fraction(t, "t")
    names = observable_names(system)
    if reference is not None:
        vals = observables(system, reference, dps)
        return Reference(float(tf), vals, names, "given", "reference state given by the caller", dps)
    form = _closed_form(system)
    if form is not None:
        vals = form.at(as_model(system), fr, tf, dps)
        return Reference(float(tf), vals, names, "exact", form.label, dps)
    rows, label = numerical_reference(system, fr, tf, dps_to_bits(dps) + 16)
    return Reference(float(tf), observables(system, rows[-1], dps), names, "numerical", label, dps)


def reference_solutions(system, y0, ts, dps: int = 30) -> list:
    """Reference :func:`observables` at several times (list of lists of mpf), or None without a closed form.

    One set-up for all times (rigid body: :func:`lieseries.exact.euler_poisson_many`).
    """
    ps = as_poisson_system(system)
    fr = state_fractions(y0, ps.dimension, "y0")
    times = [to_fraction(v, "ts") for v in ts]
    form = _closed_form(system)
    if form is None:
        return None
    if form.many is not None:
        return form.many(as_model(system), fr, times, dps)
    return [form.at(as_model(system), fr, tk, dps) for tk in times]


def max_difference(values, reference, dps: int) -> float:
    """max_i |values_i - reference_i| of two lists of mpf (any context), computed at ``dps`` digits in this
    thread's mpmath context (each left operand converted into it: a global mpf on the left would compute at the
    global precision)."""
    with mp.workdps(dps):
        return float_or_mpf(max(abs(mp.mpf(a) - b) for a, b in zip(values, reference)))


def state_error(system, y, reference: Reference) -> float:
    """Largest absolute difference between the :func:`observables` of ``y`` and ``reference``."""
    return max_difference(observables(system, y, reference.dps), reference.values, reference.dps)


def theoretical_radius(system, y0, dps: int = 30):
    """Radius of convergence (in time) of the Lie series at ``y0``, where known; else None.

    Rigid body: the distance from t = 0 to the nearest complex-time pole of Omega(t)
    (:func:`lieseries.exact.rigid_body_constants`). Sphere, 5-dimensional form: the distance to the nearest
    complex zero of the dependent coordinate x_chart(t) (:func:`lieseries.exact.sphere_pole_distance`).
    The Dirac form has no singularity on the sphere: None. Infinite radii are returned as None.
    """
    ps = as_poisson_system(system)
    fr = state_fractions(y0, ps.dimension, "y0")
    form = _closed_form(system)
    if form is None or form.radius is None:
        return None
    rho = form.radius(as_model(system), fr, dps)
    if rho is None:
        return None
    if not mp.isfinite(rho):
        return None
    return rho


def loglog_slope(x, y):
    """Least-squares slope of log(y) against log(x) over the points where both are positive (None if < 3)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    m = (x > 0) & (y > 0) & np.isfinite(x) & np.isfinite(y)
    if m.sum() < 3:
        return None
    return float(np.polyfit(np.log(x[m]), np.log(y[m]), 1)[0])


def finite_or_none(v):
    if v is None:
        return None
    f = float(v)
    if f == 0 and v != 0:
        return v  # below a float's range: kept, not read as an exact 0
    return f if math.isfinite(f) else None
