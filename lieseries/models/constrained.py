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
once per system and is kept for the process (under a second for the built-in systems, 4-5 CPU s for the
double spherical pendulum's twelve variables; docs/theory.md, "The derivation as the code does it").

This module reads and checks the input; the algebra is :mod:`~lieseries.models.constrained_derive`, the four models
are :mod:`~lieseries.models.constrained_forms` (their classes are importable from here too), the residual checks
of states and the checks of a chart or a frame at sample points :mod:`~lieseries.models.constrained_checks`.

Parameters of the Lagrangian are heyoka runtime parameters: exact values (int, str such as "9.81", Fraction) stay
exact and are rounded once to each working precision; a float is its binary value and is reported as binary data
(``PoissonSystem.coarse_data``), as everywhere in lieseries. Numbers written in the expressions are read exactly
("0.1" in a string is 1/10); those that are not short binary numbers become runtime parameters too.
"""

from __future__ import annotations

import io
import keyword
import tokenize
from fractions import Fraction

import numpy as np
import sympy as sp
from sympy.core.function import Application

from ..precision import data_bits, to_fraction
from .constrained_checks import RESIDUAL_DPS, check_chart, check_frame
from .constrained_derive import SYMBOLIC_DIRAC_MAX_CONSTRAINTS, derive_dirac, derive_intermediate, exact_number, memoized, numeric_rank, show_number
from .constrained_forms import ConstrainedDirac, ConstrainedIntermediate, ConstrainedLocal, ConstrainedReduced

__all__ = ["ConstrainedSystem", "ConstrainedDirac", "ConstrainedReduced", "ConstrainedIntermediate",
           "ConstrainedLocal"]

#: Functions a Lagrangian or constraint string may use (all of them convert to heyoka).
FUNCTIONS = {
    "sin": sp.sin, "cos": sp.cos, "tan": sp.tan, "asin": sp.asin, "acos": sp.acos, "atan": sp.atan,
    "sinh": sp.sinh, "cosh": sp.cosh, "tanh": sp.tanh, "asinh": sp.asinh, "acosh": sp.acosh, "atanh": sp.atanh,
    "exp": sp.exp, "log": sp.log, "sqrt": sp.sqrt,
}
CONSTANTS = {"pi": sp.pi}

def _is_name(s) -> bool:
    return isinstance(s, str) and s.isidentifier() and not keyword.iskeyword(s) and not s.startswith("_")


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
    frame, momenta : optional
        The tangent frame (and the names of its momenta) :meth:`intermediate` uses when it is given neither
        ``dependent`` nor ``frame``: the natural frame of a system whose charts are awkward (the rigid body's
        R^-T E_k on R^T R = 1). Checked here, as :meth:`intermediate` checks a frame.

    Attributes
    ----------
    q_symbols, qdot_symbols, parameter_symbols
        The sympy symbols of the coordinates, the velocities and the parameters (name -> symbol).
    mass_matrix, linear_term, potential
        M(q), A(q) (sympy matrices) and U(q) of L = 1/2 qdot^T M qdot + A . qdot - U: the derivation's inputs.
    constraint_jacobian
        dG_alpha/dq^A at the parameters' values; ``hessian_constant``: whether M depends on q.
    parameter_bits, input_bits
        The bits binary inputs carry (parameters; floats in the expressions), for the models' reports.

    Examples
    --------
    >>> import lieseries as ls
    >>> pend = ls.ConstrainedSystem("m/2*(x_dot**2 + y_dot**2) - m*g*y", ["x", "y"], ["x**2 + y**2 - l**2"],
    ...                             parameters={"m": 1, "g": "9.81", "l": 1})
    >>> model = pend.dirac()
    >>> y0 = model.initial_state(q=("3/5", "-4/5"), qdot=("4/5", "3/5"))
    """

    def __init__(self, lagrangian, coordinates, constraints, *, parameters=None, name=None, frame=None,
                 momenta=None):
        self.coordinates = self._check_coordinates(coordinates)
        n = len(self.coordinates)
        self.velocities = tuple(f"{c}_dot" for c in self.coordinates)
        params = self._check_parameters(parameters)
        self.parameter_values = {k: to_fraction(v, f"parameters[{k!r}]") for k, v in params.items()}
        self.parameter_bits = {f"parameters[{k!r}]": b for k, b in
                                ((k, data_bits([v])) for k, v in params.items()) if b is not None}
        self.q_symbols = [sp.Symbol(c, real=True) for c in self.coordinates]
        self.qdot_symbols = [sp.Symbol(v, real=True) for v in self.velocities]
        self.parameter_symbols = {k: sp.Symbol(k, real=True) for k in self.parameter_values}
        self.input_bits = {}
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
        self.default_frame = None
        if frame is not None:
            self._frame(None, frame, momenta)  # refused here, naming `frame` or `momenta`, if it is not a frame
            self.default_frame = (frame, momenta)
        elif momenta is not None:
            raise ValueError("`momenta` names the momenta of `frame`; give `frame` too (or pass `momenta` to "
                             "intermediate())")

    # -- input ---------------------------------------------------------------------------------------------------
    @staticmethod
    def _check_coordinates(coordinates):
        if isinstance(coordinates, (str, bytes)) or not hasattr(coordinates, "__len__"):
            raise TypeError(f"`coordinates` must be a list of names such as ['x', 'y']; got {coordinates!r}")
        names = []
        for i, c in enumerate(coordinates):
            c = str(c) if isinstance(c, sp.Symbol) else c
            if keyword.iskeyword(c):
                raise ValueError(f"`coordinates[{i}]` = {c!r} is a Python keyword, which no expression can use; "
                                 "choose another name")
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
        for c in names:  # the forms name the momentum of x p_x (Dirac, reduced) and pi_x (intermediate)
            clash = next((m for m in (f"p_{c}", f"pi_{c}") if m in names), None)
            if clash is not None:
                raise ValueError(f"`coordinates`: {clash!r} is also the name the formulations give the momentum of "
                                 f"{c!r}; rename that coordinate")
        return tuple(names)

    def _check_parameters(self, parameters):
        if parameters is None:
            return {}
        if not hasattr(parameters, "items"):
            raise TypeError(f"`parameters` must be a mapping name -> value; got {type(parameters).__name__}")
        out = {}
        taken = set(self.coordinates) | set(self.velocities)
        for k, v in parameters.items():
            if isinstance(k, str) and keyword.iskeyword(k):
                raise ValueError(f"`parameters` key {k!r} is a Python keyword, which no expression can use; rename it")
            if not _is_name(k) or k in FUNCTIONS or k in CONSTANTS:
                raise ValueError(f"`parameters` key {k!r} must be a Python identifier and not a function name")
            if k in taken:
                raise ValueError(f"`parameters` key {k!r} is also a coordinate or a velocity; rename one of them")
            out[k] = v
        return out

    def _symbols(self, velocities=True):
        table = {c: s for c, s in zip(self.coordinates, self.q_symbols)}
        if velocities:
            table.update({v: s for v, s in zip(self.velocities, self.qdot_symbols)})
        table.update(self.parameter_symbols)
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
            if any(tok.type == tokenize.OP and tok.string in ("=", "==", "<", ">", "<=", ">=", "!=") for tok in toks):
                raise ValueError(f"`{argname}` = {expr!r} is an equation or a comparison: give the expression alone "
                                 "(a constraint G for G = 0, such as 'x**2 + y**2 - 1'; a Lagrangian such as "
                                 "'m/2*x_dot**2 - m*g*x')")
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
                self.input_bits[argname] = min(int(f._prec) for f in floats)
        elif isinstance(expr, (int, Fraction)) and not isinstance(expr, bool):
            out = sp.Rational(expr.numerator, expr.denominator)
        else:
            raise TypeError(f"`{argname}` must be a string or a sympy expression; got {type(expr).__name__}")
        if not isinstance(out, sp.Expr):
            raise ValueError(f"`{argname}` must be a scalar expression; got {type(out).__name__} {out!r}")
        supported = tuple(f for f in FUNCTIONS.values() if isinstance(f, type))  # sqrt is a power
        other = sorted({str(f.func) for f in out.atoms(Application) if not isinstance(f, supported)})
        if other:
            raise ValueError(f"`{argname}` uses {', '.join(f + '()' for f in other)}, which is not one of the functions "
                             f"the vector field can be built from ({', '.join(sorted(FUNCTIONS))}): write it with those")
        if out.has(sp.I) or out.has(sp.zoo) or out.has(sp.nan) or out.has(sp.oo):
            raise ValueError(f"`{argname}` = {out} is not a finite real expression (it has I, oo or nan)")
        if not velocities:
            used = sorted(str(s) for s in out.free_symbols if s in set(self.qdot_symbols))
            if used:
                raise ValueError(
                    f"`{argname}` uses the velocities {used}: only holonomic constraints G(q) = 0 are supported "
                    "(the tangency of the velocity, dG/dq . qdot = 0, follows from them). Write the constraint on "
                    "the coordinates alone.")
        return out

    def _unknown(self, argname, unknown):
        if "t" in unknown:
            raise ValueError(
                f"`{argname}` uses `t`: time-dependent (rheonomic) Lagrangians and constraints are not supported; "
                "the method needs L(q, qdot) and G(q) without the time (a pendulum of varying length is outside "
                "it). If `t` is a constant, give it in `parameters`")
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
            poly = sp.Poly(sp.expand(L), *self.qdot_symbols)
            degree = poly.total_degree()
        except sp.PolynomialError:
            degree = None
        if degree is None or degree > 2:
            raise ValueError(
                "`lagrangian` must be quadratic in the velocities (1/2 qdot^T M(q) qdot + A(q) . qdot - U(q)): the "
                "Legendre transform p = M qdot + A is then inverted exactly; got "
                + ("an expression that is not a polynomial in the velocities" if degree is None else
                   f"degree {degree} in the velocities"))
        n = len(self.q_symbols)
        zero = {v: 0 for v in self.qdot_symbols}
        self.mass_matrix = sp.Matrix(n, n, lambda a, b: sp.expand(sp.diff(L, self.qdot_symbols[a], self.qdot_symbols[b])))
        self.linear_term = sp.Matrix(n, 1, lambda a, _b: sp.diff(L, self.qdot_symbols[a]).xreplace(zero))
        self.potential = -L.xreplace(zero)

    def parameter_substitution(self):
        return {s: sp.Rational(v.numerator, v.denominator) for k, s in self.parameter_symbols.items()
                for v in [self.parameter_values[k]]}

    def _check_hessian(self):
        M = self.mass_matrix.xreplace(self.parameter_substitution())
        det = sp.cancel(M.det(method="berkowitz"))
        if det == 0:
            raise ValueError(
                "`lagrangian` is singular: its velocity Hessian M = d2L/dqdot2 has determinant 0 "
                f"(M = {self.mass_matrix.tolist()}), so the momenta p = dL/dqdot do not determine the velocities. Every "
                "velocity must enter L quadratically (a kinetic term for each coordinate).")
        if not (M.free_symbols & set(self.q_symbols)):
            self.check_positive_definite(M, "`lagrangian`", "")
            self.hessian_constant = True
        else:
            self.hessian_constant = False

    def check_positive_definite(self, M, what, where):
        n = M.shape[0]
        for r in range(1, n + 1):
            minor = M[:r, :r].det(method="berkowitz")
            value = exact_number(minor, RESIDUAL_DPS)
            if not value > 0:
                raise ValueError(
                    f"{what}: the velocity Hessian M = d2L/dqdot2{where} is not positive definite (its leading "
                    f"{r}x{r} minor is {show_number(value)}): the kinetic energy must be positive for every nonzero "
                    "velocity. Check the signs and the mass parameters of the kinetic terms.")

    def _check_independent(self):
        """Generic rank of dG_alpha/dq^A: at two fixed pseudo-random rational points."""
        J = sp.Matrix([[sp.diff(g, q) for q in self.q_symbols] for g in self.constraints]).xreplace(self.parameter_substitution())
        self.constraint_jacobian = J
        k = len(self.constraints)
        import random

        rng = random.Random(7919 + len(self.q_symbols))
        best = 0
        for _ in range(2):
            pt = {q: sp.Rational(rng.randint(300, 1300), 1000) for q in self.q_symbols}
            best = max(best, numeric_rank(J.xreplace(pt)))
            if best == k:
                return
        raise ValueError(
            f"`constraints` are functionally dependent: their gradients dG/dq have rank {best} < {k} at generic "
            "points, so they do not cut a surface of dimension n - k (and the Dirac matrix {G, Phi} is singular). "
            "Remove the constraints that follow from the others.")

    # -- formulations --------------------------------------------------------------------------------------------
    def dirac_bracket(self):
        """The symbolic derivation (cached): ``dict`` with sympy ``q``, ``p`` (symbols), ``H0``, ``velocity``
        (qdot(q, p)), ``chi`` (the 2k constraints G then Phi), ``b`` = {G, Phi}, ``c`` = {Phi, Phi}, ``bz`` =
        {z_i, chi_I} and ``tensor`` (the 2n x 2n Dirac tensor {z_i, z_j}_D, z = (q, p)), in the parameter symbols.
        With more than ``SYMBOLIC_DIRAC_MAX_CONSTRAINTS`` constraints ``tensor`` is None: the inverse of b as
        rational functions is out of reach, and :meth:`dirac` assembles the tensor from b, c and bz instead."""
        if self._sym_dirac is None:
            self._sym_dirac = memoized(("dirac", self.memo_key()), lambda: derive_dirac(self))
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
        if len(self.constraints) > SYMBOLIC_DIRAC_MAX_CONSTRAINTS:
            raise ValueError(
                f"reduced(): a system with {len(self.constraints)} constraints has no symbolic Dirac tensor to reduce "
                f"(it is derived symbolically for at most {SYMBOLIC_DIRAC_MAX_CONSTRAINTS} constraints); use "
                "dirac() (the tensor assembled numerically) or intermediate() (the paper's formalism, reduced by "
                "construction)")
        edge_f = to_fraction(edge, "edge")
        if not 0 < edge_f < 1:
            raise ValueError(f"`edge` must lie in (0, 1) (a fraction of the largest possible |det D|); got {edge!r}")
        cache = self.__dict__.setdefault("_reduced", {})
        key = (tuple(dep), edge_f)
        if key not in cache:
            cache[key] = ConstrainedReduced(self, tuple(dep), edge_f)
        return cache[key]

    def _triangular(self, dep) -> bool:
        """Whether the block dG/dq of the coordinates ``dep`` is triangular up to an order of the constraints and
        of the coordinates (each constraint in turn has one dependent coordinate the later ones do not use)."""
        rows = [{a for a in dep if sp.diff(g, self.q_symbols[a]) != 0} for g in self.constraints]
        left = set(dep)
        while rows:
            pick = next((r for r in rows if len(r & left) == 1), None)
            if pick is None:
                return False
            left -= pick
            rows.remove(pick)
        return True

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

    def memo_key(self):
        return (sp.srepr(self.lagrangian), self.coordinates, tuple(sp.srepr(g) for g in self.constraints),
                tuple(sorted(self.parameter_symbols)))

    def intermediate_bracket(self, dependent=None, frame=None, momenta=None):
        """The symbolic intermediate formalism (paper, p9-p14.1), derived once per system and frame (a module-wide
        memo: a second system with the same Lagrangian, coordinates and constraints reuses it).

        Returns a ``dict`` with sympy ``q``, ``pi`` (the momentum symbols), ``frame`` (the (n-k) x n matrix of the
        tangent vector fields G_i, rows), ``K`` = G_i M G_j^T, ``H`` (H'_0 of p14.1), ``velocity`` (qdot(q, pi)),
        ``p`` (p_A(q, pi) on Phi = 0), ``c`` (the Lie brackets [G_i, G_j], p13/p25) and ``tensor`` (the
        (2n-k) x (2n-k) bracket of (q, pi), p12.1/p20), in the parameter symbols; see :meth:`intermediate`."""
        dep, F, names = self._frame(dependent, frame, momenta)
        return self.intermediate_derivation(dep, F, names)

    def intermediate_derivation(self, dep, F, names):
        key = ("intermediate", self.memo_key(), dep, None if F is None else sp.srepr(F), tuple(names))
        return memoized(key, lambda: derive_intermediate(self, dep, F, names))

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
            check_frame(self.constraints, self.q_symbols, self.parameter_substitution(), F)
            default = [f"pi{i + 1}" for i in range(n - k)]
        if momenta is None:
            names = default
        else:
            if isinstance(momenta, (str, bytes)) or not hasattr(momenta, "__len__") or len(momenta) != n - k:
                raise ValueError(f"`momenta` must be {n - k} names, one per tangent vector field; got {momenta!r}")
            names = [str(m) for m in momenta]
            taken = set(self.coordinates) | set(self.velocities) | set(self.parameter_symbols)
            for i, m in enumerate(names):
                if not _is_name(m) or m in FUNCTIONS or m in CONSTANTS or m in taken:
                    raise ValueError(f"`momenta[{i}]` = {m!r} must be a new identifier (not a coordinate, velocity, "
                                     "parameter or function name)")
            if len(set(names)) != len(names):
                raise ValueError(f"`momenta` must be distinct; got {names}")
        return dep, F, names

    def intermediate(self, dependent=None, frame=None, momenta=None, edge="0.05") -> "ConstrainedIntermediate":
        """The model on the intermediate submanifold in the paper's intermediate formalism (p9-p14.3): the n
        coordinates q^A and n - k momenta pi_i = G_iA(q) p_A, with G_i vector fields tangent to the surface.

        ``frame=None``: the system's own ``frame`` if it was given one and ``dependent`` is None; else the fields
        of p9 in the chart whose dependent coordinates are ``dependent`` (k names or indices; default the last k;
        beyond two constraints only where their block of dG/dq is triangular: else its inverse is out of symbolic
        reach, and it is refused naming ``frame``): G_i has 1 in the free coordinate i, 0 in the other free ones, and solves
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
        if dependent is None and frame is None and self.default_frame is not None:
            frame, own = self.default_frame
            momenta = own if momenta is None else momenta
        dep, F, names = self._frame(dependent, frame, momenta)
        if F is None and len(self.constraints) > SYMBOLIC_DIRAC_MAX_CONSTRAINTS and not self._triangular(dep):
            raise ValueError(
                f"intermediate(): the frame of a chart inverts the block dG/dq of the dependent coordinates "
                f"symbolically; with {len(self.constraints)} constraints that block must be triangular (constraints "
                "solvable one after another, as for a chain of rods): this one is not, and its inverse is out of "
                "reach (the rigid body's: more than ten minutes). Give `frame=` (your own tangent vector fields, "
                "assembled numerically), e.g. R^-T E_k for R^T R = 1, which EulerPoisson.constrained_system() "
                "uses")
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
        dep_syms = {self.q_symbols[a] for a in dep}
        for name, e in chart.items():
            a = name if isinstance(name, (int, np.integer)) else self.coordinates.index(name)
            expr = self._parse(e, f"chart[{name!r}]", velocities=False)
            used = sorted(str(s) for s in expr.free_symbols & dep_syms)
            if used:
                raise ValueError(f"`chart[{name!r}]` uses the dependent coordinates {used}: write each dependent "
                                 "coordinate as an expression of the free ones")
            sol[self.q_symbols[a]] = expr
        check_chart(self.constraints, self.q_symbols, self.parameter_substitution(), sol)
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
