"""Certified digits: a validated Lie-series integrator in Arb ball arithmetic (python-flint).

``validated_integrate(system, y0, t, dps=...)`` returns a :class:`~lieseries.solution.Solution` whose rows are
enclosures: every component at every output time is an Arb ball (``flint.arb``: midpoint and radius) that provably
contains the exact solution of the exact problem (initial data and parameters taken exactly, or as balls when the
user gives uncertainties). The argument is in ``docs/theory.md`` ("Certified enclosures"); in short, the set of
states is carried in Lohner's form m + A r (a centre point, an orthogonal matrix, a box around 0), and each step

1. computes the Taylor polynomial p of order N of the flow from m (the Lie engine's fixed-point jets, as exact
   binary numbers: nothing about them needs proving), and the coefficients up to order 12 from the whole box
   Z = m + A r as balls, proved from a guess around p's in one evaluation of the field on Arb power series
   (``arb_series``; Picard iteration when the guess fails);
2. finds an a priori enclosure by the high-order enclosure theorem: a box B around the polynomials from Z over
   [0, h] such that sum_{j<=12} c_j(Z) [0, h]^j + c_13(B) [0, h]^13 lies inside B -- then every solution from Z
   exists on [0, h] and stays in B;
3. encloses the centre's solution x as p plus a bound of x - p, which solves e' = g + A(s) e with the defect
   g = f(p) - p' and A(s) in Df(R), R the box around B and p's range: |x(tau) - p(tau)| <= exp(|tau| L)
   int_0^tau |g| (L = |Df(R)| entrywise), the defect bounded from its Taylor coefficients at the step's start and
   a Lagrange term over the whole step -- a few times the true truncation error, so the steps are about as long
   as lie_integrate's;
4. encloses the Jacobian of the flow over the step (the variational equation over 8 or 16 pieces of the step,
   each in its own narrower box) and moves the set by the mean-value theorem and a QR step.

Nothing else is assumed: when no step down to the smallest is proved, or the widths grow beyond ``max_width``,
the run stops with status ``validation_failed`` and keeps only what it has proved.
``sol.stats.extra["widths"]`` records the widest ball at every output time so the growth can be measured.

python-flint's working precision (``flint.ctx.prec``) is process-wide: a validated run holds a lock for its whole
duration and restores the precision afterwards, so runs from several threads are safe but run one at a time.
"""

from __future__ import annotations

import functools
import math
import time as _time
from fractions import Fraction

import mpmath
import numpy as np

from . import cache
from .models.base import Model
from .poisson import as_poisson_system
from .precision import (
    VALIDATED_GUARD_BITS,
    Precision,
    check_count,
    check_dps,
    check_order,
    check_seconds,
    data_bits,
    dps_to_bits,
    to_fraction,
    warn_if_coarse,
)
from .ball_series import (SUPPORTED_OPS, Singular, ball_constant, check_ops, evaluate, flint_module, norm_bound,
                          taylor_coefficients, taylor_coefficients_checked, working_precision)
from .driver import StepResult, Stop, drive
from .lie.jets import DeadlineExceeded
from .solution import ChartRows, Solution, Stats
from .timegrid import parse_times

__all__ = ["validated_integrate", "ball_taylor_coefficients", "centre_coefficients", "SUPPORTED_OPS", "midpoints",
           "radii", "certified_digits"]

#: Guard bits above the requested digits (:data:`precision.VALIDATED_GUARD_BITS`).
GUARD_BITS = VALIDATED_GUARD_BITS
#: Each step's remainder bound, relative to the state's size, is at most this times 10^-dps.
REMAINDER_FACTOR = 1e-4

def _centre_polynomial(stepper, prog, m, pars, consts, order, flint, span, deadline=None):
    """The Taylor polynomial of order ``order`` of the flow from the point m, as a :class:`_Centre` of exact
    binary balls (radius 0), and the jets it came from (None after the fallback).

    Nothing about these coefficients needs proving: the remainder bound (:func:`_defect`) holds for any
    polynomial p with p(0) = m, and only its size depends on p being close to the flow. They come from the Lie
    engine's fixed-point jets (``stepper``, a :class:`~lieseries.lie.fixed.FixedStepper` of the chart's field:
    integers ``M`` with c_k = M * 2^(u - s k), taken into Arb exactly as the coefficients in the jets' scaled time
    sigma = 2^-s tau: no composition), or from Picard iteration on Arb series when the jets fail (s = 0).
    ``span``: the time left (the stepper's time scale covers it when the solution is a polynomial). Past
    ``deadline`` (a perf_counter value) both stop with :class:`~lieseries.lie.jets.DeadlineExceeded`."""
    arb = flint.arb
    try:
        jets = stepper.expand([mpmath.make_mpf(mpmath.libmp.from_man_exp(*(int(q) for q in v.mid().man_exp())))
                               for v in m], span, deadline)
        rows, s = _exact_rows(jets.M, jets.U, order, flint), jets.s
    except (ZeroDivisionError, ValueError, ArithmeticError):
        jets, s = None, 0
        rows = [[arb(c.mid()) for c in row] for row in taylor_coefficients(prog, m, pars, consts, order, flint,
                                                                deadline=deadline)]
    return _Centre([[mi] + row[1:] for mi, row in zip(m, rows)], s, flint), jets


class _Centre:
    """The centre polynomials p_i(tau) = sum_k rows[i][k] sigma^k in the scaled time sigma = 2^-s tau (exact
    balls; rows[i][0] is the centre itself)."""

    def __init__(self, rows, s, flint):
        self.rows, self.s, self.flint = rows, s, flint
        self.down = flint.arb(2) ** -s  # sigma per unit of tau (exact)
        self.polys = [flint.arb_poly(row) for row in rows]

    def sigma(self, tau):
        """The scaled time of the ball ``tau`` (exactly: a power of two)."""
        return tau * self.down

    def at(self, tau):
        """p(tau) for a ball ``tau``: an enclosure of the polynomials' range over it."""
        x = self.sigma(tau)
        return [p(x) for p in self.polys]

    def guess(self, order, width, lip):
        """Balls around the coefficients c_1..c_{order-1} in tau of the polynomials (at 64 bits): a guess of the
        coefficients from a box of radius ``width`` around the centre (:func:`taylor_coefficients_checked`), ``lip`` about
        the norm of the field's Jacobian there. A change d of the first k coefficients moves c_k by about
        lip d_{k-1} / k, so radii r_k = (2^-52 |z| + width) (4 lip)^k / k! (2^-52: far above the rounding at
        64 bits) leave room for what the field's evaluation carries from order to order (its leading part
        r_k / 4; where the coefficients grow faster, as near the sphere's chart edges, the check's retries widen
        the guess). Beyond the polynomial's order the guess is centred at 0."""
        flint = self.flint
        arb = flint.arb
        saved = flint.ctx.prec
        flint.ctx.prec = 64
        try:
            size = max(abs(row[0]).upper() for row in self.rows)
            r = size * 2.0**-52 + width
            out = [[] for _ in self.rows]
            for k in range(1, order):
                r = (r * (4 * lip) / k).upper()
                ck = self.down ** k
                for row, o in zip(self.rows, out):  # beyond the polynomial's order: around 0
                    o.append(arb((row[k] * ck).mid() if k < len(row) else 0, r))
            return out
        finally:
            flint.ctx.prec = saved

    def unscaled(self):
        """The coefficients c_k of p in tau, exactly: ``out[i][k]``."""
        flint = self.flint
        saved = flint.ctx.prec
        flint.ctx.prec = max(64, max(c.mid().man_exp()[0].bit_length() for row in self.rows for c in row)
                             + 64 + abs(self.s) * len(self.rows[0]))
        try:
            return [[c * flint.arb(2) ** (-self.s * k) for k, c in enumerate(row)] for row in self.rows]
        finally:
            flint.ctx.prec = saved


def _exact_rows(M, U, order, flint):
    """The coefficients M[i][k] 2^U[i] as rows of exact arbs, padded to ``order`` + 1 (integers into series and
    scaled by 2^U[i] at a precision above every mantissa: exact)."""
    arb, arb_series = flint.arb, flint.arb_series
    saved = flint.ctx.prec
    flint.ctx.prec = max(64, max(int(max(map(abs, Mi))).bit_length() for Mi in M) + 64)
    try:
        rows = []
        for Mi, u in zip(M, U):
            row = (arb_series([int(c) for c in Mi], prec=order + 1) * arb(2) ** u).coeffs()
            rows.append(row + [arb(0)] * (order + 1 - len(row)))
    finally:
        flint.ctx.prec = saved
    return rows


def _field_series(prog, polys, pars, consts, length, flint, base=None):
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
        got = list(fi.coeffs()) if isinstance(fi, arb_series) else [fi if isinstance(fi, arb) else arb(fi)]
        out.append(got[:length] + [arb(0)] * (length - len(got)))
    return out


#: Orders beyond N at which the defect's Taylor coefficients are computed at the step's start; the Lagrange term
#: over the whole step comes after them (so its overestimate is damped by (h / radius of convergence)^EXTRA).
DEFECT_EXTRA = 8


def _defect_coefficients(prog, centre, pars, consts, flint):
    """Coefficients g_0..g_{N+EXTRA-1} in the scaled time sigma = 2^-s tau, at the step's start, of the defect
    g = f(p) - dp/dtau of the :class:`_Centre` p (order N): balls around ~0 below N (rounding of the jets), the
    field's own terms from N on (dp/dtau = 2^-s dp/dsigma)."""
    arb, arb_series = flint.arb, flint.arb_series
    P, down = centre.rows, centre.down
    L = len(P[0]) - 1 + DEFECT_EXTRA
    F = evaluate(prog, [arb_series(row, prec=L) for row in P], pars, consts, arb_series([arb(1)], prec=L))
    out = []
    for fi, row in zip(F, P):
        if not isinstance(fi, arb_series):  # a constant component of the field
            fi = arb_series([fi if isinstance(fi, arb) else arb(fi)], prec=L)
        got = list((fi - arb_series(row, prec=L + 1).derivative() * down).coeffs())
        out.append(got[:L] + [arb(0)] * (L - len(got)))
    return out


def _defect_terms(g, flint):
    """Per component, the upper bounds |g_k| / (k + 1) that :func:`_defect` sums (at 64 bits: upper bounds)."""
    saved = flint.ctx.prec
    flint.ctx.prec = 64
    try:
        return [[(abs(x) / (k + 1)).upper() for k, x in enumerate(gi)] for gi in g]
    finally:
        flint.ctx.prec = saved


def _defect(terms, top, flint):
    """Per component, the polynomial d_i(t) = sum_k |g_k| t^k / (k+1) + |top_i| t^L / (L+1) (``terms``: upper
    bounds of |g_k| / (k+1) of the coefficients g at the step's start, :func:`_defect_terms`; ``top``: the L-th
    coefficient of g over the whole step, L = len(terms[i])): |tau| d_i(|tau|) bounds int_0^|tau| |g_i(s)| ds
    (nonnegative coefficients: its value at a point is tight). In the scaled time: sigma and g's coefficients in
    sigma give the bound divided by 2^s."""
    return [flint.arb_poly(gi + [(abs(ti) / (len(gi) + 1)).upper()]) for gi, ti in zip(terms, top)]


def _horner(C, tau):
    """The Taylor polynomials sum_j C[i][j] tau^j (tau a ball: an enclosure of their range over it)."""
    out = []
    for cs in C:
        acc = cs[-1]
        for c in reversed(cs[:-1]):
            acc = acc * tau + c
        out.append(acc)
    return out


#: The majorant is computed in floating point when the run's working precision is at most this many bits (its
#: integers convert to floats, and its floor, below, stays far under 10^-dps).
MAJORANT_MAX_BITS = 700
#: Every value of the majorant series is raised to at least this (a majorant stays one; no float underflows).
MAJORANT_FLOOR = 1e-280
_PASCAL: dict = {}


def _lagrange_majorant(prog, P, jets, h, par_values, L, flint):
    """Per component, an upper bound (an arb) of |[f(p(xi + tau))]_L| (the L-th Taylor coefficient in tau) over
    every xi between 0 and h, for the centre polynomial p (``P``, from the integer ``jets``: c_k = M 2^(u - s k)) and a
    polynomial field f; None when the field is not a polynomial or the numbers leave the float range.

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
    N = len(jets.M[0]) - 1
    up = 1 + 2.0**-50
    try:
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

        for i, (Mi, u) in enumerate(zip(jets.M, jets.U)):
            a = np.ldexp(np.abs(np.fromiter(map(float, Mi), float, len(Mi))), u) * hpow * up
            a[0] = abs(float(P[i][0].mid())) * up  # the centre itself (the jets hold it rounded)
            vals[i] = series(T @ a * up)
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
        for node in prog.nodes:
            a = [vals[x] for x in node.args]
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
        tops = [MAJORANT_FLOOR if isinstance(vals[o], float) else float(vals[o][L]) * 1.01 for o in prog.outputs]
    except (OverflowError, ValueError):
        return None
    if not all(math.isfinite(t) for t in tops):
        return None
    arb = flint.arb
    hL = arb(flint.fmpq(hq.numerator, hq.denominator)) ** L
    return [(arb(t) / hL).upper() for t in tops]


def _enclosure_box(P, flint):
    """A box around the polynomial range P over a step, a little wider, for the a priori check."""
    arb = flint.arb
    return [arb(p.mid(), p.rad() * 1.25 + (abs(p.mid()) + p.rad() + 1) * arb(2) ** -30) for p in P]


def _prove_step(prog, jprog, CZ, centre, terms, pars, consts, jconsts, span, flint, majorant=None):
    """(``tail``, the box B that holds every solution over the step, the coefficients from B through c_{K+1}) for
    a step over ``span`` (the ball [0, h]), or None when the step is not proved. ``tail(tau)``: per component, an
    upper bound of |phi_tau(m) - p(tau)| for the centre's solution, |tau| <= h.

    ``CZ``: the Taylor coefficients c_0..c_K from the whole enclosure Z of the state (K = BOX_ORDER). B is a box
    around their polynomials' range over the step; by the high-order enclosure theorem (docs/theory.md),
    sum_{j<=K} c_j(Z) [0, h]^j + c_{K+1}(B) [0, h]^(K+1) inside B proves that every solution from Z exists over
    the step and stays in B. B is wide, so its coefficients are computed at 64 bits (outward rounding keeps them
    rigorous).

    The centre's solution x from m = p(0) and the centre polynomial p (``centre``, a :class:`_Centre`) differ by
    e = x - p with e' = g + A(s) e, g = f(p) - p' the defect (its coefficients in the centre's scaled time at the
    step's start, as ``terms`` from :func:`_defect_terms`) and A(s) a mean of Df
    over the segment from p(s) to x(s), inside the box R = B united with the range of p over the step. So
    |e(tau)| <= exp(|tau| L) G(tau) componentwise, L = |Df(R)| entrywise and G the integral of |g| over the step
    bounded by :func:`_defect` with the Lagrange term taken over the whole step (from a majorant series in
    floating point, :func:`_lagrange_majorant`, when ``majorant`` = (the centre's integer jets, |h|, the
    parameters) is given and the field is a polynomial; else by ball series at 64 bits)."""
    arb, arb_mat = flint.arb, flint.arb_mat
    K = len(CZ[0]) - 1
    n = len(centre.rows)
    Lg = len(terms[0])  # the order of the Lagrange term
    Pz = _horner(CZ, span)
    B = _enclosure_box(Pz, flint)
    saved = flint.ctx.prec
    flint.ctx.prec = 64
    try:
        R = [b.union(p) for b, p in zip(B, centre.at(span))]
        vals = evaluate(jprog, R, pars, jconsts, arb(1))
        L = arb_mat([[abs(v if isinstance(v, arb) else arb(v)).upper() for v in vals[i * n:(i + 1) * n]]
                     for i in range(n)])
        if not all(L[i, j].is_finite() for i in range(n) for j in range(n)):
            return None
        D = taylor_coefficients(prog, B, pars, consts, K + 1, flint)  # B is wide: Picard iteration
        if not all(d[K + 1].is_finite() for d in D):
            return None
        if not all(b.contains(p + d[K + 1] * span ** (K + 1)) for b, p, d in zip(B, Pz, D)):
            return None
        top = None if majorant is None else _lagrange_majorant(prog, centre.rows, *majorant, Lg, flint)
        if top is None:  # coefficient Lg in sigma, over the step in sigma
            top = [row[-1] for row in _field_series(prog, centre.rows, pars, consts, Lg + 1, flint,
                                                    base=centre.sigma(span))]
        else:  # coefficient Lg in tau, times 2^(s Lg): in sigma
            up = arb(2) ** (centre.s * Lg)
            top = [(t * up).upper() for t in top]
    except (ZeroDivisionError, ValueError):
        return None
    finally:
        flint.ctx.prec = saved
    if not all(t.is_finite() for t in top):
        return None

    back = arb(2) ** centre.s  # the bound in sigma, in tau
    saved = flint.ctx.prec
    flint.ctx.prec = 64
    try:
        defect = _defect(terms, top, flint)
    finally:
        flint.ctx.prec = saved

    def tail(tau):
        saved = flint.ctx.prec
        flint.ctx.prec = 64
        try:
            x = abs(centre.sigma(tau))
            E = _exp_times(L * abs(tau), arb_mat([[(d(x) * x).upper() * back] for d in defect]), flint)
            return [E[i, 0].upper() for i in range(n)]
        finally:
            flint.ctx.prec = saved

    return tail, B, D


def _exp_times(M, g, flint):
    """exp(M) g for a matrix M and a column g with nonnegative entries (balls of exact values): the series
    sum_j M^j g / j! by matrix-vector products, its tail bounded entrywise by mu^(j+1) / (j+1)! / (1 - mu / (j+2))
    ||g||_inf (mu = ||M||_inf: every entry of M^i g is at most mu^i ||g||_inf), stopped below 2^-40 of ||g||_inf
    (a bound, not a tight value: cheaper than the matrix exponential, which it uses when mu >= 16)."""
    arb, arb_mat = flint.arb, flint.arb_mat
    n = g.nrows()
    mu = max([arb(0)] + [sum((M[i, j] for j in range(n)), arb(0)).upper() for i in range(n)])
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
#: number of pieces a step is cut into for it (twice as many when the set is wider than 10^-dps, as from uncertain
#: data, where the Jacobian's own width multiplies the set's spread: measured on the rigid body from data known to
#: a double's width, the final ball narrows from 1.2e-14 to 9.4e-15 for 17% more time).
JACOBIAN_TERMS = 10
#: Fewer terms when their tail bound is below this (relative to the identity: the Jacobian multiplies the set's
#: spread only; its width comes mostly from the range of Df over each piece: the rigid body's widest final ball at
#: 50 digits, T = 10, is 6.5599e-53 with a tail below 2^-30 as below 2^-40, with two matrix products fewer a piece).
JACOBIAN_EPS = 2.0**-30
JACOBIAN_PIECES = 8
#: More pieces, up to MAX_JACOBIAN_PIECES, when |Df| |tau| over the step exceeds JACOBIAN_MU per piece.
JACOBIAN_MU = 1.0
MAX_JACOBIAN_PIECES = 1024
#: Order of the Taylor polynomials from the whole enclosure that the a priori box is built around.
BOX_ORDER = 12


def _jacobian_program(ps):
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


def _flow_jacobian(jprog, CZ, D, pars, consts, tau, flint, pieces=JACOBIAN_PIECES):
    """An enclosure of every Jacobian d phi_tau(y) / dy of the flow over time ``tau`` (an exact ball) for all
    starting points y in the enclosure Z, or None when the bound below does not apply.

    ``CZ``: Taylor coefficients c_0..c_K from Z, ``D``: those from the a priori box B (through c_{K+1}). The step is
    cut into ``pieces`` pieces; over piece i every solution lies in B_i = sum_j c_j(Z) T_i^j +
    c_{K+1}(B) T_i^(K+1) (T_i the piece's time interval; Taylor's theorem), much narrower than B; the polynomial
    part is evaluated in mean-value form about the piece's middle time (narrower than Horner's scheme on T_i).
    d phi / dy solves V' = Df(z(t)) V, so over piece i it is multiplied by a matrix of the Peano-Baker series
    sum_j (dt Df(B_i))^j / j!, truncated after K terms (the fewest whose tail bound is below JACOBIAN_EPS, at most
    JACOBIAN_TERMS) with the tail bounded entrywise by
    mu^(K+1) / (K+1)! / (1 - mu / (K+2)), mu an upper bound of |dt| ||Df||_inf over every solution on the piece:
    the same for all pieces, from Df over the whole step's box (docs/theory.md). Computed at 64 bits: the Jacobian
    multiplies the enclosure's tiny spread only."""
    arb, arb_mat = flint.arb, flint.arb_mat
    n = len(CZ)
    K = len(CZ[0]) - 1
    eye = arb_mat([[1 if i == j else 0 for j in range(n)] for i in range(n)])
    saved = flint.ctx.prec
    flint.ctx.prec = 64
    try:
        # a badly scaled field (|Df| |tau| large: a fast oscillation in a slow state) needs more pieces: the
        # series of each piece converges like mu^j / j!, and mu near JACOBIAN_TERMS makes the enclosure explode
        polys = [flint.arb_poly(cz) for cz in CZ]
        slopes = [p.derivative() for p in polys]

        def box(lo, hi):
            """Every solution from Z over the times between lo and hi: the polynomials in mean-value form (the
            range of q_y over the interval lies in q_y(centre) + q_y'(interval) (interval - centre) for each
            polynomial q_y with coefficients in CZ) plus the remainder term."""
            centre = (lo + hi) / 2
            seg = centre + arb(0, abs(hi - lo) / 2)
            return [p(centre) + dp(seg) * (seg - centre) + d[K + 1] * seg ** (K + 1)
                    for p, dp, d in zip(polys, slopes, D)]

        try:
            whole = evaluate(jprog, box(arb(0), tau), pars, consts, arb(1))
        except Singular:
            return None
        norm = max(sum((abs(v if isinstance(v, arb) else arb(v)).upper() for v in whole[i * n:(i + 1) * n]),
                       arb(0)) for i in range(n)) * abs(tau)
        if not norm.is_finite():
            return None
        pieces = max(pieces, min(MAX_JACOBIAN_PIECES, math.ceil(float(norm.upper()) / JACOBIAN_MU)))
        dt = tau / pieces
        # every solution over a piece lies in the whole step's box: the same mu bounds every piece
        mu = (norm / pieces).upper()
        if not mu < JACOBIAN_TERMS + 2:
            return None
        # the fewest terms whose tail bound is below JACOBIAN_EPS (at most JACOBIAN_TERMS)
        mu_f = float(mu.upper())
        terms, term = JACOBIAN_TERMS, mu_f  # term: mu^(j+1) / (j+1)!
        for j in range(1, JACOBIAN_TERMS):
            term *= mu_f / (j + 1)
            if term / (1 - mu_f / (j + 2)) < JACOBIAN_EPS:
                terms = j
                break
        fact = arb(1)
        for j in range(2, terms + 2):
            fact *= j
        eps = (mu ** (terms + 1) / fact / (1 - mu / (terms + 2))).upper()
        tail = arb_mat([[arb(0, eps)] * n for _ in range(n)])
        J = eye
        for piece in range(pieces):
            try:
                vals = evaluate(jprog, box(dt * piece, dt * (piece + 1)), pars, consts, arb(1))
            except Singular:
                return None
            M = arb_mat([vals[i * n:(i + 1) * n] for i in range(n)]) * dt
            S, T = eye, eye
            for j in range(1, terms + 1):
                T = T * M / j
                S = S + T
            J = (S + tail) * J
        if not all(J[i, j].is_finite() for i in range(n) for j in range(n)):
            return None
        return J
    finally:
        flint.ctx.prec = saved


#: A run that switches charts this many times stops (it would be cycling).
MAX_SWITCHES = 10_000
_CHART_MAPS = cache.region("validated.chart_maps", 64)


def _chart_context(model, flint):
    """What a run needs of one chart's model, in the current ball precision: (PoissonSystem, program of the field,
    parameter balls, constant balls, terminal events, their constants, Jacobian program, its constants)."""
    ps = as_poisson_system(model)
    prog = ps.program
    pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
    consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
    events = _model_events(model, ps)
    ev_consts = [(slot, ball_constant(c, flint)) for slot, c in events[0].constants] if events else []
    jprog = _jacobian_program(ps)
    jconsts = [(slot, ball_constant(c, flint)) for slot, c in jprog.constants]
    return ps, prog, pars, consts, events, ev_consts, jprog, jconsts


def _jet_stepper(ps, order, dps):
    """The fixed-point jets of a chart's field for the centre polynomials (:func:`_centre_polynomial`), at the
    run's precision (``dps`` + 10 digits: the ball arithmetic's 32 guard bits)."""
    from .lie.fixed import FixedStepper

    return FixedStepper(ps.program, list(ps.parameter_values), order, Precision.of(dps=dps, guard_digits=10))


def _lohner_set(z, flint):
    """The box z as a Lohner set m + A r: its centre, the identity, the box around 0."""
    m = [flint.arb(zi.mid()) for zi in z]
    n = len(z)
    A = flint.arb_mat([[1 if i == j else 0 for j in range(n)] for i in range(n)])
    return m, A, flint.arb_mat([[zi - mi] for zi, mi in zip(z, m)])


def _switch_chart(model, current, chart, z, flint):
    """The balls z (a state in ``current``'s chart) rewritten in chart ``chart``: the model's chart-change map
    evaluated in ball arithmetic, so the result contains the image of every point of z."""
    ps = as_poisson_system(current)
    key = (ps.key, current.chart, chart)
    prog = _CHART_MAPS.get(key)
    if prog is None:
        from .expr import compile_expressions

        prog = compile_expressions(ps.variables, current.chart_change_expressions(chart), len(ps.parameter_values))
        _CHART_MAPS[key] = prog
    pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
    consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
    out = evaluate(prog, z, pars, consts, flint.arb(1))
    return [v if isinstance(v, flint.arb) else flint.arb(v) for v in out]


def _model_events(system, ps):
    """The model's terminal events (e.g. a sphere chart's edge) as (program, statuses, messages), or None."""
    evs = system.events() if isinstance(system, Model) else []
    if not evs:
        return None
    from .expr import compile_expressions

    prog = compile_expressions(ps.variables, [e[0] for e in evs], len(ps.parameter_values))
    check_ops(prog)
    return prog, [e[1] for e in evs], [e[2] for e in evs]


def _event_in(events, B, pars, consts, one):
    """(status, message) of the first event whose expression may vanish somewhere in the box B, else None: a
    step whose box reaches an event is not taken (the run stops before it, every row proved)."""
    prog, statuses, messages = events
    values = evaluate(prog, B, pars, consts, one)
    for v, status, message in zip(values, statuses, messages):
        if not (v > 0 or v < 0):
            return status, message
    return None


def _root(x, k: int) -> float:
    """x^(1/k) as a float, for a positive ball x of any size (a float of x itself may underflow)."""
    return float((x.log() / k).exp().mid())


def _step_estimate(g, N, tol, flint) -> float:
    """The step at which the defect's terms from order N on, sum_k |g_k| h^(k+1) / (k+1) (what the remainder
    bound comes to for a step well inside the radius of convergence), reach ~tol: a first guess from g_N, refined
    once. The attempt that follows proves or shortens it; this choice affects efficiency, never rigour."""
    arb = flint.arb
    saved = flint.ctx.prec
    flint.ctx.prec = 64
    try:
        hi = [[arb(abs(x).mid()) for x in gi[N:]] for gi in g]
        gN = max((row[0] for row in hi), key=float)
        if gN.is_zero():
            return math.inf
        h = arb(_root(tol * (N + 1) / gN, N + 1))

        def estimate(h):
            return max((sum((x * h ** (N + k + 1) / (N + k + 1) for k, x in enumerate(row)), arb(0)) for row in hi),
                       key=float)

        return 0.97 * float(h.mid()) * _root(tol / estimate(h), N + 1)
    finally:
        flint.ctx.prec = saved


def _check_regular(prog, z, pars, consts, flint):
    """Refuse initial data whose centre is a singular point of the field (a pole, a root at 0): no step from there
    can be proved. A ball around a regular centre that reaches a singularity is left to the run (it ends with
    ``validation_failed`` at t0)."""
    arb = flint.arb
    centre = [arb(v.mid()) for v in z]
    try:
        values = evaluate(prog, centre, pars, consts, arb(1))
        ok = all((v if isinstance(v, arb) else arb(v)).is_finite() for v in values)
    except Singular:
        ok = False
    if not ok:
        raise ValueError(f"`y0` = {[float(v.mid()) for v in centre]} is a singular point of the vector field (it "
                         "cannot be evaluated there: a division by 0, or a root or logarithm at its branch point); "
                         "start from a regular point")


# -- the driver ------------------------------------------------------------------------------------------------------
def _initial_balls(system, y0, n, flint):
    """Balls of the initial state: exact values (rounded outward once), or the user's (value, radius) / arb."""
    arb = flint.arb
    if getattr(y0, "exact", None) is not None:
        entries = list(y0.exact)
    elif isinstance(y0, (list, tuple)):
        entries = list(y0)
    elif np.ndim(y0) == 1:
        entries = list(np.asarray(y0, dtype=object))
    else:
        raise ValueError(f"`y0` must be a sequence of {n} entries (numbers, (value, radius) pairs or arb balls); "
                         f"got {type(y0).__name__} {y0!r:.60}")
    if len(entries) != n:
        raise ValueError(f"`y0` must have {n} entries; got {len(entries)}")
    # binary data (0.1 as a double) are enclosed at their binary values: say so when the run has more digits
    plain = [v for v in entries if not isinstance(v, (tuple, flint.arb))]
    warn_if_coarse(data_bits(plain), flint.ctx.prec - GUARD_BITS, "y0")
    balls, mids = [], []
    for i, v in enumerate(entries):
        if isinstance(v, arb):
            if not v.is_finite():
                raise ValueError(f"`y0[{i}]` must be a finite ball; got {v}")
            balls.append(+v)
            mids.append(_exact_mid(v))
            continue
        if isinstance(v, tuple):
            if len(v) != 2:
                raise ValueError(f"`y0[{i}]` as an uncertain value must be (value, radius); got {v!r}")
            val, rad = to_fraction(v[0], f"y0[{i}]"), to_fraction(v[1], f"y0[{i}] radius")
            if rad < 0:
                raise ValueError(f"`y0[{i}]` radius must be >= 0; got {float(rad)}")
            ball = arb(flint.fmpq(val.numerator, val.denominator))
            balls.append(ball + arb(0, arb(flint.fmpq(rad.numerator, rad.denominator)).abs_upper()))
            mids.append(val)
            continue
        q = to_fraction(v, f"y0[{i}]")
        balls.append(arb(flint.fmpq(q.numerator, q.denominator)))
        mids.append(q)
    if isinstance(system, Model) and all(m is not None for m in mids):
        system.check_state(mids, "y0")  # the model's physical checks on the centre
    return balls


def ball_taylor_coefficients(system, y0, order: int, dps: int = 30) -> list:
    """The normalised Taylor coefficients c_0..c_order of the flow from ``y0`` as Arb balls that contain the
    exact ones: ``out[i][k]`` for component i (``y0`` entries as in :func:`validated_integrate`)."""
    dps = check_dps(dps)
    order = check_order(order)
    ps = as_poisson_system(system)
    prog = ps.program
    check_ops(prog)
    with working_precision(dps_to_bits(dps) + GUARD_BITS, cap=order + 4) as flint:
        z = _initial_balls(system, y0, ps.dimension, flint)
        pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
        consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
        return taylor_coefficients(prog, z, pars, consts, order, flint)


def centre_coefficients(system, y0, order: int, dps: int = 30, step=None) -> list:
    """The centre polynomial a validated step from ``y0`` takes (from the midpoints of its balls: exact values are
    rounded to the run's precision), as the run computes it: ``out[i][k]``,
    exact binary Arb balls (radius 0), close to the Taylor coefficients c_k of the flow (nothing about them is
    proved: each step bounds the distance of the solution from this polynomial). ``step``: the length of the run's
    previous step (the fixed-point jets then hold c_k to ``dps`` digits of the state relative to
    ``2^(ceil(log2 step) + 1)^-k``, what a step of about that length needs); none: a first step."""
    dps = check_dps(dps)
    order = check_order(order)
    ps = as_poisson_system(system)
    prog = ps.program
    check_ops(prog)
    with working_precision(dps_to_bits(dps) + GUARD_BITS, cap=order + 4) as flint:
        z = [flint.arb(v.mid()) for v in _initial_balls(system, y0, ps.dimension, flint)]
        pars = [flint.arb(flint.fmpq(p.numerator, p.denominator)) for p in ps.parameter_values]
        consts = [(slot, ball_constant(c, flint)) for slot, c in prog.constants]
        stepper = _jet_stepper(ps, order, dps)
        if step is not None:
            stepper.h_last = float(to_fraction(step, "step"))
            if not stepper.h_last > 0:
                raise ValueError(f"`step` must be a positive step length; got {step!r}")
            stepper.s = 0  # not a first expansion: the time scale follows the step
        return _centre_polynomial(stepper, prog, z, pars, consts, order, flint, mpmath.mpf(1))[0].unscaled()


def validated_integrate(system, y0, t, *, dps: int = 30, order: int | None = None, t0=0, max_steps: int = 100_000,
                        max_time: float | None = None, max_width=None, atlas: bool | None = None) -> Solution:
    """Enclose the solution of ``dz/dt = X_H(z)`` in Arb balls that provably contain it (module docstring).

    Parameters
    ----------
    system : model or PoissonSystem
        Its vector field may use the operations in :data:`SUPPORTED_OPS`; others are refused by name.
    y0 : sequence of n entries
        Exact values (a model state, ints, strings, Fractions, floats as their binary values), or uncertain
        values as ``(value, radius)`` tuples or ``flint.arb`` balls: the enclosures then contain the solutions
        from every point of the initial box.
    t : number or sequence
        Final time or output times (as for :func:`lieseries.integrate`).
    dps : int
        Digits of the ball arithmetic (32 guard bits above); the enclosures aim at widths near 10^-dps.
    order : int, optional
        Series order (default ceil(ln(10) dps / 2) + 1, the Jorba-Zou choice).
    max_steps, max_time :
        Budgets (statuses ``step_budget``, ``time_budget``); the clock is read between steps and after every order
        of a step's series, so a long step stops within about one order's work of ``max_time``.
    max_width : number, optional
        Stop with ``validation_failed`` when a ball grows wider than this (default 1e-3 x max(1, |z|)).
    atlas : bool, optional
        For a model with charts (:class:`~lieseries.Sphere`; on by default, the model's ``atlas``): switch to the
        chart of the largest coordinate when the current one is ending, mapping the enclosure in ball
        arithmetic; ``sol.charts`` gives each row's chart. With ``atlas=False`` the run stops at the chart's edge
        (``chart_edge``).

    Returns
    -------
    Solution
        ``sol.y``: object array of ``flint.arb`` (one row per output time reached); ``midpoints(sol)``,
        ``radii(sol)``, ``certified_digits(sol)`` read them. ``sol.stats.extra["widths"]``: the widest ball at each
        output time; ``["tail_bounds"]``: the remainder bound added at each step.
    """
    dps = check_dps(dps)
    max_steps = check_count(max_steps, "max_steps")
    max_time = check_seconds(max_time, "max_time")
    if max_width is not None and not to_fraction(max_width, "max_width") > 0:
        raise ValueError(f"`max_width` must be a positive radius (the widest ball the run may carry); got "
                         f"{max_width!r}. Leave it out for the default, 1e-3 x max(1, |z|)")
    N = check_order(order) if order is not None else max(8, math.ceil(math.log(10) * dps / 2) + 1)
    ps = as_poisson_system(system)
    check_ops(ps.program)
    if atlas is None:
        atlas = bool(getattr(system, "atlas", False))  # a Sphere says (True unless built with atlas=False)
    if atlas and not hasattr(system, "chart_change_expressions"):
        raise ValueError(f"`atlas` needs a model with an atlas of charts (Sphere); {type(system).__name__} has one "
                         "global chart")
    bits = dps_to_bits(dps) + GUARD_BITS
    # the rows: n balls per time (an arb object, its midpoint's limbs and its radius)
    grid, direction, t0f = parse_times(t, t0, values_per_time=ps.dimension, bytes_per_value=64 + bits // 8,
                                        max_time=max_time)
    # binary model data (inertia 1.1 as a double) or times (t = 0.1 as a double) in a longer run: the enclosures
    # are proven for those binary values, not for the decimals they round
    for name, b in list(ps.coarse_data().items()) + [("t", data_bits(t)), ("t0", data_bits(t0))]:
        warn_if_coarse(b, dps_to_bits(dps), name)
    start = _time.perf_counter()
    deadline = None if max_time is None else start + max_time

    with working_precision(bits, cap=max(N, BOX_ORDER + 1) + DEFECT_EXTRA + 4) as flint:
        arb = flint.arb
        z = _initial_balls(system, y0, ps.dimension, flint)
        width_cap = None if max_width is None else arb(flint.fmpq(*to_fraction(max_width, "max_width").as_integer_ratio()))
        widest0 = max(z, key=lambda v: float(v.rad()))
        cap0 = width_cap if width_cap is not None else arb(max([1.0] + [abs(float(v.mid())) for v in z])) / 1000
        if widest0.rad() > cap0:
            raise ValueError(
                f"`y0` has a ball of radius {float(widest0.rad()):.3g}, already wider than `max_width` = "
                f"{float(cap0):.3g} ({'given' if width_cap is not None else 'the default, 1e-3 x max(1, |z|)'}): "
                "the run would stop at once with validation_failed. Pass a larger `max_width` to follow so wide a "
                "set (its enclosures widen fast and the steps shrink), or give a narrower uncertainty"
            )
        current = system
        if atlas:
            current = system.for_chart(system.chart, edge=system.ATLAS_SWITCH)
            best = system.best_chart([_exact_mid(v) for v in z])
            if best != system.chart:
                z, current = _switch_chart(system, current, best, z, flint), system.for_chart(best, edge=system.ATLAS_SWITCH)
        # the shortest step tried: 2^-40 of the run's time span (a time, whatever the size of the state)
        engine = _ValidatedEngine(system, current, z, N, dps, flint, width_cap, deadline,
                                  float(abs(grid[-1] - t0f)) * 2.0**-40, direction, atlas)
        out = drive(engine, t0f, z, [(g, g) for g in grid], direction=direction, max_steps=max_steps,
                    max_time=max_time, start=start, kept="Every row up to here is a proven enclosure.",
                    atlas=atlas, max_switches=MAX_SWITCHES, reached="; every row is a proven enclosure")
        message = out.message
        widths = [max(_float_up(v.rad()) for v in row) for row in out.rows_y]
        n = engine.ps.dimension
        stats = Stats(method="validated lie series (arb)", precision=f"{dps} dps", tol=10.0 ** -dps, order=N,
                      steps=out.steps, run_time=out.run_time,
                      extra={"widths": widths, "tail_bounds": engine.tails,
                             "max_width": max(widths) if widths else 0.0, "chart_switches": out.switches})
        y = np.empty((len(out.rows_y), n), dtype=object)
        for i, row in enumerate(out.rows_y):
            for j, v in enumerate(row):
                y[i, j] = v
        y_reached = np.empty(n, dtype=object)
        for j, v in enumerate(out.z):
            y_reached[j] = v
    tarr = np.array([float(v) for v in out.rows_t])
    if atlas:
        return Solution(tarr, ChartRows(y, out.rows_chart), stats, out.status, message, t_reached=out.t,
                        t_requested=grid, y_reached=ChartRows(y_reached, engine.chart),
                        charts=np.array(out.rows_chart, dtype=int), chart_reached=engine.chart)
    return Solution(tarr, y, stats, out.status, message, t_reached=out.t, t_requested=grid, y_reached=y_reached)


class _ValidatedEngine:
    """One validated step for :func:`lieseries.driver.drive`: the a priori enclosure and remainder bound of the
    step (shortened until proved), the rows inside it, Lohner's QR update of the set m + A r."""

    def __init__(self, system, current, z, N, dps, flint, width_cap, deadline, h_min, direction, atlas):
        self.system, self.N, self.dps, self.flint = system, N, dps, flint
        self.width_cap, self.deadline, self.h_min, self.direction, self.atlas = (
            width_cap, deadline, h_min, direction, atlas)
        self.tails = []
        arb = flint.arb
        self.unit = arb(10) ** -dps
        # per-step remainder bound, relative: far below 10^-dps, because every step's remainder is then carried
        # (and widened by the wrapping effect) to the end of the run (a ball: 10^-dps underflows a float)
        self.rem_tol = arb(REMAINDER_FACTOR) * self.unit
        self._enter(current, z)
        _check_regular(self.prog, z, self.pars, self.consts, flint)

    def _enter(self, current, z):
        """Work in the chart of ``current`` from the balls ``z``."""
        self.current = current
        self.chart = getattr(current, "chart", None)
        (self.ps, self.prog, self.pars, self.consts, self.events, self.ev_consts, self.jprog,
         self.jconsts) = _chart_context(current, self.flint)
        self.stepper = _jet_stepper(self.ps, self.N, self.dps)
        # the set of states is m + A r: a centre point, a matrix (the identity to start) and a box around 0
        self.m, self.A, self.r = _lohner_set(z, self.flint)

    def switch_chart(self, t, z):
        """The chart is ending: the enclosure rewritten in the chart of the largest coordinate (in ball
        arithmetic: the box of the map's values over the box), or None when that is the current chart."""
        system = self.system
        best = system.best_chart([_exact_mid(v) for v in z])
        if best == self.current.chart:
            return None
        z = _switch_chart(system, self.current, best, z, self.flint)
        self._enter(system.for_chart(best, edge=system.ATLAS_SWITCH), z)
        return z

    def step(self, tcur, z, t_end):
        flint, N, direction = self.flint, self.N, self.direction
        arb = flint.arb
        prog, pars, consts, jprog, jconsts = self.prog, self.pars, self.consts, self.jprog, self.jconsts
        n = len(z)
        scale = max([1.0] + [abs(float(zi.mid())) for zi in z])
        tol = self.rem_tol * scale
        wide = any(zi.rad() > self.unit * scale for zi in z)  # wider than 10^-dps of the state's size
        pieces = 2 * JACOBIAN_PIECES if wide else JACOBIAN_PIECES
        try:
            C, jets = _centre_polynomial(self.stepper, prog, self.m, pars, consts, N, flint,
                                         mpmath.mpf(float(abs(t_end - tcur))), self.deadline)  # centre
            g = _defect_coefficients(prog, C, pars, consts, flint)  # in the centre's scaled time
            # from the whole set (checked from a guess around the centre polynomial)
            guess = C.guess(BOX_ORDER, max(zi.rad() for zi in z), norm_bound(jprog, self.m, pars, jconsts, flint))
            CZ = taylor_coefficients_checked(prog, z, guess, pars, consts, BOX_ORDER, flint)
        except DeadlineExceeded:
            raise Stop("time_budget", note=" (inside a step)") from None
        except Singular as e:
            # the enclosure of the state itself reaches a singularity of the field: nothing beyond is proved
            raise Stop("validation_failed", f"the vector field cannot be evaluated on the enclosure of the state "
                       f"({e}): the solution is at or near a singularity of the field (widest ball "
                       f"{max(float(zi.rad()) for zi in z):.3g})") from None
        left = abs(t_end - tcur)
        h_f = min(_step_estimate(g, N, tol * C.down, flint) * 2.0 ** C.s, float(left))
        terms = _defect_terms(g, flint)
        proved = None
        event_hit = None
        h_event_start = h_f
        for _attempt in range(60):
            if not (h_f > self.h_min or h_f >= float(left)):
                break
            if self.deadline is not None and _time.perf_counter() > self.deadline:
                raise Stop("time_budget", note=" (inside a step)")
            h = left if h_f >= float(left) else Fraction(math.floor(h_f * 2**50), 2**50)
            if h <= 0:
                break
            hs = h * direction
            hb = arb(flint.fmpq(hs.numerator, hs.denominator))
            span = hb / 2 + arb(0, abs(hb) / 2)  # the ball [0, h] (or [h, 0])
            got = _prove_step(prog, jprog, CZ, C, terms, pars, consts, jconsts, span, flint,
                              majorant=(jets, h, self.ps.parameter_values) if jets is not None else None)
            tail, B, D = got if got is not None else (None, None, None)
            hit = (_event_in(self.events, B, pars, self.ev_consts, arb(1)) if self.events and got is not None
                   else None)
            if hit is not None:
                # the step's box may reach the event: shorten the step towards it, and stop when that no
                # longer helps (the event is closer than 1/1000 of the step)
                event_hit = hit
                if float(h) < 1e-3 * h_event_start:
                    break
                h_f = float(h) / 2
                continue
            J = _flow_jacobian(jprog, CZ, D, pars, jconsts, hb, flint, pieces) if got is not None else None
            bounds_h = tail(hb) if J is not None else None
            worst = max(bounds_h, key=float) if J is not None else None
            if J is not None and worst <= tol:
                proved = (h, hs, tail, D, J, bounds_h)
                break
            # the remainder scales like h^(N+1): aim just below the tolerance (halve when unproved)
            shrink = 0.5 if worst is None or not worst.is_finite() else min(0.9 * _root(tol / worst, N + 1), 0.9)
            h_f = float(h) * shrink
        if proved is None and event_hit is not None:
            # the driver switches charts (atlas) or stops here
            raise Stop(event_hit[0], f"{event_hit[1]} within the next step (every row up to here is a proven "
                       "enclosure; `atlas=True` switches charts instead)")
        if proved is None:
            raise Stop("validation_failed", f"no step down to {self.h_min:.3g} has an a priori enclosure with a "
                       "small enough remainder (the field is singular near the enclosure, or the enclosure is too "
                       f"wide: widest ball {max(float(zi.rad()) for zi in z):.3g})")
        h, hs, tail, D, J, bounds_h = proved
        self.stepper.h_last = float(h)  # the next centre's jets hold what a step of about this length needs
        tnew = tcur + hs
        A, r = self.A, self.r

        def point(tau: Fraction):
            """Enclosure at tcur + tau of the solution from the centre m: its polynomial plus the bound of
            their difference."""
            ta = arb(flint.fmpq(tau.numerator, tau.denominator))
            bounds = bounds_h if tau == hs else tail(ta)  # the step's own end: bounded when it was proved
            out = [p + arb(0, e) for p, e in zip(C.at(ta), bounds)]
            return out, max(float(e) for e in bounds), ta

        def whole(phi, JA):
            """The box of phi + JA r: every solution from the set m + A r (mean-value theorem)."""
            spread = JA * r
            return [phi[i] + spread[i, 0] for i in range(n)]

        def row(tk):
            phi_k, _, ta = point(tk - tcur)
            Jk = J if tk == tnew else _flow_jacobian(jprog, CZ, D, pars, jconsts, ta, flint, pieces)
            if Jk is None:  # the field's Jacobian cannot be bounded over the shorter span: stop here
                raise Stop("validation_failed", f"the flow's Jacobian up to the output time {float(tk):.17g} cannot "
                           "be bounded (the field is singular or too steep near the enclosure)")
            return whole(phi_k, Jk * A)

        phi, tail_h, _ = point(hs)
        JA = J * A
        znew = whole(phi, JA)
        # Lohner's QR step: the new set is m' + A' r' with m' the centre of phi, A' the orthogonal factor of
        # mid(J A) (exact floats) and r' = (A'^-1 J A) r + A'^-1 (phi - m'), A'^-1 enclosed in ball arithmetic
        self.m = [arb(v.mid()) for v in phi]
        Q, _ = np.linalg.qr(np.array([[float(JA[i, j].mid()) for j in range(n)] for i in range(n)]))
        self.A = flint.arb_mat([[float(Q[i, j]) for j in range(n)] for i in range(n)])
        Ainv = self.A.inv()
        self.r = (Ainv * JA) * r + Ainv * flint.arb_mat([[phi[i] - self.m[i]] for i in range(n)])
        self.tails.append(tail_h)
        cap = self.width_cap if self.width_cap is not None else arb(scale) / 1000
        widest = max(znew, key=lambda v: float(v.rad()))
        end = None
        if not all(v.is_finite() for v in znew) or widest.rad() > cap:
            end = ("validation_failed", f"the widest ball has radius {float(widest.rad()):.3g}, beyond max_width "
                   f"({float(cap):.3g})", "")
        return StepResult(tnew, znew, h=h, row=row, stop=end)


def midpoints(sol, as_mpf: bool = False) -> np.ndarray:
    """The midpoints of a validated solution's balls (an object array shaped like ``sol.y``): exact Fractions, or
    with ``as_mpf`` mpmath numbers of the same (binary) values, exactly."""
    if as_mpf:
        return np.vectorize(_mid_mpf, otypes=[object])(sol.y)
    return np.vectorize(_exact_mid, otypes=[object])(sol.y)


def _mid_mpf(ball):
    man, exp = (int(v) for v in ball.mid().man_exp())
    return mpmath.make_mpf(mpmath.libmp.from_man_exp(man, exp))


def _exact_mid(ball) -> Fraction:
    """The midpoint of an arb ball (a binary number), exactly."""
    man, exp = (int(v) for v in ball.mid().man_exp())
    return Fraction(man << exp) if exp >= 0 else Fraction(man, 1 << -exp)


def _float_up(x) -> float:
    """An upper bound of the nonnegative ball ``x`` as a float (the smallest positive float for a radius too small
    for a float, never 0 for a nonzero ball)."""
    if x.is_zero():
        return 0.0
    return math.nextafter(float(x.upper()), math.inf)


def radii(sol) -> np.ndarray:
    """The radii of a validated solution's balls (float64 upper bounds, shaped like ``sol.y``)."""
    return np.vectorize(lambda v: _float_up(v.rad()), otypes=[float])(sol.y)


def certified_digits(sol) -> np.ndarray:
    """Per output time: -log10 of the widest ball's radius relative to max(1, |z|): the digits every component is
    certified to (computed from the balls, so beyond a float's range too; inf for a row of exact values)."""
    flint = flint_module()
    out = []
    for row in np.atleast_2d(sol.y):
        widest = functools.reduce(lambda a, b: b if b > a else a, [v.rad() for v in row])  # exact values
        if widest.is_zero():
            out.append(math.inf)
            continue
        scale = functools.reduce(lambda a, b: b if b > a else a, [abs(v.mid()) for v in row], flint.arb(1))
        out.append(float((-(flint.arb(widest) / scale).log() / flint.arb(10).log()).mid()))
    return np.array(out, dtype=float)
