"""``max_time`` bounds a run even when one step would take far longer than the budget: the expansion inside the
step reads the clock after every order, and the run ends with status ``time_budget`` and the rows it had. A job far
beyond its budget stops within the budget and a small margin, saying so (``lie_series`` too)."""

import time
from fractions import Fraction

import flint
import heyoka as hy

import lieseries as ls
from lieseries.lie.integrator import lie_integrate
from lieseries.precision import to_fraction
from lieseries.validated import validated_integrate, working_precision
from problems import RIGID_INERTIA, RIGID_OMEGA, rigid_error

# one step of the rigid body at 1000 digits (order 1153) takes ~10 s with the fixed-point jets (at 400 digits, under a
# second); the budget is a quarter of a second, 1/40 of the step and far above what comes before it (with a budget
# of 1e-6 s the run ends after 0.8 ms)
DPS, BUDGET = 1000, 0.25


def _body():
    body = ls.EulerPoisson(RIGID_INERTIA)
    return body, body.initial_state(omega=RIGID_OMEGA)


def test_validated_stops_inside_a_long_step_with_the_rows_proved():
    body, y0 = _body()
    sol = validated_integrate(body, y0, t=[0, Fraction(1, 2)], dps=DPS, max_time=BUDGET)
    assert sol.status == "time_budget" and "`max_time`" in sol.message
    assert sol.t_reached == 0 and sol.stats.steps == 0  # stopped inside the first step, not after it
    assert list(sol.t) == [0.0]
    with working_precision(5000):
        assert all(b.contains(flint.arb(flint.fmpq(q.numerator, q.denominator))) and b.rad() < flint.arb(10) ** -DPS
                   for b, q in zip(sol.y[0], y0.exact))


def test_lie_integrate_stops_inside_a_long_step_with_the_rows_it_has():
    body, y0 = _body()
    sol = lie_integrate(body, y0, t=[0, Fraction(1, 2)], dps=DPS, max_time=BUDGET)
    assert sol.status == "time_budget" and "`max_time`" in sol.message
    assert sol.t_reached == 0 and sol.stats.steps == 0
    assert list(sol.t) == [0.0]
    # the t0 row is y0 rounded to the run's digits
    assert all(abs(to_fraction(v) - q) <= Fraction(1, 10**DPS) for v, q in zip(sol.y[0], y0.exact))


# --- the exact conversion of output times is inside `max_time` --------------------------------------------------

import numpy as np
import pytest

from lieseries.taylor.plan import CHUNK_SECONDS
from lieseries.timegrid import CHUNK, parse_times

# a grid whose exact conversion takes tenths of a second, against a budget far below it
GRID_N, TINY_BUDGET = 5 * CHUNK, 1e-4


@pytest.mark.parametrize("engine", ["integrate", "lie_integrate", "validated_integrate", "ensemble"])
def test_a_grid_that_cannot_be_converted_within_max_time_is_refused_naming_t(engine):
    body, y0 = _body()
    grid = [Fraction(k, GRID_N) for k in range(GRID_N)]  # a list: the general, per-number path
    kwargs = dict(max_time=TINY_BUDGET)
    call = {
        "integrate": lambda: ls.integrate(body, y0, grid, **kwargs),
        "lie_integrate": lambda: lie_integrate(body, y0, grid, dps=20, **kwargs),
        "validated_integrate": lambda: validated_integrate(body, y0, grid, dps=20, **kwargs),
        "ensemble": lambda: ls.integrate(body, [y0, y0], grid, **kwargs),
    }[engine]
    with pytest.raises(ValueError, match=r"`t` asks for %d output times.*`max_time`" % GRID_N):
        call()


@pytest.mark.parametrize("as_array", [False, True])
def test_a_grid_converted_within_max_time_is_whole_and_exact(as_array):
    # the conversion goes chunk by chunk: nothing is dropped at the chunk boundaries, every time is exact
    values = np.linspace(0, 3, 2 * CHUNK + 7)
    grid, direction, t0 = parse_times(values if as_array else values.tolist(), max_time=600)
    assert direction == 1 and t0 == 0 and len(grid) == values.size
    assert all(g == Fraction(*v.as_integer_ratio()) for g, v in zip(grid, values.tolist()))
    # a grid that turns back inside the second chunk is still refused
    bad = values.copy()
    bad[CHUNK + 3] = bad[CHUNK + 1]
    with pytest.raises(ValueError, match="strictly increasing"):
        parse_times(bad if as_array else bad.tolist(), max_time=600)


@pytest.mark.parametrize("engine", ["integrate", "lie_integrate"])
def test_the_output_memory_estimate_counts_every_value_of_a_row(engine, monkeypatch):
    """A grid is sized by its rows (12 values per time for the rigid body), not by one value per time: 200 times
    of 12 doubles are ~118 kB by the estimate's own rule (2 x 12 x 8 + 400 bytes per time), one value per time
    would be 83 kB."""
    from lieseries import timegrid

    monkeypatch.setattr(timegrid, "MAX_OUTPUT_BYTES", 100_000)
    body, y0 = _body()
    grid = [Fraction(k, 200) for k in range(1, 201)]
    run = ls.integrate if engine == "integrate" else lambda *a: lie_integrate(*a, dps=20)
    with pytest.raises(ValueError, match=r"`t` asks for 200 output times.*\(12 values of"):
        run(body, y0, grid)


@pytest.mark.parametrize("max_steps", [None, 10**5])
def test_a_time_that_does_not_advance_ends_the_run(max_steps):
    """At 3 bits, t = 8 plus a step of 0.08 rounds to 8 (heyoka's double-length time too): the run stepped on in
    place until the default budget of 5e7 steps (minutes), or with `max_steps` said "raise `max_steps` to go on",
    which never would. A chunk of steps that leaves the time where it was ends the run, saying why."""
    import heyoka as hy

    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (q**2 + p**2) / 2, name="oscillator")
    sol = ls.integrate(osc, [1, 0], t=10, precision=3, max_steps=max_steps)
    assert sol.status == "step_collapse" and "the time does not advance" in sol.message, sol.message
    assert sol.t_reached == 8 and sol.stats.steps < 10**4


def test_lie_series_max_time():
    """Order 2000 at 3000 digits takes minutes; with max_time=0.2 it raises TimeoutError (time_budget, the order
    reached) within the budget and one order's work, and returns no shorter series."""
    start = time.perf_counter()
    with pytest.raises(TimeoutError, match=r"time_budget: `max_time` = 0\.2 s ran out .* at order \d+ of 2000"):
        ls.lie_series(*_body(), order=2000, dps=3000, max_time=0.2)
    assert time.perf_counter() - start < 2.0
    with pytest.raises(ValueError, match="`max_time`"):
        ls.lie_series(*_body(), order=4, max_time=-1)
    assert ls.lie_series(*_body(), order=4, max_time=60).order == 4


def test_lie_integrate_dense_max_time_bounds_the_call():
    """A dense run ~100 times beyond its budget stops `time_budget` and returns within the budget and a margin:
    its dense output (every step's polynomial, exported) is built as the steps go, inside the budget, not after
    (it took as long as the run itself)."""
    budget = 0.3
    start = time.perf_counter()
    sol = ls.lie_integrate(*_body(), 1e4, dps=30, max_time=budget, dense=True)
    elapsed = time.perf_counter() - start
    assert sol.status == "time_budget", sol.message
    assert elapsed < 1.6 * budget + 0.1, elapsed  # (it took 0.68-0.72 s: 2.3 times its budget)
    t_mid = sol.t_reached / 2  # (the dense output against the closed form)
    assert rigid_error(sol(t_mid), t_mid, dps=40) < 1e-20


# --- an ensemble's max_time bounds the whole call -----------------------------------------------------------------

def test_an_ensembles_max_time_bounds_all_its_members_together():
    # each member's single run once had the whole budget: 8 members far beyond it took 8 budgets. The members
    # share it now: the first runs until it is spent, the others end time_budget at y0 without a step
    body, y0 = _body()
    Y0 = [y0] * 8
    ls.integrate(body, y0, t=Fraction(1, 1000), precision=256)  # (compiled beforehand: the budget is the runs')
    sol = ls.integrate(body, Y0, t=[0, 10**5], precision=256, max_time=0.3)
    assert set(sol.status) == {"time_budget"}
    steps = [int(s) for s in sol.stats["steps"]]
    assert steps[0] > 0 and sol.t_reached[0] > 0
    assert "bounds the ensemble's members together" in sol.message[0]
    idle = [i for i in range(8) if steps[i] == 0]
    assert len(idle) >= 6  # (at most one more started before the budget was spent)
    for i in idle:
        assert sol.t_reached[i] == 0 and "before this member started" in sol.message[i]
        assert sol.rows[i] == 1 and all(np.isnan(float(v)) for v in sol.y[i][1])
        assert rigid_error(sol.y_reached[i], 0) < 1e-75 and rigid_error(sol.y[i][0], 0) < 1e-75
    # what the first member reached is the motion: against the closed form at its time, to 1e-60
    assert rigid_error(sol.y_reached[0], sol.t_reached[0], dps=100) < 1e-60
    # with events, a member not run has a record with no crossings, as a run that met none
    m2 = hy.make_vars("M2")
    ev = ls.integrate(body, Y0, t=[0, 10**5], precision=256, max_time=0.3, events=[ls.Event(m2, name="m2")])
    idle = [i for i in range(8) if ev.stats["steps"][i] == 0]
    assert idle and all(len(ev.events[i]["m2"]["t"]) == 0 and ev.events[i]["m2"]["y"].shape == (0, 12) for i in idle)


def test_an_ensembles_budget_does_not_count_the_one_off_compilation():
    # the first member's compilation (a new structure: ~0.1-0.5 s) took the whole budget of a short ensemble, and
    # the other members ended time_budget without running; it moves the deadline on, as it is not counted in a
    # single run's max_time
    q, p = hy.make_vars("q", "p")
    fresh = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + q**4 / 4 - q * q * hy.par[0] + p * q**3 / 1024,
                             parameters=[Fraction(1, 7)], name="a structure of this test's own")
    sol = ls.integrate(fresh, [["0.5", 0]] * 6, t=[0, 1], max_time=0.02)  # (each run ~0.4 ms, its first 0.26 s)
    assert list(sol.status) == ["success"] * 6, sol.message


def test_a_heyoka_run_whose_steps_are_slow_stops_within_a_step_or_two_of_its_budget():
    # at 512 bits a step of the rigid body takes ~0.1 s: chunks of at least 16 steps (2 for the first) were read
    # against max_time only at their ends, seconds beyond the budget; a chunk is now one step where a step takes
    # longer than a chunk's ~0.1 s
    body, y0 = _body()
    ls.integrate(body, y0, t=Fraction(1, 100), precision=512)  # (compiled beforehand: the budget is the run's)
    tic = time.perf_counter()
    one = ls.integrate(body, y0, t=10**4, precision=512, max_steps=1)
    step = time.perf_counter() - tic
    assert one.status == "step_budget" and one.stats.steps == 1
    budget = 1.5 * step
    sol = ls.integrate(body, y0, t=10**4, precision=512, max_time=budget)
    assert sol.status == "time_budget" and "`max_time`" in sol.message
    # the steps the budget and one chunk beyond it hold, and one more for the clock's noise (the old chunks: 18)
    assert 1 <= sol.stats.steps <= (budget + CHUNK_SECONDS) / step + 2, (sol.stats.steps, step)
