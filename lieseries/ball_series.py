"""Arb ball arithmetic for the validated engine (:mod:`lieseries.validated`): python-flint's process-wide working
precision set under a lock, balls that pickle exactly, a vector field's program evaluated on balls, complex boxes
and ball series, and its Taylor coefficients over a box (Picard iteration)."""

from __future__ import annotations

import copyreg
import threading
import time as _time
import weakref
from contextlib import contextmanager
from fractions import Fraction

from .lie.plan import DeadlineExceeded
from .precision import check_count

__all__ = ["SUPPORTED_OPS", "flint_module", "working_precision", "whole_series", "Singular", "ball_constant",
           "exact_constant", "evaluate", "check_ops", "taylor_coefficients"]

#: Operations of a vector field that the validated engine evaluates in ball arithmetic.
SUPPORTED_OPS = ("add", "sub", "neg", "mul", "div", "powi", "pow", "sqrt", "exp", "log", "sin", "cos", "tan",
                 "atan", "sinh", "cosh", "tanh")

_LOCK = threading.RLock()


def flint_module():
    try:
        import flint
    except ImportError:  # pragma: no cover - python-flint is a dependency
        raise ImportError("`validated_integrate` needs python-flint: pip install python-flint") from None
    if not _PICKLING:
        # flint.arb has no pickle support of its own: a validated Solution (its rows are arbs) pickles through
        # this reducer, which keeps every ball exactly (midpoint and radius as integer mantissa and exponent)
        copyreg.pickle(flint.arb, _reduce_arb)
        _PICKLING.append(True)
    return flint


_PICKLING: list = []


def _arb_part(x):
    """An exact arb value (a midpoint, or a radius as an arb) as (mantissa, exponent), or 'nan' / '+inf' / '-inf'."""
    if x.is_finite():
        man, exp = x.man_exp()
        return int(man), int(exp)
    if x.is_nan():
        return "nan"
    return "+inf" if x > 0 else "-inf"


def _reduce_arb(x):
    return _rebuild_arb, (_arb_part(x.mid()), _arb_part(x.rad()))


def _rebuild_arb(mid, rad):
    """The ball of :func:`_reduce_arb`, exactly (arb((man, exp), ...) takes the binary data without rounding)."""
    import flint

    def part(p):
        return p if isinstance(p, tuple) else p.replace("+", "")

    if not isinstance(rad, tuple):  # an infinite (or nan) radius
        return flint.arb(part(mid), "inf") if isinstance(mid, tuple) else flint.arb(part(mid))
    return flint.arb(part(mid), rad)


@contextmanager
def working_precision(bits: int, cap: int | None = None):
    """python-flint's working precision (bits) and, when given, its series length cap, set for the block and
    restored after it (on an exception or an interrupt too).

    python-flint keeps both in ``flint.ctx``, one for the whole process (not per thread), and no ball operation
    takes a precision of its own: every stretch of code that sets them and relies on them holds this lock (an
    RLock: the stretches nest), so threads take turns. Code that sets ``flint.ctx`` in another thread without this
    function is not covered. Series longer than the cap are cut (their O(x^n) says so): the cap must exceed the
    orders in use."""
    bits = check_count(bits, "bits", low=2)
    cap = None if cap is None else check_count(cap, "cap")
    flint = flint_module()
    with _LOCK:
        old = flint.ctx.prec, flint.ctx.cap
        try:
            flint.ctx.prec = bits
            if cap is not None:
                flint.ctx.cap = cap
            yield flint
        finally:
            try:
                flint.ctx.prec = old[0]
            finally:
                flint.ctx.cap = old[1]


def whole_series(series, length: int):
    """``series``, checked to hold its first ``length`` terms. python-flint cuts every series operation's result
    at the process-wide cap (its O(x^n) then says so): code in another thread that lowers ``flint.ctx.cap``
    without :func:`working_precision` would cut a series mid-computation, and the terms missing would read as
    zeros. Such a series raises RuntimeError (python-flint 0.8 and later say how many terms a series holds: the
    project requires them)."""
    held = getattr(series, "prec", None)
    if held is not None and held < length:
        raise RuntimeError(f"a ball series holds {held} terms where {length} were computed: python-flint's series "
                           "cap (flint.ctx.cap, one for the whole process) was lowered meanwhile by code that does "
                           "not set it through lieseries.validated.working_precision")
    return series


# -- evaluating a program on balls, complex boxes and ball series ------------------------------------------------
def _powi(x, n: int, one):
    if n < 0:
        return one / _powi(x, -n, one)
    result, base = one, x
    while n:
        if n & 1:
            result = result * base
        n >>= 1
        if n:
            base = base * base
    return result


class Singular(ValueError):
    """The field cannot be evaluated on the balls: an operation's argument reaches its singularity (a divisor, a
    series' leading term, a root's or logarithm's argument containing 0 or a negative value)."""

    def __init__(self, op, cause):
        super().__init__(f"`{op}` is singular on its argument ({cause})")
        self.op = op


def _apply(op, a, data, one):
    try:
        return _apply_op(op, a, data, one)
    except (ValueError, ZeroDivisionError) as e:
        raise Singular(op, e) from None


def _apply_op(op, a, data, one):
    if op == "add":
        s = a[0]
        for x in a[1:]:
            s = s + x
        return s
    if op == "sub":
        return a[0] - a[1]
    if op == "neg":
        return -a[0]
    if op == "mul":
        p = a[0]
        for x in a[1:]:
            p = p * x
        return p
    if op == "div":
        return a[0] / a[1]
    if op == "powi":
        return _powi(a[0], int(data), one)
    if op == "pow":
        ex = a[1] if data is None else one * data[0] / data[1]
        return (a[0].log() * ex).exp()
    if op in ("sqrt", "exp", "log", "sin", "cos", "tan", "atan"):
        return getattr(a[0], op)()
    e = a[0].exp()
    if op == "sinh":
        return (e - 1 / e) / 2
    if op == "cosh":
        return (e + 1 / e) / 2
    if op == "tanh":
        return (e - 1 / e) / (e + 1 / e)
    raise AssertionError(op)  # pragma: no cover - checked in check_ops


def ball_constant(c, flint):
    """A program's constant as a ball (exact values rounded outward at the working precision)."""
    q = exact_constant(c, flint)
    if q is not None:
        return flint.arb(q)
    return flint.arb.pi() if c[0] == "pi" else flint.arb.const_e()


def exact_constant(c, flint):
    """A program's constant as an fmpq (exactly), or None for pi and e."""
    kind, value = c
    if kind == "rational":
        return flint.fmpq(*value)
    if kind == "binary":
        sign, man, exp, _ = value
        q = Fraction(int(man) << exp) if exp >= 0 else Fraction(int(man), 1 << -exp)
        return flint.fmpq(-q.numerator if sign else q.numerator, q.denominator)
    return None


def evaluate(prog, values, pars, consts, one):
    """The program's outputs on ``values`` (balls or ball series), ``pars`` and the constant balls ``consts``
    (pairs (slot, ball) in the order of ``prog.constants``), by its straight-line Python function (the same
    operations in the same order as :func:`_interpret`, without its dispatch). An operation singular on its
    argument raises :class:`Singular`, named by the interpreter."""
    run = _COMPILED.get(prog)
    if run is None:
        run = _COMPILED[prog] = _compile(prog)
    try:
        return run(values, pars, consts, one)
    except (ValueError, ZeroDivisionError) as e:
        _interpret(prog, values, pars, consts, one)  # raises Singular with the operation's name
        raise Singular("?", e) from None  # pragma: no cover - the interpreter fails on the same operation


#: Straight-line functions of programs (:func:`_compile`), per program object.
_COMPILED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_INLINE = {"add": " + ", "mul": " * "}


def _compile(prog):
    """``run(values, pars, consts, one)``: the program as one Python function of local variables (slot i is
    ``v<i>``); arithmetic written out, other operations through :func:`_apply_op`. Factors that are the exact
    constant 1 are left out of products (an exact 1 changes no ball, series or rational)."""
    ones = {slot for slot, c in prog.constants if _is_one(c)}
    lines = ["def run(x, p, c, one):"]
    if prog.nvars:
        lines.append("    " + "".join(f"v{i}, " for i in range(prog.nvars)) + "= x")
    if prog.npars:
        lines.append("    " + "".join(f"v{prog.nvars + j}, " for j in range(prog.npars)) + "= p")
    for k, (slot, _) in enumerate(prog.constants):
        lines.append(f"    v{slot} = c[{k}][1]")
    for op, out, args, data in prog.nodes:
        a = [f"v{i}" for i in args]
        if op == "mul" and ones.intersection(args):
            a = [f"v{i}" for i in args if i not in ones] or [f"v{args[0]}"]
        if op in _INLINE:
            expr = a[0]
            for x in a[1:]:
                expr = f"({expr}{_INLINE[op]}{x})"
        elif op == "sub":
            expr = f"{a[0]} - {a[1]}"
        elif op == "div":
            expr = f"{a[0]} / {a[1]}"
        elif op == "neg":
            expr = f"-{a[0]}"
        else:
            expr = f"apply_op({op!r}, [{', '.join(a)}], data[{out}], one)"
        lines.append(f"    v{out} = {expr}")
    lines.append("    return [" + ", ".join(f"v{o}" for o in prog.outputs) + "]")
    namespace = {"apply_op": _apply_op, "data": {n.out: n.data for n in prog.nodes}}
    exec(compile("\n".join(lines), f"<validated program {len(prog.nodes)} nodes>", "exec"), namespace)
    return namespace["run"]


def _is_one(c) -> bool:
    """The program constant ``c`` is exactly 1."""
    kind, value = c
    if kind == "rational":
        return value[0] == value[1]
    if kind == "binary":
        sign, man, exp, _ = value
        return not sign and int(man) == 1 and exp == 0
    return False


def _interpret(prog, values, pars, consts, one):
    vals = [None] * prog.nslots
    vals[: prog.nvars] = values
    vals[prog.nvars: prog.nvars + prog.npars] = pars
    for slot, c in consts:
        vals[slot] = c
    for op, out, args, data in prog.nodes:
        vals[out] = _apply(op, [vals[i] for i in args], data, one)
    return [vals[o] for o in prog.outputs]


def check_ops(prog):
    bad = sorted({n.op for n in prog.nodes} - set(SUPPORTED_OPS))
    if bad:
        raise ValueError(f"`system`: the validated engine cannot evaluate the operations {bad} in ball arithmetic; "
                         f"it supports {', '.join(SUPPORTED_OPS)}")


def taylor_coefficients(prog, z0, pars, consts, order, flint, *, bits=None, deadline=None):
    """Ball Taylor coefficients c_0..c_order of the flow from the balls z0: out[i][j] for component i, order j.

    Picard iteration on Arb power series, one coefficient per iteration: the (m-1)-th coefficient of f(z) depends
    only on c_0..c_{m-1}, so iteration m evaluates f on the series known so far (length m) and takes
    z = z0 + integral of f(z), of length m + 1 (its coefficient m is c_m = f_{m-1} / m; the earlier ones enclose
    c_0..c_{m-1} again, from the same balls). ``bits``: the precision to work at (default: the
    current one); a lower precision only widens the balls, it never makes them wrong. ``deadline``: a
    perf_counter value after which :class:`~lieseries.lie.plan.DeadlineExceeded` is raised (checked every order).
    """

    arb, arb_series = flint.arb, flint.arb_series
    if flint.ctx.cap < order + 2:
        raise AssertionError("the series cap must exceed the order (set by the caller's working_precision, unless "
                             "another thread lowered it without one)")  # pragma: no cover
    with working_precision(flint.ctx.prec if bits is None else bits):
        start = [arb_series([c], prec=order + 1) for c in z0]  # a sum's length is its shorter term's
        z = [arb_series([c], prec=1) for c in z0]
        for m in range(1, order + 1):
            if deadline is not None and _time.perf_counter() > deadline:
                raise DeadlineExceeded(m - 1)
            f = evaluate(prog, z, pars, consts, arb_series([arb(1)], prec=m))
            z = [s + (fi if isinstance(fi, arb_series) else arb_series([fi], prec=m)).integral()
                 for s, fi in zip(start, f)]  # a constant component: a series of its own
        coeffs = []
        for c, zi in zip(z0, z):
            got = list(whole_series(zi, order + 1).coeffs())
            coeffs.append([c] + got[1:order + 1] + [arb(0)] * (order + 1 - max(len(got), 1)))
    return coeffs
