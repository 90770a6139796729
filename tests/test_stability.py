"""The extreme and stiff cases (lieseries/data/scenes/extreme/) and the stability study: every case runs (quick) and its
report holds what it asks for; the numbers are checked against independent references (closed forms, heyoka at
256 bits, the saddle's rate lambda from the principal moments, the pole distance of the elliptic functions)."""

import json
import math
import re

import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.precision import to_fraction
from lieseries.report import SECTION_TITLES, write_report, write_stability_report
from lieseries.run import run_scene, scaled_error
from lieseries.scenes import (
    SceneError,
    builtin_scenes,
    effective_plan,
    extreme_scenes,
    load_scene,
    parse_scene,
)
from lieseries.stability import saddle_rate, stability

EXTREME = [name for name, _ in extreme_scenes()]


#: Cases run in the default suite (about 5 s in quick mode); the others run with `make test-all` (slow).
FAST = ["damped-stiff", "unstable-axis", "unstable-axis-principal", "sphere-atlas"]


@pytest.fixture(scope="module")
def quick():
    """The FAST cases in quick mode, run once for the module."""
    return stability(cases=FAST, quick=True)


@pytest.fixture(scope="module")
def quick_all():
    """Every case in quick mode, run once for the module (about 20 s: slow tests only)."""
    return stability(quick=True)


# -- the scenes ------------------------------------------------------------------------------------------------
def test_extreme_scenes_are_apart_from_the_builtins():
    """The cases are listed by extreme_scenes(), found by name, and kept out of builtin_scenes() (whose runs must
    all succeed)."""
    assert {"separatrix-near", "separatrix-exact", "unstable-axis", "unstable-axis-principal", "inertia-extreme",
            "body-nearly-flat", "body-nearly-symmetric", "spin-fast", "spin-slow", "sphere-huge", "sphere-tiny",
            "long-run", "damped-mild", "damped-stiff", "lie-divergence", "sphere-atlas"} <= set(EXTREME)
    assert not set(EXTREME) & {name for name, _ in builtin_scenes()}
    for name in EXTREME:
        sc = load_scene(name)
        assert sc.name == name and sc.title and sc.description and sc.stability is not None


#: Cases that are deliberately no physical body (moments violating the triangle inequality).
NONPHYSICAL = {"inertia-ratios"}


def test_extreme_scenes_are_physical_except_the_declared_one():
    """Only the declared case uses moments violating the triangle inequality, and the model warns about it."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in EXTREME:
            if name not in NONPHYSICAL:
                load_scene(name).build_models()
    for name in NONPHYSICAL:
        with pytest.warns(UserWarning, match="triangle inequality"):
            load_scene(name).build_models()


RIGID = """
name = "t"
title = "test"
[model]
kind = "euler_poisson"
inertia = [1, 2, 3]
[initial]
omega = [1, "0.1", "0.5"]
[run]
t = 2
samples = 11
methods = [{ method = "taylor", precision = "double" }, { method = "taylor", precision = "quad" }]
"""


def test_stability_table_validation():
    sc = parse_scene(RIGID + '[stability]\nanalysis = "scaled"\n')
    assert sc.stability["headline"] == "heyoka double" and sc.stability["headline_model"] == "rigid body"
    assert sc.stability["expect"] == "success"
    with pytest.raises(SceneError, match="`stability.headline` must be the label of one of the run's methods"):
        parse_scene(RIGID + '[stability]\nheadline = "heyoka single"\n')
    with pytest.raises(SceneError, match="`stability.analysis`"):
        parse_scene(RIGID + '[stability]\nanalysis = "chaos"\n')
    with pytest.raises(SceneError, match="`stability.expect`"):
        parse_scene(RIGID + '[stability]\nexpect = "exploded"\n')
    with pytest.raises(SceneError, match="add 'trajectory'"):
        parse_scene(RIGID + '[stability]\nanalysis = "saddle"\n')
    with pytest.raises(SceneError, match="needs a \\[studies.drift\\] table"):
        parse_scene(RIGID + '[stability]\nanalysis = "drift"\n')
    with pytest.raises(SceneError, match="`stability.invariants\\[1\\]`: unknown invariant 'x2'"):
        parse_scene(RIGID + '[stability]\ninvariants = ["energy", "x2"]\n')
    with pytest.raises(SceneError, match="unknown field `stability.treshold`"):
        parse_scene(RIGID + '[stability]\ntreshold = 1\n')


def test_damped_model_kind_and_quick_time():
    text = RIGID.replace('kind = "euler_poisson"', 'kind = "damped_euler_poisson"\ndamping = "0.5"')
    sc = parse_scene(text.replace("samples = 11", "samples = 11\nquick_t = 1"))
    (label, model), = sc.build_models()
    assert isinstance(model, ls.DampedEulerPoisson) and model.damping == to_fraction("0.5")
    assert label == "damped rigid body"
    run, _ = effective_plan(sc, quick=True)
    assert run["t"] == 1 and sc.run["t"] == 2
    with pytest.raises(SceneError, match="missing required field `model.damping`"):
        parse_scene(RIGID.replace('kind = "euler_poisson"', 'kind = "damped_euler_poisson"'))
    with pytest.raises(SceneError, match="`model.damping` must be a number >= 0"):
        parse_scene(text.replace('damping = "0.5"', "damping = -1"))


def test_damped_body_is_measured_against_a_256_bit_run_not_the_free_body():
    """The damped body is an EulerPoisson subclass; its reference must not be the free body's closed form."""
    text = RIGID.replace('kind = "euler_poisson"', 'kind = "damped_euler_poisson"\ndamping = 1')
    res = run_scene(parse_scene(text), progress=False)
    assert "256 bits" in res.run["reference"]
    body = ls.DampedEulerPoisson((1, 2, 3), damping=1)
    # independent of the scene's 256-bit reference: a quad run (1e-34 here), far below the double error checked
    ref = ls.integrate(body, body.initial_state((1, "0.1", "0.5"), precision="quad"), t=[2]).y[-1]
    dbl = next(r for r in res.run["rows"] if r.label == "heyoka double")
    direct = ls.integrate(body, body.initial_state((1, "0.1", "0.5")), t=[2]).y[-1]
    err = max(abs(float(to_fraction(a)) - float(to_fraction(b))) for a, b in zip(direct, ref))
    assert dbl.error == pytest.approx(err, rel=0.5, abs=1e-16) and dbl.error < 1e-14
    free = ls.EulerPoisson((1, 2, 3))
    yf = ls.integrate(free, free.initial_state((1, "0.1", "0.5")), t=[2]).y[-1]
    assert max(abs(float(a) - float(to_fraction(b))) for a, b in zip(yf, ref)) > 1e-3  # the damping matters


def test_scaled_error_uses_each_quantity_scale():
    body = ls.EulerPoisson((1, 2, 3))
    ref = [mp.mpf(0)] * 9 + [mp.mpf(3e6), mp.mpf(4e6), mp.mpf(0)]
    run = list(ref)
    run[0] += mp.mpf("1e-9")  # R: against 1
    run[10] += mp.mpf("1e-3")  # M: against |M| = 5e6, so 2e-10 (the error of R is the larger)
    assert scaled_error(body, run, ref) == pytest.approx(1e-9)
    run[10] = ref[10] + 100
    assert scaled_error(body, run, ref) == pytest.approx(100 / 5e6)
    sphere = ls.Sphere(radius="1e8")
    ref = [mp.mpf(6e7), 0, mp.mpf(8e7), 0, mp.mpf(1), 0]
    run = [ref[0] + 1, 0, ref[2], 0, mp.mpf(1) + mp.mpf("1e-12"), 0]
    assert scaled_error(sphere, run, ref) == pytest.approx(1e-8)


def test_precision_eps_and_saddle_rate():
    P = ls.precision.Precision
    assert P.of("double").eps == 2.0**-52 and P.of("quad").eps == 2.0**-112
    assert P.of(256).eps == 2.0**-255 and P.of(dps=30).eps == 1e-30
    assert P.of(dps=30, guard_digits=10).working_eps == pytest.approx(1e-40)
    assert P.of(dps=30, guard_bits=32).working_eps == pytest.approx(1e-30 * 2.0**-32)
    body = ls.EulerPoisson((3, 4, 6))
    y0 = body.initial_state(("1/512", -1, "1/1024"))
    lam = exact.rigid_body_constants((3, 4, 6), ("1/512", -1, "1/1024")).lam  # on the separatrix: the saddle's rate
    assert saddle_rate(body, y0) == pytest.approx(float(lam), rel=1e-12)


# -- every case, quick -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", [pytest.param(n, marks=() if n in FAST else pytest.mark.slow) for n in EXTREME])
def test_case_runs_quick_and_its_report_has_what_it_asks_for(request, name, tmp_path):
    case = request.getfixturevalue("quick" if name in FAST else "quick_all").case(name)
    scene = load_scene(name)
    assert case.rows, case.notes
    assert case.as_expected, (case.headline.status, case.headline.message)
    head = case.headline
    assert head.method == scene.stability["headline"] and head.model == scene.stability["headline_model"]
    # one row per method and model of the scene's run, each with what the run table asks for
    assert len(case.rows) == len(scene.run["methods"]) * len(scene.models)
    for r in case.rows:
        assert r.steps is None or r.steps > 0
        assert r.run_time is not None and r.run_time > 0 and r.status and r.message
        assert r.error is not None and math.isfinite(r.error)
        assert r.scaled_error is not None and math.isfinite(r.scaled_error)
        assert r.max_drift is not None and math.isfinite(r.max_drift)
        if r.method.startswith("heyoka"):
            assert r.order >= 20
    assert case.finding
    # the scene's own report
    write_report(case.result, tmp_path)
    md = (tmp_path / "report.md").read_text()
    heads = set(re.findall(r"^## (.+)$", md, flags=re.M))
    assert SECTION_TITLES["run"] in heads
    assert "relative error" in md and f"{head.error:.2e}" in md
    for study in ("error_vs_order", "work_precision", "drift"):
        assert (SECTION_TITLES[study] in heads) == (study in scene.studies)
    for plot in scene.plots:
        assert (tmp_path / f"{plot}.png").is_file(), plot
    data = json.loads((tmp_path / "data.json").read_text())
    assert data["scene"]["stability"]["analysis"] == scene.stability["analysis"]


def test_stiff_case_stops_quickly_and_says_stiff(quick):
    case = quick.case("damped-stiff")
    for r in case.rows:  # double and quad alike
        assert r.status == "step_collapse"
        assert "stiff" in r.message
        assert r.t < 0.1 < r.t_requested  # stopped soon after the relaxation, long before T = 10
        m = re.search(r"near t = ([0-9.e+-]+) \(last step size ([0-9.e+-]+)\)", r.message)
        assert m, r.message
        assert float(m.group(1)) == pytest.approx(r.t, rel=1e-12)
        assert 1e-7 < float(m.group(2)) < 1e-4
        assert r.steps < 2000
        assert r.error < 1e3 * r.precision.eps  # right up to where it stopped (256-bit reference)
    head = case.headline
    assert head.method == "heyoka double"
    h = float(re.search(r"last step size ([0-9.e+-]+)", head.message).group(1))
    assert case.details["last_step"] == pytest.approx(h, rel=1e-12)
    assert case.details["t_reached"] == head.t


@pytest.mark.parametrize("name", ["unstable-axis", pytest.param("separatrix-near", marks=pytest.mark.slow),
                                  pytest.param("separatrix-exact", marks=pytest.mark.slow)])
def test_saddle_cases_quad_beats_double_and_errors_grow_at_the_saddle_rate(request, name):
    case = request.getfixturevalue("quick" if name in FAST else "quick_all").case(name)
    by = {r.method: r for r in case.rows}
    dbl, quad = by["heyoka double"], by["heyoka quad"]
    assert math.isfinite(dbl.error) and math.isfinite(quad.error)
    assert quad.error < 1e-6 * dbl.error
    # the rate at which the error grows is the saddle's, computed independently from the principal moments
    # (the closed form's lam on the separatrix)
    model = dict(load_scene(name).build_models())[case.details["model"]]
    omega = load_scene(name).initial["omega"]
    if name == "separatrix-exact":
        lam = float(exact.rigid_body_constants((3, 4, 6), omega).lam)
    else:
        I1, I2, I3 = sorted(model.principal_moments)
        w = float(np.linalg.norm([float(to_fraction(v)) for v in omega]))
        lam = w * math.sqrt((I2 - I1) * (I3 - I2) / (I1 * I3))
    assert case.details["lambda"] == pytest.approx(lam, rel=1e-9)
    for label in ("heyoka quad", "heyoka real256"):
        assert case.details["growth_rate"][label] == pytest.approx(lam, rel=0.05), label


def test_unstable_axis_double_departs_when_its_round_off_has_grown(quick):
    """Double departs (error > 1e-3) at ln(1e-3 / eps) / lambda up to an O(1) factor in the start offset, and
    long double later by ln(eps_double / eps_long) / lambda (within two output intervals)."""
    d = quick.case("unstable-axis").details
    lam = d["lambda"]
    t_dbl = d["departure"]["heyoka double"]
    assert abs(t_dbl - math.log(1e-3 / 2.0**-52) / lam) < 5 / lam
    t_ld = d["departure"]["heyoka long double"]
    assert t_ld - t_dbl == pytest.approx(math.log(2.0**-52 / 2.0**-63) / lam, abs=2 * 120 / 40)
    assert d["departure"]["heyoka real256"] is None


def test_unstable_axis_in_principal_axes_never_departs(quick):
    for r in quick.case("unstable-axis-principal").rows:
        assert r.error < 100 * r.precision.eps


@pytest.mark.slow
def test_long_run_drift_follows_brouwer(quick_all):
    case = quick_all.case("long-run")
    d = case.details
    assert d["total_steps"] > 50_000
    assert d["exponents"]["energy"] < 0.8
    assert d["exponents"]["orthogonality"] < 0.8
    E0 = 0.5 * (1 + 2 * 0.01 + 3 * 0.25)
    final = d["errors"]["energy"][-1]
    assert final < 20 * d["eps"] * math.sqrt(d["total_steps"]) * E0  # not eps * steps


@pytest.mark.slow
def test_scaled_cases_reach_their_precision_relative_to_the_natural_scale(quick_all):
    for name in ("spin-fast", "spin-slow", "body-nearly-flat", "body-nearly-symmetric", "damped-mild"):
        for r in quick_all.case(name).rows:
            if r.method.startswith("heyoka"):
                assert r.error_over_eps < 1e3, (name, r.method, r.error_over_eps)
    # the same motion at three speeds: the same relative accuracy
    rel = {name: next(r for r in quick_all.case(name).rows if r.method == "heyoka double").scaled_error
           for name in ("spin-fast", "spin-slow")}
    assert 0.1 < rel["spin-fast"] / rel["spin-slow"] < 10
    for name in ("sphere-huge", "sphere-tiny"):
        for r in quick_all.case(name).rows:
            if r.model.startswith("Dirac") and r.method.startswith("heyoka"):
                assert r.error_over_eps < 100, (name, r.method, r.error_over_eps)


def test_sphere_atlas_switches_charts_and_stays_on_the_great_circle(quick):
    """The atlas runs use all three charts, switch several times a revolution, and stay as accurate as the Dirac
    form against the exact great circle (rows of every chart converted with sphere.position/velocity(chart=k))."""
    case = quick.case("sphere-atlas")
    d = case.details
    t_end = d["t_end"]
    revolutions = t_end / (2 * math.pi)
    for r in case.rows:
        if r.model.startswith("intermediate"):
            assert r.status == "success", r.message
            assert r.extra["chart_switches"] >= 4 * revolutions
            eps = r.precision.eps
            assert r.error < 1e3 * eps, (r.method, r.error)
    for key, used in d["charts_used"].items():
        assert used == [0, 1, 2], key
    # independently: the chart of each output row is never the one whose coordinate is near zero
    ser = d["series"]["intermediate (5-d, atlas): heyoka double"]
    x0, v0 = np.array([2, 1, 2]) / 3, np.array([1, 2, -2]) / 3
    for t, k in zip(ser["t"], ser["charts"]):
        x = x0 * math.cos(t) + v0 * math.sin(t)
        assert abs(x[k]) >= 0.5 - 1e-9, (t, k, x)


# -- the Lie series beyond its radius --------------------------------------------------------------------------
def test_lie_series_beyond_its_radius():
    """error_estimate is inf and converges() False beyond the radius, finite inside; radius() is the pole
    distance of the closed form; the actual error beyond the radius grows with the order."""
    body = ls.EulerPoisson((1, 2, 3))
    omega = (1, "0.1", "0.5")
    y0 = body.initial_state(omega, precision=256)
    series = ls.lie_series(body, y0, order=30, dps=40)
    rho = exact.rigid_body_constants((1, 2, 3), omega, dps=40).pole_distance
    assert float(series.radius()) == pytest.approx(float(rho), rel=0.05)
    for f in (0.3, 0.5):
        assert mp.isfinite(series.error_estimate(f * rho)) and series.converges(f * rho)
    for t in (series.radius(), 1.5 * rho, 3 * rho):
        assert series.error_estimate(t) == mp.inf and not series.converges(t)
    # the actual error against the closed form, inside and beyond
    with mp.workdps(40):
        ref_in = exact.euler_poisson((1, 2, 3), omega, 0.5 * rho, dps=40)
        ref_out = exact.euler_poisson((1, 2, 3), omega, 1.5 * rho, dps=40)
        err_in = [max(abs(a - b) for a, b in zip(series.partial_sum(0.5 * rho, n), ref_in)) for n in (10, 20, 30)]
        err_out = [max(abs(a - b) for a, b in zip(series.partial_sum(1.5 * rho, n), ref_out)) for n in (10, 20, 30)]
    assert err_in[0] > err_in[1] > err_in[2]
    assert err_out[0] < err_out[1] < err_out[2]
    assert err_out[2] > 10 * err_out[0]


@pytest.mark.slow
def test_lie_integrate_never_steps_beyond_the_radius(quick_all):
    body = ls.EulerPoisson((1, 2, 3))
    omega = (1, "0.1", "0.5")
    y0 = body.initial_state(omega, precision=256)
    sol = ls.lie_integrate(body, y0, 20, dps=30)
    assert sol.success
    assert "max_step_over_radius" in sol.stats.extra
    assert 0 < sol.stats.extra["max_step_over_radius"] <= 0.5
    # independently: every point of the real orbit is at least K'/lam (the imaginary part of the poles) away from
    # a singularity; the largest step stays inside that disc
    c = exact.rigid_body_constants((1, 2, 3), omega)
    assert sol.stats.max_step < 0.5 * float(c.Kp / c.lam)
    d = quick_all.case("lie-divergence").details
    assert d["error_estimate"]["beyond"] == math.inf and d["converges"]["beyond"] is False
    assert math.isfinite(d["error_estimate"]["inside"]) and d["converges"]["inside"] is True
    assert d["lie_integrate"]["max_step_over_radius"] <= 0.5
    assert d["errors_beyond"][-1] > d["errors_beyond"][0]
    assert d["errors_inside"][-1] < d["errors_inside"][0]


# -- the stability report --------------------------------------------------------------------------------------
@pytest.mark.slow
def test_stability_report_has_one_row_per_case(quick_all, tmp_path):
    path = write_stability_report(quick_all, tmp_path, scene_reports=False)
    md = path.read_text()
    table = md.split("## Findings")[0]
    body = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| case")
            and not line.startswith("| ---")]
    assert len(body) == len(quick_all.cases) == len(EXTREME)
    stiff = next(line for line in body if line.startswith("| damped-stiff"))
    assert "step_collapse" in stiff and "stiff" in stiff and "last step size" in stiff
    for name in ("overview", "error_growth", "drift", "divergence", "atlas"):
        assert (tmp_path / f"{name}.png").is_file(), name
        assert f"({name}.png)" in md
    data = json.loads((tmp_path / "data.json").read_text())
    assert [r["case"] for r in data["rows"]] == [c.name for c in quick_all.cases]
    assert data["quick"] is True
    row = next(r for r in data["rows"] if r["case"] == "damped-stiff")
    assert row["status"] == "step_collapse"
    assert (tmp_path / "stability.csv").read_text().count("\n") == len(EXTREME) + 1


@pytest.mark.slow
def test_stability_full_size_cases():
    """Full size (validation/stability.py runs this): the separatrix and axis cases depart as predicted."""
    st = stability(["separatrix-exact", "unstable-axis"], quick=False)
    for case in st.cases:
        d = case.details
        for label, t in d["departure"].items():
            pred = d["predicted_departure"].get(label)
            if t is not None and pred is not None:
                assert abs(t - pred) < 10 / d["lambda"], (case.name, label, t, pred)
