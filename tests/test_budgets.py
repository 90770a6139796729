"""``max_time`` bounds a run even when one step would take far longer than the budget: the expansion inside the
step reads the clock after every order, and the run ends with status ``time_budget`` and the rows it had."""

from fractions import Fraction

import flint

import lieseries as ls
from lieseries.lie.integrator import lie_integrate
from lieseries.precision import to_fraction
from lieseries.validated import validated_integrate
from problems import RIGID_INERTIA, RIGID_OMEGA

# one step of the rigid body at 400 digits (order ~460) takes tens of seconds; the budget is a second
DPS, BUDGET = 400, 1.0


def _body():
    body = ls.EulerPoisson(RIGID_INERTIA)
    return body, body.initial_state(omega=RIGID_OMEGA)


def test_validated_stops_inside_a_long_step_with_the_rows_proved():
    body, y0 = _body()
    sol = validated_integrate(body, y0, t=[0, Fraction(1, 2)], dps=DPS, max_time=BUDGET)
    assert sol.status == "time_budget" and "`max_time`" in sol.message
    assert sol.t_reached == 0 and sol.stats.steps == 0  # stopped inside the first step, not after it
    assert list(sol.t) == [0.0]
    old = flint.ctx.prec
    flint.ctx.prec = 2000
    try:
        assert all(b.contains(flint.arb(flint.fmpq(q.numerator, q.denominator))) and b.rad() < flint.arb(10) ** -DPS
                   for b, q in zip(sol.y[0], y0.exact))
    finally:
        flint.ctx.prec = old


def test_lie_integrate_stops_inside_a_long_step_with_the_rows_it_has():
    body, y0 = _body()
    sol = lie_integrate(body, y0, t=[0, Fraction(1, 2)], dps=DPS, max_time=BUDGET)
    assert sol.status == "time_budget" and "`max_time`" in sol.message
    assert sol.t_reached == 0 and sol.stats.steps == 0
    assert list(sol.t) == [0.0]
    # the t0 row is y0 rounded to the run's digits
    assert all(abs(to_fraction(v) - q) <= Fraction(1, 10**DPS) for v, q in zip(sol.y[0], y0.exact))
