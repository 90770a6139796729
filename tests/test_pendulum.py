"""Pendulums in Cartesian coordinates with the Dirac bracket, against references written here: the spherical
pendulum against its equations in spherical angles (mpmath odefun at 45 digits), the planar pendulum against its
closed form in Jacobi elliptic functions, the double spherical pendulum against itself at 200 bits (chaotic: for a
short time only) and against ConstrainedSystem's own derivation of its bracket."""

import numpy as np
import pytest

import lieseries as ls
from lieseries.expr import compile_expressions
from lieseries.precision import dps_to_bits, resolve_precision, to_fraction
from problems import ctx_mpf, private_ctx

L, G, MASS = "1.5", "9.81", 2
# |q| = 1.5, theta0 = asin(0.6) from the downward vertical; faster than the conical motion: theta stays in
# [theta0, 1.1] (away from the pole, where the angle equations' series converge slowly)
Q0, V0 = ("0.9", 0, "-1.2"), (0, 3, 0)
TIMES = ["0.5", 1]


def spherical_reference(c, times, order=36, h="1/16"):
    """x(t) from the equations in spherical angles (theta from the downward vertical, x = l sin(theta) (cos phi,
    sin phi), z = -l cos(theta)):  theta'' = sin cos phi'^2 - (g/l) sin,  phi'' = -2 cot(theta) theta' phi'.
    Written polynomial with S = sin(theta), C = cos(theta), W = 1/S, A = theta', B = phi', P = phi:

        S' = C A,  C' = -S A,  W' = -W^2 C A,  A' = S C B^2 - (g/l) S,  B' = -2 C W A B,  P' = B

    and solved by a fixed-step Taylor series whose coefficients follow by Cauchy products."""
    l, kappa = ctx_mpf(c, L), ctx_mpf(c, G) / ctx_mpf(c, L)
    step = to_fraction(h)
    hh = ctx_mpf(c, h)
    S = ctx_mpf(c, "0.6")
    u = [S, c.sqrt(1 - S * S), 1 / S, c.mpf(0), 3 / ctx_mpf(c, "0.9"), c.mpf(0)]  # phi'(0) = ydot / (l sin)

    def mul(a, b, k):
        return c.fdot(a[:k + 1], b[k::-1])

    out, done = [], 0
    for t_end in times:
        for _ in range(int(to_fraction(t_end) / step) - done):
            Ss, Cs, Ws, As, Bs, Ps = ([v] for v in u)
            SC, B2, CA, W2, CW, AB, SCB2, W2CA, CWAB = ([] for _ in range(9))
            for k in range(order):
                for ser, a, b in ((SC, Ss, Cs), (B2, Bs, Bs), (CA, Cs, As), (W2, Ws, Ws), (CW, Cs, Ws), (AB, As, Bs)):
                    ser.append(mul(a, b, k))
                for ser, a, b in ((SCB2, SC, B2), (W2CA, W2, CA), (CWAB, CW, AB)):
                    ser.append(mul(a, b, k))
                rhs = [CA[k], -mul(Ss, As, k), -W2CA[k], SCB2[k] - kappa * Ss[k], -2 * CWAB[k], Bs[k]]
                for ser, r in zip((Ss, Cs, Ws, As, Bs, Ps), rhs):
                    ser.append(r / (k + 1))
            u = [c.polyval(ser[::-1], hh) for ser in (Ss, Cs, Ws, As, Bs, Ps)]
            done += 1
        S, C, _, _, _, P = u
        out.append([l * S * c.cos(P), l * S * c.sin(P), -l * C])
    return out


@pytest.fixture(scope="module")
def spherical_ref():
    c = private_ctx(45)
    return c, spherical_reference(c, TIMES)


@pytest.mark.parametrize("precision", ["double", dps_to_bits(30)])
def test_spherical_pendulum_follows_the_angle_equations(precision, spherical_ref):
    c, ref = spherical_ref
    pend = ls.SphericalPendulum(length=L, mass=MASS, g=G)
    y0 = pend.initial_state(q=Q0, qdot=V0)
    sol = ls.integrate(pend, y0, t=TIMES, precision=precision)
    assert sol.success
    eps = ctx_mpf(c, resolve_precision(precision).eps)
    for row, x_ref in zip(pend.configuration(sol), ref):
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, x_ref))
        # measured: 3.5e-16 (double, eps 2.2e-16), 1.7e-31 (103 bits, eps 2.0e-31)
        assert err < 20 * eps * ctx_mpf(c, L), (precision, err)


def test_spherical_pendulum_conserves_its_invariants():
    pend = ls.SphericalPendulum(length=L, mass=MASS, g=G)
    y0 = pend.initial_state(q=Q0, qdot=V0)
    inv0 = pend.invariants(y0)
    assert set(inv0) == {"energy", "G1", "Phi1", "L3"}
    # exact data: L3 = m (x ydot - y xdot) = 2 * 0.9 * 3, energy = m/2 |v|^2 + m g z = 9 - 2 * 9.81 * 1.2
    assert inv0["L3"] == pytest.approx(5.4, rel=1e-15) and inv0["energy"] == pytest.approx(9 - 23.544, rel=1e-15)
    sol = ls.integrate(pend, y0, t=[1, 2, 4], precision="double")
    inv = pend.invariants(sol.y)
    eps = 2.0**-52
    for i in range(3):
        assert abs(inv["L3"][i] - 5.4) < 50 * eps * 5.4
        assert abs(inv["energy"][i] - inv0["energy"]) < 50 * eps * 25
        assert abs(inv["G1"][i]) < 50 * eps * 2.25 and abs(inv["Phi1"][i]) < 50 * eps * 20


def test_planar_pendulum_follows_the_elliptic_closed_form():
    """Released at rest from theta0 (sin 0.6): sin(theta/2) = k cd(omega t, k), k = sin(theta0/2) = 1/sqrt(10),
    omega = sqrt(g/l); x = l sin(theta), y = -l cos(theta)."""
    c = private_ctx(45)
    l, g = ctx_mpf(c, L), ctx_mpf(c, G)
    k, omega = 1 / c.sqrt(10), c.sqrt(g / l)
    pend = ls.PlanarPendulum(length=L, mass=MASS, g=G)
    y0 = pend.initial_state(q=("0.9", "-1.2"), qdot=(0, 0))
    times = ["0.5", "1.25", 3]
    for precision in ("double", "quad", dps_to_bits(30)):
        sol = ls.integrate(pend, y0, t=times, precision=precision)
        assert sol.success
        eps = ctx_mpf(c, resolve_precision(precision).eps)
        for t, row in zip(times, pend.configuration(sol)):
            s = k * c.ellipfun("cd", omega * ctx_mpf(c, t), k=k)  # sin(theta/2)
            ref = [2 * l * s * c.sqrt(1 - s * s), -l * (1 - 2 * s * s)]
            err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, ref))
            # measured at t = 3: 5.0e-16 (double), 4.9e-34 (quad), 2.9e-31 (103 bits)
            assert err < 20 * eps * l, (precision, t, err)


def test_pendulum_parameters_are_checked_and_kept_exact():
    for cls in (ls.SphericalPendulum, ls.PlanarPendulum):
        with pytest.raises(ValueError, match="`length`"):
            cls(length=0)
        with pytest.raises(ValueError, match="`mass`"):
            cls(mass=-1)
        with pytest.raises(ValueError, match="`g`"):
            cls(g="heavy")
    for arg in ("l1", "l2", "m1", "m2"):
        with pytest.raises(ValueError, match=f"`{arg}`"):
            ls.DoubleSphericalPendulum(**{arg: 0})
    pend = ls.SphericalPendulum(length="0.1", g=G)
    assert pend.length_exact == to_fraction("1/10")
    assert dict(pend.poisson.coarse_data()) == {}
    # a binary length is reported as binary data
    assert ls.SphericalPendulum(length=0.1).poisson.coarse_data()


def test_pendulum_states_off_the_surface_are_refused():
    pend = ls.SphericalPendulum(length=L)
    with pytest.raises(ValueError, match="`q`"):
        pend.initial_state(q=(1, 0, 0), qdot=(0, 1, 0))
    with pytest.raises(ValueError, match="`qdot`"):
        pend.initial_state(q=Q0, qdot=(1, 0, 0))
    dbl = ls.DoubleSphericalPendulum()
    with pytest.raises(ValueError, match="`q`.*G2"):
        dbl.initial_state(q=("0.6", 0, "-0.8", "0.6", 0, -2), qdot=(0, 1, 0, 0, 1, 0))
    with pytest.raises(ValueError, match="`qdot`.*dG2"):
        dbl.initial_state(q=("0.6", 0, "-0.8", "0.6", "0.6", "-1.6"), qdot=(0, 1, 0, 0, 0, 0))
    # an exact point of the decimal surface against a model of binary length: the refusal names the length (it
    # named the point alone, and told to give it exactly, which it was)
    with pytest.raises(ValueError,
                       match=r"`q` is not on[^G]*G1[^G]*The model was built from binary numbers, `parameters\['length'\]`"):
        ls.SphericalPendulum(length=0.7).initial_state(q=("0.42", 0, "-0.56"), qdot=(0, 1, 0))
    with pytest.raises(ValueError, match="built from binary numbers, `l1`"):
        ls.DoubleSphericalPendulum(l1=0.7).initial_state(q=("0.42", 0, "-0.56", "0.42", 0, "-1.56"),
                                                         qdot=(0, 1, 0, 0, 1, 0))
    assert ls.SphericalPendulum(length="0.7").initial_state(q=("0.42", 0, "-0.56"), qdot=(0, 1, 0)) is not None


def test_pendulum_derivations_are_cached():
    a = ls.SphericalPendulum(length=L, mass=MASS, g=G)
    assert ls.SphericalPendulum(length=L, mass=MASS, g=G).system is a.system
    assert ls.SphericalPendulum(length=2, mass=MASS, g=G).system is not a.system
    # a binary float is its own binary value: not the decimal
    assert ls.SphericalPendulum(length=0.1).system is not ls.SphericalPendulum(length="0.1").system
    assert ls.DoubleSphericalPendulum(g=G).poisson is ls.DoubleSphericalPendulum(g=G).poisson


DQ0 = ("0.6", 0, "-0.8", "0.6", "0.6", "-1.6")  # r1 = (0.6, 0, -0.8), r2 - r1 = (0, 0.6, -0.8)
DV0 = (0, 1, 0, 1, 1, 0)


def test_double_spherical_pendulum_conserves_energy_constraints_and_L3():
    pend = ls.DoubleSphericalPendulum(l1=1, l2=1, m1=1, m2="0.5", g=G)
    y0 = pend.initial_state(q=DQ0, qdot=DV0)
    inv0 = pend.invariants(y0)
    # exact: energy = 1/2 + 0.5/2 * 2 + 9.81 (-0.8 - 0.5 * 1.6), L3 = 0.6 * 1 + 0.5 * (0.6 * 1 - 0.6 * 1)
    assert float(inv0["energy"]) == pytest.approx(1 - 9.81 * 1.6, rel=1e-15)
    assert float(inv0["L3"]) == pytest.approx(0.6, rel=1e-15)
    sol = ls.integrate(pend, y0, t=[1, 2, 3], precision="double")
    assert sol.success
    inv = pend.invariants(sol.y)
    eps = 2.0**-52
    for i in range(3):
        assert abs(inv["energy"][i] - inv0["energy"]) < 200 * eps * 16
        assert abs(inv["L3"][i] - inv0["L3"]) < 200 * eps
        for k in ("G1", "G2", "Phi1", "Phi2"):
            assert abs(inv[k][i]) < 200 * eps * 10, (k, inv[k][i])
    # the two rods stay of their lengths (the configuration itself, not only the Casimirs)
    for r in pend.configuration(sol.y):
        r = [float(v) for v in r]
        assert abs(sum((b - a) ** 2 for a, b in zip(r[:3], r[3:])) - 1) < 1e-13


def test_double_spherical_pendulum_double_agrees_with_quad_for_a_short_time():
    """Chaotic: errors grow exponentially, so the comparison holds for a short time only (t = 1 here)."""
    pend = ls.DoubleSphericalPendulum(l1=1, l2=1, m1=1, m2="0.5", g=G)
    y0 = pend.initial_state(q=DQ0, qdot=DV0)
    lo = ls.integrate(pend, y0, t=[1], precision="double")
    hi = ls.integrate(pend, y0, t=[1], precision="quad")
    c = private_ctx(70)
    err = max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(lo.y[-1], hi.y[-1]))
    assert 0 < err < 1e-13, err  # measured 1.4e-15 (2.1e-15 at t = 3)


def tensor_at(ps, y, dps=40):
    """The entries of a PoissonSystem's tensor at the state ``y`` (row-major), at ``dps`` digits."""
    prog = compile_expressions(ps.variables, [e for row in ps.tensor for e in row], len(ps.parameter_values))
    return prog.evaluate([to_fraction(v) for v in y], list(ps.parameter_values), dps)


@pytest.mark.slow
def test_double_spherical_pendulum_bracket_is_constrained_systems():
    """The bracket assembled in heyoka equals ConstrainedSystem's symbolic derivation, entry by entry, at a point
    on the surface (ConstrainedSystem's simplification takes 30-90 s for these twelve variables)."""
    cs = ls.ConstrainedSystem(
        "m1/2*(x1_dot**2 + y1_dot**2 + z1_dot**2) + m2/2*(x2_dot**2 + y2_dot**2 + z2_dot**2) - g*(m1*z1 + m2*z2)",
        ["x1", "y1", "z1", "x2", "y2", "z2"],
        ["x1**2 + y1**2 + z1**2 - l1**2", "(x2 - x1)**2 + (y2 - y1)**2 + (z2 - z1)**2 - l2**2"],
        parameters={"m1": 1, "m2": "0.5", "g": G, "l1": 1, "l2": 1})
    ref = cs.dirac()
    pend = ls.DoubleSphericalPendulum(l1=1, l2=1, m1=1, m2="0.5", g=G)
    c = private_ctx(40)
    y0 = pend.initial_state(q=DQ0, qdot=DV0)
    y1 = ref.initial_state(q=DQ0, qdot=DV0)
    assert list(y0.exact) == list(y1.exact)
    # generic point (off the surface too): the brackets agree as functions of (q, p)
    point = ["0.3", "-0.7", "0.2", "1.1", "0.4", "-0.9", "0.25", "1.5", "-0.6", "0.8", "-0.35", "0.45"]
    for y in (y0.exact, point):
        a, b = tensor_at(pend.poisson, y), tensor_at(ref.poisson, y)
        scale = max(abs(ctx_mpf(c, v)) for v in b)
        diff = max(abs(ctx_mpf(c, u) - ctx_mpf(c, v)) for u, v in zip(a, b))
        assert diff < c.mpf(10) ** -35 * scale
    inv = pend.invariants(y0)
    inv_ref = ref.invariants(y1)
    assert abs(ctx_mpf(c, inv["energy"]) - ctx_mpf(c, inv_ref["energy"])) < c.mpf(10) ** -35


def test_double_spherical_pendulum_runs_on_from_its_final_state_and_refuses_a_broken_one():
    pend = ls.DoubleSphericalPendulum(l1=1, l2=1, m1=1, m2="0.5", g=G)
    y0 = pend.initial_state(q=DQ0, qdot=DV0)
    sol = ls.integrate(pend, y0, t=[1], precision="double")
    again = ls.integrate(pend, sol.y[-1], t=[1], precision="double")
    assert again.success  # a state a run ended in is on the surface to its own precision
    broken = np.array(sol.y[-1], dtype=float)
    broken[3] += 1e-3  # the second rod stretched
    with pytest.raises(ValueError, match="`y0` is not on the constraint surface: G2"):
        ls.integrate(pend, broken, t=[1], precision="double")
    assert [float(a) for a in pend.velocity(y0)] == [float(a) for a in DV0]  # p = m qdot, back to qdot


@pytest.mark.slow
def test_double_spherical_pendulum_bracket_satisfies_jacobi_and_keeps_its_casimirs():
    """The Jacobi identity at three pseudo-random states (40 digits; about 80 s) and G1, G2, Phi1, Phi2 as
    Casimirs (their brackets with every coordinate vanish)."""
    pend = ls.DoubleSphericalPendulum(l1=1, l2="1.5", m1=1, m2="0.5", g=G)
    pend.poisson.check_jacobi()
    pend.poisson.check_casimirs()


def test_ensemble_parameters_of_a_pendulum_are_checked():
    pend = ls.SphericalPendulum(length=L, mass=MASS, g=G)
    y0 = pend.initial_state(q=Q0, qdot=V0)
    names = list(pend.poisson.parameter_names)
    good = list(pend.poisson.parameter_values)
    bad = list(good)
    bad[names.index("mass")] = -1
    with pytest.raises(ValueError, match=r"`params\[1\]` gives the parameter 'mass' = -1"):
        ls.integrate(pend, np.stack([y0, y0]), t=1, params=[good, bad])


def test_ensemble_member_state_must_lie_on_its_own_constraint_surface():
    """A state made for length 1.5 run as a member of length 3 keeps G = |x|^2 - 9 = -6.75 as a Casimir: its run
    succeeded on a motion that is no pendulum's. Refused, naming the row; a state made for the member's own length
    runs and agrees with a quad run of that pendulum."""
    pend = ls.SphericalPendulum(length=L, mass=MASS, g=G)
    y0 = pend.initial_state(q=Q0, qdot=V0)
    names = list(pend.poisson.parameter_names)
    own = list(pend.poisson.parameter_values)
    longer = list(own)
    longer[names.index("length")] = 3
    with pytest.raises(ValueError, match=r"`Y0\[1\]` is off the constraint surface of its member.*`params\[1\]`"
                                         r".*G1 = -6\.75"):
        ls.integrate(pend, np.stack([y0, y0]), t=1, params=[own, longer])
    with pytest.raises(ValueError, match=r"`Y0\[1\]` is off the constraint surface.*G1 = -6\.75"):
        ls.integrate(pend, [y0, y0], t=1, params=[own, longer])  # exact rows


@pytest.mark.slow
def test_ensemble_member_state_on_its_own_constraint_surface_runs():
    """A member with a length of its own and a state made for that length runs (it was refused, checked against
    the model's length), and agrees with a quad run of a pendulum of that length (its own derivation)."""
    pend = ls.SphericalPendulum(length=L, mass=MASS, g=G)
    y0 = pend.initial_state(q=Q0, qdot=V0)
    names = list(pend.poisson.parameter_names)
    own = list(pend.poisson.parameter_values)
    longer = list(own)
    longer[names.index("length")] = 3
    pend3 = ls.SphericalPendulum(length=3, mass=MASS, g=G)
    y3 = pend3.initial_state(q=("1.8", 0, "-2.4"), qdot=V0)
    ens = ls.integrate(pend, np.stack([np.asarray(y0, float), np.asarray(y3, float)]), t=1, params=[own, longer])
    assert list(ens.status) == ["success", "success"]
    ref = np.asarray(ls.integrate(pend3, y3, t=1, precision="quad").y_final, dtype=float)
    assert np.max(np.abs(np.asarray(ens.y_reached[1], dtype=float) - ref)) < 1e-13


def test_exact_state_with_a_non_dyadic_tangent_velocity_runs():
    """initial_state accepted q = (0.6, 0, -0.8), qdot = (0.8, 0, 0.6), but the run refused it as not tangent: its
    check multiplied at 53 bits (mpf(8)/5) and compared with 1e-50. The motion stays in the x-z plane: against
    theta'' = -g sin(theta) (theta from the downward vertical, theta(0) = asin(0.6), theta'(0) = 1), mpmath at 30
    digits, and run by heyoka and the Lie engine."""
    pend = ls.SphericalPendulum(length=1, mass=1, g=G)
    y0 = pend.initial_state(q=("0.6", 0, "-0.8"), qdot=("0.8", 0, "0.6"))
    c = private_ctx(30)
    g = ctx_mpf(c, G)
    theta = c.odefun(lambda t, u: [u[1], -g * c.sin(u[0])], 0, [c.asin(ctx_mpf(c, "0.6")), c.mpf(1)])(ctx_mpf(c, "0.5"))[0]
    ref = np.array([float(c.sin(theta)), 0.0, float(-c.cos(theta))])
    for sol in (ls.integrate(pend, y0, t="0.5"), ls.lie_integrate(pend, y0, t="0.5", dps=20)):
        assert sol.status == "success"
        assert np.max(np.abs(np.asarray(pend.configuration(sol.y_final), dtype=float) - ref)) < 1e-14


@pytest.mark.slow
def test_derived_double_spherical_pendulum_runs_in_double_and_follows_the_hand_written_model():
    """ConstrainedSystem's Dirac form of the double spherical pendulum (12 variables, 12000 operations in its
    tensor) is compiled in compact mode (unrolled, LLVM took 280 CPU s) and its run in double agrees with the model
    whose bracket is assembled by hand in heyoka, up to t = 1 (before the chaos amplifies the rounding)."""
    cs = ls.ConstrainedSystem(
        "m1/2*(x1_dot**2 + y1_dot**2 + z1_dot**2) + m2/2*(x2_dot**2 + y2_dot**2 + z2_dot**2) - g*(m1*z1 + m2*z2)",
        ["x1", "y1", "z1", "x2", "y2", "z2"],
        ["x1**2 + y1**2 + z1**2 - l1**2", "(x2 - x1)**2 + (y2 - y1)**2 + (z2 - z1)**2 - l2**2"],
        parameters={"m1": 1, "m2": "0.5", "g": G, "l1": 1, "l2": 1})
    derived = cs.dirac()
    assert derived.large_field
    hand = ls.DoubleSphericalPendulum(l1=1, l2=1, m1=1, m2="0.5", g=G)
    a = ls.integrate(derived, derived.initial_state(q=DQ0, qdot=DV0), t=[1], precision="double")
    b = ls.integrate(hand, hand.initial_state(q=DQ0, qdot=DV0), t=[1], precision="double")
    assert a.success and b.success
    err = max(abs(float(u) - float(v)) for u, v in zip(a.y[-1], b.y[-1]))
    assert err < 1e-11, err


def test_double_spherical_pendulum_refuses_a_point_off_its_constraints_as_every_constrained_model_does():
    """One residual check for all constrained models: the double pendulum names the constraint and gives the exact
    residual G1 = 2 * 0.8 * 1e-20 + 1e-40 of a point 1e-20 off the first rod's sphere, as ConstrainedSystem's
    form of the same system does."""
    off = ("0.6", 0, "-0.80000000000000000001", "0.6", "0.6", "-1.6")
    pend = ls.DoubleSphericalPendulum(l1=1, l2=1, m1=1, m2="0.5", g=G)
    with pytest.raises(ValueError, match=r"`q` is not on the constraint surface: G1 = \|r1\|\^2 - l1\^2 = 1\.6e-20 "):
        pend.initial_state(q=off, qdot=DV0)
    cs = ls.ConstrainedSystem("(x_dot**2 + y_dot**2 + z_dot**2)/2", ["x", "y", "z"], ["x**2 + y**2 + z**2 - 1"])
    with pytest.raises(ValueError, match=r"`q` is not on the constraint surface: G1 = .* = 1\.6e-20 "):
        cs.dirac().initial_state(q=off[:3], qdot=(0, 1, 0))
    with pytest.raises(ValueError, match=r"`qdot` is not tangent to the constraint surface: dG1/dq \. qdot = 1\.2 "):
        pend.initial_state(q=DQ0, qdot=(1, 1, 0, 1, 1, 0))  # dG1/dq = 2 r1: 2 * 0.6 * 1
