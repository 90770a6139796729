"""A Lagrangian with holonomic constraints, turned into Poisson systems (the paper's method as a tool).

:class:`ConstrainedSystem` takes a Lagrangian ``L(q, qdot)`` on n coordinates q^A and k holonomic constraints
G_alpha(q) = 0, and derives symbolically (sympy) the Hamiltonian formulations of the paper:

:meth:`ConstrainedSystem.dirac`
    The 2n variables (q^A, p_A) with the Dirac bracket (paper, eqs. p8.1, p8.7)::

        H_0 = p . v - L(q, v),   v = qdot(q, p) = M^-1 (p - A)
        chi = (G_alpha, Phi_alpha),   Phi_alpha = {G_alpha, H_0} = dG_alpha/dq^A v^A            (p6)
        b = {G, Phi},  c = {Phi, Phi},  Delta = [[0, b], [-b^T, c]],
        Delta^-1 = [[b^-T c b^-1, -b^-T], [b^-1, 0]]                                               (p8.1)
        {f, g}_D = {f, g} - {f, chi_I} Delta^-1_IJ {chi_J, g}                                        (p8.7)

    G_alpha and Phi_alpha are Casimirs of {,}_D (``invariants`` reports them), so a motion that starts on the
    surface G = 0 with a tangent velocity (Phi = 0) stays there; H_0 is the energy.

:meth:`ConstrainedSystem.reduced`
    (q^A, p_i) on the intermediate submanifold Phi = 0, the momenta of k dependent coordinates eliminated (p8.13).
:meth:`ConstrainedSystem.intermediate`
    (q^A, pi_i) with pi_i = G_iA(q) p_A for n - k vector fields G_i tangent to the surface, a chart's (p9) or your
    own (the rigid body's R^-T E_k): {q^A, pi_i} = G_iA, {pi_i, pi_j} = -c_ij^D p_D (p12.1, p20, p24), H'_0 (p14.1).
:meth:`ConstrainedSystem.local`
    Canonical (x^i, p_i) in local coordinates of the surface, from a chart solving the constraints.

The Lagrangian must be quadratic in the velocities, L = 1/2 qdot^T M(q) qdot + A(q) . qdot - U(q), with M
positive definite: that is the class the paper treats (int01.02), for which p = M qdot + A inverts in closed form
and b = G_q M^-1 G_q^T is invertible when the constraints are independent (paper, appendix). The derivation runs
once per system (a few seconds at most for small systems) and is cached.

Parameters of the Lagrangian are heyoka runtime parameters: exact values (int, str such as "9.81", Fraction) stay
exact and are rounded once to each working precision; a float is its binary value and is reported as binary data
(``PoissonSystem.coarse_data``), as everywhere in lieseries. Numbers written in the expressions are read exactly
("0.1" in a string is 1/10); those that are not short binary numbers become runtime parameters too.
"""

from __future__ import annotations

import io
import threading
import tokenize
from fractions import Fraction

import heyoka as hy
import numpy as np
import sympy as sp

from ..poisson import PoissonSystem, expand_integer_powers
from ..precision import BinaryFraction, binary_inputs, bits_to_dps, data_bits, state_bits, to_fraction
from ..precision import thread_mp as mp
from .base import Model, make_state

__all__ = ["ConstrainedSystem", "ConstrainedDirac", "ConstrainedReduced", "ConstrainedIntermediate",
           "ConstrainedLocal"]

#: Functions a Lagrangian or constraint string may use (all of them convert to heyoka).
FUNCTIONS = {
    "sin": sp.sin, "cos": sp.cos, "tan": sp.tan, "asin": sp.asin, "acos": sp.acos, "atan": sp.atan,
    "sinh": sp.sinh, "cosh": sp.cosh, "tanh": sp.tanh, "asinh": sp.asinh, "acosh": sp.acosh, "atanh": sp.atanh,
    "exp": sp.exp, "log": sp.log, "sqrt": sp.sqrt,
}
CONSTANTS = {"pi": sp.pi}

#: Digits at which :meth:`ConstrainedDirac.initial_state` and ``check_state`` measure the constraint residuals.
RESIDUAL_DPS = 60
#: Largest relative residual |G| (and |Phi|) of a point built from exact data, at RESIDUAL_DPS digits.
RESIDUAL_EXACT = Fraction(1, 10**50)
#: Bits with which a momentum that is not rational at rational (q, qdot) (a sin(q) in M) is stored.
IRRATIONAL_BITS = 320


def _residual_tolerance(bits) -> Fraction:
    """Relative residual allowed for data carrying ``bits`` bits (None: exact data)."""
    if bits is None:
        return RESIDUAL_EXACT
    return max(RESIDUAL_EXACT, Fraction(1, 2 ** max(1, int(bits) - 4)))


def _is_name(s) -> bool:
    return isinstance(s, str) and s.isidentifier() and not s.startswith("_")


class ConstrainedSystem:
    """A Lagrangian with holonomic constraints; :meth:`dirac` derives its Poisson system (module docstring).

    Parameters
    ----------
    lagrangian : str or sympy expression
        L in the coordinates and their velocities (coordinate ``x1`` has velocity ``x1_dot``) and the names of
        ``parameters``; quadratic in the velocities with a positive-definite velocity Hessian M(q). Strings are
        read exactly ("9.81" is 981/100); ``^`` means a power; functions: sin, cos, tan, exp, log, sqrt, their
        inverses and hyperbolic versions, and the constant pi.
    coordinates : sequence of str
        The names of the n coordinates q^A.
    constraints : sequence of str or sympy expressions
        The k < n holonomic constraints G_alpha(q) = 0 (no velocities), functionally independent.
    parameters : mapping name -> number, optional
        Values of the other names in the expressions (int, str, Fraction kept exact; a float is binary data).
    name : str, optional
        A label for messages and reports.

    Examples
    --------
    >>> import lieseries as ls
    >>> pend = ls.ConstrainedSystem("m/2*(x_dot**2 + y_dot**2) - m*g*y", ["x", "y"], ["x**2 + y**2 - l**2"],
    ...                             parameters={"m": 1, "g": "9.81", "l": 1})
    >>> model = pend.dirac()
    >>> y0 = model.initial_state(q=("3/5", "-4/5"), qdot=("4/5", "3/5"))
    """

    def __init__(self, lagrangian, coordinates, constraints, *, parameters=None, name=None):
        self.coordinates = self._check_coordinates(coordinates)
        n = len(self.coordinates)
        self.velocities = tuple(f"{c}_dot" for c in self.coordinates)
        params = self._check_parameters(parameters)
        self.parameter_values = {k: to_fraction(v, f"parameters[{k!r}]") for k, v in params.items()}
        self._parameter_bits = {f"parameters[{k!r}]": b for k, b in
                                ((k, data_bits([v])) for k, v in params.items()) if b is not None}
        self._q = [sp.Symbol(c, real=True) for c in self.coordinates]
        self._qd = [sp.Symbol(v, real=True) for v in self.velocities]
        self._par = {k: sp.Symbol(k, real=True) for k in self.parameter_values}
        self._input_bits = {}
        self.lagrangian = self._parse(lagrangian, "lagrangian")
        if isinstance(constraints, (str, bytes)) or not hasattr(constraints, "__len__"):
            raise TypeError("`constraints` must be a list of expressions G(q) (each G = 0 on the surface); got "
                            f"{type(constraints).__name__}. Write one constraint as a one-element list.")
        if len(constraints) == 0:
            raise ValueError("`constraints` must hold at least one constraint G(q); without constraints the motion "
                             "is an ordinary Lagrangian one (write it as a PoissonSystem)")
        self.constraints = tuple(self._parse(g, f"constraints[{i}]", velocities=False)
                                 for i, g in enumerate(constraints))
        k = len(self.constraints)
        if k >= n:
            raise ValueError(f"`constraints`: {k} constraints on {n} coordinates leave no motion; give fewer than "
                             f"{n} (one per dimension removed)")
        self.name = str(name) if name is not None else f"constrained system ({', '.join(self.coordinates)})"
        self._split_lagrangian()
        self._check_hessian()
        self._check_independent()
        self._dirac = None
        self._sym_dirac = None

    # -- input ---------------------------------------------------------------------------------------------------
    @staticmethod
    def _check_coordinates(coordinates):
        if isinstance(coordinates, (str, bytes)) or not hasattr(coordinates, "__len__"):
            raise TypeError(f"`coordinates` must be a list of names such as ['x', 'y']; got {coordinates!r}")
        names = []
        for i, c in enumerate(coordinates):
            c = str(c) if isinstance(c, sp.Symbol) else c
            if not _is_name(c):
                raise ValueError(f"`coordinates[{i}]` must be a Python identifier such as 'x1'; got {c!r}")
            if c in FUNCTIONS or c in CONSTANTS or c.endswith("_dot"):
                raise ValueError(f"`coordinates[{i}]` = {c!r} is reserved (a function, a constant or a velocity "
                                 "name); choose another name")
            names.append(c)
        if not names:
            raise ValueError("`coordinates` must not be empty")
        if len(set(names)) != len(names):
            raise ValueError(f"`coordinates` must be distinct; got {names}")
        return tuple(names)

    def _check_parameters(self, parameters):
        if parameters is None:
            return {}
        if not hasattr(parameters, "items"):
            raise TypeError(f"`parameters` must be a mapping name -> value; got {type(parameters).__name__}")
        out = {}
        taken = set(self.coordinates) | set(self.velocities)
        for k, v in parameters.items():
            if not _is_name(k) or k in FUNCTIONS or k in CONSTANTS:
                raise ValueError(f"`parameters` key {k!r} must be a Python identifier and not a function name")
            if k in taken:
                raise ValueError(f"`parameters` key {k!r} is also a coordinate or a velocity; rename one of them")
            out[k] = v
        return out

    def _symbols(self, velocities=True):
        table = {c: s for c, s in zip(self.coordinates, self._q)}
        if velocities:
            table.update({v: s for v, s in zip(self.velocities, self._qd)})
        table.update(self._par)
        return table

    def _parse(self, expr, argname, velocities=True):
        """A sympy expression in our symbols; refuses unknown names, velocities in constraints, complex numbers."""
        table = self._symbols(True)
        if isinstance(expr, str):
            unknown = []
            try:
                toks = list(tokenize.generate_tokens(io.StringIO(expr).readline))
            except (tokenize.TokenError, IndentationError, SyntaxError) as err:
                raise ValueError(f"`{argname}` could not be read ({err}); write it as a Python/sympy expression "
                                 f"such as 'm/2*x_dot**2 - m*g*x'") from None
            for i, tok in enumerate(toks):
                if tok.type == tokenize.NAME and tok.string not in table and tok.string not in CONSTANTS:
                    nxt = toks[i + 1].string if i + 1 < len(toks) else ""
                    if tok.string in FUNCTIONS and nxt == "(":
                        continue
                    unknown.append(tok.string)
            if unknown:
                self._unknown(argname, unknown)
            from sympy.parsing.sympy_parser import (convert_xor, parse_expr, rationalize,
                                                    standard_transformations)

            local = dict(table)
            local.update(FUNCTIONS)
            local.update(CONSTANTS)
            try:
                out = parse_expr(expr, local_dict=local, global_dict={"Integer": sp.Integer, "Float": sp.Float,
                                                                      "Rational": sp.Rational, "Symbol": sp.Symbol},
                                 transformations=standard_transformations + (convert_xor, rationalize))
            except Exception as err:  # sympy raises many kinds on malformed input
                raise ValueError(f"`{argname}` could not be read as an expression ({type(err).__name__}: {err}); "
                                 "write it as a Python/sympy expression such as 'm/2*x_dot**2 - m*g*x'") from None
        elif isinstance(expr, sp.Basic):
            by_name = {}
            unknown = []
            for s in expr.free_symbols:
                if s.name in table:
                    by_name[s] = table[s.name]
                else:
                    unknown.append(s.name)
            if unknown:
                self._unknown(argname, sorted(unknown))
            out = expr.xreplace(by_name)
            floats = out.atoms(sp.Float)
            if floats:
                # a sympy Float is binary data: keep its exact binary value and say it carries finite precision
                out = out.xreplace({f: sp.Rational(*to_fraction(f).as_integer_ratio()) for f in floats})
                self._input_bits[argname] = min(int(f._prec) for f in floats)
        elif isinstance(expr, (int, Fraction)) and not isinstance(expr, bool):
            out = sp.Rational(expr.numerator, expr.denominator)
        else:
            raise TypeError(f"`{argname}` must be a string or a sympy expression; got {type(expr).__name__}")
        if not isinstance(out, sp.Expr):
            raise ValueError(f"`{argname}` must be a scalar expression; got {type(out).__name__} {out!r}")
        if out.has(sp.I) or out.has(sp.zoo) or out.has(sp.nan) or out.has(sp.oo):
            raise ValueError(f"`{argname}` = {out} is not a finite real expression (it has I, oo or nan)")
        if not velocities:
            used = sorted(str(s) for s in out.free_symbols if s in set(self._qd))
            if used:
                raise ValueError(
                    f"`{argname}` uses the velocities {used}: only holonomic constraints G(q) = 0 are supported "
                    "(the tangency of the velocity, dG/dq . qdot = 0, follows from them). Write the constraint on "
                    "the coordinates alone.")
        return out

    def _unknown(self, argname, unknown):
        shown = ", ".join(f"`{u}`" for u in dict.fromkeys(unknown))
        raise ValueError(
            f"`{argname}` uses {shown}, which is neither a coordinate {list(self.coordinates)}, a velocity "
            f"({', '.join(self.velocities)}), a parameter {list(self.parameter_values)} nor a known function "
            f"({', '.join(sorted(FUNCTIONS))}, pi): add it to `parameters` with its value, or correct the name")

    # -- structure of L ------------------------------------------------------------------------------------------
    def _split_lagrangian(self):
        """M(q), A(q), U(q) with L = 1/2 qdot^T M qdot + A . qdot - U, or an error naming `lagrangian`."""
        L = self.lagrangian
        try:
            poly = sp.Poly(sp.expand(L), *self._qd)
            degree = poly.total_degree()
        except sp.PolynomialError:
            degree = None
        if degree is None or degree > 2:
            raise ValueError(
                "`lagrangian` must be quadratic in the velocities (1/2 qdot^T M(q) qdot + A(q) . qdot - U(q)): the "
                "Legendre transform p = M qdot + A is then inverted exactly; got "
                + ("an expression that is not a polynomial in the velocities" if degree is None else
                   f"degree {degree} in the velocities"))
        n = len(self._q)
        zero = {v: 0 for v in self._qd}
        self._M = sp.Matrix(n, n, lambda a, b: sp.expand(sp.diff(L, self._qd[a], self._qd[b])))
        self._A = sp.Matrix(n, 1, lambda a, _b: sp.diff(L, self._qd[a]).xreplace(zero))
        self._U = -L.xreplace(zero)

    def _values(self):
        return {s: sp.Rational(v.numerator, v.denominator) for k, s in self._par.items()
                for v in [self.parameter_values[k]]}

    def _check_hessian(self):
        M = self._M.xreplace(self._values())
        det = sp.cancel(M.det(method="berkowitz"))
        if det == 0:
            raise ValueError(
                "`lagrangian` is singular: its velocity Hessian M = d2L/dqdot2 has determinant 0 "
                f"(M = {self._M.tolist()}), so the momenta p = dL/dqdot do not determine the velocities. Every "
                "velocity must enter L quadratically (a kinetic term for each coordinate).")
        if not (M.free_symbols & set(self._q)):
            self._check_positive(M, "`lagrangian`", "")
            self._hessian_constant = True
        else:
            self._hessian_constant = False

    def _check_positive(self, M, what, where):
        n = M.shape[0]
        for r in range(1, n + 1):
            minor = M[:r, :r].det(method="berkowitz")
            value = _number(minor, RESIDUAL_DPS)
            if not value > 0:
                raise ValueError(
                    f"{what}: the velocity Hessian M = d2L/dqdot2{where} is not positive definite (its leading "
                    f"{r}x{r} minor is {_show(value)}): the kinetic energy must be positive for every nonzero "
                    "velocity. Check the signs and the mass parameters of the kinetic terms.")

    def _check_independent(self):
        """Generic rank of dG_alpha/dq^A: at two fixed pseudo-random rational points."""
        J = sp.Matrix([[sp.diff(g, q) for q in self._q] for g in self.constraints]).xreplace(self._values())
        self._jacobian = J
        k = len(self.constraints)
        import random

        rng = random.Random(7919 + len(self._q))
        best = 0
        for _ in range(2):
            pt = {q: sp.Rational(rng.randint(300, 1300), 1000) for q in self._q}
            best = max(best, _rank(J.xreplace(pt)))
            if best == k:
                return
        raise ValueError(
            f"`constraints` are functionally dependent: their gradients dG/dq have rank {best} < {k} at generic "
            "points, so they do not cut a surface of dimension n - k (and the Dirac matrix {G, Phi} is singular). "
            "Remove the constraints that follow from the others.")

    # -- formulations --------------------------------------------------------------------------------------------
    def dirac_bracket(self):
        """The symbolic derivation (cached): ``dict`` with sympy ``q``, ``p`` (symbols), ``H0``, ``velocity``
        (qdot(q, p)), ``chi`` (the 2k constraints G then Phi) and ``tensor`` (the 2n x 2n Dirac tensor
        {z_i, z_j}_D, z = (q, p)), in the parameter symbols."""
        if self._sym_dirac is None:
            self._sym_dirac = _memoized(("dirac", self._memo_key()), lambda: _derive_dirac(self))
        return self._sym_dirac

    def dirac(self) -> "ConstrainedDirac":
        """The model on (q^A, p_A) with the Dirac bracket and H_0 (module docstring); built once and cached."""
        if self._dirac is None:
            self._dirac = ConstrainedDirac(self)
        return self._dirac

    def reduced(self, dependent=None, edge="0.05") -> "ConstrainedReduced":
        """The model on the intermediate submanifold Phi = 0 with coordinates (q^A, p_i) (paper, p8.10-p8.15).

        The momenta of the coordinates ``dependent`` (k indices; default: the last k) are eliminated by solving
        Phi_alpha = 0 for them, p_alpha = f_alpha(q, p_i); the bracket is the Dirac bracket of the remaining
        variables with p_alpha = f_alpha substituted (p8.13), the Hamiltonian H_0 likewise (p8.14). Like a chart,
        it holds where the k x k block D = (G_q M^-1)[:, dependent] is invertible: runs stop (status
        ``"chart_edge"``) when det(D)^2 falls to ``edge``^2 det(W W^T), W = G_q M^-1 (for the sphere with x3
        dependent: |x3| = edge |x|). Cached per (dependent, edge)."""
        dep = self._dependent_indices(dependent)
        edge_f = to_fraction(edge, "edge")
        if not 0 < edge_f < 1:
            raise ValueError(f"`edge` must lie in (0, 1) (a fraction of the largest possible |det D|); got {edge!r}")
        cache = self.__dict__.setdefault("_reduced", {})
        key = (tuple(dep), edge_f)
        if key not in cache:
            cache[key] = ConstrainedReduced(self, tuple(dep), edge_f)
        return cache[key]

    def _dependent_indices(self, dependent, argname="dependent"):
        """k distinct coordinate indices from names or indices (default: the last k), or an error naming
        ``argname``."""
        k = len(self.constraints)
        n = len(self.coordinates)
        if dependent is None:
            return tuple(range(n - k, n))
        if isinstance(dependent, (int, np.integer, str)):
            dependent = (dependent,)
        dep = []
        for d in dependent:
            if isinstance(d, str) and d in self.coordinates:
                d = self.coordinates.index(d)
            if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or not 0 <= int(d) < n:
                raise ValueError(f"`{argname}` must name {k} of the coordinates {list(self.coordinates)} (or their "
                                 f"indices); got {dependent!r}")
            dep.append(int(d))
        if len(dep) != k or len(set(dep)) != k:
            raise ValueError(f"`{argname}` must name {k} distinct coordinates (one per constraint); got {dependent!r}")
        return tuple(dep)

    def _memo_key(self):
        return (sp.srepr(self.lagrangian), self.coordinates, tuple(sp.srepr(g) for g in self.constraints),
                tuple(sorted(self._par)))

    def intermediate_bracket(self, dependent=None, frame=None, momenta=None):
        """The symbolic intermediate formalism (paper, p9-p14.1), derived once per system and frame (a module-wide
        memo: a second system with the same Lagrangian, coordinates and constraints reuses it).

        Returns a ``dict`` with sympy ``q``, ``pi`` (the momentum symbols), ``frame`` (the (n-k) x n matrix of the
        tangent vector fields G_i, rows), ``K`` = G_i M G_j^T, ``H`` (H'_0 of p14.1), ``velocity`` (qdot(q, pi)),
        ``p`` (p_A(q, pi) on Phi = 0), ``c`` (the Lie brackets [G_i, G_j], p13/p25) and ``tensor`` (the
        (2n-k) x (2n-k) bracket of (q, pi), p12.1/p20), in the parameter symbols; see :meth:`intermediate`."""
        dep, F, names = self._frame(dependent, frame, momenta)
        return self._intermediate_derivation(dep, F, names)

    def _intermediate_derivation(self, dep, F, names):
        key = ("intermediate", self._memo_key(), dep, None if F is None else sp.srepr(F), tuple(names))
        return _memoized(key, lambda: _derive_intermediate(self, dep, F, names))

    def _frame(self, dependent, frame, momenta):
        """(dependent indices or None, frame matrix or None, momentum names) from the user's arguments."""
        n = len(self.coordinates)
        k = len(self.constraints)
        if frame is None:
            dep = self._dependent_indices(dependent)
            free = [i for i in range(n) if i not in dep]
            default = [f"pi_{self.coordinates[i]}" for i in free]
            F = None
        else:
            if dependent is not None:
                raise ValueError("give `dependent` (a chart of the paper's p9 frame) or `frame` (your own tangent "
                                 "vector fields), not both")
            dep = None
            if isinstance(frame, (str, bytes)) or not hasattr(frame, "__len__") or len(frame) != n - k:
                raise ValueError(f"`frame` must be a list of {n - k} vector fields (one per dimension of the "
                                 f"surface), each a list of {n} expressions in the coordinates; got {frame!r}")
            rows = []
            for i, row in enumerate(frame):
                if isinstance(row, (str, bytes)) or not hasattr(row, "__len__") or len(row) != n:
                    raise ValueError(f"`frame[{i}]` must be a list of {n} expressions (one component per coordinate "
                                     f"{list(self.coordinates)}); got {row!r}")
                rows.append([self._parse(e, f"frame[{i}][{a}]", velocities=False) for a, e in enumerate(row)])
            F = sp.Matrix(rows)
            self._check_frame(F)
            default = [f"pi{i + 1}" for i in range(n - k)]
        if momenta is None:
            names = default
        else:
            if isinstance(momenta, (str, bytes)) or not hasattr(momenta, "__len__") or len(momenta) != n - k:
                raise ValueError(f"`momenta` must be {n - k} names, one per tangent vector field; got {momenta!r}")
            names = [str(m) for m in momenta]
            taken = set(self.coordinates) | set(self.velocities) | set(self._par)
            for i, m in enumerate(names):
                if not _is_name(m) or m in FUNCTIONS or m in CONSTANTS or m in taken:
                    raise ValueError(f"`momenta[{i}]` = {m!r} must be a new identifier (not a coordinate, velocity, "
                                     "parameter or function name)")
            if len(set(names)) != len(names):
                raise ValueError(f"`momenta` must be distinct; got {names}")
        return dep, F, names

    def _check_frame(self, F):
        """A user frame must be tangent to every level set of the constraints (G_alpha,A G_iA = 0, p9) and of full
        rank: checked exactly at pseudo-random rational points (numerically at 60 digits where irrational)."""
        import random

        k = len(self.constraints)
        d = F.shape[0]
        Gq = sp.Matrix([[sp.diff(g, qa) for qa in self._q] for g in self.constraints])
        vals = self._values()
        rng = random.Random(4049 + len(self._q))
        checked = 0
        for _ in range(12):
            pt = {qa: sp.Rational(rng.randint(300, 1300), 1000) for qa in self._q}
            pt.update(vals)
            Fp = F.xreplace(pt)
            if any(e.has(sp.zoo, sp.nan, sp.oo) for e in Fp):
                continue
            Gp = Gq.xreplace(pt)
            prod = Gp * Fp.T
            for a in range(k):
                for i in range(d):
                    val = _number(prod[a, i], RESIDUAL_DPS)
                    if isinstance(val, Fraction):
                        bad = val != 0
                    else:
                        with mp.workdps(RESIDUAL_DPS):
                            size = mp.fsum(abs(_to_mp(_number(Gp[a, b] * Fp[i, b], RESIDUAL_DPS)))
                                           for b in range(Fp.shape[1]))
                            bad = abs(val) > mp.mpf(10) ** -45 * (size or 1)
                    if bad:
                        raise ValueError(
                            f"`frame[{i}]` is not tangent to the constraint surfaces: dG{a + 1}/dq . frame[{i}] = "
                            f"{_show(val)} at q = {[str(pt[s]) for s in self._q]} (it must vanish identically, paper "
                            "p9; e.g. for R^T R = 1 the fields R^-T E_k, E_k antisymmetric)")
            if _rank(Fp) < d:
                raise ValueError(f"`frame` has rank {_rank(Fp)} < {d} at q = {[str(pt[s]) for s in self._q]}: its "
                                 "vector fields must be linearly independent (a basis of the tangent space)")
            checked += 1
            if checked == 2:
                return
        raise ValueError("`frame` is singular (infinite or undefined) at every sample point; give vector fields "
                         "defined on an open set")

    def intermediate(self, dependent=None, frame=None, momenta=None, edge="0.05") -> "ConstrainedIntermediate":
        """The model on the intermediate submanifold in the paper's intermediate formalism (p9-p14.3): the n
        coordinates q^A and n - k momenta pi_i = G_iA(q) p_A, with G_i vector fields tangent to the surface.

        ``frame=None``: the fields of p9 in the chart whose dependent coordinates are ``dependent`` (k names or
        indices; default the last k): G_i has 1 in the free coordinate i, 0 in the other free ones, and solves
        dG_alpha/dq . G_i = 0 in the dependent ones. The chart ends where the block dG/dq_dependent is singular:
        runs stop (status ``"chart_edge"``) when det(dG/dq_dep)^2 falls to ``edge``^2 det(G_q G_q^T) (the
        sphere with x3 dependent: |x3| = edge |x|).
        ``frame``: your own n - k vector fields, each n expressions in the coordinates (and parameters), tangent
        to every level set of the constraints (checked) and independent; e.g. for the rigid body R^TR = 1 the
        fields R^-T E_k (paper, 3.7), which give the body angular momentum. No chart edge is watched then: the
        frame must be defined along the motion (``initial_state`` checks it at the start).
        ``momenta``: names of the pi_i (default ``pi_<coordinate>`` for a chart, ``pi1, ...`` for a frame).

        Bracket: {q^A, q^B} = 0, {q^A, pi_i} = G_iA, {pi_i, pi_j} = -c_ij^D p_D with c_ij = [G_i, G_j] (p12.1,
        p20, p24); H'_0 = H_0 at p on Phi = 0 (p14.1). The G_alpha are Casimirs (``invariants``). Cached."""
        dep, F, names = self._frame(dependent, frame, momenta)
        edge_f = to_fraction(edge, "edge")
        if not 0 < edge_f < 1:
            raise ValueError(f"`edge` must lie in (0, 1) (a fraction of the largest possible |det D|); got {edge!r}")
        cache = self.__dict__.setdefault("_intermediate", {})
        key = (dep, None if F is None else sp.srepr(F), tuple(names), edge_f)
        if key not in cache:
            cache[key] = ConstrainedIntermediate(self, dep, F, names, edge_f)
        return cache[key]

    def local(self, chart=None, edge="0.05") -> "ConstrainedLocal":
        """The canonical model on the surface in local coordinates (x^i, p_i), 2(n - k) variables.

        ``chart``: a mapping {dependent coordinate: expression of the others} that solves the constraints, e.g.
        ``{"x3": "sqrt(c**2 - x1**2 - x2**2)"}`` for the upper half of the sphere (checked: each G_alpha must
        vanish identically after the substitution). The free coordinates are the local ones; L restricted to the
        surface, L(x, xdot) = L(q(x), dq/dx xdot), gives p_i = dL/dxdot^i and the canonical bracket. The chart
        ends where dG/dq_dependent is singular (the branch point of the square root): runs stop (status
        ``"chart_edge"``) when det(dG/dq_dep)^2 falls to ``edge``^2 det(G_q G_q^T), as for :meth:`reduced`.
        Cached per chart and edge."""
        if chart is None:
            raise ValueError("`chart` is required: a mapping {dependent coordinate: expression of the other "
                             "coordinates} solving the constraints, e.g. {'x3': 'sqrt(c**2 - x1**2 - x2**2)'}")
        if not hasattr(chart, "items"):
            raise TypeError(f"`chart` must be a mapping {{coordinate: expression}}; got {type(chart).__name__}")
        dep = self._dependent_indices(list(chart), "chart")
        sol = {}
        dep_syms = {self._q[a] for a in dep}
        for name, e in chart.items():
            a = name if isinstance(name, (int, np.integer)) else self.coordinates.index(name)
            expr = self._parse(e, f"chart[{name!r}]", velocities=False)
            used = sorted(str(s) for s in expr.free_symbols & dep_syms)
            if used:
                raise ValueError(f"`chart[{name!r}]` uses the dependent coordinates {used}: write each dependent "
                                 "coordinate as an expression of the free ones")
            sol[self._q[a]] = expr
        vals = self._values()
        for i, g in enumerate(self.constraints):
            res = sp.simplify(g.xreplace(sol).xreplace(vals))
            if res != 0:
                raise ValueError(f"`chart` does not solve the constraints: G{i + 1} = {self.constraints[i]} becomes "
                                 f"{res} (not 0) with it; give the dependent coordinates as the solution of "
                                 "G = 0 (e.g. x3 = sqrt(c**2 - x1**2 - x2**2))")
        edge_f = to_fraction(edge, "edge")
        if not 0 < edge_f < 1:
            raise ValueError(f"`edge` must lie in (0, 1) (a fraction of the largest possible |det D|); got {edge!r}")
        cache = self.__dict__.setdefault("_local", {})
        key = (tuple(sorted((str(s), sp.srepr(e)) for s, e in sol.items())), edge_f)
        if key not in cache:
            cache[key] = ConstrainedLocal(self, dep, sol, edge_f)
        return cache[key]

    def __repr__(self) -> str:
        return (f"ConstrainedSystem({str(self.lagrangian)!r}, {list(self.coordinates)}, "
                f"{[str(g) for g in self.constraints]}, "
                f"parameters={ {k: str(v) for k, v in self.parameter_values.items()} })")


# -- helpers ---------------------------------------------------------------------------------------------------------
def _number(expr, dps):
    """A sympy number as a Fraction (exact) or an mpf at ``dps`` digits."""
    expr = sp.sympify(expr)
    if isinstance(expr, sp.Rational):
        return Fraction(int(expr.p), int(expr.q))
    val = expr.evalf(dps + 10)
    if not val.is_number or val.has(sp.I):
        raise ValueError(f"not a real number: {expr}")
    with mp.workdps(dps + 10):
        return mp.mpf(sp.Float(val, dps + 10)._mpf_)


def _to_mp(v):
    return mp.mpf(v.numerator) / v.denominator if isinstance(v, Fraction) else v


def _show(v):
    return f"{float(v):.6g}" if isinstance(v, Fraction) else mp.nstr(v, 8)


def _rank(A) -> int:
    """Rank of a matrix of numbers: exact when rational, else numerical at 50 digits."""
    if all(isinstance(e, sp.Rational) for e in A):
        return A.rank()
    with mp.workdps(60):
        B = mp.matrix([[mp.mpf(sp.Float(e.evalf(70), 70)._mpf_) for e in row] for row in A.tolist()])
        s = mp.svd_r(B, compute_uv=False)
        big = max(abs(x) for x in s) if len(s) else 0
        return sum(1 for x in s if abs(x) > big * mp.mpf(10) ** -40)


def _canonical(f, g, q, p):
    return sum(sp.diff(f, q[a]) * sp.diff(g, p[a]) - sp.diff(f, p[a]) * sp.diff(g, q[a]) for a in range(len(q)))


def _tidy(e):
    e = sp.cancel(sp.together(e))
    return sp.factor_terms(e)


def _dirac_combination(bs, cs_, bz, n, k):
    """(b, c, T): b = {G, Phi}, c = {Phi, Phi} and the Dirac tensor T_ij = {z_i, z_j} - {z_i, chi_I} Delta^-1_IJ
    {chi_J, z_j} (p8.1, p8.7) from the canonical brackets ``bs`` = {G_a, Phi_c}, ``cs_`` = {Phi_a, Phi_d} (a < d)
    and ``bz`` = {z_i, chi_I}.

    The combination is done in a field of rational functions (sympy's sparse polynomials, one gcd per operation on
    small pieces): expression-level together/cancel on the assembled entries took 25 s for the double spherical
    pendulum, the same result here takes a few. Expressions the field cannot hold (a domain that is not the
    rationals) take the expression route."""
    from sympy.polys.fields import sfield

    flat = [e for row in bs for e in row] + [e for row in cs_ for e in row] + [e for row in bz for e in row]
    try:
        K, els = sfield([sp.sympify(e) for e in flat])
    except Exception:  # sympy refuses some expressions as polynomial generators: the expression route then
        K = None
    if K is None or not (K.domain.is_ZZ or K.domain.is_QQ):
        return _dirac_combination_expr(bs, cs_, bz, n, k)
    it = iter(els)
    bf = [[next(it) for _ in range(k)] for _ in range(k)]
    cf = [[next(it) for _ in range(k)] for _ in range(k)]
    zf = [[next(it) for _ in range(2 * k)] for _ in range(2 * n)]
    for a in range(k):
        for d in range(a):
            cf[a][d] = -cf[d][a]
    binv = _field_inverse(bf, K)
    binvT = [list(r) for r in zip(*binv)]
    top = _field_mul(_field_mul(binvT, cf, K), binv, K)
    # Delta^-1 = [[b^-T c b^-1, -b^-T], [b^-1, 0]] over chi = (G, Phi)
    dinv = [top[i] + [-x for x in binvT[i]] for i in range(k)] + [binv[i] + [K.zero] * k for i in range(k)]
    T = sp.zeros(2 * n, 2 * n)
    for i in range(2 * n):
        for j in range(i + 1, 2 * n):
            acc = K.one if (i < n and j == i + n) else K.zero
            for I in range(2 * k):
                if not zf[i][I]:
                    continue
                for J in range(2 * k):
                    if dinv[I][J] and zf[j][J]:
                        acc += zf[i][I] * dinv[I][J] * zf[j][J]  # - {z_i, chi_I} D_IJ {chi_J, z_j}
            e = _field_expr(acc)
            T[i, j] = e
            T[j, i] = -e
    b = sp.Matrix(k, k, lambda a, d: _field_expr(bf[a][d]))
    c = sp.Matrix(k, k, lambda a, d: _field_expr(cf[a][d]) if a != d else 0)
    return b, c, T


def _field_mul(X, Y, K):
    return [[sum((X[i][m] * Y[m][j] for m in range(len(Y))), K.zero) for j in range(len(Y[0]))]
            for i in range(len(X))]


def _field_inverse(B, K):
    """Inverse of a small square matrix of field elements: the generic adjugate over the determinant."""
    d = len(B)
    gen = sp.Matrix(d, d, lambda i, j: sp.Symbol(f"__k{i}_{j}"))
    det = _field_eval(gen.det(method="berkowitz"), gen, B, K)
    if not det:
        raise ValueError("internal: the Dirac matrix {G, Phi} is singular")
    adj = gen.adjugate(method="berkowitz")
    return [[_field_eval(adj[i, j], gen, B, K) / det for j in range(d)] for i in range(d)]


def _field_eval(poly, gen, B, K):
    """The polynomial ``poly`` in the generic entries ``gen`` at the field elements ``B``."""
    d = len(B)
    P = sp.Poly(poly, *[gen[i, j] for i in range(d) for j in range(d)])
    vals = [B[i][j] for i in range(d) for j in range(d)]
    out = K.zero
    for monom, coeff in P.terms():
        term = K(coeff)
        for v, e in zip(vals, monom):
            if e:
                term *= v ** e
        out += term
    return out


def _field_expr(x):
    """A field element as a sympy expression: numerator and denominator with their integer content and common
    monomial pulled out (what factor_terms does, on the polynomials, at a fraction of its cost)."""
    num, den = x.numer, x.denom
    if not num:
        return sp.Integer(0)
    syms = x.field.ring.symbols
    factor = sp.Integer(1)
    parts = []
    for poly, power in ((num, 1), (den, -1)):
        content, poly = poly.primitive()
        if poly.LC < 0:
            content, poly = -content, -poly
        monom = tuple(min(es) for es in zip(*poly.itermonoms()))
        if any(monom):
            poly = poly.ring({tuple(a - b for a, b in zip(m, monom)): c for m, c in poly.items()})
        factor *= (sp.Integer(content) * sp.Mul(*[s ** e for s, e in zip(syms, monom)])) ** power
        parts.append(poly.as_expr())
    return factor * parts[0] / parts[1]


def _dirac_combination_expr(bs, cs_, bz, n, k):
    """:func:`_dirac_combination` with sympy expressions (together/cancel per entry)."""
    b = sp.Matrix(k, k, lambda a, d: _tidy(bs[a][d]))
    c = sp.Matrix(k, k, lambda a, d: (_tidy(cs_[a][d]) if a < d else -_tidy(cs_[d][a])) if a != d else 0)
    binv = _inverse(b).applyfunc(sp.cancel)
    Dinv = sp.zeros(2 * k, 2 * k)
    Dinv[:k, :k] = (binv.T * c * binv).applyfunc(sp.cancel)
    Dinv[:k, k:] = -binv.T
    Dinv[k:, :k] = binv
    T = sp.zeros(2 * n, 2 * n)
    for i in range(2 * n):
        for j in range(i + 1, 2 * n):
            canon = 1 if (i < n and j == i + n) else 0
            corr = 0
            for I in range(2 * k):
                if bz[i][I] == 0:
                    continue
                for J in range(2 * k):
                    if Dinv[I, J] == 0 or bz[j][J] == 0:
                        continue
                    corr += bz[i][I] * Dinv[I, J] * (-bz[j][J])  # {chi_J, z_j} = -{z_j, chi_J}
            e = _tidy(canon - corr)
            T[i, j] = e
            T[j, i] = -e
    return b, c, T


def _derive_dirac(cs):
    n = len(cs._q)
    k = len(cs.constraints)
    q = list(cs._q)
    p = [sp.Symbol(f"p_{c}", real=True) for c in cs.coordinates]
    M, A, U = cs._M, cs._A, cs._U
    Minv = M.inv(method="LU") if any(M[i, j] != 0 for i in range(n) for j in range(n) if i != j) else \
        sp.diag(*[1 / M[i, i] for i in range(n)])
    Minv = Minv.applyfunc(sp.cancel)
    P = sp.Matrix(p)
    v = (Minv * (P - A)).applyfunc(sp.cancel)
    H0 = sp.expand((((P - A).T * Minv * (P - A))[0, 0]) / 2 + U)
    G = list(cs.constraints)
    Phi = [sp.expand(sum(sp.diff(g, q[a]) * v[a] for a in range(n))) for g in G]
    chi = G + Phi
    z = q + p
    bz = [[_canonical(zi, ch, q, p) for ch in chi] for zi in z]  # {z_i, chi_I}
    bs = [[_canonical(G[a], Phi[c], q, p) for c in range(k)] for a in range(k)]
    cs_ = [[_canonical(Phi[a], Phi[d], q, p) if a < d else 0 for d in range(k)] for a in range(k)]
    b, c, T = _dirac_combination(bs, cs_, bz, n, k)
    return {"q": q, "p": p, "H0": H0, "velocity": list(v), "chi": chi, "G": G, "Phi": Phi, "tensor": T,
            "b": b, "c": c}


_MEMO: dict = {}
_MEMO_LOCK = threading.Lock()


def _memoized(key, derive):
    """The derivation ``derive()`` once per ``key`` in this process (symbolic results are immutable and shared by
    every system with the same inputs); one derivation at a time."""
    with _MEMO_LOCK:
        if key not in _MEMO:
            _MEMO[key] = derive()
        return _MEMO[key]


def _small(e, limit=400) -> bool:
    return sp.count_ops(e) <= limit


def _lie_bracket(Fi, Fj, q):
    """[G_i, G_j]^D = G_iE d_E G_jD - G_jE d_E G_iD (paper, p13)."""
    n = len(q)
    return [sum(Fi[E] * sp.diff(Fj[D], q[E]) - Fj[E] * sp.diff(Fi[D], q[E]) for E in range(n)) for D in range(n)]


def _inverse(K):
    """Inverse of a small symbolic matrix, entries simplified when that is cheap."""
    d = K.shape[0]
    if d == 1:
        return sp.Matrix([[1 / K[0, 0]]])
    if all(K[i, j] == 0 for i in range(d) for j in range(d) if i != j):
        return sp.diag(*[1 / K[i, i] for i in range(d)])
    # the generic d x d adjugate and determinant, then the entries put in (no expansion of large entries)
    gen = sp.Matrix(d, d, lambda i, j: sp.Symbol(f"__k{i}_{j}"))
    sub = {gen[i, j]: K[i, j] for i in range(d) for j in range(d)}
    det = gen.det(method="berkowitz").xreplace(sub)
    adj = gen.adjugate(method="berkowitz").xreplace(sub)
    if _small(det) and all(_small(e) for e in adj):
        det = sp.cancel(det)
        return adj.applyfunc(lambda e: sp.cancel(e / det))
    return adj / det


def _derive_intermediate(cs, dependent, F, names):
    """The intermediate formalism (paper, p9-p14.1) for the frame F (rows G_i; None: the chart of p9).

    With W = G_q M^-1 and the momenta pi_i = G_iA p_A, the point p of the intermediate submanifold Phi = W (p - A)
    = 0 with given pi is p = A + M G^T K^-1 (pi - G A), K = G M G^T (the velocity v = M^-1 (p - A) is tangent,
    v = G^T a, and G p = pi fixes a): this is p = G~ pi with pi_alpha = f_alpha(q, pi_i) of p10 and p19.0, written
    without the n x n inverse G~. H'_0 = 1/2 v^T M v + U at that point (p14.1)."""
    n = len(cs._q)
    k = len(cs.constraints)
    d = n - k
    q = list(cs._q)
    Gq = sp.Matrix([[sp.diff(g, qa) for qa in q] for g in cs.constraints])
    out = {"q": q, "G": list(cs.constraints), "dependent": dependent}
    if F is None:
        free = [i for i in range(n) if i not in dependent]
        D = Gq[:, list(dependent)]
        detD = sp.cancel(D.det(method="berkowitz"))
        if detD == 0:
            raise ValueError(f"`dependent`: the constraints cannot be solved for "
                             f"{[cs.coordinates[a] for a in dependent]} (the block dG/dq of these coordinates is "
                             "singular everywhere); choose other coordinates")
        Dinv = _inverse(D)
        F = sp.zeros(d, n)
        for r, i in enumerate(free):
            F[r, i] = 1
            col = -(Dinv * Gq[:, i])
            for a, dep in enumerate(dependent):
                F[r, dep] = _tidy(col[a])
        out["detD"] = detD
        out["gram"] = sp.cancel((Gq * Gq.T).det(method="berkowitz"))
    pi = [sp.Symbol(nm, real=True) for nm in names]
    M, A, U = cs._M, cs._A, cs._U
    simplify = dependent is not None  # a chart's frame is simple; a frame of your own may be large (R^-T)
    out.update({"pi": pi, "frame": F, "M": M, "A": A, "U": U})
    if not simplify:
        # the Lie brackets c_ij, K, its inverse, H'_0 and the bracket of the pi are assembled from these pieces
        # in heyoka (ConstrainedIntermediate), where common pieces stay shared: expanding them symbolically costs
        # minutes for the rigid body
        out.update({"c": None, "K": F * M * F.T, "H": None, "velocity": None, "p": None, "tensor": None})
        return out
    c = {}
    for i in range(d):
        for j in range(i + 1, d):
            c[(i, j)] = [sp.cancel(e) for e in _lie_bracket(F.row(i), F.row(j), q)]
    out["c"] = c
    K = (F * M * F.T).applyfunc(sp.cancel)
    Kinv = _inverse(K)
    w = sp.Matrix(pi) - F * A
    a = Kinv * w
    v = (F.T * a).applyfunc(_tidy)
    p = (A + M * v).applyfunc(_tidy)
    H = _tidy((w.T * a)[0, 0] / 2 + U)
    T = sp.zeros(n + d, n + d)
    for i in range(d):
        for A_ in range(n):
            if F[i, A_] != 0:
                T[A_, n + i] = F[i, A_]
                T[n + i, A_] = -F[i, A_]
    for (i, j), cij in c.items():
        if all(e == 0 for e in cij):
            continue
        e = _tidy(-sum(cij[D_] * p[D_] for D_ in range(n) if cij[D_] != 0))
        T[n + i, n + j] = e
        T[n + j, n + i] = -e
    out.update({"K": K, "H": H, "velocity": list(v), "p": list(p), "tensor": T})
    return out


def _assemble_intermediate(d, conv, z, n):
    """Heyoka tensor, H'_0 and velocity of the intermediate formalism from the pieces of a derivation (p12.1, p24,
    p14.1), for frames whose symbolic expansion is too large: K^-1 as adj(K)/det(K) of the 3x3 or smaller
    generic matrix, every piece shared."""
    F = d["frame"]
    nf = F.shape[0]
    Fh = [[conv(F[i, A]) if F[i, A] != 0 else 0 for A in range(n)] for i in range(nf)]
    M, A, U = d["M"], d["A"], d["U"]
    Mh = [[conv(M[a, b]) if M[a, b] != 0 else 0 for b in range(n)] for a in range(n)]
    Ah = [conv(A[a]) if A[a] != 0 else 0 for a in range(n)]
    Uh = conv(U)
    pis = z[n:]

    def dot(xs, ys):
        terms = [x * y for x, y in zip(xs, ys) if not (_zero(x) or _zero(y))]
        return hy.sum(terms) if terms else hy.expression(0.0)

    MF = [[dot(Mh[a], Fh[l]) for l in range(nf)] for a in range(n)]  # (M F^T)_{a l}
    K = [[dot([Fh[k][a] for a in range(n)], [MF[a][l] for a in range(n)]) for l in range(nf)] for k in range(nf)]
    gen = sp.Matrix(nf, nf, lambda i, j: sp.Symbol(f"__k{i}_{j}"))
    det_s = gen.det(method="berkowitz")
    adj_s = gen.adjugate(method="berkowitz")
    ks = {gen[i, j]: hy.expression(f"__k{i}_{j}") for i in range(nf) for j in range(nf)}
    subs = {f"__k{i}_{j}": K[i][j] for i in range(nf) for j in range(nf)}
    det = hy.subs(hy.from_sympy(det_s, s_dict=ks), subs)
    Kinv = [[hy.subs(hy.from_sympy(adj_s[i, j], s_dict=ks), subs) / det for j in range(nf)] for i in range(nf)]
    w = [pis[i] - dot(Fh[i], Ah) for i in range(nf)]
    a = [dot(Kinv[i], w) for i in range(nf)]
    H = 0.5 * dot(w, a) + Uh
    v = [dot([Fh[i][A_] for i in range(nf)], a) for A_ in range(n)]
    p = [Ah[A_] + dot(Mh[A_], v) if not _zero(Ah[A_]) else dot(Mh[A_], v) for A_ in range(n)]
    m = n + nf
    tensor = [[0] * m for _ in range(m)]
    for i in range(nf):
        for A_ in range(n):
            if not _zero(Fh[i][A_]):
                tensor[A_][n + i] = Fh[i][A_]
                tensor[n + i][A_] = -Fh[i][A_]
    qv = z[:n]
    for i in range(nf):
        for j in range(i + 1, nf):
            # c_ij^D = G_iE d_E G_jD - G_jE d_E G_iD (p13), differentiated in heyoka (shared subexpressions)
            terms = []
            for D_ in range(n):
                parts = [Fh[i][E] * hy.diff(Fh[j][D_], qv[E]) for E in range(n)
                         if not _zero(Fh[i][E]) and not _zero(Fh[j][D_])]
                parts += [-(Fh[j][E] * hy.diff(Fh[i][D_], qv[E])) for E in range(n)
                          if not _zero(Fh[j][E]) and not _zero(Fh[i][D_])]
                if parts:
                    terms.append(hy.sum(parts) * p[D_])
            if not terms:
                continue
            e = -hy.sum(terms)
            tensor[n + i][n + j] = e
            tensor[n + j][n + i] = -e
    return tensor, H, v


def _zero(x) -> bool:
    return isinstance(x, (int, float)) and x == 0


class _HeyokaConverter:
    """sympy -> heyoka, with the parameters as runtime parameters and every number that is not a short binary
    number (1/3, 981/100) turned into a runtime parameter of its own (heyoka stores constants as doubles)."""

    def __init__(self, cs, variables):
        self.values = dict(cs.parameter_values)
        self.names = list(self.values)
        self.s_dict = {s: v for s, v in variables}
        for i, k in enumerate(self.names):
            self.s_dict[cs._par[k]] = hy.par[i]
        self.constants = {}

    def __call__(self, expr):
        expr = sp.sympify(expr)
        repl = {}
        for r in expr.atoms(sp.Rational):
            if _dyadic(r):
                continue
            if r not in self.constants:
                name = f"c{len(self.constants) + 1}"
                while name in self.values:
                    name = "_" + name
                self.constants[r] = (len(self.names), name)
                self.names.append(name)
                self.values[name] = Fraction(int(r.p), int(r.q))
                self.s_dict[sp.Symbol(f"__const_{name}")] = hy.par[len(self.names) - 1]
            repl[r] = sp.Symbol(f"__const_{self.constants[r][1]}")
        if repl:
            expr = _replace_numbers(expr, repl)
        return hy.from_sympy(expand_integer_powers(expr), s_dict=self.s_dict)


def _dyadic(r) -> bool:
    num, den = abs(int(r.p)), int(r.q)
    return den & (den - 1) == 0 and num < 2**53 and den <= 2**60


def _replace_numbers(expr, repl):
    """xreplace of numbers, also where sympy folds them into a Mul's coefficient or a power's exponent."""
    if expr.is_Atom:
        return repl.get(expr, expr)
    args = [_replace_numbers(a, repl) for a in expr.args]
    if isinstance(expr, sp.Mul):
        return sp.Mul(*args, evaluate=False)
    if isinstance(expr, sp.Add):
        return sp.Add(*args, evaluate=False)
    if isinstance(expr, sp.Pow):
        return sp.Pow(*args, evaluate=False)
    return expr.func(*args)


#: Size (nodes of the sympy trees of the tensor and the Hamiltonian) above which a derived model is compiled by the
#: Taylor integrator in compact mode: unrolled, LLVM took 280 CPU s on the double spherical pendulum's Dirac
#: tensor (12 variables, 12000 operations), compact 5 s; the sphere's (200 nodes) stays unrolled.
LARGE_FIELD_NODES = 3000


def _large_field(exprs) -> bool:
    total = 0
    for e in exprs:
        for x in (e if isinstance(e, sp.MatrixBase) else [e]):
            total += sum(1 for _ in sp.preorder_traversal(x))
            if total > LARGE_FIELD_NODES:
                return True
    return False


class ConstrainedDirac(Model):
    """A :class:`ConstrainedSystem` on (q^A, p_A) with the Dirac bracket and H_0 (module docstring).

    State: the n coordinates, then their n momenta p_A = dL/dqdot^A (names ``p_<coordinate>``). ``invariants``
    gives H_0 (``energy``) and the constraints G_alpha, Phi_alpha (``G1``, ..., ``Phi1``, ...), Casimirs of the
    bracket: zero along a motion from :meth:`initial_state`, up to the run's rounding.
    """

    def __init__(self, system: ConstrainedSystem):
        self.system = system
        n = len(system.coordinates)
        self.n = n
        d = system.dirac_bracket()
        names = list(system.coordinates) + [f"p_{c}" for c in system.coordinates]
        z = hy.make_vars(*names)
        conv = _HeyokaConverter(system, list(zip(d["q"] + d["p"], z)))
        T = d["tensor"]
        self.large_field = _large_field([T, d["H0"]])
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
        bits = dict(system._parameter_bits)
        bits.update(system._input_bits)
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
        from ..expr import compile_expressions

        prog = compile_expressions(self.variables if variables is None else variables, exprs,
                                   len(self.poisson.parameter_values))
        return prog.evaluate(list(values), list(self.poisson.parameter_values), dps)

    def _check_surface(self, q, qdot, bits, qname="q", vname="qdot", loose=False):
        """Refuse a point off G = 0 or a velocity not tangent to it (relative residuals at 60 digits). ``loose``:
        for binary data, allow the square root of their precision (a state a run ended in has drifted)."""
        tol_exact = _residual_tolerance(bits)
        if loose and bits is not None:
            tol_exact = max(RESIDUAL_EXACT, Fraction(1, 2 ** max(1, (int(bits) - 4) // 2)))
        n = self.n
        qvars = self._q_variables
        point = list(q) + [0] * (len(qvars) - n)
        k = len(self._terms)
        flat = [t for ts in self._terms for t in ts] + [g for row in self._gradients for g in row]
        vals = self._eval(flat, point, variables=qvars)
        # the residuals at RESIDUAL_DPS: at the context's own 53 bits, mpf(8)/5 made a tangent velocity
        # (0.8, 0, 0.6) at (0.6, 0, -0.8) miss tangency by 6e-17 and an exact state was refused by its run
        with mp.workdps(RESIDUAL_DPS):
            tol = mp.mpf(tol_exact.numerator) / tol_exact.denominator
            pos = 0
            for a in range(k):
                terms = vals[pos:pos + len(self._terms[a])]
                pos += len(self._terms[a])
                res = mp.fsum(terms)
                scale = mp.fsum(abs(t) for t in terms)
                if abs(res) > tol * scale:
                    raise ValueError(
                        f"`{qname}` is not on the constraint surface: G{a + 1} = {self.system.constraints[a]} = "
                        f"{mp.nstr(res, 6)} at it (relative {mp.nstr(abs(res) / scale, 3)} > {mp.nstr(mp.mpf(tol), 3)})."
                        " Give a point with G = 0 exactly (strings or Fractions: '3/5', '0.6')"
                        + ("" if bits is None else f"; binary floats carry {int(bits)} bits only"))
            for a in range(k):
                grad = vals[pos:pos + n]
                pos += n
                if qdot is None:
                    continue
                terms = [g * mp.mpf(v.numerator) / v.denominator for g, v in zip(grad, qdot)]
                res = mp.fsum(terms)
                scale = mp.fsum(abs(t) for t in terms)
                if abs(res) > tol * scale:
                    raise ValueError(
                        f"`{vname}` is not tangent to the constraint surface: dG{a + 1}/dq . qdot = {mp.nstr(res, 6)} "
                        f"(relative {mp.nstr(abs(res) / scale, 3)} > {mp.nstr(mp.mpf(tol), 3)}). Remove its normal "
                        "part (the motion keeps dG/dt = 0)"
                        + ("" if bits is None else f"; binary floats carry {int(bits)} bits only"))

    def _surface_inputs(self, q, qdot):
        """(q, qdot as exact vectors, the bits their binary floats carry or None), refused unless q lies on the
        constraints and qdot is tangent to them."""
        qf = self._vector(q, "q")
        vf = self._vector(qdot, "qdot")
        binary = {}
        for nm, val in (("q", q), ("qdot", qdot)):
            binary.update(binary_inputs(val, nm))
        bits = min(binary.values()) if binary else None
        self._check_surface(qf, vf, bits)
        return qf, vf, bits

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (q, p) with p = M(q) qdot + A(q) from a point on the surface and a tangent velocity.

        Exact input (int, str, Fraction) is kept exact: an :class:`~lieseries.models.base.ExactState` unless
        ``precision`` is given. Refuses a point with |G_alpha(q)| above 1e-50 relative to the size of G's terms
        (at 60 digits; for binary floats, above their own precision), and a velocity with dG/dq . qdot likewise,
        naming ``q`` or ``qdot`` with the residual; a velocity Hessian that is not positive definite or
        constraints that are dependent at ``q``.
        """
        qf, vf, bits = self._surface_inputs(q, qdot)
        cs = self.system
        at = {s: sp.Rational(f.numerator, f.denominator) for s, f in zip(cs._q, qf)}
        at.update(cs._values())
        M = cs._M.xreplace(at)
        if not cs._hessian_constant:
            cs._check_positive(M, "`q`", " at this point")
        J = cs._jacobian.xreplace(at)
        if _rank(J) < len(cs.constraints):
            raise ValueError(f"`q`: the constraint gradients dG/dq are dependent at this point (rank "
                             f"{_rank(J)} < {len(cs.constraints)}): the surface is singular there; start elsewhere")
        vdot = sp.Matrix([sp.Rational(f.numerator, f.denominator) for f in vf])
        pvals = list(M * vdot + cs._A.xreplace(at))
        p = []
        irrational = False
        for e in pvals:
            val = _number(e, bits_to_dps(IRRATIONAL_BITS))
            if not isinstance(val, Fraction):
                irrational = True
                val = to_fraction(val)
            p.append(val)
        if irrational and precision is None:
            # stored with IRRATIONAL_BITS bits, and marked so: no estimate claims more
            p = [BinaryFraction(v, IRRATIONAL_BITS, ("p (irrational at q)",)) for v in p]
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

    def __init__(self, system: ConstrainedSystem, dependent: tuple, edge: Fraction):
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
        sol = sp.solve(d["Phi"], pdep, dict=True)
        W = sp.Matrix([[sp.diff(phi, p[a]) for a in range(n)] for phi in d["Phi"]])
        D = W[:, list(dependent)]
        detD = sp.cancel(D.det(method="berkowitz"))
        if not sol or detD == 0:
            raise ValueError(f"`dependent`: the constraints Phi = 0 cannot be solved for the momenta of "
                             f"{[system.coordinates[a] for a in dependent]} (the block of dPhi/dp is singular "
                             "everywhere); choose other coordinates")
        f = {pa: sp.cancel(sol[0][pa]) for pa in pdep}
        idx = list(range(n)) + [n + i for i in free]
        names = list(system.coordinates) + [f"p_{system.coordinates[i]}" for i in free]
        z = hy.make_vars(*names)
        syms = q + [p[i] for i in free]
        conv = _HeyokaConverter(system, list(zip(syms, z)))
        T = d["tensor"]
        m = len(idx)
        tensor = [[0] * m for _ in range(m)]
        self._sym_tensor = sp.zeros(m, m)
        for a in range(m):
            for b in range(a + 1, m):
                e = T[idx[a], idx[b]]
                if e != 0:
                    e = _tidy(e.xreplace(f))
                if e != 0:
                    self._sym_tensor[a, b], self._sym_tensor[b, a] = e, -e
                    tensor[a][b] = conv(e)
                    tensor[b][a] = -tensor[a][b]
        H0 = sp.cancel(d["H0"].xreplace(f))
        self._sym_hamiltonian = H0
        self.large_field = _large_field([self._sym_tensor, H0])
        self._sym_dependent = f
        H = conv(H0)
        casimirs = {f"G{a + 1}": conv(d["G"][a]) for a in range(k)}
        self._velocity_exprs = [conv(sp.cancel(e.xreplace(f))) for e in d["velocity"]]
        self._gradients = [[conv(sp.diff(g, qa)) for qa in q] for g in d["G"]]
        self._terms = [[conv(t) for t in sp.Add.make_args(sp.expand(g))] for g in d["G"]]
        gram = sp.cancel((W * W.T).det(method="berkowitz"))
        self._edge_expr = conv(detD**2) - conv(gram) * hy.par[len(conv.names)]
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
        bits = dict(system._parameter_bits)
        bits.update(system._input_bits)
        self.poisson = PoissonSystem(z, tensor, H, parameters=params, casimirs=casimirs,
                                     name=f"{system.name} (reduced, p of "
                                          f"{', '.join(system.coordinates[a] for a in dependent)} eliminated)",
                                     input_bits=bits, parameter_sources=sources)

    def events(self):
        return [(self._edge_expr, "chart_edge",
                 f"the chart of the momenta of {[self.system.coordinates[a] for a in self.dependent]} is ending "
                 f"(det D reached {float(self.edge)} of its largest value)")]

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


def _model_parameters(system, conv, field_exprs, extra=()):
    """(parameters, sources, bits) of a derived model: the converter's parameters, ``extra`` (name, value, source)
    appended, and an exact unit factor when the last parameter is used by nothing in ``field_exprs`` (heyoka
    counts the parameters of an ODE as 1 + the largest index it uses)."""
    params = {nm: conv.values[nm] for nm in conv.names}
    sources = {nm: f"parameters[{nm!r}]" for nm in system.parameter_values}
    sources.update({nm: "lagrangian" for nm in params if nm not in system.parameter_values})
    for name, value, source in extra:
        while name in params:
            name = "_" + name
        params[name] = value
        sources[name] = source
    used = {int(str(pp)[1:]) for pp in hy.get_params([e for e in field_exprs if isinstance(e, hy.expression)])}
    unit_index = None
    if params and (len(params) - 1) not in used:
        unit = "one"
        while unit in params:
            unit = "_" + unit
        params[unit] = Fraction(1)
        sources[unit] = "lagrangian"
        unit_index = len(params) - 1
    bits = dict(system._parameter_bits)
    bits.update(system._input_bits)
    return params, sources, bits, unit_index


def _heyoka_tensor(conv, T):
    m = T.shape[0]
    tensor = [[0] * m for _ in range(m)]
    for a in range(m):
        for b in range(a + 1, m):
            if T[a, b] != 0:
                e = conv(T[a, b])
                tensor[a][b] = e
                tensor[b][a] = -e
    return tensor


def _exact_numbers(exprs, marked):
    """Sympy numbers as Fractions; irrational ones (or any, when ``marked`` inputs carried finite bits) stored with
    IRRATIONAL_BITS bits and marked so."""
    out = []
    irrational = False
    for e in exprs:
        val = _number(e, bits_to_dps(IRRATIONAL_BITS))
        if not isinstance(val, Fraction):
            irrational = True
            val = to_fraction(val)
        out.append(val)
    if irrational or marked:
        out = [BinaryFraction(v, IRRATIONAL_BITS, ("pi (irrational at q)",)) for v in out]
    return out


class ConstrainedIntermediate(ConstrainedDirac):
    """A :class:`ConstrainedSystem` in the paper's intermediate formalism: (q^A, pi_i), 2n - k variables (p9-p14.3);
    see :meth:`ConstrainedSystem.intermediate`. ``invariants``: ``energy`` H'_0 and the Casimirs ``G1..``."""

    large_field = False

    def __init__(self, system: ConstrainedSystem, dependent, frame, names, edge: Fraction):
        self.system = system
        self.dependent = dependent
        self.edge = edge
        n = len(system.coordinates)
        k = len(system.constraints)
        self.n = n
        d = system._intermediate_derivation(dependent, frame, names)
        self.derivation = d
        self.frame = d["frame"]
        z = hy.make_vars(*(list(system.coordinates) + list(names)))
        conv = _HeyokaConverter(system, list(zip(d["q"] + d["pi"], z)))
        if d["H"] is not None:
            tensor = _heyoka_tensor(conv, d["tensor"])
            H = conv(d["H"])
            self._velocity_exprs = [conv(e) for e in d["velocity"]]
        else:
            tensor, H, self._velocity_exprs = _assemble_intermediate(d, conv, z, n)
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
            events = [self._edge_ratio[0] - self._edge_ratio[1] * hy.par[len(conv.names)]]
        params, sources, bits, unit = _model_parameters(system, conv, field + events, extra)
        if unit is not None:
            H = hy.par[unit] * H
        if dependent is not None:
            self._edge_expr = events[0]
        chart = ("chart " + ", ".join(system.coordinates[a] for a in dependent) + " dependent"
                 if dependent is not None else "own frame")
        self.poisson = PoissonSystem(z, tensor, H, parameters=params, casimirs=casimirs,
                                     name=f"{system.name} (intermediate, {chart})", input_bits=bits,
                                     parameter_sources=sources)

    def events(self):
        if self.dependent is None:
            return []
        return [(self._edge_expr, "chart_edge",
                 f"the chart of the intermediate frame with {[self.system.coordinates[a] for a in self.dependent]} "
                 f"dependent is ending (det dG/dq_dep reached {float(self.edge)} of its largest value)")]

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
        at = {s: sp.Rational(f.numerator, f.denominator) for s, f in zip(cs._q, qv)}
        at.update(cs._values())
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
        if _rank(Fq) < Fq.shape[0]:
            raise ValueError("`q`: the frame of the intermediate momenta is singular at this point (its fields are "
                             "dependent there); start elsewhere or choose another frame")
        P = sp.Matrix([sp.Rational(f.numerator, f.denominator) for f in pv])
        marked = any(isinstance(f, BinaryFraction) for f in pv)
        pis = _exact_numbers(list(Fq * P), marked)
        return make_state(qv + pis, precision, inputs=given)

    def __repr__(self) -> str:
        return f"ConstrainedIntermediate({self.system.name!r}, variables={list(self.names)})"


class ConstrainedLocal(ConstrainedDirac):
    """A :class:`ConstrainedSystem` in local coordinates of the surface: canonical (x^i, p_i), 2(n - k) variables;
    see :meth:`ConstrainedSystem.local`. ``configuration`` and ``velocity`` give q^A(x) and qdot^A as for the
    other formulations; ``invariants``: ``energy``."""

    def __init__(self, system: ConstrainedSystem, dependent, solution: dict, edge: Fraction):
        self.system = system
        self.dependent = dependent
        self.edge = edge
        self.chart = dict(solution)
        n = len(system.coordinates)
        self.n = n
        free = [i for i in range(n) if i not in dependent]
        self.free = tuple(free)
        q = list(system._q)
        x = [q[i] for i in free]
        qx = [solution.get(s, s) for s in q]
        J = sp.Matrix(n, len(free), lambda A_, i: sp.diff(qx[A_], x[i]))
        M = system._M.xreplace(solution)
        A = system._A.xreplace(solution)
        U = system._U.xreplace(solution)
        Ml = (J.T * M * J).applyfunc(_tidy)
        Al = (J.T * A).applyfunc(_tidy)
        psyms = [sp.Symbol(f"p_{system.coordinates[i]}", real=True) for i in free]
        Minv = _inverse(Ml)
        w = sp.Matrix(psyms) - Al
        xdot = (Minv * w).applyfunc(_tidy)
        H = _tidy((w.T * Minv * w)[0, 0] / 2 + U)
        self._sym_hamiltonian = H
        self._sym_mass = Ml
        self._sym_linear = Al
        qdot = [_tidy(e) for e in (J * xdot)]
        names = [system.coordinates[i] for i in free] + [str(s) for s in psyms]
        qvars = hy.make_vars(*system.coordinates)
        qvars = qvars if isinstance(qvars, list) else [qvars]
        pvars = hy.make_vars(*[str(s) for s in psyms])
        pvars = pvars if isinstance(pvars, list) else [pvars]
        z = [qvars[i] for i in free] + pvars
        conv = _HeyokaConverter(system, list(zip(q, qvars)) + list(zip(psyms, pvars)))
        d = len(free)
        T = sp.zeros(2 * d, 2 * d)
        for i in range(d):
            T[i, d + i], T[d + i, i] = 1, -1
        tensor = _heyoka_tensor(conv, T)
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
        num_x, den_x = (_tidy(e.xreplace(solution)) for e in (detD ** 2, gram))
        self._edge_ratio_x = (conv(num_x), conv(den_x))
        self._dependent_exprs = [conv(solution[q[a]]) for a in dependent]
        self.variables = z
        field = [e for row in tensor for e in row] + [hy.diff(Hh, v) for v in z]
        self._edge_expr = self._edge_ratio_x[0] - self._edge_ratio_x[1] * hy.par[len(conv.names)]
        params, sources, bits, unit = _model_parameters(system, conv, field + [self._edge_expr],
                                                        [("edge2", edge * edge, "edge")])
        if unit is not None:
            Hh = hy.par[unit] * Hh
        shown = ", ".join(f"{k} = {v}" for k, v in solution.items())
        self.poisson = PoissonSystem(z, tensor, Hh, parameters=params, name=f"{system.name} (local chart {shown})",
                                     input_bits=bits, parameter_sources=sources)

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
        n = self.n
        xf = [qf[i] for i in self.free]
        point = xf + [0] * len(self.free)
        got = self._eval(self._dependent_exprs, point)
        tol = _residual_tolerance(bits)
        for a, g in zip(self.dependent, got):
            with mp.workdps(RESIDUAL_DPS):
                want = mp.mpf(qf[a].numerator) / qf[a].denominator
                off = abs(g - want) > (mp.mpf(tol.numerator) / tol.denominator) * max(abs(want), abs(g))
            if off:
                raise ValueError(
                    f"`q` is not in this chart: {cs.coordinates[a]} = {mp.nstr(want, 8)} but the chart gives "
                    f"{cs.coordinates[a]} = {self.chart[cs._q[a]]} = {mp.nstr(g, 8)} there (another branch of the "
                    "solution); use a chart that holds the point")
        num, den = self._edge_value(point)
        if not num > den * (mp.mpf(self.edge.numerator) / self.edge.denominator) ** 2:
            raise ValueError(
                f"`q` is at or beyond the edge of the local chart (det D^2 / det G_q G_q^T = "
                f"{mp.nstr(num / den if den else mp.mpf(0), 4)} <= edge^2 = {float(self.edge) ** 2:.4g}); "
                "choose another chart, or use the global form dirac()")
        at = {cs._q[i]: sp.Rational(qf[i].numerator, qf[i].denominator) for i in self.free}
        at.update(cs._values())
        Ml = self._sym_mass.xreplace(at)
        Al = self._sym_linear.xreplace(at)
        xdot = sp.Matrix([sp.Rational(vf[i].numerator, vf[i].denominator) for i in self.free])
        p = _exact_numbers(list(Ml * xdot + Al), False)
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
