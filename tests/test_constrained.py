"""ConstrainedSystem: a Lagrangian with holonomic constraints -> the Dirac-bracket model (paper, p8.1 and p8.7).

References are independent of the derivation: the Dirac bracket of the sphere written by hand (seed NOTES), the
great circle (``ls.exact.sphere``), mpmath's ``odefun`` on the equations of motion in angles, and the pendulum's
closed form in Jacobi elliptic functions.
"""

import re
from fractions import Fraction

import mpmath
import numpy as np
import pytest
import sympy as sp

import lieseries as ls
from lieseries.precision import resolve_precision
from problems import ctx_mpf, private_ctx

SPHERE_L = "m/2*(x1_dot**2 + x2_dot**2 + x3_dot**2)"
SPHERE_Q = ["x1", "x2", "x3"]
SPHERE_G = ["x1**2 + x2**2 + x3**2 - c**2"]




@pytest.fixture(scope="module")
def sphere():
    return ls.ConstrainedSystem(SPHERE_L, SPHERE_Q, SPHERE_G, parameters={"m": "3/2", "c": 1})


@pytest.fixture(scope="module")
def spherical_pendulum():
    return ls.ConstrainedSystem(SPHERE_L + " - m*g*x3", SPHERE_Q, ["x1**2 + x2**2 + x3**2 - l**2"],
                                parameters={"m": 1, "g": "9.81", "l": 1})


# -- the derivation ----------------------------------------------------------------------------------------------
def test_sphere_dirac_bracket_is_the_known_one(sphere):
    """{x_i, x_j}_D = 0, {x_i, p_j}_D = delta_ij - x_i x_j/|x|^2, {p_i, p_j}_D = (p_i x_j - x_i p_j)/|x|^2 and
    H_0 = |p|^2/2m, symbolically (NOTES.md, 'Useful facts'); the constraints are |x|^2 - c^2 and 2 x.p/m."""
    d = sphere.dirac_bracket()
    x, p = d["q"], d["p"]
    r2 = sum(v**2 for v in x)
    expected = sp.zeros(6, 6)
    for i in range(3):
        for j in range(3):
            expected[i, 3 + j] = sp.KroneckerDelta(i, j) - x[i] * x[j] / r2
            expected[3 + j, i] = -expected[i, 3 + j]
            expected[3 + i, 3 + j] = (p[i] * x[j] - x[i] * p[j]) / r2
    assert sp.simplify(d["tensor"] - expected) == sp.zeros(6, 6)
    m = sp.Symbol("m", real=True)
    assert sp.simplify(d["H0"] - sum(v**2 for v in p) / (2 * m)) == 0
    assert sp.simplify(d["Phi"][0] - 2 * sum(a * b for a, b in zip(x, p)) / m) == 0


def test_derived_sphere_field_equals_the_hand_written_dirac_model(sphere):
    """The derived vector field and SphereDirac's (written by hand) agree at a state on the sphere."""
    model = sphere.dirac()
    hand = ls.SphereDirac(mass="3/2", radius=1)
    y = model.initial_state(q=("0.6", "0", "0.8"), qdot=("0.48", "1", "-0.36"))
    z = hand.initial_state(x=("0.6", "0", "0.8"), v=("0.48", "1", "-0.36"))
    assert list(y.exact) == list(z.exact)
    from lieseries.expr import compile_expressions

    def field(m, state):
        prog = compile_expressions(m.poisson.variables, m.poisson.vector_field, len(m.poisson.parameter_values))
        return prog.evaluate(list(state.exact), list(m.poisson.parameter_values), 40)

    for a, b in zip(field(model, y), field(hand, z)):
        assert abs(a - b) < mpmath.mpf(10) ** -38


def test_dirac_bracket_is_poisson_with_the_constraints_as_casimirs():
    """Antisymmetric, Jacobi (the Dirac bracket is Poisson everywhere C is invertible, on and off the surface),
    and G, Phi Casimirs, for a system with two constraints (a particle on a tilted circle)."""
    cs = ls.ConstrainedSystem("(x_dot**2 + 2*y_dot**2 + z_dot**2)/2 - y", ["x", "y", "z"],
                              ["x**2 + y**2 + z**2 - 1", "x + y + 2*z - 1/3"])
    model = cs.dirac()
    ps = model.poisson
    assert set(ps.casimirs) == {"G1", "G2", "Phi1", "Phi2"}
    pts = [[str(v) for v in row] for row in np.random.default_rng(1).uniform(0.3, 1.3, size=(3, 6))]
    assert ps.antisymmetry_residual(pts, 50) == 0
    assert ps.jacobi_residual(pts, 50) < mpmath.mpf(10) ** -40
    ps.check_jacobi()
    for name in ps.casimirs:
        assert ps.casimir_residual(name, pts, 50) < mpmath.mpf(10) ** -40
    # H_0 is (1/2) p.M^-1.p + y: M = diag(1, 2, 1)
    inv = model.invariants(["1", "0", "0", "2", "4", "6"])
    assert inv["energy"] == 24  # 4/2 + 16/4 + 36/2 + y


DIRAC_CASES = {
    "magnetic term, two constraints": ("(x_dot**2 + 2*y_dot**2 + z_dot**2)/2 + x*y_dot - y", ["x", "y", "z"],
                                       ["x**2 + y**2 + z**2 - 1", "x + y + 2*z - 1/3"], {}),
    "mass depending on q through sin, pi in L": ("(x_dot**2 + (2 + sin(x))*y_dot**2 + z_dot**2)/2 - pi*z",
                                                 ["x", "y", "z"], ["x**2 + y**2 + z**2 - 1"], {}),
    "double spherical pendulum": (
        "m1/2*(x1_dot**2 + y1_dot**2 + z1_dot**2) + m2/2*(x2_dot**2 + y2_dot**2 + z2_dot**2) - g*(m1*z1 + m2*z2)",
        ["x1", "y1", "z1", "x2", "y2", "z2"],
        ["x1**2 + y1**2 + z1**2 - l1**2", "(x2 - x1)**2 + (y2 - y1)**2 + (z2 - z1)**2 - l2**2"],
        {"m1": 1, "m2": "1/2", "g": "9.81", "l1": 1, "l2": 1}),
}


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if "pendulum" in c else c
                                  for c in DIRAC_CASES])  # the double pendulum: 4 s of derivation
def test_dirac_tensor_equals_the_bracket_with_the_constraint_matrix_inverted_at_the_point(case):
    """The derived tensor (block inverse p8.1, assembled in a field of rational functions) against the definition
    {f, g}_D = {f, g} - {f, chi_I} (C^-1)_IJ {chi_J, g} with the full 2k x 2k matrix C_IJ = {chi_I, chi_J} of the
    canonical brackets evaluated at a point and inverted there by mpmath at 50 digits (no block formula, no
    symbolic inverse), at pseudo-random points on and off the surface."""
    L, coords, G, pars = DIRAC_CASES[case]
    cs = ls.ConstrainedSystem(L, coords, G, parameters=pars)
    d = cs.dirac_bracket()
    q, p, chi = d["q"], d["p"], d["chi"]
    n, m = len(q), len(chi)
    z = q + p
    values = {sp.Symbol(k, real=True): sp.Rational(Fraction(v)) for k, v in pars.items()}

    def canonical(f, g):
        return sum(sp.diff(f, q[a]) * sp.diff(g, p[a]) - sp.diff(f, p[a]) * sp.diff(g, q[a]) for a in range(n))

    C = [[canonical(a, b) for b in chi] for a in chi]
    Z = [[canonical(zi, ch) for ch in chi] for zi in z]
    rng = np.random.default_rng(11)
    ctx = mpmath.mp.clone()
    ctx.dps = 50

    def num(e, at):
        return ctx.mpf(sp.Float(sp.sympify(e).xreplace(at).xreplace(values).evalf(60), 60)._mpf_)

    for row in rng.integers(-9, 10, size=(3, 2 * n)):
        at = {s: sp.Rational(int(v) or 1, 7) for s, v in zip(z, row)}
        Cinv = ctx.matrix([[num(e, at) for e in r] for r in C]) ** -1
        Zn = [[num(e, at) for e in r] for r in Z]
        for i in range(2 * n):
            for j in range(i + 1, 2 * n):
                ref = (1 if (i < n and j == i + n) else 0) - ctx.fsum(
                    Zn[i][a] * Cinv[a, b] * (-Zn[j][b]) for a in range(m) for b in range(m))
                got = num(d["tensor"][i, j], at)
                assert abs(got - ref) <= ctx.mpf(10) ** -40 * (1 + abs(ref)), (case, i, j, got, ref)


def test_derivation_is_cached(sphere):
    assert sphere.dirac() is sphere.dirac()
    assert sphere.dirac_bracket() is sphere.dirac_bracket()


# -- motions against independent references ------------------------------------------------------------------------
@pytest.mark.parametrize("precision", ["double", "quad"])
def test_derived_sphere_follows_the_great_circle(sphere, precision):
    model = sphere.dirac()
    x0, v0 = ("0.6", "0", "0.8"), ("0", "1", "0")
    y0 = model.initial_state(q=x0, qdot=v0)
    ts = [1, 2, 5, 10]
    sol = ls.integrate(model, y0, t=ts, precision=precision)
    assert sol.success
    eps = resolve_precision(precision).eps
    q, v = model.configuration(sol), model.velocity(sol)
    c = private_ctx(40)
    worst = 0
    for row_q, row_v, t in zip(q, v, ts):
        xt, vt = ls.exact.sphere(1, x0, v0, t, dps=40)
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(list(row_q) + list(row_v), list(xt) + list(vt)))
        worst = max(worst, err / (t * float(eps)))
    # measured: 0.87 eps t (double), 5.7 eps t (quad)
    assert worst < 100


@pytest.mark.parametrize("precision", ["double", "quad"])
def test_spherical_pendulum_conserves_energy_and_constraints(spherical_pendulum, precision):
    model = spherical_pendulum.dirac()
    y0 = model.initial_state(q=("0.6", "0", "-0.8"), qdot=(0, 1, 0))
    sol = ls.integrate(model, y0, t=np.linspace(0, 10, 6).tolist(), precision=precision)
    assert sol.success
    eps = float(resolve_precision(precision).eps)
    inv = model.invariants(sol)
    e0 = model.invariants(y0)["energy"]
    c = private_ctx(90)
    assert abs(c.mpf(e0) - c.mpf(-7348) / 1000) < c.mpf(10) ** -80  # 1/2 |v|^2 + g x3 = 1/2 - 0.8 * 9.81
    for e, g, phi in zip(inv["energy"], inv["G1"], inv["Phi1"]):
        assert abs(e - e0) < 200 * eps * abs(e0)
        assert abs(g) < 200 * eps and abs(phi) < 200 * eps


def _spherical_angles_reference(theta0, dtheta0, dphi0, g, ts, bits=256):
    """The spherical pendulum (l = 1) written by hand in angles, theta from the upward vertical (x3 = cos theta,
    potential g cos theta): theta'' = sin cos phi'^2 + g sin theta, phi'' = -2 cot(theta) theta' phi', integrated by
    heyoka directly at ``bits`` bits (mpmath's odefun takes minutes for t = 2 at 40 digits). Returns x(t)."""
    import heyoka as hy

    th, ph, u, w = hy.make_vars("th", "ph", "u", "w")
    sys_ = [(th, u), (ph, w), (u, hy.sin(th) * hy.cos(th) * w**2 + hy.par[0] * hy.sin(th)),
            (w, -2.0 * hy.cos(th) / hy.sin(th) * u * w)]
    r = lambda v: hy.real(str(v), bits)  # noqa: E731
    ta = hy.taylor_adaptive(sys_, [r(theta0), r(0), r(dtheta0), r(dphi0)], fp_type=hy.real, prec=bits,
                            pars=[r(g)])
    out = ta.propagate_grid([r(t) for t in [0] + list(ts)])[-1][1:]
    c = private_ctx(bits // 4)
    res = []
    for row in out:
        t_, p_ = (c.mpf(str(v)) for v in row[:2])
        res.append([c.sin(t_) * c.cos(p_), c.sin(t_) * c.sin(p_), c.cos(t_)])
    return c, res


def test_spherical_pendulum_matches_the_equations_in_angles(spherical_pendulum):
    """At 160 bits (48 digits) the Cartesian Dirac model agrees with the motion in (theta, phi) to 1e-40 at t = 1, 2."""
    model = spherical_pendulum.dirac()
    # x = (3/5, 0, -4/5): sin theta = 3/5, cos theta = -4/5, phi = 0; v = (0.3, 1, 0.225) =
    # (cos th th', sin th phi', -sin th th'): theta' = -3/8, phi' = 5/3
    y0 = model.initial_state(q=("0.6", "0", "-0.8"), qdot=("0.3", "1", "0.225"))
    c = private_ctx(80)
    theta0 = c.nstr(c.pi - c.asin(c.mpf(3) / 5), 78)
    c, ref = _spherical_angles_reference(theta0, "-0.375", c.nstr(c.mpf(5) / 3, 78), "9.81", [1, 2])
    sol = ls.integrate(model, y0, t=[1, 2], precision=160)
    assert sol.success
    for row, r in zip(model.configuration(sol), ref):
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, r))
        assert err < c.mpf(10) ** -40, err  # measured: 1.5e-48


def _pendulum_closed_form(k2, omega, t, c):
    """Released at rest from theta0 (sin^2(theta0/2) = k2): sin(theta/2) = k sn(K - omega t, k)."""
    K = c.ellipk(k2)
    s = c.sqrt(k2) * c.ellipfun("sn", K - omega * t, m=k2)
    # x = l sin theta = 2 l s sqrt(1 - s^2) (theta and sn change sign together), y = -l cos theta = -l (1 - 2 s^2)
    return [2 * s * c.sqrt(1 - s**2), -(1 - 2 * s**2)]


@pytest.mark.parametrize("precision", ["double", "quad"])
def test_planar_pendulum_in_cartesian_coordinates_matches_the_closed_form(precision):
    """g written in the Lagrangian as 981/100 (not a binary number): the quad run agrees with the closed form to
    quad's epsilon, so it is a runtime parameter, exact at every precision, not the double nearest 9.81."""
    cs = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2 - 9.81*y", ["x", "y"], ["x**2 + y**2 - 1"])
    model = cs.dirac()
    assert model.poisson.coarse_data() == {}  # nothing binary
    y0 = model.initial_state(q=("0.6", "-0.8"), qdot=(0, 0))
    ts = [1, 2, 3]
    sol = ls.integrate(model, y0, t=ts, precision=precision)
    assert sol.success
    c = private_ctx(50)
    eps = float(resolve_precision(precision).eps)
    k2 = (1 - c.mpf("0.8")) / 2   # sin^2(theta0/2) = (1 - cos theta0)/2
    omega = c.sqrt(c.mpf("9.81"))
    for row, t in zip(model.configuration(sol), ts):
        ref = _pendulum_closed_form(k2, omega, c.mpf(t), c)
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, ref))
        assert err < 500 * eps * t, (t, err)



@pytest.mark.parametrize("g", ["sqrt(2)", "2*cosh(asinh(1))/2"])
def test_irrational_constants_in_the_lagrangian_are_exact_at_every_precision(g):
    """g = sqrt(2) written in the Lagrangian (or as a function of numbers that heyoka folds into one double when an
    expression is built): the quad run and a 40-digit Lie run agree with the closed form to their own precision,
    so the constant is evaluated at the run's precision, not rounded to the double 1.4142135623730951."""
    cs = ls.ConstrainedSystem(f"(x_dot**2 + y_dot**2)/2 - {g}*y", ["x", "y"], ["x**2 + y**2 - 1"])
    model = cs.dirac()
    assert model.poisson.coarse_data() == {}
    y0 = model.initial_state(q=("0.6", "-0.8"), qdot=(0, 0))
    c = private_ctx(60)
    ref = _pendulum_closed_form((1 - c.mpf("0.8")) / 2, c.sqrt(c.sqrt(2)), c.mpf(1), c)
    quad = ls.integrate(model, y0, t=[1], precision="quad")
    lie = ls.lie_integrate(model, y0, t=[1], dps=40)
    assert quad.success and lie.success
    for sol, tol in ((quad, 1e-31), (lie, 1e-37)):
        row = model.configuration(sol)[-1]
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, ref))
        assert err < tol, (g, err)

# -- state helpers and exactness -------------------------------------------------------------------------------------
def test_initial_state_is_exact_and_velocity_roundtrips(spherical_pendulum):
    model = spherical_pendulum.dirac()
    y0 = model.initial_state(q=("0.6", "0", "-0.8"), qdot=("0.3", "1", "0.225"))
    assert y0.exact == (Fraction(3, 5), 0, Fraction(-4, 5), Fraction(3, 10), 1, Fraction(9, 40))
    assert y0.data_bits is None
    np.testing.assert_array_equal(model.velocity(y0), [0.3, 1, 0.225])
    np.testing.assert_array_equal(model.configuration(y0), [0.6, 0, -0.8])


def test_binary_input_on_the_surface_to_its_precision_is_accepted_and_carried():
    cs = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2", ["x", "y"], ["x**2 + y**2 - 1"])
    model = cs.dirac()
    th = 0.3
    y0 = model.initial_state(q=(np.cos(th), np.sin(th)), qdot=(-np.sin(th), np.cos(th)))
    assert y0.data_bits == 53 and "q[0]" in y0.binary_inputs


def test_float_parameter_is_reported_as_binary_data():
    cs = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2 - g*y", ["x", "y"], ["x**2 + y**2 - 1"],
                              parameters={"g": 9.81})
    assert cs.dirac().poisson.coarse_data() == {"parameters['g']": 53}


# -- refusals ------------------------------------------------------------------------------------------------------
def _plane(lagrangian, constraint, **kwargs):
    """A system in (x, y) with one constraint, made when called."""
    return lambda: ls.ConstrainedSystem(lagrangian, ["x", "y"], [constraint], **kwargs)


BAD = {
    "singular Lagrangian": (lambda: ls.ConstrainedSystem("x_dot**2/2 - y", ["x", "y"], ["x - y**3"]),
                            "`lagrangian` is singular"),
    "not positive definite": (lambda: ls.ConstrainedSystem("(x_dot**2 - y_dot**2)/2", ["x", "y"], ["x - y**3"]),
                              "`lagrangian`: the velocity Hessian"),
    "negative mass": (lambda: ls.ConstrainedSystem("m*(x_dot**2 + y_dot**2)/2", ["x", "y"], ["x**2 + y**2 - 1"],
                                                   parameters={"m": -1}), "not positive definite"),
    "not quadratic": (lambda: ls.ConstrainedSystem("-sqrt(1 - x_dot**2 - y_dot**2)", ["x", "y"],
                                                   ["x**2 + y**2 - 1"]), "`lagrangian` must be quadratic"),
    "dependent constraints": (lambda: ls.ConstrainedSystem(SPHERE_L, SPHERE_Q, [
        "x1**2 + x2**2 + x3**2 - 1", "2*(x1**2 + x2**2 + x3**2) - 2"], parameters={"m": 1}),
        "`constraints` are functionally dependent"),
    "velocity in a constraint": (lambda: ls.ConstrainedSystem(SPHERE_L, SPHERE_Q, ["x1*x1_dot + x2"],
                                                              parameters={"m": 1}),
                                 "`constraints[0]` uses the velocities"),
    "unknown symbol": (lambda: ls.ConstrainedSystem(SPHERE_L + " - m*g*x3", SPHERE_Q, SPHERE_G,
                                                    parameters={"m": 1, "c": 1}), "`lagrangian` uses `g`"),
    "unknown symbol in a constraint": (lambda: ls.ConstrainedSystem(SPHERE_L, SPHERE_Q, SPHERE_G,
                                                                    parameters={"m": 1}), "`constraints[0]` uses `c`"),
    "imaginary unit": (lambda: ls.ConstrainedSystem(SPHERE_L, SPHERE_Q, ["x1**2 + x2**2 + x3**2 - I"],
                                                    parameters={"m": 1}), "`constraints[0]` uses `I`"),
    "unparsable": (lambda: ls.ConstrainedSystem("m/2*(x1_dot**2 +", SPHERE_Q, SPHERE_G, parameters={"m": 1, "c": 1}),
                   "`lagrangian` could not be read"),
    "too many constraints": (lambda: ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2", ["x", "y"], ["x", "y"]),
                             "`constraints`: 2 constraints on 2 coordinates"),
    "no constraint": (lambda: ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2", ["x", "y"], []), "`constraints`"),
    "bad coordinate": (lambda: ls.ConstrainedSystem("x_dot**2", ["x y"], ["x"]), "`coordinates[0]`"),
    "parameter named like a coordinate": (lambda: ls.ConstrainedSystem(SPHERE_L, SPHERE_Q, SPHERE_G,
                                                                       parameters={"x1": 1}), "`parameters`"),
    # a Python keyword passed the identifier check and failed later as "SyntaxError: invalid syntax" or
    # "TokenError: Starred arguments in lambda not supported" under `lagrangian` or `constraints[0]`
    "keyword as a parameter": (_plane("(x_dot**2 + y_dot**2)/2 - lambda*y", "x**2 + y**2 - 1",
                                      parameters={"lambda": 2}), "`parameters` key 'lambda' is a Python keyword"),
    "keyword as a coordinate": (lambda: ls.ConstrainedSystem("(lambda_dot**2 + y_dot**2)/2", ["lambda", "y"],
                                                             ["lambda**2 + y**2 - 1"]),
                                "`coordinates[0]` = 'lambda' is a Python keyword"),
    # a time-dependent (rheonomic) constraint or Lagrangian: `t` was called an unknown name to add to `parameters`,
    # which would freeze the time at one value
    "time-dependent constraint": (_plane("(x_dot**2 + y_dot**2)/2 - y", "x**2 + y**2 - (1 + t/10)**2"),
                                  "`constraints[0]` uses `t`: time-dependent"),
    "time-dependent lagrangian": (_plane("(x_dot**2 + y_dot**2)/2 - cos(t)*y", "x**2 + y**2 - 1"),
                                  "`lagrangian` uses `t`: time-dependent"),
    # an equation where the constraint G (for G = 0) was meant: "must be a scalar expression; got BooleanFalse"
    # for `==`, a SyntaxError for `=`
    "equation as a constraint": (_plane("(x_dot**2 + y_dot**2)/2 - y", "x**2 + y**2 == 1"),
                                 "`constraints[0]` = 'x**2 + y**2 == 1' is an equation"),
    "assignment as a constraint": (_plane("(x_dot**2 + y_dot**2)/2 - y", "x**2 + y**2 = 1"),
                                   "is an equation or a comparison: give the expression alone"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_system_is_refused_naming_the_argument(case):
    make, match = BAD[case]
    with pytest.raises((ValueError, TypeError), match=re.escape(match)):
        make()


def test_off_surface_point_and_normal_velocity_are_refused_with_the_residual(spherical_pendulum):
    model = spherical_pendulum.dirac()
    with pytest.raises(ValueError, match=r"`q` is not on the constraint surface: G1 = .* = 1.0e-20 at it"):
        model.initial_state(q=("0.6", "0", "-0.80000000000000000000625"), qdot=(0, 1, 0))
    with pytest.raises(ValueError, match=r"`qdot` is not tangent .* = 1.2 "):
        model.initial_state(q=("0.6", "0", "-0.8"), qdot=(1, 1, 0))
    with pytest.raises(ValueError, match=r"`q` must be 3 numbers"):
        model.initial_state(q=(1, 0), qdot=(0, 1, 0))
    with pytest.raises(ValueError, match=r"`y0` is not on the constraint surface"):
        ls.integrate(model, [1, 1, 1, 0, 0, 0], t=1)


def test_an_irrational_point_in_decimals_is_told_how_to_pass():
    """A point on x^2 + y^2 = 1 at 45 digits, cos(1) and sin(1), is 1e-46 off: the refusal asked for G = 0
    exactly, impossible for most points of a surface a user writes; it now says how such a point passes."""
    cs = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2", ["x", "y"], ["x**2 + y**2 - 1"])
    with mpmath.workdps(60):
        c, s, minus_s = mpmath.cos(1), mpmath.sin(1), -mpmath.sin(1)
    with pytest.raises(ValueError, match=r"`q` is not on the constraint surface: .* to 55 digits or more, or as "
                                         r"binary numbers"):
        cs.dirac().initial_state(q=(mpmath.nstr(c, 45), mpmath.nstr(s, 45)), qdot=(0, 0))
    cs.dirac().initial_state(q=(mpmath.nstr(c, 55), mpmath.nstr(s, 55)), qdot=(0, 0))
    cs.dirac().initial_state(q=(c, s), qdot=(minus_s, c))
    cs.dirac().initial_state(q=(float(c), float(s)), qdot=(float(minus_s), float(c)))


def test_hessian_depending_on_q_is_checked_at_the_initial_point():
    """M = diag(1, x): positive only for x > 0; the derivation goes through, a state at x < 0 is refused."""
    cs = ls.ConstrainedSystem("(x_dot**2 + x*y_dot**2)/2", ["x", "y"], ["x - y**2 - 1/2"])
    model = cs.dirac()
    model.initial_state(q=("0.75", "0.5"), qdot=(1, 1))
    with pytest.raises(ValueError, match=r"`q`: the velocity Hessian .* at this point is not positive definite"):
        cs2 = ls.ConstrainedSystem("(x_dot**2 + x*y_dot**2)/2", ["x", "y"], ["x + y**2 + 1/2"])
        cs2.dirac().initial_state(q=("-0.75", "0.5"), qdot=(1, -1))


def test_p8_1_block_inverse_of_the_constraint_matrix():
    """(p8.1): [[0, b], [-b^T, c]]^-1 = [[b^-T c b^-1, -b^-T], [b^-1, 0]] for any invertible b and antisymmetric c
    (checked symbolically for k = 2; the derivation uses this form)."""
    b = sp.Matrix(2, 2, sp.symbols("b0:4"))
    c01 = sp.Symbol("c01")
    c = sp.Matrix([[0, c01], [-c01, 0]])
    delta = sp.BlockMatrix([[sp.zeros(2), b], [-b.T, c]]).as_explicit()
    binv = b.inv()
    inv = sp.BlockMatrix([[binv.T * c * binv, -binv.T], [binv, sp.zeros(2)]]).as_explicit()
    assert sp.simplify(delta * inv - sp.eye(4)) == sp.zeros(4)


# -- the reduced form on the intermediate submanifold (p8.13) -------------------------------------------------------
@pytest.mark.parametrize("precision", ["double", "quad"])
def test_reduced_sphere_follows_the_great_circle_and_stops_at_its_chart_edge(sphere, precision):
    """(x1, x2, x3, p1, p2) with p3 = -(x1 p1 + x2 p2)/x3 eliminated: the great circle x3 = 0.8 cos t, until
    |x3| = 0.05 |x| at t = acos(1/16) = 1.508, where the run stops with status chart_edge."""
    model = sphere.reduced()
    assert model.names == ("x1", "x2", "x3", "p_x1", "p_x2")
    x0, v0 = ("0.6", "0", "0.8"), ("0", "1", "0")
    y0 = model.initial_state(q=x0, qdot=v0)
    assert y0.exact == (Fraction(3, 5), 0, Fraction(4, 5), 0, Fraction(3, 2))
    ts = ["0.5", 1, "1.4"]
    sol = ls.integrate(model, y0, t=ts, precision=precision)
    assert sol.success
    eps = float(resolve_precision(precision).eps)
    c = private_ctx(40)
    for row_q, row_v, t in zip(model.configuration(sol), model.velocity(sol), ts):
        xt, vt = ls.exact.sphere(1, x0, v0, t, dps=40)
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(list(row_q) + list(row_v), list(xt) + list(vt)))
        assert err < 200 * eps, (t, err)  # grows like 1/x3 near the edge
    stop = ls.integrate(model, y0, t=3, precision=precision)
    assert stop.status == "chart_edge" and "1.508" in stop.message


def test_reduced_bracket_is_poisson_with_G_a_casimir(sphere):
    ps = sphere.reduced().poisson
    pts = [[str(v) for v in row] for row in np.random.default_rng(2).uniform(0.3, 1.3, size=(3, 5))]
    assert ps.antisymmetry_residual(pts, 50) == 0
    assert ps.jacobi_residual(pts, 50) < mpmath.mpf(10) ** -40  # everywhere: Phi = 0 is a union of leaves
    assert ps.casimir_residual("G1", pts, 50) < mpmath.mpf(10) ** -40
    assert set(ps.casimirs) == {"G1"}


def test_reduced_planar_pendulum_matches_the_closed_form():
    """(x, y, p_x), p_y eliminated (y < 0 along the swing): against the elliptic closed form in quad."""
    cs = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2 - g*y", ["x", "y"], ["x**2 + y**2 - 1"],
                              parameters={"g": "9.81"})
    model = cs.reduced(dependent="y")
    y0 = model.initial_state(q=("0.6", "-0.8"), qdot=(0, 0))
    sol = ls.integrate(model, y0, t=[1, 2, 3], precision="quad")
    assert sol.success
    c = private_ctx(50)
    k2 = (1 - c.mpf("0.8")) / 2
    for row, t in zip(model.configuration(sol), [1, 2, 3]):
        ref = _pendulum_closed_form(k2, c.sqrt(c.mpf("9.81")), c.mpf(t), c)
        assert max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, ref)) < 1000 * float(resolve_precision("quad").eps)


@pytest.mark.slow
def test_reduced_double_spherical_pendulum_field_is_the_dirac_field_on_phi_zero():
    """Two constraints, p_x3 and p_y3 eliminated by solving the 2x2 linear system Phi = 0: at a state on the
    surface the reduced vector field equals the Dirac form's (derived without the elimination) at 50 digits."""
    from lieseries.expr import compile_expressions

    L = "(x1_dot**2 + x2_dot**2 + x3_dot**2)/2 + (y1_dot**2 + y2_dot**2 + y3_dot**2)/2 - g*x3 - g*y3"
    cs = ls.ConstrainedSystem(L, ["x1", "x2", "x3", "y1", "y2", "y3"],
                              ["x1**2 + x2**2 + x3**2 - 1", "(y1 - x1)**2 + (y2 - x2)**2 + (y3 - x3)**2 - 1"],
                              parameters={"g": "9.81"})
    q, qdot = ("0.6", 0, "-0.8", "0.6", "0.6", "-1.6"), ("0.8", 0, "0.6", "1.8", 0, "0.6")

    def field(model):
        ps = model.poisson
        prog = compile_expressions(ps.variables, ps.vector_field, len(ps.parameter_values), cse=False)
        return prog.evaluate(list(model.initial_state(q=q, qdot=qdot).exact), list(ps.parameter_values), 50)

    full = field(cs.dirac())
    red = field(cs.reduced(dependent=("x3", "y3")))
    keep = [0, 1, 2, 3, 4, 5, 6, 7, 9, 10]  # q, then p_x1, p_x2, p_y1, p_y2
    for i, r in zip(keep, red, strict=True):
        assert abs(full[i] - r) < mpmath.mpf(10) ** -45 * (1 + abs(r)), (i, full[i], r)

def test_bad_reduced_arguments_name_the_argument(sphere):
    with pytest.raises(ValueError, match="`dependent`"):
        sphere.reduced(dependent=("x1", "x2"))
    with pytest.raises(ValueError, match="`dependent`"):
        sphere.reduced(dependent="z")
    with pytest.raises(ValueError, match="`edge`"):
        sphere.reduced(edge=2)
    with pytest.raises(ValueError, match="`q` is at or beyond the edge"):
        sphere.reduced().initial_state(q=("0.6", "0.8", "0"), qdot=(0, 0, 1))


def test_a_run_can_restart_from_its_own_end_state(spherical_pendulum):
    """A double run's last row has drifted off the surface by rounding (5e-15 at t = 200): accepted as a new start;
    a raw state far off is refused (test above)."""
    model = spherical_pendulum.dirac()
    y0 = model.initial_state(q=("0.6", "0", "-0.8"), qdot=(0, 1, 0))
    end = ls.integrate(model, y0, t=200).y[-1]  # G1 = 5.2e-15: more than 53 bits allow, far less than 2^-24
    assert 0 < abs(model.invariants(end)["G1"]) < 1e-12
    again = ls.integrate(model, end, t=1)
    assert again.success


def test_powers_of_a_coordinate_that_starts_at_zero_stay_finite():
    """U = y^4 puts 4 y^3 in the field; heyoka's recurrence for pow divides by the base, so a y**3 made every run
    from y = 0 non-finite in its first step. Against the equation in the angle, theta'' = -4 sin^3 cos (x = cos,
    y = sin), integrated by heyoka at 160 bits with the powers written as products."""
    import heyoka as hy

    cs = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2 - y**4", ["x", "y"], ["x**2 + y**2 - 1"])
    model = cs.dirac()
    y0 = model.initial_state(q=(1, 0), qdot=(0, 1))
    sol = ls.integrate(model, y0, t=[1, 2], precision="quad")
    assert sol.success, sol.message
    th, w = hy.make_vars("th", "w")
    s = hy.sin(th)
    r = lambda v: hy.real(str(v), 160)  # noqa: E731
    ta = hy.taylor_adaptive([(th, w), (w, -4.0 * s * s * s * hy.cos(th))], [r(0), r(1)], fp_type=hy.real, prec=160)
    out = ta.propagate_grid([r(0), r(1), r(2)])[-1][1:]
    c = private_ctx(48)
    for row, ref in zip(model.configuration(sol), out):
        t_ = c.mpf(str(ref[0]))
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, [c.cos(t_), c.sin(t_)]))
        assert err < 1e-30, err  # quad: measured 4e-34


def test_dirac_tensor_expression_route_equals_the_field_route():
    """The route taken when sympy cannot hold the brackets in a field of rational functions (together/cancel per
    entry) gives the same tensor, b and c, symbolically, for a system with a magnetic term and two constraints."""
    from lieseries.models import constrained_derive as D

    L, coords, G, pars = DIRAC_CASES["magnetic term, two constraints"]
    cs = ls.ConstrainedSystem(L, coords, G, parameters=pars)
    d = cs.dirac_bracket()
    q, p, chi, n, k = d["q"], d["p"], d["chi"], len(d["q"]), len(d["G"])
    bz = [[D.canonical_bracket(zi, ch, q, p) for ch in chi] for zi in q + p]
    bs = [[D.canonical_bracket(d["G"][a], d["Phi"][c], q, p) for c in range(k)] for a in range(k)]
    cs_ = [[D.canonical_bracket(d["Phi"][a], d["Phi"][e], q, p) if a < e else 0 for e in range(k)] for a in range(k)]
    b, c, T = D._dirac_combination_expr(bs, cs_, bz, n, k)
    assert (T - d["tensor"]).applyfunc(sp.cancel) == sp.zeros(2 * n, 2 * n)
    assert (b - d["b"]).applyfunc(sp.cancel) == sp.zeros(k, k)
    assert (c - d["c"]).applyfunc(sp.cancel) == sp.zeros(k, k)



def test_energy_guard_reads_energies_beyond_a_doubles_range():
    """Kinetic energy scaled by 1e400 (momenta of 1e400, gravity negligible beside it: uniform motion on the
    circle, x = cos(theta0 + t), y = sin(theta0 + t)): the Lie run's energy guard computed its energy scale in
    doubles and raised OverflowError. Its verdict and message keep energies below a double's range (a drift of
    1e-400 printed as "went from 0.0 to 0.0")."""
    from lieseries.energy import exact_energy_verdict

    model = ls.ConstrainedSystem("1e400*m*(x_dot**2 + y_dot**2)/2 - m*g*y", ["x", "y"], ["x**2 + y**2 - l**2"],
                                 parameters={"m": 1, "g": "9.81", "l": 1}).dirac()
    sol = ls.lie_integrate(model, model.initial_state(q=("0.6", "-0.8"), qdot=("0.8", "0.6")), t=1, dps=20)
    assert sol.status == "success"
    c = private_ctx(30)
    theta = c.atan2(-c.mpf(4) / 5, c.mpf(3) / 5) + 1
    got = [ctx_mpf(c, v) for v in model.configuration(sol)[-1]]
    assert max(abs(got[0] - c.cos(theta)), abs(got[1] - c.sin(theta))) < 1e-18
    status, message = exact_energy_verdict(mpmath.mpf("-6.8e-400"), mpmath.mpf("-6.9e-400"), mpmath.mpf("1e-399"),
                                           Fraction(1, 10**20), "success", "Reached t = 1.", 10)
    assert status == "invariant_drift" and "from -6.8e-400 to -6.9e-400" in message


def test_lie_steps_a_lagrangian_scaled_beyond_a_doubles_range():
    """L and L * 1e400 have the same motion; lie_integrate should run the scaled one as it runs the plain one."""
    c = private_ctx(30)
    ends = []
    for scale in (1, "1e400"):
        model = ls.ConstrainedSystem(f"{scale}*(m*(x_dot**2 + y_dot**2)/2 - m*g*y)", ["x", "y"],
                                     ["x**2 + y**2 - l**2"], parameters={"m": 1, "g": "9.81", "l": 1}).dirac()
        sol = ls.lie_integrate(model, model.initial_state(q=("0.6", "-0.8"), qdot=("0.8", "0.6")), t=1, dps=20)
        assert sol.status == "success", sol.message
        ends.append([ctx_mpf(c, v) for v in model.configuration(sol)[-1]])
    assert max(abs(a - b) for a, b in zip(*ends)) < 1e-18


def test_a_sympy_function_outside_the_supported_ones_is_refused_naming_the_argument():
    """A sympy expression with Abs(y), or an undefined V(y), was accepted; dirac() then failed with heyoka's
    "TypeError: Unable to convert the sympy object V(y)", naming neither the argument nor what to do."""
    x, y, xd, yd = sp.symbols("x y x_dot y_dot")
    for f in (sp.Abs(y), sp.Function("V")(y)):
        with pytest.raises(ValueError, match=rf"`lagrangian` uses {re.escape(str(f.func))}\(\), which is not one of "
                                             r"the functions"):
            ls.ConstrainedSystem((xd**2 + yd**2)/2 - f, ["x", "y"], [x**2 + y**2 - 1])
    with pytest.raises(ValueError, match=r"`constraints\[0\]` uses Max\(\)"):
        ls.ConstrainedSystem((xd**2 + yd**2)/2, ["x", "y"], [sp.Max(x, y)**2 + y**2 - 1])
    cs = ls.ConstrainedSystem((xd**2 + yd**2)/2 - sp.cos(y) + sp.sqrt(2 + sp.exp(x)), ["x", "y"], [x**2 + y**2 - 1])
    assert cs.dirac().dimension == 4


def test_a_coordinate_named_like_a_momentum_is_refused_at_once():
    """Coordinates x and p_x (or pi_x) were accepted; dirac() (or intermediate()) then failed with "`variables`
    must have distinct names", which does not say what to rename."""
    for other in ("p_x", "pi_x"):
        with pytest.raises(ValueError, match=rf"`coordinates`: '{other}' is also the name the formulations give "
                                             r"the momentum of 'x'"):
            ls.ConstrainedSystem(f"(x_dot**2 + {other}_dot**2)/2", ["x", other], [f"x**2 + {other}**2 - 1"])


def test_lie_keeps_its_digits_when_a_momentum_is_small():
    """L and 1e-5 L have the same motion; the intermediate form in the chart y < 0 has momentum pi ~ 1e-5. At 30
    digits the Lie run must be right to ~1e-29 (the unscaled form is right to 2.7e-31), against the unscaled Dirac
    form at 50 digits. With a tolerance absolute below 1 it ended `success` at 3.3e-27 (pi kept tol / 1e-5 of its
    digits, and the velocity is pi over 1e-5), its estimates saying 2e-32; relative to each component's own scale
    it keeps them. (heyoka in quad loses as many digits: its tolerance is relative to the largest component, as the
    README says.)"""
    c = private_ctx(60)

    def end(scale, form, dps):
        cs = ls.ConstrainedSystem(f"{scale}*(m*(x_dot**2 + y_dot**2)/2 - m*g*y)", ["x", "y"], ["x**2 + y**2 - l**2"],
                                  parameters={"m": 1, "g": "9.81", "l": 1})
        model = getattr(cs, form)()
        sol = ls.lie_integrate(model, model.initial_state(q=("0.6", "-0.8"), qdot=("0.8", "0.6")), t=1, dps=dps)
        assert sol.status == "success"
        return [ctx_mpf(c, v) for v in list(model.configuration(sol)[-1]) + list(model.velocity(sol)[-1])]

    ref = end(1, "dirac", 50)
    assert max(abs(a - b) for a, b in zip(end("1e-5", "intermediate", 30), ref)) < 1e-29
