"""Error of the truncated Lie series against its order, and the radius of convergence it reveals.

The Lie series z(t) = sum_k c_k t^k, c_k = L^k z(y0) / k!, converges for |t| < rho, rho the distance in complex
time from t = 0 to the nearest singularity of the solution. Inside the disc the truncation error at order N
behaves like C (|t| / rho)^N, so log10(error_N) is a straight line in N with slope log10(|t| / rho): fitting it
measures rho, and comparing with the pole distance of the closed-form solution checks the series end to end.

The fit uses least squares over the orders whose error lies above the precision floor (100 x 10^-dps; below
it the error is round-off, not truncation), from ``fit_min_order`` up, by default the upper half of them (low
orders can be pre-asymptotic).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..poisson import as_poisson_system
from ..precision import thread_mp as mp
from ..precision import to_fraction
from .reference import (finite_or_none, max_difference, observable_names, observables, reference_solution,
                        theoretical_radius)

__all__ = ["ErrorVsOrder", "error_vs_order", "fit_geometric_rate"]

#: Errors below FLOOR_FACTOR * 10^-dps are round-off and are left out of the fit.
FLOOR_FACTOR = 100


@dataclass
class ErrorVsOrder:
    """Truncation error of the Lie series at one time, for several orders.

    Attributes
    ----------
    t : float
        The time at which the truncated series is evaluated.
    orders : list of int
    errors : list of float
        Max-abs error of the truncated series against the reference, one per order.
    rate : float or None
        Fitted slope of log10(error) against order (negative when the series converges); None when fewer than
        three points lie above the floor.
    radius_measured : float or None
        |t| * 10^(-rate): the radius of convergence implied by the fit.
    radius_theory : float or None
        The distance to the nearest singularity of the exact solution, where known.
    floor : float
        Errors below this (100 x 10^-dps) are round-off and excluded from the fit.
    fit_orders : list of int
        The orders used in the fit.
    intercept : float or None
        log10 of the fitted error at order 0 (for drawing the fitted line).
    dps : int
        Working digits of the series and of the partial sums.
    reference : str
        What the errors are measured against.
    system : str
        Name of the system.
    quantities : list of str
        What is compared (state entries, or position and velocity for the sphere).
    """

    t: float
    orders: list
    errors: list
    rate: float | None
    radius_measured: float | None
    radius_theory: float | None
    floor: float
    fit_orders: list = field(default_factory=list)
    intercept: float | None = None
    dps: int = 60
    reference: str = ""
    system: str = ""
    quantities: list = field(default_factory=list)

    @property
    def radius_ratio(self) -> float | None:
        """radius_measured / radius_theory, when both are known."""
        if self.radius_measured is None or not self.radius_theory:
            return None
        return self.radius_measured / self.radius_theory

    def to_dict(self) -> dict:
        return {
            "t": self.t,
            "orders": list(self.orders),
            "errors": list(self.errors),
            "rate": self.rate,
            "radius_measured": self.radius_measured,
            "radius_theory": self.radius_theory,
            "radius_ratio": self.radius_ratio,
            "floor": self.floor,
            "fit_orders": list(self.fit_orders),
            "intercept": self.intercept,
            "dps": self.dps,
            "reference": self.reference,
            "system": self.system,
            "quantities": list(self.quantities),
        }


def fit_geometric_rate(orders, errors, floor: float, min_order: int | None = None):
    """Least-squares slope and intercept of log10(error) against order, above ``floor``.

    Uses the orders >= ``min_order`` whose error exceeds ``floor``. By default (``min_order=None``) the upper
    half of the orders above the floor: the low orders can be pre-asymptotic (near the separatrix of the rigid
    body the error falls steeply up to order ~20 before it settles on its geometric rate). When fewer than
    three points qualify, every order above the floor is used.

    Returns
    -------
    slope, intercept : float or None
    used : list of int
        The orders used.
    """
    n = np.asarray(orders, dtype=float)
    e = np.asarray(errors, dtype=float)
    ok = (e > floor) & np.isfinite(e)
    if min_order is None:
        above = np.sort(n[ok])
        min_order = above[len(above) // 2] if len(above) >= 6 else (above[0] if len(above) else 0)
    sel = ok & (n >= min_order)
    if sel.sum() < 3:
        sel = ok
    if sel.sum() < 3:
        return None, None, [int(v) for v in n[sel]]
    slope, intercept = np.polyfit(n[sel], np.log10(e[sel]), 1)
    return float(slope), float(intercept), [int(v) for v in n[sel]]


def _check_orders(orders):
    if isinstance(orders, (str, bytes)) or not hasattr(orders, "__iter__"):
        raise TypeError(f"`orders` must be a sequence of non-negative integers; got {type(orders).__name__}")
    out = []
    for i, k in enumerate(orders):
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
            raise ValueError(f"`orders[{i}]` must be a non-negative integer; got {k!r}")
        out.append(int(k))
    if not out:
        raise ValueError("`orders` must not be empty")
    return sorted(set(out))


def error_vs_order(system, y0, t, orders, dps: int = 60, reference=None, *, fit_min_order: int | None = None,
                   progress=None) -> ErrorVsOrder:
    """Error of the Lie series truncated at each order in ``orders``, at time ``t``.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Initial state (exact value used; build it with ``precision=`` bits for high-precision studies).
    t : number
        Evaluation time; inside the radius of convergence for a meaningful fit (0.5-0.8 of it is a good choice).
    orders : sequence of int
        Truncation orders; the series is built once at ``max(orders)``.
    dps : int
        Digits of the series coefficients and partial sums. The floor of the fit is 100 x 10^-dps.
    reference : sequence of n numbers, optional
        The state at ``t``; default: the closed form (see :mod:`lieseries.studies`).
    fit_min_order : int, optional
        Orders below this are left out of the fit (pre-asymptotic). Default: fit the upper half of the orders
        above the floor (see :func:`fit_geometric_rate`).
    progress : callable, optional
        Called as ``progress(done, total, label)``.

    Returns
    -------
    ErrorVsOrder
    """
    from ..lie.operator import lie_series

    if isinstance(dps, bool) or not isinstance(dps, int) or dps < 10:
        raise ValueError(f"`dps` must be an integer >= 10; got {dps!r}")
    orders = _check_orders(orders)
    tf = to_fraction(t, "t")
    ps = as_poisson_system(system)
    total = len(orders) + 2
    if progress:
        progress(0, total, "Lie series")
    series = lie_series(system, y0, order=max(orders), dps=dps)
    coeffs = series.coefficients
    if len(coeffs) < max(orders) + 1:
        raise RuntimeError(f"the Lie series has {len(coeffs)} coefficients; expected {max(orders) + 1}")
    if progress:
        progress(1, total, "reference")
    ref = reference_solution(system, y0, tf, dps=dps + 10, reference=reference)
    if progress:
        progress(2, total, "partial sums")
    errors = []
    n = ps.dimension
    with mp.workdps(dps):
        tm = mp.mpf(tf.numerator) / tf.denominator
        for done, N in enumerate(orders):
            # Horner: sum_{k <= N} c_k t^k
            acc = [mp.mpf(c) for c in coeffs[N]]
            for k in range(N - 1, -1, -1):
                ck = coeffs[k]
                acc = [acc[i] * tm + ck[i] for i in range(n)]
            errors.append(max_difference(observables(system, acc, dps + 10), ref.values, dps + 10))
            if progress:
                progress(3 + done, total, f"order {N}")
    floor = FLOOR_FACTOR * 10.0 ** (-dps)
    slope, intercept, used = fit_geometric_rate(orders, errors, floor, fit_min_order)
    radius_measured = None
    if slope is not None and tf != 0:
        radius_measured = abs(float(tf)) * 10.0 ** (-slope)
    rho = theoretical_radius(system, y0, dps=30)
    return ErrorVsOrder(
        t=float(tf),
        orders=orders,
        errors=errors,
        rate=slope,
        radius_measured=finite_or_none(radius_measured),
        radius_theory=finite_or_none(rho),
        floor=floor,
        fit_orders=used,
        intercept=intercept,
        dps=dps,
        reference=ref.label,
        system=getattr(ps, "name", ""),
        quantities=list(observable_names(system)),
    )
