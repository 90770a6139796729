"""Truncated power series ("jets") in mpmath: Taylor-mode automatic differentiation.

For ``dz/dt = rhs(z)``, ``z(0) = y0`` the normalised Taylor coefficients
``c_k = z^(k)(0) / k!`` are built by the classic recurrence: the jets of the
state variables start as ``[y0]``; for ``k = 0 .. order-1`` every node of the
compiled right-hand side (:class:`lieseries.expr.Program`) gets its k-th
coefficient from the coefficients ``0 .. k`` of its arguments, and then the
state gets ``c_{k+1} = rhs_k / (k+1)``.  Coefficients are computed
incrementally (nothing is recomputed), each node costs O(k) per new
coefficient, so a whole expansion costs O(order^2) per node.

The rules (``f``, ``g`` argument jets, ``c`` the result, ``Df_j = j f_j``):

* ``f ± g``, ``λ f``: linear;  ``f g``: Cauchy product;  ``f^2``: half of it;
* ``f / g``: ``c_k = (f_k - sum_{j=1..k} g_j c_{k-j}) / g_0``;
* ``f^a`` (real a): from ``f c' = a c f'``:
  ``c_k = (a sum_{j<k} Df_{k-j} c_j - sum_{j<k} Dc_j f_{k-j}) / (k f_0)``;
* ``sqrt f``: ``c_k = (f_k - sum_{j=1..k-1} c_j c_{k-j}) / (2 c_0)``;
* ``exp f``: ``k c_k = sum_{j=1..k} Df_j c_{k-j}``;
* ``log f``: ``k f_0 c_k = Df_k - sum_{j=1..k-1} Dc_j f_{k-j}``;
* ``sin f``, ``cos f`` (always together): ``k s_k = sum Df_j c_{k-j}``,
  ``k c_k = -sum Df_j s_{k-j}``; ``sinh``/``cosh`` likewise with ``+``;
* ``tan f``: ``t' = u f'`` with ``u = 1 + t^2``; ``tanh``: ``u = 1 - t^2``;
* ``atan f``: ``u t' = f'`` with ``u = 1 + f^2``.

Integer powers are expanded into squarings and products (so they work at a
zero base); parameters and constants enter as scalars, never as jets.

Everything runs in mpmath at the working precision plus guard bits, on
mpmath's raw number tuples; every sum of products is accumulated exactly
in integers and rounded once.  The engine only uses heyoka's expressions (via
sympy, compiled once per system); it never calls heyoka's integrators or
compiled functions.
"""

from __future__ import annotations

from time import perf_counter as _clock

import mpmath
from mpmath.libmp import (
    fone,
    fzero,
    from_int,
    from_man_exp,
    mpf_add,
    mpf_cos_sin,
    mpf_cosh_sinh,
    mpf_div,
    mpf_mul,
    mpf_neg,
    mpf_shift,
    mpf_sub,
    mpf_sum,
)

from .. import expr as _expr
from ..precision import MAX_DPS, check_dps, check_order
from ..expr import POINTWISE, RND, rounded_mpf
from .plan import MAX_GUARD_DIGITS, DeadlineExceeded, jet_guard_bits, jet_plan, resolve_program

__all__ = ["taylor_coefficients", "taylor_coefficients_raw"]



# --------------------------------------------------------------------------
# Exact accumulation kernels on raw mpfs
# --------------------------------------------------------------------------

def _dot(xs, ys, lim):
    """Exact ``sum x*y`` over zipped raw mpfs, as a (man, exp) pair.

    Terms smaller than the running sum by more than `lim` bits (or a
    running sum smaller than a new term by more than `lim` bits) are
    dropped, as in ``mpmath.libmp.mpf_sum``; otherwise the sum is exact.
    Returns ``(0, 0)`` for an empty or zero sum.
    """
    man = 0
    exp = None
    for (s1, m1, e1, _), (s2, m2, e2, _) in zip(xs, ys):
        if m1 and m2:
            m = m1 * m2
            if s1 != s2:
                m = -m
            e = e1 + e2
            if exp is None:
                man = m
                exp = e
            elif e >= exp:
                d = e - exp
                if d > lim and man.bit_length() + lim < d + m.bit_length():
                    man = m
                    exp = e
                else:
                    man += m << d
            else:
                d = exp - e
                if d > lim and m.bit_length() + lim < d + man.bit_length():
                    continue
                man = (man << d) + m
                exp = e
    if exp is None:
        return 0, 0
    return man, exp


def _addme(m1, e1, m2, e2, lim):
    """Exact (man, exp) sum of two (man, exp) pairs (same dropping rule)."""
    if not m2:
        return m1, e1
    if not m1:
        return m2, e2
    if e1 >= e2:
        d = e1 - e2
        if d > lim and m1.bit_length() + d > m2.bit_length() + lim:
            return m1, e1
        return (m1 << d) + m2, e2
    d = e2 - e1
    if d > lim and m2.bit_length() + d > m1.bit_length() + lim:
        return m2, e2
    return m1 + (m2 << d), e1


def _me(raw):
    """(man, exp) pair of a raw mpf (signed mantissa)."""
    s, m, e, _ = raw
    return (-m if s else m), e


def _exact(man, exp):
    return from_man_exp(man, exp) if man else fzero


def _extend_d(a, da, k):
    """Extend ``da`` (the jet ``j * a_j``) up to index k (entries for _dot only)."""
    for j in range(len(da), k + 1):
        s, m, e, _ = a[j]
        mj = m * j
        da.append((s, mj, e, 0))


def _sqr_me(a, k, lim):
    """Exact k-th coefficient of a^2 as (man, exp)."""
    h = (k + 1) >> 1
    man, exp = _dot(a[:h], a[k:k - h:-1], lim) if h else (0, 0)
    man <<= 1
    if not k & 1:
        s, m, e, _ = a[k >> 1]
        if m:
            man, exp = _addme(man, exp, m * m, 2 * e, lim)
    return man, exp


# --------------------------------------------------------------------------
# Step functions: each appends coefficient k of its node(s)
# --------------------------------------------------------------------------

def _mk_lin(out, vterms, cterms, prec):
    """out = sum(±v) + sum(±c): vterms/cterms lists of (jet or raw, negate)."""
    offset = mpf_sum([mpf_neg(c) if ng else c for c, ng in cterms]) if cterms else fzero
    if len(vterms) == 1 and not cterms:
        (a, ng), = vterms

        def step(k):
            out.append(mpf_neg(a[k]) if ng else a[k])
        return step
    if len(vterms) == 2:
        (a, na), (b, nb) = vterms
        fa = mpf_sub if nb else mpf_add

        def step(k):
            x = a[k]
            if na:
                x = mpf_neg(x)
            r = fa(x, b[k], prec if (k or not cterms) else 0, RND)
            if k == 0 and cterms:
                r = mpf_add(r, offset, prec, RND)
            out.append(r)
        return step

    def step(k):
        terms = [mpf_neg(a[k]) if ng else a[k] for a, ng in vterms]
        if k == 0 and cterms:
            terms.append(offset)
        out.append(mpf_sum(terms, prec, RND))
    return step


def _mk_scale(out, a, c, prec):
    def step(k):
        out.append(mpf_mul(c, a[k], prec, RND))
    return step


def _mk_mul(out, a, b, prec, lim):
    def step(k):
        man, exp = _dot(a[:k + 1], b[k::-1], lim)
        out.append(from_man_exp(man, exp, prec, RND) if man else fzero)
    return step


def _mk_sqr(out, a, prec, lim):
    def step(k):
        man, exp = _sqr_me(a, k, lim)
        out.append(from_man_exp(man, exp, prec, RND) if man else fzero)
    return step


def _mk_div(out, a, b, prec, lim, const_num=None):
    """out = a / b (a a jet) or const_num / b (const_num a raw scalar)."""
    b0 = [None]

    def step(k):
        if k == 0:
            b0[0] = b[0]
            num = const_num if a is None else a[0]
            out.append(mpf_div(num, b[0], prec, RND))
            return
        man, exp = _dot(b[1:k + 1], out[k - 1::-1], lim)
        if a is not None:
            am, ae = _me(a[k])
            man, exp = _addme(am, ae, -man, exp, lim)
        else:
            man = -man
        out.append(mpf_div(_exact(man, exp), b0[0], prec, RND) if man else fzero)
    return step


def _mk_pow(out, a, da, dout, ex, data, prec, lim):
    """out = a ** ex (ex a raw scalar, data the exact rational (p, q) or None)."""
    es, em, ee, _ = ex
    if es:
        em = -em
    a0 = [None]

    def step(k):
        if k == 0:
            if not a[0][1]:
                raise ZeroDivisionError("a non-integer power of a series with zero constant term")
            a0[0] = a[0]
            out.append(POINTWISE["pow"]([a[0], ex], data, prec))
            return
        _extend_d(a, da, k)
        _extend_d(out, dout, k - 1)
        m1, e1 = _dot(out[0:k], da[k:0:-1], lim)
        m2, e2 = _dot(dout[1:k], a[k - 1:0:-1], lim)
        man, exp = _addme(em * m1, ee + e1, -m2, e2, lim)
        if not man:
            out.append(fzero)
            return
        den = mpf_mul(a0[0], from_int(k))
        out.append(mpf_div(from_man_exp(man, exp), den, prec, RND))
    return step


def _mk_sqrt(out, a, prec, lim):
    c0x2 = [None]

    def step(k):
        if k == 0:
            if not a[0][1]:
                raise ZeroDivisionError("sqrt of a series with zero constant term")
            c0 = POINTWISE["sqrt"]([a[0]], None, prec)
            c0x2[0] = mpf_shift(c0, 1)
            out.append(c0)
            return
        h = (k - 1) >> 1
        man, exp = _dot(out[1:h + 1], out[k - 1:k - h - 1:-1], lim) if h else (0, 0)
        man <<= 1
        if not k & 1:
            s, m, e, _ = out[k >> 1]
            if m:
                man, exp = _addme(man, exp, m * m, 2 * e, lim)
        am, ae = _me(a[k])
        man, exp = _addme(am, ae, -man, exp, lim)
        out.append(mpf_div(_exact(man, exp), c0x2[0], prec, RND) if man else fzero)
    return step


def _mk_exp(out, a, da, prec, lim):
    def step(k):
        if k == 0:
            out.append(POINTWISE["exp"]([a[0]], None, prec))
            return
        _extend_d(a, da, k)
        man, exp = _dot(da[1:k + 1], out[k - 1::-1], lim)
        out.append(mpf_div(_exact(man, exp), from_int(k), prec, RND) if man else fzero)
    return step


def _mk_log(out, a, da, dout, prec, lim):
    a0 = [None]

    def step(k):
        if k == 0:
            a0[0] = a[0]
            out.append(POINTWISE["log"]([a[0]], None, prec))
            return
        _extend_d(a, da, k)
        _extend_d(out, dout, k - 1)
        man, exp = _dot(dout[1:k], a[k - 1:0:-1], lim)
        s, m, e, _ = da[k]
        man, exp = _addme(-m if s else m, e, -man, exp, lim)
        if not man:
            out.append(fzero)
            return
        out.append(mpf_div(from_man_exp(man, exp), mpf_mul(a0[0], from_int(k)), prec, RND))
    return step


def _mk_sincos(s_out, c_out, a, da, prec, lim, hyperbolic):
    def step(k):
        if k == 0:
            if hyperbolic:
                c0, s0 = mpf_cosh_sinh(a[0], prec, RND)
            else:
                c0, s0 = mpf_cos_sin(a[0], prec, RND)
            s_out.append(s0)
            c_out.append(c0)
            return
        _extend_d(a, da, k)
        d = da[1:k + 1]
        ms, es = _dot(d, c_out[k - 1::-1], lim)
        mc, ec = _dot(d, s_out[k - 1::-1], lim)
        if not hyperbolic:
            mc = -mc
        kk = from_int(k)
        s_out.append(mpf_div(from_man_exp(ms, es), kk, prec, RND) if ms else fzero)
        c_out.append(mpf_div(from_man_exp(mc, ec), kk, prec, RND) if mc else fzero)
    return step


def _mk_tan(out, u, a, da, prec, lim, hyperbolic):
    """out = tan(a) (or tanh), u = 1 + out^2 (or 1 - out^2) kept alongside."""
    def step(k):
        if k == 0:
            t0 = POINTWISE["tanh" if hyperbolic else "tan"]([a[0]], None, prec)
            t2 = mpf_mul(t0, t0)
            out.append(t0)
            u.append(mpf_sub(fone, t2, prec, RND) if hyperbolic else mpf_add(fone, t2, prec, RND))
            return
        _extend_d(a, da, k)
        man, exp = _dot(da[1:k + 1], u[k - 1::-1], lim)
        out.append(mpf_div(_exact(man, exp), from_int(k), prec, RND) if man else fzero)
        man, exp = _sqr_me(out, k, lim)
        if hyperbolic:
            man = -man
        u.append(from_man_exp(man, exp, prec, RND) if man else fzero)
    return step


def _mk_atan(out, u, a, da, dout, prec, lim):
    """out = atan(a), u = 1 + a^2 kept alongside."""
    def step(k):
        if k == 0:
            a2 = mpf_mul(a[0], a[0])
            u.append(mpf_add(fone, a2, prec, RND))
            out.append(POINTWISE["atan"]([a[0]], None, prec))
            return
        man, exp = _sqr_me(a, k, lim)
        u.append(from_man_exp(man, exp, prec, RND) if man else fzero)
        _extend_d(a, da, k)
        _extend_d(out, dout, k - 1)
        man, exp = _dot(dout[1:k], u[k - 1:0:-1], lim)
        s, m, e, _ = da[k]
        man, exp = _addme(-m if s else m, e, -man, exp, lim)
        if not man:
            out.append(fzero)
            return
        out.append(mpf_div(from_man_exp(man, exp), mpf_mul(u[0], from_int(k)), prec, RND))
    return step


# --------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------


def _jet_steps(plan, J, cv, prec, lim):
    """The step of each plan instruction (``step(k)`` appends coefficient k + 1 of its outputs) over the jets
    ``J`` and the constants ``cv``; the jets of derivatives some rules keep are made here, one per slot."""
    D = {}

    def dj(s):
        d = D.get(s)
        if d is None:
            d = D[s] = []
        return d

    steps = []
    for kind, out, args, extra in plan.instrs:
        if kind == "lin":
            vt = [(J[x], n) for x, n in args]
            ct = [(cv[x], n) for x, n in extra]
            steps.append(_mk_lin(J[out], vt, ct, prec))
        elif kind == "scale":
            steps.append(_mk_scale(J[out], J[args[0]], cv[extra], prec))
        elif kind == "mul":
            steps.append(_mk_mul(J[out], J[args[0]], J[args[1]], prec, lim))
        elif kind == "sqr":
            steps.append(_mk_sqr(J[out], J[args[0]], prec, lim))
        elif kind == "div":
            steps.append(_mk_div(J[out], J[args[0]], J[args[1]], prec, lim))
        elif kind == "rdiv":
            steps.append(_mk_div(J[out], None, J[args[0]], prec, lim, const_num=cv[extra]))
        elif kind == "pow":
            e, data = extra
            a = args[0]
            steps.append(_mk_pow(J[out], J[a], dj(a), dj(out), cv[e], data, prec, lim))
        elif kind == "sqrt":
            steps.append(_mk_sqrt(J[out], J[args[0]], prec, lim))
        elif kind == "exp":
            a = args[0]
            steps.append(_mk_exp(J[out], J[a], dj(a), prec, lim))
        elif kind == "log":
            a = args[0]
            steps.append(_mk_log(J[out], J[a], dj(a), dj(out), prec, lim))
        elif kind in ("sincos", "sinhcosh"):
            a = args[0]
            steps.append(_mk_sincos(J[out[0]], J[out[1]], J[a], dj(a), prec, lim,
                                    kind == "sinhcosh"))
        elif kind in ("tan", "tanh"):
            a = args[0]
            steps.append(_mk_tan(J[out[0]], J[out[1]], J[a], dj(a), prec, lim,
                                 kind == "tanh"))
        elif kind == "atan":
            a = args[0]
            steps.append(_mk_atan(J[out[0]], J[out[1]], J[a], dj(a), dj(out[0]), prec, lim))
        else:  # pragma: no cover
            raise AssertionError(kind)
    return steps


def taylor_coefficients_raw(program, y0_raw, pars_raw, order, prec, deadline=None):
    """Taylor-mode expansion on raw mpfs (no checks, no final rounding).

    Parameters
    ----------
    program : Program
        Compiled right-hand side (``nout == nvars``).
    y0_raw, pars_raw : list of raw mpf tuples
        Initial state and parameters, already at `prec` bits.
    order : int
        Highest coefficient computed (>= 1).
    prec : int
        Working precision in bits (guard bits included by the caller).
    deadline : float, optional
        A :func:`time.perf_counter` value: the clock is read after every
        order, and :class:`DeadlineExceeded` raised once it is passed (a long
        expansion then stops within one order's work of its budget).

    Returns
    -------
    list of list of raw mpf
        ``jets[i][k]`` is the k-th normalised Taylor coefficient of variable
        i (note the index order: variable first), ``k = 0 .. order``.
    """
    plan = jet_plan(program)
    cv = plan.constant_values(pars_raw, prec)
    lim = 2 * prec
    nvars = program.nvars
    is_const = plan.is_const
    J = [None] * plan.nslots
    for i in range(nvars):
        J[i] = [y0_raw[i]]
    for s in range(nvars, plan.nslots):
        if not is_const[s]:
            J[s] = []
    steps = _jet_steps(plan, J, cv, prec, lim)

    # where coefficient k of each right-hand side comes from
    rhs_src = []
    for i, o in enumerate(plan.outputs):
        rhs_src.append((J[i], None, J[o]) if not is_const[o] else (J[i], cv[o], None))
    ints = [from_int(n) for n in range(order + 2)]

    for k in range(order):
        if deadline is not None and k and _clock() > deadline:
            raise DeadlineExceeded(k)
        for st in steps:
            st(k)
        kk = ints[k + 1]
        for zi, c, src in rhs_src:
            x = src[k] if src is not None else (c if k == 0 else fzero)
            zi.append(mpf_div(x, kk, prec, RND) if x[1] else fzero)
    return [J[i] for i in range(nvars)]


def taylor_coefficients(program_or_system, y0, pars, order, dps, ctx=None, deadline=None):
    """Normalised Taylor coefficients of the solution of ``dz/dt = rhs(z)``.

    Parameters
    ----------
    program_or_system : Program or list of (variable, expression) pairs
        The vector field: a :class:`~lieseries.expr.Program` from
        :func:`~lieseries.expr.compile_system` (preferred when calling
        repeatedly), or a heyoka-style system ``[(z_1, rhs_1), ...]`` (compiled
        on first use and cached).
    y0 : sequence of numbers
        Initial state z(0): int, str (read exactly, e.g. ``"0.1"``),
        fractions.Fraction, float (its exact binary value), mpmath.mpf or a
        sympy number; converted at the working precision.
    pars : sequence of numbers
        Values of the runtime parameters ``hy.par[0..]`` (same types), exactly
        as many as the system uses.
    order : int
        Highest coefficient (>= 1); ``order + 1`` coefficients are returned.
    dps : int
        Decimal digits of the results (>= 5; at most ``MAX_DPS``, plus up to
        ``MAX_GUARD_DIGITS`` guard digits an engine adds to its user's dps).
        The computation runs with :func:`jet_guard_bits` extra bits.
    deadline : float, optional
        A :func:`time.perf_counter` value after which the expansion stops with
        :class:`DeadlineExceeded` (checked after every order).

    Returns
    -------
    list of list of mpmath.mpf
        ``c[k][i]`` is the k-th normalised Taylor coefficient
        ``z_i^(k)(0) / k!``, for ``k = 0 .. order``; ``c[0]`` is `y0`.

    Raises
    ------
    ValueError
        On a wrong length of `y0` or `pars`, ``order < 1``, ``dps < 5``, or
        when an expansion does not exist (e.g. ``log``/``sqrt``/non-integer
        power at a zero argument, or a zero denominator).

    Notes
    -----
    Cost: O(order^2) operations per node of the compiled right-hand side;
    about 8 ms for the 12-dimensional rigid body at order 30 and 50 digits
    (12 ms at 100 digits, 30 ms at order 60 and 60 digits), pure Python.
    """
    program = resolve_program(program_or_system)
    order = check_order(order)
    # the engines call this with their guard digits added to the user's dps (already checked, by the user's name)
    if isinstance(dps, int) and not isinstance(dps, bool) and MAX_DPS < dps <= MAX_DPS + MAX_GUARD_DIGITS:
        dps = int(dps)
    else:
        dps = check_dps(dps)
    # explicit precision: mpmath's global context is never touched
    prec = mpmath.libmp.dps_to_prec(dps)
    wp = prec + jet_guard_bits(order)
    y0r = _expr.convert_vector(y0, program.nvars, wp, "y0")
    pr = _expr.convert_vector(pars, program.npars, wp, "pars")
    try:
        jets = taylor_coefficients_raw(program, y0r, pr, order, wp, deadline)
    except ZeroDivisionError as exc:
        raise ValueError(
            f"the Taylor expansion does not exist at `y0` ({exc}; a zero denominator "
            "or a log/sqrt/non-integer power at zero)"
        ) from None
    return [[rounded_mpf(prec, jets[i][k], ctx) for i in range(program.nvars)] for k in range(order + 1)]
