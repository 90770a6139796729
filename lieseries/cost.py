"""Up-front estimates of how long a scene will run, and the refusal of a scene that would not finish in a budget.

A scene inside the schema can ask for hours of work (``samples = 100000`` with a Lie method at 200 digits, a
departure map on a 64 x 128 grid at 1024 bits). :func:`estimate_scene` counts, from the scene's effective plan
(:func:`lieseries.scenes.effective_plan`), the units of work each part of it needs -- sample intervals of each run,
integrations of each work-precision setting, ensemble members, grid cells, closed-form times, orders -- and prices
each unit:

- by timing one small representative unit (the Lie and validated engines over the scene's first output intervals,
  the closed form at the scene's digits, a short Lie series), each bounded by a small ``max_time``: a unit that
  does not finish within it is priced at that time, and the estimate is then a lower bound (said so);
- for heyoka's compiled runs (whose compilation alone takes seconds at high precision), by a model: the number of
  steps from a timed 15-digit Lie run over the same motion (heyoka's steps hardly depend on the precision, as its
  order grows with it), times a cost per step by precision measured for the 12-variable rigid body
  (:data:`HEYOKA_STEP_SECONDS`, scaled by the number of variables).

The calibration takes well under a second for a usual scene (:data:`CALIBRATION_BUDGET` per timed unit). An
estimate is an estimate: it says what it rests on (:meth:`SceneEstimate.summary`), and it is used to warn before a
long computation and to refuse one that would exceed a budget the user gave (``lieseries run --max-time``), naming
the scene field that drives it.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field
from fractions import Fraction

from .precision import dps_to_bits, resolve_precision, to_fraction
from .scenes import SceneError, effective_plan, load_scene, orders_of

__all__ = ["CostPart", "SceneEstimate", "SceneTooLong", "estimate_scene", "check_scene_budget",
           "CALIBRATION_BUDGET", "HEYOKA_STEP_SECONDS", "PRINT_ABOVE"]

#: Wall-time bound (seconds) of each timed calibration unit.
CALIBRATION_BUDGET = 0.12
#: Digits a Lie or validated run is timed at when one step at its own digits takes longer than the budget.
SCALE_FROM_DPS = 60
#: Output intervals of a run timed to price one (the scene's first ones, at its spacing).
CALIBRATION_INTERVALS = 4
#: ``lieseries run`` prints the estimate before computing when it exceeds this many seconds.
PRINT_ABOVE = 30.0
#: Seconds per heyoka step of the 12-variable rigid body by precision (double, long double, quad); for
#: ``heyoka.real`` of B bits see :func:`heyoka_step_seconds` (measured: 256 bits 0.06 s, 1024 bits 2.6 s per step).
HEYOKA_STEP_SECONDS = {"double": 2.6e-5, "long double": 1.2e-4, "quad": 4.3e-3}
#: Seconds per output time a run spends besides its steps (the exact conversions and the row), per variable.
OUTPUT_SECONDS = 1e-5
#: The whole scene's fixed cost besides its units: the imports, compiling heyoka's integrators (seconds each).
HEYOKA_BUILD_SECONDS = 1.5


class SceneTooLong(SceneError):
    """A scene whose estimated run time exceeds the budget it was given; the message names the scene field that
    drives the estimate and says how to proceed."""


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
        at = "at least " if self.lower_bound else "~"
        return f"{self.what} at {at}{_duration(self.seconds_each)} each"


@dataclass
class SceneEstimate:
    """The estimate of a scene's run time: its parts, their sum and what they rest on."""

    scene: str
    parts: list = field(default_factory=list)
    fixed_seconds: float = 0.0
    calibration_seconds: float = 0.0

    @property
    def seconds(self) -> float:
        return self.fixed_seconds + sum(p.seconds for p in self.parts)

    @property
    def lower_bound(self) -> bool:
        return any(p.lower_bound for p in self.parts)

    def driver(self) -> CostPart | None:
        """The part that costs most (the one to make smaller)."""
        return max(self.parts, key=lambda p: p.seconds, default=None)

    def summary(self) -> str:
        """``estimated 14 min: 100000 samples x lie dps 200 at ~8 ms each (`run.samples`)`` and the next largest
        parts."""
        head = f"estimated {'at least ' if self.lower_bound else ''}{_duration(self.seconds)}"
        top = sorted(self.parts, key=lambda p: -p.seconds)
        shown = [f"{p.describe()} (`{p.field}`)" for p in top[:3] if p.seconds >= 0.05 * self.seconds]
        return head + (": " + "; ".join(shown) if shown else "")


def _duration(s: float) -> str:
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


class _Clock:
    """The calibration's own clock (how long the estimate took)."""

    def __init__(self):
        self.spent = 0.0

    def timed(self, call):
        t0 = _time.perf_counter()
        try:
            return call(), _time.perf_counter() - t0
        finally:
            self.spent += _time.perf_counter() - t0


def _quiet(call):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return call()


def _time_engine(clock, model, y0, method, dps, order, times):
    """(seconds, time reached, steps) of a Lie / validated run over ``times`` bounded by CALIBRATION_BUDGET."""
    from .lie.integrator import lie_integrate
    from .validated import validated_integrate

    kwargs = {"dps": int(dps), "max_time": CALIBRATION_BUDGET}
    if order is not None:
        kwargs["order"] = int(order)
    engine = lie_integrate if method == "lie" else validated_integrate
    try:
        sol, secs = clock.timed(lambda: _quiet(lambda: engine(model, y0, times, **kwargs)))
    except Exception:  # the run itself will report its error; price it as the budget
        return CALIBRATION_BUDGET, Fraction(0), 0
    return secs, to_fraction(sol.t_reached), int(sol.stats.steps)


def _price_span(clock, model, y0, spec, t, n_out, cache):
    """(seconds per output interval, lower bound?, basis) of ``spec`` running to ``t`` with ``n_out`` output
    intervals of equal length."""
    m = spec["method"]
    t = to_fraction(t)
    spacing = abs(t) / max(1, n_out)
    k = min(n_out, CALIBRATION_INTERVALS)
    sign = 1 if t > 0 else -1
    times = [sign * spacing * j for j in range(1, k + 1)]
    dim = len(y0)
    if m in ("lie", "validated"):
        key = (m, spec.get("dps"), spec.get("order"), t, n_out)
        if key not in cache:
            cache[key] = _price_engine(clock, model, y0, m, spec, t, n_out, times)
        return cache[key]
    if m == "taylor":
        steps_per_time, lower = _steps_per_time(clock, model, y0, abs(t), sign, cache)
        from .taylor import STIFF_STEPS

        step = heyoka_step_seconds(spec["precision"], dim)
        # a run that would need more steps than the stiffness budget stops early (status step_collapse)
        steps_per_time = min(steps_per_time, STIFF_STEPS / float(abs(t)))
        per = steps_per_time * float(spacing) * step + OUTPUT_SECONDS * dim
        return (per, lower, "model: steps from a 15-digit Lie run, heyoka's cost per step by precision",
                OUTPUT_SECONDS * dim > steps_per_time * float(spacing) * step)
    if m == "scipy":
        return 200 * OUTPUT_SECONDS * dim, False, "model", True
    # mpmath: odefun, capped at t_max; one unit per interval inside the cap, priced like a Lie interval
    per, lower, _, by_samples = _price_span(clock, model, y0, {"method": "lie", "dps": max(15, int(spec["dps"]))},
                                            t, n_out, cache)
    return per, lower, "model: like a Lie run at its digits", by_samples


def _timed_run(clock, model, y0, m, spec, times):
    """:func:`_time_engine`, once more when the first call spent its budget setting the engine up (its jets at
    these digits: once for the scene too) and got nowhere."""
    run = _time_engine(clock, model, y0, m, spec["dps"], spec.get("order"), times)
    if run[1] == 0 and run[0] > 2 * CALIBRATION_BUDGET:
        run = _time_engine(clock, model, y0, m, spec["dps"], spec.get("order"), times)
    return run


def _price_engine(clock, model, y0, m, spec, t, n_out, times):
    """(seconds per output interval, lower bound?, basis, driven by the output times?) of a Lie or validated run
    to ``t`` with ``n_out`` output intervals: cost = steps x (seconds per step) + outputs x (seconds per output).
    The steps and their price from the run itself with one output (bounded by the calibration budget), the price
    of an output from the scene's first intervals beyond their steps. A step that does not finish within the
    budget is priced at the budget (a lower bound), with the steps counted by a 15-digit Lie run."""
    spacing = abs(t) / max(1, n_out)
    sign = 1 if t > 0 else -1
    secs_b, reached_b, steps_b = _timed_run(clock, model, y0, m, spec, [t])
    if (reached_b == 0 or not steps_b) and int(spec["dps"]) > SCALE_FROM_DPS:
        # one step at these digits takes longer than the budget: time the run at SCALE_FROM_DPS digits and scale
        # (a step ~ order x order x digits ~ dps^2, an output ~ order x digits ~ dps^1.2, measured 30-200 digits)
        low = dict(spec, dps=SCALE_FROM_DPS, order=None)
        per_step, per_out, steps, lower, _ = _engine_costs(clock, model, y0, m, low, t, n_out, times)
        r = int(spec["dps"]) / SCALE_FROM_DPS
        per_step, per_out = per_step * r**2, per_out * r**1.2
        basis = (f"timed at {SCALE_FROM_DPS} digits and scaled: {steps:.3g} steps at {_duration(per_step)}, "
                 f"{n_out} outputs at {_duration(per_out)}")
    else:
        per_step, per_out, steps, lower, basis = _engine_costs(clock, model, y0, m, spec, t, n_out, times,
                                                               (secs_b, reached_b, steps_b))
    steps = min(steps, _max_steps(m))  # the run stops at its step budget (status step_budget)
    total = steps * per_step + n_out * per_out
    return total / max(1, n_out), lower, basis, n_out * per_out > steps * per_step


def _max_steps(method) -> int:
    """The default step budget of the engine a scene's method runs (scenes set none)."""
    import inspect

    from .lie.integrator import lie_integrate
    from .validated import validated_integrate

    engine = lie_integrate if method == "lie" else validated_integrate
    default = inspect.signature(engine).parameters["max_steps"].default
    return int(default) if isinstance(default, int) else 10**9


def _engine_costs(clock, model, y0, m, spec, t, n_out, times, run_b=None):
    """(seconds per step, seconds per output, steps, lower bound?, basis) of a Lie or validated run."""
    spacing = abs(t) / max(1, n_out)
    sign = 1 if t > 0 else -1
    secs_b, reached_b, steps_b = run_b or _timed_run(clock, model, y0, m, spec, [t])
    if reached_b != 0 and steps_b:
        per_step, rate, lower = secs_b / steps_b, steps_b / float(abs(reached_b)), False
    else:
        per_step = max(secs_b, CALIBRATION_BUDGET)
        rate, _ = _steps_per_time(clock, model, y0, abs(t), sign, {})
        lower = True
    secs_a, reached_a, steps_a = _timed_run(clock, model, y0, m, spec, times)
    steps = rate * float(abs(t))
    per_out = 0.0
    if reached_a != 0:
        intervals = float(abs(reached_a) / spacing)
        if steps_a >= intervals:  # an engine that steps to every output time
            steps = max(steps, steps_a / intervals * n_out)
        per_out = max(0.0, secs_a - steps_a * per_step) / intervals
    else:
        lower = True
    basis = (f"timed: {steps:.3g} steps at {_duration(per_step)}, {n_out} outputs at {_duration(per_out)}"
             + (" (a step did not finish within the calibration budget: a lower bound)" if lower else ""))
    return per_step, per_out, steps, lower, basis


def _repeats(seconds: float, repeat: int) -> int:
    """How many of ``repeat`` best-of runs of ``seconds`` each are made: they stop once REPEAT_BUDGET is used."""
    from .methods import REPEAT_BUDGET

    return max(1, min(int(repeat), int(REPEAT_BUDGET // max(seconds, 1e-12)) + 1))


def _steps_per_time(clock, model, y0, span, sign, cache):
    """(heyoka steps per unit time, lower bound?) of the motion from ``y0``, from a 15-digit Lie run."""
    key = ("steps", span)
    if key not in cache:
        secs, reached, steps = _time_engine(clock, model, y0, "lie", 15, None, [sign * span])
        if reached == 0 or steps == 0:
            cache[key] = (1 / float(span), True)
        else:
            cache[key] = (steps / float(abs(reached)), False)
    return cache[key]


def _run_parts(clock, scene, runp, built, cache):
    from .methods import normalize_method

    parts = []
    n_int = runp["samples"] - 1
    t = to_fraction(runp["t"])
    repeat = runp["repeat"]
    for mlabel, model in built:
        y0 = scene.initial_state(model)
        for i, m in enumerate(runp["methods"]):
            spec = normalize_method(m, f"run.methods[{i}]")
            per, lower, basis, by_samples = _price_span(clock, model, y0, spec, t, n_int, cache)
            if spec["method"] == "mpmath":
                cap = min(abs(t), to_fraction(spec["t_max"]))
                units = max(1, int(n_int * cap / abs(t)))
            else:
                units = n_int
            reps = _repeats(per * units, repeat)
            name = spec["method"] + (f" dps {spec['dps']}" if "dps" in spec and spec["method"] != "taylor"
                                     else f" {spec['precision']}" if spec["method"] == "taylor" else "")
            # the output times drive it when a run steps from one to the next; else its length
            driver = "run.samples" if by_samples else "run.t"
            if "dps" in spec and spec["method"] != "mpmath" and int(spec["dps"]) > 60:
                driver = f"{driver}` and `run.methods[{i}].dps"
            parts.append(CostPart(driver, f"{n_int * reps} sample intervals x {name}" + (f" ({mlabel})" if len(built) > 1 else ""),
                                  units * reps, "sample interval", per, basis, lower))
    return parts


def _measurement_part(clock, scene, runp, built):
    """The references and measurements of every output row (closed forms at the run's digits)."""
    from .methods import normalize_method, reference_dps
    from .studies import observables, reference_solutions

    specs = [normalize_method(m, f"run.methods[{i}]") for i, m in enumerate(runp["methods"])]
    dps = reference_dps(specs)
    n_int = runp["samples"] - 1
    t = to_fraction(runp["t"])
    parts = []
    for mlabel, model in built[:1]:
        y0 = scene.initial_state(model)
        grid = [t * k / n_int for k in (1, 2)] if n_int >= 2 else [t]
        per = 0.0
        if "trajectory" in scene.plots:
            refs, secs = clock.timed(lambda: _quiet(lambda: reference_solutions(model, y0, grid, dps=dps)))
            per += secs / len(grid) if refs is not None else 0.0
        observables(model, y0, dps)  # the first call sets up the model's observables
        _, secs = clock.timed(lambda: observables(model, y0, dps))
        per += secs * (1 + len(specs))
        parts.append(CostPart("run.samples", f"{n_int * len(built)} output times measured at {dps} digits",
                              n_int * len(built), "output time", per, f"timed at {dps} digits"))
    return parts


def _study_parts(clock, scene, studies, built, quick, cache):
    from .methods import default_methods, expand_methods

    parts = []
    if "error_vs_order" in studies:
        ev = studies["error_vs_order"]
        top = max(orders_of(ev))
        dps = int(ev["dps"])
        model = built[0][1]
        y0 = scene.initial_state(model)
        o_c = min(top, 12)
        from .lie.operator import lie_series

        _, secs = clock.timed(lambda: _quiet(lambda: lie_series(model, y0, order=o_c, dps=dps)))
        per_model = secs * (top / o_c) ** 2
        parts.append(CostPart("studies.error_vs_order.max_order", f"{len(built)} Lie series to order {top} at "
                              f"{dps} digits", len(built), "series", per_model,
                              f"timed to order {o_c}, scaled by order^2"))
    if "work_precision" in studies:
        wp = studies["work_precision"]
        methods = wp["methods"] if wp["methods"] is not None else default_methods(quick)
        t = to_fraction(wp["t"] if wp["t"] is not None else (scene.run or {}).get("t", 1))
        for mlabel, model in built:
            y0 = scene.initial_state(model)
            for spec in expand_methods(methods, "studies.work_precision.methods"):
                per, lower, basis, _ = _price_span(clock, model, y0, spec, t, 1, cache)
                if spec["method"] == "mpmath":
                    per *= float(min(abs(t), to_fraction(spec["t_max"])) / abs(t))
                reps = _repeats(per, wp["repeat"])
                parts.append(CostPart("studies.work_precision.methods", f"{spec['method']} run to t = {float(t):g}",
                                      reps, "run", per, basis, lower))
    if "drift" in studies:
        dr = studies["drift"]
        for mlabel, model in built:
            y0 = scene.initial_state(model)
            t = to_fraction(dr["t"])
            rate, lower = _steps_per_time(clock, model, y0, min(t, Fraction(1)), 1, cache)
            per = rate * float(t) * heyoka_step_seconds(dr["precision"], len(y0)) + \
                dr["samples"] * OUTPUT_SECONDS * len(y0)
            parts.append(CostPart("studies.drift.ensemble", f"{dr['ensemble']} drift members to t = {float(t):g} "
                                  f"in {dr['precision']}", dr["ensemble"], "member", per,
                                  "model: steps from a 15-digit Lie run, heyoka's cost per step by precision", lower))
    if "departure_map" in studies:
        parts += _departure_parts(clock, studies["departure_map"], built, cache)
    return parts


def _departure_parts(clock, dm, built, cache):
    from . import exact
    from .models import EulerPoisson

    cells = int(dm["grid"][0]) * int(dm["grid"][1])
    samples = int(dm["samples"])
    T = to_fraction(dm["T"])
    precs = [resolve_precision(p) for p in dm["precisions"]]
    ref_dps = max(int(dm["dps"]), max(math.ceil(p.bits * math.log10(2)) for p in precs) + 10)
    parts = []
    for mlabel, model in built:
        inertia = tuple(model.inertia_exact[j][j] for j in range(3))
        # a generic unit M0 (the grid's cells differ in their motion, not in the work of one closed form)
        M0 = (Fraction(3, 5), Fraction(0), Fraction(4, 5))
        omega = tuple(m / i for m, i in zip(M0, inertia))
        times = [T * k / samples for k in (1, 2)]
        _, secs = clock.timed(lambda: exact.euler_poisson_many(inertia, omega, times, dps=ref_dps))
        parts.append(CostPart("studies.departure_map.grid", f"{cells} cells x {samples} closed-form times at "
                              f"{ref_dps} digits", cells * samples, "closed-form time", secs / len(times),
                              f"timed at {ref_dps} digits"))
        body = EulerPoisson(inertia)
        y0 = body.initial_state(omega=omega)
        rate, lower = _steps_per_time(clock, body, y0, min(T, Fraction(1)), 1, cache)
        for p in precs:
            per = rate * float(T) * heyoka_step_seconds(p, 12) + samples * OUTPUT_SECONDS * 12
            drivers = "studies.departure_map.grid" + ("` and `studies.departure_map.precisions" if p.bits > 113 else "")
            parts.append(CostPart(drivers, f"{cells} members to T = {float(T):g} in {p.name}",
                                  cells, "member", per,
                                  "model: steps from a 15-digit Lie run, heyoka's cost per step by precision",
                                  lower))
    return parts


def _guarded(field_, call) -> list:
    """The parts ``call()`` prices; a part that could not be priced (its calibration raised: the run will report
    the error itself) is kept as unpriced, which makes the estimate a lower bound."""
    try:
        return call()
    except SceneError:
        raise
    except Exception as err:
        return [CostPart(field_, f"`{field_}` not estimated ({type(err).__name__}: {err})", 0, "part", 0.0,
                         "not estimated", lower_bound=True)]


def estimate_scene(scene, quick: bool = False) -> SceneEstimate:
    """Estimate how long :func:`lieseries.run.run_scene` will take on ``scene`` (a Scene, a built-in name or a
    path), by counting its units of work and timing small representative ones (see the module docstring).

    Returns
    -------
    SceneEstimate
        ``seconds`` (the total), ``parts`` (:class:`CostPart`: the scene field, the units, the price of one and
        what it rests on), ``driver()`` (the costliest part) and ``summary()``.
    """
    scene = load_scene(scene)
    runp, studies = effective_plan(scene, quick)
    built = scene.build_models()
    clock = _Clock()
    cache = {}
    est = SceneEstimate(scene.name)
    heyoka_builds = 0
    if runp is not None:
        est.parts += _guarded("run", lambda: _run_parts(clock, scene, runp, built, cache))
        est.parts += _guarded("run.samples", lambda: _measurement_part(clock, scene, runp, built))
        heyoka_builds += sum(1 for m in runp["methods"] if m.get("method") == "taylor")
    est.parts += _guarded("studies", lambda: _study_parts(clock, scene, studies, built, quick, cache))
    heyoka_builds += len(studies.get("departure_map", {}).get("precisions", [])) + ("drift" in studies)
    est.fixed_seconds = HEYOKA_BUILD_SECONDS * heyoka_builds
    est.calibration_seconds = clock.spent
    return est


def check_scene_budget(estimate: SceneEstimate, max_time, argname: str = "--max-time") -> None:
    """Refuse (:class:`SceneTooLong`) a scene whose estimate exceeds ``max_time`` seconds, naming the scene field
    that drives the estimate and saying how to proceed."""
    if max_time is None or estimate.seconds <= max_time:
        return
    part = estimate.driver()
    field_ = f"`{part.field}`" if part is not None else "its settings"
    raise SceneTooLong(
        f"scene `{estimate.scene}` would take longer than {argname} {max_time:g} s: {estimate.summary()}. Make "
        f"{field_} smaller (or use --quick), or raise {argname} if you mean to wait."
    )
