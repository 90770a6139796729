"""Taylor-mode jets in fixed-point big integers (the fast path of the Lie-series step).

The same recurrences as :mod:`lieseries.lie.jets`, run over the same jet plan, but every coefficient is an integer
``M`` standing for ``M * 2**u`` with one binary exponent ``u`` per jet (per node of the vector field), and time is
normalised by a power of two ``sigma = 2**s``: the integers hold ``C_k = c_k * sigma**k``.  A Cauchy product is then
one exact integer dot product and one rounding shift, with no per-term exponent alignment.

Scaling (why fixed point loses nothing)
---------------------------------------
* Each jet's exponent is set at order 0 from the magnitude it will carry: ``e = max(e(f(a_0)), e(f'(a_0)) + e_a)``
  (the value, and the first-order change that the argument's scale ``e_a`` drives), and ``u = e - F`` with ``F``
  the working bits (precision + :func:`~lieseries.lie.plan.jet_guard_bits`).  A state variable takes the exponent
  of its own value (a zero one the smallest exponent of the non-zero ones, or, in an expansion run again from
  measured sizes, ``F`` bits below what it carried where that is finer), so states of size 1e6 or 1e-6 and
  parameters of any size keep ``F`` bits relative to their own scale.  Sums are exact (finest exponent); every
  other result is rounded once to half a unit.
* A product's scale is its operands' scales multiplied, a sum of products' the scale of its finest term: bounds,
  a bit above what the node carries per factor, and far above where terms cancel or a node is a residual that
  vanishes (the constraint residuals of a derived form, multiplied into its field: on a heavy top's intermediate
  form up to 40 bits, and a unit of such an exponent cost 20 digits of the state's jets).  So every expansion
  measures what each node carried (:class:`~lieseries.lie.fixed_orders.NodeSizes`: the largest
  ``|c_k| sigma**k``), and when a node's scale lay more than :data:`COARSE_BITS` above it, runs again with every
  product and sum of products rounded ``F`` bits below what its largest term carried where that is finer than
  the scales give (never coarser than they give, nor more than
  :data:`~lieseries.lie.fixed_steps.FINER_BITS` finer: :meth:`~lieseries.lie.fixed_steps.Run.exponent`; a node
  measured zero keeps its scale).  :class:`FixedStepper` starts each expansion
  from the sizes of the last one (moved to the new time scale) and runs it again when a node carried more than
  :data:`COARSE_BITS` less than both its scale and those sizes said; it goes without sizes until an expansion
  needs them.  Systems whose every node is fused into the
  states' steps (the rigid body) have nothing to measure and are unchanged.
* Where the terms of a sum cancel far below their size (``(p + x)^2 - x^2 - 2 p x`` at x = 6e20), every node is
  rounded F bits below what it carries and the sum keeps the terms' units, far above what a state's derivative
  needs: at 30 digits x' came out 7.2 instead of 8.8e-15.  Each measured expansion also bounds what its roundings
  cost the states (:class:`~lieseries.lie.fixed_orders.NodeSizes`' ``errors``: first-order error bounds carried
  through the instructions, the states' own values exact), and where that is more than the guard bits of a
  state's scale, :class:`FixedStepper` runs it again with as many working bits more as leave :data:`LOST_BITS` of
  them, and keeps them for the later steps (:func:`extra_bits`; beyond :data:`MAX_EXTRA` times F a ValueError
  says so).
* The integers hold ``c_k sigma**k`` to ``F`` bits relative to the state's scale, i.e. each ``c_k`` with the
  absolute accuracy that a step of at most ``sigma`` needs: a Lie step ``h <= sigma`` multiplies the error of
  ``c_k`` by ``h**k``, so every term of the step's sum is known to ``F`` bits of the state.  :class:`FixedStepper`
  takes ``sigma`` two to four times the last step (and below the radius of convergence), and ``lie_integrate``
  never steps beyond it: the high orders, which a step multiplies by ``(h / rho)**k``, then carry
  correspondingly fewer bits, which is where fixed point saves work over floating point.
* Rounding: sums and products are exact, and every stored coefficient is rounded once (half a unit); the error
  a coefficient inherits through the recurrences grows with the order and the depth of the expression by a
  factor of a few powers of two, well inside the :func:`~lieseries.lie.plan.jet_guard_bits` the working
  precision carries (tests/test_fixed_jets.py checks every instruction against the mpf jets at twice the digits).

The modules
-----------
:mod:`~lieseries.lie.bigint` holds the big integers (gmpy2's ``mpz`` when gmpy2 imports, Python ``int`` otherwise;
the environment variable ``LIESERIES_BIGINT=int`` or :func:`set_backend` forces Python ints) and the integer
helpers; :mod:`~lieseries.lie.fixed_steps` the step of each instruction; :mod:`~lieseries.lie.fixed_orders` the
instructions fused and grouped, the generated order loop and :func:`~lieseries.lie.fixed_orders.expand`; this
module what a step reads from an expansion (:class:`FixedJets`), the stepper that chooses the time scale
(:class:`FixedStepper`) and :func:`fixed_taylor_coefficients`.
"""

from __future__ import annotations

import math
from itertools import chain

import numpy as np
from mpmath.libmp import from_man_exp, fzero

from .. import expr as _expr
from ..precision import Precision, check_dps, check_order, mp_context
from ..precision import thread_mp as mp
from . import bigint
from .bigint import greater_abs, log2_abs, to_raw, round_shift, backend, set_backend
from .fixed_orders import NodeSizes, expand
from .plan import jet_guard_bits, radius_from_logs, resolve_program

__all__ = ["backend", "set_backend", "fixed_taylor_coefficients", "FixedStepper", "FixedJets", "cancelling_bits"]


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

    def __init__(self, M, U, s, prec, packs=None):
        self.M, self.U, self.s, self.prec = M, U, s, prec
        self.packs = packs  # (expand's ``packs``: the states' coefficients packed by the dot products, or None)
        self._cover = None
        self.max_step = mp_context().ldexp(1, s)
        self.rho = None
        self.log2_rho = None
        self.stepper = None
        # per state, log2 of the bound on what the expansion's roundings put into its terms c_k sigma^k (None: not
        # measured, or nothing to bound): below it a state's digits are the roundings' (NodeSizes.errors)
        self.noise = None
        self._norms = None
        self._abs = None
        self._log_cols = {}
        self._lnorms = None
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
                    if m and (bu is None or greater_abs(m, u, bm, bu)):
                        bm, bu = m, u
                nrm.append(make(from_man_exp(bm, bu - s * k, 64, "u") if bu is not None else fzero))
            self._norms = nrm
        return self._norms

    def _logs(self, k):
        """[log2 |M_{i,k}| of every variable i] (None for zero), computed once per order."""
        got = self._log_cols.get(k)
        if got is None:
            got = self._log_cols[k] = [log2_abs(Mi[k]) if Mi[k] else None for Mi in self.M]
        return got

    def log2_norm(self, k):
        """log2 ||c_k|| (max norm), ``-inf`` for a zero vector."""
        best = -math.inf
        for la, ui in zip(self._logs(k), self.U):
            if la is not None:
                x = la + ui
                if x > best:
                    best = x
        return best - self.s * k

    def _floats(self):
        """|M| as a float matrix (variables x orders), or None when an integer is beyond the double range."""
        if self._abs is None:
            try:
                M = self.M
                self._abs = np.abs(np.fromiter(map(float, chain.from_iterable(M)), float, len(M) * len(M[0]))
                                   .reshape(len(M), len(M[0])))
            except OverflowError:
                self._abs = False
        return self._abs if self._abs is not False else None

    def log2_norms(self, k0, k1):
        """[log2 ||c_k|| for k0 <= k < k1] (``-inf`` for zero vectors), in numpy when the integers fit in doubles."""
        if self._lnorms is None:
            a = self._floats()
            if a is None:
                return [self.log2_norm(k) for k in range(k0, k1)]
            with np.errstate(divide="ignore"):  # every order at once: the radius and the error estimate read them
                lg = np.log2(a) + np.array(self.U, dtype=float)[:, None]
            self._lnorms = (lg.max(axis=0) - self.s * np.arange(a.shape[1])).tolist()
        return self._lnorms[k0:k1]

    def log2_column(self, k):
        """log2 |c_{k,i}| of every variable i (``-inf`` for zero)."""
        sk = self.s * k
        return [la + (ui - sk) if la is not None else -math.inf for la, ui in zip(self._logs(k), self.U)]

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
            return [make(to_raw(Mi[0], ui, self.prec)) for Mi, ui in zip(self.M, self.U)]
        Z = bigint.integer_type()
        tm = -Z(tm) if sg else Z(tm)
        sh = self.s - te  # t / sigma = tm * 2**-sh
        acc = [None] * len(self.M)
        if sh > 0 and self.packs:
            self._packed_horner(acc, tm, sh, Z)
        for i, Mi in enumerate(self.M):
            if acc[i] is not None:
                continue
            a = Mi[-1]
            if sh > 0:
                half = Z(1) << (sh - 1)
                for m in Mi[-2::-1]:
                    a = ((a * tm + half) >> sh) + m
            else:
                for m in Mi[-2::-1]:
                    a = round_shift(a * tm, sh) + m
            acc[i] = a
        prec = self.prec
        return [make(to_raw(a, ui, prec)) for a, ui in zip(acc, self.U)]

    def _packed_horner(self, acc, tm, sh, Z):
        """:meth:`evaluate`'s Horner steps ``a = floor((a tm + 2**(sh-1)) / 2**sh) + M_k`` for the states whose
        coefficients a dot product packed (:attr:`packs`), several states per integer operation, into ``acc`` (the
        same integers: every field is rounded on its own).

        A field ``x`` of the packed accumulator is held as ``x + 2**(W-1-sh)``; a step multiplies by ``tm`` and adds
        ``C = 2**(W-1) + 2**(sh-1) - 2**(W-1-sh) tm`` to every field, which makes each ``z = x tm + 2**(sh-1) +
        2**(W-1)``, in [0, 2**W) while ``|x tm| + 2**(sh-1) < 2**(W-1)``: the fields are then independent, the shift
        by ``sh`` floors each (the low bits a field passes to the one below are masked off) and leaves it
        ``floor((x tm + 2**(sh-1)) / 2**sh) + 2**(W-1-sh)``, to which the packed coefficients add ``M_k``."""
        cover = self._cover
        if cover is None:  # the packs that hold two states or more not held by a larger one
            cover, seen = [], set()
            for pk in sorted(self.packs, key=lambda pk: -len(pk[2])):
                new = set(pk[2]) - seen
                if len(new) >= 2:
                    cover.append((pk, new))
                    seen |= new
            self._cover = cover
        M = self.M
        N = len(M[0]) - 1
        lim = N.bit_length() + abs(tm).bit_length() + 3
        for (P, W, states, bb), new in cover:
            if len(P) != N or sh > W - 2:
                continue
            bits = max(bb, *(M[i][N].bit_length() for i in states))  # (|a| < (N + 1) 2**bits + N + 1)
            if bits + lim > W - 1:
                continue
            one = Z(1)
            rep = sum(one << (m * W) for m in range(len(states)))  # 1 in every field
            top, low = one << (W - 1), one << (W - 1 - sh)
            C = (top + (one << (sh - 1)) - low * tm) * rep
            mask = ((one << (W - sh)) - 1) * rep
            x = 0
            for i in reversed(states):
                x = (x << W) + M[i][N]
            x += low * rep
            for p in reversed(P):
                x = (((x * tm + C) >> sh) & mask) + p
            x += (top - low) * rep  # every field x + 2**(W-1), in [0, 2**W)
            full = (one << W) - 1
            for m, i in enumerate(states):
                if i in new:
                    acc[i] = ((x >> (m * W)) & full) - top

    def _abs_horner(self, h):
        """(sum_k |M_{k,i}| (|h| / sigma)^k, U_i) for every variable i, in integers."""
        if abs(h) > self.max_step:
            raise RuntimeError(f"a step of {mp.nstr(h, 5)} beyond the jets' time scale {mp.nstr(self.max_step, 5)}")
        sg, tm, te, _ = abs(h)._mpf_
        Z = bigint.integer_type()
        out = []
        for Mi, ui in zip(self.M, self.U):
            if not tm:
                acc = abs(Mi[0])
            else:
                tmz, sh = Z(tm), self.s - te
                acc = abs(Mi[-1])
                if sh > 0:
                    half = 1 << (sh - 1)
                    for k in range(len(Mi) - 2, -1, -1):
                        acc = ((acc * tmz + half) >> sh) + abs(Mi[k])
                else:
                    for k in range(len(Mi) - 2, -1, -1):
                        acc = round_shift(acc * tmz, sh) + abs(Mi[k])
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
        return [max(0.0, log2_abs(acc) + ui) if acc else 0.0 for acc, ui in self._abs_horner(h)]



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
            list.extend(self, [[make(to_raw(M[i][k], U[i] - s * k, p)) for i in range(n)] for k in range(N)])
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

#: A node whose scale is more than this many bits above what its jet carried (:meth:`NodeSizes.coarse`) makes an
#: expansion run again with exponents from what the nodes carried: below the guard bits of every order
#: (:func:`~lieseries.lie.plan.jet_guard_bits`, at least 22), above the few bits a chain of bounds adds where
#: nothing cancels (a double spherical pendulum's nodes up to 15, a heavy top's intermediate form up to 140).
COARSE_BITS = 16


class FixedStepper:
    """Repeated expansions of one system at one order and precision (the Lie step's jets).

    ``precision`` is a :class:`~lieseries.precision.Precision`: the jets hold its working bits (guard included) and
    :func:`~lieseries.lie.plan.jet_guard_bits` more.  ``expand(z, span)`` returns :class:`FixedJets` for the state
    ``z`` (mpf) with a time scale ``sigma`` (a power of two, ``max_step`` of the result) that the caller's step must
    not exceed.  Integers hold ``c_k sigma**k`` to a fixed number of bits relative to the state, so a coefficient
    carries exactly the absolute accuracy that a step of at most ``sigma`` needs, and no more: with ``sigma`` a few
    times the step (and below the radius of convergence) the high orders, which a step multiplies by
    ``(h / rho)**k``, are held with correspondingly fewer bits.  ``sigma`` is ``2**(ceil(log2 h) + 1)`` for the last
    step ``h`` that :meth:`FixedJets.horner` evaluated (at most the largest power of two below the last radius
    estimate), a quarter of the radius estimated by a short expansion at the first call, and at least ``span`` when
    the solution is a polynomial (an infinite radius); never above ``span`` (no step goes beyond it).  ``sizes`` are
    what the nodes carried at the last expansion (:class:`~lieseries.lie.fixed_orders.NodeSizes`, the module
    docstring's Scaling), and ``redone`` counts the expansions run again because a node's scale lay above what it
    carried; ``extra`` the working bits the expansions run with beyond F since one's roundings might cost a state
    its guard bits (:func:`extra_bits`).
    """

    def __init__(self, program, pars, order, precision):
        self.program = program
        self.order = order
        self.prec = precision.working_bits
        self.wp = self.prec + jet_guard_bits(order)
        self.pars_raw = _expr.convert_vector(pars, program.npars, self.wp, "pars")
        self.s = None
        self.h_last = None
        self.last_rho = None
        self.expansions = 0
        self.sizes = None  # what the nodes carried at the last expansion (NodeSizes)
        self.redone = 0  # expansions run again with the sizes their nodes carried (NodeSizes.coarse)
        self.extra = 0  # working bits added where the roundings may cost a state its guard bits (extra_bits)
        self.measure = True
        self.packs = None  # the last expansion's packed states (expand's ``packs``)

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
            # (its roundings are not judged: at a time scale of 1 a heavy top's intermediate form holds 23 bits
            # fewer, which the radius never sees)
            M, U, got = self._measured(zr, min(self.order, 12), 0, deadline, NodeSizes(), judge=False)
            # (nothing to measure where every node is fused into the states' steps: a state at zero takes its
            # size from this short expansion, and no later state is exactly zero)
            self.measure = got.nodes
            rho = _estimate_radius(FixedJets(M, U, 0, self.prec))[0]
            self.s = _ceil_log2(span) if rho == mp.inf else _floor_log2(rho) - 2
        elif self.h_last:
            s = _ceil_log2(self.h_last) + 1
            if self.last_rho is not None and self.last_rho != mp.inf:
                s = min(s, _floor_log2(self.last_rho))
            self.s = s
        if span:  # (no step goes beyond the span: a time scale above it holds the jets coarser than a step needs)
            self.s = min(self.s, _ceil_log2(span))
        for _ in range(3):
            M, U, got = self._measured(zr, self.order, self.s, deadline, NodeSizes() if self.measure else None)
            jets = FixedJets(M, U, self.s, self.prec, self.packs)
            if got is not None and got.errors:
                jets.noise = [e for e, _ in got.errors]
            jets.rho, jets.log2_rho = _estimate_radius(jets)
            self.last_rho = jets.rho
            jets.stepper = self
            if jets.rho == mp.inf and span > jets.max_step:  # a polynomial: one step may reach the end
                self.s = _ceil_log2(span)
                continue
            return jets
        return jets

    def _measured(self, zr, order, s, deadline, got, judge=True):
        """(M, U, sizes) of an expansion at the time scale ``2**s``, measured into ``got`` (a NodeSizes, or None
        to go unmeasured): run again from what the nodes carried when a node's scale lay more than
        :data:`COARSE_BITS` above it (beyond what the sizes it was given knew), and at more working bits when the
        roundings may cost a state more than its guard bits (:func:`extra_bits`)."""
        while True:  # (the extra bits grow by 16 or more a round: check_extra ends it)
            wp = self.wp + self.extra
            first = self.sizes
            self.packs = []
            M, U = expand(self.program, zr, self.pars_raw, order, wp, s, deadline, first, got, self.packs)
            self.expansions += 1
            if got is not None and got.coarse(COARSE_BITS, first):  # rounded coarser than the nodes carry
                self.sizes, got = got, NodeSizes()
                self.packs = []
                M, U = expand(self.program, zr, self.pars_raw, order, wp, s, deadline, self.sizes, got, self.packs)
                self.expansions += 1
                self.redone += 1
            if self.sizes is not None:  # (while the scales alone serve, the expansions go without sizes)
                self.sizes = got
            more = extra_bits(got, self.wp, self.prec) if judge else 0
            if not more:
                return M, U, got
            self.extra += more
            check_extra(self.extra, self.wp)
            got = NodeSizes()  # (got is measured: it has errors)


#: What the roundings may cost a state of the jets' guard bits (F less the working bits) after the expansion is run
#: again at more working bits: it is run again when the bound (:func:`extra_bits`, a first-order one, up to ~14 bits
#: above the bits lost) exceeds the guard bits, with as many bits more as leave this many of them.
LOST_BITS = COARSE_BITS

#: The most working bits the jets may add over F, as a multiple of F, before a state's losses are an error
MAX_EXTRA = 4


def extra_bits(got, F, prec):
    """The working bits to add over ``F`` when the roundings of the expansion measured into ``got`` (a NodeSizes,
    or None) may cost a state more than its guard bits, ``F - prec`` (``prec`` the working bits): as many as leave
    it :data:`LOST_BITS` of them (0 when they do not).

    A sum whose terms cancel far below their size (``(p + x)^2 - x^2 - 2 p x`` at x = 6e20, where p + x rounded at
    x's unit drops p: 64 bits at 30 digits) holds the state's derivative to the terms' units, F bits below the
    terms, not below the result. A state is judged against its own scale (a step's tolerance is relative to each
    component's scale), unless that lies less than :data:`LOST_BITS` above ``prec`` bits below the largest state's:
    such a state is at the level of the others' roundings (a sphere's velocity along its normal, zero but for them,
    at 2^-134 of the others at 136 working bits). The bound is a first-order one and never lets errors cancel: on a
    heavy top's intermediate form at a time scale of 1 it says 37 bits where 23 were lost, at 1/8 8 bits (1 lost).
    """
    lost = lost_bits(got, F, prec)
    guard = F - prec
    return int(lost) - guard + LOST_BITS if lost > guard else 0


def lost_bits(got, F, prec):
    """The bits of the F the jets hold that the roundings of the expansion measured into ``got`` may cost a state
    (:func:`extra_bits`), ``-inf`` when none can be judged."""
    if got is None or not got.errors:
        return -math.inf
    scales = [sc for _, sc in got.errors if sc is not None]
    if not scales:
        return -math.inf
    floor = max(scales) - prec + LOST_BITS
    return max((e - sc for e, sc in got.errors if e is not None and sc >= floor), default=-math.inf) + F


def cancelling_bits(program_or_system, y0, pars, bits):
    """The bits the vector field's expression loses to its own roundings at ``y0`` when every operation is rounded
    to ``bits`` (as heyoka's are): :func:`lost_bits` of the fixed-point jets' first order at that precision, no
    guard bits (0 where nothing is lost; a time scale of 1, so a state's rate is judged per unit time).
    y' = ``(p + x)^2 - p^2 - 2 p x - x^2 + r cos y`` beside x = 6e20 loses 138 bits at any precision (the squares
    rounded at 2^(138 - bits)): at 226 bits y' is off by 6e-27; a heavy top's derived forms 16 (a bound: the
    errors do not cancel in it)."""
    program = resolve_program(program_or_system)
    y0r = _expr.convert_vector(y0, program.nvars, bits, "y0")
    pr = _expr.convert_vector(pars, program.npars, bits, "pars")
    got = NodeSizes()
    try:
        expand(program, y0r, pr, 1, bits, 0, measured=got)
        if got.coarse(COARSE_BITS):
            sizes, got = got, NodeSizes()
            expand(program, y0r, pr, 1, bits, 0, sizes=sizes, measured=got)
    except (ArithmeticError, ValueError):  # a field singular at y0 (log of a negative number): the run says so
        return 0
    lost = lost_bits(got, bits, bits)
    return max(0, int(lost)) if lost != -math.inf else 0


def check_extra(extra, F):
    """A ValueError when the jets would need more than :data:`MAX_EXTRA` times their F bits more
    (:func:`extra_bits`)."""
    if extra > MAX_EXTRA * F:
        raise ValueError(
            f"the vector field's expression cancels about {extra} bits at this state: sums of terms far larger "
            f"than their result would need {extra} working bits more than the {F} the jets hold; write the "
            "expression without the cancelling terms, or run with more digits"
        )


def _ceil_log2(x):
    """e for x = m 2**e with 1/2 < m <= 1 (mp.frexp's exponent, less one where its mantissa is 1/2), from the mpf's
    mantissa and exponent (x an mpf or a number mp.mpf takes)."""
    sign, man, exp, bc = _raw(x)
    return exp + bc if man > 1 and not sign else exp + bc - 1


def _floor_log2(x):
    """mp.frexp's exponent of x, less one."""
    _, _, exp, bc = _raw(x)
    return exp + bc - 1


def _raw(x):
    raw = getattr(x, "_mpf_", None)
    return raw if raw is not None else mp.mpf(x)._mpf_


def fixed_taylor_coefficients(program_or_system, y0, pars, order, dps, time_scale=0, ctx=None):
    """Normalised Taylor coefficients computed in fixed-point big integers.

    Same arguments as :func:`lieseries.lie.jets.taylor_coefficients`, plus ``time_scale`` = s: the computation
    holds ``c_k * 2**(s k)`` to ``dps`` digits plus guard bits relative to the scale of each variable (the size
    of its initial value), so ``c_k`` is accurate relative to ``scale * 2**(-s k)``, which is what a step of at
    most ``2**s`` needs (with ``2**s`` near the radius of convergence, every coefficient to about ``dps``
    digits).  Returns ``c[k][i]`` as mpf of ``ctx`` (the thread's context by default) at ``dps`` digits.  When a
    node's scale lies more than :data:`COARSE_BITS` above what it carried, the expansion is run again from what the
    nodes carried, and at more working bits when its roundings may cost a state more than its guard bits
    (:func:`extra_bits`; module docstring, Scaling).
    """
    program = resolve_program(program_or_system)
    order = check_order(order)
    prec = Precision.of(dps=check_dps(dps))
    stepper = FixedStepper(program, pars, order, prec)  # (its expansions, at the time scale given)
    y0r = _expr.convert_vector(y0, program.nvars, stepper.wp, "y0")
    try:
        M, U, _ = stepper._measured(y0r, order, int(time_scale), None, NodeSizes())
    except ZeroDivisionError as exc:
        raise ValueError(
            f"the Taylor expansion does not exist at `y0` ({exc}; a zero denominator "
            "or a log/sqrt/non-integer power at zero)"
        ) from None
    make = (ctx or mp_context()).make_mpf
    s, bits = int(time_scale), prec.working_bits
    return [[make(to_raw(M[i][k], U[i] - s * k, bits)) for i in range(program.nvars)] for k in range(order + 1)]
