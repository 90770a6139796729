"""The fixed-point jets (lieseries.lie.fixed) against the mpf jets at twice the digits and against closed forms.

The fixed-point jets promise every coefficient c_k to the working precision relative to ``scale * sigma**-k``
(scale: the size of the state, sigma = 2**s the time scale), the accuracy a Lie step needs at |h| <= sigma; the
tests measure exactly that, with gmpy2's integers and with Python ints.
"""

from fractions import Fraction

import heyoka as hy
import mpmath as mp
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.lie import compile_system, fixed, taylor_coefficients
from lieseries.precision import Precision

from problems import RB_PARS, RB_Y0, mpf, nonlinear, rigid_body, rigid_error


def scaled_error(got, ref, s, scale):
    """max_k,i |got - ref| 2**(s k) / scale."""
    with mp.workdps(300):
        return max(abs(mp.mpf(g) - mp.mpf(r)) * mp.mpf(2) ** (s * k)
                   for k, (rg, rr) in enumerate(zip(got, ref)) for g, r in zip(rg, rr)) / scale


def check(prog, y0, pars, order, dps, s, scale=None, rows=None, ref=None):
    """Fixed-point coefficients (time scale 2**s) against the mpf jets at 2 dps (``ref``, when given, is those
    jets): error <= 10**(1-dps) scale (default scale: the largest scaled coefficient |c_k| 2**(s k)); ``rows``
    restricts to some variables."""
    got = fixed.fixed_taylor_coefficients(prog, y0, pars, order, dps, time_scale=s)
    if ref is None:
        ref = taylor_coefficients(prog, y0, pars, order, 2 * dps)
    if rows is not None:
        got, ref = [[r[i] for i in rows] for r in got], [[r[i] for i in rows] for r in ref]
    if scale is None:
        with mp.workdps(2 * dps):
            scale = max(abs(r) * mp.mpf(2) ** (s * k) for k, row in enumerate(ref) for r in row)
    err = scaled_error(got, ref, s, scale)
    assert err <= mp.mpf(10) ** (1 - dps), (float(err), dps)
    return got, ref


def test_backend_switch():
    before = fixed.backend()
    try:
        assert fixed.set_backend("int") == "int"
        with pytest.raises(ValueError, match="`name`"):
            fixed.set_backend("float")
    finally:
        fixed.set_backend(before)


def test_every_module_follows_the_backend(bigint):
    """The integers of an expansion, of its evaluation and of its step builders are the backend's type just after
    a switch (no module keeps the type it saw at import)."""
    from lieseries.lie import bigint as big

    Z = big.integer_type()
    assert (Z is int) == (bigint == "int")
    stepper = fixed.FixedStepper(compile_system(*rigid_body()), RB_PARS, 20, Precision.of(dps=30))
    jets = stepper.expand([mp.mpf(v) for v in RB_Y0], 1)
    assert {type(m) for row in jets.M for m in row} == {Z}
    assert all(hasattr(v, "_mpf_") for v in jets.evaluate(jets.max_step / 2))


@pytest.mark.parametrize("dps", [30, 50])
@pytest.mark.parametrize("s", [0, 1, -2])
def test_rigid_body(bigint, dps, s):
    check(compile_system(*rigid_body()), RB_Y0, RB_PARS, 40, dps, s, 1.5)


@pytest.mark.parametrize("dps", [130, 320])
def test_high_precision(bigint, dps):
    # above ~100 digits Python ints take the products one by one (no packed dot products), above ~300 gmpy2 too
    check(compile_system(*rigid_body()), RB_Y0, RB_PARS, 30, dps, -1, 1.5)


@pytest.mark.parametrize("dps", [30, 90])
def test_time_scale_far_above_the_radius(bigint, dps):
    # sigma = 2**8 >> radius: the scaled coefficients grow by ~8 bits per order (packed products widen; at 90
    # digits the packed products pair their terms)
    check(compile_system(*rigid_body()), RB_Y0, RB_PARS, 40, dps, 8)


def test_rigid_body_exact_series(bigint):
    # the order-1 and order-2 coefficients in closed form: M' = M x Omega, R' = R hat(Omega)
    got = fixed.fixed_taylor_coefficients(compile_system(*rigid_body()), RB_Y0, RB_PARS, 3, 40)
    M = [Fraction(1), Fraction(1, 5), Fraction(3, 2)]
    om = [m * p for m, p in zip(M, RB_PARS)]
    dM = [M[1] * om[2] - M[2] * om[1], M[2] * om[0] - M[0] * om[2], M[0] * om[1] - M[1] * om[0]]
    with mp.workdps(60):
        for i in range(3):
            assert abs(got[1][9 + i] - mpf(dM[i])) < mp.mpf(10) ** -39


@pytest.mark.parametrize("chart", [0, 2])
def test_sphere_charts(bigint, chart):
    sph = ls.Sphere(Fraction(3, 2), chart=chart)
    x = ("0.8", "0", "0.6") if chart == 0 else ("0.6", "0", "0.8")
    y0 = sph.initial_state(x, ("0", "1", "0"))
    ps = sph.poisson
    check(ps.program, list(y0), list(ps.parameter_values), 40, 40, 0)


def test_sphere_of_radius_1e6(bigint):
    sph = ls.Sphere(2, radius=10**6)
    y0 = sph.initial_state((6 * 10**5, 0, 8 * 10**5), (0, "1e-3", 0))
    ps = sph.poisson
    # the radius of convergence in t is ~ radius / speed = 1e9
    got, ref = check(ps.program, list(y0), list(ps.parameter_values), 30, 40, 30, 10**6)
    assert abs(got[1][1] - mp.mpf("1e-3")) < mp.mpf(10) ** -42


def every_op():
    """A coupled system using sqrt, exp, log, sin/cos, sinh/cosh, tan, tanh, atan, div, rdiv, non-integer pow."""
    x, y, z = v = hy.make_vars("x", "y", "z")
    p = hy.par[0]
    rhs = [hy.tan(0.3 * y) + hy.sinh(z) / (2.0 + x * x) - hy.atan(x * z) + p,
           hy.tanh(x) * hy.cosh(y) - 3.0 / (1.5 + z) + y**p,
           hy.exp(-x * y) * hy.sin(z) + hy.cos(x) * hy.sqrt(1.0 + y * y) + hy.log(2.0 + x) - z**-0.5]
    return list(v), rhs


@pytest.mark.parametrize("dps", [30, 60, 100])
def test_every_instruction(bigint, dps):
    # from bigint.PAIR_BITS (100 digits) on, Cauchy products pair their terms (half the multiplications)
    check(compile_system(*every_op()), ["0.25", "0.5", "0.75"], [Fraction(2, 7)], 30, dps, -2, 1)
    check(compile_system(*nonlinear()), ["0.5", "0.25", "0.75"], [Fraction(2, 7)], 30, dps, -2, 1)


@pytest.mark.parametrize("factor", ["1e6", "1e-6"])
def test_states_far_from_one(bigint, factor):
    # M scaled by f: the motion is f times faster (Omega = M / I), R stays of size 1
    f = Fraction(factor)
    y0 = RB_Y0[:9] + [Fraction(v) * f for v in RB_Y0[9:]]
    s = -20 if f > 1 else 20
    prog = compile_system(*rigid_body())
    check(prog, y0, RB_PARS, 30, 40, s, 1, rows=range(9))  # R, of size 1
    check(prog, y0, RB_PARS, 30, 40, s, 1.5 * f, rows=range(9, 12))  # M, relative to its own size


@pytest.mark.parametrize("op", ["tan", "atan"])
def test_tan_atan_of_an_argument_of_size_1e20(bigint, op):
    # x = 8e20 moving at speed ~1: the argument's scale is 2**68, and tan's and atan's 1 + u^2 took the square of it
    # (136 bits, above F): tan's coefficients from order 2 on rounded to zero (an error of 1e-3 against a promise of
    # 1e-8), atan's 1 + u^2 at order 0 to zero (a division by zero: "the expansion does not exist")
    x = hy.make_vars("x")
    u = hy.sin(x * hy.par[0])
    rhs = hy.tan(0.25 * u) if op == "tan" else hy.atan(u)
    check(compile_system([x], [rhs]), [8 * 10**20], [Fraction(1, 3)], 20, 30, 0, scale=8 * 10**20)


def test_a_state_at_zero_moving_slowly_to_its_own_size(bigint):
    # y(0) = 0 with y' ~ 1e-25: y took x's exponent (of size 1), and its coefficients were 1e-6 of its own size at
    # 30 digits; an expansion run again from what y carried holds them to the working precision of y
    x, y = hy.make_vars("x", "y")
    prog = compile_system([x, y], [hy.sin(y) + 1.0, hy.par[0] * (1.0 + x * x)])
    check(prog, ["0.5", 0], ["1e-25"], 20, 30, 0, scale=mp.mpf("1e-25"), rows=[1])


@pytest.mark.parametrize("c", ["1e-20", "1e-40"])
def test_lie_integrate_from_zero_with_a_tiny_velocity(bigint, c):
    # the first step from y(0) = 0, y' ~ c: the jets at a time scale of 2**31 (the span is 1) and y at the exponent
    # of x (size 1) ended success 2e-13 (c = 1e-40) relative off at tol 1e-30
    x, y = hy.make_vars("x", "y")
    sy = ls.PoissonSystem([x, y], [[0, 0], [0, 0]], 0.0 * x, extra_field=[hy.sin(y) + 1.0, hy.par[0] * (1.0 + x * x)],
                          parameters=[c], jacobi=False)
    sol = ls.lie_integrate(sy, ["0.5", 0], 1, dps=30, guard=0)
    ref = ls.lie_integrate(sy, ["0.5", 0], 1, dps=70)
    assert sol.status == "success" and ref.status == "success"
    with mp.workdps(80):
        yb = mp.mpf(ref.y[-1][1])
        assert abs(mp.mpf(sol.y[-1][1]) - yb) <= 3 * mp.mpf(10) ** -30 * abs(yb)


def test_a_cancelling_square_of_a_state_of_size_1e20(bigint):
    # x' = (p + x)^2 - p^2 - 2 p x - x^2 + p q + r sin x = p q + r sin x: at x = 6e20, p + x rounded at x's unit
    # dropped p and the squares were rounded 2^138 - F: x' = -7.2 instead of 8.8e-15 (64 of x's bits lost at 30
    # digits); the expansion measures what its roundings cost the states and runs again at more working bits
    x = hy.make_vars("x")
    p, q, r = hy.par[0], hy.par[1], hy.par[2]
    rhs = (p + x) * (p + x) - p * p - 2.0 * p * x - x * x + p * q + r * hy.sin(x)
    check(compile_system([x], [rhs]), [6 * 10**20], ["6e-21", "1e-30", "1e-14"], 20, 30, -5, scale=6 * 10**20)


@pytest.mark.parametrize("x0, guard", [(6 * 10**20, 0), (6 * 10**20, None), (10**60, None)])
def test_lie_integrate_through_a_cancelling_square(bigint, x0, guard):
    # the field above: at x = 6e20 lie_integrate ended `success` 7.2 off (guard 0; 1.3e-9 with the default guard, at
    # a tolerance of 6e-10), at x = 1e60 `success` 1.2e40 off; the change of x over the span is 9e-15 (6e-15).
    # At 1e60 the jets hold x' to 2^-F of x (1e9), which drives sin(x) with a frequency of 1e9: a run too long for
    # its step budget (loud), right at 150 digits
    x = hy.make_vars("x")
    p, q, r = hy.par[0], hy.par[1], hy.par[2]
    rhs = (p + x) * (p + x) - p * p - 2.0 * p * x - x * x + p * q + r * hy.sin(x)
    sy = ls.PoissonSystem([x], [[0]], 0.0 * x, extra_field=[rhs], parameters=["6e-21", "1e-30", "1e-14"],
                          jacobi=False)
    kw = {} if guard is None else {"guard": guard}
    sol = ls.lie_integrate(sy, [x0], 1, dps=30, **kw)
    ref = ls.lie_integrate(sy, [x0], 1, dps=150)
    assert ref.status == "success"
    assert sol.status == "success" or x0 > 10**30
    if sol.status != "success":  # early (its steps of 1e-13 took the default budget of 100000 and two minutes)
        assert sol.status == "step_budget" and sol.stats.steps <= 1000 and "more than any step budget" in sol.message
        assert "cancels" in sol.message and "more digits" in sol.message  # (150 digits are right)
    if sol.status == "success":
        with mp.workdps(200):
            assert abs(mp.mpf(sol.y[-1][0]) - mp.mpf(ref.y[-1][0])) <= mp.mpf(10) ** -30 * x0


def test_lie_integrate_a_state_whose_rate_cancels_terms_of_a_large_one(bigint):
    # y ~ 1 with y' = (p + x)^2 - p^2 - 2 p x - x^2 + r cos y = r cos y beside x = 6e20: y ended `success` 1.3e-9 off
    # at 30 digits (the squares rounded F bits below 3.6e41)
    x, y = hy.make_vars("x", "y")
    p, r = hy.par[0], hy.par[1]
    sy = ls.PoissonSystem([x, y], [[0, 0], [0, 0]], 0.0 * x,
                          extra_field=[r * y, (p + x) * (p + x) - p * p - 2.0 * p * x - x * x + r * hy.cos(y)],
                          parameters=["6e-21", "1e-14"], jacobi=False)
    sol = ls.lie_integrate(sy, [6 * 10**20, 1], 1, dps=30)
    ref = ls.lie_integrate(sy, [6 * 10**20, 1], 1, dps=80)
    assert sol.status == "success" and ref.status == "success"
    with mp.workdps(100):
        assert abs(mp.mpf(sol.y[-1][1]) - mp.mpf(ref.y[-1][1])) <= mp.mpf(10) ** -30


@pytest.mark.parametrize("p", ["1e20", "1e-20"])
def test_parameters_far_from_one(bigint, p):
    pars = [Fraction(q) * Fraction(p) for q in RB_PARS]
    s = -66 if Fraction(p) > 1 else 66
    check(compile_system(*rigid_body()), RB_Y0, pars, 30, 40, s, 1.5)


def test_zero_state_components(bigint):
    # variables starting at 0 take the smallest exponent of the others
    x, y = hy.make_vars("x", "y")
    check(compile_system([x, y], [1.0 + y**2, x**3 - x * y]), ["1e-6", 0], [], 20, 40, 0)


def test_expansion_errors(bigint):
    x = hy.make_vars("x")
    with pytest.raises(ValueError, match="does not exist"):
        fixed.fixed_taylor_coefficients([(x, hy.log(x))], [0], [], 5, 30)
    with pytest.raises(ValueError, match="does not exist"):
        fixed.fixed_taylor_coefficients([(x, 1.0 / x)], [0], [], 5, 30)


@pytest.mark.parametrize("dps", [30, 50, 100])
def test_lie_integrate_rigid_body(bigint, dps):
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1, "0.1", "0.5"))
    sol = ls.lie_integrate(body, y0, 3, dps=dps)
    assert sol.status == "success"
    assert rigid_error(sol.y[-1], 3, dps=dps + 20) < mp.mpf(10) ** (2 - dps)


def test_lie_integrate_slow_heavy_body(bigint):
    # inertia 1e20: M ~ 1e20, the same angular velocity; the closed form from the exact data
    inertia = (10**20, 2 * 10**20, 3 * 10**20)
    body = ls.EulerPoisson(inertia)
    y0 = body.initial_state((1, "0.1", "0.5"))
    sol = ls.lie_integrate(body, y0, 2, dps=30)
    assert sol.status == "success"
    ref = exact.euler_poisson(inertia, (1, "0.1", "0.5"), 2, dps=50)
    with mp.workdps(50):
        for a, b in zip(sol.y[-1], ref):
            assert abs(mpf(a) - b) <= mp.mpf(10) ** -28 * max(1, abs(b))


def test_lie_integrate_fast_tiny_body(bigint):
    # inertia 1e-20 with omega ~ 1e3: states of size 1e-17, step ~ 1e-3
    inertia = (Fraction(1, 10**20), Fraction(2, 10**20), Fraction(3, 10**20))
    omega = (1000, 100, 500)
    body = ls.EulerPoisson(inertia)
    y0 = body.initial_state(omega)
    sol = ls.lie_integrate(body, y0, Fraction(1, 100), dps=30)
    assert sol.status == "success"
    ref = exact.euler_poisson(inertia, omega, Fraction(1, 100), dps=50)
    with mp.workdps(50):
        for a, b in zip(sol.y[-1], ref):
            assert abs(mpf(a) - b) <= mp.mpf(10) ** -28 * abs(b) + mp.mpf(10) ** -28 * (abs(b) < 1e-10)


@pytest.mark.parametrize("dps", [30, 50])
def test_lie_integrate_sphere_atlas(bigint, dps):
    sph = ls.Sphere(1)
    y0 = sph.initial_state(("0.6", "0", "0.8"), ("0", "1", "0"))
    sol = ls.lie_integrate(sph, y0, 4, dps=dps)
    assert sol.status == "success"
    X = sph.position(sol)
    ref = exact.sphere(1, ("0.6", "0", "0.8"), ("0", "1", "0"), 4, dps=dps + 20)
    with mp.workdps(dps + 20):
        err = max(abs(mp.mpf(a) - b) for a, b in zip(X[-1], ref[0] if isinstance(ref, tuple) else ref))
    assert err < mp.mpf(10) ** (2 - dps)


def test_stepper_deadline(bigint):
    from time import perf_counter

    from lieseries.lie.plan import DeadlineExceeded

    prog = compile_system(*rigid_body())
    stepper = fixed.FixedStepper(prog, RB_PARS, 60, Precision.of(dps=40))
    with pytest.raises(DeadlineExceeded):
        stepper.expand([mp.mpf(v) for v in [1, 0, 0, 0, 1, 0, 0, 0, 1, 1, "0.2", "1.5"]], 10,
                       deadline=perf_counter() - 1)


def test_dense_output_pickles_and_matches_the_closed_form(bigint):
    import pickle

    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1, "0.1", "0.5"))
    sol = pickle.loads(pickle.dumps(ls.lie_integrate(body, y0, t=3, dps=30, dense=True)))
    for t in ("0.7", "2.9"):
        assert rigid_error(list(sol(mp.mpf(t))), mp.mpf(t), dps=50) < mp.mpf(10) ** -29


@pytest.mark.parametrize("dps", [30, 50, 100])
def test_packed_horner_rounds_every_state_as_its_own_horner(bigint, dps):
    """FixedJets.evaluate runs the Horner steps of the states that the dot products packed several to an integer:
    every field is rounded on its own, so each state comes out as the per-state Horner's integers (the same bits),
    and both lie within the roundings of the polynomial evaluated at twice the digits; at positive and negative
    times, at the time scale itself, and at a time with a long mantissa."""
    prog = compile_system(*rigid_body())
    prec = Precision.of(dps=dps)
    stepper = fixed.FixedStepper(prog, RB_PARS, 40, prec)
    with mp.workdps(dps + 10):
        jets = stepper.expand([mp.mpf(v) for v in [1, 0, 0, 0, 1, 0, 0, 0, 1, 1, "0.2", "1.5"]], 10)
        assert jets.packs
        sigma = jets.max_step
        for t in (sigma / 3, -sigma * mp.mpf("0.7"), sigma, mp.mpf(2) ** -40 * sigma, sigma / 7):
            packed = jets.evaluate(t)
            packs, jets.packs = jets.packs, None
            plain = jets.evaluate(t)
            jets.packs = packs
            assert packed == plain
            with mp.workdps(2 * dps):
                ref = [sum(mp.mpf(c[i]) * mp.mpf(t) ** k for k, c in enumerate(jets.coefficients))
                       for i in range(len(packed))]
                for a, b in zip(packed, ref):
                    assert abs(mp.mpf(a) - b) <= mp.mpf(10) ** (2 - dps) * max(1, abs(b))
