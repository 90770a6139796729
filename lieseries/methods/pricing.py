"""Prices of the methods' runs, for up-front estimates of how long a scene will take (:mod:`lieseries.cost`).

A :class:`Pricer` prices one unit of work -- a run of a method specification over some output intervals, a
number of heyoka steps, a timed call -- by timing small representative units (the Lie and validated engines over
the scene's first output intervals), each bounded by :data:`CALIBRATION_BUDGET`: a unit that does not finish
within it is priced at that time, and the price is then a lower bound (said so); heyoka's compiled runs (whose
compilation alone takes seconds at high precision) are priced by a model: the number of steps from a timed
15-digit Lie run over the same motion (heyoka's steps hardly depend on the precision, as its order grows with it),
times a cost per step by precision measured for the 12-variable rigid body (:data:`HEYOKA_STEP_SECONDS`, scaled
by the number of variables). Studies price themselves with it (:meth:`lieseries.studies.Study.cost`) and return
:class:`CostPart` items: units of work, the price of one, the scene field that drives them, what the price rests
on.
"""

from __future__ import annotations

import inspect
import math
import time as _time
import warnings
from dataclasses import dataclass
from fractions import Fraction

from ..lie.integrator import jorba_zou_order, lie_integrate
from ..precision import resolve_precision, to_fraction
from ..api import integrate
from ..taylor import STIFF_STEPS
from ..validated import validated_integrate
from .registry import REPEAT_BUDGET

__all__ = ["CostPart", "Pricer", "duration", "heyoka_step_seconds", "CALIBRATION_BUDGET", "SCALE_FROM_DPS",
           "CALIBRATION_INTERVALS", "HEYOKA_STEP_SECONDS", "OUTPUT_SECONDS", "HEYOKA_BUILD_SECONDS"]

#: Wall-time bound (seconds) of each timed calibration unit.
CALIBRATION_BUDGET = 0.12
#: Digits a Lie or validated run is timed at when one step at its own digits takes longer than the budget.
SCALE_FROM_DPS = 60
#: Output intervals of a run timed to price one (the scene's first ones, at its spacing), against a run over the
#: same span with one output: enough rows that their cost stands out of the step's (a 100-digit row of the rigid
#: body costs ~0.5 ms beside a 47 ms step: four rows priced 100000 outputs at 0 s, a fifth of the real run).
CALIBRATION_INTERVALS = 64
#: Seconds per heyoka step of the 12-variable rigid body by precision (double, long double, quad); for
#: ``heyoka.real`` of B bits see :func:`heyoka_step_seconds` (measured: 256 bits 0.06 s, 1024 bits 2.6 s per step).
HEYOKA_STEP_SECONDS = {"double": 2.6e-5, "long double": 1.2e-4, "quad": 4.3e-3}
#: Seconds per output time a run spends besides its steps (the exact conversions and the row), per variable.
OUTPUT_SECONDS = 1e-5
#: Compiling one of heyoka's integrators (seconds; the scene's fixed cost besides its units).
HEYOKA_BUILD_SECONDS = 1.5


@dataclass
class CostPart:
    """One part of a scene's work: ``units`` units of ``seconds_each``, driven by the scene field ``field``."""

    field: str
    what: str
    units: int
    unit: str
    seconds_each: float
    basis: str
    lower_bound: bool = False

    @property
    def seconds(self) -> float:
        return self.units * self.seconds_each

    def describe(self) -> str:
        at = "no less than " if self.lower_bound else "~"
        return f"{self.what} at {at}{duration(self.seconds_each)} each"


def duration(s: float) -> str:
    """Seconds as a plain duration: '450 us', '1.2 ms', '15 s', '14 min', '3.5 h', '50 days'."""
    if not math.isfinite(s):
        return "forever"
    if s < 1e-3:
        return f"{_digits(s * 1e6)} us"
    if s < 1:
        return f"{_digits(s * 1e3)} ms"
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    if s < 3 * 86400:
        return f"{s / 3600:.3g} h"
    return f"{s / 86400:.3g} days"


def _digits(x: float) -> str:
    """Two or three significant digits without an exponent (150, 2.5, 0.012; '1.5e+02' read as a typo)."""
    text = f"{x:.2g}"
    return f"{x:.0f}" if "e" in text else text


def heyoka_step_seconds(precision, dimension: int) -> float:
    """Model of the seconds one heyoka step takes at ``precision`` for a system of ``dimension`` variables: the
    measured rigid-body cost scaled by the number of variables; for ``heyoka.real`` of B bits the order
    p = B ln2 / 2 + 1 and a cost ~ p^2 B^0.73 (fitted to 256 and 1024 bits)."""
    prec = resolve_precision(precision)
    scale = max(1, int(dimension)) / 12
    if prec.name in HEYOKA_STEP_SECONDS:
        return HEYOKA_STEP_SECONDS[prec.name] * scale
    p = prec.bits * math.log(2) / 2 + 1
    return 0.06 * (p / 89.7) ** 2 * (prec.bits / 256) ** 0.73 * scale


def _quiet(call):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return call()


def _max_steps(method) -> int:
    """The default step budget of the engine a scene's method runs (scenes set none)."""
    engine = lie_integrate if method == "lie" else validated_integrate
    default = inspect.signature(engine).parameters["max_steps"].default
    return int(default) if isinstance(default, int) else 10**9


class Pricer:
    """Prices units of work by timing small ones; one per estimate (it keeps what it timed, and its own time).

    Attributes
    ----------
    spent : float           seconds the calibration took
    heyoka_builds : int     heyoka integrators the priced work compiles (added by who prices it)
    """

    def __init__(self):
        self.spent = 0.0
        self.heyoka_builds = 0
        self._cache = {}

    def timed(self, call, quiet: bool = True):
        """(call(), seconds it took), warnings silenced; the seconds count towards :attr:`spent`."""
        t0 = _time.perf_counter()
        try:
            return (_quiet(call) if quiet else call()), _time.perf_counter() - t0
        finally:
            self.spent += _time.perf_counter() - t0

    @staticmethod
    def repeats(seconds: float, repeat: int) -> int:
        """How many of ``repeat`` best-of runs of ``seconds`` each are made: they stop once REPEAT_BUDGET is
        used."""
        return max(1, min(int(repeat), int(REPEAT_BUDGET // max(seconds, 1e-12)) + 1))

    def steps_per_time(self, model, y0, span, sign=1):
        """(heyoka steps per unit time, lower bound?) of the motion from ``y0``, from a 15-digit Lie run at the
        Jorba-Zou order (heyoka's: the automatic Lie order is higher at low precision, with longer steps)."""
        key = ("steps", id(model), span, sign)
        if key not in self._cache:
            secs, reached, steps = self._engine(model, y0, "lie", 15, jorba_zou_order(1e-15), [sign * span])
            if reached == 0 or steps == 0:
                self._cache[key] = (1 / float(span), True)
            else:
                self._cache[key] = (steps / float(abs(reached)), False)
        return self._cache[key]

    def heyoka_run(self, model, y0, t, precision, samples: int = 0, probe: str = "lie"):
        """(seconds, lower bound?, basis) of a heyoka run from ``y0`` to ``t`` at ``precision`` with ``samples``
        output times: the steps from a 15-digit Lie run over at most one time unit, or (``probe="double"``) from a
        heyoka run in double to ``t`` bounded by the calibration budget (its steps follow the motion further: a
        stiff start seen by a short Lie run overstates the steps of the whole run many times)."""
        t = to_fraction(t)
        rate, span, note = None, abs(t), ""
        if probe == "double":
            rate, stop = self._double_probe(model, y0, t)
            lower = False
            if stop is not None:  # a stiff motion: heyoka's runs stop there, and what is measured with them
                span, lower = stop, True
                note = f" (heyoka stops as stiff near t = {float(stop):.3g}: a run that goes further costs more)"
        if rate is None:
            rate, lower = self.steps_per_time(model, y0, min(abs(t), Fraction(1)), 1 if t > 0 else -1)
        secs = rate * float(span) * heyoka_step_seconds(precision, len(y0)) + samples * OUTPUT_SECONDS * len(y0)
        return secs, lower, (f"model: steps from a {'heyoka double' if probe == 'double' else '15-digit Lie'} run, "
                             "heyoka's cost per step by precision" + note)

    def _double_probe(self, model, y0, t):
        """(steps per unit time, the time it stopped as stiff or None) of a heyoka run in double from ``y0``
        towards ``t`` (bounded by the calibration budget; its compilation is not: once per structure, and the
        scene's own run reuses it); (None, None) when it says nothing."""
        key = ("double probe", id(model), t)
        if key not in self._cache:
            try:
                sol, _ = self.timed(lambda: integrate(model, y0, t=t, precision="double",
                                                      max_time=CALIBRATION_BUDGET))
                reached = abs(to_fraction(sol.t_reached))
                rate = int(sol.stats.steps) / float(reached) if reached and sol.stats.steps else None
                self._cache[key] = (rate, reached if sol.status == "step_collapse" and rate else None)
            except Exception:  # the run itself will report its error
                self._cache[key] = (None, None)
        return self._cache[key]

    def span(self, model, y0, spec, t, n_out):
        """(seconds per output interval, lower bound?, basis, driven by the output times?) of the method
        specification ``spec`` running to ``t`` with ``n_out`` output intervals of equal length."""
        m = spec["method"]
        t = to_fraction(t)
        spacing = abs(t) / max(1, n_out)
        sign = 1 if t > 0 else -1
        dim = len(y0)
        if m in ("lie", "validated"):
            key = (m, id(model), spec.get("dps"), spec.get("order"), t, n_out)
            if key not in self._cache:
                times = [sign * spacing * j for j in range(1, min(n_out, CALIBRATION_INTERVALS) + 1)]
                self._cache[key] = self._price_engine(model, y0, m, spec, t, n_out, times)
            return self._cache[key]
        if m == "taylor":
            steps_per_time, lower = self.steps_per_time(model, y0, abs(t), sign)
            step = heyoka_step_seconds(spec["precision"], dim)
            if steps_per_time * float(abs(t)) > STIFF_STEPS:
                # a stiff run stops early (status step_collapse, after a few chunks of steps); a run that is
                # merely long does not: which one, a short run in double says
                rate, stop = self._double_probe(model, y0, t)
                if stop is not None:
                    steps_per_time = rate * float(stop) / float(abs(t))  # the steps it takes before it stops
            per = steps_per_time * float(spacing) * step + OUTPUT_SECONDS * dim
            return (per, lower, "model: steps from a 15-digit Lie run, heyoka's cost per step by precision",
                    OUTPUT_SECONDS * dim > steps_per_time * float(spacing) * step)
        if m == "scipy":
            return 200 * OUTPUT_SECONDS * dim, False, "model", True
        # mpmath: odefun, capped at t_max; one unit per interval inside the cap, priced like a Lie interval
        per, lower, _, by_samples = self.span(model, y0, {"method": "lie", "dps": max(15, int(spec["dps"]))},
                                              t, n_out)
        return per, lower, "model: like a Lie run at its digits", by_samples

    def _engine(self, model, y0, method, dps, order, times):
        """(seconds, time reached, steps) of a Lie / validated run over ``times`` bounded by CALIBRATION_BUDGET."""
        kwargs = {"dps": int(dps), "max_time": CALIBRATION_BUDGET}
        if order is not None:
            kwargs["order"] = int(order)
        engine = lie_integrate if method == "lie" else validated_integrate
        try:
            sol, secs = self.timed(lambda: engine(model, y0, times, **kwargs))
        except Exception:  # the run itself will report its error; price it as the budget
            return CALIBRATION_BUDGET, Fraction(0), 0
        return secs, to_fraction(sol.t_reached), int(sol.stats.steps)

    def _timed_run(self, model, y0, m, spec, times):
        """:meth:`_engine`, once more when the first call spent its budget setting the engine up (its jets at
        these digits: once for the scene too) and got nowhere."""
        run = self._engine(model, y0, m, spec["dps"], spec.get("order"), times)
        if run[1] == 0 and run[0] > 2 * CALIBRATION_BUDGET:
            run = self._engine(model, y0, m, spec["dps"], spec.get("order"), times)
        return run

    def _price_engine(self, model, y0, m, spec, t, n_out, times):
        """(seconds per output interval, lower bound?, basis, driven by the output times?) of a Lie or validated
        run to ``t`` with ``n_out`` output intervals: cost = steps x (seconds per step) + outputs x (seconds per
        output). The steps and their price from the run itself with one output (bounded by the calibration
        budget), the price of an output from the scene's first intervals beyond their steps. A step that does not
        finish within the budget is priced at the budget (a lower bound), with the steps counted by a 15-digit
        Lie run."""
        secs_b, reached_b, steps_b = self._timed_run(model, y0, m, spec, [t])
        if (reached_b == 0 or not steps_b) and int(spec["dps"]) > SCALE_FROM_DPS:
            # one step at these digits takes longer than the budget: time the run at SCALE_FROM_DPS digits and
            # scale (a step ~ order x order x digits ~ dps^2, an output ~ order x digits ~ dps^1.2, measured 30-200
            # digits)
            low = dict(spec, dps=SCALE_FROM_DPS, order=None)
            per_step, per_out, steps, lower, _ = self._engine_costs(model, y0, m, low, t, n_out, times)
            r = int(spec["dps"]) / SCALE_FROM_DPS
            per_step, per_out = per_step * r**2, per_out * r**1.2
            basis = (f"timed at {SCALE_FROM_DPS} digits and scaled: {steps:.3g} steps at {duration(per_step)}, "
                     f"{n_out} outputs at {duration(per_out)}")
        else:
            per_step, per_out, steps, lower, basis = self._engine_costs(model, y0, m, spec, t, n_out, times,
                                                                        (secs_b, reached_b, steps_b))
        steps = min(steps, _max_steps(m))  # the run stops at its step budget (status step_budget)
        total = steps * per_step + n_out * per_out
        return total / max(1, n_out), lower, basis, n_out * per_out > steps * per_step

    def _engine_costs(self, model, y0, m, spec, t, n_out, times, run_b=None):
        """(seconds per step, seconds per output, steps, lower bound?, basis) of a Lie or validated run."""
        spacing = abs(t) / max(1, n_out)
        sign = 1 if t > 0 else -1
        secs_b, reached_b, steps_b = run_b or self._timed_run(model, y0, m, spec, [t])
        if reached_b != 0 and steps_b:
            per_step, rate, lower = secs_b / steps_b, steps_b / float(abs(reached_b)), False
        else:
            per_step = max(secs_b, CALIBRATION_BUDGET)
            rate, _ = self.steps_per_time(model, y0, abs(t), sign)
            lower = True
        secs_a, reached_a, steps_a = self._timed_run(model, y0, m, spec, times)
        steps = rate * float(abs(t))
        per_out = 0.0
        if reached_a != 0:
            intervals = float(abs(reached_a) / spacing)
            if steps_a >= intervals:  # an engine that steps to every output time
                steps = max(steps, steps_a / intervals * n_out)
            # the same span with one output takes the same steps: the difference is the rows' own cost
            secs_1, reached_1, steps_1 = self._timed_run(model, y0, m, spec, [reached_a])
            base = secs_1 if (reached_1 == reached_a and steps_1 == steps_a) else steps_a * per_step
            per_out = max(0.0, secs_a - base) / intervals
        else:
            lower = True
        basis = (f"timed: {steps:.3g} steps at {duration(per_step)}, {n_out} outputs at {duration(per_out)}"
                 + (" (a step did not finish within the calibration budget: a lower bound)" if lower else ""))
        return per_step, per_out, steps, lower, basis
