"""Stability: the extreme and stiff cases, one row per case. Plain data, no plotting, no file I/O.

Every case is a scene with a ``[stability]`` table (``lieseries/data/scenes/extreme/*.toml``, listed by
:func:`lieseries.scenes.extreme_scenes`). :func:`stability` runs each scene with
:func:`lieseries.run.run_scene` (its run table: every method against the closed form, or heyoka at 256 bits,
with invariant drift, steps, order, run time, status and message) and then reads what the scene's
``[stability].analysis`` asks for:

``"saddle"`` (separatrix, unstable axis)
    From the errors along the run (the scene's trajectory): the time each method *departs*, its error first above
    ``threshold``; the rate at which its error grows, fitted to log(error) against t between 1000 eps and
    threshold / 10, against the rate lambda = (|M| / I2) sqrt((I2 - I1)(I3 - I2) / (I1 I3)) at which a
    perturbation grows near the saddle (the rotation about the intermediate axis with the same |M|); and the
    departure each method should have if its error grows from its own epsilon at that rate, counted from the
    departure of the least precise one: t_dep + ln(eps_least / eps) / lambda.
``"scaled"`` (extreme inertia, spin rates and radii; the mild damping)
    Each run's error relative to the natural scales of the problem (R against 1, M against |M|; x against |x|,
    v against |v|; see :func:`lieseries.run.scaled_error`), and that error in units of the method's epsilon.
``"drift"`` (a long run)
    The exponents of the scene's drift study (energy and orthogonality defect against steps, Brouwer's law
    eps sqrt(steps) has exponent 1/2, a biased error 1).
``"stiff"``
    Where and how the headline run stopped: time reached, steps, and the engine's message.
``"divergence"`` (the Lie operator beyond its radius)
    ``lie_series(...).radius()`` against the pole distance of the closed form
    (:func:`lieseries.exact.rigid_body_constants`), ``error_estimate`` and ``converges`` inside the radius
    (``inside`` x rho) and beyond it (``beyond`` x rho), the actual error of the truncated series against the order
    at both times (:func:`lieseries.studies.error_vs_order`: it falls inside, grows beyond), and the largest step
    over the radius of an adaptive ``ls.lie_integrate`` run to the scene's final time
    (``sol.stats.extra["max_step_over_radius"]``), checked independently against the smallest true radius along
    the orbit, the imaginary part K'/lam of the poles.
``"atlas"`` (the sphere over many revolutions)
    Chart switches of ``ls.integrate(..., atlas=True)`` and ``lie_integrate(..., atlas=True)`` against the
    great circle and the Dirac form, when the engine has the atlas; otherwise the case is reported as skipped.

The *headline* of a case (``[stability].headline``, a method label of its run) is its row in the one-row-per-case
table; ``expect`` / ``expect_message`` say what that row should end with (``as_expected``).
"""

from __future__ import annotations

import math
import re
import time as _time
from dataclasses import dataclass, field

import numpy as np

from . import exact
from .lie.integrator import lie_integrate
from .lie.operator import lie_series
from .models.base import as_model
from .precision import to_fraction
from .precision import thread_mp as mp
from .run import environment, run_scene
from .scenes import SceneError, extreme_scenes, jsonable, load_scene
from .studies.convergence import error_vs_order
from .studies.reference import loglog_slope, theoretical_radius

__all__ = ["StabilityRow", "StabilityCase", "Stability", "stability", "run_case", "failed_case",
           "saddle_rate"]


# -- data ------------------------------------------------------------------------------------------------------
@dataclass
class StabilityRow:
    """One method of one model of one case (a row of the case's scene run).

    Attributes
    ----------
    case, title : str              the scene's name and title
    model, method : str            model label and method label ("heyoka double", "Lie series 30 dps", ...)
    precision : Precision or None  the run's (name, bits, eps, guard; :class:`~lieseries.precision.Precision`)
    setting : str
    t : float                      the time the run reached
    t_requested : float            the final time asked for
    error : float or None          max-abs error of the final state against the reference
    scaled_error : float or None   that error relative to the natural scales (module docstring)
    error_over_eps : float or None scaled_error / the method's epsilon
    max_drift : float or None      max |I(t) - I(0)| over the output times, over the case's invariants
    max_rel_drift : float or None  the same, each invariant relative to its scale (|I(0)|, |L|, or 1)
    steps, order : int or None
    build_time, run_time : float or None
    status, message : str
    extra : dict                   e.g. ``chart_switches`` of an atlas run
    """

    case: str
    title: str
    model: str
    method: str
    precision: str
    setting: str
    t: float
    t_requested: float
    error: float | None
    scaled_error: float | None
    error_over_eps: float | None
    max_drift: float | None
    max_rel_drift: float | None
    steps: int | None
    order: int | None
    build_time: float | None
    run_time: float | None
    status: str
    message: str
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return jsonable(dict(self.__dict__, precision=None if self.precision is None else str(self.precision)))


@dataclass
class StabilityCase:
    """One case: its scene's rows, its headline row, what its analysis found.

    Attributes
    ----------
    name, title, description : str
    analysis : str                 the scene's ``[stability].analysis``
    rows : list of StabilityRow    every method of every model of the scene's run
    headline : StabilityRow or None  the row of the one-row-per-case table
    expect, expect_message : str   what the headline should end with
    as_expected : bool or None
    finding : str                  one or two sentences: what the case shows, with the numbers
    details : dict                 the analysis data (JSON-ready; plots read it)
    notes : list of str
    wall_time : float
    result : SceneResult or None   the scene run (for the scene's own report; not in ``to_dict``)
    """

    name: str
    title: str
    description: str
    analysis: str
    rows: list
    headline: StabilityRow | None
    expect: str
    expect_message: str | None
    as_expected: bool | None
    finding: str
    details: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    wall_time: float = 0.0
    result: object = None

    def to_dict(self) -> dict:
        return {
            "name": self.name, "title": self.title, "description": self.description, "analysis": self.analysis,
            "rows": [r.to_dict() for r in self.rows],
            "headline": self.headline.to_dict() if self.headline is not None else None,
            "expect": self.expect, "expect_message": self.expect_message, "as_expected": self.as_expected,
            "finding": self.finding, "details": jsonable(self.details), "notes": list(self.notes),
            "wall_time": self.wall_time,
        }


@dataclass
class Stability:
    """The stability study: one :class:`StabilityCase` per scene.

    Attributes
    ----------
    cases : list of StabilityCase
    quick : bool
    wall_time : float
    environment : dict
    created : str
    """

    cases: list
    quick: bool
    wall_time: float = 0.0
    environment: dict = field(default_factory=dict)
    created: str = ""

    @property
    def rows(self) -> list:
        """The headline rows: one per case (cases whose scene failed have none)."""
        return [c.headline for c in self.cases if c.headline is not None]

    @property
    def all_rows(self) -> list:
        """Every row of every case."""
        return [r for c in self.cases for r in c.rows]

    def case(self, name: str) -> StabilityCase:
        """The case of that scene name."""
        for c in self.cases:
            if c.name == name:
                return c
        raise KeyError(f"no case {name!r}; cases: {', '.join(c.name for c in self.cases)}")

    def to_dict(self) -> dict:
        return {"quick": self.quick, "wall_time": self.wall_time, "environment": dict(self.environment),
                "created": self.created, "cases": [c.to_dict() for c in self.cases],
                "rows": [r.to_dict() for r in self.rows]}


# -- helpers ---------------------------------------------------------------------------------------------------
def _working_eps(precision) -> float | None:
    """The round-off a run carries between steps (its Precision's working_eps; None when unknown)."""
    return precision.working_eps if precision is not None else None


def saddle_rate(model, y0) -> float:
    """The model's :meth:`~lieseries.EulerPoisson.saddle_rate` for the angular momentum |M| of the state ``y0``."""
    return model.saddle_rate(float(np.linalg.norm([float(v) for v in np.asarray(y0)[9:12]])))


def _drift_scale(name, inv0) -> float:
    if name in ("energy", "M2", "x2"):
        return abs(inv0[name]) or 1.0
    if name in ("L1", "L2", "L3"):
        return math.sqrt(sum(inv0.get(k, 0.0) ** 2 for k in ("L1", "L2", "L3"))) or 1.0
    return 1.0


def _rows_of(scene, result) -> list:
    st = scene.stability
    run = result.run
    inv_all = run.get("invariants", [])
    wanted = st.get("invariants") or inv_all
    out = []
    for r in run["rows"]:
        inv0 = run.get("initial_invariants", {}).get(r.model, {})
        drifts = [(k, r.drift.get(k)) for k in wanted if r.drift.get(k) is not None]
        max_drift = max((v for _, v in drifts), default=None)
        rel = [v / _drift_scale(k, inv0) for k, v in drifts] if inv0 else []
        eps = r.precision.eps if r.precision is not None else None
        scaled = getattr(r, "scaled_error", None)
        out.append(StabilityRow(
            case=scene.name, title=scene.title, model=r.model, method=r.label, precision=r.precision,
            setting=r.setting, t=r.t, t_requested=float(run["t"]), error=r.error, scaled_error=scaled,
            error_over_eps=(scaled / eps) if (scaled is not None and eps) else None, max_drift=max_drift,
            max_rel_drift=max(rel) if rel else None, steps=r.steps, order=r.order, build_time=r.build_time,
            run_time=r.run_time, status=r.status, message=r.message, extra=dict(getattr(r, "extra", {}) or {}),
        ))
    return out


def _fmt(x, digits=2) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float) and math.isinf(x):
        return "inf"
    return f"{x:.{digits}e}" if (x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e4)) else f"{x:.{digits + 1}g}"


# -- analyses --------------------------------------------------------------------------------------------------
def _peak_growth_rate(points, width):
    """Largest least-squares slope of ln(error) against t over windows of length ``width`` (the whole run when
    ``width`` is None), and that window: (rate, [t_start, t_end]) or (None, None) with fewer than 4 points.

    Near the separatrix the error grows like e^(lambda t) only while the motion is near the saddle and shrinks
    again after a flip; over a window of ~10 / lambda the growth rate is that of the saddle.
    """
    if len(points) < 4:
        return None, None
    pts = sorted(points)
    t = np.array([p[0] for p in pts])
    y = np.array([p[1] for p in pts])
    if width is None or width >= t[-1] - t[0]:
        return float(np.polyfit(t, y, 1)[0]), [float(t[0]), float(t[-1])]
    best, where = None, None
    for i in range(len(t)):
        j = np.searchsorted(t, t[i] + width, side="right")
        if j - i < 4:
            continue
        slope = float(np.polyfit(t[i:j], y[i:j], 1)[0])
        if best is None or slope > best:
            best, where = slope, [float(t[i]), float(t[j - 1])]
    if best is None:
        return float(np.polyfit(t, y, 1)[0]), [float(t[0]), float(t[-1])]
    return best, where


def _analysis_saddle(scene, result, rows, opts):
    st = scene.stability
    threshold = float(st["threshold"])
    built = dict(scene.build_models())
    mlabel = st["headline_model"]
    model = built[mlabel]
    y0 = scene.initial_state(model)
    lam = saddle_rate(model, y0)
    traj = result.trajectories.get(mlabel, {})
    prec_of = {r.method: r.precision for r in rows if r.model == mlabel}
    series, departs, rates, windows = {}, {}, {}, {}
    for label, errs in traj.get("errors", {}).items():
        ts = traj["error_times"][label]
        series[label] = {"t": list(ts), "error": list(errs)}
        departs[label] = next((t for t, e in zip(ts, errs) if e > threshold), None)
        eps = _working_eps(prec_of.get(label))
        pts = [(t, math.log(e)) for t, e in zip(ts, errs)
               if eps and 1e3 * eps < e < threshold / 10 and e > 0]
        rates[label], windows[label] = _peak_growth_rate(pts, 10 / lam if lam > 0 else None)
    # predicted departures: from the least precise method that departed, shifted by ln(eps ratio) / lambda
    dep = [(_working_eps(prec_of.get(k)), k, t) for k, t in departs.items() if t is not None]
    dep = [d for d in dep if d[0]]
    predicted = {}
    if dep:
        eps0, k0, t0 = max(dep)
        for label in departs:
            eps = _working_eps(prec_of.get(label))
            if eps:
                predicted[label] = t0 + math.log(eps0 / eps) / lam if lam > 0 else None
    t_end = float(result.run["t"])
    parts = []
    for label, t in departs.items():
        if t is not None:
            pr = predicted.get(label)
            extra = f" (predicted {pr:.0f})" if pr is not None and label != (max(dep)[1] if dep else None) else ""
            parts.append(f"{label} departs at t = {t:.0f}{extra}")
        else:
            pr = predicted.get(label)
            if pr is None:
                extra = ""
            elif pr > t_end:
                extra = f", predicted {pr:.0f}"
            else:
                extra = (f" (steady growth at lambda would have crossed at {pr:.0f}: the error does not grow "
                         "steadily here, it shrinks again after each pass near the saddle)")
            parts.append(f"{label} stays below {threshold:g} to T = {t_end:g}{extra}")
    fitted = [(k, v) for k, v in rates.items() if v is not None]
    rate_txt = ""
    if fitted:
        rate_txt = "; error growth rate (largest slope of ln error against t over 10 / lambda) " + ", ".join(
            f"{k} {v:.3f}" for k, v in fitted) + f", against lambda = {lam:.4f}"
    # the runs that never departed: their final error in units of their own (working) epsilon: the amplification
    # of round-off, the same for every precision when the instability is the only source
    amp = {}
    for label, ser in series.items():
        eps = _working_eps(prec_of.get(label))
        if departs.get(label) is None and ser["error"] and eps:
            amp[label] = ser["error"][-1] / eps
    amp_txt = ""
    if amp:
        amp_txt = "; final error / eps: " + ", ".join(f"{k} {_fmt(v)}" for k, v in amp.items())
    finding = "; ".join(parts) + rate_txt + amp_txt + "."
    details = {"model": mlabel, "lambda": lam, "threshold": threshold, "t_end": t_end, "departure": departs,
               "predicted_departure": predicted, "growth_rate": rates, "growth_window": windows,
               "final_error_over_eps": amp,
               "errors": series}
    return finding, details


def _analysis_scaled(scene, result, rows, opts):
    parts = []
    multi = len({r.model for r in rows}) > 1
    for r in rows:
        if r.scaled_error is None:
            continue
        who = f"{r.model}: {r.method}" if multi else r.method
        ratio = f" ({r.error_over_eps:.3g} eps)" if r.error_over_eps is not None else ""
        parts.append(f"{who} {_fmt(r.scaled_error)}{ratio}")
    finding = "Relative errors: " + "; ".join(parts) + "." if parts else "No run produced a state."
    details = {"scaled_errors": {f"{r.model}: {r.method}": r.scaled_error for r in rows},
               "error_over_eps": {f"{r.model}: {r.method}": r.error_over_eps for r in rows}}
    return finding, details


def _analysis_drift(scene, result, rows, opts):
    items = result.studies.get("drift", [])
    if not items:
        return "The drift study did not run.", {}

    mlabel, dr = items[0]
    keys = [k for k in ("energy", "orthogonality") if k in dr.errors]
    exps = {k: dr.exponents.get(k) for k in dr.errors}
    # the study fits the second half of the samples (the last 1.5 decades); over all three decades the slope of
    # the running maximum is steadier against the random walk's wandering
    whole = {k: loglog_slope(dr.steps, np.maximum.accumulate(np.nan_to_num(np.asarray(dr.errors[k], float))))
             for k in keys}
    txt = ", ".join((f"{k} ~ steps^{exps[k]:.2f}" if exps[k] is not None else f"{k}: too few points")
                    + (f" (^{whole[k]:.2f} over all samples)" if whole.get(k) is not None else "") for k in keys)
    ens = f" x {dr.ensemble} runs (RMS)" if dr.ensemble > 1 else ""
    final = dr.errors.get("energy", [None])[-1]
    brouwer = dr.brouwer.get("energy", [None])[-1]
    finding = (f"{dr.total_steps} steps{ens} in {dr.precision}: {txt} (Brouwer's law 0.5, linear growth 1); final "
               f"energy drift {_fmt(final)} against eps sqrt(steps) |E| = {_fmt(brouwer)}.")
    details = {"model": mlabel, "total_steps": dr.total_steps, "ensemble": dr.ensemble, "eps": dr.eps,
               "exponents": exps, "exponents_all_samples": whole, "steps": list(dr.steps), "times": list(dr.times),
               "errors": {k: list(dr.errors[k]) for k in keys}, "scales": {k: dr.scales.get(k, 1.0) for k in keys},
               "status": dr.status}
    return finding, details


def _analysis_stiff(scene, result, rows, opts):
    head = _headline(scene, rows)
    if head is None:
        return "The headline run is missing.", {}
    m = re.search(r"last step size ([0-9.eE+-]+)", head.message)
    h = float(m.group(1)) if m else None
    finding = (f"{head.method} stopped with {head.status} at t = {head.t:.3g} of {head.t_requested:g} after "
               f"{head.steps} steps" + (f", last step {h:.3g}" if h is not None else "") + ".")
    details = {"t_reached": head.t, "t_requested": head.t_requested, "steps": head.steps, "last_step": h,
               "status": head.status, "message": head.message,
               "runs": {r.method: {"t": r.t, "steps": r.steps, "status": r.status} for r in rows}}
    return finding, details


def _divergence_orders(scene, opts) -> list:
    """The orders of the divergence analysis: the stability table's, else the scene's error-vs-order range
    (default 2..40 by 2); halved at most (and at least 12) in quick mode."""
    orders = scene.stability["orders"]
    if orders is None:
        ev = scene.studies.get("error_vs_order") or {}
        top = ev.get("max_order") or 40
        orders = list(range(ev.get("min_order", 2) or 2, top + 1, ev.get("step", 2) or 2))
    if opts.get("quick"):
        top = max(12, max(orders) // 2)
        orders = [o for o in orders if o <= top]
    return orders


def _smallest_orbit_radius(model, y0):
    """For a free rigid body, the smallest radius of convergence along the real orbit: the poles of Omega(t) lie
    at Im t = +-K'/lam (plus the real period shifts), so every point of the orbit is at least K'/lam from one (pi /
    2 lam on the separatrix); None for other models and regimes."""
    if getattr(model, "closed_form", None) != "free_rigid_body":  # the model says the free body describes it
        return None
    I = model.inertia_exact
    Iinv = model.inverse_inertia_exact
    fr = [to_fraction(v) for v in y0]
    omega = [sum(Iinv[i][j] * fr[9 + j] for j in range(3)) for i in range(3)]
    inertia = [I[i][i] for i in range(3)] if model.diagonal else I
    c = exact.rigid_body_constants(inertia, omega, dps=30)
    if c.branch in ("above", "below") and c.Kp is not None:
        return float(c.Kp / c.lam)
    if c.branch == "separatrix":
        return float(mp.pi / 2 / c.lam)
    return None


def _analysis_divergence(scene, result, rows, opts):
    st = scene.stability
    built = dict(scene.build_models())
    mlabel = st["headline_model"]
    model = built[mlabel]
    dps = int(st["dps"])
    y0 = scene.initial_state(model)
    rho_true = theoretical_radius(model, y0, dps=dps)
    orders = _divergence_orders(scene, opts)
    N = max(orders)
    series = lie_series(model, y0, order=N, dps=dps)
    rho_est = series.radius()
    inside = float(to_fraction(st["inside"]))
    beyond = float(to_fraction(st["beyond"]))
    with mp.workdps(dps):
        t_in = mp.mpf(inside) * rho_true
        t_out = mp.mpf(beyond) * rho_true
        probes = {
            "inside": t_in, "at the estimated radius": mp.mpf(rho_est), "beyond": t_out,
        }
        estimates = {k: float(series.error_estimate(v)) for k, v in probes.items()}
        converges = {k: bool(series.converges(v)) for k, v in probes.items()}
    ev_in = error_vs_order(model, y0, float(t_in), orders, dps=dps)
    ev_out = error_vs_order(model, y0, float(t_out), orders, dps=dps)
    # the adaptive integrator never steps beyond the radius
    lie_dps = next((int(m["dps"]) for m in scene.run["methods"] if m["method"] == "lie"), 30)  # the run's own
    t_run = scene.run["t"] if not opts.get("quick") or scene.run.get("quick_t") is None else scene.run["quick_t"]
    sol = lie_integrate(model, y0, t_run, dps=lie_dps)
    ratio = sol.stats.extra.get("max_step_over_radius")
    notes = []
    if ratio is None:
        notes.append("`sol.stats.extra['max_step_over_radius']` is not provided by this lie_integrate; the check "
                     "uses the largest step over the smallest true radius only.")
    min_radius = _smallest_orbit_radius(model, y0)  # an independent check of the steps
    step_over_min = sol.stats.max_step / min_radius if (min_radius and sol.stats.steps) else None
    grows = ev_out.errors[-1] > ev_out.errors[0] if ev_out.errors else None
    finding = (
        f"radius() = {float(rho_est):.4f} against the pole distance {float(rho_true):.4f} "
        f"({(float(rho_est) / float(rho_true) - 1) * 100:+.1f}%); inside ({inside:g} rho): estimate "
        f"{_fmt(estimates['inside'])}, actual error {_fmt(ev_in.errors[-1])} at order {N}; beyond ({beyond:g} rho): "
        f"estimate {_fmt(estimates['beyond'])}, converges() = {converges['beyond']}, actual error "
        f"{_fmt(ev_out.errors[0])} at order {orders[0]} -> {_fmt(ev_out.errors[-1])} at order {N}"
        + (" (grows with the order)" if grows else "")
        + f"; lie_integrate to t = {float(t_run):g}: {sol.stats.steps} steps, largest h / rho = "
        + (f"{ratio:.3f}" if ratio is not None else "n/a")
        + (f", largest h / (smallest true radius along the orbit) = {step_over_min:.3f}" if step_over_min else "")
        + "."
    )
    details = {
        "model": mlabel, "dps": dps, "order": N, "radius_estimated": float(rho_est), "radius_theory": float(rho_true),
        "probes": {k: float(v) for k, v in probes.items()}, "error_estimate": estimates, "converges": converges,
        "orders": list(ev_out.orders), "errors_inside": list(ev_in.errors), "errors_beyond": list(ev_out.errors),
        "t_inside": float(t_in), "t_beyond": float(t_out), "rate_beyond": ev_out.rate, "rate_inside": ev_in.rate,
        "lie_integrate": {"t": float(t_run), "dps": lie_dps, "steps": sol.stats.steps, "status": sol.status,
                          "max_step_over_radius": ratio, "max_step": sol.stats.max_step,
                          "min_true_radius": min_radius, "max_step_over_min_true_radius": step_over_min,
                          "error_estimates_max": max(sol.stats.error_estimates) if sol.stats.error_estimates
                          else None},
    }
    return finding, details, notes


_ANALYSES = {
    "saddle": _analysis_saddle,
    "scaled": _analysis_scaled,
    "none": _analysis_scaled,
    "drift": _analysis_drift,
    "stiff": _analysis_stiff,
    "divergence": _analysis_divergence,
}


def _headline(scene, rows):
    st = scene.stability
    return next((r for r in rows if r.method == st["headline"] and r.model == st["headline_model"]), None)


def _as_expected(scene, head) -> bool | None:
    if head is None:
        return None
    st = scene.stability
    ok = head.status == st["expect"]
    if st["expect_message"]:
        ok = ok and st["expect_message"] in head.message
    return ok


# -- the study -------------------------------------------------------------------------------------------------
def run_case(scene, quick: bool = False, progress=None) -> StabilityCase:
    """Run one case: its scene (:func:`lieseries.run.run_scene`) and its analysis.

    Parameters
    ----------
    scene : Scene, name or path
        A scene with a ``[stability]`` table.
    quick : bool
        The scene's quick plan (shorter runs, fewer samples; see :func:`lieseries.scenes.effective_plan`).
    progress : callable, optional
        ``progress(done, total, label)`` for the scene's run.
    """

    scene = load_scene(scene)
    if scene.stability is None:
        raise SceneError(f"scene {scene.name!r} has no [stability] table: it is not a stability case (the cases "
                         "are listed by lieseries.scenes.extreme_scenes())")
    start = _time.perf_counter()
    st = scene.stability
    analysis = st["analysis"]
    result = run_scene(scene, quick=quick, progress=progress if progress is not None else False)
    rows = _rows_of(scene, result)
    head = _headline(scene, rows)
    notes = list(result.notes)
    finding, details = "", {}
    if analysis == "atlas":
        finding, details, more = _atlas(scene, result, rows, {"quick": quick})
        notes += more
    elif analysis in _ANALYSES:
        out = _ANALYSES[analysis](scene, result, rows, {"quick": quick})
        finding, details = out[0], out[1]
        if len(out) > 2:
            notes += out[2]
    if st.get("note"):
        finding = (finding + " " + st["note"]).strip()
    return StabilityCase(
        name=scene.name, title=scene.title, description=scene.description, analysis=analysis, rows=rows,
        headline=head, expect=st["expect"], expect_message=st["expect_message"], as_expected=_as_expected(scene, head),
        finding=finding, details=details, notes=notes, wall_time=_time.perf_counter() - start, result=result,
    )


def _atlas(scene, result, rows, opts):
    """The atlas analysis."""
    return _atlas_analysis(scene, result, rows, opts)


def _atlas_analysis(scene, result, rows, opts):
    """Chart switches and errors of the atlas runs, next to the Dirac form's."""

    atlas_models = [label for label, model in scene.build_models() if as_model(model).runs_on_atlas]
    notes = []
    if not atlas_models:
        notes.append("atlas: no model of the scene has `atlas = true`; nothing switched charts.")
    series = {}
    for mlabel, traj in result.trajectories.items():
        for label, errs in traj.get("errors", {}).items():
            key = f"{mlabel}: {label}"
            charts = traj.get("charts", {}).get(label)
            series[key] = {"t": list(traj["error_times"][label]), "error": list(errs),
                           "charts": list(charts) if charts is not None else None}
    switches = {f"{r.model}: {r.method}": r.extra.get("chart_switches") for r in rows if r.model in atlas_models}
    used = {}
    for key, ser in series.items():
        if ser["charts"] is not None:
            used[key] = sorted(set(ser["charts"]))
    parts = []
    by_method = {}
    for r in rows:
        by_method.setdefault(r.method, {})[r.model] = r
    for method, per in by_method.items():
        txt = []
        for mlabel in atlas_models:
            r = per.get(mlabel)
            if r is not None:
                sw = r.extra.get("chart_switches")
                txt.append(f"{sw} chart switches, error {_fmt(r.error)}" + (f" ({r.status})" if r.status != "success"
                                                                            else ""))
        others = [r for m, r in per.items() if m not in atlas_models]
        for r in others:
            txt.append(f"{r.model} {_fmt(r.error)}")
        parts.append(f"{method}: " + ", ".join(txt))
    t_end = float(result.run["t"])
    charts_txt = ""
    if used:
        all_used = sorted({c for v in used.values() for c in v})
        charts_txt = f"; charts used: {', '.join(f'x{c + 1}' for c in all_used)}"
    finding = f"To T = {t_end:g}: " + "; ".join(parts) + charts_txt + "."
    details = {"atlas_models": atlas_models, "switches": switches, "charts_used": used, "series": series,
               "t_end": t_end}
    return finding, details, notes


def failed_case(scene, err: BaseException, wall_time: float = 0.0) -> StabilityCase:
    """The case of a scene whose run raised: no rows, the error in its finding and notes."""
    st = scene.stability or {}
    return StabilityCase(
        name=scene.name, title=scene.title, description=scene.description, analysis=st.get("analysis", "none"),
        rows=[], headline=None, expect=st.get("expect", "success"), expect_message=st.get("expect_message"),
        as_expected=False, finding=f"The case failed: {type(err).__name__}: {err}",
        notes=[f"{scene.name}: {type(err).__name__}: {err}"], wall_time=wall_time,
    )


def stability(cases=None, quick: bool = False, progress=None, on_case=None) -> Stability:
    """Run the extreme and stiff cases and collect one row per case.

    Parameters
    ----------
    cases : sequence of scene names, paths or Scenes, optional
        Default: every scene of :func:`lieseries.scenes.extreme_scenes`.
    quick : bool
        Each scene's quick plan (for tests and smoke runs; the numbers are real, the runs shorter).
    progress : callable, optional
        Called as ``progress(done, total, label)`` while the cases run (``done`` counts finished cases).
    on_case : callable, optional
        Called as ``on_case(case)`` with each :class:`StabilityCase` when it is done.

    Returns
    -------
    Stability
        A case whose scene raised is kept, with the error in its notes and no rows.
    """

    if cases is None:
        cases = [name for name, _ in extreme_scenes()]
        if not cases:
            raise ValueError("no stability cases found: lieseries/data/scenes/extreme/ is empty or missing; pass `cases`")
    if isinstance(cases, (str, bytes)) or not hasattr(cases, "__iter__"):
        raise ValueError(f"`cases` must be a list of scene names, paths or Scenes; got {cases!r}")
    scenes = [load_scene(c) for c in cases]
    start = _time.perf_counter()
    out = []
    n = len(scenes)
    for i, scene in enumerate(scenes):
        if progress:
            progress(i, n, scene.name)

        def inner(done, total, label, _i=i, _name=scene.name):
            if progress:
                progress(_i, n, f"{_name}: {label} {done}/{total}")

        t0 = _time.perf_counter()
        try:
            case = run_case(scene, quick=quick, progress=inner)
        except Exception as err:  # one failing case must not hide the others
            case = failed_case(scene, err, _time.perf_counter() - t0)
        out.append(case)
        if on_case is not None:
            on_case(case)
    if progress:
        progress(n, n, "done")
    return Stability(cases=out, quick=bool(quick), wall_time=_time.perf_counter() - start,
                     environment=environment(), created=_time.strftime("%Y-%m-%d %H:%M:%S %Z"))
