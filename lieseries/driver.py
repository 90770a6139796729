"""One driver loop for the step-by-step engines: budgets, output rows, stops, statuses and their messages.

An engine plugs in through a small step protocol: an object with

``step(t, z, t_end) -> StepResult``
    One step from ``(t, z)`` towards ``t_end`` (never beyond it). The result carries the new time and state, the
    step's length, its error estimate, a dense evaluator ``row(t)`` for the output times inside the step, and
    ``stop``: a terminal condition met in the step (an event, a chart's edge), which ends the run after it.
    A step that cannot be taken raises :class:`Stop` with its status and the cause (the run keeps what it had).
    A step may instead give its rows already evaluated (``rows``) and count for many steps (``steps``): an atlas
    run's step is a whole run in one chart (:mod:`lieseries.atlas`).

``switch_chart(t, z)`` (with ``atlas=True``) and ``chart``
    The state rewritten in a better chart when the current one is ending (status ``chart_edge``), and the chart
    the engine works in (each row records it).

The driver owns the rest, the same for every engine: the step budget ``max_steps`` and the wall-time budget
``max_time`` (read between steps; an engine that can stop inside a step raises ``Stop("time_budget")``), the rows
at the requested times (in time order, from each step's dense evaluator), progress reports, chart switches, the
energy guard of a run that reached its final time (:func:`energy_guard`), and every message a run ends with, from
one table (:data:`MESSAGES`) so that the same stop reads the same whatever the engine.

``explain(status, t)`` (optional)
    A budget stop as the engine words it: a :class:`Stop` whose ``reason`` picks an entry of :data:`MESSAGES` with
    the engine's own advice (a heyoka run says how many steps finishing would take).
``free_first_step`` (optional, True)
    The first step is taken whatever the budgets: a heyoka run's first chunk of steps (:mod:`lieseries.taylor`,
    whose step is one chunk of steps run inside heyoka), an atlas run's first segment (its rows).

An ensemble's scalar members run on it too (:mod:`lieseries.ensemble.threads`); heyoka's batch mode, many members
in the lanes of one integrator, keeps its own chunked loop (:mod:`lieseries.ensemble.batch`), with this table's
messages.
"""

from __future__ import annotations

import decimal
import time as _time
from dataclasses import dataclass, field
from typing import Any, Callable

from .energy import energy_exact, exact_energy_verdict, guard_tolerance
from .precision import short_decimal, to_fraction
from .solution import STATUSES

__all__ = ["MESSAGES", "KEPT_ROWS", "Stop", "StepResult", "Outcome", "drive", "run_message", "format_time",
           "energy_guard"]


#: The message of every way a run ends, by reason (a status of :data:`lieseries.solution.STATUSES`, or a more
#: precise reason of one). ``{where}`` is "t = <time>" (with the engine's note), ``{detail}`` the engine's own
#: account of the cause, ``{kept}`` what the rows up to the stop are worth.
MESSAGES = {
    "success": "Reached t = {t}{detail}.",
    "step_budget": "The step budget `max_steps` = {max_steps} ran out at {where}; raise `max_steps` to go on. {kept}",
    # a heyoka run, which knows how many steps finishing would take at its current step size ({detail})
    "step_budget.ahead": ("Stopped early at {where}: {detail}, more than the step budget `max_steps` = {max_steps} "
                          "allows; raise `max_steps` to go on. {kept}"),
    "step_budget.hopeless": ("Stopped early at {where}: {detail}, more than any step budget allows; shorten the time "
                             "span or rescale time. {kept}"),
    "time_budget": ("The wall-time budget `max_time` = {max_time:g} s ran out at {where}; raise `max_time` to go on. "
                    "{kept}"),
    "event": "Stopped at {where}: {detail}.",
    "chart_edge": "Stopped at {where}: {detail}.",
    "non_finite": "The step after {where} cannot be taken: {detail}. {kept}",
    "non_finite.taylor": ("The step after {where} cannot be taken: the state becomes non-finite (NaN or infinity) in "
                          "it: the solution blows up or leaves the domain of the equations there, or a number of the "
                          "step (a Taylor coefficient grows like rate^order) exceeds the range of the format -- "
                          "rescale a state or rate of order 1e300 (the last finite state is kept). {kept}"),
    "step_collapse": "The step size collapsed at {where}: {detail}.",
    "step_collapse.taylor": ("The step size collapsed near {where}, from {h_first:.3g} earlier: {detail}, more than "
                             "the {allowed} steps allowed for it (pass `max_steps` to allow more). The solution is "
                             "singular or nearly so there, or it moves on a much faster time scale than before (a "
                             "fast rotation or oscillation); an explicit Taylor method cannot cross it efficiently."),
    "step_collapse.stiff": ("Tiny steps: near {where} the state changes per step by at most {change:.1e} (relative to "
                            "its entries, the small ones measured against the largest). {detail}, more than the "
                            "{allowed} steps allowed for such a run (pass `max_steps` to allow more). Either the "
                            "problem is stiff (a fast decaying mode, e.g. strong damping: reduce it, or use an "
                            "implicit method for this part of the motion), or some variables move on a time scale "
                            "far shorter than the run (a fast rotation or oscillation: a large angular velocity, or "
                            "moments of inertia far apart): rescale time or shorten the run."),
    "step_collapse.touch": ("The run cannot go on at {where}: {detail} is zero there without crossing (its expression "
                            "and its rate of change vanish together, as `q` does from rest at q = 0), and heyoka "
                            "stops on it again at once, without a step (its cooldown after an event comes from that "
                            "rate). Start just off the event's surface, make the event non-terminal (its crossings "
                            "are recorded and the run goes on), or use lie_integrate. {kept}"),
    "validation_failed": "Validation failed at {where}: {detail}; {kept_lower}",
}


#: What the rows of a run that stopped early are worth, for an engine whose rows are plain values (``kept``).
KEPT_ROWS = "The rows up to this time are kept."


def format_time(t) -> str:
    """A time of any engine (float, Fraction, mpf, a heyoka format) rounded to 17 significant digits in decimal,
    trailing zeros dropped: the double 2.3 reads 2.2999999999999998, an mpf run's 1/20 reads 0.05 (not the
    0.050000000000000003 of the double it was read through); beyond the double range too."""
    f = to_fraction(t)
    if f == 0:
        return "0"
    try:
        float(f)
    except OverflowError:
        return short_decimal(f)
    d = decimal.Context(prec=17).divide(decimal.Decimal(f.numerator), decimal.Decimal(f.denominator))
    if d == d.to_integral_value() and abs(d) < 10**17:
        return str(int(d))
    return format(d.normalize(decimal.Context(prec=17)), "g")


def run_message(reason: str, *, t=None, note: str = "", detail: str = "", kept: str = "", **fields) -> str:
    """The message of a run that ended for ``reason`` (a key of :data:`MESSAGES`) at time ``t``."""
    where = f"t = {format_time(t)}{note}" if t is not None else ""
    kept_lower = kept[:1].lower() + kept[1:] if kept else ""
    return MESSAGES[reason].format(t=format_time(t) if t is not None else "", where=where, detail=detail,
                                   kept=kept, kept_lower=kept_lower, **fields).strip()


class Stop(Exception):
    """Raised by an engine's step (or its dense evaluator) that cannot go on: the run ends with ``status`` at the
    time the step started. ``detail``: the cause, worded to follow "at t = ...: " in :data:`MESSAGES`;
    ``message``: a whole message instead (rarely needed); ``reason``: the entry of :data:`MESSAGES` (default: the
    status), ``fields`` the values its wording needs beyond the usual ones."""

    def __init__(self, status: str, detail: str = "", message: str | None = None, note: str = "",
                 reason: str | None = None, fields: dict | None = None):
        if status not in STATUSES:  # pragma: no cover - programming error
            raise ValueError(f"unknown status {status!r}")
        super().__init__(status, detail)
        self.status, self.detail, self.message, self.note = status, detail, message, note
        self.reason, self.fields = reason or status, fields or {}

    def text(self, t, fields: dict) -> str:
        """The message of this stop at time ``t``, from :data:`MESSAGES` unless the stop carries its own."""
        return self.message or run_message(self.reason, t=t, note=self.note, detail=self.detail,
                                           **{**fields, **self.fields})


@dataclass
class StepResult:
    """What one step of an engine gives the driver."""

    t: Any
    z: Any
    h: Any = None  # the step's length (for the statistics), in the engine's numbers
    row: Callable | None = None  # the state at an output time inside the step (None: only the step's end)
    error: float | None = None  # the step's error estimate
    # (status, detail, note) or a Stop: a terminal condition met in the step; Stop("success"): the run is done
    # (an engine whose final time, rounded in its format, is not exactly the driver's)
    stop: tuple | Stop | None = None
    rows: list | None = None  # instead of ``row``: the step's rows, already evaluated, at the next output times
    steps: int = 1  # how many steps it counts for (a whole chart segment of another run: its steps)


@dataclass
class Outcome:
    """Where a driven run ended: its status and message, the time and state reached, the rows, the counts."""

    status: str
    message: str
    t: Any
    z: Any
    steps: int
    rows_t: list = field(default_factory=list)
    rows_y: list = field(default_factory=list)
    rows_chart: list = field(default_factory=list)
    switches: int = 0
    estimates: list = field(default_factory=list)
    hmin: Any = None
    hmax: Any = None
    run_time: float = 0.0


def drive(engine, t0, z0, pending, *, direction, max_steps: int, max_time: float | None = None, start=None,
          progress=None, kept: str = "", reached: str = "", atlas: bool = False, max_switches: int = 0,
          guard=None, reached_message: str | None = None) -> Outcome:
    """Run ``engine`` from ``(t0, z0)`` to the last of ``pending``, the output times as ``(time, label)`` pairs
    in time order (``time`` in the engine's numbers, ``label`` what the row is reported at).

    Rows at the times not after ``t0`` are the initial state. ``max_time`` is measured from ``start`` (a
    ``time.perf_counter()`` reading; default now). ``progress(fraction)`` is called after every step. ``kept``
    says what the rows up to an early stop are worth (ends the messages of failures); ``reached_message``, the
    message of a run that reached its final time when the caller has it already (many runs to one time)."""
    start = _time.perf_counter() if start is None else start
    sgn = 1 if direction >= 0 else -1
    pending = list(pending)
    t_end = pending[-1][0] if pending else t0
    run = _Run(engine, pending, sgn, Outcome("success", "", t0, z0, 0), atlas, max_switches,
               {"kept": kept, "max_time": max_time or 0, "max_steps": max_steps})
    out = run.out
    t, z = t0, z0
    if not getattr(engine, "emits_rows", False):
        run.emit(t, lambda tk: z0)
    span = t_end - t0
    # an engine that emits its rows gives the row at t0 in its first step, which runs whatever the budgets (it
    # bounds itself: an atlas segment gets the budgets as given); so does a heyoka run's first chunk
    budgets = not getattr(engine, "free_first_step", getattr(engine, "emits_rows", False))
    while direction and (t_end - t) * sgn > 0:
        if budgets and run.over_budget(t, max_steps, max_time, start):
            break
        budgets = True
        try:
            res = engine.step(t, z, t_end)
            run.take_rows(res)
        except Stop as stop:
            znew = run.end(stop, t, z)
            if znew is None:
                break
            z = znew  # the chart was ending before the step: go on in the new one
            continue
        run.count(res)
        t, z = res.t, res.z
        if progress is not None:
            progress(float((t - t0) / span))
        if res.stop is not None:
            stop = res.stop if isinstance(res.stop, Stop) else Stop(res.stop[0], res.stop[1], note=res.stop[2])
            znew = run.end(stop, t, z)
            if znew is None:
                break
            z = znew  # the step crossed into the chart's edge: go on in the new chart
    out.t, out.z = t, z
    if out.status == "success":
        out.message = reached_message or run_message("success", t=t_end, detail=reached)
        if guard is not None and direction:
            guard(out)
    if atlas:
        out.message = f"{out.message} ({out.switches} chart switches)"
    out.run_time = _time.perf_counter() - start
    return out


class _Run:
    """The bookkeeping of one :func:`drive`: rows at the output times, budgets, statistics, stops and chart
    switches."""

    def __init__(self, engine, pending, sgn, out, atlas, max_switches, fields):
        self.engine, self.pending, self.sgn, self.out = engine, pending, sgn, out
        self.atlas, self.max_switches, self.fields = atlas, max_switches, fields
        self.explain = getattr(engine, "explain", None)

    def emit(self, limit, row):
        """The rows at the pending times up to ``limit`` from the step's evaluator ``row``."""
        pending, out, sgn = self.pending, self.out, self.sgn
        while pending and (pending[0][0] - limit) * sgn <= 0:
            tk, label = pending.pop(0)
            out.rows_y.append(row(tk))  # may raise Stop: the rows before it stay
            out.rows_t.append(label)
            out.rows_chart.append(getattr(self.engine, "chart", None))

    def take_rows(self, res) -> None:
        """A step's rows: evaluated by the engine already (``res.rows``), or from its evaluator."""
        if res.rows is None:  # (no evaluator: the step's end only, the state it reached)
            self.emit(res.t, res.row if res.row is not None else (lambda tk: res.z))
            return
        out = self.out
        for _tk, y in res.rows:
            out.rows_t.append(self.pending.pop(0)[1])
            out.rows_y.append(y)
            out.rows_chart.append(getattr(self.engine, "chart", None))

    def over_budget(self, t, max_steps, max_time, start) -> bool:
        """Whether a budget ran out before the next step (the run's status and message set)."""
        over = None
        if self.out.steps >= max_steps:
            over = "step_budget"
        elif max_time is not None and _time.perf_counter() - start > max_time:
            over = "time_budget"
        if over is None:
            return False
        stop = self.explain(over, t) if self.explain is not None else Stop(over)
        self.out.status, self.out.message = stop.status, stop.text(t, self.fields)
        return True

    def count(self, res) -> None:
        """A step's statistics: steps, error estimate, the smallest and largest step."""
        out = self.out
        out.steps += res.steps
        if res.error is not None:
            out.estimates.append(res.error)
        if res.h is not None:
            out.hmin = res.h if out.hmin is None else min(out.hmin, res.h)
            out.hmax = res.h if out.hmax is None else max(out.hmax, res.h)

    def end(self, stop, t, z):
        """The state in a better chart when ``stop`` is a chart's edge and one can be had (the run goes on);
        else None, the run's status and message set from ``stop``."""
        if stop.status == "chart_edge" and self.atlas and self.out.switches < self.max_switches:
            znew = self.engine.switch_chart(t, z)
            if znew is not None:
                self.out.switches += 1
                return znew
        self.out.status, self.out.message = stop.status, stop.text(t, self.fields)
        return None


def energy_guard(out: Outcome, ps, y0, y_end, bits: int, tol) -> None:
    """The energy guard of a run that reached its final time: ``invariant_drift`` (with its message) when the
    Hamiltonian of ``ps``, at the exact values of ``y0`` and ``y_end`` in mpmath at ``bits`` bits, changed by more
    than :func:`lieseries.energy.drift_threshold` times the energy scale of ``y0`` (or of ``y_end``, the larger), at
    the tolerance :func:`lieseries.energy.guard_tolerance` reads."""

    if out.status != "success" or not ps.is_hamiltonian:
        return
    e0, scale0 = energy_exact(ps, y0, bits, remember=True)
    e1, scale1 = energy_exact(ps, y_end, bits)
    # the larger of the two scales: from rest at q = 0 under a force (H = p^2/2 - q + ...) H and its terms vanish
    # at y0, and a run right to 1e-33 ended invariant_drift on a threshold of 0
    out.status, out.message = exact_energy_verdict(e0, e1, max(scale0, scale1), guard_tolerance(ps, tol, bits),
                                                   out.status, out.message, out.steps)
