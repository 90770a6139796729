"""The sphere's atlas: runs switch charts where x_k -> 0 and follow the exact great circle over many revolutions."""

import math
from fractions import Fraction

import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.precision import to_fraction
from problems import mpf

X0, V0 = ("0.6", "0", "0.8"), ("0", "1", "0")  # |x| = 1 exactly; a great circle through both poles' equators


def position_errors(model, sol, times, dps):
    X = model.position(sol.y, chart=sol.charts)
    out = []
    with mp.workdps(dps):
        for tk, xk in zip(times, X):
            xe, _ = exact.sphere(1, X0, V0, tk, dps=dps)
            out.append(max(abs(mpf(a) - b) for a, b in zip(xk, xe)))
    return out


# quad over 20 revolutions is slow (the default suite has quad atlas runs against the great circle over a
# revolution: test_stability.py::test_sphere_atlas_switches_charts_and_stays_on_the_great_circle)
@pytest.mark.parametrize("precision", ["double", pytest.param("quad", marks=pytest.mark.slow)])
def test_heyoka_atlas_follows_great_circle_over_20_revolutions(precision):
    s = ls.Sphere()
    y0 = s.initial_state(X0, V0, precision=precision)
    times = [5 * k for k in range(1, 26)]  # up to t = 125: 20 revolutions
    sol = ls.integrate(s, y0, t=times, precision=precision, atlas=True)
    assert sol.success, sol.message
    # x1 and x3 each cross zero twice per revolution: ~4 switches per revolution
    assert sol.stats.extra["chart_switches"] >= 60
    assert set(sol.charts.tolist()) <= {0, 1, 2} and len(set(sol.charts.tolist())) >= 2
    eps = ls.resolve_precision(precision).eps
    revolutions = 125 / (2 * math.pi)
    errs = position_errors(s, sol, times, 80)
    assert max(errs) < 100 * eps * revolutions
    # the Casimir |x|^2 stays on its leaf across every chart change
    x2 = s.invariants(sol.y, chart=sol.charts)["x2"]
    assert max(abs(v - 1) for v in x2) < 50 * eps * revolutions


def test_atlas_error_is_that_of_the_global_dirac_form():
    """Chart changes cost nothing visible: the atlas run is as accurate as the 6-d Dirac form, same tolerance."""
    times = [20, 60, 100]
    s, d = ls.Sphere(), ls.SphereDirac()
    sa = ls.integrate(s, s.initial_state(X0, V0), t=times, atlas=True)
    sd = ls.integrate(d, d.initial_state(X0, V0), t=times)
    ea = max(position_errors(s, sa, times, 40))
    Xd = d.position(sd.y)
    with mp.workdps(40):
        ed = max(max(abs(mpf(a) - b) for a, b in zip(xk, exact.sphere(1, X0, V0, tk, dps=40)[0]))
                 for tk, xk in zip(times, Xd))
    assert ea < 10 * max(ed, 1e-15)


def test_lie_atlas_follows_great_circle():
    s = ls.Sphere()
    y0 = s.initial_state(X0, V0, precision=200)
    sol = ls.lie_integrate(s, y0, t=[10, 20], dps=30, atlas=True)
    assert sol.success, sol.message
    assert sol.stats.extra["chart_switches"] >= 8
    assert max(position_errors(s, sol, [10, 20], 50)) < 1e-27
    assert sol.stats.extra["max_step_over_radius"] <= 0.5


def test_atlas_starts_in_the_best_chart_and_says_so():
    """y0 may be given in a poor chart (|x3| small but inside it): the run moves to the best chart at once, and
    every row, the first included, is read in the chart `sol.charts` gives for it."""
    s = ls.Sphere(chart=2, edge=0.01)
    x, v = (math.sqrt(1 - 0.02**2), 0.0, 0.02), (0.0, 1.0, 0.0)
    y0 = s.initial_state(x, v)
    sol = ls.integrate(s, y0, t=[0, 1.0], atlas=True)
    assert sol.charts[0] == 0 and sol.charts[1] == 0
    assert max(abs(a - b) for a, b in zip(s.position(sol.y[0]), x)) < 1e-15
    xe, _ = exact.sphere(s.radius, x, v, 1.0, dps=30)
    got = s.position(sol.y[1], chart=sol.charts[1])
    np.testing.assert_allclose(got, [float(c) for c in xe], atol=1e-14)


def test_change_chart_is_the_same_point():
    s = ls.Sphere()
    y = s.initial_state(("0.36", "0.48", "0.8"), ("0.8", "-0.6", "0"), precision=200)
    for k in (0, 1, 2):
        z = s.change_chart(y, k, bits=200)
        before = list(s.position(y)) + list(s.velocity(y))
        after = list(s.position(z, chart=k)) + list(s.velocity(z, chart=k))
        with mp.workprec(230):
            assert max(abs(to_fraction(a) - to_fraction(b)) for a, b in zip(before, after)) < Fraction(1, 2**195)


def test_atlas_bad_input():
    body = ls.EulerPoisson((1, 2, 3))
    with pytest.raises(ValueError, match="`atlas` needs a model with an atlas"):
        ls.integrate(body, body.initial_state((1, 0, 0)), t=1, atlas=True)
    s = ls.Sphere()
    with pytest.raises(ValueError, match="`dense`"):
        ls.integrate(s, s.initial_state(X0, V0), t=1, atlas=True, dense=True)
    with pytest.raises(ValueError, match="`chart`"):
        s.change_chart(s.initial_state(X0, V0), 5)


def _scaled_position_error(R, sol, t):
    """max |x - x_exact| / R at the end of a run on the sphere of radius R from (0.6 R, 0, 0.8 R) at speed 1."""
    s = ls.Sphere(mass=1, radius=R)
    x = s.position(np.array([sol.y_reached]), chart=[sol.chart_reached])[0]
    xe, _ = exact.sphere(R, [f"{0.6 * float(R):.17g}", 0, f"{0.8 * float(R):.17g}"], V0, t, dps=30)
    return max(abs(to_fraction(a) - Fraction(str(b))) for a, b in zip(x, xe)) / Fraction(R)


@pytest.mark.parametrize("R, t", [("1e3", "2e4"), ("1e4", "2e5"), ("1e6", "2e7"), ("1e8", "2e9")])
def test_atlas_run_is_checked_against_the_initial_energy(R, t):
    """A badly scaled sphere (positions ~ R, momenta ~ 1) loses digits in the chart form; the run switches charts
    13 times. It must not end in ``success`` unless its result is right (the unit sphere's error is 1.3e-14): the
    energy guard compares the end with the initial state, not with the last chart switch, and allows a few tol
    per step (sqrt(tol) let R = 1e4 pass with 1.4e-10)."""
    s = ls.Sphere(mass=1, radius=R)
    x0 = [f"{0.6 * float(R):.17g}", 0, f"{0.8 * float(R):.17g}"]
    y0 = s.initial_state(x0, V0)
    sol = ls.integrate(s, y0, t=t)
    assert sol.stats.extra["chart_switches"] >= 10
    err = _scaled_position_error(R, sol, t)
    assert sol.status == "invariant_drift" or err < 1e-11, (sol.status, float(err))
    if sol.status == "invariant_drift":
        assert "energy" in sol.message and "chart switches" in sol.message
    # the ensemble's members that switch charts run as single atlas runs: the same verdict
    ens = ls.integrate(s, np.array([y0, y0]), t=t)
    for st in ens.status:
        assert st == "invariant_drift" or err < 1e-11, st


@pytest.mark.parametrize("R", ["3e2", "1e3"])
def test_a_sphere_a_few_hundred_times_its_speed_is_right_or_drifts(R):
    """Positions ~ R, momenta ~ 1: heyoka's tolerance is relative to the largest component, so the momenta keep
    about R eps. Over 3 radians (14 steps) R = 3e2 ended ``success`` 100 eps off the great circle and R = 1e3
    226 eps off (the unit sphere: 3 eps): its energy moved 13 and 90 tol per step, under the guard's 1000 (a sound
    run moves it by under 1). A run a double calls a success is right to a few eps per step."""
    s = ls.Sphere(mass=1, radius=R)
    y0 = s.initial_state([f"{0.6 * float(R):.17g}", 0, f"{0.8 * float(R):.17g}"], V0)
    t = 3 * int(float(R))
    sol = ls.integrate(s, y0, t=t)
    err = _scaled_position_error(R, sol, t)
    assert sol.status == "invariant_drift" or err < 3 * sol.stats.steps * 2.0 ** -52, (sol.status, float(err))


def test_ensemble_batch_members_get_the_same_energy_verdict_as_single_runs():
    """Members that stay in one chart run in heyoka's batch mode; their energy check allows the same few tol per
    step as a single run's (it allowed sqrt(tol): R = 1e5 over one radian passed with 1.4e-10, 6 digits lost)."""
    R = "1e5"
    s = ls.Sphere(mass=1, radius=R, atlas=False)
    y0 = s.initial_state(["6e4", 0, "8e4"], V0)
    single = ls.integrate(s, y0, t=R)
    err = _scaled_position_error(R, single, R)
    assert single.status == "invariant_drift" or err < 1e-11, (single.status, float(err))
    ens = ls.integrate(s, np.array([y0, y0, y0]), t=R)
    assert list(ens.status) == [single.status] * 3


@pytest.mark.parametrize("engine", ["heyoka", "lie"])
def test_atlas_budget_bounds_the_whole_run_not_each_chart(engine):
    """``max_steps`` counts every step of an atlas run (it once restarted at each chart switch: 16 steps for a
    budget of 10); the run stops on the exact great circle at the time it reached."""
    s = ls.Sphere()
    if engine == "heyoka":
        sol = ls.integrate(s, s.initial_state(X0, V0), t=200, atlas=True, max_steps=10)
        bound = 1e-12
    else:
        sol = ls.lie_integrate(s, s.initial_state(X0, V0, precision=200), t=20, dps=20, atlas=True, max_steps=10)
        bound = 1e-17
    assert sol.status == "step_budget" and sol.stats.steps == 10, (sol.stats.steps, sol.message)
    assert sol.stats.extra["chart_switches"] >= 1  # the budget ran out in the second chart
    assert "`max_steps` = 10" in sol.message
    x = s.position(sol.y_reached)
    with mp.workdps(40):
        xe, _ = exact.sphere(1, X0, V0, to_fraction(sol.t_reached), dps=40)
        assert max(abs(mpf(a) - b) for a, b in zip(x, xe)) < bound


def test_atlas_time_budget_bounds_the_whole_run():
    """``max_time`` is the whole run's (each chart segment once got it afresh, so a run of many switches went on
    far beyond it): a budget far below one segment's work stops after the first segment, with its rows on the
    exact great circle."""
    s = ls.Sphere()
    sol = ls.integrate(s, s.initial_state(X0, V0), t=[0, 1, 50], atlas=True, max_time=1e-6)
    assert sol.status == "time_budget" and "`max_time`" in sol.message, sol.message
    assert sol.stats.extra["chart_switches"] == 1 and float(sol.t_reached) < 1
    assert list(sol.t) == [0.0]
    x = s.position(sol.y_reached)
    with mp.workdps(40):
        xe, _ = exact.sphere(1, X0, V0, to_fraction(sol.t_reached), dps=40)
        assert max(abs(mpf(a) - b) for a, b in zip(x, xe)) < 1e-12


def test_atlas_run_to_a_final_time_that_is_not_a_double_ends_there():
    """t = 2.001 is reached as heyoka rounds it (its t_reached is the double next to 2.001): the run ends there,
    on the exact great circle, instead of asking for a segment of zero length."""
    s = ls.Sphere()
    sol = ls.integrate(s, s.initial_state(X0, V0), t="2.001", atlas=True)
    assert sol.success and sol.stats.extra["chart_switches"] == 1, sol.message
    assert len(sol.t) == 2 and sol.t[-1] == 2.001
    assert position_errors(s, sol, [0, Fraction(2001, 1000)], 40)[-1] < 1e-14


def test_atlas_segment_that_reaches_a_chart_edge_at_the_final_time_ends_the_run():
    """Back from t0 = 7.3 to -2.1 this great circle reaches a chart's edge within 2e-41 of -2.1 (the Lie run's times,
    40 digits, hold -2.1 rounded): the segment gave the row at -2.1 and ended chart_edge, and the atlas ran one more
    segment to the exact -21/10, whose row had no place (IndexError: pop from empty list). The run ends there, on
    the great circle."""
    s = ls.Sphere()
    x0, v0 = ("0.36", "0.48", "0.8"), ("-0.8", "0.6", "0")
    times = ["0.25", "-2.1"]
    sol = ls.lie_integrate(s, s.initial_state(x0, v0), t=times, t0="7.3", dps=30)
    assert sol.success, sol.message
    assert len(sol.t) == 2 and sol.stats.extra["chart_switches"] == 8
    X = s.position(sol.y, chart=sol.charts)
    with mp.workdps(40):
        for tk, xk in zip(times, X):
            xe, _ = exact.sphere(1, x0, v0, to_fraction(tk) - Fraction(73, 10), dps=40)
            assert max(abs(mpf(a) - b) for a, b in zip(xk, xe)) < 1e-26

@pytest.mark.parametrize("engine", ["double", "lie", "ensemble"])
def test_an_event_on_a_chart_momentum_is_refused_on_the_atlas(engine):
    """pi_c = p_c - x_c p_k / x_k is a different function in each chart (and pi2 is no variable of the chart x2):
    an event on pi1 of the chart x3 was, after the switch to the chart x2, an event on the chart x2's pi1 (with
    `success`), and one on pi2 raised midway, its variables not in the chart x2. Refused up front, naming the
    event; positions are the same in every chart, and one chart (atlas=False) keeps its own momenta."""
    import heyoka as hy

    s = ls.Sphere()
    y0 = s.initial_state(("0.6", "0", "0.8"), ("0.8", "0.6", "-0.6"))
    for ev in (hy.make_vars("pi1"), lambda m: m.poisson.variables[4] + m.poisson.variables[0]):
        events = [ls.Event(hy.make_vars("x1"), name="x"), ls.Event(ev, name="p")]
        with pytest.raises(ValueError, match=r"`events\[1\]` \('p'\).*chart"):
            if engine == "lie":
                ls.lie_integrate(s, y0, t=8, dps=20, events=events)
            elif engine == "ensemble":
                ls.integrate(s, [y0, y0], t=8, events=events)
            else:
                ls.integrate(s, y0, t=8, events=events)
    sol = ls.integrate(s, y0, t="0.3", events=[ls.Event(hy.make_vars("pi1"))], atlas=False)
    assert sol.success


def test_a_run_stopped_by_the_limit_of_chart_switches_says_it_was_advancing(monkeypatch):
    # the guard against cycling between charts stopped long runs with "made no progress", which they had made
    import lieseries.atlas as atlas

    monkeypatch.setattr(atlas, "MAX_SWITCHES", 6)
    s = ls.Sphere()
    sol = ls.integrate(s, s.initial_state(x=("0.6", "0", "0.8"), v=(0, 1, 0)), t=100)
    assert sol.status == "event" and sol.stats.extra["chart_switches"] == 6
    assert "limit of 6 chart switches" in sol.message and "it was advancing" in sol.message
    assert "no progress" not in sol.message and 0 < float(sol.t_reached) < 100
