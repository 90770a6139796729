"""The four formulations of a :class:`~lieseries.models.constrained.ConstrainedSystem` as models every engine runs:
:class:`ConstrainedDirac` (q^A, p_A), :class:`ConstrainedReduced` (q^A, p_i), :class:`ConstrainedIntermediate`
(q^A, pi_i) and :class:`ConstrainedLocal` (x^i, p_i). Each turns its symbolic derivation
(:mod:`~lieseries.models.constrained_derive`) into a :class:`~lieseries.poisson.PoissonSystem` in heyoka
expressions (:mod:`~lieseries.models.constrained_heyoka`), with the parameters as runtime parameters, and builds states from a configuration on the surface and
a tangent velocity (checked by :mod:`~lieseries.models.constrained_checks`).
"""

from __future__ import annotations

from fractions import Fraction

import heyoka as hy
import numpy as np
import sympy as sp

from ..expr import compile_expressions
from ..poisson import PoissonSystem
from ..precision import BinaryFraction, binary_inputs, bits_to_dps, data_bits, state_bits, to_fraction
from ..precision import thread_mp as mp
from .base import Model, make_state
from .constrained_checks import RESIDUAL_DPS, check_surface_residuals, residual_tolerance
from .constrained_derive import exact_number, numeric_rank, solve_linear, substitute, symbolic_inverse, tidy
from .constrained_heyoka import (HeyokaConverter, assemble_dirac, assemble_intermediate, heyoka_tensor, large_field,
                                 model_parameters)

__all__ = ["ConstrainedDirac", "ConstrainedReduced", "ConstrainedIntermediate", "ConstrainedLocal"]

#: Bits with which a momentum that is not rational at rational (q, qdot) (a sin(q) in M) is stored.
IRRATIONAL_BITS = 320


class ConstrainedDirac(Model):
    """A :class:`ConstrainedSystem` on (q^A, p_A) with the Dirac bracket and H_0 (module docstring).

    State: the n coordinates, then their n momenta p_A = dL/dqdot^A (names ``p_<coordinate>``). ``invariants``
    gives H_0 (``energy``) and the constraints G_alpha, Phi_alpha (``G1``, ..., ``Phi1``, ...), Casimirs of the
    bracket: zero along a motion from :meth:`initial_state`, up to the run's rounding.
    """

    def __init__(self, system):
        self.system = system
        n = len(system.coordinates)
        self.n = n
        d = system.dirac_bracket()
        names = list(system.coordinates) + [f"p_{c}" for c in system.coordinates]
        z = hy.make_vars(*names)
        conv = HeyokaConverter(system, list(zip(d["q"] + d["p"], z)))
        T = d["tensor"]
        if T is None:
            tensor = assemble_dirac(d, conv, n, len(system.constraints))
            self.large_field = True
        else:
            self.large_field = large_field([T, d["H0"]])
            tensor = [[0] * (2 * n) for _ in range(2 * n)]
            for i in range(2 * n):
                for j in range(i + 1, 2 * n):
                    if T[i, j] != 0:
                        e = conv(T[i, j])
                        tensor[i][j] = e
                        tensor[j][i] = -e
        H = conv(d["H0"])
        k = len(system.constraints)
        casimirs = {f"G{a + 1}": conv(d["G"][a]) for a in range(k)}
        casimirs.update({f"Phi{a + 1}": conv(d["Phi"][a]) for a in range(k)})
        self._velocity_exprs = [conv(e) for e in d["velocity"]]
        self._gradients = [[conv(sp.diff(g, qa)) for qa in d["q"]] for g in d["G"]]
        self._terms = [[conv(t) for t in sp.Add.make_args(sp.expand(g))] for g in d["G"]]
        self.variables = z
        params = {nm: conv.values[nm] for nm in conv.names}
        # heyoka counts the parameters of an ODE as 1 + the largest index it uses: a parameter used only by the
        # constraints (the radius of a free sphere) must not be the last one, so H gets an exact unit factor
        field = [e for row in tensor for e in row if isinstance(e, hy.expression)]
        field += [hy.diff(H, v) for v in z]
        used = {int(str(pp)[1:]) for pp in hy.get_params(field)}
        if params and (len(params) - 1) not in used:
            unit = "one"
            while unit in params:
                unit = "_" + unit
            params[unit] = Fraction(1)
            H = hy.par[len(params) - 1] * H
        sources = {nm: f"parameters[{nm!r}]" for nm in system.parameter_values}
        sources.update({nm: "lagrangian" for nm in params if nm not in system.parameter_values})
        bits = dict(system.parameter_bits)
        bits.update(system.input_bits)
        self.poisson = PoissonSystem(z, tensor, H, parameters=params, casimirs=casimirs,
                                     name=f"{system.name} (Dirac bracket)", input_bits=bits,
                                     parameter_sources=sources)

    # -- states --------------------------------------------------------------------------------------------------
    def _vector(self, value, argname):
        arr = np.asarray(value, dtype=object)
        if arr.shape != (self.n,):
            raise ValueError(f"`{argname}` must be {self.n} numbers (one per coordinate "
                             f"{list(self.system.coordinates)}); got shape {arr.shape}")
        return [to_fraction(v, f"{argname}[{i}]") for i, v in enumerate(arr)]

    @property
    def _q_variables(self):
        """The variables the constraint expressions (``_terms``, ``_gradients``) are written in, q first."""
        return self.variables

    def _eval(self, exprs, values, dps=RESIDUAL_DPS, variables=None):

        prog = compile_expressions(self.variables if variables is None else variables, exprs,
                                   len(self.poisson.parameter_values))
        return prog.evaluate(list(values), list(self.poisson.parameter_values), dps)

    def _check_surface(self, q, qdot, bits, qname="q", vname="qdot", loose=False):
        """Refuse a point off G = 0 or a velocity not tangent to it (relative residuals at 60 digits,
        :func:`~lieseries.models.constrained_checks.check_surface_residuals`). ``loose``: for binary data, allow the
        square root of their precision (a state a run ended in has drifted)."""
        n = self.n
        qvars = self._q_variables
        point = list(q) + [0] * (len(qvars) - n)
        flat = [t for ts in self._terms for t in ts] + [g for row in self._gradients for g in row]
        vals = self._eval(flat, point, variables=qvars)
        terms, grads, pos = [], [], 0
        for ts in self._terms:
            terms.append(vals[pos:pos + len(ts)])
            pos += len(ts)
        for _ in self._terms:
            grads.append(vals[pos:pos + n])
            pos += n
        labels = [f"G{a + 1} = {g}" for a, g in enumerate(self.system.constraints)]
        check_surface_residuals(terms, grads, qdot, bits, labels, qname, vname, loose,
                                coarse_model=self.poisson.coarse_data())

    def _surface_inputs(self, q, qdot):
        """(q, qdot as exact vectors, the bits their binary floats carry or None), refused unless q lies on the
        constraints and qdot is tangent to them."""
        qf = self._vector(q, "q")
        vf = self._vector(qdot, "qdot")
        binary = {}
        for nm, val in (("q", q), ("qdot", qdot)):
            binary.update(binary_inputs(val, nm))
        # values already marked binary (BinaryFraction: a body's surface_point of a state built from R0 in
        # doubles) carry their bits too: such a point was refused at the exact tolerance 1e-50
        marked = data_bits([q, qdot])
        bits = min(list(binary.values()) + ([int(marked)] if marked is not None else []), default=None)
        # a point marked so comes from a model's state, which passed that model's own check: a state a run ended
        # in has drifted off the surface by the run's rounding (a heavy top at t = 50 in quad by 10-30 ulps, more
        # the longer the run), and is checked as check_state checks it, to the square root of its precision
        # (a point typed in floats, 16 ulps)
        self._check_surface(qf, vf, bits, loose=marked is not None and not binary)
        return qf, vf, bits

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (q, p) with p = M(q) qdot + A(q) from a point on the surface and a tangent velocity.

        Exact input (int, str, Fraction) is kept exact: an :class:`~lieseries.models.base.ExactState` unless
        ``precision`` is given. Refuses a point with |G_alpha(q)| above 1e-50 relative to the size of G's terms
        (at 60 digits; for binary floats, above 16 units of their last place; for a point a body's
        ``surface_point`` made of a state, above the square root of its precision, as :meth:`check_state` allows
        a state a run ended in), and a velocity with dG/dq . qdot likewise,
        naming ``q`` or ``qdot`` with the residual; a velocity Hessian that is not positive definite or
        constraints that are dependent at ``q``.
        """
        qf, vf, bits = self._surface_inputs(q, qdot)
        cs = self.system
        at = {s: sp.Rational(f.numerator, f.denominator) for s, f in zip(cs.q_symbols, qf)}
        at.update(cs.parameter_substitution())
        M = cs.mass_matrix.xreplace(at)
        if not cs.hessian_constant:
            cs.check_positive_definite(M, "`q`", " at this point")
        J = cs.constraint_jacobian.xreplace(at)
        if numeric_rank(J) < len(cs.constraints):
            raise ValueError(f"`q`: the constraint gradients dG/dq are dependent at this point (rank "
                             f"{numeric_rank(J)} < {len(cs.constraints)}): the surface is singular there; start elsewhere")
        vdot = sp.Matrix([sp.Rational(f.numerator, f.denominator) for f in vf])
        # a state rounded to `precision` needs no mark: the rounding is the run's own
        p = _exact_numbers(list(M * vdot + cs.linear_term.xreplace(at)), False, "p", mark=precision is None)
        return make_state(list(qf) + p, precision, inputs={"q": q, "qdot": qdot})

    def check_state(self, y, argname="y0"):
        """The state as exact Fractions, refused (naming ``argname``) when it is off the constraint surface or its
        velocity is not tangent: relative residual above 1e-50 for exact values, above the square root of the
        precision for binary numbers (a state a run ended in has drifted by rounding; ``invariants`` shows how
        far)."""
        z = super().check_state(y, argname)
        if getattr(y, "exact", None) is not None:
            bits = getattr(y, "data_bits", None)
        elif isinstance(y, np.ndarray) and y.dtype != object:
            bits = state_bits(y)
        else:
            bits = data_bits(list(y))
        q = z[:self.n]
        qdot = self._velocity_at(z)
        self._check_surface(q, [to_fraction(v) for v in qdot], bits, qname=argname, vname=argname, loose=True)
        return z

    def _velocity_at(self, z, dps=RESIDUAL_DPS):
        return self._eval(self._velocity_exprs, z, dps)

    def configuration(self, y) -> np.ndarray:
        """q^A(t): the first n entries of each state (a Solution, one state or a 2-d array of states)."""
        y, _ = self._with_charts(y, None)
        arr = y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object)
        if arr.shape[-1] != self.dimension:
            raise ValueError(f"`y` must have {self.dimension} entries per state; got shape {arr.shape}")
        return np.asarray(arr)[..., :self.n]

    def velocity(self, y) -> np.ndarray:
        """qdot^A = M^-1(q) (p - A(q)), in the state's precision (evaluated in mpmath a little above it)."""
        y, _ = self._with_charts(y, None)
        rows, bits, was_1d = self._rows(y)
        dps = bits_to_dps(bits) + 5
        out = [self._velocity_at(r, dps) for r in rows]
        like = y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object)
        return self._out_array(out, bits, was_1d, like)

    def invariants(self, y) -> dict:
        """``energy`` H_0 and the constraints ``G1..``, ``Phi1..`` (Casimirs) at a state or each row (mpf)."""
        y, _ = self._with_charts(y, None)
        return self.poisson.invariants(y)

    def __repr__(self) -> str:
        return f"ConstrainedDirac({self.system.name!r}, variables={list(self.names)})"


class ConstrainedReduced(ConstrainedDirac):
    """A :class:`ConstrainedSystem` on the intermediate submanifold Phi = 0, coordinates (q^A, p_i) (paper,
    p8.13-p8.15); see :meth:`ConstrainedSystem.reduced`. State: the n coordinates, then the n - k independent
    momenta. ``invariants``: ``energy`` H'_0 and the Casimirs ``G1..``."""

    def __init__(self, system, dependent: tuple, edge: Fraction):
        self.system = system
        self.dependent = dependent
        self.edge = edge
        n = len(system.coordinates)
        k = len(system.constraints)
        self.n = n
        d = system.dirac_bracket()
        q, p = d["q"], d["p"]
        free = [i for i in range(n) if i not in dependent]
        self.free = tuple(free)
        # Phi = W (p - A), W = G_q M^-1: linear in p; solve for the dependent momenta
        pdep = [p[a] for a in dependent]
        W = sp.Matrix([[sp.diff(phi, p[a]) for a in range(n)] for phi in d["Phi"]])
        D = W[:, list(dependent)]
        rest = {pa: 0 for pa in pdep}
        sol = solve_linear(D, [-phi.xreplace(rest) for phi in d["Phi"]])  # D p_dep = -Phi(p_dep = 0)
        detD = sp.cancel(D.det(method="berkowitz")) if sol is not None else 0
        if detD == 0:
            raise ValueError(f"`dependent`: the constraints Phi = 0 cannot be solved for the momenta of "
                             f"{[system.coordinates[a] for a in dependent]} (the block of dPhi/dp is singular "
                             "everywhere); choose other coordinates")
        f = dict(zip(pdep, sol))
        idx = list(range(n)) + [n + i for i in free]
        names = list(system.coordinates) + [f"p_{system.coordinates[i]}" for i in free]
        z = hy.make_vars(*names)
        syms = q + [p[i] for i in free]
        conv = HeyokaConverter(system, list(zip(syms, z)))
        T = d["tensor"]
        m = len(idx)
        tensor = [[0] * m for _ in range(m)]
        self._sym_tensor = sp.zeros(m, m)
        pairs = [(a, b) for a in range(m) for b in range(a + 1, m) if T[idx[a], idx[b]] != 0]
        entries = substitute([T[idx[a], idx[b]] for a, b in pairs] + [d["H0"]], f)
        for (a, b), e in zip(pairs, entries):
            if e != 0:
                self._sym_tensor[a, b], self._sym_tensor[b, a] = e, -e
                tensor[a][b] = conv(e)
                tensor[b][a] = -tensor[a][b]
        H0 = entries[-1]
        self._sym_hamiltonian = H0
        self.large_field = large_field([self._sym_tensor, H0])
        self._sym_dependent = f
        H = conv(H0)
        casimirs = {f"G{a + 1}": conv(d["G"][a]) for a in range(k)}
        self._velocity_exprs = [conv(sp.cancel(e.xreplace(f))) for e in d["velocity"]]
        self._gradients = [[conv(sp.diff(g, qa)) for qa in q] for g in d["G"]]
        self._terms = [[conv(t) for t in sp.Add.make_args(sp.expand(g))] for g in d["G"]]
        gram = sp.cancel((W * W.T).det(method="berkowitz"))
        self._edge_expr = conv(detD**2) - conv(gram) * hy.par[len(conv.names)]
        self._edge_sign = conv(detD)
        self._edge_ratio = (conv(detD**2), conv(gram))
        self.variables = z
        params = {nm: conv.values[nm] for nm in conv.names}
        edge_name = "edge2"
        while edge_name in params:
            edge_name = "_" + edge_name
        params[edge_name] = edge * edge
        sources = {nm: f"parameters[{nm!r}]" for nm in system.parameter_values}
        sources.update({nm: "lagrangian" for nm in params if nm not in system.parameter_values})
        sources[edge_name] = "edge"
        bits = dict(system.parameter_bits)
        bits.update(system.input_bits)
        self.poisson = PoissonSystem(z, tensor, H, parameters=params, casimirs=casimirs,
                                     name=f"{system.name} (reduced, p of "
                                          f"{', '.join(system.coordinates[a] for a in dependent)} eliminated)",
                                     input_bits=bits, parameter_sources=sources)

    def events(self):
        message = (f"the chart of the momenta of {[self.system.coordinates[a] for a in self.dependent]} is ending "
                   f"(det D reached {float(self.edge)} of its largest value)")
        # det D changes sign across the band: a Lie step that jumps over it (edge = 0.001) is seen at its end
        return [(self._edge_expr, "chart_edge", message), (self._edge_sign, "chart_edge", message)]

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (q, p_i) from a point on the surface and a tangent velocity (checks as
        :meth:`ConstrainedDirac.initial_state`), refused at or beyond the chart's edge."""
        full = ConstrainedDirac.initial_state(self, q, qdot, precision=None)
        vals = list(full.exact)
        n = self.n
        qv = vals[:n]
        num, den = self._eval(list(self._edge_ratio), qv + [0] * (n - len(self.dependent)))
        if not num > den * (mp.mpf(self.edge.numerator) / self.edge.denominator) ** 2:
            raise ValueError(
                f"`q` is at or beyond the edge of the chart that eliminates the momenta of "
                f"{[self.system.coordinates[a] for a in self.dependent]} (det D^2 / det W W^T = "
                f"{mp.nstr(num / den if den else mp.mpf(0), 4)} <= edge^2 = {float(self.edge) ** 2:.4g}); "
                "choose other `dependent` coordinates, or use the global form dirac()")
        given = {"q": q, "qdot": qdot}
        return make_state(qv + [vals[n + i] for i in self.free], precision, inputs=given)

    def __repr__(self) -> str:
        return f"ConstrainedReduced({self.system.name!r}, variables={list(self.names)})"


def _exact_numbers(exprs, marked, label, mark=True):
    """Sympy numbers as Fractions; irrational ones (or any, when ``marked`` inputs carried finite bits) stored with
    IRRATIONAL_BITS bits and, with ``mark``, marked so (the source ``"<label> (irrational at q)"``): no estimate
    claims more."""
    out = []
    irrational = False
    for e in exprs:
        val = exact_number(e, bits_to_dps(IRRATIONAL_BITS))
        if not isinstance(val, Fraction):
            irrational = True
            val = to_fraction(val)
        out.append(val)
    if mark and (irrational or marked):
        out = [BinaryFraction(v, IRRATIONAL_BITS, (f"{label} (irrational at q)",)) for v in out]
    return out


class ConstrainedIntermediate(ConstrainedDirac):
    """A :class:`ConstrainedSystem` in the paper's intermediate formalism: (q^A, pi_i), 2n - k variables (p9-p14.3);
    see :meth:`ConstrainedSystem.intermediate`. ``invariants``: ``energy`` H'_0 and the Casimirs ``G1..``."""

    large_field = False

    def __init__(self, system, dependent, frame, names, edge: Fraction):
        self.system = system
        self.dependent = dependent
        self.edge = edge
        n = len(system.coordinates)
        k = len(system.constraints)
        self.n = n
        d = system.intermediate_derivation(dependent, frame, names)
        self.derivation = d
        self.frame = d["frame"]
        z = hy.make_vars(*(list(system.coordinates) + list(names)))
        conv = HeyokaConverter(system, list(zip(d["q"] + d["pi"], z)))
        if d["H"] is not None:
            tensor = heyoka_tensor(conv, d["tensor"])
            H = conv(d["H"])
            self._velocity_exprs = [conv(e) for e in d["velocity"]]
        else:
            tensor, H, self._velocity_exprs = assemble_intermediate(d, conv, z, n)
            # thousands of elementary operations (the rigid body: 3400): LLVM takes minutes on them unrolled, so
            # the Taylor integrator compiles this model in compact mode
            self.large_field = True
        casimirs = {f"G{a + 1}": conv(d["G"][a]) for a in range(k)}
        self._gradients = [[conv(sp.diff(g, qa)) for qa in d["q"]] for g in d["G"]]
        self._terms = [[conv(t) for t in sp.Add.make_args(sp.expand(g))] for g in d["G"]]
        extra = []
        events = []
        if dependent is not None:
            self._edge_ratio = (conv(d["detD"] ** 2), conv(d["gram"]))
            extra.append(("edge2", edge * edge, "edge"))
        self.variables = z
        field = [e for row in tensor for e in row] + [hy.diff(H, v) for v in z]
        if dependent is not None:
            events = [self._edge_ratio[0] - self._edge_ratio[1] * hy.par[len(conv.names)], conv(d["detD"])]
        params, sources, bits, unit = model_parameters(system, conv, field + events, extra)
        if unit is not None:
            H = hy.par[unit] * H
        if dependent is not None:
            self._edge_expr, self._edge_sign = events
        chart = ("chart " + ", ".join(system.coordinates[a] for a in dependent) + " dependent"
                 if dependent is not None else "own frame")
        self.poisson = PoissonSystem(z, tensor, H, parameters=params, casimirs=casimirs,
                                     name=f"{system.name} (intermediate, {chart})", input_bits=bits,
                                     parameter_sources=sources)

    def events(self):
        if self.dependent is None:
            return []
        message = (f"the chart of the intermediate frame with {[self.system.coordinates[a] for a in self.dependent]} "
                   f"dependent is ending (det dG/dq_dep reached {float(self.edge)} of its largest value)")
        # det dG/dq_dep changes sign across the band: a Lie step that jumps over it is seen at its end
        return [(self._edge_expr, "chart_edge", message), (self._edge_sign, "chart_edge", message)]

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (q, pi) with pi_i = G_iA(q) p_A from a point on the surface and a tangent velocity (checks as
        :meth:`ConstrainedDirac.initial_state`); refused at or beyond the chart's edge, or where the frame is
        undefined or singular."""
        given = {"q": q, "qdot": qdot}
        full = ConstrainedDirac.initial_state(self, q, qdot, precision=None)
        vals = list(full.exact)
        n = self.n
        qv, pv = vals[:n], vals[n:]
        cs = self.system
        at = {s: sp.Rational(f.numerator, f.denominator) for s, f in zip(cs.q_symbols, qv)}
        at.update(cs.parameter_substitution())
        if self.dependent is not None:
            num, den = self._eval(list(self._edge_ratio), qv + [0] * (len(self.variables) - n))
            if not num > den * (mp.mpf(self.edge.numerator) / self.edge.denominator) ** 2:
                raise ValueError(
                    f"`q` is at or beyond the edge of the chart with "
                    f"{[cs.coordinates[a] for a in self.dependent]} dependent (det D^2 / det G_q G_q^T = "
                    f"{mp.nstr(num / den if den else mp.mpf(0), 4)} <= edge^2 = {float(self.edge) ** 2:.4g}); "
                    "choose other `dependent` coordinates, or use the global form dirac()")
        Fq = self.frame.xreplace(at)
        if any(e.has(sp.zoo, sp.nan, sp.oo) for e in Fq):
            raise ValueError("`q`: the frame of the intermediate momenta is undefined at this point (a component is "
                             "infinite); start elsewhere or choose another frame / `dependent`")
        if numeric_rank(Fq) < Fq.shape[0]:
            raise ValueError("`q`: the frame of the intermediate momenta is singular at this point (its fields are "
                             "dependent there); start elsewhere or choose another frame")
        P = sp.Matrix([sp.Rational(f.numerator, f.denominator) for f in pv])
        marked = any(isinstance(f, BinaryFraction) for f in pv)
        pis = _exact_numbers(list(Fq * P), marked, "pi")
        return make_state(qv + pis, precision, inputs=given)

    def __repr__(self) -> str:
        return f"ConstrainedIntermediate({self.system.name!r}, variables={list(self.names)})"


class ConstrainedLocal(ConstrainedDirac):
    """A :class:`ConstrainedSystem` in local coordinates of the surface: canonical (x^i, p_i), 2(n - k) variables;
    see :meth:`ConstrainedSystem.local`. ``configuration`` and ``velocity`` give q^A(x) and qdot^A as for the
    other formulations; ``invariants``: ``energy``."""

    def __init__(self, system, dependent, solution: dict, edge: Fraction):
        self.system = system
        self.dependent = dependent
        self.edge = edge
        self.chart = dict(solution)
        n = len(system.coordinates)
        self.n = n
        free = [i for i in range(n) if i not in dependent]
        self.free = tuple(free)
        q = list(system.q_symbols)
        x = [q[i] for i in free]
        qx = [solution.get(s, s) for s in q]
        J = sp.Matrix(n, len(free), lambda A_, i: sp.diff(qx[A_], x[i]))
        M = system.mass_matrix.xreplace(solution)
        A = system.linear_term.xreplace(solution)
        U = system.potential.xreplace(solution)
        psyms = [sp.Symbol(f"p_{system.coordinates[i]}", real=True) for i in free]
        Ml, Al, H, qdot = self._local_form(J, M, A, U, psyms)
        self._sym_hamiltonian = H
        self._sym_mass = Ml
        self._sym_linear = Al
        qvars = hy.make_vars(*system.coordinates)
        qvars = qvars if isinstance(qvars, list) else [qvars]
        pvars = hy.make_vars(*[str(s) for s in psyms])
        pvars = pvars if isinstance(pvars, list) else [pvars]
        z = [qvars[i] for i in free] + pvars
        conv = HeyokaConverter(system, list(zip(q, qvars)) + list(zip(psyms, pvars)))
        d = len(free)
        T = sp.zeros(2 * d, 2 * d)
        for i in range(d):
            T[i, d + i], T[d + i, i] = 1, -1
        tensor = heyoka_tensor(conv, T)
        Hh = conv(H)
        self._configuration_exprs = [conv(e) for e in qx]
        self._velocity_exprs = [conv(e) for e in qdot]
        G = list(system.constraints)
        self._gradients = [[conv(sp.diff(g, qa)) for qa in q] for g in G]
        self._terms = [[conv(t) for t in sp.Add.make_args(sp.expand(g))] for g in G]
        Gq = sp.Matrix([[sp.diff(g, qa) for qa in q] for g in G])
        detD = sp.cancel(Gq[:, list(dependent)].det(method="berkowitz"))
        if detD == 0:
            raise ValueError(f"`chart`: the constraints cannot be solved for "
                             f"{[system.coordinates[a] for a in dependent]} (dG/dq of these coordinates is singular "
                             "everywhere); choose other dependent coordinates")
        gram = sp.cancel((Gq * Gq.T).det(method="berkowitz"))
        # the measure in the coordinates q (for initial_state) and in the chart (for the run's event)
        self._edge_ratio = (conv(detD ** 2), conv(gram))
        self._qvars = qvars
        num_x, den_x = (tidy(e.xreplace(solution)) for e in (detD ** 2, gram))
        self._edge_ratio_x = (conv(num_x), conv(den_x))
        self._dependent_exprs = [conv(solution[q[a]]) for a in dependent]
        self.variables = z
        field = [e for row in tensor for e in row] + [hy.diff(Hh, v) for v in z]
        self._edge_expr = self._edge_ratio_x[0] - self._edge_ratio_x[1] * hy.par[len(conv.names)]
        params, sources, bits, unit = model_parameters(system, conv, field + [self._edge_expr],
                                                        [("edge2", edge * edge, "edge")])
        if unit is not None:
            Hh = hy.par[unit] * Hh
        shown = ", ".join(f"{k} = {v}" for k, v in solution.items())
        self.poisson = PoissonSystem(z, tensor, Hh, parameters=params, name=f"{system.name} (local chart {shown})",
                                     input_bits=bits, parameter_sources=sources)

    #: The cancelled (expanded) local form is kept unless cancelling the mass matrix J^T M J gives it this many
    #: times its operations as written: an expansion that large is one whose terms cancel (a torus in the chart z =
    #: sqrt(r^2 - (sqrt(x^2 + y^2) - R)^2): its mass matrix 94 -> 264 operations, H a degree-8 polynomial fraction,
    #: and heyoka's runs lost ~5 digits, double and quad ending `invariant_drift`; the sphere's 26 -> 28, an
    #: ellipsoid's 62 -> 98).
    EXPANSION_RATIO = 2

    @staticmethod
    def _local_form(J, M, A, U, psyms):
        """(mass matrix, linear term, H, qdot) of the local chart: the pieces cancelled (:func:`tidy`: exact,
        and compact for charts such as the sphere's, whose H becomes a polynomial in p beside sqrt(1 - x^2 - y^2)),
        or as written (J^T M J and its adjugate over its determinant, nothing expanded) when cancelling expands the
        mass matrix :data:`EXPANSION_RATIO` times or more."""
        Ml = J.T * M * J
        cancelled = Ml.applyfunc(tidy)
        written = sp.count_ops(cancelled) >= ConstrainedLocal.EXPANSION_RATIO * sp.count_ops(Ml)
        simplify = (lambda e: e) if written else tidy
        Ml = Ml if written else cancelled
        Al = (J.T * A).applyfunc(simplify)
        Minv = symbolic_inverse(Ml, cancel=not written)
        w = sp.Matrix(psyms) - Al
        xdot = (Minv * w).applyfunc(simplify)
        H = simplify((w.T * Minv * w)[0, 0] / 2 + U)
        return Ml, Al, H, [simplify(e) for e in (J * xdot)]

    @property
    def _q_variables(self):
        return self._qvars

    def events(self):
        return [(self._edge_expr, "chart_edge",
                 f"the local chart {', '.join(f'{k} = {v}' for k, v in self.chart.items())} is ending "
                 f"(det dG/dq_dep reached {float(self.edge)} of its largest value)")]

    def _edge_value(self, z, dps=RESIDUAL_DPS):
        num, den = self._eval(list(self._edge_ratio_x), z, dps)
        return num, den

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (x, p) from a point q^A on the surface and a tangent velocity: x the free coordinates, p_i =
        dL/dxdot^i. Refuses what :meth:`ConstrainedDirac.initial_state` refuses, a point the chart does not hold
        (another branch: x3 = -0.8 where the chart is x3 = +sqrt(...)), and a point at or beyond its edge."""
        qf, vf, bits = self._surface_inputs(q, qdot)
        cs = self.system
        xf = [qf[i] for i in self.free]
        point = xf + [0] * len(self.free)
        got = self._eval(self._dependent_exprs, point)
        # another branch differs by O(1); the chart amplifies the relative rounding of the free coordinates
        # (x^2/y^2-fold for y = -sqrt(1 - x^2): 1/edge^2 at most), so branches are told apart at the square root
        # of the surface's tolerance
        tol = residual_tolerance(bits)
        for a, g in zip(self.dependent, got):
            with mp.workdps(RESIDUAL_DPS):
                want = mp.mpf(qf[a].numerator) / qf[a].denominator
                off = abs(g - want) > mp.sqrt(mp.mpf(tol.numerator) / tol.denominator) * max(abs(want), abs(g))
            if off:
                raise ValueError(
                    f"`q` is not in this chart: {cs.coordinates[a]} = {mp.nstr(want, 8)} but the chart gives "
                    f"{cs.coordinates[a]} = {self.chart[cs.q_symbols[a]]} = {mp.nstr(g, 8)} there (another branch of the "
                    "solution); use a chart that holds the point")
        num, den = self._edge_value(point)
        if not num > den * (mp.mpf(self.edge.numerator) / self.edge.denominator) ** 2:
            raise ValueError(
                f"`q` is at or beyond the edge of the local chart (det D^2 / det G_q G_q^T = "
                f"{mp.nstr(num / den if den else mp.mpf(0), 4)} <= edge^2 = {float(self.edge) ** 2:.4g}); "
                "choose another chart, or use the global form dirac()")
        at = {cs.q_symbols[i]: sp.Rational(qf[i].numerator, qf[i].denominator) for i in self.free}
        at.update(cs.parameter_substitution())
        Ml = self._sym_mass.xreplace(at)
        Al = self._sym_linear.xreplace(at)
        xdot = sp.Matrix([sp.Rational(vf[i].numerator, vf[i].denominator) for i in self.free])
        p = _exact_numbers(list(Ml * xdot + Al), False, "p")
        return make_state(xf + p, precision, inputs={"q": q, "qdot": qdot})

    def check_state(self, y, argname="y0"):
        """The state as exact Fractions, refused (naming ``argname``) at or beyond the chart's edge."""
        z = Model.check_state(self, y, argname)
        num, den = self._edge_value(z)
        if not num > den * (mp.mpf(self.edge.numerator) / self.edge.denominator) ** 2 * (1 - mp.mpf(10) ** -12):
            raise ValueError(f"`{argname}` is at or beyond the edge of the local chart "
                             f"{', '.join(f'{k} = {v}' for k, v in self.chart.items())}: start inside it")
        return z

    def configuration(self, y) -> np.ndarray:
        """q^A(x) (n numbers per state: the free coordinates and the chart's dependent ones), in the state's
        precision."""
        y, _ = self._with_charts(y, None)
        rows, bits, was_1d = self._rows(y)
        dps = bits_to_dps(bits) + 5
        out = [self._eval(self._configuration_exprs, r, dps) for r in rows]
        like = y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object)
        return self._out_array(out, bits, was_1d, like)

    def __repr__(self) -> str:
        return f"ConstrainedLocal({self.system.name!r}, variables={list(self.names)})"
