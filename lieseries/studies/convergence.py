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

import math
from dataclasses import dataclass, field

import mpmath
import numpy as np

from fractions import Fraction

from .. import fields as F
from ..lie.operator import lie_series
from ..methods.pricing import CostPart
from ..formatting import (MARKERS, below_float_range, fmt_num, fmt_sci, log10_or_nan, markdown_table, positive_or_nan,
                          pyplot, save_figure)
from ..poisson import as_poisson_system
from ..precision import thread_mp as mp
from ..precision import MAX_DPS, MAX_ORDER, MIN_DPS, check_count, to_fraction
from .plugin import Study, register_study
from .reference import (finite_or_none, max_difference, observable_names, observables, reference_solution,
                        theoretical_radius)

__all__ = ["ErrorVsOrder", "error_vs_order", "fit_geometric_rate", "orders_of", "ErrorVsOrderStudy"]

#: Errors below FLOOR_FACTOR * 10^-dps are round-off and are left out of the fit.
FLOOR_FACTOR = 100
#: Digits the closed-form reference carries above the series' ``dps`` (so its errors are resolved): the study's
#: ``dps`` is at most MAX_DPS - REFERENCE_DIGITS, the reference's own bound.
REFERENCE_DIGITS = 10
MAX_STUDY_DPS = MAX_DPS - REFERENCE_DIGITS


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


def log10_size(x) -> float:
    """log10(x) of a positive number as a float, also for an mpf or a Fraction below a float's range (an error of
    1e-402); NaN for None, zero, a negative or a non-finite number."""
    if x is None:
        return math.nan
    try:
        f = float(x)
    except (TypeError, ValueError, OverflowError):
        return math.nan
    if f > 0 and math.isfinite(f):
        return math.log10(f)
    if f == 0 and x > 0:
        v = x if hasattr(x, "_mpf_") else mpmath.mpf(x.numerator) / x.denominator
        return float(mpmath.log10(v))
    return math.nan


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
    le = np.array([log10_size(v) for v in errors], dtype=float)  # mpf errors below a float's range too
    lfloor = log10_size(floor) if floor is not None and floor > 0 else -math.inf
    ok = np.isfinite(le) & (le > lfloor)
    if min_order is None:
        above = np.sort(n[ok])
        min_order = above[len(above) // 2] if len(above) >= 6 else (above[0] if len(above) else 0)
    sel = ok & (n >= min_order)
    if sel.sum() < 3:
        sel = ok
    if sel.sum() < 3:
        return None, None, [int(v) for v in n[sel]]
    slope, intercept = np.polyfit(n[sel], le[sel], 1)
    return float(slope), float(intercept), [int(v) for v in n[sel]]


def _check_orders(orders):
    if isinstance(orders, (str, bytes)) or not hasattr(orders, "__iter__"):
        raise TypeError(f"`orders` must be a sequence of non-negative integers; got {type(orders).__name__}")
    out = []
    for i, k in enumerate(orders):
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= MAX_ORDER:
            raise ValueError(f"`orders[{i}]` must be an integer in [0, {MAX_ORDER}] (a series order); got {k!r}")
        out.append(int(k))
    if not out:
        raise ValueError("`orders` must not be empty")
    if max(out) < 1:
        raise ValueError(f"`orders` must reach order 1 at least (the series is built at the largest); got {out}")
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

    orders = _check_orders(orders)
    dps = check_count(dps, "dps", low=MIN_DPS, high=MAX_STUDY_DPS)
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
    ref = reference_solution(system, y0, tf, dps=dps + REFERENCE_DIGITS, reference=reference)
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
            errors.append(max_difference(observables(system, acc, dps + REFERENCE_DIGITS), ref.values, dps + REFERENCE_DIGITS))
            if progress:
                progress(3 + done, total, f"order {N}")
    # below a float's range (more than ~300 digits) an mpf: a floor of 0.0 would fit noise
    floor = FLOOR_FACTOR * 10.0 ** (-dps) if dps < 300 else mpmath.mpf(FLOOR_FACTOR) * mpmath.mpf(10) ** (-dps)
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


# -- the study in scenes and reports ---------------------------------------------------------------------------
def orders_of(ev) -> list:
    """The orders of an ``error_vs_order`` table: ``orders``, or ``min_order .. max_order`` by ``step``."""
    if ev.get("orders") is not None:
        return sorted(set(int(o) for o in ev["orders"]))
    top = ev["max_order"] if ev.get("max_order") is not None else 40
    return list(range(ev.get("min_order", 1), top + 1, ev.get("step", 1)))


class ErrorVsOrderStudy(Study):
    """``[studies.error_vs_order]``: the truncated series against its order, at one time, per model."""

    name = "error_vs_order"
    title = "Error vs order"
    quick_doc = "error vs order up to half the largest order (at least 12) and at most 40 digits"
    fields = {
        "t": (F.time(), None),
        "t_fraction": (F.fraction01, None),
        "orders": (F.orders, None),
        "max_order": (F.order, None),
        "min_order": (F.integer(0, MAX_ORDER), 1),
        "step": (F.integer(1, 1000), 1),
        "dps": (F.count(MIN_DPS, MAX_STUDY_DPS), 60),
        "fit_min_order": (F.integer(0, MAX_ORDER), None),
    }
    docs = {
        "t": ("number", "the time at which the truncated series is compared"),
        "t_fraction": ("number in (0, 1)", "or t as this fraction of the theoretical radius of convergence"),
        "orders": ("list of integers", "the orders (or max_order, min_order, step)"),
        "max_order": ("integer", "the largest order"),
        "min_order": ("integer", "the smallest order"),
        "step": ("integer", "the step between orders"),
        "dps": ("integer", "digits of the series and of the reference"),
        "fit_min_order": ("integer", "the smallest order in the rate fit (default: the upper half)"),
    }

    def check(self, ev, run, models, where):
        if (ev["t"] is None) == (ev["t_fraction"] is None):
            raise F.SceneError("`studies.error_vs_order` needs exactly one of `t` (a time) or `t_fraction` (a "
                               "fraction of the theoretical radius of convergence)" + (
                                   "; got both" if ev["t"] is not None else "; missing required field "
                                   "`studies.error_vs_order.t`"))
        if ev["orders"] is not None and ev["max_order"] is not None:
            raise F.SceneError("`studies.error_vs_order` takes `orders` or `max_order`, not both")
        try:  # the orders the study runs, as error_vs_order checks them
            _check_orders(orders_of(ev))
        except ValueError as err:
            raise F.SceneError(f"`studies.error_vs_order` (min_order = {ev['min_order']}, max_order = "
                               f"{ev['max_order']}, step = {ev['step']}): {err}") from None
        if ev["t_fraction"] is not None and all(theoretical_radius(model, y0) is None
                                                for _path, _spec, model, y0 in models):
            raise F.SceneError("`studies.error_vs_order.t_fraction` needs a theoretical radius of convergence, "
                               "which no model of this scene has (the Dirac form of the sphere, a damped body and "
                               "a model without a closed form have none); give `t` instead")

    def quick(self, ev):
        orders = orders_of(ev)
        top = max(12, max(orders) // 2)
        ev["orders"] = [o for o in orders if o <= top]
        ev["max_order"] = None
        ev["dps"] = min(ev["dps"], 40)

    def cost(self, ev, ctx, pricer):
        top = max(orders_of(ev))
        dps = int(ev["dps"])
        model = ctx.built[0][1]
        y0 = ctx.initial_state(model)
        o_c = min(top, 12)
        _, secs = pricer.timed(lambda: lie_series(model, y0, order=o_c, dps=dps))
        return [CostPart("studies.error_vs_order.max_order", f"{len(ctx.built)} Lie series to order {top} at {dps} "
                         "digits", len(ctx.built), "series", secs * (top / o_c) ** 2,
                         f"timed to order {o_c}, scaled by order^2")]

    def run(self, opts, ctx):
        orders = orders_of(opts)
        states = [(lab, model, ctx.initial_state(model)) for lab, model in ctx.built]
        if opts["t"] is not None:
            t = to_fraction(opts["t"])
        else:
            radii = [theoretical_radius(model, y0) for _, model, y0 in states]
            radii = [r for r in radii if r is not None]
            if not radii:
                raise F.SceneError("`studies.error_vs_order.t_fraction`: no model of this scene has a known radius "
                                   "of convergence; give `t`")
            t = to_fraction(opts["t_fraction"]) * to_fraction(min(radii))
            t = Fraction(t).limit_denominator(10**12)
        out = []
        for i, (lab, model, y0) in enumerate(states):
            try:
                res = error_vs_order(model, y0, t, orders, dps=opts["dps"], fit_min_order=opts["fit_min_order"],
                                     progress=ctx.model_progress(i, lab))
            except Exception as err:  # one failing model must not take the rest of the report with it
                ctx.notes.append(f"error vs order ({lab}): failed: {type(err).__name__}: {err}")
                ctx.failed.append(f"error vs order ({lab}): {type(err).__name__}: {err}")
                continue
            out.append((lab, res))
        return out

    def section(self, items, ctx):
        lines, csvs = [], []
        if not items:
            return ["Not computed (see the notes).", ""], csvs
        lines.append("Error of the Lie series truncated at order N, at a fixed time t. Inside the disc of "
                     "convergence error_N ~ C (|t| / rho)^N: the least-squares slope of log10(error) against N (over "
                     "the orders listed, above the precision floor 100 x 10^-dps; by default the upper half of them, "
                     "since low orders can be pre-asymptotic) gives rho = |t| 10^(-slope), compared with the distance "
                     "to the nearest singularity of the exact solution.")
        lines.append("")
        h = ["model", "t", "dps", "fitted slope [log10/order]", "rho measured", "rho theory", "measured / theory",
             "orders fitted"]
        rows = []
        for mlabel, ev in items:
            fit = f"{min(ev.fit_orders)}-{max(ev.fit_orders)}" if ev.fit_orders else ""
            rows.append([mlabel, fmt_num(ev.t), str(ev.dps), fmt_sci(ev.rate, 4), fmt_sci(ev.radius_measured, 4),
                         fmt_sci(ev.radius_theory, 4) if ev.radius_theory else "none",
                         f"{ev.radius_ratio:.4f}" if ev.radius_ratio else "", fit])
        lines += [markdown_table(h, rows), ""]
        csvs.append(("error_vs_order_fit.csv", h, rows))
        orders = sorted({o for _, ev in items for o in ev.orders})
        h2 = ["order"] + [f"error ({m})" if len(items) > 1 else "error" for m, _ in items]
        maps = [dict(zip(ev.orders, ev.errors)) for _, ev in items]
        rows2 = [[str(o)] + [fmt_sci(em.get(o)) for em in maps] for o in orders]
        csvs.append(("error_vs_order.csv", h2, rows2))
        for mlabel, ev in items:
            if ev.radius_theory is None:
                lines.append(f"- {mlabel}: no finite theoretical radius (no singularity at finite complex time), so "
                             "the fitted 'radius' only describes the orders shown; an entire series falls faster "
                             "than any geometric rate.")
        lines.append(f"- Reference: {items[0][1].reference}. Full error table: `error_vs_order.csv`.")
        lines.append("")
        lines += ["<details><summary>Error against order</summary>", "", markdown_table(h2, rows2), "", "</details>",
                  ""]
        if ctx.plotted:
            lines += ["![error vs order](error_vs_order.png)", ""]
        return lines, csvs

    def plot(self, items, path, scene):
        import math

        plt = pyplot()
        fig, ax = plt.subplots(figsize=(7.5, 5.5))
        # errors a double cannot draw (above ~300 digits: 1e-400 is 0.0, and a log axis left them out): the axis
        # then shows log10 of the errors, from their exact values, and the lines in log10 directly
        tiny = any(below_float_range(e) for _, ev in items for e in ev.errors)
        draw = ax.plot if tiny else ax.semilogy

        def logs(values):  # a line given by its log10 values
            return list(values) if tiny else [10 ** v for v in values]

        for k, (mlabel, ev) in enumerate(items):
            color = f"C{k}"
            draw(ev.orders, log10_or_nan(ev.errors) if tiny else positive_or_nan(ev.errors),
                 marker=MARKERS[k % len(MARKERS)], linestyle="none", color=color, markersize=4,
                 label=f"{mlabel}: truncation error at t = {ev.t:.4g}")
            if ev.rate is not None and ev.fit_orders:
                xs = [min(ev.fit_orders), max(ev.fit_orders)]
                draw(xs, logs(ev.intercept + ev.rate * x for x in xs), "-", color=color, linewidth=1,
                     label=f"fit: rho = {ev.radius_measured:.4g}")
                if ev.radius_theory:
                    slope = math.log10(abs(ev.t) / ev.radius_theory)
                    mid = 0.5 * (xs[0] + xs[1])
                    anchor = ev.intercept + ev.rate * mid
                    draw(xs, logs(anchor + slope * (x - mid) for x in xs), ":", color="k",
                         linewidth=1.2, label=f"theory: (t / rho)^N, rho = {ev.radius_theory:.4g}")
        floor = min(ev.floor for _, ev in items)
        smallest = min((e for _, ev in items for e in ev.errors if e and e > 0), default=floor)
        # drawn when the data come near it (it would only stretch the axis otherwise)
        if floor > smallest * 1e-4 and (tiny or float(floor) > 0):
            ax.axhline(log10_or_nan([floor])[0] if tiny else float(floor), color="grey", linestyle="--",
                       linewidth=0.8, label=f"precision floor {fmt_sci(floor, 1)}")
        ax.set_xlabel("truncation order N")
        ax.set_ylabel("log10 of the max-abs error of the truncated Lie series" if tiny
                      else "max-abs error of the truncated Lie series")
        ax.set_title("Lie series: error against order (slope gives the radius of convergence)", fontsize=10)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3, which="both")
        save_figure(plt, fig, path)

    def summary(self, items):
        out = []
        for mlabel, ev in items:
            th = f", theory {ev.radius_theory:.4g}" if ev.radius_theory else ""
            rm = "n/a" if ev.radius_measured is None else f"{ev.radius_measured:.4g}"
            out.append(f"error vs order ({mlabel}): radius measured {rm}{th}")
        return out


register_study(ErrorVsOrderStudy())
