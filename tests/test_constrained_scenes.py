"""Scenes of the constrained models: the kinds heavy_top, spherical_pendulum, planar_pendulum,
double_spherical_pendulum, ellipsoid_geodesic and constrained (a Lagrangian with constraints written in the scene),
their refusals at load time, and the built-in scenes heavy-top, spherical-pendulum and ellipsoid-geodesic against independent
references (mpmath's odefun on equations written here, conservation laws)."""

from fractions import Fraction

import mpmath
import pytest

import lieseries as ls
from lieseries.cli import main
from lieseries.run import run_scene
from lieseries.scenes import SceneError, load_scene, parse_scene

HEAD = 'name = "t"\ntitle = "t"\n'
RUN = '[run]\nt = "0.5"\nsamples = 3\nmethods = [{ method = "taylor", precision = "double" }]\n'

SPHERE = """
[model]
kind = "constrained"
lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z"
coordinates = ["x", "y", "z"]
constraints = ["x**2 + y**2 + z**2 - l**2"]
parameters = { m = 1, g = "9.81", l = 1 }
[initial]
q = ["0.6", 0, "-0.8"]
qdot = [0, 2, 0]
"""


def _fr(v):
    return Fraction(str(v)) if not isinstance(v, Fraction) else v


def test_each_builtin_constrained_kind_builds_its_model_from_the_scene():
    """Each kind builds the model with the scene's exact parameters, and [initial] q, qdot gives (q, m qdot)."""
    cases = [
        ('kind = "spherical_pendulum"\nlength = 1\nmass = 2\ng = "9.81"', ls.SphericalPendulum,
         'q = ["0.6", 0, "-0.8"]\nqdot = [0, 2, 0]', 2),
        ('kind = "planar_pendulum"\nlength = 1\nmass = 3\ng = "9.81"', ls.PlanarPendulum,
         'q = ["0.6", "-0.8"]\nqdot = ["0.8", "0.6"]', 3),
        ('kind = "ellipsoid_geodesic"\naxes = [1, 2, 3]', ls.EllipsoidGeodesic,
         'q = ["2/7", "6/7", "18/7"]\nqdot = [1, 0, -1]', 1),
        ('kind = "double_spherical_pendulum"\nm2 = 2\ng = "9.81"', ls.DoubleSphericalPendulum,
         'q = ["0.6", 0, "-0.8", "0.6", "0.6", "-1.6"]\nqdot = [0, 1, 0, 1, 1, 0]', None),
    ]
    for model, cls, initial, mass in cases:
        sc = parse_scene(HEAD + "[model]\n" + model + "\n[initial]\n" + initial + "\n" + RUN)
        (_lab, m), = sc.build_models()
        assert isinstance(m, cls)
        y0 = sc.initial_state(m)
        q = [Fraction(v) for v in initial.split("\n")[0].split("=")[1].strip(" []").replace('"', "").split(", ")]
        v = [Fraction(x) for x in initial.split("\n")[1].split("=")[1].strip(" []").replace('"', "").split(", ")]
        masses = [mass] * len(q) if mass is not None else [1, 1, 1, 2, 2, 2]
        assert list(y0.exact) == q + [mk * vk for mk, vk in zip(masses, v)]  # p = m qdot, exact
    assert m.parameter_values["m2"] == 2 and m.parameter_values["g"] == Fraction(981, 100)


def test_a_binary_parameter_of_a_constrained_scene_is_listed_with_the_binary_data():
    """parameters = { g = 9.81 } is the double 9.81 (TOML): the runs warned of it, but the scene's binary data (and
    so its report's note on which problem its errors are measured against) left it out: the parameters table was
    not among the kind's data. g = "9.81" and g = 10 are exact."""
    text = HEAD + SPHERE + RUN
    assert parse_scene(text.replace('g = "9.81"', "g = 9.81")).binary_inputs() == {"model.parameters.g": 53}
    note = parse_scene(text.replace('g = "9.81"', "g = 9.81")).binary_note()
    assert "`model.parameters.g`" in note and "binary data" in note
    assert parse_scene(text).binary_inputs() == {}
    assert parse_scene(text.replace('g = "9.81"', "g = 10")).binary_inputs() == {}


def test_heavy_top_kind_reads_com_mass_g_and_the_rigid_body_initial_data():
    sc = parse_scene(HEAD + '[model]\nkind = "heavy_top"\ninertia = [2, 2, 1]\ncom = [0, 0, "0.5"]\nmass = 3\n'
                     'g = "9.81"\n[initial]\nomega = [1, "0.5", 5]\n' + RUN)
    (_lab, m), = sc.build_models()
    assert isinstance(m, ls.HeavyTop) and m.case == "lagrange"
    assert m.com_exact == [0, 0, Fraction(1, 2)] and m.mass_exact == 3 and m.g_exact == Fraction(981, 100)
    y0 = sc.initial_state(m)
    assert list(y0.exact[9:]) == [2, 1, 5]  # M = I Omega
    with pytest.raises(SceneError, match="`model.com`"):
        parse_scene(HEAD + '[model]\nkind = "heavy_top"\ninertia = [2, 2, 1]\ncom = [0, 0]\n[initial]\n'
                    'omega = [1, 0, 0]\n' + RUN)


@pytest.mark.parametrize("formulation, extra, dim", [
    ("dirac", "", 6),
    pytest.param("reduced", 'dependent = ["z"]', 5, marks=pytest.mark.slow),  # derivations of 10-20 s
    pytest.param("intermediate", "", 5, marks=pytest.mark.slow),
    ("local", 'chart = { z = "-sqrt(l**2 - x**2 - y**2)" }', 4)])
def test_constrained_kind_runs_each_formulation_along_the_same_motion(formulation, extra, dim):
    """The four formulations of the spherical pendulum from the scene's strings follow one motion: the final
    configuration agrees with mpmath's odefun on the Cartesian equations with the rod's tension (written here)."""
    text = HEAD + SPHERE.replace("[initial]", f'formulation = "{formulation}"\n{extra}\n[initial]') + RUN
    sc = parse_scene(text)
    (_lab, m), = sc.build_models()
    assert m.poisson.dimension == dim
    sol = ls.integrate(m, sc.initial_state(m), t=Fraction(1, 2), precision="double")
    assert sol.status == "success"
    q = [float(v) for v in m.configuration(sol)[-1]]
    ref = _pendulum_reference(Fraction(1, 2))
    assert max(abs(a - float(b)) for a, b in zip(q, ref[:3])) < 1e-13


def _pendulum_reference(t, dps=30):
    """x(t) of the spherical pendulum (m = l = 1, g = 9.81, x0 = (0.6, 0, -0.8), v0 = (0, 2, 0)) from
    x'' = -g e_z + lambda x, lambda = -(|v|^2 - g z) / |x|^2 (the rod's tension), by mpmath's odefun."""
    with mpmath.workdps(dps):
        g = mpmath.mpf(981) / 100

        def f(_t, y):
            x, v = y[:3], y[3:]
            lam = -(sum(c * c for c in v) - g * x[2]) / sum(c * c for c in x)
            return [v[0], v[1], v[2], lam * x[0], lam * x[1], lam * x[2] - g]

        sol = mpmath.odefun(f, 0, [mpmath.mpf(3) / 5, 0, -mpmath.mpf(4) / 5, 0, 2, 0])
        return [+c for c in sol(mpmath.mpf(t.numerator) / t.denominator)]


BAD = [
    # (replace, by, field, what the message says)
    ('lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z"', 'lagrangian = "m/2*(x_dot**2 + y_dot**2) - m*g*z"',
     "model.lagrangian", "singular"),
    ('lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z"',
     'lagrangian = "m/2*(x_dot**2 + y_dot**2 - z_dot**2) - m*g*z"', "model.lagrangian", "positive definite"),
    ('constraints = ["x**2 + y**2 + z**2 - l**2"]',
     'constraints = ["x**2 + y**2 + z**2 - l**2", "2*(x**2 + y**2 + z**2 - l**2)"]', "model.constraints",
     "dependent"),
    ('constraints = ["x**2 + y**2 + z**2 - l**2"]', 'constraints = ["x**2 + y**2 + z**2 - l**2 + x_dot"]',
     "model.constraints[0]", "velocities"),
    ('lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z"',
     'lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2 - m*g*z"', "model.lagrangian", "could not be read"),
    ('lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z"',
     'lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - M*g*z"', "model.lagrangian", "`M`"),
    ('parameters = { m = 1, g = "9.81", l = 1 }', 'parameters = { m = "heavy", g = "9.81", l = 1 }',
     "model.parameters.m", "number"),
    ('[initial]', 'formulation = "local"\n[initial]', "model.chart", "required"),
    ('[initial]', 'formulation = "local"\nchart = { z = "-sqrt(l**2 - x**2)" }\n[initial]', "model.chart",
     "does not solve"),
    ('[initial]', 'chart = { z = "-sqrt(l**2 - x**2 - y**2)" }\n[initial]', "model.chart", "'local' only"),
    ('[initial]', 'formulation = "lagrange"\n[initial]', "model.formulation", "one of"),
    ('lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z"',
     'lagrangian = "m/2*(x_dot**4 + y_dot**2 + z_dot**2) - m*g*z"', "model.lagrangian", "quadratic"),
    ('constraints = ["x**2 + y**2 + z**2 - l**2"]', 'constraints = "x**2 + y**2 + z**2 - l**2"', "model.constraints",
     "list"),
    ('[initial]', 'formulation = "reduced"\ndependent = ["w"]\n[initial]', "model.dependent", "coordinates"),
]


@pytest.mark.parametrize("old, new, field, what", BAD)
def test_constrained_kind_refuses_bad_input_at_load_naming_the_field(old, new, field, what):
    text = HEAD + SPHERE + RUN
    assert old in text
    with pytest.raises(SceneError) as err:
        parse_scene(text.replace(old, new, 1))
    msg = str(err.value)
    assert f"`{field}" in msg and what in msg, msg


def test_a_second_model_is_named_by_its_table():
    text = HEAD + SPHERE.replace("[model]", '[[models]]\nlabel = "a"').replace("[initial]", "").replace(
        'q = ["0.6"', '[initial]\nq = ["0.6"') + RUN
    bad = text.replace("[[models]]", '[[models]]\nlabel = "b"\nkind = "spherical_pendulum"\n\n[[models]]', 1)
    bad = bad.replace('m/2*(x_dot**2 + y_dot**2 + z_dot**2)', 'm/2*(x_dot**2 + y_dot**2)')
    with pytest.raises(SceneError, match=r"`models\[1\]\.lagrangian` is singular"):
        parse_scene(bad)


def test_cli_exits_2_on_a_bad_constrained_scene_before_computing(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(HEAD + SPHERE.replace("- m*g*z", "- m*g*w") + RUN)
    assert main(["run", str(path), "--out", str(tmp_path / "rep"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "`model.lagrangian`" in err and "`w`" in err and "Traceback" not in err
    assert not (tmp_path / "rep").exists()


# -- the built-in scenes in quick mode -------------------------------------------------------------------------------
def _eps(row):
    return {"double": 2.0**-52, "quad": 2.0**-112}.get(getattr(row, "precision", None), None)


def _check_drifts(res, kinds):
    """Each invariant kept to a small multiple of its run's precision (heyoka double and quad, Lie at 30 digits)."""
    rows = res.run["rows"]
    assert [r.status for r in rows] == ["success"] * 3
    tol = [2.0**-52, 2.0**-112, 1e-30]  # the scene's methods, in order
    for r, eps in zip(rows, tol):
        assert set(r.drift) == kinds
        for name, d in r.drift.items():
            assert d <= 64 * eps, (r.method, name, d)
    return rows


@pytest.mark.slow
def test_builtin_heavy_top_scene_against_odefun_and_its_invariants():
    """heavy-top in quick mode (t = 1): the final M and Gamma of each run against mpmath's odefun on the heavy
    top's Euler-Poisson equations (written here, 30 digits); energy, L3, M3 (Lagrange top), R R^T kept."""
    res = run_scene(load_scene("heavy-top"), quick=True, progress=False)
    rows = _check_drifts(res, {"energy", "L3", "M3", "orthogonality", "det_R"})
    with mpmath.workdps(30):
        inv = [mpmath.mpf(1) / 2, mpmath.mpf(1) / 2, mpmath.mpf(1)]
        w = [0, 0, mpmath.mpf(981) / 200]  # mass g com

        def cross(a, b):
            return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

        def f(_t, y):
            M, G = y[:3], y[3:]
            om = [i * m for i, m in zip(inv, M)]
            return [a + b for a, b in zip(cross(M, om), cross(G, w))] + cross(G, om)

        sol = mpmath.odefun(f, 0, [2, 1, 5, 0, mpmath.mpf(3) / 5, mpmath.mpf(4) / 5])
        ref = [float(c) for c in sol(1)]
        ref_study = [float(c) for c in sol(mpmath.mpf(2) / 5)]  # the formulations study: t = 2/5 in quick mode
    for r, tol in zip(rows, (1e-13, 1e-14, 1e-14)):
        y = [float(c) for c in r.final_state]
        got = y[9:] + y[6:9]
        assert max(abs(a - b) for a, b in zip(got, ref)) < tol, (r.method, got, ref)
    assert res.run["rows"][1].error < 1e-30  # quad against the 256-bit reference run
    # the same top derived from R (Dirac, 18 variables; intermediate, 12): Gamma = third row of R against odefun,
    # the error against the 256-bit Dirac reference at each precision, the constraints kept
    (_lab, comp), = res.studies["formulations"]
    assert [(r.formulation, r.status, r.t) for r in comp.rows] == [
        (f, "success", 0.4) for f in ("dirac", "intermediate") for _ in range(3)]
    for r, tol in zip(comp.rows, (1e-14, 1e-31, 1e-29) * 2):
        assert max(abs(a - b) for a, b in zip(r.q[6:9], ref_study[3:])) < 1e-14, (r.formulation, r.method)
        assert r.error < tol and r.G < tol and r.Phi < 10 * tol, (r.formulation, r.method, r.error, r.G, r.Phi)


@pytest.mark.slow
def test_builtin_spherical_pendulum_scene_against_odefun_and_its_invariants():
    """spherical-pendulum in quick mode (t = 1): the final position of each run against mpmath's odefun on the
    Cartesian equations with the rod's tension; energy, G, Phi, L3 kept to each precision."""
    res = run_scene(load_scene("spherical-pendulum"), quick=True, progress=False)
    rows = _check_drifts(res, {"energy", "G1", "Phi1", "L3"})
    ref = [float(c) for c in _pendulum_reference(Fraction(1))]
    for r in rows:
        y = [float(c) for c in r.final_state]
        assert max(abs(a - b) for a, b in zip(y[:3], ref[:3])) < 1e-13, (r.method, y, ref)


# -- the formulations study ------------------------------------------------------------------------------------------
def _great_circle(t):
    """x(t), v(t) on the unit sphere from x0 = (0.6, 0, 0.8), v0 = (0, 1, 0): a great circle."""
    c, s = mpmath.cos(t), mpmath.sin(t)
    return [0.6 * c, s, 0.8 * c], [-0.6 * s, c, -0.8 * s]


@pytest.mark.slow  # the two derivations take ~5 s
def test_formulations_dirac_and_local_chart_follow_the_great_circle_and_the_chart_ends_where_z_is_small():
    """The Dirac form runs to t = 2; the local chart z = sqrt(1 - x^2 - y^2) stops at its edge (|z| = 0.05 |x|, so
    0.8 cos t = 0.05: t = acos(1/16) = 1.508...). Both agree with the great circle where they ran."""
    from lieseries.studies.formulations import compare_formulations

    sphere = ls.ConstrainedSystem("(x_dot**2 + y_dot**2 + z_dot**2)/2", ["x", "y", "z"], ["x**2 + y**2 + z**2 - 1"])
    res = compare_formulations(sphere, ("0.6", 0, "0.8"), (0, 1, 0), 2, [{"method": "taylor", "precision": "double"}],
                               formulations=("dirac", "local"), chart={"z": "sqrt(1 - x**2 - y**2)"}, samples=5)
    dirac, local = res.rows
    assert (dirac.status, dirac.t) == ("success", 2.0)
    assert local.status == "chart_edge" and abs(local.t - float(mpmath.acos(mpmath.mpf(1) / 16))) < 1e-6
    for r in res.rows:
        x, v = _great_circle(r.t)
        assert max(abs(a - float(b)) for a, b in zip(r.q + r.qdot, x + v)) < 1e-13, r
        assert r.error < 1e-13 and r.G < 1e-14 and r.Phi < 1e-14 and r.energy < 1e-14


@pytest.mark.slow
def test_formulations_study_in_a_scene_all_four_on_the_great_circle(tmp_path):
    """[studies.formulations] in a scene with kind = "constrained": the four formulations by heyoka (double, quad)
    and the Lie series (30 digits), each against the great circle to its precision; the report has its table."""
    from lieseries.report import write_report

    text = HEAD + """
[model]
kind = "constrained"
lagrangian = "(x_dot**2 + y_dot**2 + z_dot**2)/2"
coordinates = ["x", "y", "z"]
constraints = ["x**2 + y**2 + z**2 - 1"]
[initial]
q = ["0.6", 0, "0.8"]
qdot = [0, 1, 0]
[studies.formulations]
t = "1.2"
chart = { z = "sqrt(1 - x**2 - y**2)" }
"""
    from lieseries.cost import estimate_scene

    est = estimate_scene(parse_scene(text))  # the study prices each formulation by each method
    priced = [p.what for p in est.parts if p.field == "studies.formulations.t" and " by " in p.what]
    assert not est.lower_bound and len(priced) == 12, [p.what for p in est.parts]
    res = run_scene(parse_scene(text), progress=False)
    (_lab, comp), = res.studies["formulations"]
    assert {r.formulation for r in comp.rows} == {"dirac", "reduced", "intermediate", "local"}
    assert len(comp.rows) == 12
    tol = {"heyoka double": 1e-14, "heyoka quad": 1e-31, "Lie series 30 dps": 1e-28}
    with mpmath.workdps(40):
        x, v = _great_circle(mpmath.mpf(6) / 5)
    for r in comp.rows:
        assert r.status == "success" and r.t == 1.2
        assert max(abs(a - float(b)) for a, b in zip(r.q + r.qdot, x + v)) < max(tol[r.method], 1e-15), r
        assert r.error < tol[r.method] and r.G < tol[r.method] and r.Phi < tol[r.method], r
    assert res.unsuccessful() == []
    write_report(res, tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## Formulations compared" in md and "| intermediate |" in md


def test_formulations_study_refuses_a_model_without_constraints_and_local_without_chart():
    top = HEAD + ('[model]\nkind = "heavy_top"\ninertia = [2, 2, 1]\ncom = [0, 0, "0.5"]\n[initial]\n'
                  'omega = [1, 0, 5]\n[studies.formulations]\nt = 1\n')
    with pytest.raises(SceneError, match=r"`studies.formulations.chart` is required .* with 6 constraints give "
                                         r'formulations = \["dirac", "intermediate"\]'):
        parse_scene(top)  # the defaults, all four: the chart a top cannot have was asked for, with no way out
    with pytest.raises(SceneError, match=r"reduced\(\): a system with 6 constraints"):
        parse_scene(top + 'formulations = ["dirac", "reduced"]\n')  # the top derived from R: no reduced form
    damped = HEAD + ('[model]\nkind = "damped_euler_poisson"\ninertia = [1, 2, 3]\ndamping = 1\n[initial]\n'
                     'omega = [1, 0, 5]\n[studies.formulations]\nt = 1\nformulations = ["dirac"]\n')
    with pytest.raises(SceneError, match="`model`: a damped rigid body has no constrained_system"):
        parse_scene(damped)
    with pytest.raises(SceneError, match="`model`: a damped rigid body has no constrained_system"):
        parse_scene(damped.replace('formulations = ["dirac"]\n', ''))  # was told to give a chart first
    sphere = HEAD + ('[model]\nkind = "sphere"\n[initial]\nx = ["0.6", 0, "0.8"]\nv = [0, 1, 0]\n'
                     '[studies.formulations]\nt = 1\nformulations = ["dirac"]\n')
    with pytest.raises(SceneError, match="`model` is not one"):
        parse_scene(sphere)
    with pytest.raises(SceneError, match=r"`studies.formulations.formulations\[1\]` must be one of"):
        parse_scene(top + 'formulations = ["dirac", "chart"]\n')


def test_formulations_measures_quad_constraint_residuals_at_quad_precision():
    """A rod of length 0.3 (not a binary number): |G| and |Phi| of a quad run are measured to quad's level, not
    to the 15 digits of mpmath's default context (independent: G from the final q in exact arithmetic here)."""
    from lieseries.studies.formulations import compare_formulations

    pend = ls.ConstrainedSystem("m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z", ["x", "y", "z"],
                                ["x**2 + y**2 + z**2 - l**2"], parameters={"m": 1, "g": "9.81", "l": "0.3"})
    res = compare_formulations(pend, ("0.18", 0, "-0.24"), (0, 1, 0), "0.5", [{"method": "taylor", "precision": "quad"}],
                               formulations=("dirac",), samples=3)
    row, = res.rows
    assert row.status == "success" and row.G < 1e-31 and row.Phi < 1e-31 and row.error < 1e-31
    # the final point, as floats, is on the sphere of radius 0.3 to double rounding
    assert abs(sum(c * c for c in row.q) - 0.09) < 1e-15


def _geodesic_reference(t, dps=30):
    """(x, xdot) at t of the geodesic on x^2 + y^2/4 + z^2/9 = 1 from q0 = (2/7, 6/7, 18/7), qdot0 = (1, 0, -1), by
    mpmath's odefun on x'' = -mu n, n = (x/a^2, y/b^2, z/c^2), mu = sum v_i^2/a_i^2 / |n|^2 (G'' = 0; written here)."""
    with mpmath.workdps(dps):
        w = [mpmath.mpf(1), mpmath.mpf(1) / 4, mpmath.mpf(1) / 9]

        def f(_t, y):
            x, v = y[:3], y[3:]
            n = [xi * wi for xi, wi in zip(x, w)]
            mu = sum(vi * vi * wi for vi, wi in zip(v, w)) / sum(c * c for c in n)
            return list(v) + [-mu * c for c in n]

        sol = mpmath.odefun(f, 0, [mpmath.mpf(2) / 7, mpmath.mpf(6) / 7, mpmath.mpf(18) / 7, 1, 0, -1])
        return [+c for c in sol(mpmath.mpf(t.numerator) / t.denominator)]


@pytest.mark.slow
def test_builtin_ellipsoid_geodesic_scene_against_odefun_in_each_formulation():
    """ellipsoid-geodesic in quick mode (run to t = 1, formulations to t = 0.4): the final (q, qdot) of every run
    of every formulation against mpmath's odefun on the Cartesian geodesic equations; Joachimsthal's integral, the
    energy, G and Phi kept to each precision; the radius table has a row per formulation."""
    res = run_scene(load_scene("ellipsoid-geodesic"), quick=True, progress=False)
    rows = _check_drifts(res, {"energy", "G1", "Phi1", "joachimsthal"})
    ref = [float(c) for c in _geodesic_reference(Fraction(1))]
    for r in rows:
        y = [float(c) for c in r.final_state]
        assert max(abs(a - b) for a, b in zip(y, ref)) < 1e-13, (r.method, y, ref)  # p = qdot (unit mass)
    (_lab, comp), = res.studies["formulations"]
    ref = [float(c) for c in _geodesic_reference(Fraction(2, 5))]
    assert len(comp.rows) == 12 and {r.status for r in comp.rows} == {"success"}
    for r in comp.rows:
        assert max(abs(a - b) for a, b in zip(r.q + r.qdot, ref)) < 1e-14, r
    assert [r.formulation for r in comp.radii] == ["dirac", "reduced", "intermediate", "local"]


def test_the_formulations_study_prices_each_formulation_by_each_method_for_the_scene_estimate():
    from lieseries.cost import estimate_scene

    text = HEAD + """
[model]
kind = "constrained"
lagrangian = "(x_dot**2 + y_dot**2)/2"
coordinates = ["x", "y"]
constraints = ["x**2 + y**2 - 1"]
[initial]
q = ["0.6", "0.8"]
qdot = ["-0.8", "0.6"]
[studies.formulations]
t = "0.5"
formulations = ["dirac", "local"]
chart = { y = "sqrt(1 - x**2)" }
methods = [{ method = "taylor", precision = "double" }, { method = "lie", dps = 20 }]
radius_t = "0.1"
radius_max_order = 8
"""
    est = estimate_scene(parse_scene(text))
    parts = {p.what: p for p in est.parts if p.field.startswith("studies.formulations")}
    assert not est.lower_bound, parts
    for name in ("dirac", "local"):
        for label in ("heyoka double", "Lie series 20 dps"):
            assert parts[f"10 sample intervals of {name} by {label}"].seconds > 0
        assert parts[f"{name}: a Lie series to order 8 at 40 digits"].seconds > 0
    assert "the reference (Dirac, heyoka 256 bits)" in parts
