"""Running a scene: compute exactly what it asks for (runs, studies) and return it as data.

:func:`run_scene` is the only entry point; :mod:`lieseries.scenes` defines and validates scenes, and
:func:`lieseries.report.write_report` turns a :class:`SceneResult` into a report (this module writes no file).
"""

from __future__ import annotations

import platform
import time as _time
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from .methods import (
    MethodRun,
    best_of,
    clear_rhs_cache,
    default_methods,
    method_label,
    normalize_method,
    precision_name,
    reference_dps,
    run_method,
    setting,
)
from .precision import check_seconds, dps_to_bits, resolve_precision, to_fraction
from .precision import thread_mp as mp
from .scenes import STUDIES, Scene, SceneError, effective_plan, load_scene, orders_of
from .studies.drift import invariant_function

__all__ = ["RunRow", "SceneResult", "environment", "run_scene", "scaled_error"]


@dataclass
class RunRow:
    """One method of the [run] table on one model."""

    model: str
    method: str
    label: str
    precision: str
    setting: str
    t: float
    error: float | None
    max_error: float | None
    drift: dict
    steps: int | None
    order: int | None
    build_time: float | None
    run_time: float | None
    status: str
    message: str
    final_state: list | None = None
    scaled_error: float | None = None
    extra: dict = field(default_factory=dict)

    @property
    def max_drift(self) -> float | None:
        vals = [v for v in self.drift.values() if v is not None]
        return max(vals) if vals else None

    def to_dict(self) -> dict:
        return {
            "model": self.model, "method": self.method, "label": self.label, "precision": self.precision,
            "setting": self.setting, "t": self.t, "error": self.error, "max_error": self.max_error,
            "drift": dict(self.drift), "max_drift": self.max_drift, "steps": self.steps, "order": self.order,
            "build_time": self.build_time, "run_time": self.run_time, "status": self.status,
            "message": self.message, "scaled_error": self.scaled_error, "extra": dict(self.extra),
        }


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
        for lab, wp in self.studies.get("work_precision", []):
            out += [f"work-precision ({lab}): {r.label} {r.setting}: {r.status}" for r in wp.rows
                    if r.status != "success"]
        for lab, dr in self.studies.get("drift", []):
            if dr.status != "success":
                out.append(f"drift ({lab}): {dr.status}")
        for lab, dm in self.studies.get("departure_map", []):
            for prec, statuses in dm.statuses.items():
                bad = [s for s in statuses if s != "success"]
                if bad:
                    kinds = ", ".join(f"{k} x{bad.count(k)}" for k in sorted(set(bad)))
                    out.append(f"departure map ({lab}): {len(bad)} of {len(statuses)} {prec} members: {kinds}")
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


def _needed_bits(specs) -> int:
    """Bits for references and conversions that stay far above every method of ``specs``."""
    bits = REFERENCE_BITS
    for s in specs:
        if s["method"] == "taylor":
            for p in (s["precision"] if isinstance(s["precision"], list) else [s["precision"]]):
                bits = max(bits, resolve_precision(p).bits + 64)
        if s["method"] in ("lie", "mpmath"):
            for d in (s["dps"] if isinstance(s["dps"], list) else [s["dps"]]):
                bits = max(bits, dps_to_bits(d) + 64)
    return bits


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


def _trajectory_quantity(model, label):
    from .models import EulerPoisson, Sphere, SphereDirac
    from .poisson import as_poisson_system

    if isinstance(model, EulerPoisson):
        return "angular velocity Omega", ("Omega1", "Omega2", "Omega3")
    if isinstance(model, (Sphere, SphereDirac)):
        return "position x", ("x1", "x2", "x3")
    return "state", tuple(as_poisson_system(model).names[:3])


def _plot_values(model, ref_rows):
    """Float values of the plotted quantity (Omega, or the position) at the output times, from the reference."""
    from .models import EulerPoisson

    if isinstance(model, EulerPoisson):
        Iinv = np.linalg.inv(model.inertia)
        return [[float(c) for c in Iinv @ np.array([float(v) for v in row[9:12]])] for row in ref_rows]
    return [[float(v) for v in row[:3]] for row in ref_rows]


def _has_closed_form(model) -> bool:
    """True when the studies' closed-form references describe ``model`` (the damped body has none: it is an
    EulerPoisson subclass, but its motion is not the free body's)."""
    from .models import DampedEulerPoisson
    from .studies import has_exact_solution

    return has_exact_solution(model) and not isinstance(model, DampedEulerPoisson)


def _numerical_reference(model, y0, t, dps, bits):
    """The studies' numerical reference (heyoka, >= 256 bits, tol 2^-250) at ``t``, as a Reference."""
    from .studies import (NUMERICAL_REFERENCE_BITS, NUMERICAL_REFERENCE_TOL, Reference, observable_names,
                          observables)
    from .taylor import integrate

    bits = max(NUMERICAL_REFERENCE_BITS, bits)
    sol = integrate(model, y0, t=t, precision=bits, tol=NUMERICAL_REFERENCE_TOL)
    if not sol.success:
        raise RuntimeError(f"the numerical reference (heyoka, {bits} bits) did not reach t = {float(t)}: "
                           f"{sol.message}")
    return Reference(float(t), observables(model, sol.y[-1], dps), observable_names(model), "numerical",
                     f"heyoka, {bits} bits, tol 2^-250", dps)


def _reference_at(model, y0, t, dps, bits):
    from .studies import reference_solution

    if _has_closed_form(model):
        return reference_solution(model, y0, t, dps=dps)
    return _numerical_reference(model, y0, t, dps, bits)


def _error_groups(model, n):
    """[(indices, kind)] of the compared quantities, for errors relative to their natural scale."""
    from .models import EulerPoisson, Sphere, SphereDirac

    if isinstance(model, EulerPoisson):
        return [(range(0, 9), "unit"), (range(9, 12), "norm")]  # R (a rotation), M (scale |M|)
    if isinstance(model, (Sphere, SphereDirac)):
        return [(range(0, 3), "norm"), (range(3, 6), "norm")]  # x (scale |x|), v (scale |v|)
    return [(range(n), "norm")]


def scaled_error(model, values, reference) -> float:
    """Largest error relative to the natural scale of each compared quantity.

    Rigid body: R against 1 (a rotation), M against |M_ref|. Sphere: x against |x_ref|, v against |v_ref|. Other
    systems: the state against its max-norm (1 when it vanishes). ``values`` and ``reference`` are the
    :func:`lieseries.studies.observables` of a run and of the reference (mpf).
    """
    values = [mp.mpf(v) for v in values]  # in this thread's context, at its current precision
    reference = [mp.mpf(v) for v in reference]
    worst = mp.mpf(0)
    for idx, kind in _error_groups(model, len(values)):
        idx = list(idx)
        err = max(abs(values[i] - reference[i]) for i in idx)
        scale = mp.mpf(1) if kind == "unit" else mp.sqrt(mp.fsum(reference[i] ** 2 for i in idx))
        if scale == 0:
            scale = mp.mpf(1)
        worst = max(worst, err / scale)
    return float(worst)


def _dirac_twin(sphere):
    """The Dirac form of the same sphere: atlas rows are compared and measured as (x, p) states of it."""
    from .models import SphereDirac

    return SphereDirac(mass=sphere.mass_exact, radius=sphere.radius_exact, rtol=sphere.rtol)


def _as_dirac_state(sphere, row, chart, bits):
    """A sphere state written in ``chart``, as the (x, p) state of the Dirac form (``bits`` bits)."""
    from .models.base import state_fractions

    prec = resolve_precision(bits)
    arr = prec.array(state_fractions(row, sphere.dimension, "y"))
    x = sphere.position(arr, chart=int(chart))
    v = sphere.velocity(arr, chart=int(chart))
    m = sphere.mass_exact
    return prec.array([to_fraction(c) for c in x] + [m * to_fraction(c) for c in v])


def _run_atlas_method(sphere, y0, tf, spec, grid, repeat, bits):
    """One method across the sphere's atlas (``atlas=True``): a MethodRun whose states are the Dirac (x, p) of
    each output row (rows of an atlas run are written in different charts), with the chart of each row and the
    number of switches in ``extra``."""
    from .lie.integrator import lie_integrate
    from .taylor import integrate

    m = spec["method"]
    label = method_label(spec)
    if m == "taylor":
        prec = resolve_precision(spec["precision"])

        def call():
            return integrate(sphere, y0, t=grid, tol=spec["tol"], precision=prec, atlas=True)
    elif m == "lie":
        kwargs = {"dps": int(spec["dps"])}
        if spec.get("tol") is not None:
            kwargs["tol"] = spec["tol"]
        if spec.get("order") is not None:
            kwargs["order"] = int(spec["order"])

        def call():
            return lie_integrate(sphere, y0, grid, atlas=True, **kwargs)
    else:
        return MethodRun(m, label, precision_name(spec), setting(spec), float(tf), float(tf), status="skipped",
                         message=f"method {m!r} has no atlas runs (use taylor or lie)"), None
    try:
        sol, walls = best_of(call, repeat)
    except Exception as err:  # a failing method is a row, not the end of the run
        return MethodRun(m, label, precision_name(spec), setting(spec), float(tf), float(tf), status="error",
                         message=f"{type(err).__name__}: {err}"), None
    times = [to_fraction(v) for v in sol.t]
    rows = list(sol.y)
    charts = [int(c) for c in sol.charts]
    if sol.y_reached is not None and (not times or times[-1] != to_fraction(sol.t_reached)):
        times.append(to_fraction(sol.t_reached))
        rows.append(sol.y_reached)
        charts.append(int(getattr(sol, "chart_reached", charts[-1] if charts else sphere.chart)))
    states = [_as_dirac_state(sphere, r, c, bits) for r, c in zip(rows, charts)]
    st = sol.stats
    build = float(st.build_time or 0.0)
    run = MethodRun(
        m, label, precision_name(spec), setting(spec), float(times[-1]), float(tf), t_exact=times[-1],
        times=[float(v) for v in times], states=states, steps=int(st.steps), order=int(st.order) if st.order else None,
        build_time=build if m == "taylor" else None, run_time=float(min([walls[0] - build] + walls[1:])),
        core_time=float(st.run_time), status=sol.status, message=sol.message,
    )
    extra = {"chart_switches": int(st.extra.get("chart_switches", 0)), "charts": charts}
    if "max_step_over_radius" in st.extra:
        extra["max_step_over_radius"] = float(st.extra["max_step_over_radius"])
    return run, extra


def _do_run(scene, runp, built, bar, notes):
    from .studies import max_difference, observables, reference_solutions

    tf = to_fraction(runp["t"], "run.t")
    n_out = runp["samples"]
    grid = [tf * k / (n_out - 1) for k in range(1, n_out)]
    specs = [normalize_method(m, f"run.methods[{i}]") for i, m in enumerate(runp["methods"])]
    # a method's own `label` ("Arb 50 digits") says what the scene asked for: when quick mode changed that method,
    # its rows carry what it really ran with (the report shows it beside the label)
    given = (scene.run or {}).get("methods") or []
    quick_of = {}
    for i, m in enumerate(runp["methods"]):
        orig = given[i] if i < len(given) else m
        if m.get("label") and m != orig:
            quick_of[i] = ", ".join(f"{k} = {m[k]}" for k in m if m.get(k) != orig.get(k))
    dps = reference_dps(specs)
    bits = _needed_bits(specs)
    want_traj = "trajectory" in scene.plots
    rows, trajectories = [], {}
    total = len(built) * (len(specs) + 1)
    done = 0
    inv_names = None
    ref_label = ""
    initial_invariants = {}
    atlas_of = {m.label: bool(m.params.get("atlas", False)) for m in scene.models}
    for mlabel, model in built:
        y0 = scene.initial_state(model)
        bar(done, total, f"{mlabel}: reference")
        refs = {}
        atlas = atlas_of.get(mlabel, False)
        # an atlas run's rows are in several charts: they are measured as (x, p) states of the Dirac form
        measured = _dirac_twin(model) if atlas else model

        def ref_at(time_, _model=model, _y0=y0, _refs=refs):
            # computed when a run needs it: a run that stops early is measured where it stopped, and a
            # numerical reference is not asked to cross the stiff part a run could not cross
            if time_ not in _refs:
                _refs[time_] = _reference_at(_model, _y0, time_, dps, bits)
            return _refs[time_]

        if _has_closed_form(model):
            ref_label = f"{ref_at(tf).label}, {dps} digits"
        else:
            ref_label = f"heyoka, {max(256, bits)} bits, tol 2^-250, {dps} digits"
        refs_grid = None
        if want_traj:
            refs_grid = reference_solutions(model, y0, grid, dps=dps) if _has_closed_form(model) else None
            if refs_grid is None:  # no closed form: heyoka at 256+ bits on the grid
                from .taylor import integrate

                sol = integrate(model, y0, t=grid, precision=max(256, bits), tol=Fraction(1, 2**250))
                refs_grid = [observables(model, y, dps) for y in sol.y]
        done += 1
        inv0 = invariant_function(model, dps)(y0)
        inv_names = list(inv0)
        initial_invariants[mlabel] = {k: float(v) for k, v in inv0.items()}
        traj = None
        if want_traj:
            qname, names = _trajectory_quantity(model, mlabel)
            traj = {"quantity": qname, "names": list(names),
                    "times": [0.0] + [float(g) for g in grid[: len(refs_grid)]],
                    "values": [], "errors": {}, "error_times": {}}
        for i_spec, spec in enumerate(specs):
            bar(done, total, f"{mlabel}: {method_label(spec)}")
            extra = {}
            if atlas:
                run, extra = _run_atlas_method(model, y0, tf, spec, grid, runp["repeat"], bits)
                extra = extra or {}
            else:
                run = run_method(model, y0, tf, spec, times=grid, repeat=runp["repeat"])
                extra = dict(run.extra)
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
                ref = ref_at(run.t_exact)
                obs = observables(measured, run.y_final, ref.dps)
                err = max_difference(obs, ref.values, ref.dps)
                with mp.workdps(ref.dps):
                    scaled = scaled_error(model, obs, ref.values)
                digits = int(spec.get("dps", 16)) if run.method in ("lie", "mpmath", "validated") else 40
                inv = _invariants_of(measured, run.states, digits)
                if inv is not None:
                    drift = {k: max_difference(inv[k], [inv0[k]] * len(inv[k]), max(dps, digits) + 10)
                             for k in inv_names}
                if refs_grid is not None:
                    errs, etimes, echarts = [], [], []
                    charts = extra.get("charts")
                    # the k-th output of a run is at grid[k] (a run that stopped early has fewer outputs,
                    # plus the state where it stopped, which is not on the grid)
                    for k, (tk, yk) in enumerate(zip(run.times, run.states)):
                        if k >= len(grid) or abs(tk - float(grid[k])) > 1e-9 * (1 + abs(tk)):
                            continue
                        errs.append(max_difference(observables(measured, yk, dps), refs_grid[k], dps))
                        etimes.append(float(grid[k]))
                        if charts is not None:
                            echarts.append(charts[k])
                    if errs:
                        max_err = max(errs)
                        traj["errors"][run.label] = errs
                        traj["error_times"][run.label] = etimes
                        if charts is not None:
                            traj.setdefault("charts", {})[run.label] = echarts
            rows.append(RunRow(
                model=mlabel, method=run.method, label=run.label, precision=run.precision, setting=run.setting,
                t=run.t, error=err, max_error=max_err, drift=drift, steps=run.steps, order=run.order,
                build_time=run.build_time, run_time=run.run_time, status=run.status, message=run.message,
                final_state=[float(to_fraction(v)) for v in run.y_final] if run.ok else None,
                scaled_error=scaled, extra={k: v for k, v in extra.items() if k != "charts"},
            ))
        if traj is not None:
            traj["values"] = _plot_values(model, [observables(model, y0, dps)] + list(refs_grid))
            trajectories[mlabel] = traj
    bar(total, total, "run done")
    return {"t": float(tf), "samples": n_out, "reference": ref_label, "invariants": inv_names or [],
            "initial_invariants": initial_invariants, "rows": rows}, trajectories


def _study_error_vs_order(opts, built, scene, bar, notes, failed):
    from .studies import theoretical_radius
    from .studies.convergence import error_vs_order

    orders = orders_of(opts)
    dps = opts["dps"]
    states = [(lab, model, scene.initial_state(model)) for lab, model in built]
    if opts["t"] is not None:
        t = to_fraction(opts["t"])
    else:
        radii = [theoretical_radius(model, y0) for _, model, y0 in states]
        radii = [r for r in radii if r is not None]
        if not radii:
            raise SceneError("`studies.error_vs_order.t_fraction`: no model of this scene has a known radius of "
                             "convergence; give `t`")
        t = to_fraction(opts["t_fraction"]) * to_fraction(min(radii))
        t = Fraction(t).limit_denominator(10**12)
    out = []
    for i, (lab, model, y0) in enumerate(states):
        def prog(done, total, label, _i=i, _lab=lab):
            bar(_i * total + done, len(states) * total, f"{_lab}: {label}")

        try:
            res = error_vs_order(model, y0, t, orders, dps=dps, fit_min_order=opts["fit_min_order"], progress=prog)
        except Exception as err:  # one failing model must not take the rest of the report with it
            notes.append(f"error vs order ({lab}): failed: {type(err).__name__}: {err}")
            failed.append(f"error vs order ({lab}): {type(err).__name__}: {err}")
            continue
        out.append((lab, res))
    return out


def _study_work_precision(opts, built, scene, bar, notes, quick):
    from .studies.work_precision import work_precision

    methods = opts["methods"] if opts["methods"] is not None else default_methods(quick)
    out = []
    for i, (lab, model) in enumerate(built):
        y0 = scene.initial_state(model)

        def prog(done, total, label, _i=i, _lab=lab):
            bar(_i * total + done, len(built) * total, f"{_lab}: {label}")

        res = work_precision(model, y0, opts["t"], methods=methods, repeat=opts["repeat"], progress=prog)
        for note in res.notes:
            line = f"work-precision: {note}"
            if line not in notes:
                notes.append(line)
        out.append((lab, res))
    return out


def _study_drift(opts, built, scene, bar, notes):
    from .studies.drift import drift

    out = []
    for i, (lab, model) in enumerate(built):
        y0 = scene.initial_state(model)

        def prog(done, total, label, _i=i, _lab=lab):
            bar(_i * total + done, len(built) * total, f"{_lab}: {label}")

        out.append((lab, drift(model, y0, opts["t"], precision=opts["precision"], samples=opts["samples"],
                               tol=opts["tol"], ensemble=opts["ensemble"],
                               perturbation=float(to_fraction(opts["perturbation"])), seed=opts["seed"],
                               first=opts["first"], progress=prog)))
    return out


def _study_departure_map(opts, built, scene, bar, notes):
    """[(model label, DepartureMap)]: the scene's rigid bodies (principal inertia, checked by the scene)."""
    from .studies.departure import departure_map

    out = []
    for i, (lab, model) in enumerate(built):
        def prog(done, total, label, _i=i, _lab=lab):
            bar(_i * total + done, len(built) * total, f"{_lab}: {label}")

        inertia = tuple(model.inertia_exact[j][j] for j in range(3))
        out.append((lab, departure_map(inertia, grid=tuple(opts["grid"]), T=opts["T"], samples=opts["samples"],
                                       precisions=opts["precisions"], threshold=opts["threshold"], dps=opts["dps"],
                                       progress=prog)))
    return out


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
    The integrator cache of :mod:`lieseries.taylor` is cleared first, so that the build times reported are
    those of this scene.

    Returns
    -------
    SceneResult
    """
    from .taylor import clear_cache

    scene = load_scene(scene)
    if max_time is not None:
        from .cost import check_scene_budget, estimate_scene

        check_scene_budget(estimate_scene(scene, quick), check_seconds(max_time, "max_time"), "`max_time`")
    # build times in the report are this scene's: start without integrators compiled by earlier work in this
    # process (heyoka's own LLVM memory cache is left alone)
    clear_cache()
    clear_rhs_cache()
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
    for name in STUDIES:
        if name not in studies:
            continue
        bar = _make_progress(progress, name.replace("_", " "))
        try:
            if name == "error_vs_order":
                items = _study_error_vs_order(studies[name], built, scene, bar, result.notes, result.failed_studies)
            elif name == "work_precision":
                items = _study_work_precision(studies[name], built, scene, bar, result.notes, quick)
            elif name == "drift":
                items = _study_drift(studies[name], built, scene, bar, result.notes)
            else:
                items = _study_departure_map(studies[name], built, scene, bar, result.notes)
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
