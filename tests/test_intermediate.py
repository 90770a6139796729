"""ConstrainedSystem.intermediate() (paper, p9-p14.3) and .local(chart=): the paper's own examples.

References are independent of the derivation: the brackets (dm5) and Hamiltonian (dm6, its square restored) of the
particle on the sphere and the change of momenta (dm2)-(dm4), written here by hand; ``ls.Sphere`` (written by
hand); the great circle ``ls.exact.sphere``; for the rigid body the bracket (11.20) written by hand, the inertia
tensor I = tr(g) - g, ``ls.EulerPoisson`` and the closed form ``ls.exact.euler_poisson``.
"""

import random
import re
import time
from fractions import Fraction

import numpy as np
import pytest
import sympy as sp

import lieseries as ls
from lieseries.expr import compile_expressions
from lieseries.models.constrained_checks import check_chart
from problems import ctx_mpf, private_ctx
from lieseries.precision import resolve_precision
from problems import ctx_mpf, private_ctx

SPHERE_L = "m/2*(x1_dot**2 + x2_dot**2 + x3_dot**2)"
SPHERE_Q = ["x1", "x2", "x3"]
SPHERE_G = ["x1**2 + x2**2 + x3**2 - c**2"]
UPPER = {"x3": "sqrt(c**2 - x1**2 - x2**2)"}


@pytest.fixture(scope="module")
def sphere():
    return ls.ConstrainedSystem(SPHERE_L, SPHERE_Q, SPHERE_G, parameters={"m": "3/2", "c": 1})


def _field(model, state, dps=40):
    ps = model.poisson
    prog = compile_expressions(ps.variables, ps.vector_field, len(ps.parameter_values), cse=False)
    return prog.evaluate(list(state), list(ps.parameter_values), dps)


# -- the sphere: (dm2)-(dm6) --------------------------------------------------------------------------------------
def test_sphere_intermediate_bracket_and_hamiltonian_are_dm5_dm6(sphere):
    """Symbolically: the frame is (dm2)'s rows, the bracket (dm5), H the corrected (dm6), and p(q, pi) is (dm4) at
    pi3 = 0."""
    d = sphere.intermediate_bracket()
    x1, x2, x3 = d["q"]
    p1, p2 = d["pi"]
    m = sp.Symbol("m", real=True)
    r2 = x1**2 + x2**2 + x3**2
    assert d["frame"] == sp.Matrix([[1, 0, -x1 / x3], [0, 1, -x2 / x3]])
    expected = sp.zeros(5, 5)
    expected[0, 3], expected[1, 4], expected[2, 3], expected[2, 4] = 1, 1, -x1 / x3, -x2 / x3
    expected = expected - expected.T
    assert sp.simplify(d["tensor"] - expected) == sp.zeros(5, 5)
    dm6 = (p1**2 + p2**2 - (x1 * p1 + x2 * p2) ** 2 / r2) / (2 * m)
    assert sp.simplify(d["H"] - dm6) == 0
    s = x1 * p1 + x2 * p2  # (dm4) with pi3 = 0
    dm4 = [p1 - x1 / r2 * s, p2 - x2 / r2 * s, -x3 / r2 * s]
    assert all(sp.simplify(a - b) == 0 for a, b in zip(d["p"], dm4))


def test_sphere_intermediate_equals_ls_sphere_symbolically(sphere):
    """ls.Sphere's tensor and Hamiltonian (written by hand, read back with heyoka.to_sympy, its runtime parameter
    1/m as 1/m) are the derived ones, entry by entry."""
    import heyoka as hy

    d = sphere.intermediate_bracket(momenta=["pi1", "pi2"])
    hand = ls.Sphere(mass="3/2", radius=1, atlas=False).poisson
    by_name = {str(s): s for s in d["q"] + d["pi"]}
    m = sp.Symbol("m", real=True)

    def read(e):
        e = hy.to_sympy(e) if not isinstance(e, (int, float)) else sp.Integer(e)
        return e.xreplace({s: by_name.get(s.name, 1 / m if s.name == "par[0]" else s) for s in e.free_symbols})
    for a in range(5):
        for b in range(5):
            assert sp.simplify(read(hand.tensor[a][b]) - d["tensor"][a, b]) == 0, (a, b)
    assert sp.simplify(read(hand.hamiltonian) - d["H"]) == 0


def test_sphere_intermediate_field_equals_ls_sphere(sphere):
    """At states of several radii (|x|^2 is a Casimir: every leaf), the derived vector field is ls.Sphere's."""
    model = sphere.intermediate()
    hand = ls.Sphere(mass="3/2", radius=1, atlas=False)
    rng = random.Random(5)
    for _ in range(3):
        z = [Fraction(rng.randint(200, 900), 1000) for _ in range(5)]
        for a, b in zip(_field(model, z), _field(hand, z)):
            assert abs(a - b) < 1e-36 * (1 + abs(b))


def test_intermediate_bracket_is_poisson_with_the_constraints_as_casimirs(sphere):
    """Antisymmetry, Jacobi and the Casimirs G: symbolically for the sphere, at random points (50 digits) for a
    particle on a tilted circle (two constraints, a linear term in L)."""
    d = sphere.intermediate_bracket()
    z = d["q"] + d["pi"]
    T = d["tensor"]
    assert T + T.T == sp.zeros(5, 5)

    def br(f, g):
        return sum(sp.diff(f, z[a]) * T[a, b] * sp.diff(g, z[b]) for a in range(5) for b in range(5))
    for i in range(5):
        for j in range(i + 1, 5):
            for k in range(j + 1, 5):
                jac = br(z[i], T[j, k]) + br(z[j], T[k, i]) + br(z[k], T[i, j])
                assert sp.simplify(jac) == 0
    G = d["G"][0]
    assert all(sp.simplify(br(G, v)) == 0 for v in z)
    cs = ls.ConstrainedSystem("(x_dot**2 + 2*y_dot**2 + z_dot**2)/2 + x*y_dot - y", ["x", "y", "z"],
                              ["x**2 + y**2 + z**2 - 1", "x + y + 2*z - 1/3"])
    ps = cs.intermediate(dependent=("x", "z")).poisson
    assert set(ps.casimirs) == {"G1", "G2"}
    pts = [[str(v) for v in row] for row in np.random.default_rng(3).uniform(0.3, 1.3, size=(3, 4))]
    assert ps.antisymmetry_residual(pts, 50) == 0
    assert ps.jacobi_residual(pts, 50) < 1e-40
    for name in ps.casimirs:
        assert ps.casimir_residual(name, pts, 50) < 1e-40


def test_sphere_local_chart_is_the_canonical_form_of_the_upper_half(sphere):
    """x3 = sqrt(c^2 - x1^2 - x2^2): M = m (1 + x x^T / x3^2), H = (|p|^2 - (x.p)^2/c^2) / 2m (p = M xdot inverted
    by hand: M^-1 = (1 - x x^T / c^2)/m)."""
    model = sphere.local(chart=UPPER)
    assert model.names == ("x1", "x2", "p_x1", "p_x2")
    x1, x2 = sp.symbols("x1 x2", real=True)
    p1, p2 = sp.symbols("p_x1 p_x2", real=True)
    m, c = sp.symbols("m c", real=True)
    H = (p1**2 + p2**2 - (x1 * p1 + x2 * p2) ** 2 / c**2) / (2 * m)
    assert sp.simplify(model._sym_hamiltonian - H) == 0



def test_a_valid_chart_sympy_cannot_simplify_is_accepted_and_a_nearly_right_one_refused():
    """The chart is checked by evaluating G at points where it is real, not by sympy.simplify: cosh(asinh(1)) is
    sqrt(2), which simplify does not see, so this chart is the upper half; a chart off by 1e-30 is refused."""
    pend = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2 - y", ["x", "y"], ["x**2 + y**2 - r**2"],
                                parameters={"r": "1/1000"})
    odd = pend.local(chart={"y": "sqrt(r**2 - x**2)*cosh(asinh(1))/sqrt(2)"})
    plain = pend.local(chart={"y": "sqrt(r**2 - x**2)"})
    z = ("3/5000", "1/10")
    assert sp.simplify(sp.sympify("x**2 + (sqrt(1 - x**2)*cosh(asinh(1))/sqrt(2))**2 - 1")) != 0
    assert all(abs(a - b) < 1e-35 * abs(b) for a, b in zip(_field(odd, z), _field(plain, z), strict=True))
    with pytest.raises(ValueError, match=r"`chart` does not solve the constraints: G1 = .* is -?[0-9.e-]+ \(not 0\)"):
        pend.local(chart={"y": "sqrt(r**2 - x**2) + 10**-30"})
    with pytest.raises(ValueError, match="`chart`: found no point where the chart is real"):
        pend.local(chart={"y": "sqrt(-r**2 - x**2)"})

def test_a_chart_real_on_a_ring_only_is_accepted():
    """The upper half of a torus (R = 2, r = 1) is real only where 1 <= sqrt(x^2 + y^2) <= 3: of the sample points
    few fall there, and this valid chart was refused with "found no point where the chart is real". (The check
    local() makes, called alone: the derivation takes 2 s.)"""
    x, y, z = sp.symbols("x y z")
    torus = [(x**2 + y**2 + z**2 + 3)**2 - 16*(x**2 + y**2)]
    upper = sp.sqrt(1 - (sp.sqrt(x**2 + y**2) - 2)**2)
    check_chart(torus, [x, y, z], {}, {z: upper})
    with pytest.raises(ValueError, match=r"`chart` does not solve the constraints"):
        check_chart(torus, [x, y, z], {}, {z: upper + sp.Integer(10)**-30})


def test_a_torus_in_a_local_chart_keeps_its_digits():
    """The upper half of a torus (R = 2, r = 1), z = sqrt(r^2 - (sqrt(x^2 + y^2) - R)^2): cancelled, its H was a
    degree-8 polynomial fraction whose terms cancel, and heyoka's double and quad runs lost ~5 digits and ended
    `invariant_drift`. Written as derived (nothing expanded), each run ends `success` on the Dirac form's motion,
    an independent derivation without charts, within its own precision."""
    import mpmath

    torus = ls.ConstrainedSystem("(x_dot**2 + y_dot**2 + z_dot**2)/2", ["x", "y", "z"],
                                 ["(x**2 + y**2 + z**2 + R**2 - r**2)**2 - 4*R**2*(x**2 + y**2)"],
                                 parameters={"R": 2, "r": 1})
    local = torus.local(chart={"z": "sqrt(r**2 - (sqrt(x**2 + y**2) - R)**2)"})
    dirac = torus.dirac()
    q = ("5/2", 0, "0.8660254037844386467637231707529361834714026269051903140279034897259665084544")  # z = sqrt(3)/2
    for precision, bound in (("double", 1e-14), ("quad", 1e-31)):
        a = ls.integrate(local, local.initial_state(q, (0, 1, 0)), t=1, precision=precision)
        b = ls.integrate(dirac, dirac.initial_state(q, (0, 1, 0)), t=1, precision=precision)
        assert a.status == "success" and b.status == "success", (a.message, b.message)
        with mpmath.workdps(40):
            qa, qb = (np.asarray(m.configuration(sol), dtype=object)[-1] for m, sol in ((local, a), (dirac, b)))
            assert max(abs(mpmath.mpf(str(u)) - mpmath.mpf(str(v))) for u, v in zip(qa, qb)) < bound


def test_a_point_in_doubles_near_the_charts_edge_is_held_by_it():
    """y = -sqrt(1 - x^2) at x = cos 0.06 amplifies x's rounding 280-fold: the point in doubles, which dirac()
    accepts, was refused as "not in this chart ... (another branch of the solution)", showing y equal to the chart's
    value to every printed digit. The other branch is still refused."""
    pend = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2 - y", ["x", "y"], ["x**2 + y**2 - 1"])
    lower = pend.local(chart={"y": "-sqrt(1 - x**2)"})
    th = 0.06
    q, v = (np.cos(th), -np.sin(th)), (-np.sin(th), -np.cos(th))
    pend.dirac().initial_state(q=q, qdot=v)
    y0 = lower.initial_state(q=q, qdot=v)
    assert y0[0] == q[0]
    with pytest.raises(ValueError, match=r"`q` is not in this chart: y = 0.059964006 but the chart gives"):
        lower.initial_state(q=(q[0], -q[1]), qdot=(v[0], -v[1]))


# -- the great circle in all four formulations, by both engines -----------------------------------------------------
X0, V0 = ("0.6", "0", "0.8"), ("0", "1", "0")
FORMS = {
    "dirac": lambda cs: cs.dirac(),
    "reduced": lambda cs: cs.reduced(),
    "intermediate": lambda cs: cs.intermediate(),
    "local": lambda cs: cs.local(chart=UPPER),
}


@pytest.mark.parametrize("engine", ["heyoka", "lie"])
@pytest.mark.parametrize("form", list(FORMS))
def test_sphere_follows_the_great_circle_in_every_formulation(sphere, form, engine):
    """x3 = 0.8 cos t until the chart forms reach their edge |x3| = 0.05 at t = 1.508: heyoka in double, the Lie
    series at 30 digits, both to a small multiple of their epsilon."""
    model = FORMS[form](sphere)
    y0 = model.initial_state(q=X0, qdot=V0)
    ts = ["0.5", 1, "1.4"]
    if engine == "heyoka":
        sol = ls.integrate(model, y0, t=ts, precision="double")
        eps = float(resolve_precision("double").eps)
    else:
        sol = ls.lie_integrate(model, y0, t=ts, dps=30)
        eps = 1e-30
    assert sol.success, sol.message
    c = private_ctx(45)
    worst = 0
    for row_q, row_v, t in zip(model.configuration(sol), model.velocity(sol), ts):
        xt, vt = ls.exact.sphere(1, X0, V0, t, dps=45)
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(list(row_q) + list(row_v), list(xt) + list(vt)))
        worst = max(worst, err / eps)
    assert worst < 300, worst  # grows like 1/x3 near the edge in the chart forms


@pytest.mark.parametrize("form", ["intermediate", "local"])
def test_chart_forms_stop_at_their_edge(sphere, form):
    model = FORMS[form](sphere)
    y0 = model.initial_state(q=X0, qdot=V0)
    stop = ls.integrate(model, y0, t=3)
    assert stop.status == "chart_edge" and "1.508" in stop.message  # acos(1/16) = 1.50826
    lie = ls.lie_integrate(model, y0, t=3, dps=20)
    assert lie.status == "chart_edge"
    assert 1.5082555 <= float(lie.t_reached) < 1.6  # the Lie engine stops at the end of the step that crossed
    # the intermediate form's momentum along x1 is zero but for the roundings (1e-45 against 1.5): held to its own
    # scale, it took 1048 steps (the local chart and heyoka 21-23)
    assert lie.stats.steps < 40


def test_a_lie_step_over_a_thin_edge_band_still_stops_there(sphere):
    """With edge = 0.001 the band |x3| < 0.001 of the reduced chart is thinner than a Lie step: the run stepped from
    x3 > 0 to x3 < 0 (the edge expression det D^2 - edge^2 det W W^T positive at both ends) and ended `success` at
    t = 3 in 3 steps, past the edge heyoka stops at (t = 1.5695)."""
    model = sphere.reduced(edge="0.001")
    lie = ls.lie_integrate(model, model.initial_state(q=X0, qdot=V0), t=3, dps=20)
    assert lie.status == "chart_edge"
    assert 1.5695 <= float(lie.t_reached) < 3  # the end of the step that crossed (2.88)
    # where it stopped, the state is right (the Dirac form, which needs no chart, at 30 digits)
    dirac = sphere.dirac()
    ref = ls.lie_integrate(dirac, dirac.initial_state(q=X0, qdot=V0), t=lie.t_reached, dps=30)
    got, want = model.configuration(lie.y_reached), dirac.configuration(ref.y_reached)
    c = private_ctx(40)
    assert max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(got, want)) < c.mpf(10) ** -18


# -- the rigid body (paper, section "Rotating asymmetric body") ------------------------------------------------------
def _eps(i, j, k):
    return (i - j) * (j - k) * (k - i) // 2


def rigid_body_system(g=("5/2", "3/2", "1/2"), potential="", parameters=None):
    """R (nine entries, row-major), L = 1/2 tr(Rdot g Rdot^T) - ``potential``, R^T R = 1 (six constraints) and the
    paper's frame R^-T E_k (3.7), written with the cofactors of R: pi_k = -eps_kij (R^-1 p)_ij = M_k."""
    R = [[f"R{i}{j}" for j in range(1, 4)] for i in range(1, 4)]
    names = [e for row in R for e in row]
    L = " + ".join(f"g{j + 1}/2*{R[k][j]}_dot**2" for k in range(3) for j in range(3))
    L += f" - ({potential})" if potential else ""
    G = [" + ".join(f"{R[k][i]}*{R[k][j]}" for k in range(3)) + (" - 1" if i == j else "")
         for i in range(3) for j in range(i, 3)]

    def cof(a, b):
        r = [x for x in range(3) if x != a]
        cc = [x for x in range(3) if x != b]
        s = f"({R[r[0]][cc[0]]}*{R[r[1]][cc[1]]} - {R[r[0]][cc[1]]}*{R[r[1]][cc[0]]})"
        return s if (a + b) % 2 == 0 else f"(-{s})"

    det = "(" + " + ".join(f"{R[0][b]}*{cof(0, b)}" for b in range(3)) + ")"
    frame = [[("(" + " + ".join(f"{-_eps(k, i, b)}*{cof(a, i)}" for i in range(3) if _eps(k, i, b)) + f")/{det}")
              if b != k else "0" for a in range(3) for b in range(3)] for k in range(3)]
    values = {f"g{i + 1}": v for i, v in enumerate(g)}
    values.update(parameters or {})
    cs = ls.ConstrainedSystem(L, names, G, parameters=values, name="rigid body")
    return cs, frame


@pytest.fixture(scope="module")
def rigid():
    cs, frame = rigid_body_system()
    t0 = time.perf_counter()
    model = cs.intermediate(frame=frame, momenta=["M1", "M2", "M3"])
    return cs, frame, model, time.perf_counter() - t0


INERTIA = (2, 3, 4)  # I_i = g_j + g_k for g = (5/2, 3/2, 1/2)


def _rotation(c, a, b, cc, d):
    """A rotation with rational entries from a quaternion (Euler-Rodrigues)."""
    n = a * a + b * b + cc * cc + d * d
    return [[(a * a + b * b - cc * cc - d * d) / n, 2 * (b * cc - a * d) / n, 2 * (b * d + a * cc) / n],
            [2 * (b * cc + a * d) / n, (a * a - b * b + cc * cc - d * d) / n, 2 * (cc * d - a * b) / n],
            [2 * (b * d - a * cc) / n, 2 * (cc * d + a * b) / n, (a * a - b * b - cc * cc + d * d) / n]]


def test_rigid_body_derivation_is_fast_and_cached(rigid):
    cs, frame, model, seconds = rigid
    assert model.names == tuple(f"R{i}{j}" for i in range(1, 4) for j in range(1, 4)) + ("M1", "M2", "M3")
    assert seconds < 5, seconds  # measured: 1.6 s (0.5 s derivation, 1.1 s the model)
    again, frame2 = rigid_body_system()
    assert again.intermediate_bracket(frame=frame2, momenta=["M1", "M2", "M3"]) is \
        cs.intermediate_bracket(frame=frame, momenta=["M1", "M2", "M3"])


def test_rigid_body_bracket_is_11_20(rigid):
    """{M_i, R_jk} = -eps_ikm (R^-T)_jm and {M_i, M_j} = -eps_ijk ((R^T R)^-1 M)_k (11.20) at random matrices R
    that are NOT rotations (the bracket holds on every leaf of R^T R), at 50 digits; {R, R} = 0."""
    _cs, _frame, model, _s = rigid
    ps = model.poisson
    prog = compile_expressions(ps.variables, [e for row in ps.tensor for e in row], len(ps.parameter_values))
    c = private_ctx(60)
    rng = random.Random(11)
    for _ in range(3):
        z = [Fraction(rng.randint(-900, 900), 1000) for _ in range(12)]
        T = prog.evaluate(z, list(ps.parameter_values), 50)
        T = [[c.mpf(T[12 * a + b]) for b in range(12)] for a in range(12)]
        R = c.matrix([[ctx_mpf(c, z[3 * i + j]) for j in range(3)] for i in range(3)])
        M = c.matrix([ctx_mpf(c, v) for v in z[9:]])
        RinvT = (R ** -1).T
        CM = (R.T * R) ** -1 * M
        for i in range(3):
            for j in range(3):
                want = -sum(_eps(i, j, k) * CM[k] for k in range(3))
                assert abs(T[9 + i][9 + j] - want) < 1e-45
                for k in range(3):
                    want = -sum(_eps(i, k, m) * RinvT[j, m] for m in range(3))
                    assert abs(T[9 + i][3 * j + k] - want) < 1e-45
        assert all(T[a][b] == 0 for a in range(9) for b in range(9))


@pytest.mark.slow
def test_rigid_body_K_on_so3_is_the_inertia_tensor(rigid):
    """The identification the paper makes (R^T R = 1): K = G_k g G_l^T becomes the inertia tensor I = tr(g) - g,
    so H'_0 = 1/2 I^-1 M M (11.26); symbolically on SO(3) parametrized by a quaternion (4.7 s)."""
    cs, frame, model, _s = rigid
    d = cs.intermediate_bracket(frame=frame, momenta=["M1", "M2", "M3"])
    from sympy.polys.fields import field

    # SO(3) minus the half-turns, rationally: R(1, b, c, d) of the quaternion (1, b, c, d); exact arithmetic in the
    # field Q(b, c, d) (each entry cancelled as it is formed)
    b, cc, dd = sp.symbols("b c d", real=True)
    ring, *_gens = field([b, cc, dd], sp.QQ)
    Rq = _rotation(None, 1, b, cc, dd)
    on_so3 = {s: Rq[i // 3][i % 3] for i, s in enumerate(d["q"])}
    g = {sp.Symbol(f"g{i + 1}", real=True): sp.Rational(v) for i, v in enumerate(("5/2", "3/2", "1/2"))}
    F = [[ring.from_expr(e.xreplace(on_so3)) for e in d["frame"].row(k)] for k in range(3)]
    Mg = [ring.from_expr(d["M"][x, x].xreplace(g)) for x in range(9)]  # the mass matrix is diagonal here
    assert d["M"] == sp.diag(*[d["M"][x, x] for x in range(9)])
    K = sp.Matrix(3, 3, lambda k, l: sum(F[k][x] * Mg[x] * F[l][x] for x in range(9)).as_expr())
    assert K == sp.diag(*INERTIA)


def test_rigid_body_constraints_are_casimirs(rigid):
    """The six entries of R^T R commute with every variable (p11: {M_k, R^T R} = 0), at random R, 50 digits."""
    _cs, _frame, model, _s = rigid
    ps = model.poisson
    assert set(ps.casimirs) == {f"G{a}" for a in range(1, 7)}
    pts = [[str(v) for v in row] for row in np.random.default_rng(3).uniform(-1.3, 1.3, size=(2, 12))]
    for name in ps.casimirs:
        assert ps.casimir_residual(name, pts, 50) < 1e-45


@pytest.mark.slow
def test_rigid_body_bracket_satisfies_jacobi(rigid):
    """The Jacobi identity of the derived 12-variable bracket at a random point off SO(3), 50 digits (measured
    1.1e-49, 26 s)."""
    _cs, _frame, model, _s = rigid
    pts = [[str(v) for v in row] for row in np.random.default_rng(3).uniform(0.3, 1.3, size=(1, 12))]
    assert model.poisson.antisymmetry_residual(pts, 50) == 0
    assert model.poisson.jacobi_residual(pts, 50) < 1e-45


def test_rigid_body_hamiltonian_at_rotations_is_11_26(rigid):
    """H'_0 = 1/2 I^-1 M M (11.26) at random rotations with rational entries, 50 digits."""
    _cs, _frame, model, _s = rigid
    c = private_ctx(60)
    rng = random.Random(2)
    ps = model.poisson
    prog = compile_expressions(ps.variables, [ps.hamiltonian], len(ps.parameter_values))
    for _ in range(3):
        R = _rotation(None, *[Fraction(rng.randint(-9, 9)) for _ in range(4)])
        M = [Fraction(rng.randint(-900, 900), 100) for _ in range(3)]
        (h,) = prog.evaluate([e for row in R for e in row] + M, list(ps.parameter_values), 50)
        want = sum(m * m / i for m, i in zip(M, INERTIA)) / 2
        assert abs(c.mpf(h) - ctx_mpf(c, want)) < 1e-45


def test_rigid_body_field_equals_euler_poisson_on_so3(rigid):
    """The derived vector field is (p26): EulerPoisson's with the bracket (11.20) and its Chetaev form (11.20.2),
    at rotations, 50 digits."""
    _cs, _frame, model, _s = rigid
    rng = random.Random(4)
    for bracket in ("intermediate", "chetaev"):
        hand = ls.EulerPoisson(INERTIA, bracket=bracket)
        for _ in range(2):
            R = _rotation(None, *[Fraction(rng.randint(-9, 9)) for _ in range(4)])
            z = [e for row in R for e in row] + [Fraction(rng.randint(-900, 900), 100) for _ in range(3)]
            for x, y in zip(_field(model, z, 50), _field(hand, z, 50)):
                assert abs(x - y) < 1e-44 * (1 + abs(y))


@pytest.mark.slow
@pytest.mark.parametrize("precision", ["double", 113])
def test_rigid_body_run_agrees_with_the_closed_form(rigid, precision):
    """From R = 1 with Omega = (1, 0.1, 0.5): the derived model agrees with ls.exact.euler_poisson to a small multiple
    of the precision's epsilon at t = 1, 2 (the model asks for compact mode: its field is large, LLVM slow on it
    unrolled)."""
    _cs, _frame, model, _s = rigid
    y0 = model.initial_state(q=[1, 0, 0, 0, 1, 0, 0, 0, 1], qdot=[0, "-0.5", "0.1", "0.5", 0, -1, "-0.1", 1, 0])
    assert list(y0.exact[9:]) == [2, Fraction(3, 10), 2]  # M = I Omega
    ts = [1, 2]
    assert model.large_field  # compiled in compact mode by default
    sol = ls.integrate(model, y0, t=ts, precision=precision)
    assert sol.success
    eps = float(resolve_precision(precision).eps)
    c = private_ctx(50)
    for row, t in zip(sol.y, ts):
        ex = ls.exact.euler_poisson(INERTIA, (1, "0.1", "0.5"), t, dps=50)
        err = max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(row, ex))
        assert err < 100 * eps * t, (t, err)
    inv = model.invariants(sol)
    assert all(abs(g) < 100 * eps for k, v in inv.items() if k.startswith("G") for g in v)


def test_rigid_body_dirac_tensor_assembled_numerically_equals_the_definition_at_a_point():
    """Six constraints: the Dirac tensor is assembled in heyoka (b = {G, Phi} factored L D L^T, no symbolic inverse).
    At a rotation with rational entries and arbitrary momenta it equals the definition {z_i, z_j} - {z_i, chi_I}
    (C^-1)_IJ {chi_J, z_j} with the 12 x 12 matrix C of canonical brackets evaluated there exactly and inverted by
    sympy (no block formula), to 40 digits; G and Phi (declared as its Casimirs) are Casimirs there."""
    cs, _frame = rigid_body_system()
    d = cs.dirac_bracket()
    assert d["tensor"] is None  # k = 6: the assembled route
    model = cs.dirac()
    q, p, chi = d["q"], d["p"], d["chi"]
    n, m = len(q), len(chi)
    z = q + p

    values = {sp.Symbol(f"g{i + 1}", real=True): sp.Rational(v) for i, v in enumerate(("5/2", "3/2", "1/2"))}
    R = _rotation(*(Fraction(v) for v in (3, 1, -2, 1, 1)))
    mom = [Fraction(v, 7) for v in (3, -5, 2, 9, -1, 4, -6, 8, 1)]
    point = [x for row in R for x in row] + mom
    at = {s: sp.Rational(v) for s, v in zip(z, point)}

    def gradient(f):  # (df/dq, df/dp) at the point, exact
        return [[sp.diff(f, v).xreplace(at).xreplace(values) for v in vs] for vs in (q, p)]

    def canonical(f, g):  # the canonical bracket at the point, from the gradients there
        (fq, fp), (gq, gp) = f, g
        return sum(fq[a] * gp[a] - fp[a] * gq[a] for a in range(n))

    dchi, dz = [gradient(c) for c in chi], [gradient(v) for v in z]
    C = sp.Matrix(m, m, lambda a, b: canonical(dchi[a], dchi[b]))
    Z = sp.Matrix(2 * n, m, lambda i, a: canonical(dz[i], dchi[a]))
    ref = -Z * C.inv() * (-Z.T)
    for i in range(n):
        ref[i, i + n] += 1
        ref[i + n, i] -= 1
    ps = model.poisson
    got = compile_expressions(ps.variables, [e for row in ps.tensor for e in row], len(ps.parameter_values)
                              ).evaluate(point, list(ps.parameter_values), 50)
    c = private_ctx(50)

    def num(v):  # an exact sympy rational or an mpf, in the private context
        return ctx_mpf(c, Fraction(int(v.p), int(v.q))) if isinstance(v, sp.Basic) else ctx_mpf(c, v)

    got = [num(v) for v in got]
    tol = c.mpf(10) ** -40
    for i in range(2 * n):
        for j in range(2 * n):
            r = num(ref[i, j])
            assert abs(got[i * 2 * n + j] - r) <= tol * (1 + abs(r)), (i, j)
    assert set(ps.casimirs) == {f"G{a}" for a in range(1, 7)} | {f"Phi{a}" for a in range(1, 7)}
    for ch in chi:  # {chi, z_j} = sum_i dchi/dz_i T_ij = 0
        grad = [sp.diff(ch, zi).xreplace(at).xreplace(values) for zi in z]
        for j in range(2 * n):
            assert abs(c.fsum(num(gi) * got[i * 2 * n + j] for i, gi in enumerate(grad) if gi != 0)) < tol, (ch, j)


def test_reduced_form_of_six_constraints_is_refused_naming_the_other_forms():
    cs, _frame = rigid_body_system()
    with pytest.raises(ValueError, match=r"reduced\(\): a system with 6 constraints .* use dirac\(\) .* intermediate\(\)"):
        cs.reduced()


@pytest.mark.slow
def test_rigid_body_dirac_run_agrees_with_the_closed_form():
    """The Dirac form of the rigid body from R (18 variables, six constraints, assembled tensor) in double: R(t)
    against ls.exact.euler_poisson within 100 eps at t = 1, 2; the constraints hold to 100 eps."""
    cs, _frame = rigid_body_system()
    model = cs.dirac()
    y0 = model.initial_state(q=[1, 0, 0, 0, 1, 0, 0, 0, 1], qdot=[0, "-0.5", "0.1", "0.5", 0, -1, "-0.1", 1, 0])
    ts = [1, 2]
    sol = ls.integrate(model, y0, t=ts, precision="double")
    assert sol.success
    eps = float(resolve_precision("double").eps)
    c = private_ctx(50)
    for row, t in zip(sol.y, ts):
        ex = ls.exact.euler_poisson(INERTIA, (1, "0.1", "0.5"), t, dps=50)
        err = max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(row[:9], ex[:9]))
        assert err < 100 * eps * t, (t, err)
    inv = model.invariants(sol)
    assert all(abs(g) < 100 * eps for k, v in inv.items() if k[0] in "GP" for g in v)


# -- refusals --------------------------------------------------------------------------------------------------------
def test_bad_intermediate_and_local_arguments_are_refused_naming_them(sphere):
    cases = [
        (lambda: sphere.intermediate(frame=[["1", "0", "0"], ["0", "1", "0"]]), "`frame[0]` is not tangent"),
        (lambda: sphere.intermediate(frame=[["x2", "-x1", "0"]]), "`frame` must be a list of 2"),
        (lambda: sphere.intermediate(frame=[["x2", "-x1", "0"], ["x3", "0"]]), "`frame[1]` must be a list of 3"),
        (lambda: sphere.intermediate(frame=[["x2", "-x1", "0"], ["2*x2", "-2*x1", "0"]]), "`frame` has rank 1"),
        (lambda: sphere.intermediate(frame=[["x2", "-x1", "0"], ["x3", "0", "-x1"]], dependent="x3"),
         "not both"),
        (lambda: sphere.intermediate(frame=[["x2", "-y", "0"], ["x3", "0", "-x1"]]), "`frame[0][1]` uses `y`"),
        (lambda: sphere.intermediate(momenta=["a"]), "`momenta` must be 2 names"),
        (lambda: sphere.intermediate(momenta=["x1", "b"]), "`momenta[0]`"),
        (lambda: sphere.intermediate(dependent="w"), "`dependent`"),
        (lambda: sphere.intermediate(edge=0), "`edge`"),
        (lambda: sphere.local(), "`chart` is required"),
        (lambda: sphere.local(chart="x3"), "`chart` must be a mapping"),
        (lambda: sphere.local(chart={"x3": "sqrt(1 - x1**2)"}), "`chart` does not solve the constraints"),
        (lambda: sphere.local(chart={"x3": "sqrt(c**2 - x1**2 - x3**2)"}), "`chart['x3']` uses the dependent"),
        (lambda: sphere.local(chart={"x2": "1", "x3": "0"}), "`chart` must name 1"),
        (lambda: sphere.local(chart=UPPER).initial_state(q=("0.6", "0", "-0.8"), qdot=V0),
         "`q` is not in this chart: x3 = -0.8"),
        (lambda: sphere.local(chart=UPPER).initial_state(q=("0.6", "0.8", "0"), qdot=(0, 0, 1)),
         "`q` is at or beyond the edge"),
        (lambda: sphere.local(chart=UPPER).initial_state(q=("0.6", "0", "0.8"), qdot=(1, 0, 0)),
         "`qdot` is not tangent"),
        (lambda: sphere.intermediate().initial_state(q=("0.6", "0.8", "0"), qdot=(0, 0, 1)),
         "`q` is at or beyond the edge"),
        (lambda: sphere.intermediate().initial_state(q=("0.6", "0", "0.81"), qdot=V0),
         "`q` is not on the constraint surface"),
        (lambda: ls.integrate(sphere.local(chart=UPPER), [2, 0, 0, 1], t=1), "`y0` is at or beyond the edge"),
    ]
    for make, match in cases:
        with pytest.raises((ValueError, TypeError), match=re.escape(match)):
            make()


def test_own_frame_off_its_domain_is_refused(rigid):
    """The frame R^-T E_k is undefined where det R = 0: such a start is refused naming `q` (not a point of R^T R = 1
    either, so the surface check speaks first for it; a singular R on the surface does not exist)."""
    _cs, _frame, model, _s = rigid
    with pytest.raises(ValueError, match=re.escape("`q` is not on the constraint surface")):
        model.initial_state(q=[1, 0, 0, 0, 1, 0, 0, 0, 0], qdot=[0] * 9)


@pytest.mark.slow
def test_rigid_body_lie_run_at_30_digits_agrees_with_the_closed_form(rigid):
    """The Lie engine at 30 digits on the derived model: within 100 eps of ls.exact.euler_poisson at t = 1
    (measured: 7.8e-32, 24 s)."""
    _cs, _frame, model, _s = rigid
    y0 = model.initial_state(q=[1, 0, 0, 0, 1, 0, 0, 0, 1], qdot=[0, "-0.5", "0.1", "0.5", 0, -1, "-0.1", 1, 0])
    sol = ls.lie_integrate(model, y0, t=[1], dps=30)
    assert sol.success
    c = private_ctx(50)
    ex = ls.exact.euler_poisson(INERTIA, (1, "0.1", "0.5"), 1, dps=50)
    err = max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(sol.y[-1], ex))
    assert err < 1e-28, err


def test_intermediate_agrees_with_dirac_with_a_magnetic_term_and_two_constraints():
    """A circle (sphere cut by the plane x + y + z = 1), mass diag(1, 2, 1), a linear term x y_dot (a magnetic field)
    and a potential: the intermediate form (chart x, z dependent) follows the Dirac form (derived by another route,
    p8.7) to quad's epsilon. The start y = z = 0 also checks that powers of a zero coordinate stay
    finite in heyoka."""
    cs = ls.ConstrainedSystem("(x_dot**2 + 2*y_dot**2 + z_dot**2)/2 + x*y_dot - y", ["x", "y", "z"],
                              ["x**2 + y**2 + z**2 - 1", "x + y + z - 1"])
    ts = ["0.25", "0.5"]
    runs = {}
    for name, model in [("dirac", cs.dirac()), ("intermediate", cs.intermediate(dependent=("x", "z")))]:
        sol = ls.integrate(model, model.initial_state(q=(1, 0, 0), qdot=(0, 1, -1)), t=ts, precision="quad")
        assert sol.success, (name, sol.message)
        runs[name] = np.hstack([model.configuration(sol), model.velocity(sol)])
    c = private_ctx(40)
    for name in ("intermediate",):
        err = max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(runs[name].ravel(), runs["dirac"].ravel()))
        assert err < 1e-31, (name, err)  # measured: about 1e-34


def test_frame_tangent_only_on_the_surface_is_refused(rigid):
    """R E_k equals R^-T E_k on SO(3) but is not tangent to the other level sets of R^T R: then {pi, G} != 0 off the
    surface and the Dirac bracket would change the pi's brackets (p18), so the frame is refused naming it."""
    cs, _frame, _model, _s = rigid
    R = [[f"R{i}{j}" for j in range(1, 4)] for i in range(1, 4)]
    frame = [[" + ".join(f"{-_eps(k, i, b)}*{R[a][i]}" for i in range(3) if _eps(k, i, b)) if b != k else "0"
              for a in range(3) for b in range(3)] for k in range(3)]
    with pytest.raises(ValueError, match=r"`frame\[[012]\]` is not tangent to the constraint surfaces"):
        cs.intermediate(frame=frame)


def test_intermediate_field_route_equals_the_expression_route(monkeypatch):
    """The intermediate formalism computed in a field of rational functions equals the expression route (sympy
    together/cancel, taken when the expressions do not fit such a field), symbolically: H'_0, qdot, p(q, pi), c_ij
    and the tensor, for a mass diag(1, 2, 1), a magnetic term and two constraints (chart x, z dependent)."""
    from lieseries.models import constrained_derive as D

    cs = ls.ConstrainedSystem("(x_dot**2 + 2*y_dot**2 + z_dot**2)/2 + x*y_dot - y", ["x", "y", "z"],
                              ["x**2 + y**2 + z**2 - 1", "x + y + z - 1"])
    fast = cs.intermediate_bracket(dependent=("x", "z"))
    monkeypatch.setattr(D, "_intermediate_in_field", lambda *args: None)
    slow = D.derive_intermediate(cs, (0, 2), None, ["pi_y"])
    assert slow is not fast
    assert sp.cancel(slow["H"] - fast["H"]) == 0
    for key in ("velocity", "p"):
        assert all(sp.cancel(a - b) == 0 for a, b in zip(slow[key], fast[key])), key
    assert (slow["tensor"] - fast["tensor"]).applyfunc(sp.cancel) == sp.zeros(*fast["tensor"].shape)
    assert all(sp.cancel(a - b) == 0 for key in slow["c"] for a, b in zip(slow["c"][key], fast["c"][key]))
