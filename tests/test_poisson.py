"""Poisson structures: antisymmetry, the Jacobi identity and Casimirs, evaluated in mpmath at sample points."""

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest

import lieseries as ls

DPS = 50
TINY = mp.mpf(10) ** (-DPS + 8)


def random_points(model, rng, k=3, orthogonal=False, on_sphere=None):
    pts = []
    for _ in range(k):
        if isinstance(model, ls.EulerPoisson):
            R = rng.normal(size=(3, 3))
            if orthogonal:
                R, _ = np.linalg.qr(R)
            pts.append([str(v) for v in np.concatenate([R.ravel(), rng.normal(size=3)])])
        else:
            z = rng.normal(size=model.dimension)
            z[model.chart if hasattr(model, "chart") else 2] += 2.0  # stay off the chart edge
            if on_sphere and isinstance(model, ls.SphereDirac):
                x, p = z[:3], z[3:]
                z[3:] = p - x * np.dot(x, p) / np.dot(x, x)  # x . p = 0
            pts.append([str(v) for v in z])
    return pts


@pytest.mark.parametrize("inertia", [(1, 2, 3), [[2, "0.3", 0], ["0.3", 1, 0], [0, 0, 3]]], ids=["diag", "full"])
def test_chetaev_bracket_jacobi_everywhere(inertia):
    body = ls.EulerPoisson(inertia)
    pts = random_points(body, np.random.default_rng(3))
    assert body.poisson.antisymmetry_residual(pts, DPS) == 0
    assert body.poisson.jacobi_residual(pts, DPS) < TINY


def test_chetaev_casimirs_are_R_RT():
    """R R^T (any R) Poisson-commutes with every coordinate under the Chetaev bracket."""
    body = ls.EulerPoisson((1, 2, 3))
    z = body.poisson.variables
    R = [[z[3 * i + j] for j in range(3)] for i in range(3)]
    pts = random_points(body, np.random.default_rng(4))
    for a in range(3):
        for b in range(a, 3):
            C = hy.sum([R[a][k] * R[b][k] for k in range(3)])
            assert body.poisson.casimir_residual(C, pts, DPS) < TINY
    # while |M|^2 is conserved by the flow but is not a Casimir: {|M|^2, R_jk} != 0
    M2 = hy.sum([z[9 + i] ** 2 for i in range(3)])
    assert body.poisson.casimir_residual(M2, pts, DPS) > 1e-3


def test_intermediate_rigid_body_bracket_jacobi_on_and_off_the_group():
    """(11.20): the brackets of R and M are a closed subalgebra of the canonical brackets (R, p) -> (R, S, M),
    so the Jacobi identity holds for every invertible R, not only on R^T R = 1. Measured: ~1e-49 at 50 digits."""
    body = ls.EulerPoisson((1, 2, 3), bracket="intermediate")
    rng = np.random.default_rng(5)
    assert body.poisson.jacobi_residual(random_points(body, rng, orthogonal=True), DPS) < TINY
    assert body.poisson.jacobi_residual(random_points(body, rng, orthogonal=False), DPS) < TINY
    assert body.poisson.antisymmetry_residual(random_points(body, rng), DPS) == 0


def test_brackets_agree_on_the_rotation_group_only():
    """(11.20) and (11.20.2) coincide on R^T R = 1 and differ off it."""
    che = ls.EulerPoisson((1, 2, 3))
    inter = ls.EulerPoisson((1, 2, 3), bracket="intermediate")
    rng = np.random.default_rng(6)
    diff = [hy.expression(0.0) + a - b for ra, rb in zip(che.poisson.tensor, inter.poisson.tensor)
            for a, b in zip(ra, rb)]
    on = che.poisson._evaluate(diff, random_points(che, rng, orthogonal=True), DPS)
    off = che.poisson._evaluate(diff, random_points(che, rng, orthogonal=False), DPS)
    # QR in double gives R orthogonal to ~1e-16 only
    assert max(abs(v) for row in on for v in row) < 1e-13
    assert max(abs(v) for row in off for v in row) > 1e-2


@pytest.mark.parametrize("chart", [0, 1, 2])
def test_sphere_dm5_is_poisson_with_casimir_x2(chart):
    s = ls.Sphere(chart=chart)
    pts = random_points(s, np.random.default_rng(7))
    assert s.poisson.antisymmetry_residual(pts, DPS) == 0
    assert s.poisson.jacobi_residual(pts, DPS) < TINY
    assert s.poisson.casimir_residual("x2", pts, DPS) < TINY


def test_sphere_dirac_bracket():
    """Jacobi holds for the Dirac bracket on the constraint surface x . p = 0, where the motion lives; |x|^2 and
    x . p are Casimirs there."""
    d = ls.SphereDirac()
    pts = random_points(d, np.random.default_rng(8), on_sphere=True)
    assert d.poisson.antisymmetry_residual(pts, DPS) == 0
    assert d.poisson.jacobi_residual(pts, DPS) < 1e-10  # points given to ~16 digits: x . p ~ 1e-16
    assert d.poisson.casimir_residual("x2", pts, DPS) < TINY
    assert d.poisson.casimir_residual("xp", pts, DPS) < 1e-10


def test_bracket_of_coordinates_is_the_tensor():
    s = ls.Sphere()
    x1, x2, x3, p1, p2 = s.poisson.variables
    pts = random_points(s, np.random.default_rng(9), k=2)
    e = s.poisson.bracket(x3, p1) + x1 / x3  # {x3, pi1} = -x1/x3
    vals = s.poisson._evaluate([e, s.poisson.bracket(x1, p1) - 1.0, s.poisson.bracket(p1, p2)], pts, DPS)
    assert max(abs(v) for row in vals for v in row) < TINY


def test_poisson_system_bad_input():
    q, p = hy.make_vars("q", "p")
    with pytest.raises(ValueError, match="`tensor` must be 2 x 2"):
        ls.PoissonSystem([q, p], [[0, 1]], p**2)
    with pytest.raises(ValueError, match="runtime parameters"):
        ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], hy.par[0] * p**2)
    with pytest.raises(ValueError, match="distinct"):
        ls.PoissonSystem([q, q], [[0, 1], [-1, 0]], p**2)
    with pytest.raises(ValueError, match="not exact in binary"):
        from fractions import Fraction

        ls.PoissonSystem([q, p], [[0, Fraction(1, 3)], [Fraction(-1, 3), 0]], p**2)


# -- a user's own system: the heavy top on e(3)* ------------------------------------------------------------------
HEAVY_TOP = '''
import heyoka as hy
import lieseries as ls


def make():
    """The heavy top in (M, Gamma) with the Lie-Poisson bracket of e(3)."""
    M1, M2, M3, G1, G2, G3 = hy.make_vars("M1", "M2", "M3", "G1", "G2", "G3")
    M, G = [M1, M2, M3], [G1, G2, G3]
    P = [[0] * 6 for _ in range(6)]
    for i in range(3):
        for j in range(3):
            for k in range(3):
                e = (i - j) * (j - k) * (k - i) // 2
                if e:
                    P[i][j] = -e * M[k]
                    P[i][3 + j] = -e * G[k]
                    P[3 + j][i] = e * G[k]
    H = 0.5 * (hy.par[0] * M1**2 + hy.par[1] * M2**2 + hy.par[2] * M3**2) + hy.par[3] * G3
    return ls.PoissonSystem([M1, M2, M3, G1, G2, G3], P, H,
                            parameters={"a1": 1, "a2": "1/2", "a3": "1/3", "mgl": "0.3"},
                            casimirs={"G2": G1**2 + G2**2 + G3**2, "MG": M1 * G1 + M2 * G2 + M3 * G3},
                            name="heavy top")
'''


def _heavy_top():
    ns = {}
    exec(HEAVY_TOP, ns)
    return ns["make"]()


def test_poisson_system_invariants_read_an_exact_state_exactly():
    from fractions import Fraction as F

    from lieseries.models.base import make_state

    top = _heavy_top()
    y0 = make_state([1, "0.1", "0.5", "0.6", 0, "0.8"])
    inv = top.invariants(y0)
    # by hand: H = (1 + 0.01/2 + 0.25/3)/2 + 0.3 * 0.8, |Gamma|^2 = 1, M.Gamma = 0.6 + 0.4
    H = (1 + F(1, 100) / 2 + F(1, 4) / 3) / 2 + F(3, 10) * F(8, 10)
    with mp.workdps(90):
        assert abs(inv["energy"] - mp.mpf(H.numerator) / H.denominator) < mp.mpf(10) ** -80
        assert abs(inv["G2"] - 1) < mp.mpf(10) ** -80
        assert abs(inv["MG"] - 1) < mp.mpf(10) ** -80
    rows = top.invariants(np.array([[1, 0, 0, 0, 0, 1], [0, 0, 1, 1, 0, 0]], dtype=float))
    assert [float(v) for v in rows["G2"]] == [1.0, 1.0]


def test_python_scene_drift_is_measured_from_the_exact_initial_state(tmp_path):
    """A quad run of a user's heavy top conserves |Gamma|^2 = 1 to ~1e-34; its drift was reported as 4.4e-17 (the
    double rounding of (0.6, 0.8)), the same for every method."""
    from lieseries.run import run_scene
    from lieseries.scenes import load_scene

    (tmp_path / "top.py").write_text(HEAVY_TOP)
    (tmp_path / "top.toml").write_text(
        'name = "top"\ntitle = "heavy top"\n[model]\nkind = "python"\nfile = "top.py"\n[initial]\n'
        'y0 = [1, "0.1", "0.5", "0.6", 0, "0.8"]\n[run]\nt = 2\nsamples = 5\n'
        'methods = [{ method = "taylor", precision = "quad" }, { method = "lie", dps = 30 }]\n')
    res = run_scene(load_scene(str(tmp_path / "top.toml")), progress=False)
    rows = {r.method: r for r in res.run["rows"]}
    assert rows["taylor"].status == "success"
    assert rows["taylor"].drift["G2"] < 1e-32 and rows["taylor"].drift["energy"] < 1e-32
    assert rows["lie"].drift["G2"] < 1e-29
    # independently: |Gamma(t)|^2 of the quad run's final state against the exact 1
    top = _heavy_top()
    sol = ls.integrate(top, [1, "0.1", "0.5", "0.6", 0, "0.8"], t=2, precision="quad")
    assert abs(top.invariants(sol.y[-1])["G2"] - 1) < 1e-32


def test_poisson_system_refuses_what_is_not_a_poisson_system():
    x, y, r = hy.make_vars("x", "y", "r")
    with pytest.raises(ValueError, match=r"`tensor\[0\]\[1\]` and `tensor\[1\]\[0\]` must be opposite"):
        ls.PoissonSystem([x, y], [[0, 1], [1, 0]], x * x + y * y)
    with pytest.raises(ValueError, match=r"`tensor\[0\]\[0\]` must be 0"):
        ls.PoissonSystem([x, y], [[x, 1], [-1, 0]], x * x + y * y)
    # antisymmetric, but not written as each other's negatives: checked numerically, accepted
    ls.PoissonSystem([x, y], [[0, x * y + 1], [-(y * x) - 1, 0]], x * x + y * y)
    with pytest.raises(ValueError, match=r"`hamiltonian` uses `r`, which is not among `variables`"):
        ls.PoissonSystem([x, y], [[0, 1], [-1, 0]], x * x + y * y + r**2)
    with pytest.raises(ValueError, match=r"`tensor\[0\]\[1\]` uses `r`"):
        ls.PoissonSystem([x, y], [[0, r], [-r, 0]], x * x + y * y)
    with pytest.raises(ValueError, match=r"`hamiltonian` depends on time \(heyoka.time\)"):
        ls.PoissonSystem([x, y], [[0, 1], [-1, 0]], x * x + y * y * hy.time)
    # a state variable named t is a variable, not time
    t, p = hy.make_vars("t", "p")
    ls.PoissonSystem([t, p], [[0, 1], [-1, 0]], t * t + p * p)


def test_jacobi_identity_is_checked_at_construction_for_small_systems():
    a, b, c = hy.make_vars("a", "b", "c")
    so3 = [[0, c, -b], [-c, 0, a], [b, -a, 0]]
    ls.PoissonSystem([a, b, c], so3, a * a + b * b + c * c)
    # {a, b} = c, {b, c} = a, {c, a} = a b: by hand, sum_l P_la d_l P_bc + P_lb d_l P_ca + P_lc d_l P_ab
    # = 0 + P_ab * b + 0 = b c != 0
    bad = [[0, c, -a * b], [-c, 0, a], [a * b, -a, 0]]
    with pytest.raises(ValueError, match="does not satisfy the Jacobi identity"):
        ls.PoissonSystem([a, b, c], bad, a * a + b * b + c * c)
    ps = ls.PoissonSystem([a, b, c], bad, a * a + b * b + c * c, jacobi=False)
    assert abs(ps.jacobi_residual([[2, 3, 5]]) - 15) < 1e-40
    with pytest.raises(ValueError, match="Jacobi identity"):
        ps.check_jacobi()


def test_a_structure_undefined_at_the_first_sample_states_is_checked_where_it_is_defined():
    """A tensor defined only for a > 2 (a logarithm of a - 2) was evaluated at no sample state, so nothing was
    checked and a bracket failing the Jacobi identity was accepted: the checks go on to states of other signs and
    scales, and one defined at none of them is refused rather than taken as checked."""
    a, b, c = hy.make_vars("a", "b", "c")
    f = hy.log(a - 2.0)
    # {a, b} = 1, {b, c} = -b f, {c, a} = -a: P_ij = eps_ijk v_k with v = (-b f, a, 1), whose Jacobiator is
    # v . curl v = 1 + f(a) = 1 + log(a - 2): 1 at a = 3, and defined nowhere in the first sample states
    bad = [[0, 1, -a], [-1, 0, -b * f], [a, b * f, 0]]
    with pytest.raises(ValueError, match="does not satisfy the Jacobi identity"):
        ls.PoissonSystem([a, b, c], bad, a * a + b * b + c * c)
    ps = ls.PoissonSystem([a, b, c], bad, a * a + b * b + c * c, jacobi=False)
    assert abs(abs(ps.jacobi_residual([[3, 2, 5]])) - 1) < 1e-40
    # {a, b} = f(a) alone is a Poisson bracket wherever it is defined: accepted
    ls.PoissonSystem([a, b, c], [[0, f, 0], [-f, 0, 0], [0, 0, 0]], a * a + b * b + c * c)
    far = hy.log(a - 1000.0)
    with pytest.raises(ValueError, match=r"cannot be checked.*`jacobi=False`"):
        ls.PoissonSystem([a, b, c], [[0, c * far, -b], [-c * far, 0, a], [b, -a, 0]], a * a + b * b + c * c)
    with pytest.raises(ValueError, match=r"`points`"):
        ps.check_jacobi(points=[[1, 2, 5]])  # log(a - 2) undefined


def test_builtin_brackets_pass_the_explicit_jacobi_check():
    for model in (ls.EulerPoisson((1, 2, 3)), ls.EulerPoisson((1, 2, 3), bracket="intermediate"), ls.Sphere(),
                  ls.SphereDirac()):
        model.poisson.check_jacobi()


def test_a_parameter_the_field_does_not_read_is_accepted_by_every_engine():
    """The oscillator H = p^2/2 + k q^2/2 with a second declared parameter that nothing reads: heyoka counts only
    the parameters an ODE uses and refused the two values. Every engine runs it and follows cos t."""
    import math
    q, p = hy.make_vars("q", "p")
    ps = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 + hy.par[0] * q**2 / 2,
                          parameters={"k": 1, "unused": 2})
    runs = [ls.integrate(ps, [1, 0], t=1), ls.integrate(ps, [1, 0], t=1, precision="quad"),
            ls.lie_integrate(ps, [1, 0], t=1, dps=20)]
    for sol in runs:
        assert sol.status == "success" and abs(float(sol.y[-1][0]) - math.cos(1)) < 1e-14
    ens = ls.integrate(ps, [[1, 0], [0, 1]], t=1)
    assert list(ens.status) == ["success"] * 2 and abs(float(ens.y[1][-1][0]) - math.sin(1)) < 1e-14


def test_a_declared_casimir_that_is_not_one_is_refused():
    """q is no Casimir of the canonical bracket ({q, p} = 1): declaring it is refused naming it; |m|^2 of the
    so(3) bracket is one (it commutes with x, y, z by hand) and is accepted."""
    q, p = hy.make_vars("q", "p")
    with pytest.raises(ValueError, match=r"`casimirs\['fake'\]` is not a Casimir"):
        ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + q**2) / 2, casimirs={"fake": q})
    x, y, z = hy.make_vars("x", "y", "z")
    ps = ls.PoissonSystem([x, y, z], [[0, z, -y], [-z, 0, x], [y, -x, 0]], (x**2 + 2 * y**2 + 3 * z**2) / 2,
                          casimirs={"m2": x**2 + y**2 + z**2})
    from fractions import Fraction
    from lieseries.precision import to_fraction
    assert abs(to_fraction(ps.invariants(["0.1", "0.2", "0.3"], dps=40)["m2"]) - Fraction(14, 100)) < Fraction(1, 10**35)


def test_a_quartic_potential_runs_from_q_equal_zero_in_heyoka():
    """heyoka's ``pow`` recurrence divides by its base: the force -q**3 was NaN from the first step at q = 0
    (``non_finite``). Written as q*q*q it runs; the Lie engine at 40 digits is the reference."""
    q, p = hy.make_vars("q", "p")
    s = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 + q**4 / 4)
    from problems import ctx_mpf, private_ctx

    c = private_ctx(50)
    ref = ls.lie_integrate(s, ["0", "1"], t=1, dps=40)
    assert ref.status == "success"
    for precision, tol in (("double", 1e-14), ("quad", 1e-31)):
        sol = ls.integrate(s, ["0", "1"], t=1, precision=precision)
        assert sol.status == "success", sol.message
        err = max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(sol.y[-1], ref.y[-1]))
        assert err < tol, (precision, err)


def test_powers_as_products_keeps_parameters_and_refuses_to_round_a_constant():
    from lieseries.expr.rewrite import powers_as_products

    q = hy.make_vars("q")
    e = hy.par[0] * q**3 - 0.1 * q**-4
    out, = powers_as_products([e])
    assert "**" not in str(out) and "p0" in str(out)
    # evaluated at q = 0.7, par = 3: the same number
    f_in, f_out = (hy.cfunc([x], [q]) for x in (e, out))
    assert f_in([0.7], pars=[3.0])[0] == pytest.approx(f_out([0.7], pars=[3.0])[0], rel=1e-15)
    # a long double constant would be read back as a double: the expression is kept as it is
    ld = hy.expression(np.longdouble(1) / 3) * q**3
    assert str(powers_as_products([ld])[0]) == str(ld)


def test_coarse_constants_of_a_field_with_shared_subexpressions_are_found_by_walking_the_graph():
    """A Hamiltonian built by 40 doublings (e_{k+1} = e_k * e_k + e_k, with 0.1 at the bottom) is a graph of ~80
    nodes but a tree of ~2^40: the constant 0.1 (53 bits) is found, each distinct node visited once (a walk of the
    tree, sympy's ``atoms``, never ends; a derived rigid body's quad run spent 9 minutes there)."""
    q, p = hy.make_vars("q", "p")
    e = q + 0.1
    for _ in range(40):
        e = e * e + e
    ps = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], e + p * p)
    assert ps.coarse_data() == {"the constant 0.1 in hamiltonian": 53}


def test_programs_are_compiled_once_per_structure_and_hamiltonian():
    """A system built again (a model made anew, `with_parameters`) reuses the compiled field as heyoka writes it
    and the energy's program (1.4-1.8 s and 0.25 s of sympy for a heavy top's intermediate form, paid again by
    every new system object before); a Hamiltonian that differs by a constant has the same field and its own
    energy."""
    from lieseries.energy import energy_exact

    q, p = hy.make_vars("q", "p")
    a = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + q * q / 2)
    b = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + q * q / 2)
    c = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + q * q / 2 + 3.0)
    assert a.written_program is b.written_program is c.written_program
    assert a.key == c.key
    h_a, h_c = energy_exact(a, [1, 2], 100)[0], energy_exact(c, [1, 2], 100)[0]
    assert (h_a, h_c) == (mp.mpf("2.5"), mp.mpf("5.5"))
    assert energy_exact(b, [1, 2], 100)[0] == h_a
