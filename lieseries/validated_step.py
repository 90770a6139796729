"""The proof of one validated step (:mod:`lieseries.validated` runs them): the centre's Taylor polynomial and its
defect, the a priori enclosure and the remainder bound, the flow's Jacobian over the step, in Arb ball arithmetic.

One step from t to t + h of the set m + A r (docs/theory.md, "Certified enclosures"):

* :func:`centre_polynomial` -- the Taylor polynomial p of order N of the flow from the centre m, from the Lie
  engine's fixed-point jets (:func:`jet_stepper`), as exact binary numbers (:class:`Centre`);
* :func:`defect_coefficients` -- the defect g = f(p) - p' at the step's start: exact in rational arithmetic for a
  polynomial field (:func:`exact_data`), on ball series otherwise; :func:`defect_terms` and
  :func:`step_estimate` read it;
* :func:`prove_step` -- the remainder bound |x - p| <= exp(|tau| L) int |g|, its Lagrange term from
  :func:`lagrange_majorant` (a float majorant series, polynomial fields) or from :func:`field_series` over the
  step, and the a priori box R around p's range that no solution from the set leaves (by continuation);
* :func:`flow_jacobian` -- the Jacobian of the flow over the step, by the Peano-Baker series over pieces of it.
"""

from __future__ import annotations

import math
import weakref
from fractions import Fraction

import mpmath
import numpy as np

from . import cache
from .ball_series import (Singular, check_ops, evaluate, exact_constant, taylor_coefficients, whole_series,
                          working_precision)
from .precision import Precision

__all__ = ["Centre", "centre_polynomial", "field_series", "defect_coefficients", "defect_terms",
           "defect_polynomials", "lagrange_majorant", "prove_step", "exp_times", "jacobian_program",
           "flow_jacobian", "exact_data", "jet_stepper", "nth_root", "step_estimate", "affine_in_state",
           "jacobian_pieces", "DEFECT_EXTRA", "BOX_MARGIN", "BOX_SPREAD", "JACOBIAN_TERMS", "JACOBIAN_EPS",
           "JACOBIAN_PIECES", "WIDE_JACOBIAN_PIECES", "AFFINE_JACOBIAN_PIECES", "AFFINE_WIDE_JACOBIAN_PIECES",
           "JACOBIAN_MU", "MAX_JACOBIAN_PIECES", "JACOBIAN_DEGREE", "JET_EXTRA_DPS"]


def centre_polynomial(stepper, prog, m, pars, consts, order, flint, span, deadline=None):
    """The Taylor polynomial of order ``order`` of the flow from the point m, as a :class:`Centre` of exact
    binary numbers, and the jets it came from (None after the fallback).

    Nothing about these coefficients needs proving: the remainder bound (:func:`defect_polynomials`) holds for any
    polynomial p with p(0) = m, and only its size depends on p being close to the flow. They come from the Lie
    engine's fixed-point jets (``stepper``, a :class:`~lieseries.lie.fixed.FixedStepper` of the chart's field:
    integers ``M`` with c_k = M * 2^(u - s k), taken exactly as the coefficients in the jets' scaled time
    sigma = 2^-s tau: no composition), or from Picard iteration on Arb series when the jets fail (s = 0).
    ``span``: the time left (the stepper's time scale covers it when the solution is a polynomial). Past
    ``deadline`` (a perf_counter value) both stop with :class:`~lieseries.lie.plan.DeadlineExceeded`."""
    arb = flint.arb
    try:
        jets = stepper.expand([mpmath.make_mpf(mpmath.libmp.from_man_exp(*(int(q) for q in v.mid().man_exp())))
                               for v in m], span, deadline)
    except (ZeroDivisionError, ValueError, ArithmeticError):
        rows = [[arb(c.mid()) for c in row] for row in taylor_coefficients(prog, m, pars, consts, order, flint,
                                                                deadline=deadline)]
        return Centre([flint.arb_poly([mi] + row[1:]) for mi, row in zip(m, rows)], m, 0, order, flint), None
    fmpq, fmpq_poly, fmpz_poly = flint.fmpq, flint.fmpq_poly, flint.fmpz_poly
    exact, bits = [], 0
    for Mi, u, mi in zip(jets.M, jets.U, m):
        ints = [int(c) for c in Mi]
        ints[0] = 0  # p(0) = m exactly (the jets hold the state rounded)
        man, exp = (int(v) for v in mi.mid().man_exp())
        integers = fmpz_poly(ints)
        bits = max(bits, int(integers.height_bits()), man.bit_length())
        exact.append(fmpq_poly(integers) * _fmpq_two(u, fmpq) + fmpq(man) * _fmpq_two(exp, fmpq))
    with working_precision(bits + 64):  # above every numerator (integers below 2^(bits) times powers of two):
        polys = [flint.arb_poly(q) for q in exact]  # the balls are exact
    return Centre(polys, m, jets.s, order, flint, exact), jets


def _fmpq_two(e, fmpq):
    """2^e as an fmpq."""
    return fmpq(1 << e) if e >= 0 else fmpq(1, 1 << -e)


class Centre:
    """The centre polynomials p_i(tau) = sum_k c_ik sigma^k of order ``order`` in the scaled time
    sigma = 2^-s tau: ``polys`` (exact arb_polys), ``exact`` (the same as fmpq_polys, or None), ``mids`` the centre
    itself (p(0))."""

    def __init__(self, polys, mids, s, order, flint, exact=None):
        self.polys, self.mids, self.s, self.order, self.flint, self.exact = polys, mids, s, order, flint, exact
        self.down = flint.arb(2) ** -s  # sigma per unit of tau (exact)
        self._rows = None

    @property
    def rows(self):
        """The coefficients as exact balls, ``rows[i][k]`` (k <= order)."""
        if self._rows is None:
            arb = self.flint.arb
            self._rows = []
            for p, mi in zip(self.polys, self.mids):
                row = [mi] + list(p.coeffs())[1:self.order + 1]
                self._rows.append(row + [arb(0)] * (self.order + 1 - len(row)))
        return self._rows

    def sigma(self, tau):
        """The scaled time of the ball ``tau`` (exactly: a power of two)."""
        return tau * self.down

    def at(self, tau):
        """p(tau) for a ball ``tau``: an enclosure of the polynomials' range over it."""
        x = self.sigma(tau)
        return [p(x) for p in self.polys]

    def unscaled(self):
        """The coefficients c_k of p in tau, exactly: ``out[i][k]``."""
        flint = self.flint
        with working_precision(max(64, max(c.mid().man_exp()[0].bit_length() for row in self.rows for c in row)
                                   + 64 + abs(self.s) * len(self.rows[0]))):
            return [[c * flint.arb(2) ** (-self.s * k) for k, c in enumerate(row)] for row in self.rows]


def field_series(prog, polys, pars, consts, length, flint, base=None):
    """Coefficients 0..length-1 of f(p(base + tau)) in tau, for the polynomials p = ``polys`` (base: a ball,
    default 0): ``out[i][k]``."""
    arb, arb_series = flint.arb, flint.arb_series
    if base is None:
        series = [arb_series(row, prec=length) for row in polys]
    else:
        x = arb_series([base, arb(1)], prec=length)
        series = []
        for row in polys:
            acc = arb_series([row[-1]], prec=length)
            for c in reversed(row[:-1]):
                acc = acc * x + c
            series.append(acc)
    f = evaluate(prog, series, pars, consts, arb_series([arb(1)], prec=length))
    out = []
    for fi in f:
        got = (list(whole_series(fi, length).coeffs()) if isinstance(fi, arb_series)
               else [fi if isinstance(fi, arb) else arb(fi)])
        out.append(got[:length] + [arb(0)] * (length - len(got)))
    return out


#: Orders beyond N at which the defect's Taylor coefficients are computed at the step's start; the Lagrange term
#: over the whole step comes after them (so its overestimate is damped by (h / radius of convergence)^EXTRA).
DEFECT_EXTRA = 8


def defect_coefficients(prog, centre, pars, consts, flint, exact=None, fine=None):
    """The defect g = f(p) - dp/dtau of the :class:`Centre` p (order N) at the step's start, in the scaled time
    sigma = 2^-s tau (dp/dtau = 2^-s dp/dsigma), as ``(low, high)``: per component, ``low[i]`` an upper bound of
    |g_k| for every k < N (the rounding of the jets: p is close to the flow's Taylor polynomial) and ``high[i]``
    balls holding g_N..g_{N+EXTRA-1} (the field's own terms).

    ``fine``: where ``low[i]`` exceeds it, ``low[i]`` is instead the list of upper bounds of |g_0|..|g_{N-1}|, one
    per order. The jets' rounding is relative to their time scale: when the step is much shorter than that scale
    (coefficients growing like 2^k in sigma: a first step with the scale of the whole run), the rounding of the
    high orders, taken for every order, dwarfs the first ones and no step is proved (a relativistic oscillator:
    6e-11 at order N - 1 against a tolerance of 1e-24).

    ``exact``: the parameters and constants as fmpqs (:func:`exact_data`) when the field is a polynomial with
    exact constants; with the centre's exact polynomials (the jets' integers), f(p) is then computed in exact
    rational arithmetic (FLINT's fmpq series) and g is exact before it is bounded; otherwise on Arb series at the
    working precision."""
    arb = flint.arb
    N = centre.order
    L = N + DEFECT_EXTRA
    if flint.ctx.cap < L + 1:  # series beyond the cap are cut silently: the terms from N on would be lost
        raise AssertionError("the series cap must exceed the defect's length (set by the run, unless another "
                             "thread lowered it without working_precision)")  # pragma: no cover
    if exact is not None and centre.exact is not None:
        fmpq, series = flint.fmpq, flint.fmpq_series
        F = evaluate(prog, [series(q, prec=L) for q in centre.exact], exact[0], exact[1], series([1], prec=L))
        down = _fmpq_two(-centre.s, fmpq)
        lows, highs = [], []
        with working_precision(64):
            for fi, q in zip(F, centre.exact):
                if not isinstance(fi, series):  # a constant component of the field
                    fi = series([fi], prec=L)
                g = whole_series(fi - series(q.derivative(), prec=L) * down, L)
                num, den = g.numer().coeffs(), arb(g.denom())
                # |g_k| < 2^height for k < N: a factor below 2 on the jets' rounding, far under the tolerance
                low = flint.fmpz_poly(num[:N]).height_bits() if len(num) else 0
                low = (arb(2) ** low / den).upper() if low else arb(0)
                if fine is not None and low > fine:  # per order: |g_k| < 2^(bit length of its numerator) / d
                    low = [(arb(2) ** abs(int(c)).bit_length() / den).upper() if c else arb(0) for c in num[:N]]
                    low += [arb(0)] * (N - len(low))
                lows.append(low)
                highs.append([arb(num[k]) / den if k < len(num) else arb(0) for k in range(N, L)])
        return lows, highs
    arb_series = flint.arb_series
    P, down = centre.rows, centre.down
    F = evaluate(prog, [arb_series(row, prec=L) for row in P], pars, consts, arb_series([arb(1)], prec=L))
    lows, highs = [], []
    for fi, row in zip(F, P):
        if not isinstance(fi, arb_series):  # a constant component of the field
            fi = arb_series([fi if isinstance(fi, arb) else arb(fi)], prec=L)
        got = list(whole_series(fi - arb_series(row, prec=L + 1).derivative() * down, L).coeffs())
        got = got[:L] + [arb(0)] * (L - len(got))
        with working_precision(64):
            low = [abs(x).upper() for x in got[:N]]
            top = max([arb(0)] + low)
            lows.append(low if fine is not None and top > fine else top)
        highs.append(got[N:])
    return lows, highs


def defect_terms(g, N, flint):
    """(low, high): per component, the bound of |g_k| below N and the upper bounds |g_k| / (k + 1) from N on that
    :func:`defect_polynomials` sums (at 64 bits: upper bounds), from :func:`defect_coefficients`."""
    lows, highs = g
    with working_precision(64):
        return lows, [[(abs(x) / (k + 1)).upper() for k, x in enumerate(gi, N)] for gi in highs]


def defect_polynomials(terms, top, N, flint):
    """Per component, the polynomial d_i(t) = low_i sum_{k<N} t^k / (k+1) + sum_{k>=N} |g_k| t^k / (k+1)
    + |top_i| t^L / (L+1) (``terms`` = (low, high) from :func:`defect_terms`, low_i one bound or a list of one per
    order, as from :func:`defect_coefficients`; ``top``: the L-th coefficient of g
    over the whole step, L = N + len(high[i])): |tau| d_i(|tau|) bounds int_0^|tau| |g_i(s)| ds (nonnegative
    coefficients: its value at a point is tight). In the scaled time: sigma and g's coefficients in sigma give the
    bound divided by 2^s."""
    lows, highs = terms
    arb, arb_poly = flint.arb, flint.arb_poly
    base = _LOW_SUMS.get(N)
    if base is None:
        base = _LOW_SUMS[N] = arb_poly([(arb(1) / (k + 1)).upper() for k in range(N)])
    out = []
    for low, gi, ti in zip(lows, highs, top):
        L = N + len(gi)
        first = (arb_poly([(x * b).upper() for x, b in zip(low, base.coeffs())]) if isinstance(low, list)
                 else base * low)
        out.append(first + arb_poly([0] * N + gi + [(abs(ti) / (L + 1)).upper()]))
    return out


#: sum_{k<N} t^k / (k + 1) with upper-bound coefficients, per N (64 bits).
_LOW_SUMS: dict = {}


#: The majorant is computed in floating point when the run's working precision is at most this many bits (its
#: integers convert to floats, and its floor, below, stays far under 10^-dps).
MAJORANT_MAX_BITS = 700
#: Every value of the majorant series is raised to at least this (a majorant stays one; no float underflows).
MAJORANT_FLOOR = 1e-280
#: The scaled coefficients |c_k| |h|^k must be at least this (or 0): the majorant is not used otherwise.
MAJORANT_TINY = 1e-290
#: Every float operation of the majorant is raised by this factor (its relative rounding error is below 2^-52).
MAJORANT_UP = 1 + 2.0**-50
_PASCAL: dict = {}


def lagrange_majorant(prog, P, jets, h, par_values, L, flint):
    """Per component, an upper bound (an arb) of |[f(p(xi + tau))]_L| (the L-th Taylor coefficient in tau) over
    every xi between 0 and h, for the centre polynomial p (its coefficients from the integer ``jets``:
    c_k = M 2^(u - s k), the centre itself as ``P[i][0]``) and a polynomial field f; None when the field is not a
    polynomial or the numbers leave the float range.

    In the time u = tau / |h|, the shifted polynomial's coefficients are bounded by those of a(1 + u) with
    a_k = |c_k| |h|^k (binomial expansion, |xi| <= |h|), and a polynomial field's Taylor coefficients of order L by
    those of its majorant (constants and parameters by their absolute values, subtractions as additions) on these
    nonnegative series. Everything is nonnegative, so floating point errs by a relative 2^-52 per operation and
    term (a few parts in 10^12 here; the result is raised by 1%), underflow is kept off by a floor that only
    raises values, and overflow gives None. The bound of order L in tau is the one in u divided by |h|^L."""
    if jets is None or max(int(max(map(abs, Mi))).bit_length() for Mi in jets.M) > MAJORANT_MAX_BITS:
        return None
    hq = abs(Fraction(h))
    if hq == 0:
        return None
    ops = {"add", "sub", "neg", "mul", "powi"}
    if any(node.op not in ops or (node.op == "powi" and int(node.data) < 0) for node in prog.nodes):
        return None
    try:
        vals = _majorant_inputs(prog, P, jets, hq, par_values, L)
        if vals is None:
            return None
        tops = _majorant_outputs(prog, vals, L)
    except (OverflowError, ValueError):
        return None
    if not all(math.isfinite(t) for t in tops):
        return None
    arb = flint.arb
    hL = arb(flint.fmpq(hq.numerator, hq.denominator)) ** L
    return [(arb(t) / hL).upper() for t in tops]


def _majorant_inputs(prog, P, jets, hq, par_values, L):
    """The majorant's values before the field's nodes: per variable, the series a(1 + u) up to order L (the
    shifted centre polynomial's bound in u = tau / |h|); parameters and constants as their absolute values (floats).
    None when a coefficient is too close to the float range for the floor to stay a bound."""
    up = MAJORANT_UP
    N = len(jets.M[0]) - 1
    hs = float(hq) * 2.0 ** -jets.s * up
    hpow = np.cumprod(np.concatenate(([1.0], np.full(N, hs))))
    T = _PASCAL.get(N)
    if T is None:
        T = _PASCAL[N] = np.array([[math.comb(k, j) for k in range(N + 1)] for j in range(N + 1)], dtype=float)
    vals = [None] * prog.nslots  # series (arrays of L + 1) or constants (floats)

    def series(v):
        out = np.zeros(L + 1)
        out[: min(len(v), L + 1)] = v[: L + 1]
        return np.maximum(out, MAJORANT_FLOOR)

    def scalar(x):
        return max(abs(x) * up, MAJORANT_FLOOR)

    M = np.abs(np.array([list(map(float, Mi)) for Mi in jets.M]))
    A = np.ldexp(M, np.array(jets.U)[:, None]) * hpow * up
    A[:, 0] = [abs(float(row[0].mid())) * up for row in P]  # the centre itself (the jets hold it rounded)
    if np.any((A < MAJORANT_TINY) & (M != 0)):
        # a coefficient near or below the float range: a dropped term, times the binomials (up to 2^N),
        # could exceed the floor
        return None
    for i, v in enumerate(A @ T.T * up):
        vals[i] = series(v)
    for j, q in enumerate(par_values):
        vals[prog.nvars + j] = scalar(float(abs(Fraction(q))))
    for slot, (kind, value) in prog.constants:
        if kind == "rational":
            x = abs(Fraction(*value))
        elif kind == "binary":
            x = abs(math.ldexp(float(value[1]), value[2]))
        else:
            x = 3.2 if kind == "pi" else 2.8
        vals[slot] = scalar(float(x))
    return vals


def _majorant_outputs(prog, vals, L):
    """The field's nodes on the majorant's values (``vals``, filled in place): per output, the bound of its
    coefficient L in u (inf or nan after an overflow)."""
    up = MAJORANT_UP
    top_only = _top_only(prog)
    for node in prog.nodes:
        a = [vals[x] for x in node.args]
        if node.out in top_only:
            # only coefficient L is read downstream (through sums): a _Top, no series
            if node.op in ("add", "sub", "neg"):  # a constant adds to coefficient 0 only
                v = sum(x.value if isinstance(x, _Top) else x[L] for x in a if not isinstance(x, float))
            else:
                factors = a if node.op == "mul" else [a[0]] * int(node.data)
                c, ser = 1.0, [x for x in factors if not isinstance(x, float)]
                for x in factors:
                    if isinstance(x, float):
                        c *= x
                if not ser:
                    v = 0.0
                else:
                    w = ser[0]
                    for x in ser[1:-1]:
                        w = np.convolve(w, x)[: L + 1]
                    v = (float(w[L]) if len(ser) == 1 else float(np.dot(w, ser[-1][::-1]))) * c
            vals[node.out] = _Top(max(v * up, MAJORANT_FLOOR))
            continue
        if node.op in ("add", "sub"):
            # a constant c is the series (|c|, 0, 0, ...): it adds to the first coefficient only
            c = sum(x for x in a if isinstance(x, float))
            s = [x for x in a if not isinstance(x, float)]
            if not s:
                v = c
            else:
                v = s[0].copy()
                for x in s[1:]:
                    v += x
                v[0] += c
        elif node.op == "neg":
            v = a[0]
        else:  # products: the constant factors multiply, the series convolve
            factors = a if node.op == "mul" else [a[0]] * int(node.data)
            c, v = 1.0, None
            for x in factors:
                if isinstance(x, float):
                    c *= x
                else:
                    v = x if v is None else np.convolve(v, x)[: L + 1]
            v = c if v is None else v * c
        # an overflow (inf, or nan from inf * 0) reaches the outputs it feeds: checked there
        vals[node.out] = (max(v * up, MAJORANT_FLOOR) if isinstance(v, float)
                          else np.maximum(v * up, MAJORANT_FLOOR))
    return [MAJORANT_FLOOR if isinstance(vals[o], float) else
            (vals[o].value if isinstance(vals[o], _Top) else float(vals[o][L])) * 1.01 for o in prog.outputs]


class _Top:
    """Coefficient L alone of a nonnegative majorant series (a float), where nothing downstream needs the rest."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value


_TOP_ONLY: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _top_only(prog):
    """The slots of ``prog`` whose majorant series only the coefficient L of the outputs reads: outputs, and the
    arguments of sums, differences and negations that are themselves read so (a product's factors need their whole
    series)."""
    got = _TOP_ONLY.get(prog)
    if got is None:
        top, full = set(prog.outputs), set()
        for node in reversed(prog.nodes):  # every consumer of a slot comes after it
            if node.out in full or node.out not in top:
                if node.out in full:
                    full.update(node.args)
                continue
            if node.op in ("add", "sub", "neg"):
                top.update(x for x in node.args if x not in full)
            else:
                full.update(node.args)
        got = _TOP_ONLY[prog] = frozenset(top - full - set(range(prog.nvars + prog.npars))
                                          - {slot for slot, _ in prog.constants})
    return got


#: The box R around the centre polynomial's range over a step reaches this far beyond it (relative to the state's
#: size, plus a multiple of the set's spread): every solution from the set is proved to stay well inside it.
BOX_MARGIN = 2.0**-30
BOX_SPREAD = 8


def prove_step(prog, jprog, centre, terms, pars, consts, jconsts, step, spread, flint, majorant=None):
    """(``tail``, the box R that holds every solution from the set over the step, ``reach``, L) for the step
    ``step`` (h as a ball, negative backward: a non-binary h is not exact), or None when the step is not proved.
    ``tail(tau)``: per component, an upper bound of |phi_tau(m) - p(tau)| for the centre's solution, |tau| <= h;
    ``reach(tau)``: of |phi_t(y) - p(t)| for every
    y in the set and |t| <= |tau|; L: the entrywise upper bounds of |Df(R)| (a matrix).

    The centre's solution x from m = p(0) and the centre polynomial p (``centre``, a :class:`Centre`) differ by
    e = x - p with e' = g + A(s) e, g = f(p) - p' the defect (its coefficients in the centre's scaled time at the
    step's start, as ``terms`` from :func:`defect_terms`) and A(s) a mean of Df over the segment from p(s) to
    x(s). R is the range of p over the step widened by delta (BOX_MARGIN of the state, and BOX_SPREAD times the
    set's ``spread``: per component, an upper bound of |y - m| over the set); L = |Df(R)| entrywise. While x stays
    in R (a box: the segment too), |e(tau)| <= exp(|tau| L) G(tau) componentwise, G the integral of |g| over the
    step bounded by :func:`defect_polynomials` with the Lagrange term taken over the whole step (from a majorant
    series in floating point, :func:`lagrange_majorant`, when ``majorant`` = (the centre's integer jets, |h|, the
    parameters) is given and the field is a polynomial; else by ball series at 64 bits); and a solution x_y from
    y in the set, while it stays in R, is within exp(|t| L) |y - m| of x. Their sum, exp(|t| L) (G(t) + spread),
    is ``reach``; when reach(h) < delta, no solution can leave R during the step (at a first exit it would be at
    distance delta from p, more than the bound that holds up to then), so every solution from the set exists over
    the step and stays in R (docs/theory.md)."""
    span = step / 2 + flint.arb(0, abs(step) / 2)  # the ball [0, h] (or [h, 0]) for every h in the ball ``step``
    try:
        with working_precision(64):
            box = _a_priori_box(prog, jprog, centre, pars, consts, jconsts, span, spread, flint)
            if box is None:
                return None
            delta, R, L = box
            Lg = centre.order + len(terms[1][0])  # the order of the Lagrange term
            top = _lagrange_term(prog, centre, pars, consts, span, Lg, majorant, flint)
    except (ZeroDivisionError, ValueError):
        return None
    if not all(t.is_finite() for t in top):
        return None
    with working_precision(64):
        defect = defect_polynomials(terms, top, centre.order, flint)
    tail, reach = _remainder_bounds(centre, defect, L, spread, flint)
    # at the ball h itself (so at every |t| <= |h|, not at a rounded midpoint when h is not binary); the same key
    # as the bound at h that the run reads next, and the Jacobian's reach(h)
    if not all(r < d for r, d in zip(reach(step), delta)):
        return None
    return tail, R, reach, L


def _a_priori_box(prog, jprog, centre, pars, consts, jconsts, span, spread, flint):
    """(delta, R, L) of :func:`prove_step`: the margins delta, the box R around p's range over the step (the ball
    ``span``) widened by them, and the entrywise upper bounds L of |Df(R)|; None when the field or its Jacobian is
    not finite on R."""
    arb, arb_mat = flint.arb, flint.arb_mat
    n = len(centre.polys)
    P = centre.at(span)  # the range of p over the step
    delta = [((abs(p.mid()) + p.rad() + 1) * BOX_MARGIN + BOX_SPREAD * e).upper() for p, e in zip(P, spread)]
    R = [arb(p.mid(), (p.rad() + d).upper()) for p, d in zip(P, delta)]
    # the field and its Jacobian finite on R: f is smooth there (no pole, no root or logarithm at its branch)
    if not all((v if isinstance(v, arb) else arb(v)).is_finite() for v in evaluate(prog, R, pars, consts, arb(1))):
        return None
    vals = evaluate(jprog, R, pars, jconsts, arb(1))
    L = arb_mat([[abs(v if isinstance(v, arb) else arb(v)).upper() for v in vals[i * n:(i + 1) * n]]
                 for i in range(n)])
    if not all(x.is_finite() for x in (L * arb_mat([[1]] * n)).entries()):  # row sums of upper bounds
        return None
    return delta, R, L


def _lagrange_term(prog, centre, pars, consts, span, Lg, majorant, flint):
    """Per component, the defect's coefficient ``Lg`` (the Lagrange term) over the step, in the centre's scaled
    time: from the majorant series when ``majorant`` is given and the field is a polynomial
    (:func:`lagrange_majorant`), else on ball series over the step (:func:`field_series`)."""
    top = (None if majorant is None
           else lagrange_majorant(prog, [[mi] for mi in centre.mids], *majorant, Lg, flint))
    if top is None:  # coefficient Lg in sigma, over the step in sigma
        return [row[-1] for row in field_series(prog, centre.rows, pars, consts, Lg + 1, flint,
                                                base=centre.sigma(span))]
    up = flint.arb(2) ** (centre.s * Lg)  # coefficient Lg in tau, times 2^(s Lg): in sigma
    return [(t * up).upper() for t in top]


def _remainder_bounds(centre, defect, L, spread, flint):
    """(``tail``, ``reach``) of :func:`prove_step` from the defect's polynomials (:func:`defect_polynomials`):
    exp(|tau| L) G(|tau|), and exp(|tau| L) (G(|tau|) + ``spread``), per component (upper bounds), each computed
    once per time."""
    arb_mat = flint.arb_mat
    n = len(centre.polys)
    back = flint.arb(2) ** centre.s  # the bound in sigma, in tau
    known = {}

    def bound(tau, with_spread):
        at = tuple(int(v) for v in abs(tau).upper().mid().man_exp())
        if (at, with_spread) not in known:
            with working_precision(64):
                if at not in known:
                    x = abs(centre.sigma(tau))
                    known[at] = [((d(x) * x).upper() * back).upper() for d in defect]  # G(|tau|)
                g = known[at]
                if with_spread:
                    g = [(gi + e).upper() for gi, e in zip(g, spread)]
                E = exp_times(L * abs(tau), arb_mat([[gi] for gi in g]), flint)
                known[at, with_spread] = [E[i, 0].upper() for i in range(n)]
        return known[at, with_spread]

    def tail(tau):
        return bound(tau, False)

    def reach(tau):
        return bound(tau, True)

    return tail, reach


def exp_times(M, g, flint):
    """exp(M) g for a matrix M and a column g with nonnegative entries (balls of exact values): the series
    sum_j M^j g / j! by matrix-vector products, its tail bounded entrywise by mu^(j+1) / (j+1)! / (1 - mu / (j+2))
    ||g||_inf (mu = ||M||_inf: every entry of M^i g is at most mu^i ||g||_inf), stopped below 2^-40 of ||g||_inf
    (a bound, not a tight value: cheaper than the matrix exponential, which it uses when mu >= 16)."""
    arb, arb_mat = flint.arb, flint.arb_mat
    n = g.nrows()
    mu = max([arb(0)] + [x.upper() for x in (M * arb_mat([[1]] * n)).entries()])  # the row sums
    if not mu < 16:  # a long series: Arb's matrix exponential (scaling and squaring)
        return M.exp() * g
    size = max([arb(0)] + [g[i, 0].upper() for i in range(n)])
    S = T = g
    j, rest = 0, size  # rest: mu^(j+1) / (j+1)! ||g||, the first term left out
    while True:
        rest = (rest * mu / (j + 1)).upper()
        if mu < j + 2 and rest / (1 - mu / (j + 2)) <= size * 2.0**-40:
            break
        j += 1
        T = M * T / j
        S = S + T
    tail = (rest / (1 - mu / (j + 2))).upper()
    return S + arb_mat([[arb(0, tail)] for _ in range(n)])


_JACOBIANS = cache.region("validated.jacobians", 64)
#: Terms of the interval-matrix exponential that encloses the flow's Jacobian over one piece of a step, and the
#: number of pieces a step is cut into for it (more when the set is wider than 10^-dps, as from
#: uncertain data, where the Jacobian's own width multiplies the set's spread: measured on the rigid body at 50
#: digits from data known to a double's width, the final ball at T = 10 is 1.0e-14 with 16 pieces, 8.9e-15 with 24,
#: for a few percent more time).
JACOBIAN_TERMS = 10
#: Fewer terms when their tail bound is below this (relative to the identity: the Jacobian multiplies the set's
#: spread only; its width comes mostly from the range of Df over each piece, ~2e-2 on the rigid body at 50 digits:
#: to T = 10 it certifies 52.4616 digits with a tail below 2^-30, 52.4606 below 2^-20 with one matrix product fewer
#: a piece, 52.40 below 2^-14 and 51.44 below 2^-10, where the tail, added to every entry, widens the entries that
#: are otherwise near-exact).
JACOBIAN_EPS = 2.0**-20
#: 16 pieces, not 8, since the steps are only as short as the remainder's tolerance asks (no a priori box from the
#: set's Taylor coefficients limits them): the sphere at 50 digits to T = 10 takes 139 steps and certifies 45.7
#: digits with 8 pieces, 46.2 with 16, 46.4 with 32 (216 steps and 46.7 digits before, with 8).
JACOBIAN_PIECES = 16
WIDE_JACOBIAN_PIECES = 24
#: The same for a field whose Jacobian is affine in the state (a field of degree 2, as the rigid body's): the first
#: term of each piece's series is then near-exact (:func:`flow_jacobian`) and the Jacobian's width shrinks like the
#: square of the pieces' length, not like their length. The rigid body at 50 digits to T = 10: 52.46 certified
#: digits with 8 pieces before, 52.64 with 8, 52.58 with 3 (a Jacobian at half the cost), 52.47 with 2; from
#: double-width data the final ball 8.95e-15 with 24 pieces before, 7.20e-15 with 24, 7.42e-15 with 8.
AFFINE_JACOBIAN_PIECES = 3
AFFINE_WIDE_JACOBIAN_PIECES = 8
#: The centre polynomial's terms up to this degree give the pieces' boxes; the rest is bounded over the step.
JACOBIAN_DEGREE = 16
#: More pieces, up to MAX_JACOBIAN_PIECES, when |Df| |tau| over the step exceeds JACOBIAN_MU per piece.
JACOBIAN_MU = 1.0
MAX_JACOBIAN_PIECES = 1024


def jacobian_program(ps):
    """The Jacobian of the vector field, d f_i / d z_j (row-major), compiled once per structure."""
    prog = _JACOBIANS.get(ps.key)
    if prog is None:
        import heyoka as hy

        from .expr import compile_expressions

        exprs = [hy.diff(fi, vj) for fi in ps.vector_field for vj in ps.variables]
        prog = compile_expressions(ps.variables, exprs, len(ps.parameter_values))
        check_ops(prog)
        _JACOBIANS[ps.key] = prog
    return prog


def jacobian_pieces(jprog, wide: bool) -> int:
    """The pieces a step is cut into for the flow's Jacobian (:func:`flow_jacobian`): for a set wider than 10^-dps
    of the state (``wide``) or not, and a Jacobian program affine in the state or not."""
    if affine_in_state(jprog):
        return AFFINE_WIDE_JACOBIAN_PIECES if wide else AFFINE_JACOBIAN_PIECES
    return WIDE_JACOBIAN_PIECES if wide else JACOBIAN_PIECES


def flow_jacobian(jprog, centre, reach, L, pars, consts, tau, flint, pieces=JACOBIAN_PIECES):
    """An enclosure of every Jacobian d phi_tau(y) / dy of the flow over time ``tau`` (an exact ball) for all
    starting points y in the set, or None when the bound below does not apply.

    ``centre``: the step's :class:`Centre` p; ``reach(t)``: per component, an upper bound of |phi_s(y) - p(s)| for
    every y in the set and |s| <= |t|; ``L``: entrywise upper bounds of |Df| over every solution during the step
    (from :func:`prove_step`). The step is cut into ``pieces`` pieces; over piece i every solution lies in
    B_i = q(T_i) +- (reach(tau) + r) (T_i the piece's time interval, q the terms of p up to JACOBIAN_DEGREE
    evaluated in mean-value form about the piece's middle time, r a bound of p's other terms over the step).
    d phi / dy solves V' = Df(z(t)) V, so over piece i it is multiplied by a matrix of the
    Peano-Baker series sum_j (dt Df(B_i))^j / j!, truncated after K terms (the fewest whose tail bound is below
    JACOBIAN_EPS, at most JACOBIAN_TERMS) with the tail bounded entrywise by mu^(K+1) / (K+1)! / (1 - mu / (K+2)),
    mu = |dt| ||L||_inf (docs/theory.md). When Df is affine in the state (:func:`affine_in_state`), the series'
    first term, the integral of Df(z_y(t)) over the piece, is dt times Df at the mean of z_y over the piece, which
    lies within reach(tau) + r of the mean of q over the piece (its integral, exactly); the terms from the second on
    keep Df(B_i). Computed at 64 bits: the Jacobian multiplies the set's tiny spread only."""
    arb, arb_mat = flint.arb, flint.arb_mat
    n = len(centre.polys)
    eye = arb_mat([[1 if i == j else 0 for j in range(n)] for i in range(n)])
    with working_precision(64):
        # p in the scaled time sigma = 2^-s tau (exactly: a power of two), its terms beyond JACOBIAN_DEGREE
        # bounded over the step (their sum on the ball of the step's sigmas) and added to the boxes' radii
        down, back = centre.down, arb(2) ** centre.s
        within = arb(0, abs(tau * down).upper())  # every sigma of the step
        polys = [p.truncate(JACOBIAN_DEGREE + 1) for p in centre.polys]
        rest = [abs((p - q)(within)).upper() for p, q in zip(centre.polys, polys)]
        slopes = [p.derivative() for p in polys]

        def box(lo, hi, radii):
            """Every solution from the set over the times between lo and hi: p in mean-value form (its range
            over the interval lies in p(centre) + p'(interval) (interval - centre)) widened by ``radii``."""
            centre_s = (lo + hi) / 2 * down
            seg = centre_s + arb(0, abs(hi - lo) / 2 * down)
            return [p(centre_s) + dp(seg) * (seg - centre_s) + arb(0, r)
                    for p, dp, r in zip(polys, slopes, radii)]

        # a badly scaled field (|Df| |tau| large: a fast oscillation in a slow state) needs more pieces: the
        # series of each piece converges like mu^j / j!, and mu near JACOBIAN_TERMS makes the enclosure explode
        norm = max(x.upper() for x in (L * arb_mat([[1]] * n)).entries()) * abs(tau)  # exact bounds compare
        if not norm.is_finite():
            return None
        pieces = max(pieces, min(MAX_JACOBIAN_PIECES, math.ceil(float(norm.upper()) / JACOBIAN_MU)))
        dt = tau / pieces
        # every solution over a piece lies in the whole step's box: the same mu bounds every piece
        mu = (norm / pieces).upper()
        if not mu < JACOBIAN_TERMS + 2:
            return None
        terms, eps = _series_terms(mu, arb)
        tail = arb_mat([[arb(0, eps)] * n for _ in range(n)])
        steps = [None] + [dt / j for j in range(1, terms + 1)]  # the series' term j is (dt Df)^j / j!
        # Df affine in the state: the first term, the integral of Df(z(t)) over the piece, is dt Df(mean of z)
        prims = [p.integral() for p in polys] if affine_in_state(jprog) else None
        radii = [(r + e).upper() for r, e in zip(reach(tau), rest)]  # for every piece (they grow with the time)
        J = eye
        for piece in range(pieces):
            lo, hi = dt * piece, dt * (piece + 1)
            try:
                vals = evaluate(jprog, box(lo, hi, radii), pars, consts, arb(1))
                if prims is not None:
                    # the mean of every solution over the piece: within reach of p's mean, its integral
                    mean = [(q(hi * down) - q(lo * down)) * back / dt + arb(0, r) for q, r in zip(prims, radii)]
                    first = arb_mat(n, n, evaluate(jprog, mean, pars, consts, arb(1))) * dt
            except Singular:
                return None
            M = arb_mat(n, n, vals)  # Df(B_i); dt comes in with 1/j
            T = M * steps[1]
            S = eye + (T if prims is None else first)
            for j in range(2, terms + 1):
                T = T * M * steps[j]
                S = S + T
            J = S + tail if piece == 0 else (S + tail) * J
        if not all(J[i, j].is_finite() for i in range(n) for j in range(n)):
            return None
        return J


_AFFINE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def affine_in_state(prog) -> bool:
    """Every output of ``prog`` is an affine function of its variables (a polynomial of degree at most 1 in them,
    with parameters and constants as coefficients): the Jacobian program of a field of degree 2, as the rigid
    body's. Decided from the operations (the degree of each slot), once per program."""
    got = _AFFINE.get(prog)
    if got is None:
        deg = dict.fromkeys(range(prog.nvars), 1)  # parameters and constants: degree 0
        for node in prog.nodes:
            a = [deg.get(x, 0) for x in node.args]
            if node.op in ("add", "sub", "neg"):
                d = max(a)
            elif node.op == "mul":
                d = sum(a)
            elif node.op == "powi" and int(node.data) >= 0:
                d = a[0] * int(node.data)
            elif node.op == "div" and a[1] == 0:
                d = a[0]
            else:  # any other operation of a state-dependent argument
                d = 0 if max(a) == 0 else 2
            deg[node.out] = d
        got = _AFFINE[prog] = all(deg.get(o, 0) <= 1 for o in prog.outputs)
    return got


def _series_terms(mu, arb):
    """(K, bound): the fewest terms K of the Peano-Baker series whose tail bound is below JACOBIAN_EPS (at most
    JACOBIAN_TERMS), and the rigorous bound mu^(K+1) / (K+1)! / (1 - mu / (K+2)) of that tail's entries (an
    upper bound, at the current ball precision). The geometric bound of the tail needs mu < K + 2 (the caller
    ensures mu < JACOBIAN_TERMS + 2): a smaller K is taken only where it holds (float(mu) < K + 2 implies it,
    K + 2 being a float), else the quotient is negative and no bound at all."""
    mu_f = float(mu.upper())
    terms, term = JACOBIAN_TERMS, mu_f  # term: mu^(j+1) / (j+1)!
    for j in range(1, JACOBIAN_TERMS):
        term *= mu_f / (j + 1)
        if mu_f < j + 2 and term / (1 - mu_f / (j + 2)) < JACOBIAN_EPS:
            terms = j
            break
    fact = arb(1)
    for j in range(2, terms + 2):
        fact *= j
    return terms, (mu ** (terms + 1) / fact / (1 - mu / (terms + 2))).upper()


def exact_data(ps, prog, flint):
    """(parameters, constants) as fmpqs for the exact defect (:func:`defect_coefficients`), or None when the field
    is not a polynomial (only sums, products and powers of nonnegative integer exponents) with rational or binary
    constants."""
    if not all(node.op in ("add", "sub", "neg", "mul") or (node.op == "powi" and int(node.data) >= 0)
               for node in prog.nodes):
        return None
    consts = [(slot, exact_constant(c, flint)) for slot, c in prog.constants]
    if any(c is None for _, c in consts):
        return None
    return [flint.fmpq(p.numerator, p.denominator) for p in ps.parameter_values], consts


def jet_stepper(ps, order, dps):
    """The fixed-point jets of a chart's field for the centre polynomials (:func:`centre_polynomial`), at
    ``dps`` + 6 digits and the jets' own guard bits (34 at order 67): their rounding, which the defect bounds,
    stays about ten digits below a step's tolerance of 10^-4 x 10^-dps, and the centre (at dps digits and 32
    guard bits) is exact at their precision."""
    from .lie.fixed import FixedStepper

    return FixedStepper(ps.program, list(ps.parameter_values), order, Precision.of(dps=dps, guard_digits=JET_EXTRA_DPS))


#: Digits of the centre's jets above the run's (:func:`jet_stepper`).
JET_EXTRA_DPS = 6


def nth_root(x, k: int) -> float:
    """x^(1/k) as a float, for a positive ball x of any size (a float of x itself may underflow)."""
    return float((x.log() / k).exp().mid())


def step_estimate(g, N, tol, flint) -> float:
    """The step at which the defect's terms from order N on, sum_k |g_k| h^(k+1) / (k+1) (what the remainder
    bound comes to for a step well inside the radius of convergence), reach ~tol: a first guess from g_N, refined
    once. The attempt that follows proves or shortens it; this choice affects efficiency, never rigour."""
    arb = flint.arb
    with working_precision(64):
        hi = [[arb(abs(x).mid()) for x in gi] for gi in g[1]]
        gN = max((row[0] for row in hi), key=float)
        if gN.is_zero():
            return math.inf
        h = arb(nth_root(tol * (N + 1) / gN, N + 1))

        def estimate(h):
            powers = [h ** (N + k + 1) / (N + k + 1) for k in range(len(hi[0]))]
            return max((sum((x * p for x, p in zip(row, powers)), arb(0)) for row in hi), key=float)

        return 0.97 * float(h.mid()) * nth_root(tol / estimate(h), N + 1)
