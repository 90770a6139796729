"""Ensembles (lieseries.ensemble): every member against its single run and against closed forms; early stops per
member; per-member parameters; the Dask path against the local one; pickling; input errors."""

import pickle
import sys
import warnings
from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries.ensemble import integrate_ensemble
from lieseries.solution import EnsembleSolution

EPS = 2.0**-52


def run(system, Y0, t, **kw):
    return integrate_ensemble(system, Y0, t, **kw)


def omegas(k, seed=0):
    rng = np.random.default_rng(seed)
    return np.array([1.0, 0.1, 0.5]) + 0.05 * rng.standard_normal((k, 3))


def body_states(body, oms, precision="double"):
    return np.stack([body.initial_state(o, precision=precision) for o in oms])


def blowup_system():
    """dq/dt = q^2, dp/dt = -2 p q (H = p q^2, canonical): q(t) = q0 / (1 - q0 t) blows up at t = 1/q0."""
    q, p = hy.make_vars("q", "p")
    return ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * q**2, name="blow-up")


def close(a, b, rtol):
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)))


def test_members_equal_single_runs_and_closed_form():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    oms = omegas(11)  # not a multiple of the batch size: the last batch is padded
    Y0 = body_states(body, oms)
    es = run(body, Y0, 20.0, batch_size=4, workers=2)
    assert isinstance(es, EnsembleSolution) and es.success and es.y.shape == (11, 2, 12)
    assert es.stats["path"] == "batch" and es.stats["single_runs"] == 0
    for i in range(11):
        sol = ls.integrate(body, Y0[i], 20.0)
        assert close(es.y[i], sol.y, 0) <= 64 * EPS
        assert es.stats["steps"][i] == sol.stats.steps  # each lane steps as its single run
        assert es.t_reached[i] == sol.t_reached == 20
    with mp.workdps(30):
        for i in (0, 5, 10):
            ref = ls.exact.euler_poisson((1, 2, 3), list(oms[i]), 20, dps=30)
            assert close(es.y[i, 1], [float(v) for v in ref], 0) <= 2e-13


def test_output_grid_and_backward():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(5, seed=1))
    grid = [1, 2.5, "3.7", 8]  # t0 = 0 not in the grid: the batch adds it in front and drops it
    es = run(body, Y0, grid)
    assert es.y.shape == (5, 4, 12) and es.success
    back = run(body, Y0, -3.0)
    for i in range(5):
        sol = ls.integrate(body, Y0[i], grid)
        assert close(es.y[i], sol.y, 0) <= 64 * EPS
        sb = ls.integrate(body, Y0[i], -3.0)
        assert close(back.y[i], sb.y, 0) <= 64 * EPS and back.t_reached[i] == -3


def test_members_that_end_in_their_first_step_beside_members_that_go_on():
    """A batch reads its members' series from its own first step, taken alone, then goes on: members that go the
    whole way in that step (slow ones) or stop in it (at a chart's edge) sit beside members that go on, from t0 = 0
    and from t0 = 0.1 (t_end - t0 is then not a double: the batch runs its first chunk again in one call), forward
    and backward. Each member takes the steps of its single run and ends where it does."""
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(8, seed=2))
    Y0[1::2, 9:] *= 1e-4  # slow: the whole span in one step
    for t0, t in ((0, 3), (0.1, 2.3), (0.1, -2.2)):
        es = run(body, Y0, t, t0=t0, batch_size=4)
        assert es.stats["path"] == "batch" and es.stats["single_runs"] == 0 and es.success
        for i in range(8):
            sol = ls.integrate(body, Y0[i], t, t0=t0)
            assert es.stats["steps"][i] == sol.stats.steps and (sol.stats.steps == 1) == (i % 2 == 1)
            assert close(es.y[i], sol.y, 0) <= 64 * EPS and es.t_reached[i] == sol.t_reached
    sphere = ls.Sphere(mass=1, radius=1)
    # x3 = 0.0502 |x| running down to the edge 0.05 |x| (within the first step), beside x3 = 0.6 |x|
    states = [sphere.initial_state(x=(float(np.sqrt(1 - c * c)), 0, c), v=(c, 0, -float(np.sqrt(1 - c * c))))
              for c in (0.0502, 0.6) * 3]
    es = run(sphere, np.stack(states), 0.2, batch_size=4, atlas=False)
    assert list(es.status) == ["chart_edge", "success"] * 3 and es.stats["single_runs"] == 0
    for i, y0 in enumerate(states):
        sol = ls.integrate(sphere, y0, 0.2, atlas=False)
        assert sol.status == es.status[i] and es.stats["steps"][i] == sol.stats.steps
        assert (sol.stats.steps == 1) == (i % 2 == 0) and es.t_reached[i] == sol.t_reached
        assert close(es.y_reached[i], sol.y_reached, 0) <= 64 * EPS


def test_exact_input_rounded_once():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    y_str = [1, 0, 0, 0, 1, 0, 0, 0, 1, "1", "0.2", "1.5"]
    y_frac = [Fraction(v) for v in y_str]
    es = run(body, [y_str, y_frac], 4.0)
    sol = ls.integrate(body, y_str, 4.0)
    assert np.array_equal(es.y[0, 0], es.y[1, 0]) and es.y[0, 0, 10] == 0.2
    assert close(es.y[0], sol.y, 0) <= 64 * EPS and close(es.y[1], sol.y, 0) <= 64 * EPS


def test_per_member_inertia_list_and_params():
    inertias = [(1, 2, 3), (2, 3, 4), ("1.5", 2, "2.5")]
    bodies = [ls.EulerPoisson(inertia=I) for I in inertias]
    om = [1.0, 0.1, 0.5]
    Y0 = np.stack([b.initial_state(om) for b in bodies])
    es = run(bodies, Y0, 10.0)
    params = [[Fraction(1) / Fraction(v) for v in I] for I in inertias]  # entries of I^-1 (diagonal bodies)
    es2 = run(bodies[0], Y0, 10.0, params=params)
    assert np.array_equal(es.y, es2.y)
    for i, (b, I) in enumerate(zip(bodies, inertias)):
        sol = ls.integrate(b, Y0[i], 10.0)
        assert close(es.y[i], sol.y, 0) <= 64 * EPS
        with mp.workdps(30):
            ref = ls.exact.euler_poisson(I, om, 10, dps=30)
        assert close(es.y[i, 1], [float(v) for v in ref], 0) <= 2e-13


def test_sphere_member_stops_at_chart_edge_others_succeed():
    sphere = ls.Sphere(mass=1, radius=1)
    # the first member runs down a meridian to the chart's edge |x3| = 0.05 at t = asin(0.8) - asin(0.05) = 0.877;
    # the other two move slowly and stay far from it up to t = 2
    states = [sphere.initial_state(x=(0.6, 0, 0.8), v=(0.8, 0, -0.6)),
              sphere.initial_state(x=(0, 0.6, 0.8), v=(0.3, 0, 0)),
              sphere.initial_state(x=(0.6, 0, 0.8), v=(0, 0.2, 0))]
    t = [0.5, 1.0, 2.0]
    es = run(sphere, np.stack(states), t, atlas=False)
    assert list(es.status) == ["chart_edge", "success", "success"]
    assert not es.success and list(es.succeeded) == [False, True, True]
    for i, y0 in enumerate(states):
        sol = ls.integrate(sphere, y0, t, atlas=False)
        assert sol.status == es.status[i]
        assert es.rows[i] == len(sol.t)
        assert close(es.y[i, : len(sol.t)], sol.y, 0) <= 64 * EPS
        assert close(es.y_reached[i], sol.y_reached, 0) <= 64 * EPS
        assert abs(float(es.t_reached[i] - sol.t_reached)) <= 64 * EPS
        m = es.member(i)
        assert m.status == sol.status and len(m.t) == len(sol.t)
    assert np.isnan(es.y[0, es.rows[0]:]).all()
    assert es.rows[0] == 1 and "chart" in es.message[0]
    # to a final time, the lanes the stop interrupted go on in the batch (no single run), as their single runs
    fin = run(sphere, np.stack(states * 3), 2.0, batch_size=4, atlas=False)
    assert fin.stats["single_runs"] == 0 and list(fin.status) == ["chart_edge", "success", "success"] * 3
    for i, y0 in enumerate(states * 3):
        sol = ls.integrate(sphere, y0, 2.0, atlas=False)
        assert fin.stats["steps"][i] == sol.stats.steps and fin.t_reached[i] == sol.t_reached
        assert close(fin.y_reached[i], sol.y_reached, 0) <= 64 * EPS
    # the stop is where the great circle (closed form) has x3 = 0.05, and the state is the closed form's there
    t_edge = float(es.t_reached[0])
    assert abs(t_edge - (np.arcsin(0.8) - np.arcsin(0.05))) <= 1e-12
    x_ref, _ = ls.exact.sphere(1, (0.6, 0, 0.8), (0.8, 0, -0.6), es.t_reached[0], dps=30)
    assert close(es.y_reached[0, :3], [float(v) for v in x_ref], 0) <= 1e-13
    for i in (1, 2):
        x_ref, _ = ls.exact.sphere(1, ["0.6", 0, "0.8"] if i == 2 else [0, "0.6", "0.8"],
                                   [0, "0.2", 0] if i == 2 else ["0.3", 0, 0], 2, dps=30)
        assert close(es.y[i, -1, :3], [float(v) for v in x_ref], 0) <= 1e-14


def test_sphere_atlas_members_equal_atlas_single_runs():
    sphere = ls.Sphere()
    states = [sphere.initial_state(x=(0.6, 0, 0.8), v=(0.8, 0, -0.6)),  # leaves |x3| > 0.5 |x|: switches charts
              sphere.initial_state(x=(0.6, 0, 0.8), v=(0, 0.2, 0)),  # stays near the pole
              sphere.initial_state(x=(0.6, 0, 0.8), v=(0.1, 0, -0.075))]  # slow: stays in the chart
    for t in (3.0, [1.0, 3.0]):
        es = run(sphere, np.stack(states), t, atlas=True)
        assert list(es.status) == ["success"] * 3
        assert es.stats["single_runs"] == 1  # only the member that switches charts
        for i, y0 in enumerate(states):
            sol = ls.integrate(sphere, y0, t, atlas=True)
            assert sol.status == es.status[i]
            assert close(es.y[i], np.asarray(sol.y, dtype=np.float64), 0) <= 64 * EPS
            # every state knows its chart, as in the single run: helpers read it in the right chart
            assert list(es.charts[i]) == list(sol.charts) and es.chart_reached[i] == sol.chart_reached
            m = es.member(i)
            assert list(m.charts) == list(sol.charts) and m.y.charts.tolist() == list(sol.charts)
            x0, v0 = sphere.position(y0), sphere.velocity(y0)
            times = [t] if np.ndim(t) == 0 else t
            for j, tj in enumerate(times):
                row = j - len(times)  # the output rows of the times t (a scalar t: the rows t0, t)
                _, v_ref = ls.exact.sphere(1, [Fraction(float(c)) for c in x0], [Fraction(float(c)) for c in v0],
                                           Fraction(tj), dps=30)
                v_ref = [float(c) for c in v_ref]
                for got in (sphere.velocity(es.y[i, row]), sphere.velocity(es.y[i])[row], sphere.velocity(m)[row]):
                    assert close(got, v_ref, 0) <= 1e-12
            for got in (sphere.velocity(es.y_reached[i]), sphere.velocity(m.y_reached)):
                assert close(got, v_ref, 0) <= 1e-12
        if np.ndim(t):
            assert list(es.charts[0]) == [0, 2]  # the switching member is in chart 0 at t = 1, back in 2 at t = 3
    with pytest.raises(ValueError, match="`atlas` needs a model with an atlas"):
        run(ls.EulerPoisson(), np.zeros((1, 12)), 1.0, atlas=True)


def test_non_finite_member_next_to_finite_ones():
    ps = blowup_system()
    # q0 = 1e200: q^2 overflows in the first step (non_finite at t = 0, the last finite state is y0);
    # q0 = 1: the solution blows up at t = 1 (the single run's guard stops it there); the others are finite
    Y0 = [["1e200", 1], [1, 1], [-1, 1], ["0.25", 1]]
    es = run(ps, Y0, 2.0)
    assert es.status[0] == "non_finite" and es.status[1] != "success"
    assert list(es.status[2:]) == ["success", "success"]
    for i, y0 in enumerate(Y0):
        sol = ls.integrate(ps, y0, 2.0)
        assert sol.status == es.status[i] and sol.message == es.message[i]
        assert close(es.y_reached[i], sol.y_reached, 0) <= 64 * EPS
        assert es.t_reached[i] == sol.t_reached
    assert es.t_reached[0] == 0 and es.y_reached[0, 0] == 1e200
    assert 0.99 < es.t_reached[1] <= 1
    # q(2) = q0 / (1 - 2 q0): -1/3 and 0.5, against the closed form
    assert abs(es.y[2, 1, 0] + 1 / 3) <= 8 * EPS and abs(es.y[3, 1, 0] - 0.5) <= 8 * EPS
    assert np.isnan(es.y[:2, 1]).all() and list(es.rows) == [1, 1, 2, 2]
    assert es.stats["single_runs"] >= 2


def test_non_finite_member_next_to_finite_ones_on_a_grid():
    """On an output grid heyoka's batch stops every lane where one becomes non-finite and calls the others'
    outcome a time limit reached: they were recorded as successes with rows of NaN, reached at t = 0."""
    ps = blowup_system()
    Y0 = [["1e200", 1], [-1, 1], ["0.25", 1], ["-0.5", 1]]
    es = run(ps, Y0, [1.5, 2.0], batch_size=4)
    assert es.status[0] == "non_finite" and list(es.status[1:]) == ["success"] * 3
    for i, q0 in enumerate((-1, 0.25, -0.5), 1):  # q(t) = q0 / (1 - q0 t), against the closed form
        assert es.t_reached[i] == 2 and es.rows[i] == 2
        assert close(es.y[i, :, 0], [q0 / (1 - q0 * 1.5), q0 / (1 - q0 * 2.0)], 0) <= 8 * EPS
        sol = ls.integrate(ps, Y0[i], [1.5, 2.0])
        assert sol.status == es.status[i] and sol.message == es.message[i]


def test_stiff_member_handed_to_its_single_run_and_long_runs_in_chunks():
    # damping 1e5 makes the body stiff (the single run stops with step_collapse); damping 0 is the free body
    bodies = [ls.DampedEulerPoisson((1, 2, 3), damping=d) for d in (100000, 0, 100000)]
    om = [1.0, 0.1, 0.5]
    Y0 = np.stack([b.initial_state(om) for b in bodies])
    es = run(bodies, Y0, 10.0)
    singles = [ls.integrate(b, y0, 10.0) for b, y0 in zip(bodies, Y0)]
    assert list(es.status) == [s.status for s in singles] == ["step_collapse", "success", "step_collapse"]
    assert es.stats["single_runs"] == 2 and "stiff" in es.message[0]
    assert close(es.y[1], singles[1].y, 0) <= 64 * EPS
    # the same members through `params=` on one model: the single runs must use each member's own values
    params = [list(b.poisson.parameter_values) for b in bodies[::-1]]
    es2 = run(bodies[1], Y0[::-1], 10.0, params=params)
    assert list(es2.status) == list(es.status)[::-1]
    assert es2.t_reached[0] == singles[2].t_reached and es2.t_reached[2] == singles[0].t_reached
    # about 4800 steps: the batch goes on over several chunks of steps, each lane as its single run
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    oms = omegas(3, seed=5)
    es = run(body, body_states(body, oms), 2000.0)
    assert es.success and es.stats["single_runs"] == 0 and min(es.stats["steps"]) > 2048
    for i in range(3):
        sol = ls.integrate(body, body_states(body, oms)[i], 2000.0)
        assert es.stats["steps"][i] == sol.stats.steps
        with mp.workdps(30):
            ref = [float(v) for v in ls.exact.euler_poisson((1, 2, 3), list(oms[i]), 2000, dps=30)]
        # rounding errors grow over 2000 time units: the member is as close to the closed form as its single run
        assert close(es.y[i, 1], ref, 0) <= max(4 * close(sol.y[1], ref, 0), 1e-12)


def test_long_double_members_equal_single_runs():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(3, seed=2), precision="long double")
    es = run(body, Y0, 5.0, precision="long double", workers=2)
    assert es.y.dtype == np.longdouble and es.success and es.stats["path"] == "threads"
    for i in range(3):
        sol = ls.integrate(body, Y0[i], 5.0, precision="long double")
        assert np.array_equal(es.y[i], sol.y) and es.stats["steps"][i] == sol.stats.steps  # the same compiled code



@pytest.mark.parametrize("precision", ["long double", "quad"])
@pytest.mark.parametrize("t", ["0.1", ["1.5", "0.1"]])
def test_scalar_members_back_to_a_time_the_format_rounds_end_there(precision, t):
    """From t0 = 2.3 back to 0.1 heyoka's double-length time ends beside the final time as the format rounds it
    (an ulp past it): the members on the scalar integrator raised a bare TypeError (no row at t = 0.1), and on a
    grid reached a t_reached an ulp off their single runs'. Each member ends at 0.1 as its single run does, on the
    closed form q = q0 cos(t - t0) + p0 sin(t - t0)."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + q**2) / 2)
    Y0 = [[0, 1], ["0.5", "-0.25"], ["-1.5", "0.1"]]
    es = run(osc, Y0, t, t0="2.3", precision=precision)
    assert es.stats["path"] == "threads" and es.success
    with mp.workdps(40):
        for i, (q0, p0) in enumerate(Y0):
            sol = ls.integrate(osc, Y0[i], t, t0="2.3", precision=precision)
            assert es.t_reached[i] == sol.t_reached and es.rows[i] == len(sol.t)
            assert np.array_equal(es.y[i], sol.y)
            s = mp.mpf(-2.2)
            ref = [mp.mpf(q0) * mp.cos(s) + mp.mpf(p0) * mp.sin(s), -mp.mpf(q0) * mp.sin(s) + mp.mpf(p0) * mp.cos(s)]
            assert max(abs(mp.mpf(float(a)) - b) for a, b in zip(es.y[i, -1], ref)) < 1e-15

def test_long_double_sphere_edge_and_grid():
    sphere = ls.Sphere()
    S0 = np.stack([sphere.initial_state(x=("0.6", 0, "0.8"), v=("0.8", 0, "-0.6"), precision="long double"),
                   sphere.initial_state(x=("0.6", 0, "0.8"), v=(0, "0.2", 0), precision="long double")])
    for t in ([0.5, 1.0, 2.0], 2.0):
        es = run(sphere, S0, t, precision="long double", atlas=False)
        assert list(es.status) == ["chart_edge", "success"]
        for i in range(2):
            sol = ls.integrate(sphere, S0[i], t, precision="long double", atlas=False)
            assert sol.status == es.status[i] and es.rows[i] == len(sol.t)
            assert np.array_equal(es.y[i, : len(sol.t)], sol.y) and np.array_equal(es.y_reached[i], sol.y_reached)
            assert es.t_reached[i] == sol.t_reached


@pytest.mark.slow
def test_real_precision_members_in_processes_equal_single_runs():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(3, seed=4), precision=80)
    es = run(body, Y0, 2.0, precision=80, workers=2)  # spawned processes, each with its own cache
    assert es.stats["path"] == "single" and es.stats["workers"] == 2 and es.success
    for i in range(3):
        assert np.array_equal(es.y[i], ls.integrate(body, Y0[i], 2.0, precision=80).y)


def test_quad_members_equal_single_runs():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = [[1, 0, 0, 0, 1, 0, 0, 0, 1, 1, "0.2", "1.5"], [1, 0, 0, 0, 1, 0, 0, 0, 1, "1.1", "0.2", "1.5"]]
    es = run(body, Y0, 1.0, precision="quad")
    assert es.stats["path"] == "threads" and es.y.dtype == np.dtype(hy.real128)
    for i in range(2):
        assert np.array_equal(es.y[i], ls.integrate(body, Y0[i], 1.0, precision="quad").y)


def test_progress_and_single_run_options():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(20))
    seen = []
    es = run(body, Y0, 2.0, progress=seen.append, batch_size=4, workers=1)
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) == 5
    # min_step routes every member through its single run, with the single run's own check
    es2 = run(body, Y0[:2], 2.0, min_step=1e-300)
    assert es2.stats["path"] == "single" and es2.stats["single_runs"] == 2
    assert close(es2.y, es.y[:2], 0) <= 64 * EPS


def test_nothing_to_integrate_and_integrate_ensemble_called_directly():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(2))
    es = run(body, Y0, 0.0)
    assert es.success and np.array_equal(es.y[:, 0], Y0) and np.array_equal(es.y_reached, Y0)
    # members that need single runs (80 bits) run them: integrate_ensemble called directly needed
    # `single_run=ls.integrate` (it raised RuntimeError without)
    Y80 = body_states(body, omegas(2), precision=80)
    es = integrate_ensemble(body, Y80, 1.0, precision=80)
    assert es.success and es.stats["single_runs"] == 2
    for i in range(2):
        assert list(es.y_reached[i]) == list(ls.integrate(body, Y80[i], 1.0, precision=80).y_final)


def test_precision_from_the_data_and_coarse_data_warned():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Yld = body_states(body, omegas(2), precision="long double")
    assert run(body, Yld, 1.0).stats["precision"] == "long double"  # precision=None: the data's own
    assert run(body, Yld.astype(np.float64), 1.0).stats["precision"] == "double"
    with pytest.warns(ls.PrecisionWarning, match="`Y0` carries only 53 bits"):
        run(body, Yld.astype(np.float64), 1.0, precision="long double")
    # binary doubles anywhere in a run of more bits are named, as in a single run: params, t, t0, the models'
    # inertia; exact input is silent
    Y = [body.initial_state((1, "0.1", "0.5"))] * 2
    inv = [["1", "0.5", "0.25"], ["1", "0.5", "0.2"]]
    for kw, name in ((dict(params=[[1, 0.5, 0.2]] * 2), "params"), (dict(t=[0.1]), "t"),
                     (dict(t0=0.3), "t0"), (dict(system=[body, ls.EulerPoisson((1, 2, 2.2))]), "inertia")):
        args = dict(system=body, Y0=Y, t=1.0, precision="quad") | kw
        with pytest.warns(ls.PrecisionWarning, match=f"`{name}` carries only 53 bits"):
            run(args.pop("system"), args.pop("Y0"), args.pop("t"), **args)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run(body, Y, ["0.1", 1], precision="quad", params=inv, t0="-0.3")
        run([body, ls.EulerPoisson((1, 2, "2.2"))], Y, 1, precision="quad")
        run(body, np.array(Y, dtype=np.float64), [0.5, 1.0], params=[[1, 0.5, 0.2]] * 2)  # double: doubles are exact


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(Y0=[[1, 2, 3]]), "`Y0` must have shape"),
        (dict(Y0=np.zeros(12)), "`Y0` is one state of 12 numbers, but an ensemble"),
        (dict(params=[[1, 2]]), "`params` must have shape"),
        (dict(workers=0), "`workers` must be a positive integer"),
        (dict(workers=1.5), "`workers` must be a positive integer"),
        (dict(batch_size=0), "`batch_size` must be a positive integer"),
        (dict(chunk_size=-1), "`chunk_size` must be a positive integer"),
        (dict(client="tcp://127.0.0.1:8786"), "`client` must be a dask.distributed.Client"),
        (dict(Y0=[[np.nan] + [0] * 11]), r"`Y0\[0\]\[0\]` must be finite"),
        (dict(dense=True), "`dense=True` is not available for an ensemble"),
        (dict(events=["M2"]), r"`events\[0\]` must be an ls.Event"),
        (dict(events=[ls.Event(hy.make_vars("q"))]), r"`events\[0\]` uses variables \['q'\]"),
        (dict(progress=3), "`progress` must be a callable"),
    ],
)
def test_bad_input_names_the_argument(kwargs, match):
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    args = dict(Y0=body_states(body, omegas(1)))
    args.update(kwargs)
    Y0 = args.pop("Y0")
    with pytest.raises((ValueError, TypeError), match=match):
        run(body, Y0, 1.0, **args)


def test_bad_model_list():
    with pytest.raises(ValueError, match=r"`system\[1\]`"):
        run([ls.EulerPoisson(), ls.Sphere()], np.zeros((2, 12)), 1.0)


def test_client_without_dask_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed now raises ImportError
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    with pytest.raises(ImportError, match=r"pip install 'lieseries\[distributed\]'"):
        run(body, body_states(body, omegas(1)), 1.0, client=object())


def test_models_systems_and_solutions_pickle():
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    for system in (body, ls.DampedEulerPoisson(), ls.Sphere(), ls.SphereDirac(), blowup_system()):
        ps = system.poisson if hasattr(system, "poisson") else system
        ps.vector_field  # the cached field must pickle too
        copy = pickle.loads(pickle.dumps(system))
        ps2 = copy.poisson if hasattr(copy, "poisson") else copy
        assert ps2.key == ps.key and ps2.parameter_values == ps.parameter_values
    y0 = body.initial_state((1, 0.1, 0.5))
    again = pickle.loads(pickle.dumps(body))
    assert np.array_equal(ls.integrate(again, y0, 3.0).y, ls.integrate(body, y0, 3.0).y)
    es = run(body, body_states(body, omegas(3)), 2.0)
    es2 = pickle.loads(pickle.dumps(es))
    assert np.array_equal(es2.y, es.y) and list(es2.status) == list(es.status)
    assert es2.member(1).status == "success"
    # immutable, as a Solution is (also after a round trip): nothing a caller holds can change what it reported
    for sol in (es, es2):
        with pytest.raises(AttributeError, match="immutable"):
            sol.status = ["success"] * 3
        with pytest.raises(ValueError, match="read-only"):
            sol.y[0, 0, 0] = 0.0
        with pytest.raises(ValueError, match="read-only"):
            sol.status[0] = "success"
        with pytest.raises(TypeError):
            sol.stats["steps"] = None
        with pytest.raises(ValueError, match="read-only"):  # through the read-only view: changed the steps
            sol.stats["steps"][0] = 99
        assert isinstance(sol.message, tuple)
    events = run(body, body_states(body, omegas(2)), 2.0, events=[ls.Event(hy.make_vars("M2"), name="m2")]).events
    with pytest.raises(AttributeError):
        events.append({})  # a list: members could be added to the record
    single = pickle.loads(pickle.dumps(ls.integrate(body, y0, 3.0)))
    with pytest.raises(ValueError, match="read-only"):
        single.y[0, 0] = 0.0



def test_concatenate_joins_only_chunks_of_one_run():
    """``EnsembleSolution.concatenate`` labelled every row with the first part's times: parts run to other times,
    in another precision, or with events in one and not the other were joined silently. Refused, naming the
    part and what differs; chunks of one run join."""
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(4))
    a, b = run(body, Y0[:2], [5, 10]), run(body, Y0[2:], [5, 10])
    whole = EnsembleSolution.concatenate([a, b], workers=2)
    assert np.array_equal(whole.y, run(body, Y0, [5, 10]).y) and whole.stats["workers"] == 2
    m2 = hy.make_vars("M2")
    for other, what in ((run(body, Y0[2:], [5, 20]), "output times"),
                        (run(body, body_states(body, omegas(2), "quad"), [5, 10], precision="quad"), "output times"),
                        (run(body, Y0[2:], [5, 10], tol=1e-10), "tolerance"),
                        (run(body, Y0[2:], [5, 10], events=[ls.Event(m2, name="m2")]), "events")):
        with pytest.raises(ValueError, match=rf"`parts\[1\]` differs from `parts\[0\]` in its {what}"):
            EnsembleSolution.concatenate([a, other])
    with pytest.raises(TypeError, match=r"`parts\[1\]` must be an EnsembleSolution"):
        EnsembleSolution.concatenate([a, b.member(0)])


# -- Dask --------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")
    # one worker process with two threads: the chunks cross a process boundary and finish out of order, and the
    # worker starts Python and compiles each integrator once, not once per process
    cluster = distributed.LocalCluster(processes=True, n_workers=1, threads_per_worker=2, host="127.0.0.1",
                                       dashboard_address=None)
    cl = distributed.Client(cluster)
    yield cl
    cl.close()
    cluster.close()


def test_dask_equals_local(client):
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    Y0 = body_states(body, omegas(20, seed=3))
    local = run(body, Y0, [5, 10])
    dist = run(body, Y0, [5, 10], client=client, chunk_size=8)
    assert dist.stats["chunks"] == 3
    assert np.array_equal(dist.y, local.y) and list(dist.status) == list(local.status)
    assert list(dist.t_reached) == list(local.t_reached)
    # events travel with the chunks: each member's crossings and a terminal stop, as in the local run
    m2 = hy.make_vars("M2")
    stops = []
    for ev in (ls.Event(m2, name="m2"), ls.Event(m2, terminal=True, name="flip")):
        a = run(body, Y0[:6], [5, 10], events=[ev])
        b = run(body, Y0[:6], [5, 10], events=[ev], client=client, chunk_size=4)
        assert list(b.status) == list(a.status) and np.array_equal(a.y, b.y, equal_nan=True)
        assert [list(e[ev.name]["t"]) for e in b.events] == [list(e[ev.name]["t"]) for e in a.events]
        assert list(b.t_reached) == list(a.t_reached)
        stops.append(list(b.status).count("event"))
    assert stops[0] == 0 and stops[1] > 0  # the terminal event ends members on the workers
    # early stops on the workers: a chart edge (batch) and a non-finite blow-up (single run on the worker)
    sphere = ls.Sphere()
    S0 = np.stack([sphere.initial_state(x=(0.6, 0, 0.8), v=(0.8, 0, -0.6)),
                   sphere.initial_state(x=(0.6, 0, 0.8), v=(0, 0.2, 0))])
    a = run(sphere, S0, 2.0, atlas=False)
    b = run(sphere, S0, 2.0, client=client, chunk_size=1, atlas=False)
    assert list(b.status) == list(a.status) == ["chart_edge", "success"]
    assert np.array_equal(a.y_reached, b.y_reached, equal_nan=True)
    # across the atlas, the charts of the states come back with them
    a, b = run(sphere, S0, [1.0, 3.0]), run(sphere, S0, [1.0, 3.0], client=client, chunk_size=1)
    assert np.array_equal(a.y, b.y) and np.array_equal(a.charts, b.charts) and list(b.charts[0]) == [0, 2]
    assert b.member(0).y.charts.tolist() == [0, 2] and list(b.chart_reached) == [2, 2]
    ps = blowup_system()
    Y0 = [["1e200", 1], [-1, 1]]
    a, b = run(ps, Y0, 2.0), run(ps, Y0, 2.0, client=client)
    assert list(b.status) == list(a.status) == ["non_finite", "success"]
    assert np.array_equal(a.y, b.y, equal_nan=True)


def test_max_time_bounds_the_whole_ensemble_on_the_cluster(client):
    # the deadline travels with the chunks: members not started on a worker before it end time_budget at y0, not run
    # (each chunk once had the whole budget for each of its members)
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    sol = run(body, [y0] * 8, [0, 10**5], precision=256, max_time=0.5, client=client, chunk_size=2)
    assert set(sol.status) == {"time_budget"}
    idle = [i for i in range(8) if sol.stats["steps"][i] == 0]
    assert len(idle) >= 4 and all(sol.t_reached[i] == 0 and "before this member started" in sol.message[i]
                                  for i in idle)


def test_a_closed_client_is_named_with_what_to_do():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None)
    cl = distributed.Client(cluster)
    cl.close()
    cluster.close()
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    with pytest.raises(RuntimeError, match=r"`client` is closed .* new dask.distributed.Client"):
        run(body, body_states(body, omegas(2)), 1.0, client=cl)


def test_dask_machinery_errors_become_a_runtime_error_naming_client():
    pytest.importorskip("distributed")
    from distributed.client import FutureCancelledError

    from lieseries.ensemble.cluster import dask_failure as _dask_failure, is_dask_error as _is_dask_error

    err = FutureCancelledError("key", "lost")
    assert _is_dask_error(err) and not _is_dask_error(ValueError("`y0` bad"))
    out = _dask_failure(err, "collecting the chunks")
    assert isinstance(out, RuntimeError) and "`client`" in str(out) and "more than one worker" in str(out)



@pytest.mark.slow
def test_a_single_worker_that_dies_mid_run_is_restarted_and_its_chunks_rerun():
    # the system is not scattered: each chunk carries its inputs, so Dask reruns it on the restarted worker
    # (before: FutureCancelledError, the scattered system being lost with the worker)
    import os
    import threading

    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(processes=True, n_workers=1, threads_per_worker=1, host="127.0.0.1",
                                       dashboard_address=None)
    cl = distributed.Client(cluster)
    try:
        body = ls.EulerPoisson(inertia=(1, 2, 3))
        Y0 = body_states(body, omegas(4, seed=1))
        times = [1, 5000, 10000, 20000]
        local = run(body, Y0, times, precision="long double")
        cl.submit(abs, 1).result()  # the worker is up
        killer = threading.Timer(1.5, lambda: cl.run(lambda: os._exit(1)))
        killer.start()
        dist = run(body, Y0, times, precision="long double", client=cl, chunk_size=1)
        killer.join()
        assert list(dist.status) == list(local.status) and np.array_equal(dist.y, local.y)
    finally:
        cl.close()
        cluster.close()


def test_a_quad_ensemble_of_a_field_with_binary_constants_checks_energy_as_a_single_run_does():
    # a single quad run loosens its energy guard to the 53 bits of the constants written in H (heyoka folds their
    # derivatives in double); the ensemble's members did not, and ended `invariant_drift` ("went from 0.08525390625
    # to 0.08525390625") where the single runs succeed. Each member against its single run.
    q, p = hy.make_vars("q", "p")
    H = p**2 / 2 + 0.1 * q**2 + 0.3 * q**4 + 0.7 * q**6 + 1.1 * q**8 + 1.3 * q**10 + 0.2 * q**3
    system = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], H)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ls.PrecisionWarning)  # the constants' bits, said and tested elsewhere
        ens = ls.integrate(system, [["0.5", "0"], ["0.4", "0"]], t=1, precision="quad")
        singles = [ls.integrate(system, y, t=1, precision="quad") for y in (["0.5", "0"], ["0.4", "0"])]
    assert list(ens.status) == ["success", "success"] and all(s.status == "success" for s in singles)
    for i, s in enumerate(singles):
        assert max(abs(float(a - b)) for a, b in zip(ens.y_reached[i], s.y_final)) < 1e-30
