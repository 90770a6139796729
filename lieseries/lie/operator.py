"""The truncated Lie-series operator exp(t X_H) at a point, evaluated in mpmath.

The general solution of dz/dt = X_H(z) is the Lie series (paper, eqs. hvf7.1, hvf9)

    z(t) = exp(t L) z |_{z0} = sum_k t^k c_k,     c_k = L^k z (z0) / k!,     L = X_H . grad,

and ``c_k`` are the normalised Taylor coefficients of the solution at t = 0. :func:`lie_series` computes them by
truncated power-series arithmetic ("jets", :mod:`lieseries.lie.jets`) in O(order^2) operations per node of the
vector field's expression graph, at any precision; :mod:`lieseries.lie.literal` computes the same numbers the
paper's way, by iterated symbolic Lie derivatives, and the tests check one against the other.

Error estimate and radius of convergence
----------------------------------------
With a_k = ||c_k|| |t|^k (max norm over the state) the truncation error of the order-N sum is estimated from
the geometric tail that the last two terms imply: the next term is about max(a_{N-1} q, a_N) q with
q = |t| / rho, and the tail is that over (1 - q). ``rho`` is the radius of convergence estimated from the
coefficients by a least-squares fit of log ||c_k|| against k over the upper half of the orders (a root test
that tolerates coefficients that vanish by symmetry). For |t| >= rho the series diverges: the estimate is
``inf`` and :meth:`LieSeries.converges` is False.

No finite number of coefficients shows what comes after them: a pendulum started near its unstable equilibrium
(q0 = 3.1) has coefficients that fall as 1/k! up to order ~12, where the singularities at |t| ~ 5.5 take over,
and the estimate from orders up to 10 was 6-8 times below the error. :func:`lie_series` therefore also computes
the orders N+1..N+m (m = max(8, N/2)) at :data:`PROBE_DIGITS` digits by the fixed-point jets (a small part of the
series' own cost), whose magnitudes suffice: the estimate is the sum of their terms and the geometric tail beyond
them (never below the order-N tail estimate); ``rho`` stays the series' own orders' fit.
"""

from __future__ import annotations

import time

import numpy as np

from ..models.base import Model, state_fractions
from .fixed import fixed_taylor_coefficients
from .jets import taylor_coefficients
from .plan import DeadlineExceeded, radius_from_logs
from ..poisson import as_poisson_system
from ..precision import (
    LIE_GUARD_DIGITS,
    check_dps,
    check_order,
    check_seconds,
    data_bits,
    dps_to_bits,
    export_mpf,
    mp_context,
    to_mpf,
    warn_if_coarse,
)
from ..precision import thread_mp as mp

__all__ = ["LieSeries", "lie_series"]
#: Guard digits carried above the requested precision inside the operator (:data:`precision.LIE_GUARD_DIGITS`).
GUARD_DIGITS = LIE_GUARD_DIGITS
#: Digits at which :func:`lie_series` computes the orders after the series' own for its error estimate (their
#: magnitudes are what it reads).
PROBE_DIGITS = 20


def prepare(system, y0, argname="y0"):
    """(PoissonSystem, model or None, exact initial state, exact parameters) for a Lie-series computation."""
    ps = as_poisson_system(system)
    model = system if isinstance(system, Model) else None
    z0 = model.check_state(y0, argname) if model is not None else state_fractions(y0, ps.dimension, argname)
    return ps, model, z0, list(ps.parameter_values)


def horner(coefficients, t, order=None):
    """sum_{k <= order} c_k t^k for vector coefficients, in the current mpmath precision."""
    order = len(coefficients) - 1 if order is None else order
    n = len(coefficients[0])
    acc = list(coefficients[order])
    for k in range(order - 1, -1, -1):
        ck = coefficients[k]
        acc = [acc[i] * t + ck[i] for i in range(n)]
    return acc


def norms(coefficients):
    """Max-norm of each coefficient vector."""
    return [max(abs(c) for c in ck) for ck in coefficients]


def estimate_radius(nrm) -> mp.mpf:
    """Radius of convergence from coefficient norms: the slope of log||c_k|| over the upper half of the orders, fitted
    to the norms' upper envelope (:func:`lieseries.lie.plan.radius_from_logs`).

    Returns ``mp.inf`` when the coefficients vanish (a polynomial solution).
    """
    N = len(nrm) - 1
    pts = [(k, float(mp.log(nrm[k]))) for k in range(max(1, N // 2), N + 1) if nrm[k] > 0]
    if len(pts) < 2:
        pts = [(k, float(mp.log(nrm[k]))) for k in range(1, N + 1) if nrm[k] > 0]
    rho = radius_from_logs(pts)
    return mp.inf if rho == float("inf") else mp.mpf(rho)


def tail_estimate(nrm, t, rho) -> mp.mpf:
    """Estimated truncation error of the order-N sum at |t| (``inf`` when |t| >= rho)."""
    t = abs(t)
    if t == 0:
        return mp.mpf(0)
    if rho != mp.inf and t >= rho:
        return mp.inf
    N = len(nrm) - 1
    q = t / rho if rho != mp.inf else mp.mpf(0)
    a_last = nrm[N] * t**N
    a_prev = nrm[N - 1] * t ** (N - 1) if N >= 1 else mp.mpf(0)
    nxt = max(a_prev * q, a_last) * (q if q > 0 else mp.mpf(1))
    return nxt / (1 - q) if q < 1 else mp.inf


def _truncation(nrm, more, t, rho) -> mp.mpf:
    """The truncation error of the order-N sum at |t|: with the norms ``more`` of the orders after N, the sum of
    their terms and the geometric tail after them (or this order's own tail estimate, the larger); without,
    :func:`tail_estimate`."""
    own = tail_estimate(nrm, t, rho)
    if not more or own == mp.inf:
        return own
    a = abs(t)
    N = len(nrm) - 1
    seen = mp.fsum(m * a ** (N + 1 + j) for j, m in enumerate(more))
    return max(own, seen + tail_estimate(nrm + more, t, rho))


def _local(coefficients):
    """Coefficients as mpf of this thread's context (arithmetic takes the precision of its left operand's
    context, so mixing in mpmath's global mpf would round to the global precision)."""
    make = mp.make_mpf
    return [[make(c._mpf_) for c in ck] for ck in coefficients]


def _times(t, dps):
    """(values, scalar): a real or complex time, or a sequence/array of them, in this thread's context (binary
    times with fewer bits than ``dps`` digits give a PrecisionWarning)."""
    warn_if_coarse(data_bits(t), dps_to_bits(dps), "t")
    if np.ndim(t) > 0 and not isinstance(t, str):
        vals = [_time(v, f"t[{i}]") for i, v in enumerate(np.asarray(t, dtype=object).ravel())]
        return vals, False
    return [_time(t, "t")], True


def _time(t, argname):
    if isinstance(t, complex) or hasattr(t, "_mpc_") or (isinstance(t, np.generic) and np.iscomplexobj(t)):
        z = mp.mpc(complex(t) if not hasattr(t, "_mpc_") else t)
        if not (mp.isfinite(z.real) and mp.isfinite(z.imag)):
            raise ValueError(f"`{argname}` must be finite; got {t!r}")
        return z
    return to_mpf(t, argname, ctx=mp_context())


class LieSeries:
    """exp(t X_H) truncated at ``order``, applied to the state ``y0``: z(t) ~ sum_{k<=order} c_k t^k.

    ``t`` may be real or complex (the series is analytic in t; its radius of convergence is the distance to the
    nearest complex singularity), or an array of times (one state per time).

    Attributes
    ----------
    coefficients : list of order+1 lists of n mpf
        c_k = L^k z (y0) / k!, rounded to ``dps`` digits.
    order, dps : int
    names : tuple of str
        Variable names, in state order.
    data_bits : int or None
        The precision carried by the input data (``y0``, parameters); None when they are exact. Error estimates
        never go below the uncertainty this leaves in the data.
    """

    def __init__(self, coefficients, order, dps, names, t0=0, data_bits=None, beyond=None):
        self.order = order
        self.dps = dps
        self.names = names
        self.t0 = t0
        self.data_bits = data_bits
        prec = dps_to_bits(dps)
        with mp.workdps(dps + GUARD_DIGITS):
            nrm = norms(_local(coefficients))
            # the norms of the orders after the series' own (``beyond``: computed at fewer digits, module docstring)
            more = [] if beyond is None else [mp.make_mpf(v._mpf_) for v in beyond]
            radius = estimate_radius(nrm)
            # never below what the data carry, nor below the rounding of the result to `dps` digits
            floor = mp.mpf(2) ** (-min(data_bits or prec, prec)) * max(mp.mpf(1), nrm[0])
        # plain mpmath numbers (not the thread's private context), so a LieSeries pickles
        self._norms, self._radius, self._floor = export_mpf(nrm), export_mpf(radius), export_mpf(floor)
        self._beyond = export_mpf(more)
        self.coefficients = export_mpf(coefficients)

    def __call__(self, t):
        """The truncated series at time ``t`` (relative to the expansion point), as mpf rounded to ``dps``; one
        state per time for an array of times."""
        return self.partial_sum(t, self.order)

    def partial_sum(self, t, order: int):
        """sum_{k <= order} c_k t^k."""
        order = check_order(order)
        if order > self.order:
            raise ValueError(f"`order` must be at most the series order {self.order}; got {order}")
        prec = dps_to_bits(self.dps)
        with mp.workdps(self.dps + GUARD_DIGITS):
            ts, scalar = _times(t, self.dps)
            coeffs = _local(self.coefficients)
            rows = [export_mpf(horner(coeffs, tk, order), prec) for tk in ts]
        return rows[0] if scalar else rows

    def radius(self) -> mp.mpf:
        """Estimated radius of convergence in t (``inf`` for an entire or polynomial solution)."""
        return export_mpf(self._radius, dps_to_bits(self.dps))

    def error_estimate(self, t):
        """Estimated error at ``t``: the truncation error, and never less than the uncertainty the data carry
        (``data_bits``) nor the rounding of the result to ``dps`` digits; ``inf`` where the series diverges
        (|t| >= radius)."""
        with mp.workdps(self.dps + GUARD_DIGITS):
            ts, scalar = _times(t, self.dps)
            nrm = [mp.make_mpf(v._mpf_) for v in self._norms]
            more = [mp.make_mpf(v._mpf_) for v in getattr(self, "_beyond", ())]
            radius, floor = mp.make_mpf(self._radius._mpf_), mp.make_mpf(self._floor._mpf_)
            es = [max(_truncation(nrm, more, tk, radius), floor) if tk != 0 else floor for tk in ts]
            es = [export_mpf(e, dps_to_bits(self.dps)) for e in es]
        return es[0] if scalar else es

    def converges(self, t):
        """False where |t| is at or beyond the estimated radius of convergence."""
        with mp.workdps(self.dps + GUARD_DIGITS):
            ts, scalar = _times(t, self.dps)
            out = [abs(tk) < mp.make_mpf(self._radius._mpf_) for tk in ts]
        return out[0] if scalar else out

    def __repr__(self) -> str:
        return f"LieSeries(order={self.order}, dps={self.dps}, radius~{mp.nstr(self._radius, 5)})"


def lie_series(system, y0, order: int = 20, dps: int = 30, *, max_time: float | None = None) -> LieSeries:
    """The truncated Lie series exp(t X_H) y0 of a model or PoissonSystem, in mpmath.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Expansion point, taken at its exact value (a model state built from exact input, strings, Fractions and
        mpf keep full precision). Binary data carrying fewer bits than ``dps`` digits give one
        :class:`~lieseries.precision.PrecisionWarning`, and the error estimates never claim more digits than the
        data carry.
    order : int in [1, precision.MAX_ORDER]
        Truncation order N: coefficients c_0..c_N.
    dps : int in [precision.MIN_DPS, precision.MAX_DPS]
        Decimal digits of the result (the computation carries 10 guard digits).
    max_time : float, optional
        Wall-time budget in seconds, as :func:`lieseries.lie_integrate`'s: the clock is read after every order,
        and once the budget is spent a :class:`TimeoutError` (``time_budget``, with the order reached) is raised
        -- a series of lower order than asked is never returned. The costly order 2000 at 3000 digits takes
        minutes.

    Examples
    --------
    >>> body = ls.EulerPoisson((1, 2, 3))
    >>> series = ls.lie_series(body, body.initial_state((1, "0.1", "0.5")), order=40, dps=50)
    >>> series(0.5)                 # state at t = 0.5
    >>> series.error_estimate(0.5)  # truncation error estimate
    """

    start = time.perf_counter()
    order = check_order(order)
    dps = check_dps(dps)
    max_time = check_seconds(max_time, "max_time")
    ps, _model, z0, pars = prepare(system, y0)
    bits = coarse_bits(ps, y0, dps_to_bits(dps))
    deadline = None if max_time is None else start + max_time
    try:
        with mp.workdps(dps + GUARD_DIGITS):
            coeffs = taylor_coefficients(ps.program, z0, pars, order, dps + GUARD_DIGITS, mp_context(),
                                         deadline=deadline)
            beyond = _beyond(ps, z0, pars, order, coeffs)
    except DeadlineExceeded as exc:
        raise DeadlineExceeded(exc.order, f"time_budget: `max_time` = {max_time:g} s ran out after "
                               f"{time.perf_counter() - start:.3g} s, at order {exc.order} of {order} ({dps} "
                               "digits); raise `max_time`, or ask a lower order or fewer digits") from None
    prec = dps_to_bits(dps)
    coeffs = [[export_mpf(c, prec) for c in ck] for ck in coeffs]
    return LieSeries(coeffs, order, dps, ps.names, data_bits=bits, beyond=beyond)


def _beyond(ps, z0, pars, order, coeffs):
    """The norms of the orders order+1 .. order+m (m = max(8, order/2)) at :data:`PROBE_DIGITS` digits, by the
    fixed-point jets at a time scale near the radius the series' own orders show (each held to those digits
    relative to its size there); None for a polynomial."""
    nrm = norms(coeffs)
    rho = estimate_radius(nrm)
    if rho == mp.inf:
        return None
    scale = int(mp.floor(mp.log(rho, 2)))
    with mp.workdps(PROBE_DIGITS + GUARD_DIGITS):
        try:
            more = fixed_taylor_coefficients(ps.program, z0, pars, order + max(8, order // 2), PROBE_DIGITS,
                                             time_scale=scale, ctx=mp_context())[order + 1:]
        except (ValueError, ArithmeticError):  # (a field whose roundings cost these digits all they carry: the
            return None  # estimate is the order-N tail's, as the series' own orders show it)
        return export_mpf(norms(more))


def coarse_bits(ps, y0, work_bits: int, *, times=()):
    """The least precision carried by ``y0`` and the system's data (None when exact), warning once per coarse
    input when it is below ``work_bits``; binary ``times`` (t, t0) below ``work_bits`` are warned about too (the
    run is exact for their binary values)."""
    found = {"y0": data_bits(y0)}
    found.update(ps.coarse_data())
    bits = [b for b in found.values() if b is not None]
    for name, value in zip(("t", "t0"), times):
        found[name] = data_bits(value)
    for name, b in found.items():
        warn_if_coarse(b, work_bits, name)
    return min(bits) if bits else None
