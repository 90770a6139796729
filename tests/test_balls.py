"""Balls of validated runs shown and checked at their own precision, against the closed form."""

import re
from fractions import Fraction

import mpmath as mp
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.balls import ball_bounds, ball_str, contains

INERTIA = (1, 2, 3)
OMEGA = (1, "0.1", "0.5")


@pytest.fixture(scope="module")
def run():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(OMEGA)
    sol = ls.validated_integrate(body, y0, t=[0, "0.5"], dps=30)
    ref = exact.euler_poisson(INERTIA, OMEGA, "0.5", dps=60)
    return y0, sol, ref


def _parse(text):
    m = re.fullmatch(r"\[(\S+) \+/- (\S+)\]", text)
    return Fraction(m.group(1)), Fraction(m.group(2))


def test_ball_str_shows_the_ball_at_its_own_precision(run):
    _y0, sol, ref = run
    ball = sol.y[-1][10]
    _mid, rad = ball_bounds(ball)
    assert rad < Fraction(1, 10**30)  # a 30-digit run
    text = ball_str(ball)
    mid_shown, rad_shown = _parse(text)
    assert len(re.sub(r"[^0-9]", "", text.split(" ")[0].lstrip("[").split("e")[0])) >= 30  # flint's str shows 15
    assert rad_shown < Fraction(1, 10**30)
    # the printed ball encloses the closed form (and the ball)
    assert abs(Fraction(mp.nstr(ref[10], 55)) - mid_shown) <= rad_shown
    # fewer digits: the printed midpoint's rounding widens the printed radius, so it still encloses
    mid10, rad10 = _parse(ball_str(ball, digits=10))
    assert rad10 > Fraction(1, 10**12) and abs(Fraction(mp.nstr(ref[10], 55)) - mid10) <= rad10


def test_contains_checks_references_exactly_at_the_run_precision(run):
    y0, sol, ref = run
    assert contains(sol.y[-1], ref)
    assert contains(sol.y, [y0, ref])  # the exact initial state (its exact values) and the closed form
    # a reference off by 1e-28 (far beyond the radius ~1e-34) is not enclosed
    off = list(ref)
    with mp.workdps(60):
        off[10] = ref[10] + mp.mpf("1e-28")
    assert not contains(sol.y[-1], off)
    assert contains(sol.y[-1], off, tol="2e-28")
    with pytest.raises(ValueError, match="`reference`"):
        contains(sol.y[-1], ref[:5])
