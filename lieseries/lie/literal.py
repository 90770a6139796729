"""The literal Lie operator: iterated Lie derivatives built symbolically.

For ``dz/dt = rhs(z)`` the Lie derivative is ``L = sum_i rhs_i d/dz_i`` and
the solution is the Lie series ``z(t) = sum_k t^k L^k z (z0) / k!``.  This
module builds the ``L^k`` literally, as symbolic objects, and is the
reference the Taylor-mode engine (:mod:`lieseries.lie.jets`) is checked
against: it never uses the recurrences of Taylor-mode arithmetic.

Two symbolic routes are provided.

``"heyoka"``
    ``L^{k+1} f = sum_i rhs_i * hy.diff(L^k f, z_i)`` on heyoka expressions
    (:func:`lie_derivatives`), then compiled with
    :func:`lieseries.expr.compile_expressions` and evaluated in mpmath.
    Works for every vector field the compiler supports, but the size of
    ``L^k f`` grows geometrically with k (no simplification happens): for
    the 12-dimensional rigid body about x4 per order, about 1 s at k = 8
    for the heyoka side alone plus several seconds of sympy conversion;
    practical up to k ~ 6-8.

``"exact"``
    For vector fields that are rational functions of the state (polynomial
    ones included, which covers the rigid body and the particle on a
    sphere), exact arithmetic in sympy's sparse polynomial rings over QQ.
    Every ``L^k z_i`` is kept as ``P / prod_j q_j^{e_j}`` where the ``q_j``
    are the irreducible factors of the denominators of `rhs`.  Writing
    ``rhs_i = N_i / D`` with ``D = prod_j q_j^{A_j}``,

        ``L(P / q^e) = (L~P * prod_j q_j - P * sum_j e_j L~q_j prod_{l!=j} q_l)
        / q^(e + 1 + A)``  with  ``L~ = D L = sum_i N_i d/dz_i``,

    after which common factors ``q_j`` are divided out exactly (no gcd is
    ever computed).  The cost grows polynomially with k (with the size of
    the reduced numerators): numerical coefficients of the rigid body to
    order 12 in ~0.2 s, of the particle on a sphere to order 12 in ~0.5 s.
    Values at a point are computed exactly in rationals (the inputs are
    exact numbers) and rounded once.

``"auto"`` (the default) uses ``"exact"`` when the vector field is rational
and ``"heyoka"`` otherwise.
"""

from __future__ import annotations

import math
import numbers

import heyoka as hy
import mpmath
import sympy
from mpmath.libmp import from_rational, mpf_div, from_int
from sympy import QQ
from sympy.polys.polyerrors import ExactQuotientFailed
from sympy.polys.rings import PolyRing

from .. import expr as _expr
from ..precision import check_dps, check_order, to_fraction
from ..expr import RND, rounded_mpf

__all__ = [
    "lie_derivatives",
    "literal_coefficients",
    "literal_series_symbolic",
    "RationalLieOperator",
    "is_rational_system",
]

_METHODS = ("auto", "exact", "heyoka")


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------

def _check_system(variables, rhs):
    names = _expr.variable_names(variables)
    if isinstance(rhs, hy.expression) or not hasattr(rhs, "__len__"):
        raise TypeError("`rhs` must be a list of heyoka expressions")
    if len(rhs) != len(names):
        raise ValueError(
            f"`rhs` must have one expression per variable ({len(names)}); got {len(rhs)}"
        )
    rhs = [_expr.as_expression(r, f"rhs[{i}]") for i, r in enumerate(rhs)]
    return names, rhs


def _check_method(method):
    if method not in _METHODS:
        raise ValueError(f"`method` must be one of {_METHODS}; got {method!r}")
    return method


def _symbol(name):
    """The sympy symbol heyoka.to_sympy uses for a variable name."""
    return sympy.Symbol(name, real=True)


def _par_symbol(j):
    """The sympy symbol heyoka.to_sympy uses for ``hy.par[j]``."""
    return sympy.Symbol(f"par[{j}]", real=True)


def _exact_sympy(value, name):
    """An exact sympy number (or a sympy expression passed through)."""
    if isinstance(value, sympy.Basic):
        if isinstance(value, sympy.Float):
            fr = to_fraction(value, name)
            return sympy.Rational(fr.numerator, fr.denominator)
        return value
    fr = to_fraction(value, name)
    return sympy.Rational(fr.numerator, fr.denominator)


def _exact_floats(e):
    """Replace the (binary) sympy Floats of `e` by their exact rational values."""
    floats = e.atoms(sympy.Float)
    if not floats:
        return e
    return e.xreplace({f: _exact_sympy(f, "constant") for f in floats})


def _used_pars(sym_exprs):
    used = set()
    for s in sym_exprs:
        for f in s.free_symbols:
            m = _expr.PAR_RE.match(f.name)
            if m:
                used.add(int(m.group(1)))
    return used


def _npars(sym_exprs):
    used = _used_pars(sym_exprs)
    return max(used) + 1 if used else 0


def _subs_map(substitute, names):
    """Symbol -> sympy value map from a user `substitute` dict."""
    if substitute is None:
        return {}
    if not isinstance(substitute, dict):
        raise TypeError("`substitute` must be a dict: variable name -> value")
    out = {}
    for key, value in substitute.items():
        if isinstance(key, sympy.Symbol):
            nm = key.name
        elif isinstance(key, hy.expression):
            nm = _expr.variable_names([key], "substitute")[0]
        elif isinstance(key, str):
            nm = key
        else:
            raise TypeError(
                f"`substitute` keys must be variable names (str); got {type(key).__name__}"
            )
        if nm not in names:
            raise ValueError(f"`substitute` names `{nm}`, which is not in `variables`")
        out[_symbol(nm)] = _exact_sympy(value, f"substitute[{nm!r}]")
    return out


# --------------------------------------------------------------------------
# heyoka route
# --------------------------------------------------------------------------

def lie_derivatives(variables, rhs, f, order):
    """Iterated Lie derivatives ``[f, L f, ..., L^order f]`` as heyoka expressions.

    ``L^{k+1} f = sum_i rhs_i * hy.diff(L^k f, z_i)``; each ``L^k f`` is
    differentiated once (heyoka shares common subexpressions, but nothing is
    simplified, so the size of ``L^k f`` grows geometrically with k: for the
    rigid body about x4 per order).

    Parameters
    ----------
    variables : sequence of heyoka.expression
        State variables z_i.
    rhs : sequence of heyoka.expression
        Right-hand sides, ``dz_i/dt = rhs_i``.
    f : heyoka.expression or sequence of heyoka.expression
        Function(s) of the state to differentiate.
    order : int
        Highest power of L (>= 1).

    Returns
    -------
    list of heyoka.expression, or list of lists
        ``out[k] = L^k f`` (length ``order + 1``); when `f` is a sequence,
        ``out[k][j] = L^k f_j``.
    """
    names, rhs = _check_system(variables, rhs)
    order = check_order(order)
    single = isinstance(f, hy.expression) or isinstance(f, numbers.Real)
    fs = [f] if single else list(f)
    fs = [_expr.as_expression(g, "f") for g in fs]
    zvars = [hy.expression(nm) for nm in names]
    zero = hy.expression(0.0)
    out = [fs]
    for _ in range(order):
        nxt = []
        for g in out[-1]:
            terms = []
            for r, z in zip(rhs, zvars):
                d = hy.diff(g, z)
                if d != zero and r != zero:
                    terms.append(r * d)
            nxt.append(hy.sum(terms) if terms else zero)
        out.append(nxt)
    if single:
        return [x[0] for x in out]
    return out


def _literal_heyoka_values(names, rhs, y0, pars, order, dps):
    lie = lie_derivatives(names, rhs, [hy.expression(nm) for nm in names], order)
    flat = [e for level in lie for e in level]
    # one-shot and possibly huge: compiled without cse and outside the cache
    prog = _expr.compile_program(names, flat, len(pars), False)
    n = len(names)
    # explicit precision: mpmath's global context is never touched
    prec = mpmath.libmp.dps_to_prec(dps)
    wp = prec + 20
    vr = _expr.convert_vector(y0, n, wp, "y0")
    pr = _expr.convert_vector(pars, len(pars), wp, "pars")
    vals = prog.evaluate_raw(vr, pr, wp)
    out = []
    for k in range(order + 1):
        fk = from_int(math.factorial(k))
        out.append([rounded_mpf(prec, mpf_div(vals[k * n + i], fk, prec, RND)) for i in range(n)])
    return out


# --------------------------------------------------------------------------
# exact rational route
# --------------------------------------------------------------------------

class NotRationalError(ValueError):
    """The vector field is not a rational function of the state."""


def is_rational_system(variables, rhs):
    """True when every ``rhs_i`` is a rational function of the variables.

    Parameters may appear anywhere polynomially/rationally; double constants
    count as exact rationals.
    """
    names, rhs = _check_system(variables, rhs)
    syms = [_exact_floats(hy.to_sympy(r)) for r in rhs]
    gens = [_symbol(nm) for nm in names] + sorted(
        (_par_symbol(j) for j in _used_pars(syms)), key=lambda s: s.name
    )
    return all(s.is_rational_function(*gens) for s in syms)


class RationalLieOperator:
    """Exact Lie operator of a rational vector field, over QQ.

    Parameters
    ----------
    names : sequence of str
        State variable names.
    rhs_sympy : sequence of sympy.Expr
        Right-hand sides in the symbols ``Symbol(name, real=True)`` (and
        possibly parameter symbols, listed in `extra_symbols`), with exact
        rational constants.
    extra_symbols : sequence of sympy.Symbol
        Symbols that are constant under the flow (kept as ring generators).

    Notes
    -----
    Functions are pairs ``(P, e)`` meaning ``P / prod_j q_j**e_j`` with ``P``
    a ring element and ``q_j`` the irreducible (monic) factors of the
    denominators of the vector field (:attr:`factors`).
    """

    def __init__(self, names, rhs_sympy, extra_symbols=()):
        self.state_symbols = [_symbol(nm) for nm in names]
        self.symbols = self.state_symbols + list(extra_symbols)
        for s in rhs_sympy:
            if not s.is_rational_function(*self.symbols):
                raise NotRationalError(f"not a rational function of the state: {s}")
        self.ring = PolyRing(self.symbols, QQ)
        R = self.ring
        self.n = len(names)
        self.zgens = R.gens[:self.n]
        factors = []
        nums = []
        dens = []
        for s in rhs_sympy:
            num, den = sympy.fraction(sympy.together(s))
            N = R.from_expr(num)
            _, fl = sympy.factor_list(den, *self.symbols)
            exps = {}
            prod = R.one
            for fexpr, m in fl:
                q = R.from_expr(fexpr)
                if q.is_ground:
                    continue
                q = q.monic()
                for j, qq in enumerate(factors):
                    if qq == q:
                        break
                else:
                    factors.append(q)
                    j = len(factors) - 1
                exps[j] = exps.get(j, 0) + m
                prod *= q ** m
            c = R.from_expr(den).exquo(prod)
            if not c.is_ground or not c:
                raise NotRationalError(f"cannot split the denominator {den}")
            nums.append(N.mul_ground(QQ(1) / c.LC))
            dens.append(exps)
        self.factors = factors
        nq = len(factors)
        self.A = [max((d.get(j, 0) for d in dens), default=0) for j in range(nq)]
        self.Ntilde = []
        for N, d in zip(nums, dens):
            for j in range(nq):
                N = N * factors[j] ** (self.A[j] - d.get(j, 0))
            self.Ntilde.append(N)
        self.prodq = R.one
        for q in factors:
            self.prodq *= q
        self.others = []
        for j in range(nq):
            o = R.one
            for l, q in enumerate(factors):
                if l != j:
                    o *= q
            self.others.append(o)
        self.Lq = [self.Ltilde(q) for q in factors]

    def Ltilde(self, P):
        """``sum_i N_i dP/dz_i`` (the operator ``D * L`` on polynomials)."""
        R = self.ring
        out = R.zero
        for Ni, z in zip(self.Ntilde, self.zgens):
            if Ni:
                d = P.diff(z)
                if d:
                    out += Ni * d
        return out

    def apply(self, P, e):
        """``L`` applied to ``P / q**e``; returns the reduced ``(P', e')``."""
        num = self.Ltilde(P) * self.prodq
        for j, ej in enumerate(e):
            if ej and self.Lq[j]:
                num -= (self.Lq[j] * self.others[j]).mul_ground(QQ(ej)) * P
        e2 = [ej + 1 + aj for ej, aj in zip(e, self.A)]
        if not num:
            return num, [0] * len(e)
        for j, q in enumerate(self.factors):
            while e2[j] > 0:
                try:
                    num = num.exquo(q)
                except ExactQuotientFailed:
                    break
                e2[j] -= 1
        return num, e2

    def iterate(self, order, funcs=None):
        """``[[L^k f_i as (P, e)] for k in 0..order]``; default f = the state."""
        cur = [(z, [0] * len(self.factors)) for z in (funcs or self.zgens)]
        out = [cur]
        for _ in range(order):
            cur = [self.apply(P, e) for P, e in cur]
            out.append(cur)
        return out


def _rational_operator(names, rhs, pars_sym):
    """RationalLieOperator with parameters replaced by `pars_sym` (or kept)."""
    syms = [_exact_floats(hy.to_sympy(r)) for r in rhs]
    if pars_sym is None:
        extra = sorted((_par_symbol(j) for j in _used_pars(syms)), key=lambda s: s.name)
    else:
        extra = []
        psub = {_par_symbol(j): v for j, v in enumerate(pars_sym)}
        syms = [s.xreplace(psub) for s in syms]
        free = set()
        for s in syms:
            free |= s.free_symbols
        zs = {_symbol(nm) for nm in names}
        extra = sorted(free - zs, key=lambda s: s.name)
    return RationalLieOperator(names, syms, extra)


def _literal_exact_values(names, rhs, y0, pars, order, dps):
    y0f = [to_fraction(v, f"y0[{i}]") for i, v in enumerate(y0)]
    pf = [to_fraction(v, f"pars[{j}]") for j, v in enumerate(pars)]
    op = _rational_operator(names, rhs, [sympy.Rational(p.numerator, p.denominator) for p in pf])
    point = [QQ(v.numerator, v.denominator) for v in y0f]
    qvals = []
    for j, q in enumerate(op.factors):
        qv = q(*point)
        if not qv:
            raise ValueError(
                f"the vector field is singular at `y0` (the denominator factor "
                f"{q.as_expr()} vanishes)"
            )
        qvals.append(qv)
    levels = op.iterate(order)
    # explicit precision: mpmath's global context is never touched
    prec = mpmath.libmp.dps_to_prec(dps)
    out = []
    for k, level in enumerate(levels):
        fk = math.factorial(k)
        row = []
        for P, e in level:
            v = P(*point) if P else QQ(0)
            for qv, ej in zip(qvals, e):
                if ej:
                    v = v / qv ** ej
            num, den = int(v.numerator), int(v.denominator) * fk
            row.append(rounded_mpf(prec, from_rational(num, den, prec, RND)))
        out.append(row)
    return out


def _symbolic_from_operator(op, levels, smap):
    """sympy coefficients ``L^k z_i / k!`` with `smap` substituted, from ring elements.

    Rational substituted values are plugged in inside the polynomial ring
    (fast, and the result comes out expanded); any other values are
    substituted afterwards in sympy.
    """
    R = op.ring
    gen_of = dict(zip(op.symbols, R.gens))
    ring_subs = []
    rest = {}
    for sym, val in smap.items():
        if isinstance(val, sympy.Rational) and sym in gen_of:
            ring_subs.append((gen_of[sym], QQ(int(val.p), int(val.q))))
        else:
            rest[sym] = val

    def sub(P):
        return P.subs(ring_subs) if ring_subs and not P.is_ground else P

    qs = [sub(q) for q in op.factors]
    n = len(levels[0])
    out = [[None] * len(levels) for _ in range(n)]
    for k, level in enumerate(levels):
        fk = QQ(1, math.factorial(k))
        for i, (P, e) in enumerate(level):
            num = sub(P)
            den = R.one
            for q, ej in zip(qs, e):
                if ej:
                    den *= q**ej
            if not den:
                raise ValueError(
                    "the substituted values make a denominator of the vector field vanish"
                )
            if den.is_ground:
                expr = num.mul_ground(fk / den.LC).as_expr()
                den_expr = sympy.Integer(1)
            else:
                expr = num.mul_ground(fk).as_expr()
                den_expr = den.as_expr()
            if rest:
                expr = sympy.expand(expr.xreplace(rest))
                den_expr = sympy.expand(den_expr.xreplace(rest))
                if den_expr == 0:
                    raise ValueError(
                        "the substituted values make a denominator of the vector field vanish"
                    )
            out[i][k] = expr if den_expr == 1 else expr / den_expr
    return out


# --------------------------------------------------------------------------
# Public numeric and symbolic entry points
# --------------------------------------------------------------------------

def literal_coefficients(variables, rhs, y0, pars, order, dps, method="auto"):
    """Taylor coefficients ``L^k z_i (y0) / k!`` from the literal Lie operator.

    Same shape and meaning as
    :func:`lieseries.lie.jets.taylor_coefficients`, computed independently of
    Taylor-mode arithmetic by building ``L^k z_i`` symbolically.

    Parameters
    ----------
    variables : sequence of heyoka.expression
        State variables.
    rhs : sequence of heyoka.expression
        Right-hand sides (``dz_i/dt = rhs_i``), in the variables and in
        ``hy.par[j]``.
    y0 : sequence of numbers
        The point (int, str, Fraction, float, mpmath.mpf, sympy number).
    pars : sequence of numbers
        Values of the parameters, exactly as many as `rhs` uses.
    order : int
        Highest coefficient (>= 1).
    dps : int
        Decimal digits of the results (>= 5).
    method : {"auto", "exact", "heyoka"}
        ``"exact"``: exact rational arithmetic (rational vector fields only;
        the inputs are taken as exact rationals and each result is correctly
        rounded); ``"heyoka"``: :func:`lie_derivatives` compiled with
        :mod:`~lieseries.expr` and evaluated in mpmath (any supported
        vector field; cost grows geometrically with `order`); ``"auto"``:
        ``"exact"`` when possible.

    Returns
    -------
    list of list of mpmath.mpf
        ``c[k][i] = L^k z_i (y0) / k!`` for ``k = 0 .. order``.
    """
    names, rhs = _check_system(variables, rhs)
    order = check_order(order)
    dps = check_dps(dps)
    method = _check_method(method)
    n = len(names)
    if isinstance(y0, (str, bytes)) or not hasattr(y0, "__len__"):
        raise TypeError(f"`y0` must be a sequence of {n} numbers")
    if len(y0) != n:
        raise ValueError(f"`y0` must have length {n}; got {len(y0)}")
    npars = _npars([hy.to_sympy(r) for r in rhs])
    if isinstance(pars, (str, bytes)) or not hasattr(pars, "__len__"):
        raise TypeError(f"`pars` must be a sequence of {npars} numbers")
    if len(pars) != npars:
        raise ValueError(f"`pars` must have length {npars}; got {len(pars)}")
    if method in ("auto", "exact"):
        try:
            return _literal_exact_values(names, rhs, y0, pars, order, dps)
        except NotRationalError:
            if method == "exact":
                raise ValueError(
                    "`method='exact'` needs a vector field that is a rational function of "
                    "the state; use method='heyoka'"
                ) from None
    return _literal_heyoka_values(names, rhs, y0, pars, order, dps)


def _symbolic_pars(pars, rhs) -> list:
    """The parameter values as exact sympy numbers (or the user's expressions), one per parameter the field uses."""
    if isinstance(pars, (str, bytes)) or not hasattr(pars, "__len__"):
        raise TypeError("`pars` must be a sequence of numbers or None")
    npars = _npars([hy.to_sympy(r) for r in rhs])
    if len(pars) != npars:
        raise ValueError(f"`pars` must have length {npars}; got {len(pars)}")
    return [_exact_sympy(p, f"pars[{j}]") for j, p in enumerate(pars)]


def literal_series_symbolic(variables, rhs, order, substitute=None, pars=None, method="auto"):
    """Lie-series coefficients as sympy expressions, with chosen values substituted.

    ``L^k z_i`` is built with every state variable symbolic; then the
    variables named in `substitute` are replaced by the given values, and the
    results are divided by ``k!``.  E.g. for the rigid body: apply ``L^k``
    with ``R0`` symbolic, substitute ``R0 = identity`` and get the
    coefficients of ``R(t)`` as exact functions of ``M0``; with rational
    parameter values (`pars`) and rational substituted values the results are
    exact rationals.

    Parameters
    ----------
    variables : sequence of heyoka.expression
        State variables.
    rhs : sequence of heyoka.expression
        Right-hand sides.
    order : int
        Highest coefficient (>= 1).
    substitute : dict, optional
        Variable name (str, heyoka variable or sympy symbol) -> value (int,
        Fraction, str, float — taken exactly — or a sympy expression).
    pars : sequence, optional
        Parameter values (taken exactly, or sympy expressions).  Default: the
        parameters stay symbolic as ``Symbol("par[j]", real=True)``.
    method : {"auto", "exact", "heyoka"}
        As in :func:`literal_coefficients`.  ``"exact"`` returns expanded
        polynomials (over a denominator that is a product of powers of the
        vector field's denominator factors, when there is one).

    Returns
    -------
    list of list of sympy.Expr
        ``out[i][k]`` = coefficient ``c_k`` of variable ``i`` (note: variable
        first), ``k = 0 .. order``.  The remaining free symbols are
        ``sympy.Symbol(name, real=True)`` (what :func:`heyoka.to_sympy` uses).

    Notes
    -----
    Cost: the ``"exact"`` route grows polynomially with `order` and with the
    number of symbols left free (rigid body, R0 = 1 substituted, M0 free,
    rational parameters: ~0.4 s to order 12; with the parameters symbolic
    too: ~2.5 s to order 8); the ``"heyoka"`` route grows geometrically
    (about x4 per order for the rigid body) and is practical to order ~6-8.
    """
    names, rhs = _check_system(variables, rhs)
    order = check_order(order)
    method = _check_method(method)
    smap = _subs_map(substitute, names)
    pars_sym = _symbolic_pars(pars, rhs) if pars is not None else None
    n = len(names)
    if method in ("auto", "exact"):
        try:
            op = _rational_operator(names, rhs, pars_sym)
        except NotRationalError:
            if method == "exact":
                raise ValueError(
                    "`method='exact'` needs a vector field that is a rational function of "
                    "the state; use method='heyoka'"
                ) from None
            op = None
        if op is not None:
            return _symbolic_from_operator(op, op.iterate(order), smap)
    # heyoka route
    lie = lie_derivatives(names, rhs, [hy.expression(nm) for nm in names], order)
    full = dict(smap)
    if pars_sym is not None:
        full.update({_par_symbol(j): v for j, v in enumerate(pars_sym)})
    out = [[None] * (order + 1) for _ in range(n)]
    for k, level in enumerate(lie):
        fk = sympy.Rational(1, math.factorial(k))
        for i, e in enumerate(level):
            s = _exact_floats(hy.to_sympy(e)).xreplace(full)
            out[i][k] = sympy.expand(fk * s)
    return out
