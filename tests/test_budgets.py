"""Budgets that bound: a job far beyond its budget stops within the budget and a small margin, saying so."""

import time

import pytest

import lieseries as ls

from problems import RIGID_INERTIA, RIGID_OMEGA, rigid_error

BODY = ls.EulerPoisson(RIGID_INERTIA)
Y0 = BODY.initial_state(RIGID_OMEGA)


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
    assert elapsed < 1.6 * budget + 0.1, elapsed  # (it took 0.68-0.72 s: 2.3 times its budget)
    t_mid = sol.t_reached / 2  # (the dense output against the closed form)
    assert rigid_error(sol(t_mid), t_mid, dps=40) < 1e-20

