"""Taylor-mode jets (lieseries.lie.jets) and the expression compiler (lieseries.expr).

References are independent of the jet recurrences: closed forms, mpmath's own
``mp.taylor`` (numerical differentiation), and heyoka's Taylor coefficients
of its first step (double and 256-bit ``hy.real``).
"""

from fractions import Fraction
from math import factorial

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest
import sympy

from lieseries.lie import compile_expressions, compile_system, taylor_coefficients
from lieseries.expr import Program

from problems import RB_PARS, RB_Y0, SPHERE_M, max_rel, rigid_body, sphere, sphere_initial  # test systems


def heyoka_tc(variables, rhs, y0, pars, **kw):
    ta = hy.taylor_adaptive(list(zip(variables, rhs)), y0, pars=pars, **kw)
    ta.step(write_tc=True)
    tc = ta.tc
    return [[tc[i, k] for i in range(tc.shape[0])] for k in range(tc.shape[1])]


# --------------------------------------------------------------------------
# Closed forms
# --------------------------------------------------------------------------

def test_harmonic_oscillator_closed_form():
    x, v = hy.make_vars("x", "v")
    w = hy.par[0]
    sys_ = [(x, v), (v, -w * w * x)]
    wv = Fraction(3, 2)
    c = taylor_coefficients(sys_, [1, 0], [wv], 40, 60)
    with mp.workdps(70):
        for k in range(41):
            # x = cos(w t), v = -w sin(w t)
            xk = Fraction((-1) ** (k // 2)) * wv**k / factorial(k) if k % 2 == 0 else Fraction(0)
            vk = -wv * Fraction((-1) ** ((k - 1) // 2)) * wv**k / factorial(k) \
                if k % 2 == 1 else Fraction(0)
            for got, ref in ((c[k][0], xk), (c[k][1], vk)):
                ref = mp.mpf(ref.numerator) / ref.denominator
                assert abs(got - ref) <= mp.mpf(10) ** -58 * max(abs(ref), mp.mpf(10) ** -40)


def test_nonlinear_closed_forms():
    # y' = y^2 (y = 1/(2 - t) for y0 = 1/2); u' = 1 + u^2 (u = tan(t + atan(u0)));
    # w' = exp(-w) (w = log(t + e^{w0})); s' = -s^3 (s = (s0^-2 + 2t)^-1/2)
    y, u, w, s = hy.make_vars("y", "u", "w", "s")
    sys_ = [(y, y**2), (u, 1.0 + u * u), (w, hy.exp(-w)), (s, -s**3)]
    u0, w0, s0 = mp.mpf("0.25"), mp.mpf("0.5"), mp.mpf("0.75")
    n = 25
    c = taylor_coefficients(sys_, [Fraction(1, 2), "0.25", "0.5", "0.75"], [], n, 40)
    with mp.workdps(60):
        refs = [
            [mp.mpf(2) ** -(k + 1) for k in range(n + 1)],
            mp.taylor(lambda t: mp.tan(t + mp.atan(u0)), 0, n),
            mp.taylor(lambda t: mp.log(t + mp.exp(w0)), 0, n),
            mp.taylor(lambda t: (s0**-2 + 2 * t) ** -0.5, 0, n),
        ]
        for i, ref in enumerate(refs):
            for k in range(n + 1):
                assert abs(c[k][i] - ref[k]) <= mp.mpf(10) ** -36 * max(1, abs(ref[k])), (i, k)


def _clock_system():
    """s' = 1 plus u_j' = f_j(s): u_j's coefficients are f_j's Taylor coefficients / (k+1)."""
    s = hy.make_vars("s")
    p = hy.par[0]
    funcs = [
        ("exp", hy.exp(s), mp.exp),
        ("log", hy.log(s), mp.log),
        ("sin", hy.sin(s), mp.sin),
        ("cos", hy.cos(s), mp.cos),
        ("tan", hy.tan(s), mp.tan),
        ("sinh", hy.sinh(s), mp.sinh),
        ("cosh", hy.cosh(s), mp.cosh),
        ("tanh", hy.tanh(s), mp.tanh),
        ("atan", hy.atan(s), mp.atan),
        ("sqrt", hy.sqrt(s), mp.sqrt),
        ("pow1.5", s**1.5, lambda t: t ** mp.mpf(1.5)),
        ("pow-2", s**-2.0, lambda t: t**-2),
        ("pow-0.5", s**-0.5, lambda t: t ** mp.mpf(-0.5)),
        ("pow0.3", s**0.3, lambda t: t ** mp.mpf(0.3)),  # exact binary exponent 0.3
        ("pow_par", s**p, lambda t: t ** (mp.mpf(2) / 7)),
        ("pow7", s**7, lambda t: t**7),
        ("div", (s + 2.0) / (1.0 + s * s), lambda t: (t + 2) / (1 + t * t)),
        ("rdiv", 3.0 / s, lambda t: 3 / t),
        ("compose", hy.exp(hy.sin(s) * s) / (2.0 + hy.cos(s)) - hy.log(1.0 + s**2),
         lambda t: mp.exp(mp.sin(t) * t) / (2 + mp.cos(t)) - mp.log(1 + t**2)),
        ("varpow", s**s, lambda t: t**t),
        ("par_mul", p * hy.sin(s) - s / p, lambda t: mp.mpf(2) / 7 * mp.sin(t) - t * 7 / 2),
    ]
    us = hy.make_vars(*[f"u{j}" for j in range(len(funcs))])
    sys_ = [(s, hy.expression(1.0))] + [(u, f[1]) for u, f in zip(us, funcs)]
    return sys_, funcs


def test_every_op_against_mp_taylor():
    sys_, funcs = _clock_system()
    s0 = mp.mpf("0.75")
    n = 20
    c = taylor_coefficients(sys_, ["0.75"] + [0] * len(funcs), [Fraction(2, 7)], n + 1, 40)
    with mp.workdps(60):
        for j, (name, _, f) in enumerate(funcs):
            ref = mp.taylor(f, s0, n)
            for k in range(n + 1):
                got = c[k + 1][j + 1]
                want = ref[k] / (k + 1)
                assert abs(got - want) <= mp.mpf(10) ** -36 * max(1, abs(want)), (name, k)


def test_zero_base_integer_powers_and_products():
    # R-like variables start at 0: integer powers/products must not divide by the base
    x, y = hy.make_vars("x", "y")
    sys_ = [(x, 1.0 + y**2), (y, x**3 - x * y)]
    c = taylor_coefficients(sys_, [0, 0], [], 12, 30)
    # x = t + O(t^4)... check against literal series via sympy ODE recursion
    t = sympy.Symbol("t")
    X, Y = sympy.Poly(0, t, domain="QQ"), sympy.Poly(0, t, domain="QQ")

    def trunc(p):
        return sympy.Poly({m: c for m, c in p.as_dict().items() if m[0] <= 12} or {(0,): 0}, t,
                          domain="QQ")

    for _ in range(13):  # Picard iteration, exact in polynomials (one more order each time)
        X, Y = trunc((1 + Y**2).integrate()), trunc((X**3 - X * Y).integrate())
    with mp.workdps(40):
        for k in range(13):
            for got, ref in ((c[k][0], X.coeff_monomial(t**k)), (c[k][1], Y.coeff_monomial(t**k))):
                assert abs(got - mp.mpf(ref.p) / ref.q) < mp.mpf(10) ** -28


def test_singular_expansions_raise():
    x = hy.make_vars("x")
    for rhs in (hy.log(x), hy.sqrt(x), 1.0 / x, x**1.5):
        with pytest.raises((ValueError, ZeroDivisionError)):
            taylor_coefficients([(x, rhs)], [0], [], 5, 20)


# --------------------------------------------------------------------------
# Against heyoka's own Taylor coefficients
# --------------------------------------------------------------------------

@pytest.mark.parametrize("system", ["rigid_body", "sphere"])
def test_against_heyoka_double(system):
    if system == "rigid_body":
        variables, rhs = rigid_body()
        y0 = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0, 1.0, 0.2, 1.5]
        pars = [1.0, 0.5, 1 / 3]
    else:
        variables, rhs = sphere()
        y0 = [float(v) for v in sphere_initial(SPHERE_M)]
        pars = [float(SPHERE_M)]
    ref = heyoka_tc(variables, rhs, y0, pars, tol=1e-15)
    order = len(ref) - 1
    assert order >= 15
    # same double inputs (floats are taken as their exact binary values)
    ours = taylor_coefficients(compile_system(variables, rhs), y0, pars, order, 30)
    assert max_rel(ours, ref) < 1e-14


def test_against_heyoka_real():
    prec = 256
    variables, rhs = rigid_body()
    y0s = ["1", "0", "0", "0", "1", "0", "0", "0", "1", "1", "0.2", "1.5"]
    y0 = np.array([hy.real(v, prec) for v in y0s])
    pars = np.array([hy.real(1, prec), hy.real(1, prec) / 2, hy.real(1, prec) / 3])
    ref = heyoka_tc(variables, rhs, y0, pars, fp_type=hy.real, prec=prec)
    order = len(ref) - 1
    assert order >= 60
    ours = taylor_coefficients(compile_system(variables, rhs), y0s, RB_PARS, order, 80)
    with mp.workdps(100):
        refm = [[mp.mpf(str(x)) for x in row] for row in ref]
        assert max_rel(ours, refm) < mp.mpf(10) ** -70


def test_sphere_against_heyoka_real():
    prec = 256
    variables, rhs = sphere()
    y0f = sphere_initial(SPHERE_M)
    y0 = np.array([hy.real(v.numerator, prec) / v.denominator for v in y0f])
    pars = np.array([hy.real(3, prec) / 2])
    ref = heyoka_tc(variables, rhs, y0, pars, fp_type=hy.real, prec=prec)
    ours = taylor_coefficients(compile_system(variables, rhs), y0f, [SPHERE_M], len(ref) - 1, 80)
    with mp.workdps(100):
        refm = [[mp.mpf(str(x)) for x in row] for row in ref]
        assert max_rel(ours, refm) < mp.mpf(10) ** -70


# --------------------------------------------------------------------------
# Precision
# --------------------------------------------------------------------------

def test_precision_is_carried():
    variables, rhs = rigid_body()
    prog = compile_system(variables, rhs)
    a = taylor_coefficients(prog, RB_Y0, RB_PARS, 25, 80)
    b = taylor_coefficients(prog, RB_Y0, RB_PARS, 25, 120)
    with mp.workdps(130):
        assert max_rel(a, b) < mp.mpf(10) ** -78
        # a parameter rounded through a double is visible at this precision
        c = taylor_coefficients(prog, RB_Y0, [1, 0.5, 1 / 3], 25, 80)
        d = max_rel(c, b)
        assert mp.mpf(10) ** -19 < d < mp.mpf(10) ** -14
        # ... and so is an initial state read from a double
        e = taylor_coefficients(prog, RB_Y0[:10] + [0.2, 1.5], RB_PARS, 25, 80)
        assert max_rel(e, b) > mp.mpf(10) ** -19


def test_returned_precision_and_context():
    variables, rhs = rigid_body()
    before = mp.mp.prec
    c = taylor_coefficients(list(zip(variables, rhs)), RB_Y0, RB_PARS, 4, 33)
    assert mp.mp.prec == before
    with mp.workdps(33):
        assert all(x == +x for row in c for x in row)
    assert c[0][10] != mp.mpf(0.2)  # "0.2" is read as a decimal, not as a double
    assert len(c) == 5 and all(len(row) == 12 for row in c)


# --------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------

def test_bad_input_messages():
    variables, rhs = rigid_body()
    prog = compile_system(variables, rhs)
    with pytest.raises(ValueError, match="`y0` must have length 12"):
        taylor_coefficients(prog, RB_Y0[:-1], RB_PARS, 5, 30)
    with pytest.raises(ValueError, match="`order` must be an integer >= 1; got 0"):
        taylor_coefficients(prog, RB_Y0, RB_PARS, 0, 30)
    with pytest.raises(ValueError, match="`dps` must be at least 15 decimal digits; got 3"):
        taylor_coefficients(prog, RB_Y0, RB_PARS, 5, 3)
    with pytest.raises(ValueError, match="`dps` must be at least 15 decimal digits; got 0"):
        taylor_coefficients(prog, RB_Y0, RB_PARS, 5, 0)
    with pytest.raises(ValueError, match="`pars` must have length 3; got 2"):
        taylor_coefficients(prog, RB_Y0, RB_PARS[:2], 5, 30)
    with pytest.raises(TypeError, match=r"`y0\[3\]`"):
        taylor_coefficients(prog, RB_Y0[:3] + [object()] + RB_Y0[4:], RB_PARS, 5, 30)
    with pytest.raises(ValueError, match=r"`y0\[0\]`"):
        taylor_coefficients(prog, ["abc"] + RB_Y0[1:], RB_PARS, 5, 30)
    with pytest.raises(TypeError, match="program_or_system"):
        taylor_coefficients(42, RB_Y0, RB_PARS, 5, 30)


# --------------------------------------------------------------------------
# The compiler
# --------------------------------------------------------------------------

def test_compile_is_cached_and_reusable_at_any_precision():
    variables, rhs = rigid_body()
    p1 = compile_system(variables, rhs)
    p2 = compile_system(*rigid_body())
    assert isinstance(p1, Program) and p1 is p2
    assert p1.nvars == 12 and p1.npars == 3 and p1.nout == 12
    lo = taylor_coefficients(p1, RB_Y0, RB_PARS, 10, 20)
    hi = taylor_coefficients(p1, RB_Y0, RB_PARS, 10, 60)
    assert max_rel(lo, hi) < 1e-19


def test_float_constants_are_exact_binary_and_rationals_exact():
    x = hy.make_vars("x")
    prog = compile_expressions([x], [x * 0.1, hy.sqrt(x), x**0.5 + 0 * x, hy.expression(0.1)])
    with mp.workdps(60):
        vals = prog.evaluate([2], [], 60)
        assert vals[0] == 2 * mp.mpf(0.1)  # the double 0.1, exactly
        assert vals[0] != 2 * mp.mpf("0.1")
        assert vals[1] == mp.sqrt(2) and vals[2] == mp.sqrt(2)
        assert vals[3] == mp.mpf(0.1)
    # sympy's view of heyoka doubles: exact binary value, also for 0.1
    f = hy.to_sympy(hy.expression(0.1))
    sign, man, exp, _ = f._mpf_
    assert isinstance(f, sympy.Float) and f._prec == 53
    assert (-1) ** sign * Fraction(man) * Fraction(2) ** exp == Fraction(0.1)


def test_evaluate_matches_mpmath():
    x, y = hy.make_vars("x", "y")
    exprs = [hy.exp(x) * hy.cos(y) / (1.0 + x * x) - hy.par[0] * hy.log(y),
             hy.atan(x * y) + hy.tanh(x) - hy.sinh(y) + hy.cosh(x) ** 3,
             x ** hy.par[0], hy.tan(y) - y**-3]
    prog = compile_expressions([x, y], exprs)
    assert prog.npars == 1
    with mp.workdps(50):
        X, Y, P = mp.mpf("0.3"), mp.mpf("1.7"), mp.mpf(5) / 4
        got = prog.evaluate(["0.3", "1.7"], [Fraction(5, 4)], 50)
        want = [mp.exp(X) * mp.cos(Y) / (1 + X * X) - P * mp.log(Y),
                mp.atan(X * Y) + mp.tanh(X) - mp.sinh(Y) + mp.cosh(X) ** 3,
                X**P, mp.tan(Y) - Y**-3]
        for g, w in zip(got, want):
            assert abs(g - w) <= mp.mpf(10) ** -48 * abs(w)


def test_unsupported_functions_are_named():
    x = hy.make_vars("x")
    with pytest.raises(NotImplementedError, match="erf"):
        compile_expressions([x], [hy.erf(x)])
    with pytest.raises(NotImplementedError, match="asin"):
        compile_expressions([x], [hy.asin(x) + x])
    with pytest.raises(NotImplementedError, match="time"):
        compile_expressions([x], [x * hy.time])
    y = hy.make_vars("y")
    with pytest.raises(ValueError, match="`y`"):
        compile_expressions([x], [x + y])
    with pytest.raises(ValueError, match="npars"):
        compile_expressions([x], [x + hy.par[2]], npars=1)


def test_a_passed_deadline_stops_the_expansion_and_none_changes_nothing():
    import time

    from lieseries.lie.plan import DeadlineExceeded

    x, v = hy.make_vars("x", "v")
    sys_ = [(x, v), (v, -x)]
    with pytest.raises(DeadlineExceeded) as info:
        taylor_coefficients(sys_, [1, 0], [], 40, 30, deadline=time.perf_counter() - 1)
    assert info.value.order == 1  # the clock is read after every order
    c = taylor_coefficients(sys_, [1, 0], [], 40, 30, deadline=time.perf_counter() + 3600)
    # x = cos t: c_k = (-1)^(k/2) / k! for even k
    from lieseries.precision import to_fraction

    assert all(abs(to_fraction(c[k][0]) - Fraction((-1) ** (k // 2), factorial(k))) < Fraction(1, 10**29)
               for k in range(0, 41, 2))


def test_the_engines_guard_digits_above_the_user_limit_are_accepted():
    # an engine asks for the user's dps (at most MAX_DPS) plus its guard digits: 10000 + 10 must work
    from lieseries.precision import MAX_DPS

    x, v = hy.make_vars("x", "v")
    c = taylor_coefficients([(x, v), (v, -x)], [1, 0], [], 4, MAX_DPS + 10)
    ctx = mp.MPContext()
    ctx.dps = MAX_DPS + 40
    # x = cos t, v = -sin t: to 10010 digits
    for got, ref in ((c[2][0], ctx.mpf(-1) / 2), (c[4][0], ctx.mpf(1) / 24), (c[3][1], ctx.mpf(1) / 6)):
        assert abs(ctx.convert(got) - ref) < ctx.mpf(10) ** -(MAX_DPS + 9)
    with pytest.raises(ValueError, match="`dps`"):
        taylor_coefficients([(x, v), (v, -x)], [1, 0], [], 4, MAX_DPS + 5000)
