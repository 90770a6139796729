"""Step builders of the fixed-point jets: for each instruction of the jet plan, step(k) appending coefficient k of
its jet(s) (:mod:`lieseries.lie.fixed`)."""

from __future__ import annotations

from mpmath.libmp import (
    fone,
    mpf_add,
    mpf_cos_sin,
    mpf_cosh_sinh,
    mpf_div,
    mpf_mul,
    mpf_sub,
)

from ..expr import POINTWISE, RND
from .bigint import PAIR_BITS, Cauchy, bit_length_function, div_round, sum_products, ebits, emax, eraw, to_raw, round_shift, sqr_sum, to_int


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


#: How much finer than F bits below its largest term an expansion given sizes may round a node (:meth:`Run.exponent`).
FINER_BITS = 64


class Run:
    """The state of one expansion: jets J (lists of integers), exponents U, working bits F, the integer type Z
    (:func:`~lieseries.lie.bigint.integer_type`, read once per expansion), and ``sizes``: None, or for every slot
    the binary exponent of the largest ``|c_k| sigma**k`` an earlier expansion measured (None where unknown), from
    which products and sums of products take a finer exponent than their operands' scales give (:meth:`exponent`).
    ``B`` holds, for the products, sums of products and scalings of an expansion given sizes, the exponent the
    scales alone give (None elsewhere: the exponent itself)."""

    def __init__(self, nslots, F, Z, sizes=None):
        self.Z = Z
        self.J = [None] * nslots
        self.U = [None] * nslots
        self.B = [None] * nslots
        self.D = {}
        self.F = F
        self.products = {}
        self.sizes = sizes
        self.order = 0

    def bound(self, x):
        """The exponent the scales alone give slot ``x`` (its exponent, unless sizes made it finer)."""
        b = self.B[x]
        return self.U[x] if b is None else b

    def exponent(self, out, rule, bound, size):
        """The exponent of ``out``: ``rule`` (the rule over the operands' exponents) without sizes; with the size of
        its largest term (``size``, None when unknown), F bits below it where that is finer, but never coarser than
        ``bound`` (the rule over the operands' bounds: what the exponent was without sizes) nor more than
        :data:`FINER_BITS` finer than F bits below ``size`` (where terms are residuals that vanish, every term
        rounded finer than the last makes the finest term's exponent, the rule of a sum, drift down)."""
        if self.sizes is None:
            return rule
        self.B[out] = bound
        if size is None:
            return rule
        s = size - self.F
        return min(bound, max(min(rule, s), s - FINER_BITS))

    def size(self, *slots):
        """The measured exponent of the product of ``slots`` (None when one is unknown or there is none)."""
        sz = self.sizes
        if sz is None:
            return None
        e = 0
        for x in slots:
            v = sz[x]
            if v is None:
                return None
            e += v
        return e

    def product(self, a, b):
        """sum_{j<=k} a_j b_{k-j} as a function of k (:class:`Cauchy`), one per pair of slots: a product that
        several sum-of-products steps read is computed once per order."""
        key = (a, b) if a <= b else (b, a)
        f = self.products.get(key)
        if f is None:
            f = self.products[key] = _Once(Cauchy(self.J[a], self.J[b], self.F >= PAIR_BITS))
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
    e = emax(*cands)
    if e is None:
        e = run.U[slot] + run.F if run.U[slot] is not None else 0
    return e - run.F


def mk_lin(run, out, vterms, offset):
    J, U = run.J, run.U
    c = J[out]
    shifts = []
    off = [0]

    def step(k):
        if k == 0:
            u = min(U[a] for a, _ in vterms)
            U[out] = u
            shifts.extend((J[a], U[a] - u, ng) for a, ng in vterms)
            off[0] = to_int(offset, u) if offset is not None else 0
        r = 0
        for a, d, ng in shifts:
            x = a[k] << d if d else a[k]
            r = r - x if ng else r + x
        if k == 0:
            r += off[0]
        c.append(r)
    return step


def mk_scale(run, out, a, craw):
    J, U, Z = run.J, run.U, run.Z
    A, C = J[a], J[out]
    s, m, e, bc = craw
    cm = -Z(m) if s else Z(m)

    def step(k):
        if k == 0:
            U[out] = U[a] + (e + bc if m else 0)
            if run.B[a] is not None:
                run.B[out] = run.B[a] + (e + bc if m else 0)
        C.append(round_shift(A[k] * cm, bc) if m else Z(0))
    return step


def mk_mul(run, out, a, b):
    J, U, F = run.J, run.U, run.F
    A, B, C = J[a], J[b], J[out]
    dot = Cauchy(A, B, F >= PAIR_BITS)

    sh = [F]

    def step(k):
        if k == 0:
            u = U[out] = run.exponent(out, U[a] + U[b] + F, run.bound(a) + run.bound(b) + F, run.size(a, b))
            sh[0] = u - U[a] - U[b]
        C.append(round_shift(dot(k), sh[0]))
    return step


def mk_sop(run, out, prods, lins, offset, state=None):
    """out = sum of ±c (a * b) product terms and ±c x linear terms (c a raw constant or None) plus an offset:
    all terms exact at their finest exponent, one rounding (a lin whose terms' products were fused into it).
    With ``state`` = i (out is the right-hand side of state variable i and used nowhere else) the step appends
    the state's next coefficient sigma out_k / (k + 1) instead, with the same single rounding."""
    C = run.J[out]
    nxt = run.nxt
    terms = []
    st = {}

    def step(k, values=True):
        if k == 0:
            terms[:], fin, off = _sop_terms(run, out, prods, lins, offset, state)
            st.update(fin=fin, off=off)
            attrs["terms"], attrs["fin"] = terms, fin  # (step.terms, step.fin)
            if not values:  # order 0's exponents and terms only (the order loop computes its values)
                return
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
            C.append(round_shift(tot, st["fin"]))
        else:  # appended after the order's last step: every step of order k sees k + 1 state coefficients
            nxt[state] = div_round(tot, k + 1, st["fin"])
    # the step writes its attributes through its __dict__: a closure over `step` itself would make a
    # reference cycle holding the expansion's jets until the cyclic garbage collector runs
    attrs = step.__dict__
    step.kind, step.C, step.state = "sop", C, state
    return step


def _sop_terms(run, out, prods, lins, offset, state):
    """Order 0 of a :func:`mk_sop` step: sets the exponent ``U[out]`` and returns (terms, fin, off): per term (its
    jet, or the dots product's slot; its product's evaluator or None; its constant, None for 1; its shift above
    the finest term), the shift of the sum to the result, and the offset at the finest term's exponent."""
    U = run.U
    xs, noms, sizes, bounds, raw_terms = _sop_exponents(run, prods, lins, state is None and run.sizes is not None)
    if not xs:
        xs = noms = [min(U[a] for a, *_ in list(prods) + list(lins))]
    x0 = min(xs)
    uo = min(noms)
    if bounds:
        if offset is not None and offset[1]:
            sizes.append(eraw(offset))
        uo = run.exponent(out, uo, min(bounds), max(sizes) if sizes else None)
    U[out] = uo
    terms = []
    for A, B, cm, x in raw_terms:
        if isinstance(B, int):  # a dot product computed by a dots step
            A, B = B, None
        terms.append((A, B, None if cm == 1 else (-1 if cm == -1 else cm), x - x0))
    fin = uo - x0 if state is None else x0 + run.s - U[state]
    return terms, fin, to_int(offset, x0) if offset is not None else 0


def _sop_exponents(run, prods, lins, sized):
    """The nonzero terms of a :func:`mk_sop` step at order 0, as (xs, noms, sizes, bounds, raw_terms): each term's
    exponent, its nominal exponent (the finest the result needs of it), with ``sized`` the bounds and measured
    sizes :meth:`Run.exponent` reads, and per term (jet, product or None, signed constant, exponent)."""
    J, U, F = run.J, run.U, run.F
    xs, noms, sizes, bounds, raw_terms = [], [], [], [], []
    for a, b, c, ng, key in prods:
        cm, ce, cbc = _sop_constant(run, c)
        if not cm:
            continue
        x = U[a] + U[b] + ce
        xs.append(x)
        noms.append(x + F + cbc)
        if sized:
            bounds.append(run.bound(a) + run.bound(b) + ce + F + cbc)
            e = run.size(a, b)
            if e is not None:  # (a term measured zero: finer is never less accurate)
                sizes.append(e + ce + cbc)
        raw_terms.append((J[a], run.product(a, b) if key is None else key, -cm if ng else cm, x))
    for a, c, ng in lins:
        cm, ce, cbc = _sop_constant(run, c)
        if not cm:
            continue
        x = U[a] + ce
        xs.append(x)
        noms.append(x + cbc)
        if sized:
            bounds.append(run.bound(a) + ce + cbc)
            e = run.size(a)
            if e is not None:
                sizes.append(e + ce + cbc)
        raw_terms.append((J[a], None, -cm if ng else cm, x))
    return xs, noms, sizes, bounds, raw_terms


def _sop_constant(run, c):
    """A term's raw constant ``c`` (None for 1) as (signed integer mantissa, exponent, bit count)."""
    if c is None:
        return 1, 0, 0
    cs, cm, ce, cbc = c
    return (-run.Z(cm) if cs else run.Z(cm)), ce, cbc


class Dots:
    """Several Cauchy products sharing one operand in one dot product: the partners' coefficients are packed
    into one integer per order (fields of W bits, W above the bits any of the products can reach) and the
    products' k-th coefficients are read back from the fields of one sum.

    The fields' width is set at order 0 with 20 bits to spare (a narrower packed integer is a cheaper product).  The order loop either checks the bound at every
    order (widening the fields when a coefficient outgrows it) or, faster, runs without checks, after which
    :meth:`all_fit` checks the same bound over every order at once (the expansion is then run again with the checks
    when it fails)."""

    kind = "dots"

    def __init__(self, run, pivot, partners, keys):
        self.dv = run.dv
        self.Z = run.Z
        self.A = run.J[pivot]
        self.Bs = [run.J[b] for b in partners]
        self.rBs = self.Bs[::-1]
        self.keys = keys
        self.P = []
        self.dot = Cauchy(self.A, self.P, run.F >= PAIR_BITS)
        self.W = self.ba = self.bb = 0
        self.run, self.slots = run, (pivot, *partners)
        self.mask = self.full = self.half = self.bias = self.bias_all = 0

    def repack(self, k, need):
        """Widen the fields to hold ``need`` bits: the packed partners of orders < k again; the new
        (W, mask, full, half)."""
        W = self.W = need + 20
        # the masks and biases in the backend's integers: an operation between gmpy2's mpz and a Python int of
        # hundreds of bits converts the int every time (~0.1 us for a 500-bit mask, ~0.7 us for a 4000-bit bias)
        Z = self.Z
        self.full, self.half = Z(1) << W, Z(1) << (W - 1)
        self.mask = self.full - 1
        # half a field added to every field but the top one makes them all non-negative (no borrows between
        # fields): field m of D + bias, less half, is the m-th sum of products, and what lies above the last but
        # one field is the last (the order loop's way of reading them)
        self.bias = sum(self.half << (m * W) for m in range(len(self.Bs) - 1))
        # with the top field too, every field of D + bias_all is its sum of products plus half, in [0, 2**W): the
        # order loop without checks reads the fields so (with one mask each, and subtracts the halves where it sums
        # them)
        self.bias_all = self.bias + (self.half << ((len(self.Bs) - 1) * W))
        P = self.P
        P[:] = []
        for j in range(k):
            v = 0
            for B in self.rBs:
                v = (v << W) + B[j]
            P.append(v)
        self.dot.reset(P, k)
        return W, self.mask, self.half, self.bias

    def start(self):
        """At order 0, with measured sizes (:attr:`Run.sizes`): the fields as wide as the operands' sizes show their
        coefficients will be at every order (:attr:`Run.order`; the width of order 0 with 20 bits to spare
        is too narrow where a node's later orders outgrow its value, and the expansion is then run again with
        the checks)."""
        run = self.run
        sz, U = run.sizes, run.U
        if sz is None:
            return
        pivot, *partners = self.slots
        # (a node measured zero, without a size: F bits, what a node carries)
        self.ba = max(self.ba, run.F if sz[pivot] is None else sz[pivot] - U[pivot])
        self.bb = max(self.bb, *(run.F if sz[b] is None else sz[b] - U[b] for b in partners))
        self.ba += run.order.bit_length()

    @staticmethod
    def all_fit(dots, n):
        """Whether the fields of width W of each of ``dots`` held every sum of products of the orders k < n
        exactly: |sum_{j<=k} a_j b_{k-j}| < (k + 1) 2**(ba + bb) <= 2**(W - 1), with ba and bb the largest bit
        lengths of the pivot's and the partners' coefficients of orders < n (the first order that overflowed would
        have read only correct coefficients, all of them within these bounds)."""
        bl = bit_length_function()
        known = {}

        def bits(jet):  # the largest bit length of a jet's coefficients (a jet several products share: once)
            b = known.get(id(jet))
            if b is None:
                b = known[id(jet)] = max(map(bl, jet[:n]))
            return b

        for d in dots:
            bb = max(map(bits, d.Bs))
            if bits(d.A) + bb + n.bit_length() + 2 > d.W:
                return False
            d.bb = max(d.bb, bb)  # (what the partners' coefficients of every order reach: FixedJets' packed Horner)
        return True

    def setup(self):
        """Order 0's field width, from the coefficients 0 of the pivot and the partners (which must be known: state
        variables), without the order's dot product (the order loop computes it)."""
        self.start()
        self.ba = max(self.ba, self.A[0].bit_length())
        self.bb = max(self.bb, *(B[0].bit_length() for B in self.Bs))
        self.repack(0, self.ba + self.bb + 3)

    def __call__(self, k):
        if k == 0:
            self.start()
        x = self.A[k].bit_length()
        if x > self.ba:
            self.ba = x
        x = max(B[k].bit_length() for B in self.Bs)
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



def mk_sqr(run, out, a):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]

    sh = [F]

    def step(k):
        if k == 0:
            u = U[out] = run.exponent(out, 2 * U[a] + F, 2 * run.bound(a) + F, run.size(a, a))
            sh[0] = u - 2 * U[a]
        C.append(round_shift(sqr_sum(A, k), sh[0]))
    return step


def mk_div(run, out, a, b, wp, cnum=None):
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
            b0 = to_raw(B0, ub)
            eb0 = ebits(B0, ub)
            if A is not None:
                a0 = to_raw(A[0], U[a])
                ea = U[a] + F
                e0 = eraw(a0)
                cands = (ea - eb0, None if e0 is None else e0 + ub + F - 2 * eb0)
            else:
                a0 = cnum
                e0 = eraw(cnum)
                cands = (None,) if e0 is None else (e0 - eb0, e0 + ub + F - 2 * eb0)
            uc = _fn_exp(run, b, *cands)
            U[out] = uc
            C.append(to_int(mpf_div(a0, b0, wp, RND), uc))
            us = ub + uc
            if A is not None:
                ucom = min(U[a], us)
                st.update(da=U[a] - ucom, ds=us - ucom, d=ucom - ub - uc)
            else:
                st.update(da=0, ds=0, d=us - ub - uc)
            st["B0"] = B0 if B0 > 0 else -B0
            st["sg"] = B0 < 0
            return
        num = -(sum_products(B[1:k + 1], C[k - 1::-1]) << st["ds"])
        if A is not None:
            num += A[k] << st["da"]
        if st["sg"]:
            num = -num
        C.append(div_round(num, st["B0"], st["d"]))
    return step


def mk_pow(run, out, a, ex, data, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    DA, DC = run.dj(a), run.dj(out)
    es, em, ee, ebc = ex
    pm = -run.Z(em) if es else run.Z(em)
    st = {}

    def step(k):
        if k == 0:
            if not A[0]:
                raise ZeroDivisionError("a non-integer power of a series with zero constant term")
            a0 = to_raw(A[0], U[a])
            c0 = POINTWISE["pow"]([a0, ex], data, wp)
            e0 = eraw(c0)
            ep = eraw(ex)
            uc = _fn_exp(run, a, e0, None if (e0 is None or ep is None) else ep + e0 - eraw(a0) + U[a] + F)
            U[out] = uc
            C.append(to_int(c0, uc))
            # num = p S1 - S2 at exponent ua + uc + min(ee, 0); p S1 has ee, S2 has 0
            pe = min(ee, 0)
            st.update(p=pm << (ee - pe), s2=-pe, d=pe, A0=A[0] if A[0] > 0 else -A[0], sg=A[0] < 0)
            return
        _ext(A, DA, k)
        _ext(C, DC, k - 1)
        s1 = sum_products(C[0:k], DA[k:0:-1])
        s2 = sum_products(DC[1:k], A[k - 1:0:-1])
        num = st["p"] * s1 - (s2 << st["s2"])
        if st["sg"]:
            num = -num
        C.append(div_round(num, st["A0"] * k, st["d"]))
    return step


def mk_sqrt(run, out, a, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    st = {}

    def step(k):
        if k == 0:
            if not A[0]:
                raise ZeroDivisionError("sqrt of a series with zero constant term")
            c0 = POINTWISE["sqrt"]([to_raw(A[0], U[a])], None, wp)
            e0 = eraw(c0)
            uc = _fn_exp(run, a, e0, U[a] + F - e0 - 1)
            U[out] = uc
            C0 = to_int(c0, uc)
            C.append(C0)
            ucom = min(U[a], 2 * uc)
            st.update(da=U[a] - ucom, ds=2 * uc - ucom, d=ucom - 2 * uc, den=2 * C0)
            return
        h = (k - 1) >> 1
        s = sum_products(C[1:h + 1], C[k - 1:k - h - 1:-1]) << 1 if h else 0
        if not k & 1:
            x = C[k >> 1]
            s += x * x
        num = (A[k] << st["da"]) - (s << st["ds"])
        C.append(div_round(num, st["den"], st["d"]))
    return step


def mk_exp(run, out, a, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    DA = run.dj(a)

    def step(k):
        if k == 0:
            c0 = POINTWISE["exp"]([to_raw(A[0], U[a])], None, wp)
            e0 = eraw(c0)
            uc = _fn_exp(run, a, e0, None if e0 is None else e0 + U[a] + F)
            U[out] = uc
            C.append(to_int(c0, uc))
            return
        _ext(A, DA, k)
        C.append(div_round(sum_products(DA[1:k + 1], C[k - 1::-1]), k, U[a]))
    return step


def mk_log(run, out, a, wp):
    J, U, F = run.J, run.U, run.F
    A, C = J[a], J[out]
    DA, DC = run.dj(a), run.dj(out)
    st = {}

    def step(k):
        if k == 0:
            if not A[0]:
                raise ZeroDivisionError("log of a series with zero constant term")
            a0 = to_raw(A[0], U[a])
            c0 = POINTWISE["log"]([a0], None, wp)
            uc = _fn_exp(run, a, eraw(c0), U[a] + F - eraw(a0))
            U[out] = uc
            C.append(to_int(c0, uc))
            ucom = min(U[a], uc + U[a])
            st.update(da=U[a] - ucom, ds=uc + U[a] - ucom, d=ucom - U[a] - uc,
                      A0=A[0] if A[0] > 0 else -A[0], sg=A[0] < 0)
            return
        _ext(A, DA, k)
        _ext(C, DC, k - 1)
        num = (DA[k] << st["da"]) - (sum_products(DC[1:k], A[k - 1:0:-1]) << st["ds"])
        if st["sg"]:
            num = -num
        C.append(div_round(num, st["A0"] * k, st["d"]))
    return step


def mk_sincos(run, so, co, a, wp, hyperbolic):
    J, U, F = run.J, run.U, run.F
    A, S, C = J[a], J[so], J[co]
    DA = run.dj(a)
    st = {}

    def step(k):
        if k == 0:
            a0 = to_raw(A[0], U[a])
            c0, s0 = (mpf_cosh_sinh if hyperbolic else mpf_cos_sin)(a0, wp, RND)
            ea = U[a] + F
            es0, ec0 = eraw(s0), eraw(c0)
            us = _fn_exp(run, a, es0, None if ec0 is None else ec0 + ea)
            uc = _fn_exp(run, a, ec0, None if es0 is None else es0 + ea)
            U[so], U[co] = us, uc
            S.append(to_int(s0, us))
            C.append(to_int(c0, uc))
            st.update(ds=U[a] + uc - us, dc=U[a] + us - uc)
            return
        _ext(A, DA, k)
        d = DA[1:k + 1]
        ss = sum_products(d, C[k - 1::-1])
        sc = sum_products(d, S[k - 1::-1])
        if not hyperbolic:
            sc = -sc
        S.append(div_round(ss, k, st["ds"]))
        C.append(div_round(sc, k, st["dc"]))
    return step


def mk_tan(run, out, aux, a, wp, hyperbolic):
    """out = tan(a) (tanh), aux = 1 + out^2 (1 - out^2)."""
    J, U, F = run.J, run.U, run.F
    A, T, W = J[a], J[out], J[aux]
    DA = run.dj(a)
    st = {}

    def step(k):
        if k == 0:
            a0 = to_raw(A[0], U[a])
            t0 = POINTWISE["tanh" if hyperbolic else "tan"]([a0], None, wp)
            t2 = mpf_mul(t0, t0)
            w0 = mpf_sub(fone, t2, wp, RND) if hyperbolic else mpf_add(fone, t2, wp, RND)
            ew0, et0 = eraw(w0), eraw(t0)
            ut = _fn_exp(run, a, et0, None if ew0 is None else ew0 + U[a] + F)
            # w's first-order change 2 t0 dt (not the square of t's scale: a scale above F / 2 bits, from an argument
            # of size 1e20, rounded w's every coefficient to zero)
            uw = _fn_exp(run, a, ew0, None if et0 is None else et0 + 1 + ut + F)
            U[out], U[aux] = ut, uw
            T.append(to_int(t0, ut))
            W.append(to_int(w0, uw))
            st.update(dt=U[a] + uw - ut, dw=uw - 2 * ut)
            return
        _ext(A, DA, k)
        T.append(div_round(sum_products(DA[1:k + 1], W[k - 1::-1]), k, st["dt"]))
        w = round_shift(sqr_sum(T, k), st["dw"])
        W.append(-w if hyperbolic else w)
    return step


def mk_atan(run, out, aux, a, wp):
    """out = atan(a), aux = 1 + a^2."""
    J, U, F = run.J, run.U, run.F
    A, C, W = J[a], J[out], J[aux]
    DA, DC = run.dj(a), run.dj(out)
    st = {}

    def step(k):
        if k == 0:
            a0 = to_raw(A[0], U[a])
            w0 = mpf_add(fone, mpf_mul(a0, a0), wp, RND)
            c0 = POINTWISE["atan"]([a0], None, wp)
            ea, ew0 = U[a] + F, eraw(w0)
            e0 = eraw(a0)
            # w's first-order change 2 a0 da (not the square of a's scale: a scale above F / 2 bits rounded w0 to 0)
            uw = _fn_exp(run, a, ew0, None if e0 is None else e0 + 1 + ea)
            uc = _fn_exp(run, a, eraw(c0), ea - ew0)
            U[out], U[aux] = uc, uw
            C.append(to_int(c0, uc))
            W0 = to_int(w0, uw)
            W.append(W0)
            ucom = min(U[a], uc + uw)
            st.update(dw=uw - 2 * U[a], da=U[a] - ucom, ds=uc + uw - ucom, d=ucom - uw - uc, W0=W0)
            return
        W.append(round_shift(sqr_sum(A, k), st["dw"]))
        _ext(A, DA, k)
        _ext(C, DC, k - 1)
        num = (DA[k] << st["da"]) - (sum_products(DC[1:k], W[k - 1:0:-1]) << st["ds"])
        C.append(div_round(num, st["W0"] * k, st["d"]))
    return step
