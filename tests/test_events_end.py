"""Crossings at the final time and at a terminal stop: one semantics in every engine (docs/api.md, events).

References are closed forms: q = t (a free particle from q = 0, p = 1) crosses q = 1 at t = 1 exactly; q = sin t
(an oscillator from q = 0, p = 1) crosses q = 1/2 at pi/6."""

from fractions import Fraction

import heyoka as hy
import mpmath as mp
import pytest

import lieseries as ls
from lieseries.precision import to_fraction

q, p = hy.make_vars("q", "p")
FREE = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2)
OSC = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + q**2) / 2)
ENGINES = [("double", 1e-14), ("long double", 1e-17), ("quad", 1e-30), (128, 1e-35), ("lie", 1e-28)]


def run(system, engine, t, events):
    if engine == "lie":
        return ls.lie_integrate(system, [0, 1], t=t, dps=30, events=events)
    return ls.integrate(system, [0, 1], t=t, precision=engine, events=events)


@pytest.mark.parametrize("engine", [e for e, _ in ENGINES])
def test_crossing_at_the_final_time(engine):
    """q = t against q - 1 with t = 1: recorded, and a terminal one ends the run `event` at t = 1; the other way
    than a one-way event's direction, nothing; backward to t = -1 against q + 1 alike."""
    plain = run(FREE, engine, 1, [ls.Event(q - 1, name="hit")])
    assert plain.status == "success", plain.message
    assert [to_fraction(x) for x in plain.events["hit"]["t"]] == [1]
    stop = run(FREE, engine, 1, [ls.Event(q - 1, direction=1, terminal=True, name="hit"), ls.Event(q - 1, name="also")])
    assert stop.status == "event" and "'hit'" in stop.message, stop.message
    assert [to_fraction(x) for x in stop.events["hit"]["t"]] == [1]
    assert [to_fraction(x) for x in stop.events["also"]["t"]] == [1]
    assert to_fraction(stop.t_reached) == 1
    other = run(FREE, engine, 1, [ls.Event(q - 1, direction=-1, terminal=True, name="hit")])
    assert other.status == "success" and len(other.events["hit"]["t"]) == 0, other.message
    back = run(FREE, engine, -1, [ls.Event(q + 1, direction=1, terminal=True, name="hit")])  # (q rises in time)
    assert back.status == "event" and [to_fraction(x) for x in back.events["hit"]["t"]] == [-1], back.message


@pytest.mark.parametrize("engine, bound", ENGINES)
def test_crossing_simultaneous_with_a_terminal_stop(engine, bound):
    """q = sin t: a terminal q - 1/2 and a plain 2 q - 1 cross together at pi/6; both are recorded, the run stops
    there; a plain q - 1/4 before it is recorded first (asin(1/4))."""
    half = Fraction(1, 2)
    events = [ls.Event(q - 0.25, name="quarter"), ls.Event(q - half, terminal=True, name="stop"),
              ls.Event(2 * q - 1, name="plain")]
    sol = run(OSC, engine, 1, events)
    assert sol.status == "event" and "'stop'" in sol.message, sol.message
    with mp.workdps(50):
        ref = to_fraction(mp.pi / 6)
        quarter = to_fraction(mp.asin(mp.mpf(1) / 4))
    for name, t_ref in (("quarter", quarter), ("stop", ref), ("plain", ref)):
        got = [to_fraction(x) for x in sol.events[name]["t"]]
        assert len(got) == 1 and abs(got[0] - t_ref) < bound, (name, got)
    assert abs(to_fraction(sol.t_reached) - ref) < bound


def test_ensemble_crossing_at_the_final_time():
    """An ensemble with events runs each member as a single run: the member whose q = t reaches 1 at t = 1 ends
    `event` with the crossing, the slower one (q = t / 2) `success` without."""
    from lieseries.ensemble import integrate_ensemble

    sol = integrate_ensemble(FREE, [[0, 1], [0, 0.5]], 1, events=[ls.Event(q - 1, terminal=True, name="hit")])
    assert list(sol.status) == ["event", "success"], sol.message
    assert [to_fraction(x) for x in sol.events[0]["hit"]["t"]] == [1]
    assert len(sol.events[1]["hit"]["t"]) == 0
