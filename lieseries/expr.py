"""Compile heyoka expressions into flat evaluation programs for mpmath.

heyoka expressions have no Python traversal API, but :func:`heyoka.to_sympy`
gives a faithful sympy tree of them: variables become ``sympy.Symbol(name,
real=True)``, runtime parameters ``hy.par[i]`` become ``Symbol("par[i]",
real=True)`` and double constants become ``sympy.Float`` objects with 53 bits
of precision holding the *exact* binary value of the double.  This module
turns a list of such expressions into a :class:`Program`: a flat list of
elementary operations over numbered *slots*, in topological order, with the
common subexpressions of all the expressions shared (``sympy.cse`` plus
structural hashing).

Slots are laid out as

* ``0 .. nvars-1``: the state variables, in the order given;
* ``nvars .. nvars+npars-1``: the runtime parameters ``par[0] ..``;
* then constants and intermediate results, in creation order.

A slot is *constant* when it does not depend on the variables (numbers,
parameters, and operations on them only); the Taylor-mode engine in
:mod:`lieseries.lie.jets` uses this to turn ``p * x`` into a scaling instead
of a Cauchy product.

Numbers are kept exact inside a program and rounded only when a program is run
at a given precision, so one compiled program serves every precision:

* sympy ``Integer``/``Rational`` -> the exact rational, rounded once at the
  working precision (``Rational(1, 3)`` -> ``mpf(1)/3``);
* sympy ``Float`` (a heyoka double) -> its exact binary value;
* ``pi`` and ``E`` -> computed at the working precision.

Note that heyoka folds numeric constants into doubles when it builds
expressions (``x / 3`` becomes ``0.333... * x`` in heyoka itself), so exact
rational coefficients of a vector field must be passed as runtime parameters.

All numeric work uses mpmath's raw representation (``mpmath.libmp`` tuples
``(sign, mantissa, exponent, bitcount)``), which avoids the cost of creating
``mpf`` objects; public functions take and return ordinary ``mpmath.mpf``.
"""

from __future__ import annotations

import numbers
import re
import time
from collections import OrderedDict, namedtuple
from fractions import Fraction

import heyoka as hy
import mpmath
import sympy
from mpmath import libmp
from mpmath.libmp import (
    fzero,
    from_int,
    from_rational,
    mpf_add,
    mpf_atan,
    mpf_cos,
    mpf_cosh,
    mpf_div,
    mpf_e,
    mpf_exp,
    mpf_log,
    mpf_mul,
    mpf_neg,
    mpf_nthroot,
    mpf_pi,
    mpf_pos,
    mpf_pow,
    mpf_pow_int,
    mpf_sin,
    mpf_sinh,
    mpf_sqrt,
    mpf_sub,
    mpf_sum,
    mpf_tan,
    mpf_tanh,
)

from . import cache
from .precision import check_dps, dps_to_bits, to_fraction
from .precision import to_raw as precision_raw

__all__ = [
    "Program",
    "Node",
    "Constant",
    "compile_expressions",
    "compile_system",
    "SUPPORTED_OPS",
    "uses_time",
]

#: A variable name no system uses: heyoka's time is substituted by it to find out whether an expression uses time.
_TIME_PROBE = "__lieseries_time_probe__"


def uses_time(expr) -> bool:
    """True when the heyoka expression ``expr`` (or any of a list of them) contains heyoka's time
    (``heyoka.time``, printed ``t``); a state variable named ``t`` is a variable, not time."""
    if isinstance(expr, (list, tuple)):
        exprs = [e for e in expr if isinstance(e, hy.expression)]
        if not exprs:
            return False
    elif isinstance(expr, hy.expression):
        exprs = expr
    else:
        return False
    probe = hy.expression(_TIME_PROBE)
    return _TIME_PROBE in hy.get_variables(hy.subs(exprs, {hy.time: probe}))

#: Rounding mode used everywhere (round to nearest).
RND = libmp.round_nearest

#: Guard bits added to the working precision by :meth:`Program.evaluate`.
EVAL_GUARD_BITS = 10

#: Operations a :class:`Program` can contain (pointwise semantics):
#: ``add`` (n-ary sum), ``sub`` (a - b), ``neg``, ``mul`` (n-ary product),
#: ``div`` (a / b), ``powi`` (a ** n, integer n >= 2 in ``data``), ``pow``
#: (a ** b, b a constant slot; ``data`` is ``(p, q)`` when b is the exact
#: rational p/q, else None), ``sqrt``, ``exp``, ``log``, ``sin``, ``cos``,
#: ``tan``, ``sinh``, ``cosh``, ``tanh``, ``atan``.
SUPPORTED_OPS = (
    "add", "sub", "neg", "mul", "div", "powi", "pow", "sqrt",
    "exp", "log", "sin", "cos", "tan", "sinh", "cosh", "tanh", "atan",
)

_FUNCTIONS = ("exp", "log", "sin", "cos", "tan", "sinh", "cosh", "tanh", "atan")

#: One elementary operation: ``vals[out] = op(vals[args[0]], ...)``.
Node = namedtuple("Node", ["op", "out", "args", "data"])

_PAR_RE = re.compile(r"^par\[(\d+)\]$")


# --------------------------------------------------------------------------
# Argument checking and conversion of user numbers
# --------------------------------------------------------------------------

def rounded_mpf(prec, raw, ctx=None):
    """An mpf of context ``ctx`` (mpmath's global one by default) holding the raw value ``raw`` rounded to
    ``prec`` bits; no context's working precision is involved."""
    return (ctx or mpmath.mp).make_mpf(mpf_pos(raw, prec, RND))


def _raw_to_fraction(raw, name):
    sign, man, exp, _ = raw
    if not man:
        if exp:
            raise ValueError(f"`{name}` must be finite; got {mpmath.mpf(raw)}")
        return Fraction(0)
    man = int(man)  # an mpz under the gmpy2 backend: Fractions (and sympy Rationals) get Python ints
    v = Fraction(man << exp) if exp >= 0 else Fraction(man, 1 << -exp)
    return -v if sign else v


def to_raw(value, prec, name):
    """Raw mpf of a user number, rounded once to `prec` bits (:func:`lieseries.precision.to_raw`); sympy's
    irrational numbers (``sqrt(2)``, ``pi``) too, evaluated at `prec`."""
    if isinstance(value, sympy.Basic) and not isinstance(value, (sympy.Rational, sympy.Float)):
        if getattr(value, "is_number", False) and value.is_real:
            digits = int(prec * 0.30103) + 5
            return mpf_pos(sympy.N(value, digits)._mpf_, prec, RND)
    return precision_raw(value, prec, name)


def convert_vector(values, n, prec, name):
    """Convert a sequence of `n` user numbers to raw mpfs at `prec` bits."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__"):
        raise TypeError(f"`{name}` must be a sequence of {n} numbers; got {type(values).__name__}")
    if len(values) != n:
        raise ValueError(f"`{name}` must have length {n}; got {len(values)}")
    return [to_raw(v, prec, f"{name}[{i}]") for i, v in enumerate(values)]


def variable_names(variables, name="variables"):
    """Names of a list of heyoka variables (or of plain strings)."""
    if isinstance(variables, (str, hy.expression)) or not hasattr(variables, "__iter__"):
        raise TypeError(f"`{name}` must be a list of heyoka variables")
    names = []
    for i, v in enumerate(variables):
        if isinstance(v, str):
            nm = v
        elif isinstance(v, hy.expression):
            s = hy.to_sympy(v)
            if not isinstance(s, sympy.Symbol) or _PAR_RE.match(s.name):
                raise TypeError(f"`{name}[{i}]` must be a heyoka variable; got {v}")
            nm = s.name
        else:
            raise TypeError(
                f"`{name}[{i}]` must be a heyoka variable (hy.make_vars); got {type(v).__name__}"
            )
        names.append(nm)
    if len(set(names)) != len(names):
        raise ValueError(f"`{name}` contains duplicate variables: {names}")
    if not names:
        raise ValueError(f"`{name}` must not be empty")
    return names


def as_expression(e, name):
    """Coerce `e` to a heyoka expression (numbers are accepted)."""
    if isinstance(e, hy.expression):
        return e
    if isinstance(e, (numbers.Real,)) and not isinstance(e, bool):
        return hy.expression(float(e))
    raise TypeError(f"`{name}` must be a heyoka expression; got {type(e).__name__}")


# --------------------------------------------------------------------------
# Exact constants
# --------------------------------------------------------------------------

class Constant(namedtuple("Constant", ["kind", "value"])):
    """An exact number stored in a program.

    ``kind`` is ``"rational"`` (``value = (p, q)``), ``"binary"`` (``value``
    is an exact raw mpf, e.g. a heyoka double), ``"pi"`` or ``"e"``.
    """

    __slots__ = ()

    def raw(self, prec):
        """The constant correctly rounded to `prec` bits (raw mpf)."""
        kind, value = self
        if kind == "rational":
            p, q = value
            if q == 1:
                return from_int(p, prec, RND)
            return from_rational(p, q, prec, RND)
        if kind == "binary":
            return mpf_pos(value, prec, RND)
        if kind == "pi":
            return mpf_pi(prec, RND)
        if kind == "e":
            return mpf_e(prec, RND)
        raise AssertionError(kind)

    def is_zero(self):
        return (self.kind == "rational" and self.value[0] == 0) or (
            self.kind == "binary" and not self.value[1]
        )


# --------------------------------------------------------------------------
# Pointwise evaluation of nodes on raw mpfs
# --------------------------------------------------------------------------

def _pw_add(a, data, prec):
    if len(a) == 2:
        return mpf_add(a[0], a[1], prec, RND)
    return mpf_sum(a, prec, RND)


def _pw_mul(a, data, prec):
    r = a[0]
    for x in a[1:]:
        r = mpf_mul(r, x)  # exact: the operands are few and already rounded
    return mpf_pos(r, prec, RND)


def _pw_pow(a, data, prec):
    base, ex = a
    if base[0] and base[1]:
        raise ValueError(
            "pow with a non-integer exponent of a negative number has no real value"
        )
    if data is not None:
        p, q = data
        if not base[1]:
            if p > 0:
                return fzero
            raise ZeroDivisionError("zero raised to a negative power")
        wp = prec + 10 + abs(p).bit_length()
        r = mpf_nthroot(base, q, wp, RND)
        return mpf_pow_int(r, p, prec, RND)
    return mpf_pow(base, ex, prec + 10 + max(0, ex[2] + ex[3]), RND)


def _pw_log(a, data, prec):
    x = a[0]
    if x[0] or not x[1]:
        raise ValueError("log of a non-positive number")
    return mpf_log(x, prec, RND)


def _pw_sqrt(a, data, prec):
    x = a[0]
    if x[0] and x[1]:
        raise ValueError("sqrt of a negative number")
    return mpf_sqrt(x, prec, RND)


POINTWISE = {
    "add": _pw_add,
    "sub": lambda a, d, prec: mpf_sub(a[0], a[1], prec, RND),
    "neg": lambda a, d, prec: mpf_neg(a[0]),
    "mul": _pw_mul,
    "div": lambda a, d, prec: mpf_div(a[0], a[1], prec, RND),
    "powi": lambda a, d, prec: mpf_pow_int(a[0], d, prec, RND),
    "pow": _pw_pow,
    "sqrt": _pw_sqrt,
    "exp": lambda a, d, prec: mpf_exp(a[0], prec, RND),
    "log": _pw_log,
    "sin": lambda a, d, prec: mpf_sin(a[0], prec, RND),
    "cos": lambda a, d, prec: mpf_cos(a[0], prec, RND),
    "tan": lambda a, d, prec: mpf_tan(a[0], prec, RND),
    "sinh": lambda a, d, prec: mpf_sinh(a[0], prec, RND),
    "cosh": lambda a, d, prec: mpf_cosh(a[0], prec, RND),
    "tanh": lambda a, d, prec: mpf_tanh(a[0], prec, RND),
    "atan": lambda a, d, prec: mpf_atan(a[0], prec, RND),
}


def eval_nodes(nodes, vals, prec):
    """Run `nodes` in order on the raw values list `vals` (modified in place)."""
    pw = POINTWISE
    for op, out, args, data in nodes:
        try:
            vals[out] = pw[op]([vals[i] for i in args], data, prec)
        except ZeroDivisionError:
            raise ZeroDivisionError(f"division by zero in `{op}` (slot {out})") from None


# --------------------------------------------------------------------------
# The program
# --------------------------------------------------------------------------

class Program:
    """A compiled list of expressions: elementary operations over slots.

    Build it with :func:`compile_expressions` (or :func:`compile_system`);
    run it with :meth:`evaluate`.  A program holds exact constants only, so it
    can be run at any precision; it is immutable after construction.

    Attributes
    ----------
    variables : tuple of str
        Names of the state variables (slots ``0 .. nvars-1``).
    npars : int
        Number of runtime parameters (slots ``nvars .. nvars+npars-1``).
    constants : tuple of (int, Constant)
        Constant slots and their exact values.
    nodes : tuple of Node
        Operations in topological order.
    outputs : tuple of int
        Slot holding each compiled expression.
    is_const : tuple of bool
        Per slot: True when the slot does not depend on the variables.
    """

    def __init__(self, variables, npars, constants, nodes, outputs, is_const):
        self.variables = tuple(variables)
        self.npars = int(npars)
        self.constants = tuple(constants)
        self.nodes = tuple(nodes)
        self.outputs = tuple(outputs)
        self.is_const = tuple(is_const)
        self.nslots = len(self.is_const)
        self.const_nodes = tuple(n for n in self.nodes if self.is_const[n.out])
        self.var_nodes = tuple(n for n in self.nodes if not self.is_const[n.out])
        self._const_cache = {}
        self._par_cache = OrderedDict()
        self._engine_cache = {}

    @property
    def nvars(self):
        """Number of state variables."""
        return len(self.variables)

    @property
    def nout(self):
        """Number of compiled expressions."""
        return len(self.outputs)

    def __repr__(self):
        return (
            f"Program(nvars={self.nvars}, npars={self.npars}, nout={self.nout}, "
            f"nodes={len(self.nodes)}, constants={len(self.constants)})"
        )

    def op_counts(self):
        """Number of nodes of each operation (dict op -> count)."""
        counts = {}
        for n in self.nodes:
            counts[n.op] = counts.get(n.op, 0) + 1
        return counts

    def describe(self):
        """Human-readable listing of the program (one line per slot)."""
        lines = []
        for i, nm in enumerate(self.variables):
            lines.append(f"s{i} = {nm}")
        for j in range(self.npars):
            lines.append(f"s{self.nvars + j} = par[{j}]")
        for slot, c in self.constants:
            lines.append(f"s{slot} = const {c.kind} {c.value}")
        for n in self.nodes:
            data = "" if n.data is None else f" [{n.data}]"
            tag = " (const)" if self.is_const[n.out] else ""
            lines.append(
                f"s{n.out} = {n.op}({', '.join('s%d' % a for a in n.args)}){data}{tag}"
            )
        lines.append("outputs: " + ", ".join(f"s{o}" for o in self.outputs))
        return "\n".join(lines)

    # -- raw-level machinery (used by the jet engine too) -------------------

    def constant_raws(self, prec):
        """Values of the exact constants at `prec` bits: list of (slot, raw)."""
        c = self._const_cache.get(prec)
        if c is None:
            c = [(slot, k.raw(prec)) for slot, k in self.constants]
            if len(self._const_cache) > 16:
                self._const_cache.clear()
            self._const_cache[prec] = c
        return c

    def constant_slots(self, pars_raw, prec):
        """Raw values of every constant slot for given parameters.

        Returns a list of length ``nslots`` whose constant slots are filled
        (other entries are None).  Cached on (prec, pars).
        """
        key = (prec, tuple(pars_raw))
        vals = self._par_cache.get(key)
        if vals is not None:
            self._par_cache.move_to_end(key)
            return vals
        vals = [None] * self.nslots
        nv = self.nvars
        vals[nv:nv + self.npars] = pars_raw
        for slot, raw in self.constant_raws(prec):
            vals[slot] = raw
        eval_nodes(self.const_nodes, vals, prec)
        self._par_cache[key] = vals
        if len(self._par_cache) > 8:
            self._par_cache.popitem(last=False)
        return vals

    def evaluate_raw(self, values_raw, pars_raw, prec):
        """Evaluate on raw mpfs at `prec` bits; returns raw output values."""
        vals = list(self.constant_slots(pars_raw, prec))
        vals[:self.nvars] = values_raw
        eval_nodes(self.var_nodes, vals, prec)
        return [vals[o] for o in self.outputs]

    # -- public --------------------------------------------------------------

    def evaluate(self, values, pars, dps, ctx=None):
        """Evaluate the compiled expressions at a point, in mpmath.

        Parameters
        ----------
        values : sequence of numbers
            Values of the variables, in the order of :attr:`variables`
            (int, str, Fraction, float, mpmath.mpf, sympy number).
        pars : sequence of numbers
            Values of the runtime parameters ``par[0] .. par[npars-1]``.
        dps : int
            Decimal digits of the result (>= 5).  Inputs are converted and
            the program is run with a few guard bits beyond this.

        Returns
        -------
        list of mpmath.mpf
            One value per compiled expression, rounded to `dps` digits.
        """
        dps = check_dps(dps)
        # explicit precision: mpmath's global context is never touched
        prec = dps_to_bits(dps)
        wp = prec + EVAL_GUARD_BITS
        vr = convert_vector(values, self.nvars, wp, "values")
        pr = convert_vector(pars, self.npars, wp, "pars")
        out = self.evaluate_raw(vr, pr, wp)
        return [rounded_mpf(prec, r, ctx) for r in out]


# --------------------------------------------------------------------------
# The compiler
# --------------------------------------------------------------------------

class _Builder:
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
        m = _PAR_RE.match(e.name)
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
        slot = self.memo.get(e)
        if slot is not None:
            return slot
        slot = self._build(e)
        self.memo[e] = slot
        return slot

    def _build(self, e):
        if isinstance(e, sympy.Symbol):
            return self.symbol(e)
        if isinstance(e, sympy.Number) or e is sympy.pi or e is sympy.E:
            return self.number(e)
        if isinstance(e, sympy.Add):
            coeff, terms = e.as_coeff_add()
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


#: Compiled programs by (variables, expressions, npars, cse), in the shared cache (:mod:`lieseries.cache`).
_PROGRAMS = cache.region("expr.programs", 32)


def compile_expressions(variables, exprs, npars=None, cse=True):
    """Compile heyoka expressions into a :class:`Program`.

    The expressions are converted with :func:`heyoka.to_sympy`, their common
    subexpressions are shared with :func:`sympy.cse` and structural hashing,
    and the result is flattened into elementary operations in topological
    order.  Compilation is cached (on the variables, the expressions and
    `npars`), so compiling the same system twice is free.

    Parameters
    ----------
    variables : sequence of heyoka.expression
        The state variables (from :func:`heyoka.make_vars`), or their names.
    exprs : sequence of heyoka.expression
        Expressions in these variables and in runtime parameters
        ``heyoka.par[i]``.  Plain numbers are accepted too.
    npars : int, optional
        Number of runtime parameters the program takes.  Default: one more
        than the largest parameter index used (0 if none).
    cse : bool, optional
        Run :func:`sympy.cse` before flattening (default).  Identical
        subtrees are always shared; ``cse=False`` skips the (superlinear)
        search for common sub-sums/sub-products, which is worthwhile only for
        very large one-shot expressions.

    Returns
    -------
    Program

    Raises
    ------
    NotImplementedError
        If an expression uses an unsupported function (the message names it)
        or depends on time.
    ValueError
        If an expression uses a variable not in `variables`, or a parameter
        index >= `npars`.
    """
    names = variable_names(variables)
    if isinstance(exprs, hy.expression) or not hasattr(exprs, "__iter__"):
        raise TypeError("`exprs` must be a list of heyoka expressions")
    exprs = [as_expression(e, f"exprs[{i}]") for i, e in enumerate(exprs)]
    if npars is not None and (
        isinstance(npars, bool) or not isinstance(npars, numbers.Integral) or npars < 0
    ):
        raise ValueError(f"`npars` must be None or an integer >= 0; got {npars!r}")
    key = (tuple(names), tuple(exprs), npars, bool(cse))
    prog = _PROGRAMS.get(key)
    if prog is not None:
        _PROGRAMS.touch(key)
        return prog
    start = time.perf_counter()
    prog = _compile(names, exprs, npars, bool(cse))
    return _PROGRAMS.put(key, prog, cost=time.perf_counter() - start)


def _compile(names, exprs, npars, use_cse):
    sym = [hy.to_sympy(e) for e in exprs]
    if npars is None:
        used = set()
        for s in sym:
            for f in s.free_symbols:
                m = _PAR_RE.match(f.name)
                if m:
                    used.add(int(m.group(1)))
        npars = max(used) + 1 if used else 0
    b = _Builder(names, int(npars))
    if use_cse:
        repl, reduced = sympy.cse(
            sym, symbols=sympy.numbered_symbols("_cse", cls=sympy.Dummy), order="none"
        )
    else:
        repl, reduced = [], sym
    for s, e in repl:
        b.cse_map[s] = b.build(e)
    outputs = [b.build(e) for e in reduced]
    return Program(names, npars, b.constants, b.nodes, outputs, b.is_const)


def compile_system(variables, rhs, npars=None):
    """Compile the right-hand side of ``dz/dt = rhs(z)``.

    Same as ``compile_expressions(variables, rhs, npars)`` after checking
    that there is one right-hand side per variable.  The outputs of the
    program are the components of `rhs`, in order.
    """
    names = variable_names(variables)
    if isinstance(rhs, hy.expression) or not hasattr(rhs, "__len__"):
        raise TypeError("`rhs` must be a list of heyoka expressions")
    if len(rhs) != len(names):
        raise ValueError(
            f"`rhs` must have one expression per variable ({len(names)}); got {len(rhs)}"
        )
    return compile_expressions(variables, rhs, npars)
