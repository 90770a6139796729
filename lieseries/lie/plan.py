"""What the two jet engines share: the jet plan of a compiled right-hand side, the guard bits of an order, the
deadline of an expansion, and the radius of convergence that coefficient norms show.

The plan lowers a :class:`~lieseries.expr.Program` into jet instructions once (integer powers into squarings and
products, parameters and constants as scalars, products paired and shared) and is kept per program; the mpf jets
(:mod:`lieseries.lie.jets`) and the fixed-point jets (:mod:`lieseries.lie.fixed_orders`) both run it.
"""

from __future__ import annotations

import math
import weakref

from .. import expr as _expr
from ..expr import Constant, Node, Program, eval_nodes

__all__ = ["jet_plan", "resolve_program", "radius_from_logs", "jet_guard_bits", "DeadlineExceeded",
           "MAX_GUARD_DIGITS"]


def radius_from_logs(points) -> float:
    """The radius of convergence that coefficient norms show: ``points`` are (k, ln ||c_k||) of the nonzero norms of
    the upper half of the orders. The slope of log ||c_k|| against k is fitted by least squares to the vertices of
    their upper hull (the coefficients' envelope: the root test is a limsup), after the hull's rising start; radius
    = exp(-slope). A series whose coefficients alternate between the growth of a singularity and much smaller values
    (an even function, 1/cos t: the odd orders come from other, entire components) is measured by the former, not
    by an average of both, which put 1/cos's radius pi/2 at 3.7 and claimed convergence where the series diverges.
    Coefficients that do not decay: their growth rate from the first point to the last (the root test on the last
    one alone, |c_k|^(-1/k), depends on the variables' scale: momenta of 1e400 made a radius of 1e-34, and the run
    collapsed at its first step); the root test on a single point. ``inf`` for no points."""
    pts = sorted(points)
    if not pts:
        return math.inf
    hull = []
    for p in pts:
        while len(hull) >= 2 and ((hull[-1][0] - hull[-2][0]) * (p[1] - hull[-2][1])
                                  - (hull[-1][1] - hull[-2][1]) * (p[0] - hull[-2][0])) >= 0:
            hull.pop()
        hull.append(p)
    # a falling end: the hull always ends on the last point, and a last coefficient of the parity that stays small
    # (the even orders of a field whose odd ones grow: log-norms 8.06, 8.19 at orders 37, 39, then 4.50 at 40) made
    # a last segment far steeper than the envelope, and a radius of 40 where the series diverges beyond ~0.9; the
    # envelope's slope changes gradually (by ~1/k an order for 1/k!), so a last vertex that turns it down by more
    # than 1 an order is not the envelope
    while len(hull) >= 3 and _slope(hull[-2], hull[-1]) < _slope(hull[-3], hull[-2]) - 1:
        hull.pop()
    while len(hull) >= 2 and hull[1][1] >= hull[0][1]:  # the rising start (the envelope's first points)
        hull.pop(0)
    if len(hull) == 1:
        return _growth_radius(pts)
    n = len(hull)
    kbar = sum(k for k, _ in hull) / n
    lbar = sum(lg for _, lg in hull) / n
    slope = sum((k - kbar) * (lg - lbar) for k, lg in hull) / sum((k - kbar) ** 2 for k, _ in hull)
    if slope >= 0:
        return _growth_radius(pts)
    return math.exp(min(-slope, 700.0))


def _slope(a, b) -> float:
    return (b[1] - a[1]) / (b[0] - a[0])


def _growth_radius(pts) -> float:
    """exp(-rate) for the rate at which ln ||c_k|| grows from the first point to the last: the radius of C rho^-k
    whatever C (the variables' scale); the root test |c_k|^(-1/k) for a single point."""
    (k0, lg0), (k1, lg1) = pts[0], pts[-1]
    if k1 > k0:
        return math.exp(max(min(-(lg1 - lg0) / (k1 - k0), 700.0), -700.0))
    return math.exp(max(min(-lg1 / k1, 700.0), -700.0)) if k1 > 0 else math.inf


#: Working digits above ``MAX_DPS`` that the engines may add as guard digits to a user's ``dps``.
MAX_GUARD_DIGITS = 1000


class DeadlineExceeded(TimeoutError):
    """An expansion passed its ``deadline`` (a :func:`time.perf_counter` value) before reaching its order: the
    caller's wall-time budget ran out inside one step. ``order`` is the last order completed. A
    :class:`TimeoutError`: what :func:`lieseries.lie_series` raises when its ``max_time`` runs out."""

    def __init__(self, order, message=None):
        super().__init__(message or f"the deadline passed after order {order}")
        self.order = order


def jet_guard_bits(order):
    """Guard bits used by :func:`taylor_coefficients` for a given order."""
    return 20 + 2 * int(order).bit_length()


# --------------------------------------------------------------------------
# The plan: a program specialised for jets (built once per program)
# --------------------------------------------------------------------------

class _Plan:
    """Jet instructions for a :class:`Program` (one per program: :func:`jet_plan`).

    ``instrs`` are tuples ``(kind, outs, args, extra)``: ``outs`` and
    ``args`` are slots of jets, ``extra`` holds constant slots / data.
    Constant slots beyond the program's are computed by ``const_nodes`` from
    ``consts``.
    """

    def __init__(self, program):
        self.program = program
        self.is_const = list(program.is_const)
        self.consts = []
        self.const_nodes = []
        self.instrs = []
        self.alias = {}
        self._paired = {}  # (sincos | sinhcosh, argument slot) -> {function name: slot}
        self._one = None  # the slot of the constant 1, once needed
        for op, out, args, data in program.var_nodes:
            args = [self.alias.get(x, x) for x in args]
            if op in ("add", "sub", "neg"):
                self._lower_linear(op, out, args)
            elif op == "mul":
                self._lower_mul(out, args)
            elif op == "div":
                self._lower_div(out, args)
            elif op == "powi":
                self._lower_powi(out, args[0], data)
            elif op == "pow":
                a, e = args
                if not self.is_const[e]:  # the compiler never emits this
                    raise AssertionError("pow with a non-constant exponent")
                self.instrs.append(("pow", out, (a,), (e, data)))
            elif op in ("sin", "cos", "sinh", "cosh"):
                self._lower_sincos(op, out, args[0])
            elif op in ("tan", "tanh", "atan"):
                aux = self._new_slot(False)
                self.instrs.append((op, (out, aux), (args[0],), None))
            elif op in ("sqrt", "exp", "log"):
                self.instrs.append((op, out, (args[0],), None))
            else:
                raise NotImplementedError(f"no Taylor-mode rule for `{op}`")
        self.nslots = len(self.is_const)
        self.outputs = tuple(self.alias.get(o, o) for o in program.outputs)

    # -- building the plan: slots, constants and one method per kind of node ------------------------------------
    def _new_slot(self, const):
        self.is_const.append(const)
        return len(self.is_const) - 1

    def _const_node(self, op, args, data=None):
        s = self._new_slot(True)
        self.const_nodes.append(Node(op, s, tuple(args), data))
        return s

    def _one_slot(self):
        if self._one is None:
            self._one = self._new_slot(True)
            self.consts.append((self._one, Constant("rational", (1, 1))))
        return self._one

    def _emit_mul(self, out, x, y):
        if x == y:
            self.instrs.append(("sqr", out, (x,), None))
        else:
            self.instrs.append(("mul", out, (x, y), None))

    def _lower_linear(self, op, out, args):
        """add / sub / neg: one ``lin`` of its variable and constant terms (a lone variable is an alias)."""
        if op == "add":
            negs = [False] * len(args)
        elif op == "sub":
            negs = [False, True]
        else:
            negs = [True]
        isc = [self.is_const[x] for x in args]
        vt = [(x, n) for x, n, c in zip(args, negs, isc) if not c]
        ct = [(x, n) for x, n, c in zip(args, negs, isc) if c]
        if len(vt) == 1 and not ct and not vt[0][1]:
            self.alias[out] = vt[0][0]
            return
        self.instrs.append(("lin", out, tuple(vt), tuple(ct)))

    def _lower_mul(self, out, args):
        """A product: its constant factors folded into one scale, the variable ones multiplied in turn."""
        isc = [self.is_const[x] for x in args]
        vs = [x for x, c in zip(args, isc) if not c]
        cs = [x for x, c in zip(args, isc) if c]
        cslot = None
        if cs:
            cslot = cs[0] if len(cs) == 1 else self._const_node("mul", cs)
        if len(vs) == 1:
            self.instrs.append(("scale", out, (vs[0],), cslot))
            return
        cur = vs[0]
        for i, v in enumerate(vs[1:]):
            last = i == len(vs) - 2
            dst = out if (last and cslot is None) else self._new_slot(False)
            self._emit_mul(dst, cur, v)
            cur = dst
        if cslot is not None:
            self.instrs.append(("scale", out, (cur,), cslot))

    def _lower_div(self, out, args):
        """A quotient: by a constant, a scale by its inverse; of a constant, ``rdiv``; else ``div``."""
        a, b = args
        ca, cb = self.is_const[a], self.is_const[b]
        if cb:
            inv = self._const_node("div", (self._one_slot(), b))
            self.instrs.append(("scale", out, (a,), inv))
        elif ca:
            self.instrs.append(("rdiv", out, (b,), a))
        else:
            self.instrs.append(("div", out, (a, b), None))

    def _lower_powi(self, out, a, n):
        """An integer power by squaring and multiplying (the bits of n after the leading one)."""
        bits = bin(n)[3:]
        cur = a
        for i, bit in enumerate(bits):
            last = i == len(bits) - 1
            dst = out if (last and bit == "0") else self._new_slot(False)
            self.instrs.append(("sqr", dst, (cur,), None))
            cur = dst
            if bit == "1":
                dst = out if last else self._new_slot(False)
                self._emit_mul(dst, cur, a)
                cur = dst

    def _lower_sincos(self, op, out, arg):
        """sin / cos (sinh / cosh) of one argument computed together: the second one asked for is an alias."""
        hyp = op in ("sinh", "cosh")
        key = ("sinhcosh" if hyp else "sincos", arg)
        if key in self._paired:
            self.alias[out] = self._paired[key][op]
            return
        other = self._new_slot(False)
        if op in ("sin", "sinh"):
            s_slot, c_slot = out, other
        else:
            s_slot, c_slot = other, out
        names = ("sinh", "cosh") if hyp else ("sin", "cos")
        self._paired[key] = {names[0]: s_slot, names[1]: c_slot}
        self.instrs.append((key[0], (s_slot, c_slot), (arg,), None))

    def constant_values(self, pars_raw, prec):
        base = self.program.constant_slots(pars_raw, prec)
        vals = list(base) + [None] * (self.nslots - len(base))
        for slot, c in self.consts:
            vals[slot] = c.raw(prec)
        eval_nodes(self.const_nodes, vals, prec)
        return vals


_PLANS = weakref.WeakKeyDictionary()  # program -> its jet plan (built once; a race builds it twice, harmlessly)


def jet_plan(program):
    """The jet instructions of a :class:`Program` (built once per program, kept while the program lives)."""
    plan = _PLANS.get(program)
    if plan is None:
        plan = _PLANS[program] = _Plan(program)
    return plan


def resolve_program(program_or_system, name="program_or_system"):
    """A :class:`Program` from a Program or a heyoka-style system, checked to have one output per variable."""
    return _resolve_program(program_or_system, name)


def _resolve_program(program_or_system, name="program_or_system"):
    if isinstance(program_or_system, Program):
        prog = program_or_system
    else:
        try:
            pairs = list(program_or_system)
            variables = [p[0] for p in pairs]
            rhs = [p[1] for p in pairs]
            if any(len(p) != 2 for p in pairs):
                raise TypeError
        except TypeError:
            raise TypeError(
                f"`{name}` must be a Program (compile_system) or a heyoka-style system: "
                "a list of (variable, rhs) pairs"
            ) from None
        prog = _expr.compile_system(variables, rhs)
    if prog.nout != prog.nvars:
        raise ValueError(
            f"`{name}` must compute one right-hand side per variable; the program has "
            f"{prog.nvars} variables and {prog.nout} outputs"
        )
    return prog


