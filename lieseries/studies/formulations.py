"""The paper's comparison: one constrained system in its four Hamiltonian formulations, each run by each method.

For a model derived by :class:`~lieseries.models.constrained.ConstrainedSystem` (the scene kind ``constrained``
or a built-in model on it, such as ``spherical_pendulum``), or a model that derives itself by it
(``constrained_system()``: the rigid body and the heavy top from the nine entries of R, starting from the model's
own R and R hat(Omega)), ``[studies.formulations]`` runs

- ``dirac``: (q^A, p_A), 2n variables, the Dirac bracket (p8.7);
- ``reduced``: (q^A, p_i), n + k variables, on Phi = 0 (p8.13);
- ``intermediate``: (q^A, pi_i), n + k variables, the intermediate formalism (p9-p14);
- ``local``: canonical (x^i, p_i), 2(n - k) variables, in the chart ``chart``;

from the scene's [initial] q, qdot, with each method of ``methods`` (heyoka's Taylor method, the Lie series, ...).
Every run is compared on the same footing, in the original variables q^A(t) and their velocities: the error of
(q, qdot) at the time the run reached against a reference (the Dirac formulation by heyoka at a precision well
above every run's, stated in the report), the largest |G_alpha(q)| and |Phi_alpha(q, qdot)| along the run (the
constraints and their time derivatives, evaluated from q and qdot whatever the formulation's variables), the drift
of the energy, steps, run time, and where a chart (reduced, intermediate, local) ends: such a run stops with
status ``chart_edge`` and its row says at which time.

With ``radius_t``, the study also measures the radius of convergence of the Lie series exp(t X_H) y0 in each
formulation, in the formulation's own variables, as :mod:`~lieseries.studies.convergence` does: the error of the
series truncated at each order N, at t = ``radius_t``, against heyoka at 256 bits or more; inside the disc
error_N ~ C (t / rho)^N, and the least-squares slope of log10(error_N) gives rho. The formulations need not agree:
the series of one set of variables can converge for every t (the Dirac form of the sphere: sines and cosines)
while another's ends at a complex singularity (a local chart's momenta, which blow up where the chart does). A
radius is claimed only when the rate is steady: the radii fitted over the lower and the upper half of the fitted
orders agree within ``RADIUS_AGREEMENT``. A rate that steepens is a series falling faster than geometrically (an
entire series, or a singularity farther than these orders resolve): no radius is given. So is one that flattens,
or that has fewer than ``RADIUS_MIN_POINTS`` errors above the precision floor.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from fractions import Fraction

import sympy as sp

from .. import fields as F
from ..formatting import fmt_int, fmt_num, fmt_sci, markdown_table
from ..lie.operator import lie_series
from ..methods import method_label, normalize_method, reference_dps, run_method, scene_methods
from ..methods.pricing import CostPart
from ..models.constrained import ConstrainedSystem
from ..models.constrained_derive import SYMBOLIC_DIRAC_MAX_CONSTRAINTS
from ..precision import MIN_DPS, dps_to_bits, exact_states_read_at, float_or_mpf, to_fraction
from ..precision import thread_mp as mp
from .convergence import MAX_STUDY_DPS, error_vs_order, fit_geometric_rate
from .plugin import Study, register_study
from .reference import numerical_reference, numerical_reference_label

__all__ = ["FormulationRow", "FormulationComparison", "compare_formulations", "FormulationsStudy", "FORMULATIONS",
           "FormulationRadius", "formulation_radii", "radius_verdict", "radius_text", "RADIUS_AGREEMENT",
           "RADIUS_MIN_POINTS", "RADIUS_DIGITS"]

FORMULATIONS = ("dirac", "reduced", "intermediate", "local")

#: Statuses with which a run ended inside its chart's domain: a comparison, not a failure.
CHART_END = "chart_edge"


@dataclass
class FormulationRow:
    """One formulation run by one method, measured in the original variables (module docstring)."""

    formulation: str
    dimension: int
    method: str
    status: str
    t: float
    error: float | None
    G: float | None
    Phi: float | None
    energy: float | None
    steps: int | None
    run_time: float | None
    message: str = ""
    q: list | None = None      # q^A at the time reached (floats)
    qdot: list | None = None   # their velocities

    def to_dict(self) -> dict:
        return dict(self.__dict__)


#: A radius is claimed when the radii fitted over the lower and the upper half of the fitted orders differ by less
#: than this factor. A geometric rate (a pole or branch point at distance rho) keeps its slope: the halves agree to a
#: few per cent (up to ~12 % where the errors come in pairs, as for an even function). An entire series of order 1
#: (errors ~ t^N / N!) over orders [a, 2a] steepens by a factor ~1.35-1.45 between the halves.
RADIUS_AGREEMENT = 1.2

#: Fewest errors above the precision floor for a radius to be fitted (three per half).
RADIUS_MIN_POINTS = 6


@dataclass
class FormulationRadius:
    """The radius of convergence of one formulation's Lie series, measured at one time (module docstring).

    ``radius`` is the fitted rho, or None when the data do not support one (``verdict`` says why); ``radius_fit``
    is the fit over all fitted orders whatever the verdict, ``radius_low`` / ``radius_high`` over their lower and
    upper halves."""

    formulation: str
    dimension: int
    t: float
    dps: int
    verdict: str
    radius: float | None
    radius_fit: float | None = None
    radius_low: float | None = None
    radius_high: float | None = None
    slope: float | None = None
    fit_orders: list = field(default_factory=list)
    orders: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    reference: str = ""
    message: str = ""

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class FormulationComparison:
    t: float
    rows: list
    reference: str
    notes: list = field(default_factory=list)
    radii: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"t": self.t, "reference": self.reference, "notes": list(self.notes),
                "rows": [r.to_dict() for r in self.rows], "radii": [r.to_dict() for r in self.radii]}


def _system_of(model):
    """The ConstrainedSystem behind a scene's model: a formulation of one (``model.system``), or a built-in model
    that derives itself by the paper's method (``model.constrained_system()``, the rigid body and the heavy top);
    None otherwise."""
    system = getattr(model, "system", None)
    if isinstance(system, ConstrainedSystem):
        return system
    derive = getattr(model, "constrained_system", None)
    if callable(derive):
        system = derive()  # a ValueError says why this model has none (a damped body)
        return system if isinstance(system, ConstrainedSystem) else None
    return None


def _start(model, ini, y0):
    """(q, qdot) the comparison starts from: the scene's [initial] q, qdot, or the point of the model's own
    initial state ``y0`` (a rigid body's R and R hat(Omega), exact)."""
    if "q" in ini and "qdot" in ini:
        return ini["q"], ini["qdot"]
    return model.surface_point(y0)


def _formulation(system, name, chart, dependent):
    if name == "dirac":
        return system.dirac()
    if name == "reduced":
        return system.reduced(dependent)
    if name == "intermediate":
        return system.intermediate(dependent)
    return system.local(chart)


class _Constraints:
    """G_alpha(q) and Phi_alpha = dG_alpha/dq . qdot at the system's exact parameter values: evaluated exactly (the
    states' numbers are binary rationals) where the constraints are rational functions, else by sympy at ``dps``
    digits (no mpmath global context, whose 15 digits would hide a quad run's residuals)."""

    def __init__(self, system, dps: int):
        self.q = [sp.Symbol(c, real=True) for c in system.coordinates]
        vals = {sp.Symbol(k, real=True): sp.Rational(v.numerator, v.denominator)
                for k, v in system.parameter_values.items()}
        self.G = [g.xreplace(vals) for g in system.constraints]
        self.grad = [[sp.diff(g, qa) for qa in self.q] for g in self.G]
        self.dps = dps

    def _value(self, e, subs):
        v = e.xreplace(subs)
        if not v.is_Rational:
            v = sp.Rational(v.evalf(self.dps + 10))
        return mp.mpf(int(v.p)) / int(v.q)

    def residuals(self, q, v):
        """(max |G_alpha|, max |Phi_alpha|) at one configuration and velocity (lists of exact Fractions)."""
        subs = {s: sp.Rational(c.numerator, c.denominator) for s, c in zip(self.q, q)}
        vel = [sp.Rational(c.numerator, c.denominator) for c in v]
        g = max(abs(self._value(f, subs)) for f in self.G)
        phi = max(abs(self._value(sum(d * vk for d, vk in zip(row, vel)), subs)) for row in self.grad)
        return g, phi


def _mpf(v):
    f = to_fraction(v)
    return mp.mpf(f.numerator) / f.denominator


def _qv(model, state):
    """q and qdot of a state as exact Fractions (the state's own binary values)."""
    return [to_fraction(c) for c in model.configuration(state)], [to_fraction(c) for c in model.velocity(state)]


def compare_formulations(system, q, qdot, t, methods, *, formulations=FORMULATIONS, chart=None, dependent=None,
                         samples: int = 11, progress=None) -> FormulationComparison:
    """Run each formulation of ``system`` with each method from (``q``, ``qdot``) to ``t`` (module docstring)."""
    tf = to_fraction(t, "t")
    grid = [tf * Fraction(i, samples - 1) for i in range(1, samples)]
    cons = _Constraints(system, reference_dps(methods))
    ref_dps = reference_dps(methods)
    bits = max(256, dps_to_bits(ref_dps) + 16)
    dirac = system.dirac()
    y0_ref = dirac.initial_state(q, qdot)
    refs = {}

    def reference(t_end):
        if t_end not in refs:
            rows_ref, _label = numerical_reference(dirac, y0_ref, t_end, bits)  # the Lie series above 1024 bits
            refs[t_end] = _qv(dirac, rows_ref[-1])
        return refs[t_end]

    rows, notes = [], []
    total = len(formulations) * len(methods)
    done = 0
    with mp.workdps(ref_dps):
        for name in formulations:
            model = _formulation(system, name, chart, dependent)
            y0 = model.initial_state(q, qdot)
            with exact_states_read_at(dps_to_bits(ref_dps)):  # not at 256 bits: a drift of 1e-87 for every run
                e0 = _mpf(model.invariants(y0)["energy"])
            for spec in methods:
                if progress is not None:
                    progress(done, total, f"{name}: {spec['method']}")
                start = time.perf_counter()
                rec = run_method(model, y0, tf, spec, times=grid)
                if not rec.states:
                    rows.append(FormulationRow(name, model.poisson.dimension, rec.label, rec.status, rec.t, None,
                                               None, None, None, rec.steps, time.perf_counter() - start,
                                               rec.message))
                    done += 1
                    continue
                g = phi = en = mp.mpf(0)
                for st in rec.states:
                    qs, vs = _qv(model, st)
                    gk, pk = cons.residuals(qs, vs)
                    g, phi = max(g, gk), max(phi, pk)
                    en = max(en, abs(_mpf(model.invariants(st)["energy"]) - e0))
                t_end = to_fraction(rec.t_exact if rec.t_exact is not None else rec.t)
                qr, vr = reference(t_end)
                qs, vs = _qv(model, rec.states[-1])
                err = max(abs(_mpf(a - b)) for a, b in zip(qs + vs, qr + vr))
                # below a float's range (a 400-digit run) they stay mpf: 0.0 would claim every digit
                rows.append(FormulationRow(name, model.poisson.dimension, rec.label, rec.status, float(t_end),
                                           float_or_mpf(err), float_or_mpf(g), float_or_mpf(phi), float_or_mpf(en), rec.steps,
                                           rec.run_time,
                                           rec.message, [float(c) for c in qs], [float(c) for c in vs]))
                done += 1
    if any(r.status == CHART_END for r in rows):
        notes.append("A run with status chart_edge reached the edge of its chart (reduced, intermediate: where "
                     "the block of dG/dq of the dependent coordinates becomes singular; local: the chart's own "
                     "edge) and stopped there; its error is measured at the time it reached.")
    return FormulationComparison(float(tf), rows, f"the Dirac formulation by {numerical_reference_label(bits)} "
                                 "(the most precise run), at the time each run reached", notes)


# -- the radius of convergence of the Lie series, per formulation -------------------------------------------------
def radius_verdict(t, orders, errors, floor, fit_orders, slope):
    """(verdict, radius or None, radius over all fitted orders, over their lower half, over their upper half) of an
    error-against-order table (:func:`~lieseries.studies.convergence.error_vs_order`'s ``orders``, ``errors``,
    ``floor``, ``fit_orders``, ``rate``). The radius is given only when the rate is steady (module docstring)."""
    t = abs(float(t))
    fit = None if slope is None else t * 10.0 ** (-slope)
    used = list(fit_orders)
    if slope is None or len(used) < RADIUS_MIN_POINTS:
        return (f"not measured: {len(used)} errors above the precision floor {fmt_sci(floor, 1)} (at least "
                f"{RADIUS_MIN_POINTS} are needed): raise the digits or the orders, or lower t"), None, fit, None, None
    by_order = dict(zip(orders, errors))
    half = len(used) // 2
    radii = []
    for part in (used[:half + len(used) % 2], used[half:]):
        s, _i, _u = fit_geometric_rate(part, [by_order[k] for k in part], floor, min_order=part[0])
        radii.append(None if s is None else t * 10.0 ** (-s))
    low, high = radii
    if low is None or high is None:  # pragma: no cover - each half has >= 3 points above the floor
        return "not measured: a half of the fitted orders has too few points", None, fit, low, high
    span = f"orders {used[0]}-{used[-1]}"
    if high > RADIUS_AGREEMENT * low:
        return (f"no radius: the rate steepens with the order (rho {low:.3g} over the lower half of {span}, "
                f"{high:.3g} over the upper): faster than geometric, as an entire series"), None, fit, low, high
    if low > RADIUS_AGREEMENT * high:
        return (f"no radius: the rate flattens with the order (rho {low:.3g} over the lower half of {span}, "
                f"{high:.3g} over the upper): not a steady geometric rate"), None, fit, low, high
    where = "inside the disc" if fit > t else "beyond the disc: the series diverges there"
    return f"geometric over {span} (t {where})", fit, fit, low, high


#: Significant digits a fitted radius shows. The errors of a series truncated at order N go as
#: N^a (t / rho)^N with an unknown a (the order of the singularity, alternating terms): over orders ~15-30 the
#: fitted rate is tilted by ~a / (N ln 10) per order, a few per cent of rho (sec t: 1.577 for pi/2 = 1.5708, with
#: both halves of the orders giving 1.595). Two digits are what such a fit carries.
RADIUS_DIGITS = 2


def radius_text(radius) -> str:
    """The radius with the ``RADIUS_DIGITS`` significant digits such a fit carries; "none" without one. (Fewer
    digits where the two halves of the orders disagree would round 0.352 and 0.349 to "0.4" and "0.3": the halves
    are in their own columns, and a radius is given only when they agree within ``RADIUS_AGREEMENT``.)"""
    return "none" if radius is None else f"{radius:.{RADIUS_DIGITS}g}"


def formulation_radii(system, q, qdot, t, *, max_order: int = 30, dps: int = 40, formulations=FORMULATIONS,
                      chart=None, dependent=None, progress=None) -> list:
    """The radius of convergence of the Lie series of each formulation of ``system`` at (``q``, ``qdot``),
    measured from its error at time ``t`` for the orders 1..``max_order`` at ``dps`` digits (module docstring).

    Returns a list of :class:`FormulationRadius`; a formulation whose measurement fails (its reference run ends at
    its chart's edge before ``t``, say) has ``radius`` None and the reason in ``message``."""
    out = []
    orders = list(range(1, int(max_order) + 1))
    for i, name in enumerate(formulations):
        if progress is not None:
            progress(i, len(formulations), f"radius: {name}")
        model = _formulation(system, name, chart, dependent)
        dim = model.poisson.dimension
        try:
            ev = error_vs_order(model, model.initial_state(q, qdot), t, orders, dps=dps)
        except RuntimeError as err:
            out.append(FormulationRadius(name, dim, float(to_fraction(t)), dps, f"not measured: {err}", None,
                                         message=str(err)))
            continue
        verdict, rho, fit, low, high = radius_verdict(ev.t, ev.orders, ev.errors, ev.floor, ev.fit_orders, ev.rate)
        out.append(FormulationRadius(name, dim, ev.t, dps, verdict, rho, fit, low, high, ev.rate, ev.fit_orders,
                                     ev.orders, ev.errors, ev.reference))
    return out


# -- the study ---------------------------------------------------------------------------------------------------
def _chart_field(value, path):
    if not isinstance(value, dict) or not value or not all(isinstance(v, str) for v in value.values()):
        F.fail(path, "a table {dependent coordinate = \"expression of the others\"}", value)
    return value


def _formulations_field(value, path):
    if not isinstance(value, list) or not value:
        F.fail(path, f"a non-empty list of {', '.join(repr(f) for f in FORMULATIONS)}", value)
    for i, v in enumerate(value):
        F.choice(*FORMULATIONS)(v, f"{path}[{i}]")
    return value


class FormulationsStudy(Study):
    name = "formulations"
    title = "Formulations compared"
    fields = {"t": (F.positive, F.REQUIRED), "methods": (scene_methods(lists=False), None),
              "formulations": (_formulations_field, list(FORMULATIONS)), "chart": (_chart_field, None),
              "dependent": (F.list_of(F.string, allow_scalar=False), None), "samples": (F.integer(2, 1001), 11),
              "radius_t": (F.positive, None), "radius_max_order": (F.order, 30),
              "radius_dps": (F.count(MIN_DPS, MAX_STUDY_DPS), 40)}
    docs = {"t": ("positive number", "the final time"),
            "methods": ("list of methods", "the methods run on each formulation (default: heyoka double and quad, "
                        "the Lie series at 30 digits)"),
            "formulations": ("list of 'dirac' | 'reduced' | 'intermediate' | 'local'", "the formulations compared"),
            "chart": ("table name = string", "the local chart (required with 'local'): each dependent coordinate "
                      "as an expression of the others"),
            "dependent": ("list of names", "reduced / intermediate: the coordinates whose momenta are eliminated"),
            "samples": ("integer >= 2", "output times at which G, Phi and the energy are measured"),
            "radius_t": ("positive number", "measure the radius of convergence of each formulation's Lie series "
                         "from its error at this time (default: not measured)"),
            "radius_max_order": ("integer", "the radius: orders 1..radius_max_order (a radius needs at least 6 "
                                 "errors above the precision floor)"),
            "radius_dps": ("integer", "the radius: digits of the series")}
    has_plot = False
    quick_doc = "a fifth of the time, 5 samples; the radius up to half the order (at least 12) at most 40 digits"

    def check(self, opts, run, models, where):
        # the model first: a damped body was told to give a chart, then that it has no constrained system
        for path, _spec, model, _y0 in models:
            try:
                system = _system_of(model)
            except ValueError as err:
                raise F.SceneError(f"`studies.formulations` compares the formulations of a constrained system; "
                                   f"`{path}`: {err}") from None
            if system is None:
                raise F.SceneError(f"`studies.formulations` compares the formulations of a constrained system; "
                                   f"`{path}` is not one (use kind 'constrained', a model derived from it, or a "
                                   "rigid body or heavy top, derived from R)")
            if "local" in opts["formulations"] and opts["chart"] is None:
                many = len(system.constraints) > SYMBOLIC_DIRAC_MAX_CONSTRAINTS
                raise F.SceneError(
                    "`studies.formulations.chart` is required with 'local' in `studies.formulations.formulations` (by "
                    "default all four): a table {dependent coordinate = \"expression of the others\"}"
                    + (f"; with {len(system.constraints)} constraints give formulations = [\"dirac\", "
                       "\"intermediate\"] (the rigid body's R^T R = 1 has no such chart, and 'reduced' is derived "
                       f"for at most {SYMBOLIC_DIRAC_MAX_CONSTRAINTS} constraints)" if many else ""))
            try:
                for name in opts["formulations"]:
                    _formulation(system, name, opts["chart"], opts["dependent"])
            except (TypeError, ValueError) as err:
                raise F.SceneError(f"`studies.formulations`: {err}") from None

    def quick(self, opts):
        t = to_fraction(opts["t"]) / 5  # kept exact: 1.2 becomes 6/25, not the double 0.24
        opts["t"] = str(t) if t.denominator > 1 else t.numerator
        opts["samples"] = min(opts["samples"], 5)
        opts["radius_max_order"] = min(opts["radius_max_order"], max(12, opts["radius_max_order"] // 2))
        opts["radius_dps"] = min(opts["radius_dps"], 40)

    @staticmethod
    def _methods(opts):
        return opts["methods"] or [{"method": "taylor", "precision": "double"},
                                   {"method": "taylor", "precision": "quad"}, {"method": "lie", "dps": 30}]

    def cost(self, opts, ctx, pricer):
        specs = [normalize_method(m, f"studies.formulations.methods[{i}]") for i, m in enumerate(self._methods(opts))]
        ini = ctx.scene.initial
        n_int = opts["samples"] - 1
        bits = max(256, dps_to_bits(reference_dps(specs)) + 16)
        parts = []
        for _lab, model in ctx.built:
            system = _system_of(model)
            q, qdot = _start(model, ini, ctx.initial_state(model))
            pricer.heyoka_builds += 1  # the reference
            for name in opts["formulations"]:
                form = _formulation(system, name, opts["chart"], opts["dependent"])  # derived once, cached
                y0 = form.initial_state(q, qdot)
                if name == "dirac":
                    secs, lower, basis = pricer.heyoka_run(form, y0, opts["t"], bits, n_int)
                    parts.append(CostPart("studies.formulations.t", f"the reference (Dirac, heyoka {bits} bits)", 1,
                                          "run", secs, basis, lower))
                for spec in specs:
                    pricer.heyoka_builds += spec["method"] == "taylor"
                    per, lower, basis, _ = pricer.span(form, y0, spec, opts["t"], n_int)
                    parts.append(CostPart("studies.formulations.t", f"{n_int} sample intervals of {name} by "
                                          f"{method_label(spec)}", n_int, "sample interval", per, basis, lower))
                if opts["radius_t"] is not None:
                    pricer.heyoka_builds += 1  # its reference
                    top, dps = int(opts["radius_max_order"]), int(opts["radius_dps"])
                    o_c = min(top, 12)
                    _, secs = pricer.timed(lambda: lie_series(form, y0, order=o_c, dps=dps))
                    parts.append(CostPart("studies.formulations.radius_max_order", f"{name}: a Lie series to order "
                                          f"{top} at {dps} digits", 1, "series", secs * (top / o_c) ** 2,
                                          f"timed to order {o_c}, scaled by order^2"))
        return parts

    def run(self, opts, ctx):
        methods = self._methods(opts)
        out = []
        for i, (lab, model) in enumerate(ctx.built):
            system = _system_of(model)
            q, qdot = _start(model, ctx.scene.initial, ctx.initial_state(model))
            comp = compare_formulations(
                system, q, qdot, opts["t"], methods, formulations=opts["formulations"],
                chart=opts["chart"], dependent=opts["dependent"], samples=opts["samples"],
                progress=ctx.model_progress(i, lab))
            if opts["radius_t"] is not None:
                comp.radii = formulation_radii(
                    system, q, qdot, opts["radius_t"], max_order=opts["radius_max_order"],
                    dps=opts["radius_dps"], formulations=opts["formulations"], chart=opts["chart"],
                    dependent=opts["dependent"], progress=ctx.model_progress(i, lab))
            out.append((lab, comp))
        return out

    def unsuccessful(self, items):
        return [f"formulations ({lab}): {r.formulation} by {r.method}: {r.status}" for lab, c in items for r in c.rows
                if r.status not in ("success", CHART_END)]

    def section(self, items, ctx):
        h = ["model", "formulation", "variables", "method", "status", "t reached", "error (q, qdot)", "max |G|",
             "max |Phi|", "energy drift", "steps", "run time (s)"]
        rows = [[lab, r.formulation, fmt_int(r.dimension), r.method, r.status, fmt_num(r.t), fmt_sci(r.error),
                 fmt_sci(r.G), fmt_sci(r.Phi), fmt_sci(r.energy), fmt_int(r.steps), fmt_num(r.run_time)]
                for lab, c in items for r in c.rows]
        lines = ["Each formulation of the constrained system run by each method from the same q, qdot, measured in "
                 "the original variables: the error of (q, qdot) against "
                 + (items[0][1].reference if items else "a reference")
                 + "; the largest |G| and |Phi| along the run; the largest change of the energy.", "",
                 markdown_table(h, rows), ""]
        for _lab, c in items:
            lines += [n for n in c.notes if n not in lines]
        csvs = [("formulations.csv", h, rows)]
        if any(c.radii for _lab, c in items):
            lines += [""] + self._radius_section(items, csvs)
        return lines, csvs

    @staticmethod
    def _radius_section(items, csvs):
        first = next(r for _lab, c in items for r in c.radii)
        h = ["model", "formulation", "variables", "t", "dps", "orders fitted", "rho (all fitted orders)",
             "rho (lower half)", "rho (upper half)", "radius", "verdict"]
        rows = [[lab, r.formulation, fmt_int(r.dimension), fmt_num(r.t), str(r.dps),
                 f"{min(r.fit_orders)}-{max(r.fit_orders)}" if r.fit_orders else "", fmt_sci(r.radius_fit, 4),
                 fmt_sci(r.radius_low, 4), fmt_sci(r.radius_high, 4),
                 radius_text(r.radius), r.verdict]
                for lab, c in items for r in c.radii]
        csvs.append(("formulations_radius.csv", h, rows))
        orders = sorted({o for _lab, c in items for r in c.radii for o in r.orders})
        h2 = ["order"] + [f"{r.formulation} ({lab})" if len(items) > 1 else r.formulation
                          for lab, c in items for r in c.radii]
        maps = [dict(zip(r.orders, r.errors)) for _lab, c in items for r in c.radii]
        rows2 = [[str(o)] + [fmt_sci(m.get(o)) for m in maps] for o in orders]
        csvs.append(("formulations_radius_errors.csv", h2, rows2))
        return ["**The radius of convergence of the Lie series exp(t X_H), per formulation.** Each formulation's "
                "series in its own variables, truncated at order N, evaluated at t and compared with "
                f"{first.reference or 'a numerical reference'}: inside the disc error_N ~ C (t / rho)^N, and the "
                "least-squares slope of log10(error_N) over the upper half of the orders above the precision "
                "floor (100 x 10^-dps) gives rho = t 10^(-slope). A radius is given only when the rate is steady: "
                f"the fits over the lower and the upper half of those orders agree within a factor "
                f"{RADIUS_AGREEMENT}; the column 'radius' shows the {RADIUS_DIGITS} significant digits such a fit "
                "carries (an unknown power of N in the errors, the order of the singularity, tilts the fitted rate "
                "by a few per cent over these orders). "
                "A rate that steepens is a series falling faster than geometrically (an entire "
                "series, or a singularity farther than these orders resolve): the column 'rho (all fitted orders)' "
                "is then only the mean rate over the orders shown, not a radius. The formulations need not agree: "
                "the same motion in other variables can have other singularities (a chart's momenta blow up where "
                "the chart does).", "", markdown_table(h, rows), "",
                "<details><summary>Error of the truncated series against its order</summary>", "",
                markdown_table(h2, rows2), "", "</details>", ""]

    def summary(self, items):
        out = []
        for lab, c in items:
            out.append(f"formulations ({lab}): {len(c.rows)} runs, largest error "
                       f"{fmt_sci(max((r.error or 0) for r in c.rows))}")
            if c.radii:
                out.append(f"formulations ({lab}): Lie series radius " + ", ".join(
                    f"{r.formulation} {radius_text(r.radius)}" for r in c.radii))
        return out


register_study(FormulationsStudy())
