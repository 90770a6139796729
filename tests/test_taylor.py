"""ls.integrate (heyoka): the sphere against the exact great circle in every precision; outcomes; bad input."""

import math
from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries.taylor import build_integrator
from problems import mpf, rigid_error


def great_circle(x0, v0, t):
    """Exact position on the great circle through x0 with velocity v0 (plain mpmath, current precision)."""
    x = [mpf(c) for c in x0]
    v = [mpf(c) for c in v0]
    r = mp.sqrt(mp.fsum(c * c for c in x))
    w = mp.sqrt(mp.fsum(c * c for c in v)) / r
    t = mpf(t)
    return [x[i] * mp.cos(w * t) + v[i] / w * mp.sin(w * t) for i in range(3)]


@pytest.mark.parametrize("form", ["intermediate", "dirac"])
def test_sphere_follows_great_circle(form, precision):
    """Error at the level of the precision's epsilon, over a time that stays inside the chart x3 != 0."""
    model = ls.Sphere(mass=2, radius="1.5") if form == "intermediate" else ls.SphereDirac(mass=2, radius="1.5")
    x0, v0 = ("0.9", "0", "1.2"), ("0", "0.75", "0")
    y0 = model.initial_state(x0, v0, precision=precision)
    sol = ls.integrate(model, y0, t=[0.5, 1.0, 1.5, 2.0], precision=precision)
    assert sol.success, sol.message
    assert len(sol.t) == 4
    eps = ls.resolve_precision(precision).eps
    with mp.workdps(90):
        err = max(
            abs(mpf(a) - b)
            for tk, yk in zip(sol.t, sol.y)
            for a, b in zip(model.position(yk), great_circle(x0, v0, tk))
        )
        # and the Casimir |x|^2 stays on its leaf
        drift = max(abs(mpf(c) - mpf("2.25")) for c in model.invariants(sol.y)["x2"])
    assert err < 20 * eps * 1.5
    assert drift < 20 * eps * 2.25


def test_sphere_stops_cleanly_at_chart_edge():
    """The 5-d chart ends on x3 = 0; the run stops there with a status, no NaN, and keeps what it computed."""
    s = ls.Sphere()
    y0 = s.initial_state((0.6, 0.0, 0.8), (0.0, 1.0, 0.0))
    sol = ls.integrate(s, y0, t=np.linspace(0, 5, 11), atlas=False)
    assert sol.status == "chart_edge"
    assert "x3" in sol.message and "t = 1.50" in sol.message
    # x3(t) = 0.8 cos t reaches edge * |x| = 0.05 at cos t = 1/16
    assert float(sol.t_reached) == pytest.approx(np.arccos(0.05 / 0.8), rel=1e-12)
    assert list(sol.t) == [0.0, 0.5, 1.0, 1.5]
    assert np.all(np.isfinite(sol.y)) and np.all(np.isfinite(sol.y_reached))
    assert abs(s.position(sol.y_reached)[2]) == pytest.approx(0.05, rel=1e-10)


def test_backward_integration_retraces():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1.0, 0.1, 0.5))
    fwd = ls.integrate(body, y0, t=3.0)
    back = ls.integrate(body, fwd.y[-1], t=-3.0, t0=0)
    assert back.success
    np.testing.assert_allclose(back.y[-1], y0, atol=1e-13)
    grid = ls.integrate(body, y0, t=[-1.0, -2.0, -3.0])
    assert grid.success and len(grid.t) == 3


def test_dense_output_matches_grid_run():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1.0, 0.1, 0.5))
    sol = ls.integrate(body, y0, t=5.0, dense=True)
    grid = ls.integrate(body, y0, t=[1.3, 2.7])
    np.testing.assert_allclose(sol([1.3, 2.7]), grid.y, atol=1e-13)
    with pytest.raises(ValueError, match="`t`"):
        sol(6.0)
    with pytest.raises(RuntimeError, match="dense"):
        grid(1.0)


@pytest.mark.parametrize("t_end, just_outside", [(10, "-1e-20"), (-10, "1e-20")])
def test_dense_output_just_outside_the_start_reads_the_first_chunk(t_end, just_outside):
    """``sol(t)`` takes times a rounding outside the interval; at t0's end it evaluated the last chunk of steps
    there (t0 - 1e-20 of a 10-unit quad run: 0.39 off, at 200 bits 6e17): the chunk nearest to t is read."""
    body = ls.EulerPoisson((1, 2, 3))
    sol = ls.integrate(body, body.initial_state((1, "0.1", "0.5")), t=t_end, dense=True, precision="quad")
    assert sol.success and rigid_error(sol(just_outside), just_outside, dps=50) < 1e-30
    assert rigid_error(sol(t_end / 2), t_end / 2, dps=50) < 1e-30


def test_second_call_reuses_the_compiled_integrator():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1.0, 0.1, 0.5))
    ls.integrate(body, y0, t=1.0, tol=1e-12)
    other = ls.EulerPoisson((2, 3, 4))  # same structure, other parameters: same integrator
    sol = ls.integrate(other, other.initial_state((1.0, 0.1, 0.5)), t=1.0, tol=1e-12)
    assert sol.stats.cached and sol.stats.build_time == 0.0
    # and the parameters really are the new ones: energy of the new body is conserved
    e = other.invariants(sol.y)["energy"]
    assert abs(e[1] - e[0]) < 1e-13 and abs(e[0] - 0.5 * (2 + 3 * 0.01 + 4 * 0.25)) < 1e-15


def test_repeated_calls_follow_their_arguments():
    """A repeated call reuses its validated arguments; a changed argument (a mutated array, another state, other
    options) must still give that argument's answer, checked against the closed form."""
    body = ls.EulerPoisson((1, 2, 3))
    exact = body.initial_state(omega=(1, "0.1", "0.5"))
    y = np.array(exact, dtype=float)  # a plain array the caller owns and changes
    errs = []
    for _ in range(3):
        sol = ls.integrate(body, exact, t=5)
        errs.append(rigid_error(sol.y[-1], 5))
    assert max(errs) < 1e-13 and sol.success
    first = ls.integrate(body, y, t=5).y[-1].copy()
    y[9:] = 0.0, 0.2, 1.5  # the caller changes M in place: now M = I omega for omega = (0, 0.1, 0.5)
    second = ls.integrate(body, y, t=5)
    assert rigid_error(second.y[-1], 5, omega=(0, "0.1", "0.5")) < 1e-13
    assert np.max(np.abs(second.y[-1] - first)) > 1e-2
    # other options, same state: a coarser tolerance is honoured, not served from the memo
    coarse = ls.integrate(body, exact, t=5, tol=1e-6)
    assert coarse.stats.tol == 1e-6 and coarse.stats.order < sol.stats.order
    assert 1e-13 < rigid_error(coarse.y[-1], 5) < 1e-4


def test_non_finite_state_is_reported():
    q, p = hy.make_vars("q", "p")
    # dq/dt = dH/dp = log(q): non-finite as soon as q <= 0
    sys = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * hy.log(q), name="log")
    sol = ls.integrate(sys, [-1.0, 0.0], t=1.0)
    assert sol.status == "non_finite"
    assert "after t = 0" in sol.message
    assert not sol.success
    np.testing.assert_array_equal(sol.y_reached, [-1.0, 0.0])  # the last finite state, not heyoka's NaN


def test_non_finite_mid_run_keeps_good_part():
    q, p = hy.make_vars("q", "p")
    # q' = -1 from q = 1, p' = sqrt(q): a step that lands past q = 0 (t = 1) turns the state into NaN
    sys = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], -p - (2.0 / 3.0) * q * hy.sqrt(q), name="sqrt")
    for dense in (True, False):
        sol = ls.integrate(sys, [1.0, 0.0], t=np.linspace(0, 2, 5), dense=dense, max_steps=10**9)
        assert sol.status == "non_finite", sol.message
        assert list(sol.t) == [0.0, 0.5, 1.0][: len(sol.t)] and len(sol.t) >= 2
        assert 0.5 < float(sol.t_reached) <= 1.0 + 1e-9
        assert np.all(np.isfinite(sol.y)) and np.all(np.isfinite(sol.y_reached))
        # exact: p(t) = 2/3 (1 - (1 - t)^(3/2))
        assert sol.y[1][1] == pytest.approx(2 / 3 * (1 - 0.5**1.5), rel=1e-13)


def test_step_collapse_is_diagnosed_not_hung():
    """dq/dt = q^2 blows up at t = 1/q0: the steps shrink towards it, and the run stops with where and how small
    (at 200 bits), or, in double, where the state overflows just before it (its last finite state kept)."""
    q, p = hy.make_vars("q", "p")
    sys = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * q**2, name="blow-up")
    sol = ls.integrate(sys, ["1", "0"], t=2, precision=200)
    assert sol.status == "step_collapse"
    assert 1 - 1e-2 < float(sol.t_reached) <= 1.0
    assert "collapsed" in sol.message and "step size" in sol.message
    sol = ls.integrate(sys, [1.0, 0.0], t=2.0, max_steps=10_000)
    assert sol.status == "non_finite" and "blows up" in sol.message
    assert 1 - 1e-12 < float(sol.t_reached) < 1.0 and sol.stats.steps < 10_000
    assert np.all(np.isfinite(sol.y_reached))
    # a step budget's message counts the steps at the last step size, the one it names (it counted at an older
    # probe's: 'about 23.6 steps at this step size, more than max_steps = 40')
    sol = ls.integrate(sys, ["1", "0"], t=2, precision="quad", max_steps=40)
    if sol.status == "step_budget":
        need = float(sol.message.split("about ")[1].split(" steps")[0])
        h = float(sol.message.split("last step size ")[1].split(")")[0])
        assert need > 40 and need == pytest.approx((2 - float(sol.t_reached)) / h, rel=0.02), sol.message
    # a budget that runs out while the steps go on shrinking towards the pole: a collapse, not "raise max_steps"
    for kw in ({"precision": 256, "max_steps": 300}, {"max_steps": 200}):
        sol = ls.integrate(sys, ["1", "0"], t=2, **kw)
        assert sol.status == "step_collapse" and "collapsed" in sol.message, (kw, sol.message)


def test_a_comets_pericentre_is_not_taken_for_a_collapse():
    # Kepler's problem at eccentricity 2499/2501 from its apocentre: at the pericentre the steps shrink 10^4-fold
    # for a moment and grow back. The run was stopped step_collapse there ("singular or stiff"), with max_steps =
    # 10**6 too; it now goes on, against Kepler's equation at 80 digits
    x, y, px, py = hy.make_vars("x", "y", "px", "py")
    kepler = ls.PoissonSystem([x, y, px, py], [[0, 0, 1, 0], [0, 0, 0, 1], [-1, 0, 0, 0], [0, -1, 0, 0]],
                              (px**2 + py**2) / 2 - 1 / hy.sqrt(x**2 + y**2), name="kepler")
    e, s = Fraction(2499, 2501), Fraction(100, 2501)
    sol = ls.integrate(kepler, [-(1 + e), 0, 0, -s / (1 + e)], t=4, precision=200)
    assert sol.status == "success", sol.message
    with mp.workdps(80):
        em, sm = mp.mpf(e.numerator) / e.denominator, mp.mpf(s.numerator) / s.denominator
        M = mp.mpf(4) + mp.pi  # the mean anomaly (period 2 pi, from the apocentre)
        E = mp.findroot(lambda E: E - em * mp.sin(E) - M, M)
        den = 1 - em * mp.cos(E)
        ref = [mp.cos(E) - em, sm * mp.sin(E), -mp.sin(E) / den, sm * mp.cos(E) / den]
        assert max(abs(mp.mpf(str(a)) - b) for a, b in zip(sol.y_final, ref)) < 1e-50
    # in double over two periods (two pericentres, chunks' ends at either): never a collapse; the energy check says
    # what double keeps of such an orbit
    e9 = Fraction(9999, 10000)
    far = ls.integrate(kepler, [-(1 + e9), 0, 0, -(1 - e9 * e9) ** 0.5 / (1 + e9)], t=4 * math.pi)
    assert far.status in ("success", "invariant_drift") and float(far.t_reached) == pytest.approx(4 * math.pi)
    # a pericentre passed inside a chunk: the next probe's step, grown back 5000-fold from the chunk's smallest, was
    # below the probe's before it and read as still shrinking (quad, e = 0.999899, stopped at t = 3.1468)
    e, s = Fraction(9999, 10001), Fraction(200, 10001)
    y0 = [-(1 + e), 0, 0, -s / (1 + e)]
    quad = ls.integrate(kepler, y0, t=100, precision="quad")
    assert quad.status in ("success", "invariant_drift") and float(quad.t_reached) == 100, quad.message
    # and a budget spent just after it is a budget, not a collapse
    short = ls.integrate(kepler, y0, t=6 * math.pi, precision="quad", max_steps=150)
    assert short.status == "step_budget" and "raise `max_steps`" in short.message, short.message


def test_time_budget_stops_a_long_run():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1.0, 0.1, 0.5))
    sol = ls.integrate(body, y0, t=1e6, max_time=0.05, dense=False)
    assert sol.status == "time_budget"
    assert "max_time" in sol.message
    assert 0 < float(sol.t_reached) < 1e6


def test_hopeless_step_budget_stops_early():
    """Asking for 1e9 time units (~2e9 steps) with the default budget stops at once and says why."""
    body = ls.EulerPoisson((1, 2, 3))
    sol = ls.integrate(body, body.initial_state((1.0, 0.1, 0.5)), t=1e9, dense=False, max_steps=10**6)
    assert sol.status == "step_budget"
    assert sol.stats.steps < 100 and "max_steps" in sol.message


def test_step_budget():
    body = ls.EulerPoisson((1, 2, 3))
    sol = ls.integrate(body, body.initial_state((1.0, 0.1, 0.5)), t=1e4, max_steps=100, dense=False)
    assert sol.status in ("step_budget", "step_collapse")
    assert sol.stats.steps <= 100


def test_user_defined_system_harmonic_oscillator(precision):
    """A new model from a bracket and a Hamiltonian alone; exact solution cos/sin."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], 0.5 * hy.par[0] * p**2 + 0.5 * q**2,
                           parameters={"inv_mass": Fraction(1, 4)})
    sol = ls.integrate(osc, ["1", "0"], t=3, precision=precision)
    prec = ls.resolve_precision(precision)
    with mp.workprec(prec.bits + 30):
        w = mp.mpf(1) / 2  # sqrt(k/m), m = 4
        err = abs(mpf(sol.y[-1][0]) - mp.cos(3 * w))
    assert err < 20 * prec.eps


# -- bad input --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def body():
    return ls.EulerPoisson((1, 2, 3))


@pytest.mark.parametrize(
    "y0,match",
    [
        (np.zeros(11), "`y0` must be a 1-d sequence of 12"),
        (np.zeros((2, 3, 12)), "`y0` must be a 1-d"),
        (np.r_[np.eye(3).ravel(), 1.0, np.nan, 0.0], r"`y0\[10\]` must be finite"),
        (np.r_[np.eye(3).ravel(), 1.0, np.inf, 0.0], r"`y0\[10\]`"),
    ],
)
def test_bad_state(body, y0, match):
    with pytest.raises(ValueError, match=match):
        ls.integrate(body, y0, t=1.0)


@pytest.mark.parametrize(
    "t,match",
    [
        ([0.0, 2.0, 1.0], "strictly increasing"),
        ([-1.0, 0.5, 1.0], "starts before t0"),
        ([], "empty"),
        ([[1.0, 2.0]], "1-d"),
        (float("nan"), "`t` must be finite"),
    ],
)
def test_bad_times(body, t, match):
    with pytest.raises(ValueError, match=match):
        ls.integrate(body, body.initial_state((1, 0, 0)), t=t)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(precision="single"), "`precision`"),
        (dict(tol=0.0), "`tol` must be positive"),
        (dict(tol=-1e-10), "`tol` must be positive"),
        (dict(tol=2.0), "`tol` must be below 1"),
        (dict(max_steps=0), "`max_steps`"),
        (dict(max_time=-1), "`max_time`"),
    ],
)
def test_bad_options(body, kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        ls.integrate(body, body.initial_state((1, 0, 0)), t=1.0, **kwargs)


def test_not_a_system():
    with pytest.raises(TypeError, match="`system`"):
        ls.integrate("body", [0, 1], t=1.0)


def test_sphere_state_at_chart_edge_is_refused():
    s = ls.Sphere()
    with pytest.raises(ValueError, match="edge of the chart"):
        ls.integrate(s, [1.0, 0.0, 0.0, 0.0, 1.0], t=1.0)


def test_build_integrator_cache_key_separates_precisions():
    body = ls.EulerPoisson((1, 2, 3))
    a = build_integrator(body, "double", 1e-10)[0]
    b = build_integrator(body, "long double", 1e-10)[0]
    assert a is not b
    assert build_integrator(body, "double", 1e-10)[0] is a


def test_sqrt_branch_point_is_a_collapse_with_the_default_budget():
    q, p = hy.make_vars("q", "p")
    sys = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], -p - (2.0 / 3.0) * q * hy.sqrt(q), name="sqrt")
    sol = ls.integrate(sys, [1.0, 0.0], t=2.0)
    assert sol.status in ("step_collapse", "non_finite")
    assert float(sol.t_reached) == pytest.approx(1.0, abs=1e-3)


def test_stiff_damped_body_is_diagnosed():
    """A large internal damping makes the body stiff: the run stops at once, says 'stiff', where, and the step."""
    body = ls.DampedEulerPoisson((1, 2, 3), damping=1e5)
    sol = ls.integrate(body, body.initial_state((1.0, 0.1, 0.5)), t=20.0)
    assert sol.status == "step_collapse"
    assert "stiff" in sol.message and "step size" in sol.message
    # checked between chunks of steps (64, 256, 1024, ...): it stops within the first few thousand steps
    assert float(sol.t_reached) < 0.1 and sol.stats.steps < 2000
    assert np.all(np.isfinite(sol.y_reached))
    # the same body with mild damping relaxes to rotation about the axis of largest inertia, |M| kept
    mild = ls.DampedEulerPoisson((1, 2, 3), damping=10)
    y0 = mild.initial_state((1.0, 0.1, 0.5))
    sol = ls.integrate(mild, y0, t=20.0)
    assert sol.success
    om = mild.angular_velocity(sol.y[-1])
    M2 = float(mild.invariants(y0)["M2"])
    assert abs(om[0]) < 1e-12 and abs(om[1]) < 1e-12
    assert om[2] == pytest.approx(np.sqrt(M2) / 3, rel=1e-12)


@pytest.mark.parametrize("precision", ["double", "quad"])
def test_output_times_not_representable_in_the_precision(precision):
    """'0.1' is not a binary number: the run ends at its rounding and still returns every requested row."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1, "0.1", "0.5"), precision=precision)
    sol = ls.integrate(body, y0, t="0.1", precision=precision)
    assert sol.success and len(sol.t) == 2
    grid = ls.integrate(body, y0, t=["0.1", "0.3"], precision=precision)
    assert grid.success and len(grid.t) == 2
    np.testing.assert_array_equal(np.asarray(grid.y[0], dtype=float), np.asarray(sol.y[-1], dtype=float))


def test_progress_is_reported_on_a_long_run():
    body = ls.EulerPoisson((1, 2, 3))
    seen = []
    # ~24000 steps: chunks of 64 steps, then growing ones (up to ~0.1 s each), report between them
    sol = ls.integrate(body, body.initial_state((1.0, 0.1, 0.5)), t=1e4, progress=seen.append)
    assert sol.success and sol.stats.steps > 10000
    assert len(seen) >= 2 and all(0 <= a <= b <= 1 for a, b in zip(seen, seen[1:]))


@pytest.mark.parametrize("precision, t, bound", [("double", [5, 200], 1e-11),
                                                 pytest.param(90, [5, 20], 1e-22, marks=pytest.mark.slow)])
def test_runs_are_bit_for_bit_reproducible_whatever_the_chunks_and_threads(monkeypatch, precision, t, bound):
    """A run with output times went chunk by chunk through propagate_grid, whose first grid point (ta.time) is only
    the high part of heyoka's double-length time: each chunk stepped back by the low part, so the result depended on
    where the wall-time-sized chunks ended (at 90 bits, 9 distinct results in 40 runs from 4 threads)."""
    from concurrent.futures import ThreadPoolExecutor

    import lieseries.taylor as taylor

    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))

    def run(_=None, y0=y0):
        sol = ls.integrate(body, y0, t=t, precision=precision)
        assert sol.success, sol.message
        return tuple(str(v) for row in sol.y for v in row)

    serial = run()
    assert run() == serial
    with ThreadPoolExecutor(4) as pool:
        assert set(pool.map(run, range(8))) == {serial}
    for first in (1, 3, 100):  # other chunk boundaries (what a loaded machine makes of wall-time chunks)
        if precision == "double":
            monkeypatch.setitem(taylor.FIRST_CHUNK, "double", first)
        else:
            monkeypatch.setattr(taylor, "FIRST_CHUNK_REAL", first)
        assert run(y0=body.initial_state(omega=(1, "0.1", "0.5"))) == serial  # a new state: a new call plan
    sol = ls.integrate(body, y0, t=t, precision=precision)
    assert rigid_error(sol.y[-1], t[-1]) < bound  # and right


def test_collapse_near_a_blow_up_far_from_t0_reports_itself():
    """q' = q^2 (H = p q^2) from q = 1 at t0 = 1e12 blows up at t0 + 1, where the steps fall below the time's ulp:
    the probe step read 0 and the message had an empty slot ("from 0.13 earlier: , more than ...")."""
    q, p = hy.make_vars("q", "p")
    sys_ = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * q**2)
    t0 = 10**12
    sol = ls.integrate(sys_, [1, 1], t=t0 + 2, t0=t0)
    assert sol.status in ("non_finite", "step_collapse"), sol.message
    assert ": ," not in sol.message and "earlier: ," not in sol.message
    assert abs(float(sol.t_reached - t0) - 1) < 1e-3  # the blow-up of q = 1 / (1 - (t - t0))


def _plain_problems():
    """(name, model, y0, t, options, check): runs of every ending the plain path of a repeated call meets; ``check``
    compares a solution with an independent reference (closed form, or an invariant the motion must keep)."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))

    def rigid(sol):
        assert sol.status == "success", sol.message
        for tk, yk in zip(sol.t, sol.y):
            assert rigid_error(yk, float(tk)) < 1e-14 * max(20.0, abs(float(tk)))  # the error grows with t

    slow = body.initial_state(omega=("1e-16", "1e-17", "5e-17"))

    def drift(sol):
        # one huge step that fooled heyoka's error control: R is far from a rotation (R^T R - 1 of order 1)
        assert sol.status == "invariant_drift" and "rescale time" in sol.message
        assert float(body.invariants(sol.y_final)["orthogonality"]) > 1

    q, p = hy.make_vars("q", "p")
    sqrt_sys = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], -p - (2.0 / 3.0) * q * hy.sqrt(q), name="sqrt")

    def non_finite(sol):
        # q = 1 - t, p = 2/3 (1 - (1 - t)^(3/2)) until q < 0 (t = 1), where the state turns NaN
        assert sol.status == "non_finite", sol.message
        assert 0.5 < float(sol.t_reached) <= 1.0 + 1e-9
        for tk, yk in zip(sol.t, sol.y):
            assert yk[1] == pytest.approx(2 / 3 * (1 - (1 - float(tk)) ** 1.5), rel=1e-13, abs=1e-15)
        assert np.all(np.isfinite(sol.y_reached))

    sphere = ls.Sphere()
    s0 = sphere.initial_state((0.6, 0.0, 0.8), (0.0, 1.0, 0.0))

    def edge(sol):
        # x3(t) = 0.8 cos t reaches the chart's edge (|x3| = 0.05) at cos t = 1/16; every row on the great circle
        assert sol.status == "chart_edge", sol.message
        assert float(sol.t_reached) == pytest.approx(np.arccos(0.05 / 0.8), rel=1e-12)
        for tk, yk in zip(list(sol.t) + [sol.t_reached], list(sol.y) + [sol.y_reached]):
            exact = [0.6 * np.cos(float(tk)), np.sin(float(tk)), 0.8 * np.cos(float(tk))]
            assert np.max(np.abs(sphere.position(yk) - exact)) < 1e-13

    return [
        ("final time", body, y0, 15.0, {}, rigid),
        ("grid from t0", body, y0, np.linspace(0.0, 20.0, 5), {}, rigid),
        ("grid after t0", body, y0, np.array([2.5, 7.0, 15.0]), {}, rigid),
        ("backward grid", body, y0, np.array([-1.0, -6.5]), {}, rigid),
        ("beyond the first chunk", body, y0, 700.0, {}, rigid),
        ("invariant drift", body, slow, "1e17", {}, drift),
        ("non-finite", sqrt_sys, np.array([1.0, 0.0]), np.linspace(0.0, 2.0, 5), {"max_steps": 10**9}, non_finite),
        ("chart edge", sphere, s0, 5.0, {"atlas": False}, edge),
        ("chart edge on a grid", sphere, s0, np.linspace(0.0, 5.0, 11), {"atlas": False}, edge),
    ]


@pytest.mark.parametrize("problem", _plain_problems(), ids=lambda p: p[0])
def test_repeated_plain_calls_match_the_general_path_and_the_reference(problem, monkeypatch):
    """A repeated call with one final time or a grid of doubles, no events of the user's and no dense output runs
    its first chunk (up to 1024 steps once it has succeeded) as one heyoka call, checks the energy with plain
    Python floats and makes its Solution's fields when read; everything else goes on through the general path.
    Both must give the same statuses, messages, steps and bits, and be right."""
    import copy
    import pickle

    import lieseries.taylor as taylor

    name, model, y0, t, options, check = problem
    ls.integrate(model, y0, t=t, **options)  # a new call: its plan is memoised (the first chunk is the short one)
    plain = [ls.integrate(model, y0, t=t, **options) for _ in range(2)]  # repeated: the long first chunk
    general = ls.integrate(model, y0, t=t, progress=lambda f: None, **options)  # progress: the general path
    for sol in plain + [general]:
        check(sol)
        assert (sol.status, sol.message) == (general.status, general.message)
        assert sol.t.tolist() == general.t.tolist()
        assert sol.y.tobytes() == general.y.tobytes() and sol.y_reached.tobytes() == general.y_reached.tobytes()
        assert sol.t_reached == general.t_reached and sol.t_requested == general.t_requested
        assert (sol.stats.steps, sol.stats.order, sol.stats.precision) == (
            general.stats.steps, general.stats.order, general.stats.precision)
        assert (sol.stats.min_step, sol.stats.max_step) == (general.stats.min_step, general.stats.max_step)
        assert not sol.y.flags.writeable
        with pytest.raises(AttributeError, match="immutable"):
            sol.status = "success"
        for other in (pickle.loads(pickle.dumps(sol)), copy.deepcopy(sol)):
            assert other.y.tobytes() == sol.y.tobytes() and other.status == sol.status
            assert other.stats.steps == sol.stats.steps and other.t_reached == sol.t_reached
    if name in ("final time", "grid from t0", "grid after t0", "backward grid"):
        # a success within the first chunk: no general path (fields made when read, the cheap energy check)
        def general_path(*args):
            raise AssertionError("the repeated call took the general path")

        monkeypatch.setattr(taylor.plain, "execute_general", general_path)
        sol = ls.integrate(model, y0, t=t, **options)
        check(sol)
        assert sol.y.tobytes() == general.y.tobytes()


def test_cheap_energy_check_never_passes_what_the_compiled_check_stops():
    """The plain path asks a plain Python function of floats first (energy_quick) and the compiled check only when
    the cheap one is not sure: the cheap one must say yes only to end states the compiled one accepts, and yes to a
    sound run's end (else it saves nothing)."""
    from lieseries.energy import energy_function, energy_quick, energy_verdict

    body = ls.EulerPoisson((1, 2, 3))
    prec = ls.resolve_precision("double")
    y0 = np.asarray(body.initial_state(omega=(1, "0.1", "0.5")), dtype=np.float64)
    sol = ls.integrate(body, body.initial_state(omega=(1, "0.1", "0.5")), t=15)
    assert sol.success and rigid_error(sol.y_final, 15) < 1e-13
    energy = energy_function(body.poisson, prec, y0)
    sqrt_tol = float(np.sqrt(prec.eps))
    assert energy_quick(energy, sqrt_tol, np.asarray(sol.y_final), sol.stats.steps)
    rng = np.random.default_rng(7)
    said_yes = said_no = 0
    for rel in np.geomspace(1e-16, 1e-6, 41):
        for component in (slice(9, 12), slice(0, 9)):  # M moves H; R moves the Casimirs R R^T
            for steps in (1, 36, 10**4):
                y = np.array(sol.y_final, dtype=np.float64)
                y[component] *= 1 + rel * rng.uniform(-1, 1, size=y[component].shape)
                quick = energy_quick(energy, sqrt_tol, y, steps)
                status, _ = energy_verdict(energy, sqrt_tol, y, steps, "success", "Reached t = 15.")
                assert not quick or status == "success", (rel, component, steps)
                said_yes += quick
                said_no += status != "success"
    assert said_yes > 0 and said_no > 0  # both sides of the threshold were tried


def test_repeated_call_skips_the_energy_check_only_on_the_bits_it_passed(monkeypatch):
    """The plain path checks the energy of a run unless the run ended on the very bits and step count of one of
    the call's runs that passed the check (the check is a function of those alone); any other end is checked, and
    a drift found there is reported."""
    import lieseries.taylor as taylor

    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    first = ls.integrate(body, y0, t=2.0)
    call = taylor.call.CALLS.get((id(body), id(y0), 2.0, float) + taylor.call.DEFAULT_KEY_TAIL)
    assert first.success and call is not None and call.plain
    checked = []
    call.quick = (lambda check: lambda y, steps: checked.append(steps) or check(y, steps))(
        call.quick or taylor.plain.quick_energy(call))
    call.passed = None
    for _ in range(3):
        sol = ls.integrate(body, y0, t=2.0)
        assert sol.success and sol.y_reached.tobytes() == first.y_reached.tobytes()
    assert checked == [first.stats.steps]  # checked once; then the same bits and steps
    passed = call.passed
    call.passed = (passed[0], passed[1] + 1)  # another step count: checked again
    ls.integrate(body, y0, t=2.0)
    end = bytearray(passed[0])
    end[0] ^= 1  # another end state (the last bit of its first entry): checked again
    call.passed = (bytes(end), passed[1])
    ls.integrate(body, y0, t=2.0)
    assert len(checked) == 3
    # an end state the check stops (the stored bits of a passed run stand for it): reported, not skipped
    call.quick = lambda y, steps: False
    for path in (taylor.plain, taylor.general):  # the plain path's check, and the general path it hands on to
        monkeypatch.setattr(path, "energy_verdict", lambda *a: ("invariant_drift", "drift."))
    call.passed = (bytes(end), passed[1])
    assert ls.integrate(body, y0, t=2.0).status == "invariant_drift"


def test_memoised_grid_follows_the_array_not_its_identity():
    """Float64 output grids are memoised by their bytes: the same array changed in place is a new call."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    grid = np.array([0.0, 1.0, 2.0])
    first = ls.integrate(body, y0, t=grid)
    grid[1:] = [3.0, 4.0]
    second = ls.integrate(body, y0, t=grid)
    assert first.t.tolist() == [0.0, 1.0, 2.0] and second.t.tolist() == [0.0, 3.0, 4.0]
    for tk, yk in zip(second.t, second.y):
        assert rigid_error(yk, float(tk)) < 1e-13


@pytest.mark.parametrize("t", [[1, "1.1", "1.10000000000000000001", 2], ["1.00000000000000000001", "1.5", 2],
                               ["1.00000000000000000001", "1.00000000000000000002", 2]])
def test_output_times_that_round_together_keep_their_rows(t):
    """Distinct exact times that round to one double (or to t0 = 1) are one point for heyoka's propagate_grid,
    which refuses a grid that does not move (the plain path raised ValueError); every time keeps its row, right."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    for _ in range(2):  # a new call, then a repeated one
        sol = ls.integrate(body, y0, t=t, t0=1)
        assert sol.success and len(sol.t) == len(t)
        for tk, yk in zip(sol.t, sol.y):
            assert rigid_error(yk, float(tk) - 1) < 1e-14


def test_a_repeated_call_refuses_what_a_fresh_call_refuses():
    """The memo keys options by value and type: after high_accuracy=True and t=1, the equal values 1 and True
    (refused by a fresh call) are refused, not answered from the memo."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    assert ls.integrate(body, y0, t=2.0, high_accuracy=True).success
    with pytest.raises(TypeError, match="`high_accuracy`"):
        ls.integrate(body, y0, t=2.0, high_accuracy=1)
    assert ls.integrate(body, y0, t=1).success
    with pytest.raises(TypeError, match="`t`"):
        ls.integrate(body, y0, t=True)


def test_drift_threshold_of_a_float_below_1e_280_is_a_float():
    """The energy check of a heyoka run squares its float sqrt(tol): above ~930 bits a float below 1e-280, which
    raised AttributeError (the mpf branch read .numerator); heyoka's reals multiply with floats, not with mpf."""
    from lieseries.energy import drift_threshold

    thr = drift_threshold(math.sqrt(2.0 ** -1023) ** 2, 2)
    assert isinstance(thr, float) and thr == 2000 * math.sqrt(2.0 ** -1023) ** 2


@pytest.mark.slow  # 2.4 s: compiling the 1024-bit integrator
def test_a_run_at_the_largest_heyoka_precision_succeeds_right():
    """1024 bits (MAX_BITS, tol 2^-1023 = 1.1e-308): the energy check squared sqrt(tol) into a float below 1e-280
    and raised AttributeError (every run above ~930 bits). Against the closed form at 330 digits."""
    from lieseries import exact
    from problems import ctx_mpf, private_ctx

    body = ls.EulerPoisson((1, 2, "2.5"))
    sol = ls.integrate(body, body.initial_state(omega=(1, "0.1", "0.5")), t="0.25", precision=1024)
    assert sol.status == "success", sol.message
    ref = exact.euler_poisson((1, 2, "2.5"), (1, "0.1", "0.5"), "0.25", dps=330)
    c = private_ctx(330)
    assert max(abs(ctx_mpf(c, a) - ctx_mpf(c, b)) for a, b in zip(sol.y[-1], ref)) < c.mpf(10) ** -305


@pytest.mark.parametrize("precision", ["double", "long double"])
def test_a_backward_run_that_heyoka_ends_an_ulp_past_the_final_time(precision):
    # from t0 = 2.3 back to 0.1 heyoka's double-length time ended at 0.09999999999999998 (past 0.1) and called it
    # the final time: the run raised "no row at t = 0.1 in a heyoka chunk". y0 is the body's state at t = 2.3 (the
    # closed form), so the run ends on the closed form at 0.1
    from lieseries import exact
    from lieseries.precision import to_fraction

    body = ls.EulerPoisson((1, 2, 3))
    y0 = [to_fraction(v) for v in exact.euler_poisson((1, 2, 3), (1, "0.1", "0.5"), Fraction(23, 10), dps=40)]
    for t in ("0.1", [1, "0.1"]):
        sol = ls.integrate(body, y0, t, t0="2.3", precision=precision)
        assert sol.success, sol.message
        assert sol.t_reached == Fraction(1, 10) or float(sol.t_reached) == 0.1
        assert rigid_error(sol.y_reached, Fraction(1, 10)) < 1e-14
