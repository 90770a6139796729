"""The paper's comparison: one constrained system in its four Hamiltonian formulations, each run by each method.

For a model derived by :class:`~lieseries.models.constrained.ConstrainedSystem` (the scene kind ``constrained``
or a built-in model on it, such as ``spherical_pendulum``), ``[studies.formulations]`` runs

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
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from fractions import Fraction

import sympy as sp

from .. import fields as F
from ..formatting import fmt_int, fmt_num, fmt_sci, markdown_table
from ..methods import reference_dps, run_method, scene_methods
from ..models.constrained import ConstrainedSystem
from ..precision import dps_to_bits, to_fraction
from ..precision import thread_mp as mp
from .plugin import Study, register_study

__all__ = ["FormulationRow", "FormulationComparison", "compare_formulations", "FormulationsStudy", "FORMULATIONS"]

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


@dataclass
class FormulationComparison:
    t: float
    rows: list
    reference: str
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"t": self.t, "reference": self.reference, "notes": list(self.notes),
                "rows": [r.to_dict() for r in self.rows]}


def _system_of(model):
    system = getattr(model, "system", None)
    return system if isinstance(system, ConstrainedSystem) else None


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
            from ..taylor import integrate  # the driver layer below studies

            sol = integrate(dirac, y0_ref, t=t_end, precision=bits)
            if not sol.success:
                raise RuntimeError(f"the reference (Dirac, heyoka {bits} bits) did not reach t = {float(t_end)}: "
                                   f"{sol.message}")
            refs[t_end] = _qv(dirac, sol.y[-1])
        return refs[t_end]

    rows, notes = [], []
    total = len(formulations) * len(methods)
    done = 0
    with mp.workdps(ref_dps):
        for name in formulations:
            model = _formulation(system, name, chart, dependent)
            y0 = model.initial_state(q, qdot)
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
                rows.append(FormulationRow(name, model.poisson.dimension, rec.label, rec.status, float(t_end),
                                           float(err), float(g), float(phi), float(en), rec.steps, rec.run_time,
                                           rec.message, [float(c) for c in qs], [float(c) for c in vs]))
                done += 1
    if any(r.status == CHART_END for r in rows):
        notes.append("A run with status chart_edge reached the edge of its chart (reduced, intermediate: where "
                     "the block of dG/dq of the dependent coordinates becomes singular; local: the chart's own "
                     "edge) and stopped there; its error is measured at the time it reached.")
    return FormulationComparison(float(tf), rows, f"the Dirac formulation by heyoka at {bits} bits (the most "
                                 f"precise run), at the time each run reached", notes)


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
              "dependent": (F.list_of(F.string, allow_scalar=False), None), "samples": (F.integer(2, 1001), 11)}
    docs = {"t": ("positive number", "the final time"),
            "methods": ("list of methods", "the methods run on each formulation (default: heyoka double and quad, "
                        "the Lie series at 30 digits)"),
            "formulations": ("list of 'dirac' | 'reduced' | 'intermediate' | 'local'", "the formulations compared"),
            "chart": ("table name = string", "the local chart (required with 'local'): each dependent coordinate "
                      "as an expression of the others"),
            "dependent": ("list of names", "reduced / intermediate: the coordinates whose momenta are eliminated"),
            "samples": ("integer >= 2", "output times at which G, Phi and the energy are measured")}
    has_plot = False
    quick_doc = "a fifth of the time, 5 samples"

    def check(self, opts, run, models, where):
        if "local" in opts["formulations"] and opts["chart"] is None:
            raise F.SceneError("`studies.formulations.chart` is required with 'local' in "
                               "`studies.formulations.formulations`: a table {dependent coordinate = \"expression of "
                               "the others\"}")
        for path, _spec, model, _y0 in models:
            system = _system_of(model)
            if system is None:
                raise F.SceneError(f"`studies.formulations` compares the formulations of a constrained system; "
                                   f"`{path}` is not one (use kind 'constrained' or a model derived from it)")
            try:
                for name in opts["formulations"]:
                    _formulation(system, name, opts["chart"], opts["dependent"])
            except (TypeError, ValueError) as err:
                raise F.SceneError(f"`studies.formulations`: {err}") from None

    def quick(self, opts):
        t = to_fraction(opts["t"]) / 5  # kept exact: 1.2 becomes 6/25, not the double 0.24
        opts["t"] = str(t) if t.denominator > 1 else t.numerator
        opts["samples"] = min(opts["samples"], 5)

    def run(self, opts, ctx):
        methods = opts["methods"] or [{"method": "taylor", "precision": "double"},
                                      {"method": "taylor", "precision": "quad"}, {"method": "lie", "dps": 30}]
        out = []
        for i, (lab, model) in enumerate(ctx.built):
            ini = ctx.scene.initial
            out.append((lab, compare_formulations(
                _system_of(model), ini["q"], ini["qdot"], opts["t"], methods, formulations=opts["formulations"],
                chart=opts["chart"], dependent=opts["dependent"], samples=opts["samples"],
                progress=ctx.model_progress(i, lab))))
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
        return lines, [("formulations.csv", h, rows)]

    def summary(self, items):
        return [f"formulations ({lab}): {len(c.rows)} runs, largest error {fmt_sci(max((r.error or 0) for r in c.rows))}"
                for lab, c in items]


register_study(FormulationsStudy())
