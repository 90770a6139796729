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
import tokenize
from fractions import Fraction

import heyoka as hy
import numpy as np
import sympy as sp

from ..poisson import PoissonSystem
from ..precision import BinaryFraction, binary_inputs, bits_to_dps, data_bits, state_bits, to_fraction
from ..precision import thread_mp as mp
from .base import Model, make_state

__all__ = ["ConstrainedSystem", "ConstrainedDirac", "ConstrainedReduced"]

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
            self._sym_dirac = _derive_dirac(self)
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
        k = len(self.constraints)
        n = len(self.coordinates)
        if dependent is None:
            dependent = tuple(range(n - k, n))
        if isinstance(dependent, (int, np.integer, str)):
            dependent = (dependent,)
        dep = []
        for d in dependent:
            if isinstance(d, str) and d in self.coordinates:
                d = self.coordinates.index(d)
            if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or not 0 <= int(d) < n:
                raise ValueError(f"`dependent` must name {k} of the coordinates {list(self.coordinates)} (or their "
                                 f"indices); got {dependent!r}")
            dep.append(int(d))
        if len(dep) != k or len(set(dep)) != k:
            raise ValueError(f"`dependent` must name {k} distinct coordinates (one per constraint); got {dependent!r}")
        edge_f = to_fraction(edge, "edge")
        if not 0 < edge_f < 1:
            raise ValueError(f"`edge` must lie in (0, 1) (a fraction of the largest possible |det D|); got {edge!r}")
        cache = self.__dict__.setdefault("_reduced", {})
        key = (tuple(dep), edge_f)
        if key not in cache:
            cache[key] = ConstrainedReduced(self, tuple(dep), edge_f)
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
    b = sp.Matrix(k, k, lambda a, c: _tidy(_canonical(G[a], Phi[c], q, p)))
    c = sp.Matrix(k, k, lambda a, d: _tidy(_canonical(Phi[a], Phi[d], q, p)) if a != d else 0)
    binv = (b.inv(method="LU") if k > 1 else sp.Matrix([[1 / b[0, 0]]])).applyfunc(sp.cancel)
    Dinv = sp.zeros(2 * k, 2 * k)
    Dinv[:k, :k] = (binv.T * c * binv).applyfunc(sp.cancel)
    Dinv[:k, k:] = -binv.T
    Dinv[k:, :k] = binv
    z = q + p
    bz = [[_canonical(zi, ch, q, p) for ch in chi] for zi in z]  # {z_i, chi_I}
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
    return {"q": q, "p": p, "H0": H0, "velocity": list(v), "chi": chi, "G": G, "Phi": Phi, "tensor": T,
            "b": b, "c": c}


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
        return hy.from_sympy(expr, s_dict=self.s_dict)


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

    def _eval(self, exprs, values, dps=RESIDUAL_DPS):
        from ..expr import compile_expressions

        prog = compile_expressions(self.variables, exprs, len(self.poisson.parameter_values))
        return prog.evaluate(list(values), list(self.poisson.parameter_values), dps)

    def _check_surface(self, q, qdot, bits, qname="q", vname="qdot", loose=False):
        """Refuse a point off G = 0 or a velocity not tangent to it (relative residuals at 60 digits). ``loose``:
        for binary data, allow the square root of their precision (a state a run ended in has drifted)."""
        tol_exact = _residual_tolerance(bits)
        if loose and bits is not None:
            tol_exact = max(RESIDUAL_EXACT, Fraction(1, 2 ** max(1, (int(bits) - 4) // 2)))
        n = self.n
        point = list(q) + [0] * (len(self.variables) - n)
        k = len(self._terms)
        flat = [t for ts in self._terms for t in ts] + [g for row in self._gradients for g in row]
        vals = self._eval(flat, point)
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

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (q, p) with p = M(q) qdot + A(q) from a point on the surface and a tangent velocity.

        Exact input (int, str, Fraction) is kept exact: an :class:`~lieseries.models.base.ExactState` unless
        ``precision`` is given. Refuses a point with |G_alpha(q)| above 1e-50 relative to the size of G's terms
        (at 60 digits; for binary floats, above their own precision), and a velocity with dG/dq . qdot likewise,
        naming ``q`` or ``qdot`` with the residual; a velocity Hessian that is not positive definite or
        constraints that are dependent at ``q``.
        """
        given = {"q": q, "qdot": qdot}
        qf = self._vector(q, "q")
        vf = self._vector(qdot, "qdot")
        binary = {}
        for nm, val in given.items():
            binary.update(binary_inputs(val, nm))
        bits = min(binary.values()) if binary else None
        self._check_surface(qf, vf, bits)
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
        return make_state(list(qf) + p, precision, inputs=given)

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
