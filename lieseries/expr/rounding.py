"""What floating-point roundings cost a vector field at a state: a first-order bound, evaluated in floats.

heyoka evaluates the field in the run's floating-point format, every operation rounded relative to its own
value. Where a sum's terms cancel far below their size -- ``(p + x)^2 - p^2 - 2 p x - x^2`` at x = 1e10 -- the
roundings of the terms, relative to them, are far above the result, and a state's rate is as far off: no error
estimate of the integrator sees it (its Taylor coefficients come from the same arithmetic). :func:`lost_bits`
bounds it: every node's value carries an absolute error bound ``e`` in units of the format's unit roundoff,
propagated to first order through the program's operations (``e(a + b) = e(a) + e(b) + |a + b|``,
``e(a b) = |a| e(b) + |b| e(a) + |a b|``, ``e(f(a)) = |f'(a)| e(a) + |f(a)|``, ...), the states and parameters
exact (their rounding is the problem's conditioning, the same for any arithmetic) and constants rounded once.
The errors never cancel in the bound. A state's loss is ``log2(e / scale)`` with ``scale = max(|y_i|,
|f_i(y)| - e 2^-53)`` (the rate computed in floats less its error bound: where the terms cancel it is noise): the
bits of the format its rate may be off by per unit time, relative to the state. A state whose scale lies more than
:data:`JUDGED_BITS` bits under the format's precision below the largest one's is judged relative to the largest
instead (heyoka's tolerance is relative to it). The bound is computed in floats (its own roundings are far below
what it judges); a state or field beyond a float's range gives None, for an exact check to decide
(:func:`lieseries.lie.fixed.cancelling_bits`).

One generated function per program and kind of operand (Python floats for a state, numpy arrays for many), cached.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

__all__ = ["lost_bits", "JUDGED_BITS"]

#: States whose scale lies this many bits below the format's precision under the largest state's are judged
#: relative to the largest: their own size is at the level of the others' roundings (a sphere's momentum zero but
#: for them).
JUDGED_BITS = 16

#: The unit roundoff of the floats the bound is computed in: the computed rate |f| less e _U is a lower bound of
#: the rate (where the field cancels, f is the floats' noise, whatever the format judged)
_U = 2.0 ** -53

_FUNCTIONS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()  # program -> {vectorised: function}

#: The error rule of each unary operation: e(f(a)) = D e(a) + |v|, D written over the argument ``a`` and the value
#: ``v`` (a bound of |f'(a)|).
_UNARY = {
    "sqrt": "0.5 / A(v)",
    "exp": "A(v)",
    "log": "1.0 / A(a)",
    "sin": "A(cos(a))",
    "cos": "A(sin(a))",
    "tan": "(1.0 + v * v)",
    "sinh": "cosh(a)",
    "cosh": "A(sinh(a))",
    "tanh": "(1.0 - v * v)",
    "atan": "1.0 / (1.0 + a * a)",
}


def _constant(c) -> float:
    """A program's constant as a float (inf beyond their range: the bound is then not taken in floats)."""
    kind, value = c
    try:
        if kind == "rational":
            return value[0] / value[1]
        if kind == "binary":
            sign, man, exp, _ = value
            return math.ldexp(-float(man) if sign else float(man), exp)
    except OverflowError:
        return math.inf
    return math.pi if kind == "pi" else math.e


def _float(v) -> float:
    """v as a float, inf beyond their range (an exact check then decides)."""
    try:
        return float(v)
    except OverflowError:
        return math.inf


def _source(prog) -> str:
    exact = set(range(prog.nvars + prog.npars))  # slots without error (their terms are left out)
    lines = ["def bound(x, p, c):"]
    for i in range(prog.nvars):
        lines.append(f"    v{i} = x[{i}]")
    for j in range(prog.npars):
        lines.append(f"    v{prog.nvars + j} = p[{j}]")
    for k, (slot, c) in enumerate(prog.constants):
        lines.append(f"    v{slot} = c[{k}]")
        if c[0] == "binary" and int(c[1][1]).bit_length() <= 53:  # a float itself: exact
            exact.add(slot)
        else:
            lines.append(f"    e{slot} = A(c[{k}])")

    def err(i, factor=None):  # the term factor * e_i, or None for an exact slot
        if i in exact:
            return None
        return f"e{i}" if factor is None else f"{factor} * e{i}"

    def total(*terms):
        return " + ".join(t for t in terms if t is not None) or "0.0"

    for op, out, args, data in prog.nodes:
        v = f"v{out}"
        a = [f"v{i}" for i in args]
        if op == "add":  # n-ary, summed in any order: every partial sum is below the sum of the |terms|
            lines.append(f"    {v} = {' + '.join(a)}")
            e = total(*(err(i) for i in args), f"{len(a) - 1} * ({' + '.join(f'A({x})' for x in a)})")
        elif op == "sub":
            lines.append(f"    {v} = {a[0]} - {a[1]}")
            e = total(err(args[0]), err(args[1]), f"A({v})")
        elif op == "mul":  # n-ary: one factor after the other (u: the error of the partial product t, or None)
            lines.append(f"    t = {a[0]}")
            u = err(args[0])
            for i, x in zip(args[1:], a[1:]):
                lines.append(f"    w = t * {x}")
                e_next = total(err(i, "A(t)"), None if u is None else f"A({x}) * {u}", "A(w)")
                lines.append(f"    u = {e_next}; t = w")
                u = "u"
            lines.append(f"    {v} = t")
            e = u
        elif op == "div":
            lines.append(f"    {v} = {a[0]} / {a[1]}")
            e = total(f"({total(err(args[0]), err(args[1], f'A({v})'))}) / A({a[1]})"
                      if not {args[0], args[1]} <= exact else None, f"A({v})")
        elif op == "powi":  # a^n, n >= 2: at most n roundings
            n = int(data)
            lines.append(f"    {v} = {a[0]} ** {n}")
            e = total(err(args[0], f"{n} * A({a[0]}) ** {n - 1}"), f"{n} * A({v})")
        elif op == "pow":  # a^b = exp(b log a): d/da = b v / a, d/db = v log a
            lines.append(f"    {v} = {a[0]} ** {a[1]}")
            e = total(err(args[0], f"A({a[1]} * {v} / {a[0]})"), err(args[1], f"A({v} * log(A({a[0]})))"),
                      f"2 * A({v})")
        elif op == "neg":
            lines.append(f"    {v} = -{a[0]}")
            if args[0] in exact:
                exact.add(out)
                continue
            e = f"e{args[0]}"
        elif op in _UNARY:
            lines.append(f"    a = {a[0]}; v = {op}(a); {v} = v")
            e = total(err(args[0], _UNARY[op]), "A(v)")
        else:  # pragma: no cover - every operation of SUPPORTED_OPS has its rule
            raise AssertionError(op)
        lines.append(f"    e{out} = {e}")
    lines.append("    return [" + ", ".join(f"v{o}" for o in prog.outputs) + "], ["
                 + ", ".join("0.0" if o in exact else f"e{o}" for o in prog.outputs) + "]")
    return "\n".join(lines) + "\n"


def _function(prog, vectorised: bool):
    by_kind = _FUNCTIONS.setdefault(prog, {})
    fn = by_kind.get(vectorised)
    if fn is None:
        lib = np if vectorised else math
        scope = {name: getattr(lib, name) for name in ("sqrt", "exp", "log", "sin", "cos", "tan", "sinh", "cosh",
                                                        "tanh")}
        scope["atan"] = np.arctan if vectorised else math.atan
        scope["A"] = np.abs if vectorised else abs
        exec(compile(_source(prog), f"<lieseries rounding bound, {len(prog.nodes)} nodes>", "exec"), scope)
        fn = by_kind[vectorised] = scope["bound"]
    return fn


def lost_bits(prog, rows, pars_rows, bits: int) -> list:
    """Per row (a state; ``pars_rows`` the parameters of each, or one sequence for all), the bits of a
    ``bits``-bit floating-point format the field's own roundings may cost a state's rate per unit time (0 when
    none, an int), or None where the bound cannot be taken in floats (a value beyond their range, a singular
    derivative such as sqrt at 0): an exact check decides those."""
    consts = [_constant(c) for _, c in prog.constants]
    one_par = pars_rows is None or not len(pars_rows) or np.ndim(pars_rows[0]) == 0
    if len(rows) == 1:  # a single run: plain floats
        pars = list(map(_float, pars_rows if one_par else pars_rows[0])) if pars_rows is not None else []
        y = list(map(_float, rows[0]))
        try:
            f, e = _function(prog, False)(y, pars, consts)
            if not all(map(math.isfinite, y + pars + f + e)):
                return [None]
            scale = [max(abs(a), abs(b) - ei * _U) for a, b, ei in zip(y, f, e)]
            big = max(scale)
            floor = big * 2.0 ** (JUDGED_BITS - bits)
            top = max((ei / (si if si >= floor else big) for ei, si in zip(e, scale) if big > 0), default=0.0)
        except (ArithmeticError, ValueError, TypeError):  # (a complex power of a negative number: TypeError)
            return [None]
        return [_bits(top)]
    if isinstance(rows, np.ndarray) and rows.dtype.kind == "f":
        Y = rows.astype(float)
    else:
        Y = np.array([[_float(v) for v in r] for r in rows], dtype=float).reshape(len(rows), prog.nvars)
    k = Y.shape[0]
    if pars_rows is None:
        P = []
    elif one_par:
        P = [_float(v) for v in pars_rows]
    else:
        P = list(np.array([[_float(v) for v in r] for r in pars_rows], dtype=float).T)
    with np.errstate(all="ignore"):
        f, e = _function(prog, True)(list(Y.T), P, consts)
        f = np.column_stack([np.broadcast_to(v, k) for v in f])
        e = np.column_stack([np.broadcast_to(v, k) for v in e])
        scale = np.maximum(np.abs(Y), np.abs(f) - e * _U)
        big = scale.max(axis=1, keepdims=True)
        judged = scale >= big * 2.0 ** (JUDGED_BITS - bits)
        top = np.where(big > 0, e / np.where(judged, scale, big), 0.0).max(axis=1)
        finite = np.isfinite(Y).all(axis=1) & np.isfinite(f).all(axis=1) & np.isfinite(e).all(axis=1)
        if len(P):
            finite &= np.isfinite(np.column_stack([np.broadcast_to(v, k) for v in P])).all(axis=1)
    return [_bits(r) if ok else None for r, ok in zip(top.tolist(), finite.tolist())]


def _bits(ratio: float):
    """The bits a ratio of an error bound to a scale amounts to (None for one that is not finite)."""
    if not math.isfinite(ratio):
        return None
    return max(0, math.ceil(math.log2(ratio))) if ratio > 1 else 0
