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
"""

from __future__ import annotations

import mpmath as mp

from ..models.base import Model, state_fractions
from ..poisson import as_poisson_system
from ..precision import check_dps, check_order, to_mpf

__all__ = ["LieSeries", "lie_series"]
#: Guard digits carried above the requested precision inside the operator.
GUARD_DIGITS = 10


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
    """Radius of convergence from coefficient norms: least-squares slope of log||c_k|| over the upper half.

    Returns ``mp.inf`` when the coefficients vanish (a polynomial solution).
    """
    N = len(nrm) - 1
    pts = [(k, mp.log(nrm[k])) for k in range(max(1, N // 2), N + 1) if nrm[k] > 0]
    if len(pts) < 2:
        pts = [(k, mp.log(nrm[k])) for k in range(1, N + 1) if nrm[k] > 0]
    if not pts:
        return mp.inf
    if len(pts) == 1:
        k, lg = pts[0]
        return mp.exp(-lg / k)
    kbar = mp.fsum(k for k, _ in pts) / len(pts)
    lbar = mp.fsum(lg for _, lg in pts) / len(pts)
    num = mp.fsum((k - kbar) * (lg - lbar) for k, lg in pts)
    den = mp.fsum((k - kbar) ** 2 for k, _ in pts)
    slope = num / den
    if slope >= 0:
        # coefficients not decaying: a radius below 1, from the root test on the last one
        k, lg = pts[-1]
        return mp.exp(-lg / k)
    return mp.exp(-slope)


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


class LieSeries:
    """exp(t X_H) truncated at ``order``, applied to the state ``y0``: z(t) ~ sum_{k<=order} c_k t^k.

    Attributes
    ----------
    coefficients : list of order+1 lists of n mpf
        c_k = L^k z (y0) / k!, rounded to ``dps`` digits.
    order, dps : int
    names : tuple of str
        Variable names, in state order.
    """

    def __init__(self, coefficients, order, dps, names, t0=0):
        self.coefficients = coefficients
        self.order = order
        self.dps = dps
        self.names = names
        self.t0 = t0
        with mp.workdps(dps + GUARD_DIGITS):
            self._norms = norms(coefficients)
            self._radius = estimate_radius(self._norms)

    def __call__(self, t) -> list:
        """The truncated series at time ``t`` (relative to the expansion point), as mpf rounded to ``dps``."""
        return self.partial_sum(t, self.order)

    def partial_sum(self, t, order: int) -> list:
        """sum_{k <= order} c_k t^k."""
        order = check_order(order)
        if order > self.order:
            raise ValueError(f"`order` must be at most the series order {self.order}; got {order}")
        with mp.workdps(self.dps + GUARD_DIGITS):
            vals = horner(self.coefficients, to_mpf(t, "t"), order)
        with mp.workdps(self.dps):
            return [+v for v in vals]

    def radius(self) -> mp.mpf:
        """Estimated radius of convergence in t (``inf`` for an entire or polynomial solution)."""
        with mp.workdps(self.dps):
            return +self._radius

    def error_estimate(self, t) -> mp.mpf:
        """Estimated truncation error at ``t``; ``inf`` where the series diverges (|t| >= radius)."""
        with mp.workdps(self.dps + GUARD_DIGITS):
            e = tail_estimate(self._norms, to_mpf(t, "t"), self._radius)
        with mp.workdps(self.dps):
            return +e

    def converges(self, t) -> bool:
        """False where |t| is at or beyond the estimated radius of convergence."""
        return abs(to_mpf(t, "t")) < self._radius

    def __repr__(self) -> str:
        return f"LieSeries(order={self.order}, dps={self.dps}, radius~{mp.nstr(self._radius, 5)})"


def lie_series(system, y0, order: int = 20, dps: int = 30) -> LieSeries:
    """The truncated Lie series exp(t X_H) y0 of a model or PoissonSystem, in mpmath.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Expansion point, taken at its exact value (strings, Fractions and mpf keep full precision).
    order : int >= 1
        Truncation order N: coefficients c_0..c_N.
    dps : int >= 5
        Decimal digits of the result (the computation carries 10 guard digits).

    Examples
    --------
    >>> body = ls.EulerPoisson((1, 2, 3))
    >>> series = ls.lie_series(body, body.initial_state((1, "0.1", "0.5"), precision=200), order=40, dps=50)
    >>> series(0.5)                 # state at t = 0.5
    >>> series.error_estimate(0.5)  # truncation error estimate
    """
    from .jets import taylor_coefficients

    order = check_order(order)
    dps = check_dps(dps)
    ps, _model, z0, pars = prepare(system, y0)
    with mp.workdps(dps + GUARD_DIGITS):
        coeffs = taylor_coefficients(ps.program, z0, pars, order, dps + GUARD_DIGITS)
    with mp.workdps(dps):
        coeffs = [[+c for c in ck] for ck in coeffs]
    return LieSeries(coeffs, order, dps, ps.names)

