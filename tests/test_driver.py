"""The one driver loop (lieseries.driver): budgets, rows at the requested times, stops and the message table,
first with a toy engine whose steps are exact (dz/dt = z: z(t) = e^t), then through the engines driven by it."""

import math
from fractions import Fraction

import mpmath as mp
import lieseries as ls
from lieseries import exact
from lieseries.driver import MESSAGES, StepResult, Stop, drive, run_message
from lieseries.solution import STATUSES

OMEGA = (1, "0.1", "0.5")


class Exponential:
    """Steps of length at most ``h`` of dz/dt = z, exact in floats (z e^tau): the reference is e^t itself."""

    def __init__(self, h=0.25, fail_at=None, stop_at=None):
        self.h, self.fail_at, self.stop_at, self.calls = h, fail_at, stop_at, 0

    def step(self, t, z, t_end):
        self.calls += 1
        if self.fail_at is not None and t >= self.fail_at:
            raise Stop("non_finite", "the toy field is singular here")
        h = min(self.h, t_end - t)
        tnew = t + h if h < t_end - t else t_end
        stop = None
        if self.stop_at is not None and t < self.stop_at <= tnew:
            tnew, h = self.stop_at, self.stop_at - t
            stop = ("event", "the event 'mark' fired", "")
        return StepResult(tnew, z * math.exp(h), h=h, row=lambda tk: z * math.exp(tk - t), error=0.0, stop=stop)


def _grid(times):
    return [(float(tk), tk) for tk in times]


def test_rows_at_the_requested_times_are_the_exact_solution():
    times = [0, Fraction(1, 10), Fraction(7, 10), 1, Fraction(23, 10)]
    out = drive(Exponential(), 0.0, 1.0, _grid(times), direction=1, max_steps=100)
    assert out.status == "success" and out.message == "Reached t = 2.2999999999999998."
    assert out.rows_t == times
    assert all(abs(y - math.exp(float(tk))) <= 1e-14 * math.exp(float(tk)) for y, tk in zip(out.rows_y, times))
    assert out.steps == math.ceil(2.3 / 0.25) and out.t == 2.3 and abs(out.z - math.exp(2.3)) < 1e-13


def test_an_engine_without_an_evaluator_gives_the_step_end_at_the_step_end():
    """A step without ``row`` (the protocol's "only the step's end"): the row at a time the step reaches is the
    state it reached (the loop read the state before the step there)."""

    class EndOnly(Exponential):
        def step(self, t, z, t_end):
            res = super().step(t, z, t_end)
            return StepResult(res.t, res.z, h=res.h, error=0.0)

    out = drive(EndOnly(h=0.5), 0.0, 1.0, _grid([0, Fraction(1, 2), 1]), direction=1, max_steps=100)
    assert out.status == "success"
    assert [abs(y - math.exp(float(tk))) < 1e-15 * math.exp(1) for y, tk in zip(out.rows_y, [0, 0.5, 1])] == [True] * 3


def test_backward_rows_and_progress():
    seen = []
    out = drive(Exponential(), 0.0, 1.0, _grid([0, -0.5, -1]), direction=-1, max_steps=100, progress=seen.append)
    # the toy engine steps forward only when asked to: here its steps are negative (t_end - t < 0)
    assert out.status == "success" and out.t == -1
    assert abs(out.rows_y[-1] - math.exp(-1)) < 1e-15
    assert seen and seen[-1] == 1.0 and all(a <= b for a, b in zip(seen, seen[1:]))


def test_step_budget_keeps_the_rows_before_it():
    out = drive(Exponential(h=0.25), 0.0, 1.0, _grid([0, 0.3, 2]), direction=1, max_steps=3)
    assert out.status == "step_budget" and out.steps == 3 and out.t == 0.75
    assert out.rows_t == [0, 0.3] and abs(out.rows_y[1] - math.exp(0.3)) < 1e-15
    assert out.message == ("The step budget `max_steps` = 3 ran out at t = 0.75; raise `max_steps` to go on.")


def test_time_budget_is_read_between_steps():
    engine = Exponential(h=0.25)
    out = drive(engine, 0.0, 1.0, _grid([0, 2]), direction=1, max_steps=100, max_time=0.5, start=-1e9)
    assert out.status == "time_budget" and engine.calls == 0 and out.t == 0.0
    assert "`max_time` = 0.5 s" in out.message and "t = 0" in out.message


class Explaining(Exponential):
    """An engine that words its budget stops (as a heyoka run does: the steps finishing would take) and whose first
    step is taken whatever the budgets (a heyoka run's first chunk)."""

    free_first_step = True

    def explain(self, status, t):
        return Stop(status, f"{2 - t:g} time units remain", note=" (last step size 0.25)",
                    reason=f"{status}.ahead" if status == "step_budget" else None)


def test_an_engine_words_its_budget_stops_from_the_table_and_may_take_its_first_step_free():
    out = drive(Explaining(h=0.25), 0.0, 1.0, _grid([0, 2]), direction=1, max_steps=3)
    assert out.status == "step_budget" and out.steps == 3 and out.t == 0.75
    assert out.message == ("Stopped early at t = 0.75 (last step size 0.25): 1.25 time units remain, more than the "
                           "step budget `max_steps` = 3 allows; raise `max_steps` to go on.")
    assert out.message == run_message("step_budget.ahead", t=0.75, note=" (last step size 0.25)",
                                      detail="1.25 time units remain", max_steps=3)
    # a spent wall-time budget: the first step is still taken, the stop comes after it, with the engine's note
    engine = Explaining(h=0.25)
    out = drive(engine, 0.0, 1.0, _grid([0, 2]), direction=1, max_steps=100, max_time=0.5, start=-1e9)
    assert out.status == "time_budget" and engine.calls == 1 and out.t == 0.25
    assert "ran out at t = 0.25 (last step size 0.25)" in out.message


def test_a_failing_step_stops_where_it_started_with_the_table_message():
    out = drive(Exponential(fail_at=0.5), 0.0, 1.0, _grid([0, 0.6, 1]), direction=1, max_steps=100,
                kept="The rows up to this time are kept.")
    assert out.status == "non_finite" and out.t == 0.5 and abs(out.z - math.exp(0.5)) < 1e-15
    assert out.rows_t == [0]
    assert out.message == ("The step after t = 0.5 cannot be taken: the toy field is singular here. The rows up to "
                           "this time are kept.")


def test_a_terminal_condition_ends_the_run_after_its_step():
    out = drive(Exponential(stop_at=0.6), 0.0, 1.0, _grid([0, 0.5, 0.7]), direction=1, max_steps=100)
    assert out.status == "event" and out.t == 0.6 and abs(out.z - math.exp(0.6)) < 1e-15
    assert out.rows_t == [0, 0.5]
    assert out.message == "Stopped at t = 0.59999999999999998: the event 'mark' fired."


def test_the_message_table_covers_every_status_a_step_can_end_with():
    # a key is a status, or "status.reason": an engine's own wording of it (heyoka's advice on its step size)
    statuses = {key.split(".")[0] for key in MESSAGES}
    assert statuses <= set(STATUSES)
    assert set(STATUSES) - statuses == {"divergent", "invariant_drift"}  # set by the engines' own checks
    # times beyond the double range are written, not overflowed
    assert "~1e400" in run_message("step_budget", t=Fraction(10) ** 400, max_steps=5)


def test_lie_integrate_budgets_read_as_the_table_says():
    """The Lie-series engine on the driver: its stops carry the table's messages, and the state it stopped at is
    the exact solution at the time it reached."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(OMEGA, precision=400)
    sol = ls.lie_integrate(body, y0, t=50, dps=20, max_steps=3)
    assert sol.status == "step_budget" and sol.stats.steps == 3
    assert sol.message == run_message("step_budget", t=sol.t_reached, max_steps=3,
                                      kept="The rows up to this time are kept.")
    assert "raise `max_steps`" in sol.message
    ref = exact.euler_poisson((1, 2, 3), OMEGA, sol.t_reached, dps=40)
    with mp.workdps(40):
        assert max(abs(a - b) for a, b in zip(sol.y_reached, ref)) < 1e-17
    assert list(sol.t) == [] or sol.t[0] == 0



def test_lie_integrate_stop_messages_match_across_engines():
    """The same budget reads the same in every engine driven by the loop."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(OMEGA, precision=400)
    lie = ls.lie_integrate(body, y0, t=50, dps=20, max_steps=2)
    val = ls.validated_integrate(body, y0, t=50, dps=20, max_steps=2)
    assert lie.status == val.status == "step_budget"
    strip = lambda m: m.split(" at t = ")[0]  # noqa: E731 - the times differ, the wording must not
    assert strip(lie.message) == strip(val.message) == "The step budget `max_steps` = 2 ran out"



class Segments(Exponential):
    """Steps that give their rows evaluated (an atlas run's segments): the rows at t0 come from the first."""

    emits_rows = True

    def step(self, t, z, t_end):
        res = super().step(t, z, t_end)
        times = [tk for tk in (0.0, 0.1, 0.2, 0.3) if t <= tk <= res.t and (tk > t or t == 0.0)]
        return StepResult(res.t, res.z, rows=[(tk, z * math.exp(tk - t)) for tk in times], steps=7)


def test_evaluated_rows_and_a_first_step_whatever_the_budget():
    guarded = []
    out = drive(Segments(h=0.15), 0.0, 1.0, _grid([0.0, 0.1, 0.2, 0.3]), direction=1, max_steps=10, max_time=0.5,
                start=-1e9, guard=guarded.append)
    # the first step runs (it gives the row at t0), the budget stops the second
    assert out.status == "time_budget" and out.steps == 7 and out.t == 0.15 and not guarded
    assert out.rows_t == [0.0, 0.1] and abs(out.rows_y[1] - math.exp(0.1)) < 1e-15
    out = drive(Segments(h=0.1), 0.0, 1.0, _grid([0.0, 0.1, 0.2, 0.3]), direction=1, max_steps=10,
                guard=guarded.append)
    assert out.status == "step_budget" and out.steps == 14 and out.t == 0.2  # a step counts for its steps
    assert "`max_steps` = 10" in out.message and out.rows_t == [0.0, 0.1, 0.2]
    out = drive(Segments(h=0.5), 0.0, 1.0, _grid([0.0, 0.1, 0.2, 0.3]), direction=1, max_steps=10,
                guard=guarded.append)
    assert out.status == "success" and guarded == [out] and len(out.rows_t) == 4
    assert all(abs(y - math.exp(tk)) < 1e-15 for tk, y in zip(out.rows_t, out.rows_y))
