"""Running a scene: compute exactly what it asks for (runs, studies) and return it as data.

:func:`run_scene` is the only entry point; :mod:`lieseries.scenes` defines and validates scenes, and
:func:`lieseries.report.write_report` turns a :class:`SceneResult` into a report (this module writes no file).
"""

from __future__ import annotations

import platform
import re
import threading
import time as _time
import warnings
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from .methods import (
    RunRecord,
    method_label,
    method_plugin,
    normalize_method,
    reference_bits,
    reference_dps,
    run_atlas_method,
    run_method,
)
from .models.base import as_model
from .precision import check_seconds, dps_to_bits, float_or_mpf, to_fraction
from .precision import thread_mp as mp
from .scenes import Scene, SceneError, effective_plan, load_scene
from .studies.drift import invariant_function
from .studies.reference import max_difference, numerical_reference_label, observables
from .studies.plugin import StudyContext, studies_registry

__all__ = ["RunRow", "SceneResult", "environment", "run_scene", "scaled_error"]


#: One method of the [run] table on one model: the one run record (:class:`lieseries.methods.RunRecord`).
RunRow = RunRecord


@dataclass
class SceneResult:
    """Everything a scene run computed (plain data; :func:`lieseries.report.write_report` writes it).

    Attributes
    ----------
    scene : Scene
    quick : bool
    run : dict or None         {"t", "reference", "rows": [RunRow], "invariants": [...]} or None
    trajectories : dict        model label -> {"quantity", "names", "times", "values", "errors": {label: [...]}}
    studies : dict             study name -> list of (model label, study result)
    notes : list of str        what was left out and why
    failed_studies : list      "study (model): what went wrong" for a study that raised (its results are missing)
    wall_time : float
    environment : dict
    """

    scene: Scene
    quick: bool
    run: dict | None = None
    trajectories: dict = field(default_factory=dict)
    studies: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    failed_studies: list = field(default_factory=list)
    wall_time: float = 0.0
    environment: dict = field(default_factory=dict)
    created: str = ""

    def unsuccessful(self) -> list:
        """One line for each run of the scene that ended without success -- in the ``[run]`` table or in a study
        (work-precision rows, drift runs, departure-map members by precision) -- and each study that failed.
        Empty when everything succeeded (the CLI's exit status 0)."""
        out = [f"run: {r.label} ({r.model}): {r.status}" for r in (self.run or {}).get("rows", [])
               if r.status != "success"]
        for name, study in studies_registry().items():
            out += study.unsuccessful(self.studies.get(name, []))
        return out + list(self.failed_studies)

    def to_dict(self) -> dict:
        run = None
        if self.run is not None:
            run = {k: v for k, v in self.run.items() if k != "rows"}
            run["rows"] = [r.to_dict() for r in self.run["rows"]]
        return {
            "scene": self.scene.to_dict(),
            "quick": self.quick,
            "run": run,
            "trajectories": self.trajectories,
            "studies": {name: [{"model": lab, **res.to_dict()} for lab, res in items]
                        for name, items in self.studies.items()},
            "notes": list(self.notes),
            "wall_time": self.wall_time,
            "environment": dict(self.environment),
            "created": self.created,
        }


def environment() -> dict:
    """Versions of what computed a result (for reports); "not installed" for a package that cannot be imported."""
    import importlib
    from importlib.metadata import PackageNotFoundError, version

    try:
        own = version("lieseries")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
        own = "?"
    env = {"lieseries": own, "python": platform.python_version()}
    for name in ("heyoka", "numpy", "mpmath", "scipy"):
        try:
            env[name] = getattr(importlib.import_module(name), "__version__", "?")
        except ImportError:
            env[name] = "not installed"
    env["platform"] = platform.platform()
    return env


def _make_progress(progress, title):
    from .progress import ProgressBar, null_progress

    if progress is True:
        return ProgressBar(title)
    if progress in (False, None):
        return _Null(null_progress)
    return _Null(progress)


class _Null:
    """Wraps a plain callable into the bar interface (call + close)."""

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, done, total, label=""):
        self.fn(done, total, label)

    def close(self):
        pass


#: Fewest bits of the numerical references and of the conversions of atlas rows.
REFERENCE_BITS = 256


def _invariants_of(model, states, digits: int):
    """model.invariants of a list of states in any number type (mpf states evaluated with ``digits``)."""
    if not states:
        return None
    first = states[0]
    invariants = invariant_function(model, digits)
    if isinstance(first, np.ndarray) and first.dtype != object:
        return invariants(np.stack(states))
    # mpf (or Fraction) states: hand them over exactly as mpf rows (the model reads their precision)
    with mp.workprec(dps_to_bits(digits) + 32):
        arr = np.stack([np.array([mp.mpf(to_fraction(v).numerator) / to_fraction(v).denominator for v in s],
                                 dtype=object) for s in states])
    return invariants(arr)


def _has_closed_form(model) -> bool:
    """True when the studies' closed-form references describe ``model`` (the model names its closed form)."""
    from .studies import has_exact_solution

    return has_exact_solution(model)


def _numerical_reference(model, y0, t, dps, bits):
    """The studies' numerical reference (:func:`lieseries.studies.numerical_reference`) at ``t``, as a Reference."""
    from .studies import Reference, numerical_reference, observable_names, observables

    rows, label = numerical_reference(model, y0, t, bits)
    return Reference(float(t), observables(model, rows[-1], dps), observable_names(model), "numerical", label, dps)


def _reference_at(model, y0, t, dps, bits):
    from .studies import reference_solution

    if _has_closed_form(model):
        return reference_solution(model, y0, t, dps=dps)
    return _numerical_reference(model, y0, t, dps, bits)


def scaled_error(model, values, reference):
    """Largest error relative to the natural scale of each compared quantity (a float, or an mpf below a float's
    range).

    The model's ``error_groups``: rigid body: R against 1 (a rotation), M against |M_ref|. Sphere: x against
    |x_ref|, v against |v_ref|. Other systems: the state against its norm (1 when it vanishes). ``values`` and ``reference`` are the
    :func:`lieseries.studies.observables` of a run and of the reference (mpf).
    """
    values = [mp.mpf(v) for v in values]  # in this thread's context, at its current precision
    reference = [mp.mpf(v) for v in reference]
    worst = mp.mpf(0)
    for idx, kind in as_model(model).error_groups(len(values)):
        idx = list(idx)
        err = max(abs(values[i] - reference[i]) for i in idx)
        scale = mp.mpf(1) if kind == "unit" else mp.sqrt(mp.fsum(reference[i] ** 2 for i in idx))
        if scale == 0:
            scale = mp.mpf(1)
        worst = max(worst, err / scale)
    return float_or_mpf(worst)  # an mpf below a float's range: a 400-digit run's 1e-402 was written 0.0


def _quick_labels(scene, runp) -> dict:
    """{index: "key = value, ..."} of the [run] methods that carry their own `label` ("Arb 50 digits", which says
    what the scene asked for) and that quick mode changed: their rows say what they really ran with."""
    given = (scene.run or {}).get("methods") or []
    out = {}
    for i, m in enumerate(runp["methods"]):
        orig = given[i] if i < len(given) else m
        if m.get("label") and m != orig:
            out[i] = ", ".join(f"{k} = {m[k]}" for k in m if m.get(k) != orig.get(k))
    return out


def _grid_references(model, y0, grid, dps, bits):
    """The reference's compared quantities at every output time: the closed form, or the numerical reference."""
    from .studies import numerical_reference, observables, reference_solutions

    refs = reference_solutions(model, y0, grid, dps=dps) if _has_closed_form(model) else None
    if refs is None:
        rows, _label = numerical_reference(model, y0, grid, bits)
        refs = [observables(model, y, dps) for y in rows]
    return refs


def _error_along(run, measured, grid, refs_grid, charts, dps):
    """(errors, times, charts) of a run's outputs on the grid against the reference there (the k-th output of a
    run is at grid[k]; a run that stopped early has fewer, plus the state where it stopped, off the grid)."""
    from .studies import max_difference, observables

    errs, etimes, echarts = [], [], []
    for k, (tk, yk) in enumerate(zip(run.times, run.states)):
        if k >= len(grid) or abs(tk - float(grid[k])) > 1e-9 * (1 + abs(tk)):
            continue
        errs.append(max_difference(observables(measured, yk, dps), refs_grid[k], dps))
        etimes.append(float(grid[k]))
        if charts is not None:
            echarts.append(charts[k])
    return errs, etimes, echarts


def _do_run(scene, runp, built, bar, notes):
    tf = to_fraction(runp["t"], "run.t")
    n_out = runp["samples"]
    grid = [tf * k / (n_out - 1) for k in range(1, n_out)]
    specs = [normalize_method(m, f"run.methods[{i}]") for i, m in enumerate(runp["methods"])]
    quick_of = _quick_labels(scene, runp)
    dps = reference_dps(specs)
    bits = reference_bits(specs, REFERENCE_BITS)
    want_traj = "trajectory" in scene.plots
    rows, trajectories = [], {}
    total = len(built) * (len(specs) + 1)
    done = 0
    inv_names = None
    ref_label = ""
    initial_invariants = {}
    for mlabel, model in built:
        y0 = scene.initial_state(model)
        bar(done, total, f"{mlabel}: reference")
        refs = {}
        atlas = as_model(model).runs_on_atlas
        # an atlas run's rows are in several charts: they are measured as states of the model's atlas twin
        measured = model.atlas_twin() if atlas else model

        def ref_at(time_, _model=model, _y0=y0, _refs=refs):
            # computed when a run needs it: a run that stops early is measured where it stopped, and a
            # numerical reference is not asked to cross the stiff part a run could not cross
            if time_ not in _refs:
                _refs[time_] = _reference_at(_model, _y0, time_, dps, bits)
            return _refs[time_]

        ref_label = (f"{ref_at(tf).label}, {dps} digits" if _has_closed_form(model)
                     else f"{numerical_reference_label(bits)}, {dps} digits")
        refs_grid = _grid_references(model, y0, grid, dps, bits) if want_traj else None
        done += 1
        inv0 = invariant_function(model, dps + 10)(y0)  # at the reference's digits (a 400-digit run's drift too)
        inv_names = list(inv0)
        initial_invariants[mlabel] = {k: float(v) for k, v in inv0.items()}
        traj = _new_trajectory(model, grid[: len(refs_grid)]) if want_traj else None
        for i_spec, spec in enumerate(specs):
            bar(done, total, f"{mlabel}: {method_label(spec)}")
            run, extra = _run_spec(model, y0, tf, spec, grid, runp["repeat"], bits, atlas)
            if i_spec in quick_of:
                extra["quick_mode"] = quick_of[i_spec]
            done += 1
            if run.status == "skipped":
                note = f"run: {run.label} skipped ({run.message})."
                if note not in notes:
                    notes.append(note)
                continue
            err = max_err = scaled = None
            drift = {k: None for k in inv_names}
            if run.ok:
                err, scaled, drift = _final_errors(run, model, measured, spec, ref_at(run.t_exact), inv0, dps)
                if refs_grid is not None:
                    max_err = _errors_along_grid(run, measured, grid, refs_grid, extra.get("charts"), dps, traj)
            rows.append(run.measured(model=mlabel, error=err, max_error=max_err, drift=drift, scaled_error=scaled,
                                     extra={k: v for k, v in extra.items() if k != "charts"}))
        if traj is not None:
            shown = as_model(model)
            traj["values"] = [shown.plot_values(row) for row in [observables(model, y0, dps)] + list(refs_grid)]
            trajectories[mlabel] = traj
    bar(total, total, "run done")
    return {"t": float(tf), "samples": n_out, "reference": ref_label, "invariants": inv_names or [],
            "initial_invariants": initial_invariants, "rows": rows}, trajectories


def _new_trajectory(model, times):
    """A model's trajectory for the report: what it plots, at t = 0 and ``times`` (values and errors to come)."""
    qname, names = as_model(model).plot_quantity()
    return {"quantity": qname, "names": list(names), "times": [0.0] + [float(g) for g in times],
            "values": [], "errors": {}, "error_times": {}}


def _run_spec(model, y0, tf, spec, grid, repeat, bits, atlas):
    """One method's run on a model (across its charts for an atlas model): the run record and its extra data."""
    if atlas:
        run, extra = run_atlas_method(model, y0, tf, spec, times=grid, repeat=repeat, bits=bits)
        return run, extra or {}
    run = run_method(model, y0, tf, spec, times=grid, repeat=repeat)
    return run, dict(run.extra)


def _final_errors(run, model, measured, spec, ref, inv0, dps):
    """A finished run against the reference ``ref`` where it ended: the error of its observables, the model's
    scaled error, and each invariant's largest drift from ``inv0`` over its states (None when it kept none)."""
    obs = observables(measured, run.y_final, ref.dps)
    err = max_difference(obs, ref.values, ref.dps)
    with mp.workdps(ref.dps):
        scaled = scaled_error(model, obs, ref.values)
    digits = method_plugin(run.method).state_digits(spec)
    inv = _invariants_of(measured, run.states, digits)
    if inv is None:
        return err, scaled, {k: None for k in inv0}
    drift = {k: max_difference(inv[k], [inv0[k]] * len(inv[k]), max(dps, digits) + 10) for k in inv0}
    return err, scaled, drift


def _errors_along_grid(run, measured, grid, refs_grid, charts, dps, traj):
    """A run's errors on the output grid, recorded in the trajectory ``traj``: the largest, or None."""
    errs, etimes, echarts = _error_along(run, measured, grid, refs_grid, charts, dps)
    if not errs:
        return None
    traj["errors"][run.label] = errs
    traj["error_times"][run.label] = etimes
    if charts is not None:
        traj.setdefault("charts", {})[run.label] = echarts
    return max(errs)


def run_scene(scene, quick: bool = False, progress=True, max_time=None) -> SceneResult:
    """Compute what ``scene`` asks for, and nothing else.

    Parameters
    ----------
    scene : Scene, or a built-in name or path
    quick : bool
        Scale the studies down for CI (see :func:`effective_plan`).
    progress : bool or callable
        True: progress bars on stderr (only when it is a terminal); False: silent; a callable
        ``progress(done, total, label)`` receives the updates.
    max_time : float, optional
        Refuse (:class:`lieseries.cost.SceneTooLong`, naming the scene field that drives it), before computing, a
        scene whose estimated run time (:func:`lieseries.cost.estimate_scene`) exceeds ``max_time`` seconds.

    Notes
    -----
    What the process has compiled already (:mod:`lieseries.cache`: integrators, programs) is used as it is: a run
    whose integrator was built earlier in the process, by this scene or another, reports a build time of 0 (the
    report says so). The runs' warnings are gathered and given once each when the scene returns; scenes run one at
    a time in a process (calls from other threads wait).

    Returns
    -------
    SceneResult
    """
    scene = load_scene(scene)
    if max_time is not None:
        from .cost import check_scene_budget, estimate_scene

        check_scene_budget(estimate_scene(scene, quick), check_seconds(max_time, "max_time"), "`max_time`")
    # every run of the scene warns of its binary numbers at its own precision: said once per number, at the end.
    # Python's warning capture is one for the whole process (two threads that overlap restore each other's and the
    # later warnings of the process went to a finished scene's list, never shown): scenes run one at a time
    caught = []
    with _ONE_SCENE:
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                return _run_scene(scene, quick, progress)
        finally:
            for category, message in scene_warnings(scene, caught):
                warnings.warn(message, category, stacklevel=2)


_ONE_SCENE = threading.RLock()


#: The words of a PrecisionWarning that differ from run to run of a scene: the run's precision.
_RUN_BITS = re.compile(r"the run works with (\d+) bits")


def scene_warnings(scene, caught) -> list:
    """The distinct warnings of a scene's runs, ``[(category, message)]`` in order: a
    :class:`~lieseries.precision.PrecisionWarning` that the runs gave at several precisions is given once (the
    precisions named as "up to" the highest), and one about a binary number the scene holds says which field
    of the scene it is and to write it as a string."""
    from .precision import PrecisionWarning

    groups: dict = {}
    for w in caught:
        text = str(w.message)
        bits = _RUN_BITS.search(text) if issubclass(w.category, PrecisionWarning) else None
        key = (w.category, _RUN_BITS.sub("", text) if bits else text)
        first, top = groups.get(key, (text, 0))
        groups[key] = (first, max(top, int(bits.group(1)) if bits else 0))
    binary = scene.binary_inputs() if isinstance(scene, Scene) else {}
    out = []
    for (category, _), (text, top) in groups.items():
        if issubclass(category, PrecisionWarning):
            text = _RUN_BITS.sub(f"the scene's runs work with up to {top} bits", text)
            fields = [path for path in binary if _names_field(text, path)]
            if fields:
                text += (" In the scene, write " + ", ".join(f"`{p}`" for p in fields) +
                         ' as strings ("0.1", not 0.1) to mean the decimals exactly.')
        out.append((category, text))
    return out


def _names_field(text: str, path: str) -> bool:
    """Whether a warning's ``text`` is about the scene field at the dotted ``path`` (``model.g``, ``initial.x``):
    it names its last part as an argument or a parameter."""
    name = path.rsplit(".", 1)[-1].split("[")[0]
    return any(f"{a}{name}{b}" in text for a, b in (("`", "`"), ("`", "["), ("['", "']"), ("`", "'")))


def _run_scene(scene, quick, progress) -> SceneResult:
    """:func:`run_scene` of a loaded scene within its budget."""
    start = _time.perf_counter()
    runp, studies = effective_plan(scene, quick)
    built = scene.build_models()
    result = SceneResult(scene=scene, quick=bool(quick), environment=environment(),
                         created=_time.strftime("%Y-%m-%d %H:%M:%S %Z"))
    if scene.binary_note():  # the errors below are measured against the problem with the binary data
        result.notes.append(scene.binary_note())
    if runp is not None:
        bar = _make_progress(progress, "run")
        try:
            result.run, result.trajectories = _do_run(scene, runp, built, bar, result.notes)
        finally:
            bar.close()
    for name, study in studies_registry().items():
        if name not in studies:
            continue
        bar = _make_progress(progress, name.replace("_", " "))
        ctx = StudyContext(scene=scene, built=built, bar=bar, notes=result.notes, failed=result.failed_studies,
                           quick=bool(quick))
        try:
            items = study.run(studies[name], ctx)
        except SceneError:
            raise  # the scene's own settings: bad input
        except Exception as err:  # a failing study must not take the rest of the report with it
            what = f"{name.replace('_', ' ')}: {type(err).__name__}: {err}"
            result.notes.append(f"{what} (the study is missing from this report)")
            result.failed_studies.append(what)
            items = []
        finally:
            bar.close()
        result.studies[name] = items
    result.wall_time = _time.perf_counter() - start
    return result
