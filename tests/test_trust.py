"""Results that are right or loud: precision carried by the data, honest statuses, threads, hard limits.

Every expectation is an independent reference (closed forms of `lieseries.exact` at more digits, the exact
Hamiltonian, a hand-computed quantity) or a precise statement of what must happen (a status, a warning, an error
naming the argument).
"""

import math
import pickle
import threading
import time
import warnings

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.precision import PrecisionWarning, to_fraction

from problems import RIGID_INERTIA as INERTIA
from problems import RIGID_OMEGA as OMEGA
from problems import rigid_error as body_error


# -- 1. precision carried by the data -----------------------------------------------------------------------------
def test_exact_state_reaches_237_bits_without_a_precision_argument():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)  # no precision: the exact values are kept
    assert np.asarray(y0, float)[10] == 0.2 and "0.2" in repr(y0)  # numpy reads it as doubles
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        sol = ls.integrate(body, y0, t=2, precision=237)
    assert sol.success
    assert body_error(sol.y_final, 2) < 1e-68  # before: 7.8e-18 at t = 20 (the doubles of 0.1 and 0.5)


def test_binary_state_warns_once_naming_y0_and_runs_from_its_values():
    body = ls.EulerPoisson(INERTIA)
    y0 = np.asarray(body.initial_state(omega=OMEGA), dtype=float)
    with pytest.warns(PrecisionWarning, match=r"`y0` carries only 53 bits") as rec:
        sol = ls.integrate(body, y0, t=20, precision=237)
    assert len([w for w in rec if issubclass(w.category, PrecisionWarning)]) == 1
    assert sol.success
    # it is the exact run of the binary data: the decimal problem differs by about a double's rounding
    assert 1e-19 < body_error(sol.y_final, 20) < 1e-14


def test_a_state_rounded_to_a_lower_precision_warns_at_a_higher_one():
    body = ls.EulerPoisson(INERTIA)
    y0q = body.initial_state(omega=OMEGA, precision="quad")
    with pytest.warns(PrecisionWarning, match="113 bits"):
        ls.integrate(body, y0q, t=1, precision=237)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        ls.integrate(body, y0q, t=1, precision="double")  # lower precision: nothing to say


def test_float_parameters_and_constants_warn_by_name_above_double():
    with pytest.warns(PrecisionWarning, match="`inertia`"):
        body = ls.EulerPoisson((1.1, 2, 3))
        ls.integrate(body, body.initial_state(omega=(1, 0, 0)), t=1, precision=113)
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 + 0.05 * q**2)
    # named as typed in H (0.05), not as its derivative in the vector field (0.1), with what to do
    with pytest.warns(PrecisionWarning, match=r"`the constant 0.05 in hamiltonian`.*runtime parameter"):
        ls.integrate(osc, [1, 0], t=1, precision=113)
    quartic = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 + 0.1 * q**4)
    assert quartic.coarse_data() == {"the constant 0.1 in hamiltonian": 53}
    # many constants in one expression: one warning naming the first four and how many more
    many = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 + sum(hy.cos(k * q) / (10 * k) for k in range(1, 8)))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ls.integrate(many, [1, 0], t=1, precision=113)
    said = [str(w.message) for w in caught if issubclass(w.category, PrecisionWarning)]
    assert len(said) == 1 and "`the constants 0.014285714285714285, 0.016666666666666666, 0.02, 0.025 and 3 more " \
        "in hamiltonian` carry only 53 bits" in said[0] and "Make each a runtime parameter" in said[0], said
    # short dyadic constants are exact: no warning
    exact_osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 + 0.25 * q**2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        ls.integrate(exact_osc, [1, 0], t=1, precision=113)


def test_binary_times_warn_in_every_engine_and_the_run_is_for_their_binary_value():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    calls = {
        "integrate t list": lambda: ls.integrate(body, y0, t=[0.1, 1], precision=237),
        "integrate t array": lambda: ls.integrate(body, y0, t=np.array([0.1, 1]), precision=237),
        "integrate t0": lambda: ls.integrate(body, y0, t=1, t0=0.1, precision=237),
        "ensemble t": lambda: ls.integrate(body, [y0, y0], t=0.1, precision="quad"),
        "lie_integrate t": lambda: ls.lie_integrate(body, y0, t=0.1, dps=30),
        "lie_integrate t0": lambda: ls.lie_integrate(body, y0, t=[1], t0=0.1, dps=30),
        "lie_series call": lambda: ls.lie_series(body, y0, order=10, dps=30)(0.1),
        "validated t0": lambda: ls.validated_integrate(body, y0, t=1, t0=0.1, dps=30),
    }
    for name, call in calls.items():
        arg = "t0" if name.endswith("t0") else "t"  # each time argument is named as the user passed it
        with pytest.warns(PrecisionWarning, match=f"`{arg}` carries only 53 bits"):
            call()
    with pytest.warns(PrecisionWarning, match="`t` carries only 53 bits"):
        sol = ls.validated_integrate(body, y0, t=0.1, dps=30)
    # the enclosure is proven for the double nearest 0.1, not for 1/10: it holds the closed form at the first and
    # (its balls are far narrower than the 5.5e-18 between the two times) not at the second
    at = {when: to_fraction(exact.euler_poisson(INERTIA, OMEGA, when, dps=50)[10]) for when in (to_fraction(0.1), "0.1")}
    mid, rad = ls.validated.midpoints(sol)[-1][10], to_fraction(ls.validated.radii(sol)[-1][10])
    assert abs(at[to_fraction(0.1)] - mid) <= rad < 1e-28 and abs(at["0.1"] - mid) > 1e-18
    # exact and short binary times are silent, as are doubles in a double run
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        ls.integrate(body, y0, t=["0.1", 0.5, 1], precision=237)
        ls.lie_integrate(body, y0, t=[0.25, "0.3"], dps=30)
        ls.validated_integrate(body, y0, t="0.1", dps=30)
        ls.integrate(body, y0, t=[0.1, 1])


@pytest.mark.parametrize("precision, dtype_of", [("quad", lambda: np.dtype(hy.real128)), (160, None)])
def test_precision_left_out_runs_at_the_precision_of_y0(precision, dtype_of):
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA, precision=precision)
    sol = ls.integrate(body, y0, t=5)
    eps = ls.resolve_precision(precision).eps
    assert sol.stats.precision == ls.resolve_precision(precision).name
    assert body_error(sol.y_final, 5) < 1e3 * eps  # not double's 1e-15
    with pytest.raises(ValueError, match="`y0` holds mpmath numbers.*`precision=`"):
        ls.integrate(body, [mp.mpf(v) for v in np.asarray(y0, float)], t=1)


def test_a_single_run_and_an_ensemble_read_the_precision_of_the_same_data_alike():
    """Rows of mpf numbers are refused in an ensemble as in a single run (they ran in double, a 60-digit mpf
    losing its digits without a word), and long double scalars run in long double in both (a single run read them
    as double)."""
    body = ls.EulerPoisson(INERTIA)
    with mp.workdps(60):
        rows = [mp.mpf(v) for v in exact.euler_poisson(INERTIA, OMEGA, 0, dps=60)]
    for y in (rows, [rows, rows]):
        with pytest.raises(ValueError, match="`y0` holds mpmath numbers.*`precision=`"):
            ls.integrate(body, y, t=1)
    # the rows of 160-bit heyoka.real states stacked in one array (its dtype has no fixed precision) ran in
    # double
    y160 = np.asarray(body.initial_state(omega=OMEGA, precision=160))
    ens = ls.integrate(body, np.stack([y160, y160]), t=5)
    assert ens.stats["precision"] == "real160" and body_error(ens.y[1, -1], 5) < 1e-40
    if np.finfo(np.longdouble).nmant > 52:
        dyadic = (1, "0.5", "0.25")  # omega whose state is exact in binary: the run's error is its own
        y0 = [np.longdouble(v) for v in np.asarray(body.initial_state(omega=dyadic), dtype=float)]
        single, ens = ls.integrate(body, y0, t=5), ls.integrate(body, [y0, y0], t=5)
        assert single.stats.precision == ens.stats["precision"] == "long double"
        ref = exact.euler_poisson(INERTIA, dyadic, 5, dps=30)
        for y in (single.y_final, ens.y[1, -1]):
            assert np.asarray(y).dtype == np.longdouble
            err = max(abs(mp.mpf(to_fraction(a).numerator) / to_fraction(a).denominator - b) for a, b in zip(y, ref))
            assert err < 1e-16  # long double's 1e-19 steps; a double run is 1e-15 off here


def test_lie_estimates_never_claim_more_digits_than_the_data():
    body = ls.EulerPoisson(INERTIA)
    y0 = np.asarray(body.initial_state(omega=OMEGA), dtype=float)
    with pytest.warns(PrecisionWarning):
        series = ls.lie_series(body, y0, order=30, dps=70)
    actual = body_error(series(0.25), 0.25)  # against the decimal problem the user wrote
    assert actual > 1e-19  # the data's own rounding
    assert series.error_estimate(0.25) >= actual  # before: 4.5e-31 against an actual 1e-17
    with pytest.warns(PrecisionWarning):
        sol = ls.lie_integrate(body, y0, t=2, dps=40)
    assert max(sol.stats.error_estimates) >= body_error(sol.y_final, 2)  # before: 3e-72 against 6e-18
    # exact data keep the full claim
    series = ls.lie_series(body, body.initial_state(omega=OMEGA), order=30, dps=70)
    assert series.error_estimate(0.25) < 1e-25


def test_lie_series_takes_arrays_of_times_and_complex_times():
    body = ls.EulerPoisson(INERTIA)
    series = ls.lie_series(body, body.initial_state(omega=OMEGA), order=60, dps=40)
    rows = series(np.array([0.125, 0.25]))  # short binary times are exact: no warning
    assert len(rows) == 2 and body_error(rows[1], 0.25) < 1e-30
    # complex time: Omega(t) = I^-1 M(t), compared with the analytic continuation of the closed form
    tc = 0.2 + 0.1j
    M = series(tc)[9:]
    om = exact.angular_velocity(INERTIA, OMEGA, tc, dps=40)
    with mp.workdps(40):
        assert max(abs(M[i] / INERTIA[i] - om[i]) for i in range(3)) < 1e-30
    assert series.converges(tc) and series.error_estimate(tc) < 1e-20
    with pytest.raises(ValueError, match="`t`"):
        series(complex(float("nan"), 1))


# -- 2. statuses and rows ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("T", [5, 10])
def test_chart_edge_whatever_the_final_time(T):
    s = ls.Sphere()
    y0 = s.initial_state(x=("0.6", "0", "0.8"), v=(0, 1, 0))
    sol = ls.integrate(s, y0, t=T, atlas=False)
    assert sol.status == "chart_edge"  # before: 'step_collapse' ("the problem is stiff") for T = 10
    # x3(t) = 0.8 cos t reaches 0.05 |x| at cos t = 1/16
    assert float(sol.t_reached) == pytest.approx(math.acos(0.05 / 0.8), rel=1e-12)
    assert np.asarray(sol.y_final, float)[2] == pytest.approx(0.05, rel=1e-9)


def test_sphere_switches_charts_by_default_and_helpers_read_the_charts():
    s = ls.Sphere()
    x0, v0 = ("0.6", "0", "0.8"), (0, 1, 0)
    for sol in (ls.integrate(s, s.initial_state(x0, v0), t=[3, 10]),
                ls.lie_integrate(s, s.initial_state(x0, v0), t=[3, 10], dps=20)):
        assert sol.success and sol.stats.extra["chart_switches"] >= 2
        energy = s.invariants(sol.y)["energy"]  # before: 0.1745 instead of 0.5
        assert max(abs(e - 0.5) for e in energy) < 1e-13
        xe, _ = exact.sphere(1, x0, v0, 10, dps=30)
        for got in (s.position(sol)[-1], s.position(sol.y[-1]), s.position(sol.y_final)):
            assert max(abs(a - b) for a, b in zip(got, xe)) < 1e-13


def test_messages_come_from_the_run_that_produced_them():
    x0, v0 = ("0.6", "0", "0.8"), (0, 1, 0)
    for edge in (0.05, 0.2, 0.05):
        s = ls.Sphere(edge=edge)
        sol = ls.integrate(s, s.initial_state(x0, v0), t=5, atlas=False)
        assert f"{edge} * radius" in sol.message
        assert float(sol.t_reached) == pytest.approx(math.acos(edge / 0.8), rel=1e-12)


def test_t_equal_to_t0_is_success_with_one_row():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    for sol in (ls.integrate(body, y0, t=0), ls.integrate(body, y0, t=3, t0=3),
                ls.lie_integrate(body, y0, t=0, dps=20)):
        assert sol.status == "success" and len(sol.t) == 1
        assert [float(v) for v in sol.y[0]] == [float(v) for v in np.asarray(y0, float)]


def test_solution_is_immutable_and_y_final_is_the_state_reached():
    s = ls.Sphere()
    sol = ls.integrate(s, s.initial_state(("0.6", "0", "0.8"), (0, 1, 0)), t=[0, 5], atlas=False)
    assert sol.status == "chart_edge" and len(sol.t) == 1  # only t = 0 was reached as an output row
    assert np.asarray(sol.y_final, float)[2] == pytest.approx(0.05, rel=1e-9)  # before: the t = 0 row
    with pytest.raises(AttributeError):
        sol.status = "success"
    with pytest.raises(ValueError):
        sol.y[0, 0] = 1.0
    with pytest.raises(ValueError):
        sol.y_reached[0] = 1.0


def test_every_solution_pickles_dense_output_included():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    for sol in (ls.integrate(body, y0, t=10, dense=True), ls.lie_integrate(body, y0, t=2, dps=20, dense=True),
                ls.integrate(ls.Sphere(), ls.Sphere().initial_state(("0.6", "0", "0.8"), (0, 1, 0)), t=[5])):
        back = pickle.loads(pickle.dumps(sol))
        assert back.status == sol.status and back.message == sol.message
        np.testing.assert_array_equal(np.asarray(back.y, float), np.asarray(sol.y, float))
        if sol._dense is not None:
            assert body_error(back(1.5), 1.5) < 1e-13


def test_mixed_scales_are_not_stiff():
    """An oscillator beside a conserved variable of size 1e4: not stiff (before: 'stiff' at t = 0.18)."""
    q, p, c = hy.make_vars("q", "p", "c")
    sys = ls.PoissonSystem([q, p, c], [[0, 1, 0], [-1, 0, 0], [0, 0, 0]], (p**2 + q**2) / 2 + 0 * c)
    sol = ls.integrate(sys, [1, 0, 10000], t=2000)
    assert sol.success, sol.message
    assert float(sol.y_final[0]) == pytest.approx(math.cos(2000), abs=1e-9)


def test_a_motion_slow_for_its_time_span_is_not_success():
    """omega ~ 1e-16 over T ~ 1e17 (the omega = 1, T = 20 motion rescaled): heyoka's coefficients underflow and
    one step 'succeeds' with a relative error of 8e16. The energy check says so."""
    body = ls.EulerPoisson(INERTIA)
    slow = body.initial_state(omega=("1e-16", "1e-17", "5e-17"))
    sol = ls.integrate(body, slow, t="2e17")
    assert sol.status == "invariant_drift" and "rescale time" in sol.message
    # at 5e16 and 1e17 the energy moves by far less than 1 but by far more than its own size (9e-33): before, an
    # absolute floor of 1 let these pass as success, with R no longer a rotation
    for T in ("5e16", "1e17"):
        sol = ls.integrate(body, slow, t=T)
        assert float(body.invariants(sol.y_final)["orthogonality"]) > 1  # independent: R^T R is far from 1
        assert sol.status == "invariant_drift", T
        # the span in one or two steps (the first bounded where the last two orders underflow to 0 while lower
        # ones do not: lieseries.heyoka_build.sparse_first_step); each step a sizeable part of T
        assert sol.stats.steps <= 2 and sol.stats.min_step > float(T) / 4
    # an ensemble member ends as its single run does
    ens = ls.integrate(body, [slow, body.initial_state(omega=(1, "0.1", "0.5"))], t="1e17", max_steps=10)
    assert list(ens.status) == ["invariant_drift", "step_budget"]
    # the same motion in rescaled time is right: M(2e17) = 1e-16 M_fast(20)
    fast = ls.integrate(body, body.initial_state(omega=(1, "0.1", "0.5")), t=20)
    assert fast.success and body_error(fast.y_final, 20) < 1e-13


def test_closed_forms_at_huge_times_are_computed_not_noise():
    # sphere, w = 1: x1(t) = 0.6 cos t, computed directly with enough digits for the argument reduction
    x, _ = exact.sphere(1, ("0.6", "0", "0.8"), (0, 1, 0), "1e300", dps=20)
    with mp.workdps(340):
        ref = mp.mpf("0.6") * mp.cos(mp.mpf(10) ** 300)
    assert abs(x[0] - ref) < 1e-18
    # rigid body: the answer at 20 digits agrees with the one at 40 digits (noise would not)
    a = exact.angular_velocity(INERTIA, OMEGA, "1e300", dps=20)
    b = exact.angular_velocity(INERTIA, OMEGA, "1e300", dps=40)
    assert max(abs(u - v) for u, v in zip(a, b)) < 1e-18


# -- 3. threads --------------------------------------------------------------------------------------------------------
def test_four_threads_on_different_systems_and_precisions_each_match_their_reference():
    bodies = [ls.EulerPoisson((1, 2, 3)), ls.EulerPoisson((2, 3, 4)), ls.EulerPoisson((1, 2, 3)),
              ls.EulerPoisson((3, 4, 5))]
    jobs = [("double", bodies[0], 1e-13), (113, bodies[1], 1e-30), ("lie60", bodies[2], 1e-55),
            ("lie15", bodies[3], 1e-12)]
    errors, failures = {}, []

    def work(i, kind, body, bound):
        try:
            inertia = tuple(int(v) for v in np.diag(body.inertia))
            y0 = body.initial_state(omega=OMEGA)
            worst = 0.0
            for rep in range(6):
                T = 1 + rep % 3
                if kind == "lie60":
                    row = ls.lie_series(body, y0, order=70, dps=60)(mp.mpf(T) / 10)
                    T = mp.mpf(T) / 10
                elif kind == "lie15":
                    row = ls.lie_integrate(body, y0, t=T, dps=15).y_final
                else:
                    row = ls.integrate(body, y0, t=T, precision=kind).y_final
                ref = exact.euler_poisson(inertia, OMEGA, T, dps=70)
                worst = max(worst, float(max(abs(to_fraction(a) - to_fraction(b)) for a, b in zip(row, ref))))
            errors[i] = worst
            if worst > bound:
                failures.append((kind, worst))
        except Exception as exc:  # pragma: no cover - a failure is reported below
            failures.append((kind, repr(exc)))

    threads = [threading.Thread(target=work, args=(i, *job)) for i, job in enumerate(jobs)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not failures, failures
    assert len(errors) == 4


def test_events_in_threads_are_each_runs_own():
    """Four bodies' M2 = 0 crossings, 120 runs over four threads: each run returns its own crossings (before, a
    run could return with the crossings of another thread's run on the same pooled integrator)."""
    from concurrent.futures import ThreadPoolExecutor

    body = ls.EulerPoisson(INERTIA)
    ev = [ls.Event(hy.make_vars("M2"), name="m2")]
    states = [body.initial_state(omega=w) for w in (OMEGA, ("0.2", "0.1", 1), (1, "-0.3", "0.2"), ("0.5", 1, 1))]
    alone = [list(ls.integrate(body, y, t=30, events=ev).events["m2"]["t"]) for y in states]
    assert all(alone) and len({len(a) for a in alone}) > 1  # every body crosses, not all equally often
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(lambda i: list(ls.integrate(body, states[i % 4], t=30, events=ev).events["m2"]["t"]),
                            range(120)))
    assert [i for i, g in enumerate(got) if g != alone[i % 4]] == []


# -- 4. hard limits ----------------------------------------------------------------------------------------------------
def test_limits_refuse_at_once_naming_the_argument():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    cases = [
        (lambda: ls.integrate(body, y0, t=1, tol=1e-300), "`tol`.*below the epsilon of double"),
        (lambda: ls.integrate(body, y0, t=1, precision=4000), "`precision`.*at most|`precision` as a number"),
        (lambda: ls.lie_series(body, y0, order=5000), "`order` must be at most"),
        (lambda: ls.lie_series(body, y0, dps=100_000), "`dps` must be at most"),
        (lambda: ls.integrate(body, y0, t="1e99999999"), "`t`.*out of range"),
        (lambda: ls.integrate(body, y0, t="1e400"), "`t`.*overflows double"),
        (lambda: ls.integrate(body, y0, t="1/0"), "`t`.*divides by zero"),
        (lambda: ls.EulerPoisson(("1e99999999", 1, 1)), "`inertia\\[0\\]`.*out of range"),
    ]
    for call, pattern in cases:
        tic = time.perf_counter()
        with pytest.raises(ValueError, match=pattern):
            call()
        assert time.perf_counter() - tic < 5  # refused, not attempted (a generous bound; no timing claim)


def test_max_time_bounds_a_high_precision_run():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    ls.integrate(body, y0, t="0.01", precision=256)  # compile once (compilation is not bounded)
    tic = time.perf_counter()
    sol = ls.integrate(body, y0, t=1e6, precision=256, max_time=0.05)
    assert sol.status == "time_budget"
    assert time.perf_counter() - tic < 10  # before: precision=4000, max_time=1 took 69 s


def test_fixed_order_far_below_the_automatic_one_warns():
    body = ls.EulerPoisson(INERTIA)
    with pytest.warns(UserWarning, match="`order` = 8 is far below the automatic order"):
        sol = ls.lie_integrate(body, body.initial_state(omega=OMEGA), t="0.05", dps=40, order=8, max_steps=3)
    assert sol.status == "step_budget"


def test_numpy_integers_are_counts_everywhere():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    sol = ls.lie_integrate(body, y0, t=5, dps=20, max_steps=np.int64(2))  # before: refused
    assert sol.status == "step_budget" and sol.stats.steps == 2
    assert ls.integrate(body, y0, t=5, max_steps=np.int64(3)).status == "step_budget"


def test_invariants_of_an_exact_state_are_exact_to_far_beyond_quad():
    """An ExactState has no format: its invariants are evaluated well above quad (they were once taken at the
    float64 view's 69 bits, which made quad runs' invariant drift read 1e-22 in reports)."""
    body = ls.EulerPoisson(INERTIA)
    inv = body.invariants(body.initial_state(omega=OMEGA))
    with mp.workdps(80):
        assert abs(inv["energy"] - mp.mpf(177) / 200) < 1e-70  # (1 + 2 * 0.01 + 3 * 0.25) / 2
        assert abs(inv["M2"] - mp.mpf(329) / 100) < 1e-70      # 1 + 0.04 + 2.25


def test_natural_slips_are_refused_naming_what_to_change():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    # events: a constant never crosses zero; a time-dependent one is not a function of the state (both engines)
    for run in (lambda ev: ls.integrate(body, y0, t=1, events=ev), lambda ev: ls.lie_integrate(body, y0, t=1, dps=20,
                                                                                              events=ev)):
        with pytest.raises(ValueError, match=r"`events\[0\]` is the constant 1.0+, which never crosses zero"):
            run([ls.Event(hy.expression(1.0))])
        with pytest.raises(ValueError, match=r"`events\[1\]` \('half'\) depends on time"):
            run([ls.Event(hy.make_vars("M2")), ls.Event(hy.time - 0.5, name="half")])
    # per-member parameters are the entries of I^-1: a zero (infinite moment) or negative one is no body
    for bad in ([1, 0, "0.3"], [1, -1, "0.3"]):
        with pytest.raises(ValueError, match=r"`params\[1\]` gives the inverse inertia .* not positive definite"):
            ls.integrate(body, [y0, y0], t=1, params=[[1, "0.5", "0.3"], bad])
    full = ls.EulerPoisson([[2, "0.1", 0], ["0.1", 3, 0], [0, 0, 4]])
    with pytest.raises(ValueError, match=r"`params\[0\]` gives the inverse inertia"):
        ls.integrate(full, [full.initial_state((1, 0, 0))], t=1, params=[[1, 2, 0, 1, 0, 1]])  # det < 0
    with pytest.raises(ValueError, match=r"damping must be >= 0"):
        damped = ls.DampedEulerPoisson(INERTIA, damping="0.1")
        ls.integrate(damped, [y0], t=1, params=[[1, "0.5", "0.25", -1]])
    # an uncertainty wider than the enclosures may grow is refused up front, naming max_width
    with pytest.raises(ValueError, match=r"`y0` has a ball of radius 0.5, already wider than `max_width`"):
        ls.validated_integrate(body, [(v, "0.5") for v in y0.exact], t=1, dps=20)
    # a time span beyond any step budget says so with finite numbers, not "inf"
    sol = ls.integrate(body, y0, t="1e400", precision="quad", max_steps=200)
    assert sol.status == "step_budget" and "inf" not in sol.message
    assert "~1e400 time units remain" in sol.message and "shorten the time span" in sol.message


def test_scenes_and_studies_never_set_mpmath_global_precision(tmp_path, monkeypatch):
    """mpmath's global precision is process-wide (not thread-safe, and the user's own): a scene with the Lie
    series, the mpmath peer, the error-vs-order and work-precision studies, and a departure map run with a guard
    that refuses any change of ``mpmath.mp.prec`` or ``mpmath.mp.dps``. Their results keep their digits: errors
    against the closed form far below a double's (the mpmath peer started from the double rounding of the
    state's 0.2 and reached only 1e-17 at 30 digits)."""
    import mpmath
    from mpmath.ctx_mp_python import PythonMPContext

    from lieseries.run import run_scene
    from lieseries.scenes import load_scene
    from lieseries.studies import departure_map

    for name in ("prec", "dps"):
        prop = PythonMPContext.__dict__[name]

        def guarded(ctx, value, _set=prop.fset, _name=name):
            if ctx is mpmath.mp:
                raise AssertionError(f"mpmath.mp.{_name} set to {value}")
            _set(ctx, value)

        monkeypatch.setattr(PythonMPContext, name, property(prop.fget, guarded))
    path = tmp_path / "g.toml"
    path.write_text('name = "g"\ntitle = "global precision guard"\n[model]\nkind = "euler_poisson"\n'
                    'inertia = [1, 2, 3]\n[initial]\nomega = [1, "0.1", "0.5"]\n[run]\nt = "1/2"\nsamples = 3\n'
                    'repeat = 1\n'
                    'methods = [{ method = "lie", dps = 30 }, { method = "mpmath", dps = 30, t_max = "1/2" }]\n'
                    '[studies.error_vs_order]\nt_fraction = 0.1\nmax_order = 40\ndps = 40\n'
                    '[studies.work_precision]\nt = "1/2"\nrepeat = 1\nmethods = [{ method = "lie", dps = 25, '
                    'tol = [1e-20] }, { method = "mpmath", dps = [20], t_max = "1/4" }]\n')
    result = run_scene(load_scene(str(path)), progress=False)
    errors = {row.method: row.error for row in result.run["rows"]}
    assert all(row.status == "success" for row in result.run["rows"])
    assert errors["lie"] < 1e-27 and errors["mpmath"] < 1e-27
    assert min(result.studies["error_vs_order"][0][1].errors) < 1e-30
    dm = departure_map(grid=(2, 2), T=1, samples=2, precisions=("double",), dps=40)
    assert float(np.max(dm.max_error["double"])) < 1e-14


def test_a_motion_whose_energy_lies_beyond_the_format_is_not_a_success():
    """omega ~ 1e-200 to t = 2e201 is the motion of omega = (1, 0.1, 0.5) to t = 2, slowed down: its energy ~1e-400
    is 0 in double and its Taylor coefficients underflow in double and quad, so heyoka takes one step over the whole
    span (double: the state unchanged; quad: R entries ~1e19). Neither may read success; long double, whose range
    holds the motion, is right against the closed form."""
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    om, T = ("1e-200", "1e-201", "5e-201"), "2e201"
    y0 = body.initial_state(omega=om)
    ref = exact.euler_poisson((1, 2, 3), om, T, dps=30)
    for p in ("double", "quad"):
        sol = ls.integrate(body, y0, t=T, precision=p)
        assert sol.status == "invariant_drift", (p, sol.status)
        assert abs(float(sol.y[-1][0]) - float(ref[0])) > 0.1  # the state is indeed wrong
    ens = ls.integrate(body, [y0, y0], t=T)  # the batch members in double
    assert list(ens.status) == ["invariant_drift"] * 2 and "below the smallest normal" in ens.message[0]
    sol = ls.integrate(body, y0, t=T, precision="long double")
    if np.finfo(np.longdouble).nmant > 52:  # an x87 long double (range 1e-4932)
        assert sol.status == "success"
        assert max(abs(float(a) - float(b)) for a, b in zip(sol.y[-1][:9], ref[:9])) < 1e-12


def test_the_guard_reads_the_casimirs_of_the_bracket_too():
    """The rigid body's energy depends on M alone: an end state whose R was wrecked (doubled) keeps H exactly, but
    the entries of R R^T are Casimirs of the Chetaev bracket ({R, R} = 0 and M_i moves R by R -> R exp(tA), A
    antisymmetric), so the guard reports invariant_drift; the true end state passes."""
    from lieseries.energy import energy_function, energy_verdict
    from lieseries.precision import resolve_precision
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    y0 = body.initial_state(omega=OMEGA)
    assert set(body.poisson.casimirs) == {"RRT11", "RRT12", "RRT13", "RRT22", "RRT23", "RRT33"}
    prec = resolve_precision("double")
    true_end = np.array([float(v) for v in exact.euler_poisson(INERTIA, OMEGA, 2, dps=30)])
    energy = energy_function(body.poisson, prec, np.asarray(y0, dtype=float))
    assert energy_verdict(energy, 1.5e-8, true_end, 10, "success", "Reached t = 2.")[0] == "success"
    wrecked = true_end.copy()
    wrecked[:9] *= 2
    status, message = energy_verdict(energy, 1.5e-8, wrecked, 10, "success", "Reached t = 2.")
    assert status == "invariant_drift" and "Casimir" in message


@pytest.mark.parametrize("precision, eps", [("double", 2.0**-52), ("quad", 2.0**-112)])
def test_a_casimir_that_vanishes_with_its_terms_at_y0_is_measured_in_its_own_units(precision, eps):
    """The Dirac sphere from x = (0.6, 0, 0.8) at speed 10^6: x . p and its terms x_i p_i all vanish at y0, and
    the guard measured its change against |x|^2 (1) where its own size is |x| |p| (10^6): a run right to eps
    (against the great circle) ended invariant_drift, "the result is wrong". Its terms at the end give its size; a
    wrecked end state (p turned off the sphere's tangent plane) is still caught."""
    from lieseries.energy import energy_function, energy_verdict
    from lieseries.precision import resolve_precision

    sphere = ls.SphereDirac()
    x, v, t = ("0.6", 0, "0.8"), (0, 10**6, 0), "3e-6"
    y0 = sphere.initial_state(x, v)
    sol = ls.integrate(sphere, y0, t=t, precision=precision)
    ex, _ = exact.sphere(1, x, v, t, dps=40)
    assert sol.status == "success", sol.message
    assert max(abs(float(a) - float(b)) for a, b in zip(sol.y[-1][:3], ex)) < 64 * eps
    energy = energy_function(sphere.poisson, resolve_precision("double"), np.asarray(y0, dtype=float))
    wrecked = np.array([float(c) for c in sol.y[-1]])
    xs, ps = wrecked[:3], wrecked[3:]  # p turned by 1e-3 towards x: H kept, x . p = 1e3 (1e-3 of its size)
    wrecked[3:] = math.cos(1e-3) * ps + math.sin(1e-3) * np.linalg.norm(ps) * xs / np.linalg.norm(xs)
    status, message = energy_verdict(energy, 1.5e-8, wrecked, 3, "success", "Reached t = 3e-6.")
    assert status == "invariant_drift" and "Casimir" in message


def test_a_span_the_run_cannot_hold_beside_a_large_t0_is_said():
    """t0 = 10^6, t = '1000000.1' in double: the times are rounded to doubles, and the run goes 0.0999999999767
    time units, its state 2e-11 from the closed form at 0.1, with a success: now with one PrecisionWarning naming
    t - t0. The same from t0 = 0, or outputs at '5.1', '5.3' from t0 = 5, keep the span to the run's precision
    and say nothing; the Lie engine, which adds its steps to times of 30 digits, says so from t0 = 10^20. A span
    heyoka would keep to fewer than 8 bits is refused."""
    body = ls.EulerPoisson(inertia=INERTIA)
    y0 = body.initial_state(omega=OMEGA)

    def run(fn):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            sol = fn()
        return sol, [str(x.message) for x in w if issubclass(x.category, PrecisionWarning)]

    sol, msgs = run(lambda: ls.integrate(body, y0, t="1000000.1", t0=10**6))
    assert len(msgs) == 1 and "`t` - `t0` = 0.1 " in msgs[0] and "32 bits" in msgs[0], msgs
    assert body_error(sol.y[-1], "0.1", dps=40) > 1e-12  # the state is indeed that far from the one asked for
    sol, msgs = run(lambda: ls.integrate(body, y0, t="0.1"))
    assert msgs == [] and body_error(sol.y[-1], "0.1", dps=40) < 1e-15
    assert run(lambda: ls.integrate(body, y0, t=["5.1", "5.3", "7.7"], t0=5))[1] == []
    assert len(run(lambda: ls.integrate(body, [y0, y0], t="1000000.1", t0=10**6))[1]) == 1
    _, msgs = run(lambda: ls.lie_integrate(body, y0, t=10**20 + 100, t0=10**20, dps=20))
    assert len(msgs) == 1 and "30 digits" in msgs[0], msgs
    assert run(lambda: ls.lie_integrate(body, y0, t=10**6 + 100, t0=10**6, dps=20))[1] == []
    # a span heyoka's times cannot hold at all (t0 = 10^20, t - t0 = 1 in double: no step, `success` at y0) is
    # refused, naming `t0`, for a single run and an ensemble
    for call in (lambda: ls.integrate(body, y0, t=10**20 + 1, t0=10**20),
                 lambda: ls.integrate(body, [y0, y0], t=10**20 + 1, t0=10**20)):
        with pytest.raises(ValueError, match=r"`t0` = .* too large beside `t` - `t0` = 1 .*start from t0 = 0"):
            call()
    # an atlas run restarts at each chart switch from a time rounded near t0: the Sphere from t0 = 10^12 to t0 + 10
    # ended `success` 2e-4 off with no warning; refused, alone and in an ensemble. From t0 = 1000 it runs, on the
    # motion from t0 = 0
    sphere = ls.Sphere()
    x0 = sphere.initial_state(x=("0.6", "0", "0.8"), v=(0, 1, 0))
    for call in (lambda: ls.integrate(sphere, x0, t=10**12 + 10, t0=10**12),
                 lambda: ls.integrate(sphere, [x0, x0], t=10**12 + 10, t0=10**12)):
        with pytest.raises(ValueError, match=r"`t0` = 1000000000000 is too large .* for a run across charts"):
            call()
    later, first = ls.integrate(sphere, x0, t=1010, t0=1000), ls.integrate(sphere, x0, t=10)
    assert later.status == first.status == "success"
    np.testing.assert_allclose(np.asarray(sphere.position(later)[-1], dtype=float),
                               np.asarray(sphere.position(first)[-1], dtype=float), rtol=0, atol=1e-12)
    # at 113 bits the same times are exact: no warning, and the state at t - t0 = 1
    sol, msgs = run(lambda: ls.integrate(body, y0, t=10**20 + 1, t0=10**20, precision=113))
    assert msgs == [] and body_error(sol.y[-1], "1", dps=40) < 1e-30


def test_statuses_beyond_the_double_range_of_time():
    """omega ~1e-2000 to t = 2e2001 (the same motion slowed down): quad, long double and 113 bits all end without
    success (the Taylor coefficients underflow), and their messages print the time instead of failing to make a
    double of it (an OverflowError at 113 bits)."""
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    y0 = body.initial_state(omega=("1e-2000", "1e-2001", "5e-2001"))
    for p in ("quad", 113):
        sol = ls.integrate(body, y0, t="2e2001", precision=p)
        assert sol.status != "success" and ("1e2001" in sol.message or "1e2000" in sol.message), (p, sol.message)


def test_a_run_at_400_digits_is_a_success_with_its_error_and_drift_at_400_digits(tmp_path):
    """Above a double's range: the energy guard's threshold (1e-400 as a float was 0.0: every such run was
    `invariant_drift`), the final error against the closed form (printed "0"), the initial invariants of an exact
    state (read at 256 bits: a drift of 2e-83; and a state of dyadic numbers must not be read at their own short
    significands) and data.json (1e-402 written as 0.0) keep their size, and so does the error scaled to each quantity's size."""
    import json

    from lieseries.report import write_report
    from lieseries.run import run_scene
    from lieseries.scenes import parse_scene

    scene = parse_scene('name = "x"\ntitle = "x"\ndescription = "x"\n[model]\nkind = "euler_poisson"\n'
                        'inertia = [1, 2, 3]\n[initial]\nomega = [1, "0.5", 2]\n[run]\nt = "0.125"\nsamples = 3\n'
                        'repeat = 1\n'
                        'methods = [{ method = "lie", dps = 400 }]\n')  # dyadic data: short mpf significands; one step
    res = run_scene(scene, progress=False)
    row, = res.run["rows"]
    assert row.status == "success", row.message
    assert 0 < row.error < mp.mpf(10) ** -399 and all(0 <= d < mp.mpf(10) ** -398 for d in row.drift.values())
    assert 0 < row.scaled_error < mp.mpf(10) ** -399  # written 0.0 (float of an mpf below a float's range)
    write_report(res, tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    line = next(ln for ln in md.splitlines() if ln.startswith("| Lie series 400 dps"))
    assert "e-40" in line and "| 0 " not in line
    data = json.loads((tmp_path / "rep" / "data.json").read_text())
    assert "e-40" in json.dumps(data["run"]["rows"][0]["error"])
    assert "e-40" in json.dumps(data["run"]["rows"][0]["scaled_error"])


def test_a_lie_run_at_400_digits_reports_its_tolerance():
    """``sol.stats.tol`` of a 400-digit Lie run read 0.0: a tolerance that claims every digit."""
    body = ls.EulerPoisson((1, 2, "2.5"))
    sol = ls.lie_integrate(body, body.initial_state(omega=(1, "0.1", "0.5")), t="0.05", dps=400)
    assert sol.status == "success" and mp.mpf(10) ** -401 < sol.stats.tol < mp.mpf(10) ** -399


def test_a_validated_run_at_400_digits_reports_its_tolerance():
    """``sol.stats.tol`` of a 400-digit validated run read 0.0."""
    body = ls.EulerPoisson((1, 2, "2.5"))
    sol = ls.validated_integrate(body, body.initial_state(omega=(1, "0.1", "0.5")), t="0.01", dps=400)
    assert sol.status == "success" and mp.mpf(10) ** -401 < sol.stats.tol < mp.mpf(10) ** -399


def test_a_binary_constant_in_the_hamiltonian_does_not_make_a_right_run_wrong():
    """H = p^2/2 - q + q^3/3: heyoka stores 1/3 as the nearest double and folds 3 * 0.333... of the derivative to
    1.0, so the field is the gradient of H to 53 bits only. A 30-digit Lie run right to 1e-33 (against a 60-digit
    run of the same field) ended invariant_drift, "the result is wrong", on H's change of 2e-18 -- the constant the
    PrecisionWarning names is the cause, not the run; from rest at q = 0 (H and its terms vanish at y0) the
    threshold was 0. A heyoka double run from there is right too (its series has the orders 2, 6, 10, ... only:
    test_heyoka_bounds_a_first_step_whose_last_two_orders_vanish)."""
    import heyoka as hy

    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - q + q**3 / 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PrecisionWarning)
        for y0 in ([0, 0], ["0.5", 0]):
            sol = ls.lie_integrate(osc, y0, t=1, dps=30)
            ref = ls.lie_integrate(osc, y0, t=1, dps=60)
            assert sol.status == "success", sol.message
            with mp.workdps(60):
                assert max(abs(mp.mpf(a) - mp.mpf(b)) for a, b in zip(sol.y_reached, ref.y_reached)) < 1e-31
        sol = ls.integrate(osc, [0, 0], t=1)
        ref = ls.lie_integrate(osc, [0, 0], t=1, dps=60)
        with mp.workdps(60):
            assert max(abs(mp.mpf(float(a)) - mp.mpf(b)) for a, b in zip(sol.y_reached, ref.y_reached)) < 1e-15
        assert sol.status == "success", sol.message


def _exact(x):
    f = to_fraction(x)
    return mp.mpf(f.numerator) / f.denominator


@pytest.mark.parametrize("precision, tol", [("double", 1e-15), ("long double", 1e-18), ("quad", 1e-32),
                                            (113, 1e-32)])
def test_heyoka_bounds_a_first_step_whose_last_two_orders_vanish(precision, tol):
    """H = p^2/2 - q + q^3 from rest at q = 0: q has only the orders 2, 6, 10, ... of t and p only 1, 5, 9, ...;
    heyoka sizes a step from its last two orders (both 0 at order 20 in double, 40 in quad) and took the whole
    span in one step: off by 3.5e-7 in double and 5e-15 in quad, ended invariant_drift (and the energy guard, its
    scale 0 at y0, called any change wrong). Single runs (plain, events, dense, output times) and ensembles (the
    batch, the scalar threads) are now right against a 60-digit Lie run and end success."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - q + q**3)
    with mp.workdps(60):
        ref = [_exact(v) for v in ls.lie_integrate(osc, [0, 0], t=1, dps=60).y_reached]

        def err(y):
            return max(abs(_exact(a) - b) for a, b in zip(y, ref))

        runs = [ls.integrate(osc, [0, 0], t=1, precision=precision),
                ls.integrate(osc, [0, 0], t=1, precision=precision, events=[ls.Event(q - 2, name="far")]),
                ls.integrate(osc, [0, 0], t=1, precision=precision, dense=True),
                ls.integrate(osc, [0, 0], t=[0.5, 1], precision=precision)]
        for sol in runs:
            assert sol.status == "success", sol.message
            assert err(sol.y_reached) < tol
        if not isinstance(precision, int):
            es = ls.integrate(osc, [[0, 0], ["1/2", 0], [0, 0]], t=1, precision=precision)
            assert list(es.status) == ["success"] * 3
            assert err(es.y_reached[0]) < tol and err(es.y_reached[2]) < tol


@pytest.mark.parametrize("precision, tol", [("double", 1e-15), ("quad", 1e-32)])
def test_heyoka_bounds_a_first_step_whose_last_two_orders_are_small(precision, tol):
    """The same field from q = 1e-6, 1e-12, 1e-20 instead of 0: orders 19 and 20 are not zero but small, heyoka's
    rho from them came out 1.9-3x too long and its first step was off: 6e-14 in double from 1e-6 (270 units of
    its last place) with status success, 3.5e-7 and 125 (to t = 3) invariant_drift from 1e-12 and 1e-20; quad
    6e-33 from 1e-5. The first step is bounded where heyoka's rho exceeds the smallest its last orders give by a
    quarter. Single runs and ensembles, against 40-digit Lie runs."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - q + q**3)
    q0s = ("1e-5", "1e-6", "1e-12", "1e-20")
    # the ensemble (the batch in double, the scalar threads in quad) checked only members that went the whole way
    # in one step: 6e-14 (double) and 8e-32 (quad) off from 1e-6 with success, the others invariant_drift
    es = ls.integrate(osc, [[q0, 0] for q0 in q0s], t=3, precision=precision)
    for i, q0 in enumerate(q0s):
        sol = ls.integrate(osc, [q0, 0], t=3, precision=precision)
        ref = ls.lie_integrate(osc, [q0, 0], t=3, dps=40)
        with mp.workdps(60):
            for y, status, message in ((sol.y_reached, sol.status, sol.message),
                                       (es.y_reached[i], es.status[i], es.message[i])):
                assert status == "success", (q0, message)
                assert max(abs(_exact(a) - mp.mpf(b)) for a, b in zip(y, ref.y_reached)) < 3 * tol, q0


@pytest.mark.parametrize("precision, tol", [("double", 1e-15), ("quad", 1e-32)])
def test_a_first_step_taken_back_for_its_bound_leaves_no_trace(precision, tol):
    """The bound on a first step is read from the run's own first step (its Taylor coefficients): from rest at
    q = 0 heyoka's first step spans the whole run and is taken back, then taken again bounded. Nothing of the
    step taken back stays: the crossing of p = 1/2 at t ~ 0.5 that it spans is recorded once, where the 40-digit
    Lie run has it, a terminal event stops the run there, and a call's first run (which reads the series) gives
    the bits of its repeated runs (the bound known). A first step within the bound (a span of 1e-3) is kept: the
    run is that one step."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - q + q**3)
    half = 2 * p - 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PrecisionWarning)
        lie = ls.lie_integrate(osc, [0, 0], t=1, dps=40, events=[ls.Event(half, name="half")])
        stop = ls.lie_integrate(osc, [0, 0], t=1, dps=40, events=[ls.Event(half, terminal=True, name="half")])
    (t_ref,) = lie.events["half"]["t"]
    with mp.workdps(60):
        def err(y, ref):
            return max(abs(_exact(a) - _exact(b)) for a, b in zip(y, ref))

        sol = ls.integrate(osc, [0, 0], t=1, precision=precision, events=[ls.Event(half, name="half")])
        assert sol.status == "success" and err(sol.y_reached, lie.y_reached) < 3 * tol
        assert len(sol.events["half"]["t"]) == 1 and abs(_exact(sol.events["half"]["t"][0]) - _exact(t_ref)) < 10 * tol
        sol = ls.integrate(osc, [0, 0], t=1, precision=precision, events=[ls.Event(half, terminal=True, name="half")])
        assert sol.status == "event" and abs(_exact(sol.t_reached) - _exact(t_ref)) < 10 * tol
        assert err(sol.y_reached, stop.y_reached) < 10 * tol
        y0 = np.zeros(2)  # a float64 array: the call is memoised, its repeated runs know the bound
        for t in (1, [0.25, 0.5, 1], "1e-3"):
            runs = [ls.integrate(osc, y0, t=t, precision=precision) for _ in range(3)]
            assert all(r.status == "success" for r in runs)
            for r in runs[1:]:
                assert r.stats.steps == runs[0].stats.steps
                assert np.array_equal(r.y, runs[0].y) and np.array_equal(r.y_reached, runs[0].y_reached)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", PrecisionWarning)
                ref = ls.lie_integrate(osc, [0, 0], t=t, dps=40)
            assert err(runs[0].y_reached, ref.y_reached) < 3 * tol
            if t == "1e-3":
                assert runs[0].stats.steps == 1


@pytest.mark.parametrize("precision, tol", [("double", 1e-15), ("long double", 1e-18), ("quad", 1e-32)])
def test_a_right_run_from_rest_where_h_and_its_terms_vanish_is_success(precision, tol):
    """H = p^2/2 - q + q^4/4 from rest at q = 0: H(y0) = 0 and so is the energy scale sum_i |dH/dy_i y_i| at y0,
    so the heyoka guard's threshold was 0 and a double run right to 7e-17 (single, and in the ensemble's batch)
    ended invariant_drift; in long double and quad (q has the orders 2, 8, 14, ..., p 1, 7, 13, ...: both of
    their last two orders vanish) one step over the span was off by 4e-9 and 5e-16. The guard reads the larger
    of the scales at y0 and at the end, as the driver's does."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - q + q**4 / 4)
    with mp.workdps(60):
        ref = [_exact(v) for v in ls.lie_integrate(osc, [0, 0], t=1, dps=60).y_reached]
        sol = ls.integrate(osc, [0, 0], t=1, precision=precision)
        es = ls.integrate(osc, [[0, 0], [0, "1/2"]], t=1, precision=precision)
        assert sol.status == "success", sol.message
        assert list(es.status) == ["success", "success"], es.message
        for y in (sol.y_reached, es.y_reached[0]):
            assert max(abs(_exact(a) - b) for a, b in zip(y, ref)) < tol


def test_heyoka_above_64_bits_warns_of_a_field_that_cancels_at_y0():
    # y' = (p + x)^2 - p^2 - 2 p x - x^2 + r cos y = r cos y beside x = 6e20: heyoka at 226 bits ended `success` with
    # y 6.5e-27 off (the squares rounded at 2^(138 - 226)), its error estimate blind to it; the warning says so
    x, y = hy.make_vars("x", "y")
    p, r = hy.par[0], hy.par[1]
    sy = ls.PoissonSystem([x, y], [[0, 0], [0, 0]], 0.0 * x,
                          extra_field=[r * y, (p + x) * (p + x) - p * p - 2.0 * p * x - x * x + r * hy.cos(y)],
                          parameters=["6e-21", "1e-14"], jacobi=False)
    with pytest.warns(PrecisionWarning, match=r"cancels at `y0`: rounded to 226 bits.*14[0-9] of the 226 bits"):
        sol = ls.integrate(sy, [6 * 10**20, 1], 1, precision=226)
    # x = 1e400, beyond a float's range: the fixed-point jets' bound decides (1394 bits)
    with pytest.warns(PrecisionWarning, match=r"cancels at `y0`: rounded to 226 bits.*\(a bound; 1[0-9]{3} of"):
        ls.integrate(sy, [10**400, 1], 1, precision=226, max_steps=10)
    # an ensemble in quad (its members run by the scalar threads, not as single runs): one warning, naming them
    with pytest.warns(PrecisionWarning, match=r"cancels at `Y0\[0\]`, `Y0\[2\]` \(2 of the 3 members\)"):
        ls.integrate(sy, [[6 * 10**20, 1], [1, 1], [6 * 10**20, 2]], 1, precision="quad")
    ref = ls.lie_integrate(sy, [6 * 10**20, 1], 1, dps=80)
    with mp.workdps(100):
        f = to_fraction(sol.y[-1][1])
        assert abs(mp.mpf(f.numerator) / f.denominator - mp.mpf(ref.y[-1][1])) > mp.mpf(10) ** -40  # as it says
    # a heavy top and a sphere's chart form (no sum cancels beyond the bound's slack: 4 and 3 bits in floats, 1 and
    # 3 by the fixed-point jets) do not warn
    from lieseries.expr.rounding import lost_bits
    from lieseries.lie.fixed import cancelling_bits
    from lieseries.poisson import as_poisson_system
    from lieseries.taylor.plan import CANCELLING_BITS

    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
    sphere = ls.Sphere()
    for model, y0 in [(top, top.initial_state(omega=(1, "0.5", 5))),
                      (sphere, sphere.initial_state(("0.6", "0", "0.8"), ("0", "1", "0")))]:
        ps = as_poisson_system(model)
        assert cancelling_bits(ps.program, list(y0), list(ps.parameter_values), 113) <= CANCELLING_BITS
        assert lost_bits(ps.program, [list(y0)], ps.parameter_values, 113)[0] <= CANCELLING_BITS


def _cancelling_system():
    # y' = (p + x)^2 - p^2 - 2 p x - x^2 + r cos y = r cos y: the squares of x cancel
    x, y = hy.make_vars("x", "y")
    p, r = hy.par[0], hy.par[1]
    return ls.PoissonSystem([x, y], [[0, 0], [0, 0]], 0.0 * x,
                            extra_field=[r * y, (p + x) * (p + x) - p * p - 2.0 * p * x - x * x + r * hy.cos(y)],
                            parameters=["3", "1"], jacobi=False)


def test_heyoka_in_double_and_long_double_warns_of_a_field_that_cancels_at_y0():
    # beside x = 1e10, double ended `success` with y 17.9 off (its tolerance, relative to the largest state, allows
    # 2e-6) and long double 1.2 off: each now warns, and the warning says what the run shows
    sy = _cancelling_system()
    ref = ls.lie_integrate(sy, [10**10, 1], 1, dps=40)
    for precision in ("double", "long double"):
        with pytest.warns(PrecisionWarning, match=r"cancels at `y0`: rounded to (53|64) bits"):
            sol = ls.integrate(sy, [10**10, 1], 1, precision=precision)
        assert abs(mp.mpf(str(sol.y[-1][1])) - ref.y[-1][1]) > 1e-3  # as it says
    # an ensemble in double (heyoka's batch mode): one warning, naming the member concerned
    with pytest.warns(PrecisionWarning, match=r"cancels at `Y0\[1\]` \(1 of the 2 members\)"):
        ls.integrate(sy, [[1, 1], [10**10, 1]], 1)
    # where nothing cancels beyond the bound's slack, no warning (a heavy top, a sphere, the rigid body)
    top = ls.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
    sphere = ls.Sphere()
    body = ls.EulerPoisson(INERTIA)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        for model, y0 in [(top, top.initial_state(omega=(1, "0.5", 5))),
                          (sphere, sphere.initial_state(("0.6", "0", "0.8"), ("0", "1", "0"))),
                          (body, body.initial_state(omega=OMEGA))]:
            for precision in ("double", "long double"):
                ls.integrate(model, y0, "0.5", precision=precision)


def test_a_field_that_comes_to_cancel_on_the_way_warns_at_the_end():
    """u' = u, w' = (u^2 + 1) - u^2 (= 1) from (1, 0): nothing cancels at y0, but by t = 20 u^2 = 2.4e17 and
    double ended ``success`` with w = 20.685 (the exact 20; 6e6 eps of the largest state), silent: no energy check
    guards a non-Hamiltonian field. The cancellation check runs at the end state too, on the first run and on a
    repeated one."""
    u, w = hy.make_vars("u", "w")
    sy = ls.PoissonSystem([u, w], [[0, 0], [0, 0]], 0 * u, extra_field=[u, (u * u + 1.0) - u * u])
    y0 = [1, 0]
    for _ in range(2):
        with pytest.warns(PrecisionWarning, match="cancels at the end state: rounded to 53 bits"):
            sol = ls.integrate(sy, y0, 20)
        assert abs(float(sol.y_reached[1]) - 20) > 0.5  # as it says
    with warnings.catch_warnings():  # till t = 10 (u^2 = 4.9e8) it holds: no warning, w right
        warnings.simplefilter("error", PrecisionWarning)
        assert ls.integrate(sy, y0, 10).y_reached[1] == 10


def test_an_ensemble_whose_field_comes_to_cancel_warns_at_the_members_end_states():
    """The field above as an ensemble (heyoka's batch mode): its members ended ``success`` with w 0.685 off, no
    warning; the members' end states are checked as a single run's is, the warning naming them."""
    u, w = hy.make_vars("u", "w")
    sy = ls.PoissonSystem([u, w], [[0, 0], [0, 0]], 0 * u, extra_field=[u, (u * u + 1.0) - u * u])
    with pytest.warns(PrecisionWarning, match=r"cancels at the end states of the members 0, 1 \(2 of the 3 checked\)"):
        es = ls.integrate(sy, [[1, 0], [1, 0], ["1e-6", 0]], 20)
    assert abs(float(es.y_reached[0][1]) - 20) > 0.5 and abs(float(es.y_reached[2][1]) - 20) < 1e-13  # as it says


def test_a_cancellation_that_sympy_would_simplify_away_is_seen_as_heyoka_computes_it():
    # H = p^2/2 + (q + B)^2/2 - B q is the oscillator: heyoka evaluates q' as 0.5 (2 (q + B)) - B, which cancels
    # 1e12 beside q ~ 1, and ended `success` 5e-5 off cos 3 in double; the bound read the field as sympy simplifies
    # it (q) and did not warn. It now reads heyoka's arithmetic (PoissonSystem.written_program)
    q, p = hy.make_vars("q", "p")
    B = 10**12
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 + (q + B) ** 2 / 2 - B * q)
    with pytest.warns(PrecisionWarning, match=r"cancels at `y0`: rounded to 53 bits"):
        sol = ls.integrate(osc, [1, 0], t=3)
    assert abs(float(sol.y[-1][0]) - math.cos(3)) > 1e-6  # as it says
    with pytest.warns(PrecisionWarning, match=r"43 of the 113 bits"):  # the same 43 bits, of 113 here
        quad = ls.integrate(osc, [1, 0], t=3, precision="quad")
    assert abs(float(quad.y[-1][0]) - math.cos(3)) < 1e-15  # (its bound: 2^-70 of the state per unit time)


def test_the_float_rounding_bound_agrees_with_the_jets_bound():
    # two bounds of the same roundings by different means: floats relative to each value (lieseries.expr.rounding,
    # heyoka's arithmetic) and the fixed-point jets' first order (lieseries.lie.fixed.cancelling_bits)
    from lieseries.expr.rounding import lost_bits
    from lieseries.lie.fixed import cancelling_bits
    from lieseries.poisson import as_poisson_system

    ps = as_poisson_system(_cancelling_system())
    pars = list(ps.parameter_values)
    for X in (10**4, 10**6, 10**8, 10**10):
        fl = lost_bits(ps.program, [[X, 1]], pars, 53)[0]
        ex = cancelling_bits(ps.program, [X, 1], pars, 53)
        assert ex - 2 <= fl <= ex + 8, (X, fl, ex)
    # y beside x = 1e12 lies 37 bits below x's precision: judged against x (heyoka's tolerance is relative to the
    # largest state), still far beyond it (its rate's error bound 1e9 against 1e12 eps)
    from lieseries.taylor.plan import CANCELLING_BITS

    assert lost_bits(ps.program, [[10**12, 1]], pars, 53)[0] > CANCELLING_BITS
    many = lost_bits(ps.program, np.array([[1e4, 1], [1e10, 1], [1, 1]]), pars, 53)  # vectorised: the same
    assert many == [lost_bits(ps.program, [r], pars, 53)[0] for r in ([1e4, 1], [1e10, 1], [1, 1])]
    # beyond a float's range, or singular: None (the exact check decides)
    assert lost_bits(ps.program, [[10**400, 1]], pars, 53) == [None]
    assert lost_bits(ps.program, np.array([[1.0, 1], [np.inf, 1]]), pars, 53)[1] is None
