"""Taylor-mode jets in fixed-point big integers (the fast path of the Lie-series step).

The same recurrences as :mod:`lieseries.lie.jets`, run over the same jet plan, but every coefficient is an integer
``M`` standing for ``M * 2**u`` with one binary exponent ``u`` per jet (per node of the vector field), and time is
normalised by a power of two ``sigma = 2**s``: the integers hold ``C_k = c_k * sigma**k``.  A Cauchy product is then
one exact integer dot product and one rounding shift, with no per-term exponent alignment.

Scaling (why fixed point loses nothing)
---------------------------------------
* Each jet's exponent is set at order 0 from the magnitude it will carry: ``e = max(e(f(a_0)), e(f'(a_0)) + e_a)``
  (the value, and the first-order change that the argument's scale ``e_a`` drives), and ``u = e - F`` with ``F``
  the working bits (precision + :func:`~lieseries.lie.jets.jet_guard_bits`).  A state variable takes the exponent
  of its own value (a zero one the smallest exponent of the non-zero ones), so states of size 1e6 or 1e-6 and
  parameters of any size keep ``F`` bits relative to their own scale.  Sums are exact (finest exponent); every
  other result is rounded once to half a unit.
* The integers hold ``c_k sigma**k`` to ``F`` bits relative to the state's scale, i.e. each ``c_k`` with the
  absolute accuracy that a step of at most ``sigma`` needs: a Lie step ``h <= sigma`` multiplies the error of
  ``c_k`` by ``h**k``, so every term of the step's sum is known to ``F`` bits of the state.  :class:`FixedStepper`
  takes ``sigma`` two to four times the last step (and below the radius of convergence), and ``lie_integrate``
  never steps beyond it: the high orders, which a step multiplies by ``(h / rho)**k``, then carry
  correspondingly fewer bits, which is where fixed point saves work over floating point.
* Rounding: sums and products are exact, and every stored coefficient is rounded once (half a unit); the error
  a coefficient inherits through the recurrences grows with the order and the depth of the expression by a
  factor of a few powers of two, well inside the :func:`~lieseries.lie.jets.jet_guard_bits` the working
  precision carries (tests/test_fixed_jets.py checks every instruction against the mpf jets at twice the digits).

Execution
---------
Order 0 runs the step functions of the plan's instructions, which fix every exponent, shift and constant; the
orders k >= 1 run as one generated Python function (:func:`_order_loop`, cached per structure) that writes the
sums of products and the packed dot products out over local variables and calls the other steps.  Products
sharing an operand are packed into one dot product up to :data:`_GMP_GROUP_BITS` (gmpy2) or
:data:`_INT_GROUP_BITS` (Python ints) working bits, and computed separately, each once per order, above.

Big integers are gmpy2's ``mpz`` when gmpy2 imports, Python ``int`` otherwise; the environment variable
``LIESERIES_BIGINT=int`` (or :func:`set_backend`) forces Python ints.
"""

from __future__ import annotations

import math
import os
import weakref
from operator import add as _add
from operator import mul as _mul
from time import perf_counter as _clock

import numpy as np
from mpmath.libmp import (
    fone,
    fzero,
    from_man_exp,
    mpf_add,
    mpf_cos_sin,
    mpf_cosh_sinh,
    mpf_div,
    mpf_mul,
    mpf_sub,
)

from .. import expr as _expr
from ..expr import POINTWISE, RND
from ..precision import check_dps, check_order, dps_to_bits, mp_context
from ..precision import thread_mp as mp
from .jets import DeadlineExceeded, jet_guard_bits, jet_plan, radius_from_logs, resolve_program

__all__ = ["backend", "set_backend", "fixed_taylor_coefficients", "FixedStepper", "FixedJets"]

try:  # pragma: no cover - depends on the installation
    from gmpy2 import bit_length as _gmpy_bit_length
    from gmpy2 import mpz as _mpz
except ImportError:  # pragma: no cover
    _mpz = _gmpy_bit_length = None

_Z = int


def _bitlen(x):
    return x.bit_length()


def set_backend(name=None):
    """Choose the big integers: ``"gmpy"`` (gmpy2's mpz), ``"int"`` (Python ints) or None (gmpy2 when it imports,
    unless the environment variable ``LIESERIES_BIGINT`` is ``int``).  Returns the backend now in use."""
    global _Z
    if name is None:
        name = "int" if os.environ.get("LIESERIES_BIGINT", "").strip().lower() == "int" else "gmpy"
    if name not in ("gmpy", "int"):
        raise ValueError(f"`name` must be 'gmpy', 'int' or None; got {name!r}")
    global _bitlen
    _Z = _mpz if (name == "gmpy" and _mpz is not None) else int
    _bitlen = _gmpy_bit_length if _Z is _mpz else int.bit_length
    return backend()


def backend():
    """The big integers in use: ``"gmpy"`` or ``"int"``."""
    return "int" if _Z is int else "gmpy"


set_backend()


# --------------------------------------------------------------------------
# Integer helpers
# --------------------------------------------------------------------------

def _sh(x, n):
    """round(x / 2**n) (a left shift for n <= 0)."""
    if n <= 0:
        return x << -n
    return (x + (1 << (n - 1))) >> n


def _divr(num, den, d):
    """round(num * 2**d / den), den > 0."""
    if d >= 0:
        num = num << d
    else:
        den = den << -d
    return ((num << 1) + den) // (den << 1)


def _ebits(m, u):
    """Binary exponent of m * 2**u (|x| < 2**e), None for zero."""
    return u + m.bit_length() if m else None


def _eraw(raw):
    return raw[2] + raw[3] if raw[1] else None


def _emax(*es):
    es = [e for e in es if e is not None]
    return max(es) if es else None


def _to_int(raw, u):
    """round(raw / 2**u) as a big integer."""
    s, m, e, _ = raw
    if not m:
        return _Z(0)
    m = _Z(m)
    m = _sh(m, u - e)
    return -m if s else m


def _raw(m, u, prec=None):
    if not m:
        return fzero
    return from_man_exp(m, u, prec, RND) if prec else from_man_exp(m, u)


def _dot(a, b):
    return sum(map(_mul, a, b))


#: Working precisions (bits) from which Cauchy products pair their terms (:class:`_Cauchy`): half the big-integer
#: multiplications for a few more additions, a gain once multiplications dominate.
PAIR_BITS = 300


class _Cauchy:
    """sum_{j<=k} A_j B_{k-j} at k = 0, 1, 2, ... (called for every k in turn, A and B holding k + 1 terms).

    With ``paired``, the terms j and k - j go into one product: A_j B_{k-j} + A_{k-j} B_j =
    (A_j + A_{k-j}) (B_j + B_{k-j}) - A_j B_j - A_{k-j} B_{k-j}, and the diagonal products A_j B_j, summed once
    as they arrive (S_k = sum_{j<=k} A_j B_j), account for every correction: the sum is
    sum_{j<k/2} (A_j + A_{k-j}) (B_j + B_{k-j}) - S_k + 2 A_{k/2} B_{k/2} (the last for even k), exact in
    integers with about k/2 + 2 multiplications instead of k + 1."""

    __slots__ = ("A", "B", "S", "paired")

    def __init__(self, A, B, paired):
        self.A, self.B, self.S, self.paired = A, B, 0, paired

    def reset(self, B, k):
        """Use B from now on (the partners repacked) with its diagonal sum through k - 1."""
        self.B = B
        A = self.A
        self.S = sum(map(_mul, A[:k], B[:k]))

    def __call__(self, k):
        A, B = self.A, self.B
        if not self.paired:
            return sum(map(_mul, A, reversed(B)))
        self.S += A[k] * B[k]
        h = (k + 1) >> 1
        v = sum(map(_mul, map(_add, A[:h], A[k:k - h:-1]), map(_add, B[:h], B[k:k - h:-1]))) - self.S
        if not k & 1:
            v += (A[h] * B[h]) << 1
        return v


# --------------------------------------------------------------------------
# Step builders: each returns step(k) appending coefficient k of its jet(s)
# --------------------------------------------------------------------------

class _Once:
    """f(k) computed once for each k (f called for k = 0, 1, 2, ... in turn)."""

    __slots__ = ("f", "k", "v")

    def __init__(self, f):
        self.f, self.k, self.v = f, -1, None

    def __call__(self, k):
        if k != self.k:
            self.k, self.v = k, self.f(k)
        return self.v


class _Run:
    """The state of one expansion: jets J (lists of integers), exponents U, working bits F."""

    def __init__(self, nslots, F):
        self.J = [None] * nslots
        self.U = [None] * nslots
        self.D = {}
        self.F = F
        self.products = {}

    def product(self, a, b):
        """sum_{j<=k} a_j b_{k-j} as a function of k (:class:`_Cauchy`), one per pair of slots: a product that
        several sum-of-products steps read is computed once per order."""
        key = (a, b) if a <= b else (b, a)
        f = self.products.get(key)
        if f is None:
            f = self.products[key] = _Once(_Cauchy(self.J[a], self.J[b], self.F >= PAIR_BITS))
        return f

    def dj(self, s):
        """The jet j * a_j of slot s (extended on demand)."""
        d = self.D.get(s)
        if d is None:
            d = self.D[s] = []
        return d


def _ext(a, da, k):
    for j in range(len(da), k + 1):
        da.append(a[j] * j)


def _fn_exp(run, slot, *cands):
    """Exponent of a jet from candidate magnitudes (None ignored); u = e - F."""
    e = _emax(*cands)
    if e is None:
        e = run.U[slot] + run.F if run.U[slot] is not None else 0
    return e - run.F


def _mk_lin(run, out, vterms, offset):
    J, U = run.J, run.U
    c = J[out]
    shifts = []
    off = [0]

    def step(k):
        if k == 0:
            u = min(U[a] for a, _ in vterms)
            U[out] = u
            shifts.extend((J[a], U[a] - u, ng) for a, ng in vterms)
            off[0] = _to_int(offset, u) if offset is not None else 0
        r = 0
        for a, d, ng in shifts:
            x = a[k] << d if d else a[k]
            r = r - x if ng else r + x
        if k == 0:
            r += off[0]
        c.append(r)
    return step


def _mk_scale(run, out, a, craw):
    J, U = run.J, run.U
    A, C = J[a], J[out]
    s, m, e, bc = craw
    cm = -_Z(m) if s else _Z(m)

    def step(k):
        if k == 0:
            U[out] = U[a] + (e + bc if m else 0)
        C.append(_sh(A[k] * cm, bc) if m else _Z(0))
    return step


def _mk_mul(run, out, a, b):
    J, U, F = run.J, run.U, run.F
    A, B, C = J[a], J[b], J[out]
    dot = _Cauchy(A, B, F >= PAIR_BITS)

    def step(k):
        if k == 0:
            U[out] = U[a] + U[b] + F
        C.append(_sh(dot(k), F))
    return step


def _mk_sop(run, out, prods, lins, offset, state=None):
    """out = sum of ±c (a * b) product terms and ±c x linear terms (c a raw constant or None) plus an offset:
    all terms exact at their finest exponent, one rounding (a lin whose terms' products were fused into it).
    With ``state`` = i (out is the right-hand side of state variable i and used nowhere else) the step appends
    the state's next coefficient sigma out_k / (k + 1) instead, with the same single rounding."""
    J, U, F = run.J, run.U, run.F
    C = J[out]
    nxt = run.nxt
    terms = []
    st = {}

    def const(c):
        if c is None:
            return 1, 0, 0
        cs, cm, ce, cbc = c
        return (-_Z(cm) if cs else _Z(cm)), ce, cbc

    def step(k):
        if k == 0:
            xs, noms = [], []
            raw_terms = []
            for a, b, c, ng, key in prods:
                cm, ce, cbc = const(c)
                if not cm:
                    continue
                x = U[a] + U[b] + ce
                xs.append(x)
                noms.append(x + F + cbc)
                raw_terms.append((J[a], run.product(a, b) if key is None else key,
                                  -cm if ng else cm, x))
            for a, c, ng in lins:
                cm, ce, cbc = const(c)
                if not cm:
                    continue
                x = U[a] + ce
                xs.append(x)
                noms.append(x + cbc)
                raw_terms.append((J[a], None, -cm if ng else cm, x))
            if not xs:
                xs = noms = [min(U[a] for a, *_ in list(prods) + list(lins))]
            x0 = min(xs)
            uo = min(noms)
            U[out] = uo
            for A, B, cm, x in raw_terms:
                if isinstance(B, int):  # a dot product computed by a dots step
                    A, B = B, None
                terms.append((A, B, None if cm == 1 else (-1 if cm == -1 else cm), x - x0))
            st.update(fin=uo - x0 if state is None else x0 + run.s - U[state],
                      off=_to_int(offset, x0) if offset is not None else 0)
            step.terms, step.fin = terms, st["fin"]
        tot = st["off"] if k == 0 else 0
        dv = run.dv
        for A, B, cm, d in terms:
            if B is not None:
                v = B(k)
            else:
                v = dv[A] if A.__class__ is int else A[k]
            if cm is not None:
                v = -v if cm == -1 else v * cm
            tot += v << d if d else v
        if state is None:
            C.append(_sh(tot, st["fin"]))
        else:  # appended after the order's last step: every step of order k sees k + 1 state coefficients
            nxt[state] = _divr(tot, k + 1, st["fin"])
    step.kind, step.C, step.state = "sop", C, state
    return step


class _Dots:
    """Several Cauchy products sharing one operand in one dot product: the partners' coefficients are packed
    into one integer per order (fields of W bits, W above the bits any of the products can reach, checked at
    every order) and the products' k-th coefficients are read back from the fields of one sum."""

    kind = "dots"

    def __init__(self, run, pivot, partners, keys):
        self.dv = run.dv
        self.A = run.J[pivot]
        self.Bs = [run.J[b] for b in partners]
        self.rBs = self.Bs[::-1]
        self.keys = keys
        self.P = []
        self.dot = _Cauchy(self.A, self.P, run.F >= PAIR_BITS)
        self.W = self.ba = self.bb = 0
        self.mask = self.full = self.half = self.bias = 0

    def repack(self, k, need):
        """Widen the fields to hold ``need`` bits: the packed partners of orders < k again; the new
        (W, mask, full, half)."""
        W = self.W = need + 32
        self.full, self.half = 1 << W, 1 << (W - 1)
        self.mask = self.full - 1
        # half a field added to every field but the top one makes them all non-negative (no borrows between
        # fields): field m of D + bias, less half, is the m-th sum of products, and what lies above the last but
        # one field is the last (the order loop's way of reading them)
        self.bias = sum(self.half << (m * W) for m in range(len(self.Bs) - 1))
        P = self.P
        P[:] = []
        for j in range(k):
            v = 0
            for B in self.rBs:
                v = (v << W) + B[j]
            P.append(v)
        self.dot.reset(P, k)
        return W, self.mask, self.half, self.bias

    def __call__(self, k):
        x = self.A[k].bit_length()
        if x > self.ba:
            self.ba = x
        x = max(map(_bitlen, [B[k] for B in self.Bs]))
        if x > self.bb:
            self.bb = x
        need = self.ba + self.bb + (k + 1).bit_length() + 2
        if need > self.W:
            self.repack(k, need)
        W = self.W
        v = 0
        for B in self.rBs:
            v = (v << W) + B[k]
        self.P.append(v)
        D = self.dot(k)
        mask, full, half, dv = self.mask, self.full, self.half, self.dv
        for key in self.keys:
            r = D & mask
            if r >= half:
                r -= full
            dv[key] = r
            D = (D - r) >> W


def _cprod(cv, slots):
    """The exact product of constant slots (None for none)."""
    if not slots:
        return None
    r = cv[slots[0]]
    for x in slots[1:]:
        r = mpf_mul(r, cv[x])
    return r


def _arg_slots(ins):
    """The slots an instruction reads."""
    kind, out, args, extra = ins
    if kind == "lin":
        return [x for x, _ in args]
    if kind == "sop":
        return [x for a, b, *_ in args[0] for x in (a, b)] + [a for a, *_ in args[1]]
    if kind == "dots":
        return [args[0], *args[1]]
    return list(args)


def _use_counts(instrs, outputs) -> dict:
    """How many times each slot is read: by the instructions, and once more for each output."""
    used = {}
    for ins in instrs:
        for x in _arg_slots(ins):
            used[x] = used.get(x, 0) + 1
    for o in outputs:
        used[o] = used.get(o, 0) + 1
    return used


#: Working precisions (bits) up to which products sharing an operand are packed into one dot product
#: (:func:`_group`), with Python ints and with gmpy2: above them a packed product, half of whose bits are the
#: fields' headroom, costs more than the separate products it replaces (gmpy2: 1.7 against 1.3 us per term
#: at 800 bits, 18 against 10 at 3500 bits, 7 partners).
_INT_GROUP_BITS = 400
_GMP_GROUP_BITS = 1000


def _group(instrs, enabled=True):
    """Insert ``dots`` steps: the products of the ``sop`` steps that share an operand, computed together at the
    first step that needs one of them (when both operands are computed by then); none when not ``enabled``."""
    pos = {}
    for i, ins in enumerate(instrs):
        outs = ins[1] if isinstance(ins[1], tuple) else (ins[1],)
        for o in outs:
            pos[o] = i
    count = {}
    prods = []  # (consumer index, term index, a, b)
    for i, ins in enumerate(instrs):
        if ins[0] == "sop":
            for t, (a, b, c, ng) in enumerate(ins[2][0]):
                prods.append((i, t, a, b))
                for x in {a, b}:
                    count[x] = count.get(x, 0) + 1
    groups = {}
    for i, t, a, b in (prods if enabled else ()):
        pv, pt = (a, b) if (count[a], -a) >= (count[b], -b) else (b, a)
        groups.setdefault(pv, []).append((i, t, pt))
    at = {}  # instruction index -> dots steps to run before it
    keyed = {}
    nkeys = 0
    for pv, members in groups.items():
        P = min(i for i, _, _ in members)
        ready = [m for m in members if pos.get(pv, -1) < P and pos.get(m[2], -1) < P]
        partners = list(dict.fromkeys(m[2] for m in ready))  # a product used twice is computed once
        if len(partners) < 2:
            continue
        keys = tuple(range(nkeys, nkeys + len(partners)))
        nkeys += len(partners)
        key_of = dict(zip(partners, keys))
        for i, t, pt in ready:
            keyed[(i, t)] = key_of[pt]
        at.setdefault(P, []).append(("dots", None, (pv, tuple(partners)), keys))
    out = []
    for i, ins in enumerate(instrs):
        out.extend(at.get(i, ()))
        if ins[0] == "sop":
            prods_i = tuple((a, b, c, ng, keyed.get((i, t))) for t, (a, b, c, ng) in enumerate(ins[2][0]))
            ins = ("sop", ins[1], (prods_i, ins[2][1]), ins[3])
        out.append(ins)
    return out, nkeys


_FUSED = weakref.WeakKeyDictionary()  # jet plan -> its fused instructions


def _fuse(plan):
    """The plan's instructions with every lin whose terms are single-use products (possibly scaled by a
    constant) or scaled slots turned into one ``sop`` instruction."""
    uses = {}

    def use(x):
        uses[x] = uses.get(x, 0) + 1

    for kind, out, args, extra in plan.instrs:
        if kind == "lin":
            for x, _ in args:
                use(x)
        else:
            for x in args:
                use(x)
    for o in plan.outputs:
        use(o)
    producer = {}
    for ins in plan.instrs:
        kind, out = ins[0], ins[1]
        if kind in ("mul", "sqr", "scale"):
            producer[out] = ins
    fused = set()
    new = []

    def unscale(a, b, cs, ng):
        """A product term with scaled operands (c y) written as c (y * ...)."""
        ops = []
        for x in (a, b):
            p = producer.get(x)
            while p is not None and p[0] == "scale":
                cs = cs + (p[3],)
                x = p[2][0]
                p = producer.get(x)
            ops.append(x)
        return ops[0], ops[1], cs, ng

    for ins in plan.instrs:
        kind, out, args, extra = ins
        if kind != "lin":
            new.append(ins)
            continue
        prods, lins = [], []
        for v, ng in args:
            p = producer.get(v) if uses.get(v) == 1 else None
            if p is not None and p[0] == "scale":
                inner = producer.get(p[2][0]) if uses.get(p[2][0]) == 1 else None
                if inner is not None and inner[0] in ("mul", "sqr"):
                    fused.update((v, inner[1]))
                    a = inner[2][0]
                    b = inner[2][1] if inner[0] == "mul" else a
                    prods.append(unscale(a, b, (p[3],), ng))
                else:
                    fused.add(v)
                    lins.append((p[2][0], (p[3],), ng))
            elif p is not None and p[0] in ("mul", "sqr"):
                fused.add(v)
                a = p[2][0]
                b = p[2][1] if p[0] == "mul" else a
                prods.append(unscale(a, b, (), ng))
            else:
                lins.append((v, (), ng))
        new.append(("sop", out, (tuple(prods), tuple(lins)), extra))
    new = [ins for ins in new if ins[1] not in fused or ins[0] == "sop"]
    # scalings whose every use moved into products are dropped
    while True:
        used = _use_counts(new, plan.outputs)
        keep = [ins for ins in new if ins[0] != "scale" or used.get(ins[1])]
        if len(keep) == len(new):
            return new
        new = keep


def _sqr_sum(A, k):
    h = (k + 1) >> 1
    r = _dot(A[:h], A[k:k - h:-1]) << 1 if h else 0
    if not k & 1:
        x = A[k >> 1]
        r += x * x
    return r


def _mk_sqr(run, out, a):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]

    def step(k):
        if k == 0:
            U[out] = 2 * U[a] + F
        C.append(_sh(_sqr_sum(A, k), F))
    return step


def _mk_div(run, out, a, b, wp, cnum=None):
    """out = a / b, or cnum / b (cnum a raw constant) when a is None."""
    J, U, F = run.J, run.U, run.F
    A = J[a] if a is not None else None
    B, C = J[b], J[out]
    st = {}

    def step(k):
        if k == 0:
            B0, ub = B[0], U[b]
            if not B0:
                raise ZeroDivisionError("a division by a series with zero constant term")
            b0 = _raw(B0, ub)
            eb0 = _ebits(B0, ub)
            if A is not None:
                a0 = _raw(A[0], U[a])
                ea = U[a] + F
                e0 = _eraw(a0)
                cands = (ea - eb0, None if e0 is None else e0 + ub + F - 2 * eb0)
            else:
                a0 = cnum
                e0 = _eraw(cnum)
                cands = (None,) if e0 is None else (e0 - eb0, e0 + ub + F - 2 * eb0)
            uc = _fn_exp(run, b, *cands)
            U[out] = uc
            C.append(_to_int(mpf_div(a0, b0, wp, RND), uc))
            us = ub + uc
            if A is not None:
                ucom = min(U[a], us)
                st.update(da=U[a] - ucom, ds=us - ucom, d=ucom - ub - uc)
            else:
                st.update(da=0, ds=0, d=us - ub - uc)
            st["B0"] = B0 if B0 > 0 else -B0
            st["sg"] = B0 < 0
            return
        num = -(_dot(B[1:k + 1], C[k - 1::-1]) << st["ds"])
        if A is not None:
            num += A[k] << st["da"]
        if st["sg"]:
            num = -num
        C.append(_divr(num, st["B0"], st["d"]))
    return step


def _mk_pow(run, out, a, ex, data, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    DA, DC = run.dj(a), run.dj(out)
    es, em, ee, ebc = ex
    pm = -_Z(em) if es else _Z(em)
    st = {}

    def step(k):
        if k == 0:
            if not A[0]:
                raise ZeroDivisionError("a non-integer power of a series with zero constant term")
            a0 = _raw(A[0], U[a])
            c0 = POINTWISE["pow"]([a0, ex], data, wp)
            e0 = _eraw(c0)
            ep = _eraw(ex)
            uc = _fn_exp(run, a, e0, None if (e0 is None or ep is None) else ep + e0 - _eraw(a0) + U[a] + F)
            U[out] = uc
            C.append(_to_int(c0, uc))
            # num = p S1 - S2 at exponent ua + uc + min(ee, 0); p S1 has ee, S2 has 0
            pe = min(ee, 0)
            st.update(p=pm << (ee - pe), s2=-pe, d=pe, A0=A[0] if A[0] > 0 else -A[0], sg=A[0] < 0)
            return
        _ext(A, DA, k)
        _ext(C, DC, k - 1)
        s1 = _dot(C[0:k], DA[k:0:-1])
        s2 = _dot(DC[1:k], A[k - 1:0:-1])
        num = st["p"] * s1 - (s2 << st["s2"])
        if st["sg"]:
            num = -num
        C.append(_divr(num, st["A0"] * k, st["d"]))
    return step


def _mk_sqrt(run, out, a, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    st = {}

    def step(k):
        if k == 0:
            if not A[0]:
                raise ZeroDivisionError("sqrt of a series with zero constant term")
            c0 = POINTWISE["sqrt"]([_raw(A[0], U[a])], None, wp)
            e0 = _eraw(c0)
            uc = _fn_exp(run, a, e0, U[a] + F - e0 - 1)
            U[out] = uc
            C0 = _to_int(c0, uc)
            C.append(C0)
            ucom = min(U[a], 2 * uc)
            st.update(da=U[a] - ucom, ds=2 * uc - ucom, d=ucom - 2 * uc, den=2 * C0)
            return
        h = (k - 1) >> 1
        s = _dot(C[1:h + 1], C[k - 1:k - h - 1:-1]) << 1 if h else 0
        if not k & 1:
            x = C[k >> 1]
            s += x * x
        num = (A[k] << st["da"]) - (s << st["ds"])
        C.append(_divr(num, st["den"], st["d"]))
    return step


def _mk_exp(run, out, a, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    DA = run.dj(a)

    def step(k):
        if k == 0:
            c0 = POINTWISE["exp"]([_raw(A[0], U[a])], None, wp)
            e0 = _eraw(c0)
            uc = _fn_exp(run, a, e0, None if e0 is None else e0 + U[a] + F)
            U[out] = uc
            C.append(_to_int(c0, uc))
            return
        _ext(A, DA, k)
        C.append(_divr(_dot(DA[1:k + 1], C[k - 1::-1]), k, U[a]))
    return step


def _mk_log(run, out, a, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    DA, DC = run.dj(a), run.dj(out)
    st = {}

    def step(k):
        if k == 0:
            if not A[0]:
                raise ZeroDivisionError("log of a series with zero constant term")
            a0 = _raw(A[0], U[a])
            c0 = POINTWISE["log"]([a0], None, wp)
            uc = _fn_exp(run, a, _eraw(c0), U[a] + F - _eraw(a0))
            U[out] = uc
            C.append(_to_int(c0, uc))
            ucom = min(U[a], uc + U[a])
            st.update(da=U[a] - ucom, ds=uc + U[a] - ucom, d=ucom - U[a] - uc,
                      A0=A[0] if A[0] > 0 else -A[0], sg=A[0] < 0)
            return
        _ext(A, DA, k)
        _ext(C, DC, k - 1)
        num = (DA[k] << st["da"]) - (_dot(DC[1:k], A[k - 1:0:-1]) << st["ds"])
        if st["sg"]:
            num = -num
        C.append(_divr(num, st["A0"] * k, st["d"]))
    return step


def _mk_sincos(run, so, co, a, wp, hyperbolic):
    J, U, F = run.J, run.U, run.F
    A, S, C = J[a], J[so], J[co]
    DA = run.dj(a)
    st = {}

    def step(k):
        if k == 0:
            a0 = _raw(A[0], U[a])
            c0, s0 = (mpf_cosh_sinh if hyperbolic else mpf_cos_sin)(a0, wp, RND)
            ea = U[a] + F
            es0, ec0 = _eraw(s0), _eraw(c0)
            us = _fn_exp(run, a, es0, None if ec0 is None else ec0 + ea)
            uc = _fn_exp(run, a, ec0, None if es0 is None else es0 + ea)
            U[so], U[co] = us, uc
            S.append(_to_int(s0, us))
            C.append(_to_int(c0, uc))
            st.update(ds=U[a] + uc - us, dc=U[a] + us - uc)
            return
        _ext(A, DA, k)
        d = DA[1:k + 1]
        ss = _dot(d, C[k - 1::-1])
        sc = _dot(d, S[k - 1::-1])
        if not hyperbolic:
            sc = -sc
        S.append(_divr(ss, k, st["ds"]))
        C.append(_divr(sc, k, st["dc"]))
    return step


def _mk_tan(run, out, aux, a, wp, hyperbolic):
    """out = tan(a) (tanh), aux = 1 + out^2 (1 - out^2)."""
    J, U, F = run.J, run.U, run.F
    A, T, W = J[a], J[out], J[aux]
    DA = run.dj(a)
    st = {}

    def step(k):
        if k == 0:
            a0 = _raw(A[0], U[a])
            t0 = POINTWISE["tanh" if hyperbolic else "tan"]([a0], None, wp)
            t2 = mpf_mul(t0, t0)
            w0 = mpf_sub(fone, t2, wp, RND) if hyperbolic else mpf_add(fone, t2, wp, RND)
            ew0 = _eraw(w0)
            ut = _fn_exp(run, a, _eraw(t0), None if ew0 is None else ew0 + U[a] + F)
            uw = _fn_exp(run, a, ew0, 2 * (ut + F))
            U[out], U[aux] = ut, uw
            T.append(_to_int(t0, ut))
            W.append(_to_int(w0, uw))
            st.update(dt=U[a] + uw - ut, dw=uw - 2 * ut)
            return
        _ext(A, DA, k)
        T.append(_divr(_dot(DA[1:k + 1], W[k - 1::-1]), k, st["dt"]))
        w = _sh(_sqr_sum(T, k), st["dw"])
        W.append(-w if hyperbolic else w)
    return step


def _mk_atan(run, out, aux, a, wp):
    """out = atan(a), aux = 1 + a^2."""
    J, U, F = run.J, run.U, run.F
    A, C, W = J[a], J[out], J[aux]
    DA, DC = run.dj(a), run.dj(out)
    st = {}

    def step(k):
        if k == 0:
            a0 = _raw(A[0], U[a])
            w0 = mpf_add(fone, mpf_mul(a0, a0), wp, RND)
            c0 = POINTWISE["atan"]([a0], None, wp)
            ea, ew0 = U[a] + F, _eraw(w0)
            uw = _fn_exp(run, a, ew0, 2 * ea)
            uc = _fn_exp(run, a, _eraw(c0), ea - ew0)
            U[out], U[aux] = uc, uw
            C.append(_to_int(c0, uc))
            W0 = _to_int(w0, uw)
            W.append(W0)
            ucom = min(U[a], uc + uw)
            st.update(dw=uw - 2 * U[a], da=U[a] - ucom, ds=uc + uw - ucom, d=ucom - uw - uc, W0=W0)
            return
        W.append(_sh(_sqr_sum(A, k), st["dw"]))
        _ext(A, DA, k)
        _ext(C, DC, k - 1)
        num = (DA[k] << st["da"]) - (_dot(DC[1:k], W[k - 1:0:-1]) << st["ds"])
        C.append(_divr(num, st["W0"] * k, st["d"]))
    return step


# --------------------------------------------------------------------------
# The expansion
# --------------------------------------------------------------------------

def _state_exponents(y0_raw):
    es = [_eraw(r) for r in y0_raw]
    nz = [e for e in es if e is not None]
    fallback = min(nz) if nz else 0
    return [fallback if e is None else e for e in es]


# --------------------------------------------------------------------------
# The orders k >= 1 as one generated function
# --------------------------------------------------------------------------

_LOOPS = {}  # the structure of an expansion's orders -> its generated function


def _order_loop(steps, deferred, rest):
    """(run, env): ``run(k0, order, deadline, env)`` computes the orders k0..order-1 of an expansion whose order 0
    the steps have computed (it fixed every exponent, shift and constant).  The ``sop`` and ``dots`` steps are
    written out as straight-line Python over local variables (the same integer operations as their step
    functions, without their per-term loops and lookups), the other steps are called; the function is generated
    once per structure (the instructions and which constant factors are -1, 1 or other) and cached."""
    sig, names, env = [], [], []

    def bind(name, value):
        names.append(name)
        env.append(value)

    for j, st in enumerate(steps):
        kind = getattr(st, "kind", None)
        if kind == "dots":
            bind(f"o{j}", st)
            bind(f"a{j}", st.A)
            bind(f"p{j}", st.P)
            for m, B in enumerate(st.Bs):
                bind(f"b{j}_{m}", B)
            paired = st.dot.paired
            if paired:
                bind(f"c{j}", st.dot)
            sig.append(("d", len(st.Bs), paired, tuple(st.keys)))
        elif kind == "sop":
            tsig = []
            for m, (A, B, cm, d) in enumerate(st.terms):
                if B is not None:
                    src = "call"
                    bind(f"t{j}_{m}", B)
                elif A.__class__ is int:
                    src = A  # a dot product's key
                else:
                    src = "jet"
                    bind(f"t{j}_{m}", A)
                if cm is not None and cm != -1:
                    bind(f"cm{j}_{m}", cm)
                bind(f"d{j}_{m}", d)
                # (cm depends on the constants only; the shifts and the final rounding's direction depend on the
                # state's exponents and are variables, so that one function serves every step)
                tsig.append((src, None if cm is None else (-1 if cm == -1 else 0)))
            fin = st.fin
            if st.state is None:
                bind(f"C{j}", st.C)
                bind(f"fin{j}", max(fin, 0))
                bind(f"hf{j}", 1 << (fin - 1) if fin > 0 else 0)
            else:
                bind(f"fin{j}", fin + 1 if fin >= 0 else 0)
            bind(f"fp{j}", fin > 0 if st.state is None else fin >= 0)
            bind(f"nf{j}", max(-fin, 0))
            sig.append(("s", st.state, tuple(tsig)))
        else:
            bind(f"g{j}", st)
            sig.append(("g",))
    for zi, i in deferred:
        bind(f"z{i}", zi)
    if rest is not None:
        bind("rest", rest)
    key = (tuple(sig), tuple(i for _, i in deferred), rest is not None)
    fn = _LOOPS.get(key)
    if fn is None:
        if len(_LOOPS) >= 256:  # a process that meets many systems: start again
            _LOOPS.clear()
        fn = _LOOPS[key] = _generate(key, names)
    return fn, env


def _generate(key, names):
    sig, deferred, rest = key
    head = ["def run(k0, order, deadline, env):", f"    ({', '.join(names)},) = env"]
    body = []
    for j, st in enumerate(sig):
        if st[0] == "dots" or st[0] == "d":
            _, n, paired, keys = st
            head.append(f"    W{j}, mask{j}, half{j}, bias{j}, ba{j}, bb{j} = o{j}.W, o{j}.mask, o{j}.half, o{j}.bias, "
                        f"o{j}.ba, o{j}.bb")
            body += [f"x = a{j}[k].bit_length()",
                     f"if x > ba{j}: ba{j} = x",
                     f"x = max({', '.join(f'b{j}_{m}[k].bit_length()' for m in range(n))})" if n > 1 else
                     f"x = b{j}_0[k].bit_length()",
                     f"if x > bb{j}: bb{j} = x",
                     f"need = ba{j} + bb{j} + k1.bit_length() + 2",
                     f"if need > W{j}: W{j}, mask{j}, half{j}, bias{j} = o{j}.repack(k, need)"]
            e = f"b{j}_{n - 1}[k]"
            for m in range(n - 2, -1, -1):
                e = f"(({e}) << W{j}) + b{j}_{m}[k]"
            body.append(f"p{j}.append({e})")
            body.append(f"D = c{j}(k)" if paired else f"D = sum(map(_mul, a{j}, reversed(p{j})))")
            if n == 1:
                body.append(f"dv{keys[0]} = D")
            else:  # the fields of D + bias (_Dots.repack)
                at = ["E", f"(E >> W{j})"] + [f"(E >> {m} * W{j})" for m in range(2, n)]
                body.append(f"E = D + bias{j}")
                body += [f"dv{key_} = ({e} & mask{j}) - half{j}" for key_, e in zip(keys[:-1], at)]
                body.append(f"dv{keys[-1]} = E >> " + (f"W{j}" if n == 2 else f"{n - 1} * W{j}"))
        elif st[0] == "s":
            _, state, terms = st
            parts = []
            for m, (src, cm) in enumerate(terms):
                v = f"t{j}_{m}(k)" if src == "call" else (f"t{j}_{m}[k]" if src == "jet" else f"dv{src}")
                if cm == 0:
                    v = f"({v} * cm{j}_{m})"
                parts.append(("- " if cm == -1 else "+ ") + f"({v} << d{j}_{m})")
            tot = " ".join(parts)
            tot = tot[2:] if tot.startswith("+ ") else "-" + tot[2:]
            body.append(f"tot = {tot}")
            if state is None:  # round(tot / 2**fin)
                body += [f"if fp{j}: C{j}.append((tot + hf{j}) >> fin{j})", f"else: C{j}.append(tot << nf{j})"]
            else:  # round(tot 2**fin / (k + 1))
                body += [f"if fp{j}: nx{state} = ((tot << fin{j}) + k1) // k2",
                         f"else: dd = k1 << nf{j}; nx{state} = ((tot << 1) + dd) // (dd << 1)"]
        else:
            body.append(f"g{j}(k)")
    body += [f"z{i}.append(nx{i})" for i in deferred]
    if rest:
        body.append("rest(k)")
    src = "\n".join(head + ["    for k in range(k0, order):",
                             "        if deadline is not None and _clock() > deadline:",
                             "            raise DeadlineExceeded(k)",
                             "        k1 = k + 1",
                             "        k2 = k1 << 1"] + ["        " + line for line in body]) + "\n"
    scope = {"_clock": _clock, "DeadlineExceeded": DeadlineExceeded, "_mul": _mul}
    exec(compile(src, "<lieseries.lie.fixed orders>", "exec"), scope)
    return scope["run"]


_PREPARED = weakref.WeakKeyDictionary()  # jet plan -> {(grouped, wp, parameters): prepared instructions}


def _prepared(plan, grouped, wp, pars_raw):
    """(instructions, number of dot-product keys, outputs fused into their state's step, constant values) of a
    plan at ``wp`` bits for the parameters ``pars_raw``: the fused and grouped instructions with their constants
    (offsets of lin/sop steps, the exact constant factors of their terms) evaluated, once per plan, precision and
    parameters."""
    by_plan = _PREPARED.setdefault(plan, {})
    key = (grouped, wp, tuple(pars_raw))
    got = by_plan.get(key)
    if got is not None:
        return got
    cv = plan.constant_values(pars_raw, wp)
    cache = _FUSED.setdefault(plan, {})
    fused = cache.get(grouped)
    if fused is None:
        instrs, nkeys = _group(_fuse(plan), grouped)
        uses = _use_counts(instrs, plan.outputs)
        to_state = {o: i for i, o in enumerate(plan.outputs) if uses[o] == 1}
        fused = cache[grouped] = (instrs, nkeys, to_state)
    instrs, nkeys, to_state = fused
    out = []
    for kind, o, args, extra in instrs:
        if kind in ("lin", "sop"):
            offset = None
            if extra:
                offset = fzero
                for x, ng in extra:
                    offset = (mpf_sub if ng else mpf_add)(offset, cv[x], 2 * wp, RND)
            if kind == "sop":
                args = ([(a, b, _cprod(cv, cs), ng, k) for a, b, cs, ng, k in args[0]],
                        [(a, _cprod(cv, cs), ng) for a, cs, ng in args[1]])
            extra = offset
        out.append((kind, o, args, extra))
    if len(by_plan) >= 16:  # a plan run with many parameter sets or precisions: start again
        by_plan.clear()
    got = by_plan[key] = (out, nkeys, to_state, cv)
    return got


def expand(program, y0_raw, pars_raw, order, wp, s, deadline=None):
    """Fixed-point jets of the state: (M, U) with ``c_{i,k} = M[i][k] * 2**(U[i] - s*k)``.

    ``wp`` is the working precision in bits (guard bits included), ``s`` the time scale exponent, ``deadline`` an
    optional :func:`time.perf_counter` value checked after every order (:class:`DeadlineExceeded`).
    """
    plan = jet_plan(program)
    # packed dot products pay off with Python ints up to about 100 digits, with gmpy2 up to about 300
    grouped = wp <= (_GMP_GROUP_BITS if _Z is not int else _INT_GROUP_BITS)
    instrs, nkeys, to_state, cv = _prepared(plan, grouped, wp, pars_raw)
    run = _Run(plan.nslots, wp)
    J, U = run.J, run.U
    nvars = program.nvars
    is_const = plan.is_const
    for i, e in enumerate(_state_exponents(y0_raw)):
        U[i] = e - wp
        J[i] = [_to_int(y0_raw[i], U[i])]
    for x in range(nvars, plan.nslots):
        if not is_const[x]:
            J[x] = []
    steps = []
    run.dv = [None] * nkeys
    run.nxt = [None] * nvars
    run.s = s
    for kind, out, args, extra in instrs:
        if kind == "dots":
            steps.append(_Dots(run, args[0], args[1], extra))
        elif kind == "lin":
            steps.append(_mk_lin(run, out, args, extra))
        elif kind == "sop":
            steps.append(_mk_sop(run, out, args[0], args[1], extra, to_state.get(out)))
        elif kind == "scale":
            steps.append(_mk_scale(run, out, args[0], cv[extra]))
        elif kind == "mul":
            steps.append(_mk_mul(run, out, args[0], args[1]))
        elif kind == "sqr":
            steps.append(_mk_sqr(run, out, args[0]))
        elif kind == "div":
            steps.append(_mk_div(run, out, args[0], args[1], wp))
        elif kind == "rdiv":
            steps.append(_mk_div(run, out, None, args[0], wp, cnum=cv[extra]))
        elif kind == "pow":
            e, data = extra
            steps.append(_mk_pow(run, out, args[0], cv[e], data, wp))
        elif kind == "sqrt":
            steps.append(_mk_sqrt(run, out, args[0], wp))
        elif kind == "exp":
            steps.append(_mk_exp(run, out, args[0], wp))
        elif kind == "log":
            steps.append(_mk_log(run, out, args[0], wp))
        elif kind in ("sincos", "sinhcosh"):
            steps.append(_mk_sincos(run, out[0], out[1], args[0], wp, kind == "sinhcosh"))
        elif kind in ("tan", "tanh"):
            steps.append(_mk_tan(run, out[0], out[1], args[0], wp, kind == "tanh"))
        elif kind == "atan":
            steps.append(_mk_atan(run, out[0], out[1], args[0], wp))
        else:  # pragma: no cover
            raise AssertionError(kind)
    srcs = []
    fused_out = {o for kind, o, *_ in instrs if kind == "sop" and o in to_state}
    deferred = [(J[to_state[o]], to_state[o]) for o in fused_out]
    nxt = run.nxt
    for i, o in enumerate(plan.outputs):
        if o in fused_out:
            continue
        if is_const[o]:
            srcs.append((J[i], i, None, cv[o]))
        else:
            srcs.append((J[i], i, o, None))

    def rest(k):  # the outputs not fused into their sop
        k1 = k + 1
        for zi, i, o, c in srcs:
            if o is not None:
                zi.append(_divr(J[o][k], k1, U[o] + s - U[i]))
            elif k == 0 and c[1]:
                cs, cm, ce, _ = c
                m = _divr(_Z(cm), k1, ce + s - U[i])
                zi.append(-m if cs else m)
            else:
                zi.append(_Z(0))

    if order:  # order 0 sets every jet's exponent and the constants of the later orders
        for st in steps:
            st(0)
        for zi, i in deferred:
            zi.append(nxt[i])
        rest(0)
    if order > 1:
        run_orders, env = _order_loop(steps, deferred, rest if srcs else None)
        run_orders(1, order, deadline, env)
    return [J[i] for i in range(nvars)], [U[i] for i in range(nvars)]


# --------------------------------------------------------------------------
# Results at the boundary: norms, Horner, coefficients as mpf
# --------------------------------------------------------------------------

class FixedJets:
    """One expansion: scaled integer coefficients and what a Lie step needs from them.

    ``norms`` are the max-norms of the coefficient vectors (mpf, 64 bits, rounded up; computed when first read);
    :meth:`log2_norm` (:meth:`log2_norms`), :meth:`log2_column` and :meth:`log2_scales` give magnitudes as base-2
    logarithms in floating point (what a step-size rule reads: a few digits, of numbers of any size);
    :meth:`evaluate` evaluates the polynomial at ``|t| <= 2**s`` in integers, :meth:`horner` too, as the step
    the next time scale follows; ``coefficients`` is a lazily converted sequence of
    the coefficient vectors (mpf at ``prec`` bits), for dense output and events; ``rho`` and ``log2_rho`` (set by
    :class:`FixedStepper`) are :func:`~lieseries.lie.operator.estimate_radius` of the norms and its logarithm.
    """

    def __init__(self, M, U, s, prec):
        self.M, self.U, self.s, self.prec = M, U, s, prec
        self.max_step = mp_context().ldexp(1, s)
        self.rho = None
        self.log2_rho = None
        self.stepper = None
        self._norms = None
        self._abs = None
        self.coefficients = _LazyCoefficients(M, U, s, prec)

    @property
    def norms(self):
        if self._norms is None:
            make = mp_context().make_mpf
            M, U, s = self.M, self.U, self.s
            # per order, the largest |M| of the variables sharing an exponent, then across exponents
            by_u = {}
            for Mi, ui in zip(M, U):
                by_u.setdefault(ui, []).append(list(map(abs, Mi)))
            cols = [(u, list(map(max, *ms)) if len(ms) > 1 else ms[0]) for u, ms in by_u.items()]
            nrm = []
            for k in range(len(M[0])):
                bm, bu = 0, None
                for u, col in cols:
                    m = col[k]
                    if m and (bu is None or _gt(m, u, bm, bu)):
                        bm, bu = m, u
                nrm.append(make(from_man_exp(bm, bu - s * k, 64, "u") if bu is not None else fzero))
            self._norms = nrm
        return self._norms

    def log2_norm(self, k):
        """log2 ||c_k|| (max norm), ``-inf`` for a zero vector."""
        best = -math.inf
        for Mi, ui in zip(self.M, self.U):
            m = Mi[k]
            if m:
                x = _lg(m) + ui
                if x > best:
                    best = x
        return best - self.s * k

    def _floats(self):
        """|M| as a float matrix (variables x orders), or None when an integer is beyond the double range."""
        if self._abs is None:
            try:
                self._abs = np.abs(np.array([[float(m) for m in Mi] for Mi in self.M]))
            except OverflowError:
                self._abs = False
        return self._abs if self._abs is not False else None

    def log2_norms(self, k0, k1):
        """[log2 ||c_k|| for k0 <= k < k1] (``-inf`` for zero vectors), in numpy when the integers fit in doubles."""
        a = self._floats()
        if a is None:
            return [self.log2_norm(k) for k in range(k0, k1)]
        with np.errstate(divide="ignore"):
            lg = np.log2(a[:, k0:k1]) + np.array(self.U, dtype=float)[:, None]
        return (lg.max(axis=0) - self.s * np.arange(k0, k1)).tolist()

    def log2_column(self, k):
        """log2 |c_{k,i}| of every variable i (``-inf`` for zero)."""
        sk = self.s * k
        return [_lg(Mi[k]) + (ui - sk) if Mi[k] else -math.inf for Mi, ui in zip(self.M, self.U)]

    def horner(self, t):
        """sum_k c_k t^k as mpf at ``prec`` bits (``t`` an mpf with |t| <= ``max_step``): the step to ``t``; a
        :class:`FixedStepper`'s next time scale follows this step."""
        out = self.evaluate(t)
        if self.stepper is not None:
            self.stepper.h_last = abs(t)
        return out

    def evaluate(self, t):
        """sum_k c_k t^k as mpf at ``prec`` bits (``t`` an mpf with |t| <= ``max_step``), in integers."""
        make = mp_context().make_mpf
        if abs(t) > self.max_step:
            raise RuntimeError(f"a step of {mp.nstr(t, 5)} beyond the jets' time scale {mp.nstr(self.max_step, 5)}")
        raw = t._mpf_
        sg, tm, te, _ = raw
        if not tm:
            return [make(_raw(Mi[0], ui, self.prec)) for Mi, ui in zip(self.M, self.U)]
        tm = -_Z(tm) if sg else _Z(tm)
        sh = self.s - te  # t / sigma = tm * 2**-sh
        out = []
        prec = self.prec
        for Mi, ui in zip(self.M, self.U):
            acc = Mi[-1]
            if sh > 0:
                half = 1 << (sh - 1)
                for k in range(len(Mi) - 2, -1, -1):
                    acc = ((acc * tm + half) >> sh) + Mi[k]
            else:
                for k in range(len(Mi) - 2, -1, -1):
                    acc = _sh(acc * tm, sh) + Mi[k]
            out.append(make(_raw(acc, ui, prec)))
        return out

    def _abs_horner(self, h):
        """(sum_k |M_{k,i}| (|h| / sigma)^k, U_i) for every variable i, in integers."""
        if abs(h) > self.max_step:
            raise RuntimeError(f"a step of {mp.nstr(h, 5)} beyond the jets' time scale {mp.nstr(self.max_step, 5)}")
        sg, tm, te, _ = abs(h)._mpf_
        out = []
        for Mi, ui in zip(self.M, self.U):
            if not tm:
                acc = abs(Mi[0])
            else:
                tmz, sh = _Z(tm), self.s - te
                acc = abs(Mi[-1])
                if sh > 0:
                    half = 1 << (sh - 1)
                    for k in range(len(Mi) - 2, -1, -1):
                        acc = ((acc * tmz + half) >> sh) + abs(Mi[k])
                else:
                    for k in range(len(Mi) - 2, -1, -1):
                        acc = _sh(acc * tmz, sh) + abs(Mi[k])
            out.append((acc, ui))
        return out

    def log2_scales(self, h):
        """log2 of each variable's size over a step of length ``|h| <= max_step``: max(1, sum_k |c_{k,i}| |h|^k)
        (absolute below 1), each >= 0, in floating point (the sums in numpy when the integers fit in doubles, else
        in integers)."""
        a = self._floats()
        if a is not None:
            if abs(h) > self.max_step:
                raise RuntimeError(f"a step of {mp.nstr(h, 5)} beyond the jets' time scale "
                                   f"{mp.nstr(self.max_step, 5)}")
            x = float(abs(h) / self.max_step)  # <= 1
            with np.errstate(divide="ignore", under="ignore", over="ignore"):
                lg = np.log2(a @ (x ** np.arange(a.shape[1]))) + np.array(self.U, dtype=float)
            if not (lg == np.inf).any():  # (a sum beyond the double range: in integers)
                return np.maximum(lg, 0.0).tolist()
        return [max(0.0, _lg(acc) + ui) if acc else 0.0 for acc, ui in self._abs_horner(h)]


def _lg(m):
    """log2 |m| of a nonzero big integer, in floating point."""
    b = _bitlen(m)
    if b > 1000:
        return math.log2(abs(m) >> (b - 64)) + (b - 64)
    return math.log2(abs(m))


def _gt(m1, u1, m2, u2):
    """|m1| 2**u1 > |m2| 2**u2."""
    m1, m2 = abs(m1), abs(m2)
    if u1 >= u2:
        return (m1 << (u1 - u2)) > m2
    return m1 > (m2 << (u2 - u1))


class _LazyCoefficients(list):
    """coefficients[k][i] = c_{i,k} as mpf, converted on first access (a list: what copies lists, such as
    :func:`lieseries.precision.export_mpf`, gets the converted rows)."""

    def __init__(self, M, U, s, prec):
        super().__init__()
        self._M, self._U, self._s, self._prec = M, U, s, prec
        self._built = False

    def _build(self):
        if not self._built:
            make = mp_context().make_mpf
            M, U, s, p = self._M, self._U, self._s, self._prec
            n, N = len(M), len(M[0])
            list.extend(self, [[make(_raw(M[i][k], U[i] - s * k, p)) for i in range(n)] for k in range(N)])
            self._built = True

    def __len__(self):
        return len(self._M[0])

    def __getitem__(self, k):
        self._build()
        return list.__getitem__(self, k)

    def __iter__(self):
        self._build()
        return list.__iter__(self)


# --------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------

def _estimate_radius(jets):
    """:func:`lieseries.lie.operator.estimate_radius` of the norms of ``jets``, in floating point (the radius steers
    the step and enters the error estimate as h / rho: a few digits are all it carries): (rho as mpf, log2 rho)."""
    N = len(jets.M[0]) - 1
    k0 = max(1, N // 2)
    lg = dict(zip(range(k0, N + 1), jets.log2_norms(k0, N + 1)))
    pts = [(k, x * _LN2) for k, x in lg.items() if x != -math.inf]
    if len(pts) < 2:
        lg.update((k, jets.log2_norm(k)) for k in range(1, max(1, N // 2)))
        pts = [(k, x * _LN2) for k, x in lg.items() if x != -math.inf]
    rho = radius_from_logs(pts)
    if rho == math.inf:
        return mp_context().inf, math.inf
    return mp_context().mpf(rho), (math.log2(rho) if rho > 0 else -math.inf)


_LN2 = math.log(2)


class FixedStepper:
    """Repeated expansions of one system at one order and precision (the Lie step's jets).

    ``expand(z, span)`` returns :class:`FixedJets` for the state ``z`` (mpf) with a time scale ``sigma`` (a power
    of two, ``max_step`` of the result) that the caller's step must not exceed.  Integers hold
    ``c_k sigma**k`` to a fixed number of bits relative to the state, so a coefficient carries exactly the
    absolute accuracy that a step of at most ``sigma`` needs, and no more: with ``sigma`` a few times the step
    (and below the radius of convergence) the high orders, which a step multiplies by ``(h / rho)**k``, are
    held with correspondingly fewer bits.  ``sigma`` is ``2**(ceil(log2 h) + 1)`` for the last step ``h`` that
    :meth:`FixedJets.horner` evaluated (at most the largest power of two below the last radius estimate), a
    quarter of the radius estimated by a short expansion at the first call, and at least ``span`` when the
    solution is a polynomial (an infinite radius).
    """

    def __init__(self, program, pars, order, dps):
        self.program = program
        self.order = order
        self.prec = dps_to_bits(dps)
        self.wp = self.prec + jet_guard_bits(order)
        self.pars_raw = _expr.convert_vector(pars, program.npars, self.wp, "pars")
        self.s = None
        self.h_last = None
        self.last_rho = None
        self.expansions = 0

    def expand(self, z, span, deadline=None):
        try:
            return self._expand(z, span, deadline)
        except ZeroDivisionError as exc:
            raise ValueError(
                f"the Taylor expansion does not exist at the state {[mp.nstr(v, 8) for v in z]} ({exc}; a zero "
                "denominator or a log/sqrt/non-integer power at zero)"
            ) from None

    def _expand(self, z, span, deadline):
        zr = _expr.convert_vector(z, self.program.nvars, self.wp, "z")
        if self.s is None:  # a short expansion to find the time scale
            M, U = expand(self.program, zr, self.pars_raw, min(self.order, 12), self.wp, 0, deadline)
            rho = _estimate_radius(FixedJets(M, U, 0, self.prec))[0]
            self.s = _ceil_log2(span) if rho == mp.inf else _floor_log2(rho) - 2
        elif self.h_last:
            s = _ceil_log2(self.h_last) + 1
            if self.last_rho is not None and self.last_rho != mp.inf:
                s = min(s, _floor_log2(self.last_rho))
            self.s = s
        for _ in range(3):
            M, U = expand(self.program, zr, self.pars_raw, self.order, self.wp, self.s, deadline)
            self.expansions += 1
            jets = FixedJets(M, U, self.s, self.prec)
            jets.rho, jets.log2_rho = _estimate_radius(jets)
            self.last_rho = jets.rho
            jets.stepper = self
            if jets.rho == mp.inf and span > jets.max_step:  # a polynomial: one step may reach the end
                self.s = _ceil_log2(span)
                continue
            return jets
        return jets


def _ceil_log2(x):
    m, e = mp.frexp(x)  # x = m 2**e, 1/2 <= m < 1
    return int(e) if m > 0.5 else int(e) - 1


def _floor_log2(x):
    return int(mp.frexp(x)[1]) - 1


def fixed_taylor_coefficients(program_or_system, y0, pars, order, dps, time_scale=0, ctx=None):
    """Normalised Taylor coefficients computed in fixed-point big integers.

    Same arguments as :func:`lieseries.lie.jets.taylor_coefficients`, plus ``time_scale`` = s: the computation
    holds ``c_k * 2**(s k)`` to ``dps`` digits plus guard bits relative to the scale of each variable (the size
    of its initial value), so ``c_k`` is accurate relative to ``scale * 2**(-s k)``, which is what a step of at
    most ``2**s`` needs (with ``2**s`` near the radius of convergence, every coefficient to about ``dps``
    digits).  Returns ``c[k][i]`` as mpf of ``ctx`` (the thread's context by default) at ``dps`` digits.
    """
    program = resolve_program(program_or_system)
    order = check_order(order)
    dps = check_dps(dps)
    prec = dps_to_bits(dps)
    wp = prec + jet_guard_bits(order)
    y0r = _expr.convert_vector(y0, program.nvars, wp, "y0")
    pr = _expr.convert_vector(pars, program.npars, wp, "pars")
    try:
        M, U = expand(program, y0r, pr, order, wp, int(time_scale))
    except ZeroDivisionError as exc:
        raise ValueError(
            f"the Taylor expansion does not exist at `y0` ({exc}; a zero denominator "
            "or a log/sqrt/non-integer power at zero)"
        ) from None
    make = (ctx or mp_context()).make_mpf
    s = int(time_scale)
    return [[make(_raw(M[i][k], U[i] - s * k, prec)) for i in range(program.nvars)] for k in range(order + 1)]
