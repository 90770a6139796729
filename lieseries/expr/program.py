"""A compiled :class:`Program` and its evaluation: exact constants (:class:`Constant`), elementary operations
(:data:`Node`, :data:`SUPPORTED_OPS`) run pointwise on mpmath's raw numbers (:data:`POINTWISE`,
:func:`eval_nodes`), and the conversion of user numbers to raw numbers rounded once (:func:`to_raw`,
:func:`convert_vector`).

All numeric work uses mpmath's raw representation (``mpmath.libmp`` tuples ``(sign, mantissa, exponent,
bitcount)``), which avoids the cost of creating ``mpf`` objects; public functions take and return ordinary
``mpmath.mpf``.
"""

from __future__ import annotations

from collections import OrderedDict, namedtuple

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

from ..precision import check_dps, dps_to_bits
from ..precision import to_raw as precision_raw

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

#: One elementary operation: ``vals[out] = op(vals[args[0]], ...)``.
Node = namedtuple("Node", ["op", "out", "args", "data"])


# --------------------------------------------------------------------------
# Argument checking and conversion of user numbers
# --------------------------------------------------------------------------


def rounded_mpf(prec, raw, ctx=None):
    """An mpf of context ``ctx`` (mpmath's global one by default) holding the raw value ``raw`` rounded to
    ``prec`` bits; no context's working precision is involved."""
    return (ctx or mpmath.mp).make_mpf(mpf_pos(raw, prec, RND))


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

    Build it with :func:`lieseries.expr.compile_expressions` (or :func:`~lieseries.expr.compile_system`);
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
