"""Budgets that bound: a job far beyond its budget stops within the budget and a small margin, saying so."""

import time

import numpy as np
import pytest

import lieseries as ls

BODY = ls.EulerPoisson((1, 2, 3))
Y0 = BODY.initial_state((1, "0.1", "0.5"))


def test_lie_series_max_time():
    """Order 2000 at 3000 digits takes minutes; with max_time=0.2 it raises TimeoutError (time_budget, the order
    reached) within the budget and one order's work, and returns no shorter series."""
    start = time.perf_counter()
    with pytest.raises(TimeoutError, match=r"time_budget: `max_time` = 0\.2 s ran out .* at order \d+ of 2000"):
        ls.lie_series(BODY, Y0, order=2000, dps=3000, max_time=0.2)
    assert time.perf_counter() - start < 2.0
    with pytest.raises(ValueError, match="`max_time`"):
        ls.lie_series(BODY, Y0, order=4, max_time=-1)
    assert ls.lie_series(BODY, Y0, order=4, max_time=60).order == 4


def test_lie_integrate_dense_max_time_bounds_the_call():
    """A dense run ~100 times beyond its budget stops `time_budget` and returns within the budget and a margin:
    its dense output (every step's polynomial, exported) is built as the steps go, inside the budget, not after
    (it took as long as the run itself)."""
    budget = 0.3
    start = time.perf_counter()
    sol = ls.lie_integrate(BODY, Y0, 1e4, dps=30, max_time=budget, dense=True)
    elapsed = time.perf_counter() - start
    assert sol.status == "time_budget", sol.message
    assert elapsed < 1.5 * budget + 0.1, elapsed
    t_mid = sol.t_reached / 2
    ref = ls.lie_integrate(BODY, Y0, t_mid, dps=30)
    assert max(abs(a - b) for a, b in zip(sol(t_mid), ref.y[-1])) < 1e-20


@pytest.mark.parametrize("engine", ["integrate", "lie_integrate", "validated_integrate"])
def test_max_time_counts_the_output_times(engine):
    """max_time bounds the call, the conversion and checks of a long grid of output times included (they were
    counted apart: 60001 output times and max_time = 0.4 s returned after 0.67-0.77 s)."""
    budget = 0.4
    grid = np.linspace(0, 1e6, 60001)
    if engine == "integrate":
        ls.integrate(BODY, Y0, 1.0)  # (the one-off compilation, which max_time does not bound)
    start = time.perf_counter()
    try:
        sol = getattr(ls, engine)(BODY, Y0, grid, max_time=budget)
        assert sol.status == "time_budget", sol.message
    except ValueError as err:  # (a loaded machine: the conversion alone is projected beyond the budget)
        assert "`t` asks for 60001 output times" in str(err) and "`max_time`" in str(err)
    elapsed = time.perf_counter() - start
    assert elapsed < 1.4 * budget + 0.1, elapsed
