"""HeavyTop: EulerPoisson's bracket with gravity in H, against a Taylor-series solution of the (M, Gamma)
Euler-Poisson equations written here in mpmath (independent of heyoka and of the model's bracket)."""

import warnings
from fractions import Fraction

import heyoka as hy
import numpy as np
import pytest

import lieseries as ls
from lieseries.precision import data_bits, dps_to_bits, resolve_precision, to_fraction
from problems import ctx_mpf, private_ctx




def euler_poisson_reference(inertia, weight, M0, G0, ts, c, order=36, h="1/16"):
    """dM/dt = M x Omega + Gamma x w, dGamma/dt = Gamma x Omega, Omega = M / I (principal axes), w = mass g com:
    fixed-step Taylor series whose coefficients follow from the bilinear right-hand side (Cauchy products).
    Returns (M, Gamma) at each of the times ``ts`` (multiples of ``h``)."""
    step = to_fraction(h)
    h = ctx_mpf(c, h)
    Iinv = [1 / ctx_mpf(c, i) for i in inertia]
    w = [ctx_mpf(c, v) for v in weight]
    M = [ctx_mpf(c, v) for v in M0]
    G = [ctx_mpf(c, v) for v in G0]

    out, done = [], 0
    for t_end in ts:
        steps = int(to_fraction(t_end) / step) - done
        done += steps
        M, G = _taylor_steps(M, G, Iinv, w, h, steps, order, c)
        out.append((M, G))
    return out


def _taylor_steps(M, G, Iinv, w, h, steps, order, c):
    def cross_k(a, b, k):  # the order-k coefficient of a x b from the series a, b
        out = []
        for i in range(3):
            j, l = (i + 1) % 3, (i + 2) % 3
            out.append(c.fsum(a[j][m] * b[l][k - m] - a[l][m] * b[j][k - m] for m in range(k + 1)))
        return out

    for _ in range(steps):
        Ms = [[M[i]] for i in range(3)]
        Gs = [[G[i]] for i in range(3)]
        for k in range(order):
            Om = [[Iinv[i] * Ms[i][m] for m in range(k + 1)] for i in range(3)]
            dM = cross_k(Ms, Om, k)
            gw = [Gs[(i + 1) % 3][k] * w[(i + 2) % 3] - Gs[(i + 2) % 3][k] * w[(i + 1) % 3] for i in range(3)]
            dG = cross_k(Gs, Om, k)
            for i in range(3):
                Ms[i].append((dM[i] + gw[i]) / (k + 1))
                Gs[i].append(dG[i] / (k + 1))
        M = [c.polyval(Ms[i][::-1], h) for i in range(3)]
        G = [c.polyval(Gs[i][::-1], h) for i in range(3)]
    return M, G


TOP = dict(inertia=(3, 4, 5), com=("0.1", "-0.2", "0.3"), mass=1, g="9.81")
OMEGA = (1, "0.5", "-0.3")


def test_heavy_top_matches_the_euler_poisson_equations_at_44_digits():
    top = ls.HeavyTop(**TOP)
    y0 = top.initial_state(omega=OMEGA)
    sol = ls.integrate(top, y0, t=["0.5", 1], precision=160)
    assert sol.success
    c = private_ctx(55)
    weight = [Fraction(981, 100) * to_fraction(v) for v in TOP["com"]]
    M0 = [3 * 1, 4 * Fraction(1, 2), 5 * Fraction(-3, 10)]
    ref = euler_poisson_reference(TOP["inertia"], weight, M0, [0, 0, 1], ["0.5", 1], c)
    for t, row, (M, G) in zip(["0.5", 1], sol.y, ref):
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(list(row[9:]) + list(row[6:9]), M + G))
        # 160 bits: 48 digits; measured 5.6e-48 at t = 1 (a reference of order 30, h = 1/32, was off by 1.4e-50)
        assert err < c.mpf(10) ** -44, (t, err)


@pytest.mark.parametrize("precision", ["double", "quad"])
def test_lagrange_top_conserves_M3_energy_and_vertical_momentum(precision):
    top = ls.HeavyTop(inertia=(2, 2, 1), com=(0, 0, "0.5"), mass=2, g="9.81")
    y0 = top.initial_state(omega=("0.3", "-0.2", 5), R0=[["0.6", 0, "-0.8"], [0, 1, 0], ["0.8", 0, "0.6"]])
    sol = ls.integrate(top, y0, t=np.linspace(0, 10, 6).tolist(), precision=precision)
    assert sol.success
    eps = float(resolve_precision(precision).eps)
    inv0 = top.invariants(y0)
    inv = top.invariants(sol.y)
    M3 = top.angular_momentum(sol.y)[:, 2]
    for i in range(len(sol.t)):
        assert abs(inv["energy"][i] - inv0["energy"]) < 100 * eps * abs(inv0["energy"])
        assert abs(inv["L3"][i] - inv0["L3"]) < 100 * eps * 5
        assert abs(float(M3[i]) - 5) < 100 * eps * 5
    # the top nutates: Gamma_3 = R33 moves (so gravity acts and the check above is not vacuous)
    assert max(abs(float(r) - 0.6) for r in np.asarray(sol.y)[:, 8]) > 1e-3


def test_heavy_top_energy_is_kinetic_plus_potential():
    top = ls.HeavyTop(inertia=(3, 4, 5), com=(1, 2, 3), mass=2, g=10)
    y0 = top.initial_state(omega=(1, 1, 1))
    c = private_ctx(50)
    assert abs(ctx_mpf(c, top.invariants(y0)["energy"]) - (Fraction(12, 2) + 2 * 10 * 3)) < c.mpf(10) ** -40


def test_bad_heavy_top_input_names_the_argument():
    with pytest.raises(ValueError, match="`com`"):
        ls.HeavyTop(com=(0, 1))
    with pytest.raises(ValueError, match="`mass`"):
        ls.HeavyTop(mass=0)
    with pytest.raises(ValueError, match="`inertia`"):
        ls.HeavyTop(inertia=(1, -2, 3))


# -- the integrable cases: M3 (Lagrange) and Kovalevskaya's integral among the invariants ----------------------------
R_TILT = [["0.6", 0, "-0.8"], [0, 1, 0], ["0.8", 0, "0.6"]]
PRECISIONS = ["double", "quad", dps_to_bits(50)]


@pytest.mark.parametrize("precision", PRECISIONS)
def test_lagrange_top_M3_invariant_is_conserved_to_epsilon(precision):
    top = ls.HeavyTop(inertia=(2, 2, 1), com=(0, 0, "0.5"), mass=2, g="9.81")
    assert top.case == "lagrange"
    y0 = top.initial_state(omega=("0.3", "-0.2", 5), R0=R_TILT)
    inv0 = top.invariants(y0)
    assert "M2" not in inv0  # |M|^2 is not conserved under gravity
    c = private_ctx(70)
    assert ctx_mpf(c, inv0["M3"]) == 5  # M3 = I3 omega3, exactly
    sol = ls.integrate(top, y0, t=[1, 2, 3], precision=precision)
    assert sol.success
    eps = ctx_mpf(c, resolve_precision(precision).eps)
    inv = top.invariants(sol.y)
    for i in range(3):
        # measured: 0 (dM3/dt = (I1 - I2) Omega1 Omega2 / ... is exactly 0: M3 is never rounded)
        assert abs(ctx_mpf(c, inv["M3"][i]) - 5) < 20 * eps * 5, (precision, i)
        assert abs(ctx_mpf(c, inv["energy"][i]) - ctx_mpf(c, inv0["energy"])) < 20 * eps * 20
    assert max(abs(float(r) - 0.6) for r in np.asarray(sol.y, dtype=float)[:, 8]) > 1e-3  # it nutates


KOVALEVSKAYA = dict(inertia=(4, 4, 2), com=("0.3", "-0.4", 0), mass=2, g="9.81")


def kovalevskaya_reference(c, M, G):
    """K = |(O1 + i O2)^2 - (mass g / I3) (com1 + i com2)(G1 + i G2)|^2, O = M / I, written here."""
    I, com = KOVALEVSKAYA["inertia"], KOVALEVSKAYA["com"]
    kappa = 2 * ctx_mpf(c, "9.81") / I[2]
    w = c.mpc(M[0] / I[0], M[1] / I[1]) ** 2 - kappa * c.mpc(ctx_mpf(c, com[0]), ctx_mpf(c, com[1])) * c.mpc(G[0], G[1])
    return abs(w) ** 2


def test_kovalevskaya_integral_is_a_first_integral_of_the_equations():
    """The K written in the test is conserved by the heavy top's Euler-Poisson equations (sympy), and the model's
    ``kovalevskaya`` invariant equals it at arbitrary states."""
    sp = pytest.importorskip("sympy")
    M = sp.Matrix(sp.symbols("M1:4", real=True))
    G = sp.Matrix(sp.symbols("G1:4", real=True))
    c1, c2, mg, s = sp.symbols("c1 c2 mg s", real=True)
    I = [2 * s, 2 * s, s]
    Om = sp.Matrix([M[i] / I[i] for i in range(3)])
    com = sp.Matrix([c1, c2, 0])
    dM = M.cross(Om) + mg * G.cross(com)
    dG = G.cross(Om)
    Z = (Om[0] + sp.I * Om[1]) ** 2 - mg / s * (c1 + sp.I * c2) * (G[0] + sp.I * G[1])
    K = sp.expand(Z * sp.conjugate(Z))
    dK = sum(sp.diff(K, M[i]) * dM[i] + sp.diff(K, G[i]) * dG[i] for i in range(3))
    assert sp.simplify(sp.expand(dK)) == 0
    top = ls.HeavyTop(**KOVALEVSKAYA)
    assert top.case == "kovalevskaya"
    c = private_ctx(60)
    state = [Fraction(v) for v in ("0.6", "0.8", "0.0", "-0.8", "0.6", "0.0", "0.1", "0.3", "-0.2", "1.5", "-0.7", "2.5")]
    got = top.invariants(np.array(state, dtype=object))["kovalevskaya"]
    ref = kovalevskaya_reference(c, [ctx_mpf(c, v) for v in state[9:]], [ctx_mpf(c, v) for v in state[6:9]])
    assert abs(ctx_mpf(c, got) - ref) < c.mpf(2) ** -48 * ref  # a state of Fractions: evaluated in double


@pytest.mark.parametrize("precision", PRECISIONS)
def test_kovalevskaya_integral_is_conserved_to_epsilon(precision):
    top = ls.HeavyTop(**KOVALEVSKAYA)
    y0 = top.initial_state(omega=("0.7", "-0.4", "2.5"), R0=R_TILT)
    c = private_ctx(70)
    K0 = ctx_mpf(c, top.invariants(y0)["kovalevskaya"])
    sol = ls.integrate(top, y0, t=[1, 2, 3], precision=precision)
    assert sol.success
    eps = ctx_mpf(c, resolve_precision(precision).eps)
    inv = top.invariants(sol.y)
    # the terms of K are of the size of |Omega|^4 and (mass g |com| / I3)^2: the scale of its rounding
    scale = (ctx_mpf(c, "0.65") + 2 * ctx_mpf(c, "9.81") * ctx_mpf(c, "0.5") / 2) ** 2
    for i in range(3):
        drift = abs(ctx_mpf(c, inv["kovalevskaya"][i]) - K0)
        # measured: at most 0.85 (double), 1.6 (quad), 3.2 (169 bits) eps * scale (scale 30, K0 = 10.75)
        assert drift < 20 * eps * scale, (precision, i, drift / (eps * scale))
    # gravity acts: |M|^2 changes
    M2 = [sum(float(v) ** 2 for v in r[9:]) for r in np.asarray(sol.y, dtype=float)]
    assert max(abs(m - M2[0]) for m in M2) > 1e-2


@pytest.fixture(scope="module")
def heavy_top_intermediate():
    """(intermediate form, its state, program, parameters, mpf jets to order 36 at 60 digits) of a heavy top, built
    once for the module: compiling the form's ~1500 products takes most of a second."""
    from lieseries.lie import taylor_coefficients
    from lieseries.poisson import as_poisson_system

    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
    inter = top.constrained_system().intermediate()
    q, qdot = top.surface_point(top.initial_state(omega=(1, "0.5", 5)))
    z0 = inter.initial_state(q=q, qdot=qdot)
    ps = as_poisson_system(inter)
    y0, pars = list(z0), list(ps.parameter_values)
    return inter, z0, ps.program, y0, pars, taylor_coefficients(ps.program, y0, pars, 36, 60)


def test_heavy_top_intermediate_field_to_the_working_precision(bigint, heavy_top_intermediate):
    """The fixed-point jets on the intermediate form of a heavy top (12 variables; ~1500 products, 260 constant
    factors, 5 divisions, constraint residuals that are zero): scales propagated through its products lie up to 40
    bits above what the nodes carry, and rounding at them lost 20 digits (c_5 to 6e-21 of the state's scale
    sigma^-5 at 30 digits)."""
    from test_fixed_jets import check

    _, _, prog, y0, pars, ref = heavy_top_intermediate
    check(prog, y0, pars, 36, 30, -4, scale=5, ref=ref)


def test_intermediate_form_at_30_digits_is_right_with_few_guard_digits(heavy_top_intermediate):
    """The intermediate form of a heavy top (12 variables; a field of ~1500 products whose constraint residuals are
    zero, so that scales propagated through the products lie up to 40 bits above what the nodes carry) integrated
    at 30 digits with 5 and with no guard digits, against a run at 45 (5e-57 from a run at 60): within the
    tolerance 1e-30 (the fixed-point jets rounded every node at its propagated scale, and a run with 5 guard digits
    reported a `success` 2e-28 off; without guard digits, `invariant_drift` 3e-23 off)."""
    inter, z0 = heavy_top_intermediate[:2]
    ref = ls.lie_integrate(inter, z0, t="0.05", dps=45)
    c = private_ctx(70)
    for guard in (5, 0):
        sol = ls.lie_integrate(inter, z0, t="0.05", dps=30, guard=guard)
        err = max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(sol.y_reached, ref.y_reached))
        assert sol.status == "success" and err < c.mpf(10) ** -30, (guard, sol.status, float(err))


def test_heavy_top_case_detection():
    assert ls.HeavyTop(inertia=(3, 4, 5), com=(0, 0, 1)).case is None
    assert ls.HeavyTop(inertia=(2, 2, 1), com=(0, "0.1", 1)).case is None
    assert ls.HeavyTop(inertia=(2, 2, 1), com=(1, 0, 0)).case == "kovalevskaya"
    assert ls.HeavyTop(inertia=(3, 3, 1), com=(1, 0, 0)).case is None
    free = ls.HeavyTop(inertia=(2, 2, 1), com=(0, 0, 0))
    assert free.case is None and "M2" in free.invariants(free.initial_state(omega=(1, 2, 3)))
    generic = ls.HeavyTop(**TOP)
    inv = generic.invariants(generic.initial_state(omega=OMEGA))
    assert not {"M2", "M3", "kovalevskaya"} & set(inv)


@pytest.mark.slow  # 2 s; test_dirac_and_intermediate_forms_of_the_heavy_top_give_its_equations checks the library's
def test_heavy_top_is_the_rigid_body_with_gravity_derived_by_constrained_system():
    """The nine entries of R with R^T R = 1, L = 1/2 tr(Rdot g Rdot^T) - mass g (R com)_3 and the frame R^-T E_k,
    derived by ConstrainedSystem's intermediate formalism: its vector field equals HeavyTop's (both brackets, 11.20
    and its Chetaev form) at rotations with rational entries, at 50 digits; g = (5/2, 3/2, 1/2) gives the inertia
    I = tr(g) - g = (2, 3, 4)."""
    import random

    from lieseries.expr import compile_expressions
    from test_intermediate import _rotation, rigid_body_system

    com = ("1/2", "-1/3", "1/4")
    cs, frame = rigid_body_system(potential="mass*grav*(R31*c1 + R32*c2 + R33*c3)",
                                  parameters={"mass": 2, "grav": "9.81", "c1": com[0], "c2": com[1], "c3": com[2]})
    derived = cs.intermediate(frame=frame, momenta=["M1", "M2", "M3"])

    def field(model, z):
        ps = model.poisson
        prog = compile_expressions(ps.variables, ps.vector_field, len(ps.parameter_values), cse=False)
        return prog.evaluate(list(z), list(ps.parameter_values), 50)

    rng = random.Random(8)
    for bracket in ("intermediate", "chetaev"):
        top = ls.HeavyTop((2, 3, 4), com=com, mass=2, g="9.81", bracket=bracket)
        for _ in range(2):
            R = _rotation(None, *[Fraction(rng.randint(-9, 9)) for _ in range(4)])
            z = [e for row in R for e in row] + [Fraction(rng.randint(-900, 900), 100) for _ in range(3)]
            for x, y in zip(field(derived, z), field(top, z)):
                assert abs(x - y) < 1e-44 * (1 + abs(y))


@pytest.mark.slow  # 6 s: the fast test below checks a diagonal tensor
def test_constrained_system_of_a_heavy_top_with_a_full_inertia_tensor_gives_its_equations():
    """``HeavyTop.constrained_system()`` (the nine entries of R, R^T R = 1, J = tr(I)/2 - I, its frame R^-T E_k as
    the default of ``intermediate()``): the intermediate field equals HeavyTop's hand-written one at rotations with
    rational entries (50 digits), for an inertia tensor with products of inertia."""
    import random

    from test_intermediate import _rotation

    inertia = [[3, "1/2", 0], ["1/2", 4, "-1/3"], [0, "-1/3", 5]]
    top = ls.HeavyTop(inertia, com=("1/2", "-1/3", "1/4"), mass=2, g="9.81")
    cs = top.constrained_system()
    assert cs is top.constrained_system()
    derived = cs.intermediate()
    rng = random.Random(3)
    for _ in range(2):
        R = _rotation(None, *[Fraction(rng.randint(-9, 9)) for _ in range(4)])
        z = [e for row in R for e in row] + [Fraction(rng.randint(-900, 900), 100) for _ in range(3)]
        for x, y in zip(_field(derived, z), _field(top, z)):
            assert abs(x - y) < 1e-44 * (1 + abs(y))


def _field(model, z, rows=None):
    """The field of ``model`` at ``z``, at 50 digits (compiled without sympy's cse: evaluated once, the search for
    shared sub-sums costs more than it saves)."""
    from lieseries.expr import compile_expressions

    ps = model.poisson
    exprs = ps.vector_field if rows is None else ps.vector_field[:rows]
    prog = compile_expressions(ps.variables, exprs, len(ps.parameter_values), cse=False)
    return prog.evaluate(list(z), list(ps.parameter_values), 50)


def test_dirac_and_intermediate_forms_of_the_heavy_top_give_its_equations():
    """The Dirac form of ``HeavyTop.constrained_system()`` (18 variables) at the point ``surface_point`` gives
    (q = R, qdot = R hat(Omega), Omega = I^-1 M, exact): its field moves R as R hat(Omega), at 50 digits; its
    intermediate form (the default frame R^-T E_k) has HeavyTop's hand-written field there."""
    from test_intermediate import _rotation

    top = ls.HeavyTop(**TOP)
    R = _rotation(None, *(Fraction(v) for v in (3, 1, -2, 1)))
    om = [Fraction(1), Fraction(-2, 3), Fraction(5, 2)]
    q, qdot = top.surface_point(top.initial_state(omega=om, R0=R))
    hat = [[0, -om[2], om[1]], [om[2], 0, -om[0]], [-om[1], om[0], 0]]
    want = [sum(R[i][k] * hat[k][j] for k in range(3)) for i in range(3) for j in range(3)]
    assert q == [e for row in R for e in row] and qdot == want
    dirac = top.constrained_system().dirac()
    c = private_ctx(50)
    for x, w in zip(_field(dirac, list(dirac.initial_state(q, qdot).exact), rows=9), want):
        assert abs(ctx_mpf(c, x) - ctx_mpf(c, w)) < c.mpf(10) ** -44
    y0 = top.initial_state(omega=om, R0=R)
    inter = top.constrained_system().intermediate()
    assert list(inter.initial_state(q, qdot).exact) == list(y0.exact)  # pi = M in the frame R^-T E_k
    for x, y in zip(_field(inter, list(y0.exact)), _field(top, list(y0.exact))):
        assert abs(ctx_mpf(c, x) - ctx_mpf(c, y)) < c.mpf(10) ** -44 * (1 + abs(ctx_mpf(c, y)))


def test_damped_body_has_no_constrained_system():
    with pytest.raises(ValueError, match="dissipates energy"):
        ls.DampedEulerPoisson((1, 2, 3), damping=1).constrained_system()


def test_a_flat_body_has_no_constrained_system_and_says_why():
    """I = (1, 2, 3): I3 = I1 + I2, a flat body, J = tr(I)/2 - I has J33 = 0: L in R is singular."""
    with pytest.raises(ValueError, match=r"`inertia`: the mass tensor J = tr\(I\)/2 - I of this body is not positive"):
        ls.EulerPoisson((1, 2, 3)).constrained_system()


def test_a_chart_frame_for_six_constraints_is_refused_naming_frame():
    """R^T R = 1 solved for six entries of R: not triangular, its inverse out of symbolic reach: refused at once
    (it ran for more than ten minutes). A chain of three rods (triangular) keeps its chart frame."""
    cs = ls.HeavyTop(**TOP).constrained_system()
    with pytest.raises(ValueError, match=r"intermediate\(\): the frame of a chart .* must be triangular .* "
                                         r"Give `frame=`"):
        cs.intermediate(dependent=["R11", "R21", "R22", "R31", "R32", "R33"])
    rods = ls.ConstrainedSystem("(x1_dot**2+y1_dot**2+x2_dot**2+y2_dot**2+x3_dot**2+y3_dot**2)/2",
                                ["x1", "y1", "x2", "y2", "x3", "y3"],
                                ["x1**2+y1**2-1", "(x2-x1)**2+(y2-y1)**2-1", "(x3-x2)**2+(y3-y2)**2-1"])
    assert rods._triangular((1, 3, 5)) and not cs._triangular((0, 3, 4, 6, 7, 8))


def test_binary_data_of_a_body_carry_their_bits_into_its_derived_forms():
    """g = 9.81 as a double carries 53 bits: the top warns naming `g` and its Lie estimates stay above 2^-53; the
    same top derived by ``constrained_system()`` must do the same (J and the weights were passed on as exact
    Fractions: a 30-digit run claimed 1e-40). A state of doubles handed to ``surface_point`` carries 53 bits into
    the form's initial state too."""
    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g=9.81)
    inter = top.constrained_system().intermediate()
    q, qdot = top.surface_point(top.initial_state(omega=(1, "0.5", 5)))
    with pytest.warns(ls.PrecisionWarning, match="`g`"):
        sol = ls.lie_integrate(inter, inter.initial_state(q=q, qdot=qdot), t="0.05", dps=30)
    assert sol.status == "success" and max(sol.stats.error_estimates) >= 2.0 ** -54
    exact = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
    y = np.asarray(exact.initial_state(omega=(1, "0.1", 5)), dtype=float)   # 0.1 rounded to a double
    q, qdot = exact.surface_point(y)
    z0 = exact.constrained_system().intermediate().initial_state(q=q, qdot=qdot)
    assert z0.data_bits == 53
    q, qdot = exact.surface_point(exact.initial_state(omega=(1, "0.1", 5)))
    assert data_bits(q + qdot) is None and qdot[2] == Fraction(1, 10)   # exact data stay exact


def test_a_body_started_from_a_rotation_in_doubles_starts_its_derived_forms():
    """R0 typed in doubles (0.8, 0.6: R0 R0^T = 1 to 4e-17) is accepted by the top; its surface_point carries 53
    bits, but the derived forms checked it at the exact tolerance 1e-50 and refused it. In the frame R^-T E_k the
    intermediate form's state is the top's own (pi = M)."""
    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
    y0 = top.initial_state(omega=(1, "0.5", 5), R0=[[1, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]])
    q, qdot = top.surface_point(y0)
    cs = top.constrained_system()
    z0 = cs.intermediate().initial_state(q=q, qdot=qdot)
    assert z0.data_bits == 53 and list(z0.exact) == list(y0.exact)
    assert cs.dirac().initial_state(q=q, qdot=qdot).data_bits == 53
    with pytest.raises(ValueError, match="`q` is not on the constraint surface"):
        cs.intermediate().initial_state(q=[Fraction(2)] + list(q[1:]), qdot=qdot)


def test_orthogonality_is_conserved_from_a_rotation_in_doubles():
    """R0 in doubles misses R0 R0^T = 1 by 4.4e-17. The flow R -> R exp(t hat(Omega)) keeps R R^T exactly (its
    Casimirs) but not the entries of R^T R: ``orthogonality`` measured max |R^T R - 1|, which moved by 1.3e-17
    over a quad run and was reported as that run's drift. Against the exact value of the start at 60 digits."""
    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
    y0 = top.initial_state(omega=(1, "0.5", 5), R0=[[1, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]])
    c = private_ctx(60)
    R = [[ctx_mpf(c, y0.exact[3 * i + j]) for j in range(3)] for i in range(3)]
    start = max(abs(c.fsum(R[i][k] * R[j][k] for k in range(3)) - (i == j)) for i in range(3) for j in range(3))
    assert start > 1e-17
    sol = ls.integrate(top, y0, t=[Fraction(k, 8) for k in range(1, 9)], precision="quad")
    for row in top.invariants(sol.y)["orthogonality"]:
        assert abs(ctx_mpf(c, row) - start) < 1e-32


def test_an_overflowing_weight_names_mass_g_and_com():
    """mass g com_i is one runtime parameter: with mass = g = 1e300 it overflows a double, and the refusal named
    `com` alone."""
    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="1e300", mass="1e300")
    with pytest.raises(ValueError, match=r"`mass \* g \* com` gives the runtime parameter 'mgc3', whose value ~1e600 "
                                         "overflows double"):
        ls.integrate(top, top.initial_state(omega=(1, "0.5", 5)), t=1)


def test_the_derived_forms_start_from_a_state_a_quad_run_ended_in():
    """A top run in quad to t = 50 (295 steps) ends 7-30 ulps off R^T R = 1 (its rounding); surface_point of that
    state was refused by the derived forms ("not tangent", 1.9e-33 relative against 16 ulps = 1.5e-33). A point
    from a model's state is checked as that model's check_state checks a run's state, to the square root of its
    precision; the same state 1e-10 off the surface is still refused, and a point typed in floats keeps its 16
    ulps and says what to do."""
    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
    sol = ls.integrate(top, top.initial_state(omega=(1, "0.5", 5)), t=50, precision="quad")
    assert sol.status == "success"
    cs = top.constrained_system()
    q, qdot = top.surface_point(sol.y_reached)
    z0 = cs.intermediate().initial_state(q=q, qdot=qdot)
    assert z0.data_bits == 113 and list(z0.exact[:9]) == q
    assert cs.dirac().initial_state(q=q, qdot=qdot).data_bits == 113
    off = np.array(sol.y_reached, copy=True)
    off[:9] *= hy.real128("1.0000000001")  # R 1e-10 off the rotations
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the top warns that R is not a rotation
        q_off, qdot_off = top.surface_point(off)
    with pytest.raises(ValueError, match="`q` is not on the constraint surface"):
        cs.intermediate().initial_state(q=q_off, qdot=qdot_off)
    with pytest.raises(ValueError, match="continue from that state itself"):
        cs.intermediate().initial_state(q=[to_fraction(v) for v in q_off[:8]] + [float(q_off[8])], qdot=qdot_off)
