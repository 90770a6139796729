"""Up-front estimates of how long a scene will run, and the refusal of a scene that would not finish in a budget.

A scene inside the schema can ask for hours of work (``samples = 100000`` with a Lie method at 200 digits, a
departure map on a 64 x 128 grid at 1024 bits). :func:`estimate_scene` counts, from the scene's effective plan
(:func:`lieseries.scenes.effective_plan`), the units of work each part of it needs -- sample intervals of each run,
the measurements of its output rows, and what each study prices itself at (:meth:`lieseries.studies.Study.cost`:
integrations of each work-precision setting, ensemble members, grid cells, closed-form times, orders) -- and prices
each unit with a :class:`~lieseries.methods.pricing.Pricer` (small timed units bounded by
:data:`CALIBRATION_BUDGET`, a model of heyoka's cost per step; see :mod:`lieseries.methods.pricing`). A study that
does not price itself makes the estimate a lower bound, said so.

The calibration takes well under a second for a usual scene. An estimate is an estimate: it says what it rests on
(:meth:`SceneEstimate.summary`), and it is used to warn before a long computation and to refuse one that would
exceed a budget the user gave (``lieseries run --max-time``), naming the scene field that drives it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .methods import normalize_method, reference_bits, reference_dps
from .methods.pricing import (CALIBRATION_BUDGET, HEYOKA_BUILD_SECONDS, HEYOKA_STEP_SECONDS, CostPart, Pricer,
                              duration, heyoka_step_seconds)
from .precision import to_fraction
from .scenes import SceneError, effective_plan, load_scene
from .studies import (NUMERICAL_REFERENCE_BITS, StudyContext, has_exact_solution, observables, reference_solutions,
                      studies_registry)

__all__ = ["CostPart", "SceneEstimate", "SceneTooLong", "estimate_scene", "check_scene_budget",
           "CALIBRATION_BUDGET", "HEYOKA_STEP_SECONDS", "PRINT_ABOVE", "heyoka_step_seconds"]

#: ``lieseries run`` prints the estimate before computing when it exceeds this many seconds.
PRINT_ABOVE = 30.0


class SceneTooLong(SceneError):
    """A scene whose estimated run time exceeds the budget it was given; the message names the scene field that
    drives the estimate and says how to proceed."""


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
        head = f"estimated {'at least ' if self.lower_bound else ''}{duration(self.seconds)}"
        top = sorted(self.parts, key=lambda p: -p.seconds)
        shown = [f"{p.describe()} (`{p.field}`)" for p in top[:3] if p.seconds >= 0.05 * self.seconds]
        return head + (": " + "; ".join(shown) if shown else "")


def _run_parts(pricer, scene, runp, built):
    parts = []
    n_int = runp["samples"] - 1
    t = to_fraction(runp["t"])
    for mlabel, model in built:
        y0 = scene.initial_state(model)
        for i, m in enumerate(runp["methods"]):
            spec = normalize_method(m, f"run.methods[{i}]")
            per, lower, basis, by_samples = pricer.span(model, y0, spec, t, n_int)
            if spec["method"] == "mpmath":
                cap = min(abs(t), to_fraction(spec["t_max"]))
                units = max(1, int(n_int * cap / abs(t)))
            else:
                units = n_int
            reps = pricer.repeats(per * units, runp["repeat"])
            name = spec["method"] + (f" dps {spec['dps']}" if "dps" in spec and spec["method"] != "taylor"
                                     else f" {spec['precision']}" if spec["method"] == "taylor" else "")
            # the output times drive it when a run steps from one to the next; else its length
            driver = "run.samples" if by_samples else "run.t"
            if "dps" in spec and spec["method"] != "mpmath" and int(spec["dps"]) > 60:
                driver = f"{driver}` and `run.methods[{i}].dps"
            parts.append(CostPart(driver, f"{n_int * reps} sample intervals x {name}" + (f" ({mlabel})" if len(built) > 1 else ""),
                                  units * reps, "sample interval", per, basis, lower))
    pricer.heyoka_builds += sum(1 for m in runp["methods"] if m.get("method") == "taylor")
    return parts


def _measurement_part(pricer, scene, runp, built):
    """The references and measurements of every output row (closed forms at the run's digits)."""
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
            refs, secs = pricer.timed(lambda: reference_solutions(model, y0, grid, dps=dps))
            per += secs / len(grid) if refs is not None else 0.0
        observables(model, y0, dps)  # the first call sets up the model's observables
        _, secs = pricer.timed(lambda: observables(model, y0, dps), quiet=False)
        per += secs * (1 + len(specs))
        parts.append(CostPart("run.samples", f"{n_int * len(built)} output times measured at {dps} digits",
                              n_int * len(built), "output time", per, f"timed at {dps} digits"))
    bits = reference_bits(specs, NUMERICAL_REFERENCE_BITS)
    for mlabel, model in built:
        if not has_exact_solution(model):  # measured against heyoka at `bits` run to t (and where runs stopped)
            pricer.heyoka_builds += 1
            secs, lower, basis = pricer.heyoka_run(model, scene.initial_state(model), t, bits, probe="double")
            parts.append(CostPart("run.t", f"the reference (heyoka {bits} bits)" + (f" ({mlabel})" if len(built) > 1
                                                                                  else ""), 1, "run", secs, basis,
                                  lower))
    return parts


def _study_parts(pricer, scene, studies, built, quick):
    """What each study of the plan prices itself at; a study that does not is kept as unpriced (a lower
    bound)."""
    registry = studies_registry()
    parts = []
    for name, opts in studies.items():
        ctx = StudyContext(scene, built, quick=quick)
        priced = _guarded(f"studies.{name}", lambda: registry[name].cost(opts, ctx, pricer))
        if priced is None:
            priced = [CostPart(f"studies.{name}", f"`studies.{name}` not estimated (the study does not price "
                               "itself)", 0, "part", 0.0, "not estimated", lower_bound=True)]
        parts += priced
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
    pricer = Pricer()
    est = SceneEstimate(scene.name)
    if runp is not None:
        est.parts += _guarded("run", lambda: _run_parts(pricer, scene, runp, built))
        est.parts += _guarded("run.samples", lambda: _measurement_part(pricer, scene, runp, built))
    est.parts += _study_parts(pricer, scene, studies, built, quick)
    est.fixed_seconds = HEYOKA_BUILD_SECONDS * pricer.heyoka_builds
    est.calibration_seconds = pricer.spent
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
