"""The compiler's walk: sympy trees (from :func:`heyoka.to_sympy`) turned into the nodes of a
:class:`~lieseries.expr.program.Program`, with structural sharing (:class:`Builder`)."""

from __future__ import annotations

import re
from fractions import Fraction

import heyoka as hy
import mpmath
import sympy
from sympy.core.cache import clear_cache

from .program import Constant, Node

_FUNCTIONS = ("exp", "log", "sin", "cos", "tan", "sinh", "cosh", "tanh", "atan")

#: A runtime parameter ``heyoka.par[i]`` as sympy names it.
PAR_RE = re.compile(r"^par\[(\d+)\]$")


def _raw_to_fraction(raw, name):
    sign, man, exp, _ = raw
    if not man:
        if exp:
            raise ValueError(f"`{name}` must be finite; got {mpmath.mpf(raw)}")
        return Fraction(0)
    man = int(man)  # an mpz under the gmpy2 backend: Fractions (and sympy Rationals) get Python ints
    v = Fraction(man << exp) if exp >= 0 else Fraction(man, 1 << -exp)
    return -v if sign else v


#: Characters of the expressions' text (or one expression printed cut short) above which :func:`sympy_forms`
#: empties sympy's cache first. A small field (the rigid body's ~1600, the sphere's ~2000) converts 3.5 times
#: faster from a warm cache (sympy's assumptions on names and numbers are kept there); the heavy top's Dirac form
#: (18000) walks whole trees in it.
LARGE_TEXT = 8000


def sympy_forms(exprs, as_written=False) -> list:
    """The sympy trees of heyoka expressions (:func:`heyoka.to_sympy`; ``as_written``: without sympy's automatic
    simplification), sympy's cache emptied first when the expressions are large (:data:`LARGE_TEXT`).

    sympy keeps what it builds in a process-wide cache and compares each new object with an equal one it holds node
    by node, with no shortcut but identity: once a derived field's trees are held twice (converted again, or as
    written beside evaluated, or rebuilt by ``cse``), every lookup walks a whole tree. The Dirac form of a heavy top
    took 2.4 s to convert after its program had been compiled (0.36 s the first time); emptying the cache costs ~10
    us and changes nothing but what sympy has to build again -- which for a small field is most of its
    conversion (6 ms from a warm cache, 20 ms from an empty one, for the rigid body)."""
    exprs = list(exprs)
    size = 0
    for e in exprs:
        text = str(e)
        size += len(text)
        if size > LARGE_TEXT or text.endswith("..."):  # (heyoka prints ~1000 characters of an expression at most)
            clear_cache()
            break
    if as_written:
        with sympy.evaluate(False):
            return [_to_sympy(e) for e in exprs]
    return [_to_sympy(e) for e in exprs]


def _to_sympy(e):
    """:func:`heyoka.to_sympy`, a function it cannot convert (``select``, a comparison) refused with what to do."""
    try:
        return hy.to_sympy(e)
    except TypeError as err:
        raise ValueError(
            f"{err}: lieseries reads every expression of a system (its `hamiltonian`, `tensor` and `extra_field`, "
            "and the events') in sympy, for its checks and its Lie engine; write it with the functions both know "
            "(arithmetic, powers, exp, log, sqrt, the trigonometric and hyperbolic functions and their inverses)"
        ) from None


def _coeff_add(e):
    """``e.as_coeff_add()`` of a sympy ``Add`` without sympy's cache (:func:`sympy_forms`: a lookup that walks a
    whole tree; 30 s of the 44 s the heavy top's Dirac form took to compile as written)."""
    first = e.args[0]
    if isinstance(first, sympy.Add):
        coeff, rest = _coeff_add(first)
    elif first.is_Rational:
        coeff, rest = first, ()
    else:
        coeff, rest = sympy.S.Zero, (first,)
    if coeff is not sympy.S.Zero:
        return coeff, rest + e.args[1:]
    return sympy.S.Zero, e.args


# --------------------------------------------------------------------------
# The compiler
# --------------------------------------------------------------------------


class Builder:
    """Turns sympy trees into program nodes (with structural sharing)."""

    def __init__(self, names, npars):
        self.var_index = {nm: i for i, nm in enumerate(names)}
        self.nvars = len(names)
        self.npars = npars
        self.max_par = -1
        self.is_const = [False] * self.nvars + [True] * npars
        self.constants = []
        self.const_index = {}
        self.nodes = []
        self.node_index = {}
        self.memo = {}
        self.cse_map = {}

    # -- slots ---------------------------------------------------------------

    def _new_slot(self, const):
        self.is_const.append(const)
        return len(self.is_const) - 1

    def const(self, c):
        slot = self.const_index.get(c)
        if slot is None:
            slot = self._new_slot(True)
            self.constants.append((slot, c))
            self.const_index[c] = slot
        return slot

    def rational(self, p, q=1):
        from math import gcd

        g = gcd(p, q)
        return self.const(Constant("rational", (p // g, q // g)))

    def node(self, op, args, data=None):
        args = tuple(args)
        key = (op, args, data)
        slot = self.node_index.get(key)
        if slot is None:
            const = all(self.is_const[a] for a in args)
            slot = self._new_slot(const)
            self.nodes.append(Node(op, slot, args, data))
            self.node_index[key] = slot
        return slot

    # -- helpers building composite operations ------------------------------

    def add_sub(self, pos, neg):
        """Slot of sum(pos) - sum(neg)."""
        p = pos[0] if len(pos) == 1 else (self.node("add", pos) if pos else None)
        n = neg[0] if len(neg) == 1 else (self.node("add", neg) if neg else None)
        if n is None:
            return p if p is not None else self.rational(0)
        if p is None:
            return self.node("neg", (n,))
        return self.node("sub", (p, n))

    def product(self, slots):
        if not slots:
            return None
        if len(slots) == 1:
            return slots[0]
        return self.node("mul", slots)

    def number(self, e):
        """Slot for a sympy number, or raise."""
        if isinstance(e, sympy.Rational):
            return self.rational(int(e.p), int(e.q))
        if isinstance(e, sympy.Float):
            raw = e._mpf_
            if not raw[1] and raw[2]:
                raise ValueError(f"non-finite constant {e} in the expressions")
            if not raw[1]:
                return self.rational(0)
            return self.const(Constant("binary", raw))
        if e is sympy.pi:
            return self.const(Constant("pi", None))
        if e is sympy.E:
            return self.const(Constant("e", None))
        raise NotImplementedError(f"the number `{e}` is not supported by the compiler")

    def power(self, base, ex):
        """Slot of base**ex for sympy base and exponent."""
        if isinstance(ex, sympy.Float):
            fr = _raw_to_fraction(ex._mpf_, "exponent")
            if fr.denominator <= 2:
                ex = sympy.Rational(fr.numerator, fr.denominator)
        if isinstance(ex, sympy.Integer):
            n = int(ex)
            if n == 0:
                return self.rational(1)
            b = self.build(base)
            if n < 0:
                return self.node("div", (self.rational(1), self._powi(b, -n)))
            return self._powi(b, n)
        if isinstance(ex, sympy.Rational):
            p, q = int(ex.p), int(ex.q)
            b = self.build(base)
            if p < 0:
                return self.node("div", (self.rational(1), self._powq(b, -p, q)))
            return self._powq(b, p, q)
        if isinstance(ex, sympy.Float):
            b = self.build(base)
            if ex.is_negative:
                pos = self.node("pow", (b, self.number(-ex)))
                return self.node("div", (self.rational(1), pos))
            return self.node("pow", (b, self.number(ex)))
        # symbolic exponent
        e_slot = self.build(ex)
        if self.is_const[e_slot]:
            return self.node("pow", (self.build(base), e_slot))
        if base is sympy.E:
            return self.node("exp", (e_slot,))
        lg = self.node("log", (self.build(base),))
        return self.node("exp", (self.node("mul", (e_slot, lg)),))

    def _powi(self, b, n):
        if n == 1:
            return b
        return self.node("powi", (b,), n)

    def _powq(self, b, p, q):
        """b**(p/q) with p, q > 0 coprime, q > 1."""
        if q == 2:
            return self._powi(self.node("sqrt", (b,)), p)
        return self.node("pow", (b, self.rational(p, q)), (p, q))

    # -- the recursive walk -----------------------------------------------

    def symbol(self, e):
        if e in self.cse_map:
            return self.cse_map[e]
        i = self.var_index.get(e.name)
        if i is not None:
            return i
        m = PAR_RE.match(e.name)
        if m:
            j = int(m.group(1))
            self.max_par = max(self.max_par, j)
            if j >= self.npars:
                raise ValueError(
                    f"the expressions use par[{j}] but `npars` is {self.npars}; pass "
                    f"npars >= {j + 1} (or leave it None to infer it)"
                )
            return self.nvars + j
        raise ValueError(
            f"the expressions contain the variable `{e.name}`, which is not in `variables`"
        )

    def build(self, e):
        # by identity (the object kept beside its slot), not by sympy's equality, which walks a tree that an equal
        # twin of it ends: a twin is walked again and meets the same nodes (``node`` shares them by their slots)
        hit = self.memo.get(id(e))
        if hit is not None:
            return hit[0]
        slot = self._build(e)
        self.memo[id(e)] = (slot, e)
        return slot

    def _build(self, e):
        if isinstance(e, sympy.Symbol):
            return self.symbol(e)
        if isinstance(e, sympy.Number) or e is sympy.pi or e is sympy.E:
            return self.number(e)
        if isinstance(e, sympy.Add):
            coeff, terms = _coeff_add(e)
            pos, neg = [], []
            for t in terms:
                c, rest = t.as_coeff_Mul()
                if c.is_negative:
                    neg.append(self._mul_parts(-c, rest))
                else:
                    pos.append(self._mul_parts(c, rest))
            if coeff != 0:
                (neg if coeff.is_negative else pos).append(self.number(abs(coeff)))
            return self.add_sub(pos, neg)
        if isinstance(e, sympy.Mul):
            c, rest = e.as_coeff_Mul()
            if c.is_negative:
                return self.node("neg", (self._mul_parts(-c, rest),))
            return self._mul_parts(c, rest)
        if isinstance(e, sympy.Pow):
            return self.power(e.base, e.exp)
        if isinstance(e, sympy.Function):
            name = type(e).__name__
            if name == "heyoka_time":
                raise NotImplementedError(
                    "time-dependent vector fields (heyoka.time) are not supported by "
                    "the expression compiler"
                )
            if name in _FUNCTIONS and len(e.args) == 1:
                return self.node(name, (self.build(e.args[0]),))
            raise NotImplementedError(
                f"function `{name}` is not supported by the expression compiler "
                f"(supported: {', '.join(_FUNCTIONS)}, sqrt and powers)"
            )
        raise NotImplementedError(
            f"expression node `{type(e).__name__}` ({e}) is not supported by the "
            "expression compiler"
        )

    def _mul_parts(self, coeff, rest):
        """Slot of coeff * rest, coeff >= 0 a sympy Number, rest a sympy expr."""
        if coeff == 0:
            return self.rational(0)
        factors = sympy.Mul.make_args(rest)
        num, den = [], []
        for f in factors:
            if f == 1:
                continue
            if isinstance(f, sympy.Pow) and isinstance(f.exp, sympy.Number) and f.exp.is_negative:
                den.append(self.power(f.base, -f.exp))
            else:
                num.append(self.build(f))
        if coeff != 1:
            num.insert(0, self.number(coeff))
        n = self.product(num)
        if not den:
            return n if n is not None else self.rational(1)
        if n is None:
            n = self.rational(1)
        return self.node("div", (n, self.product(den)))
