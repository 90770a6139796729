"""Error against run time for several integrators and settings (a work-precision diagram, as data).

The methods and their settings are those of :mod:`lieseries.methods`.

In :func:`work_precision` any of ``tol``, ``rtol``, ``dps`` (and ``precision``) may be a list: one row per value.

Timing: ``run_time`` is the wall time of the call, best of ``repeat`` (repeats stop once a method has used two
seconds); heyoka's compile time (and the scipy right-hand side's) is kept apart in ``build_time``. Times are
measured in this one run on a shared machine: compare them with each other, not with other runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction

from .. import fields as F
from ..formatting import (MARKERS, below_float_range, fmt_int, fmt_num, fmt_sci, log10_or_nan, markdown_table, pyplot,
                          save_figure)
from ..methods import (RunRecord, default_methods, expand_methods, method_label, method_plugin, reference_dps,
                       run_method, scene_methods, setting)
from ..methods.pricing import CostPart
from ..poisson import as_poisson_system
from ..precision import check_count, to_fraction
from .plugin import Study, register_study
from .reference import reference_solution, state_error

#: Most best-of repeats of each timing (the API's and the scene's bound).
MAX_REPEAT = 1000

__all__ = ["WorkPrecisionRow", "WorkPrecision", "work_precision", "WorkPrecisionStudy"]


#: A row of a work-precision study: the one run record (``error`` is the max-abs error of the final state against
#: the reference at time ``t``).
WorkPrecisionRow = RunRecord


@dataclass
class WorkPrecision:
    """Error against run time: one row per (method, setting).

    Attributes
    ----------
    t : float               final time
    rows : list of WorkPrecisionRow
    reference : str         what the errors are measured against
    notes : list of str     methods left out and why
    system : str
    """

    t: float
    rows: list
    reference: str
    notes: list = field(default_factory=list)
    system: str = ""

    def to_dict(self) -> dict:
        return {"t": self.t, "reference": self.reference, "notes": list(self.notes), "system": self.system,
                "rows": [r.to_dict() for r in self.rows]}


# -- method specifications -------------------------------------------------------------------------------------
def work_precision(system, y0, t, methods=None, reference=None, repeat: int = 3, progress=None) -> WorkPrecision:
    """Error of the final state against run time, for each method and setting.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Initial state (build it at high precision, e.g. ``precision=256``, so that quad and Lie runs start
        from the exact problem; each method rounds it once to its own precision).
    t : number
        Final time.
    methods : list of dict, optional
        Method specifications (module docstring); list-valued settings give one row each. Default:
        :func:`default_methods`.
    reference : sequence of n numbers, optional
        The state at ``t``; default: the closed form where the model has one, else heyoka at 256 bits.
    repeat : int
        Best-of repeats of each timing.
    progress : callable, optional
        Called as ``progress(done, total, label)`` after each run.

    Returns
    -------
    WorkPrecision
    """
    repeat = check_count(repeat, "repeat", low=1, high=MAX_REPEAT)
    if methods is None:
        methods = default_methods()
    specs = expand_methods(methods)
    tf = to_fraction(t, "t")
    dps = reference_dps(specs)
    refs = {}

    def ref_at(time_: Fraction):
        if time_ not in refs:
            given = reference if time_ == tf else None
            refs[time_] = reference_solution(system, y0, time_, dps=dps, reference=given)
        return refs[time_]

    rows, notes = [], []
    total = len(specs)
    for i, spec in enumerate(specs):
        label = method_label(spec)
        if progress:
            progress(i, total, f"{label} {setting(spec)}")
        run = run_method(system, y0, tf, spec, repeat=repeat)
        if run.status == "skipped":
            note = f"{label}: {run.message}; its rows are left out."
            if note not in notes:
                notes.append(note)
            continue
        err = None
        if run.ok:
            t_reached = run.t_exact if run.t_exact is not None else to_fraction(run.t)
            err = state_error(system, run.y_final, ref_at(t_reached))
        rows.append(run.measured(error=err))
    if progress:
        progress(total, total, "done")
    ref = ref_at(tf)
    ps = as_poisson_system(system)
    return WorkPrecision(t=float(tf), rows=rows, reference=f"{ref.label}, {ref.dps} digits", notes=notes,
                         system=ps.name)


# -- the study in scenes and reports ---------------------------------------------------------------------------
class WorkPrecisionStudy(Study):
    """``[studies.work_precision]``: error against run time, one row per method and setting."""

    name = "work_precision"
    title = "Work-precision"
    quick_doc = "work-precision with at most three values per setting, one repeat and mpmath capped at t = 0.5"
    fields = {
        "t": (F.time(), None),
        "methods": (scene_methods(lists=True), None),
        "repeat": (F.count(1, MAX_REPEAT), 3),
    }
    docs = {
        "t": ("number", "the final time (default run.t)"),
        "methods": ("array of method tables", "settings may be lists: one row per value"),
        "repeat": ("integer 1..100", "best-of repeats of each timing"),
    }

    def check(self, wp, run, models, where):
        if wp["t"] is None:
            if run is None:
                raise F.SceneError("missing required field `studies.work_precision.t` (there is no [run] to take it "
                                   "from)")
            wp["t"] = run["t"]

    def quick(self, wp):
        wp["repeat"] = 1
        for m in wp["methods"] or []:
            hook = method_plugin(m["method"]).quick_study
            if hook is not None:
                hook(m)

    def cost(self, wp, ctx, pricer):
        methods = wp["methods"] if wp["methods"] is not None else default_methods(ctx.quick)
        t = to_fraction(wp["t"] if wp["t"] is not None else (ctx.scene.run or {}).get("t", 1))
        specs = expand_methods(methods, "studies.work_precision.methods")
        pricer.heyoka_builds += sum(1 for spec in specs if spec["method"] == "taylor")
        parts = []
        for _lab, model in ctx.built:
            y0 = ctx.initial_state(model)
            for spec in specs:
                per, lower, basis, _ = pricer.span(model, y0, spec, t, 1)
                if spec["method"] == "mpmath":
                    per *= float(min(abs(t), to_fraction(spec["t_max"])) / abs(t))
                parts.append(CostPart("studies.work_precision.methods", f"{spec['method']} run to t = {float(t):g}",
                                      pricer.repeats(per, wp["repeat"]), "run", per, basis, lower))
        return parts

    def run(self, opts, ctx):
        methods = opts["methods"] if opts["methods"] is not None else default_methods(ctx.quick)
        out = []
        for i, (lab, model) in enumerate(ctx.built):
            res = work_precision(model, ctx.initial_state(model), opts["t"], methods=methods, repeat=opts["repeat"],
                                 progress=ctx.model_progress(i, lab))
            for note in res.notes:
                ctx.note(f"work-precision: {note}")
            out.append((lab, res))
        return out

    def unsuccessful(self, items):
        return [f"work-precision ({lab}): {r.label} {r.setting}: {r.status}" for lab, wp in items for r in wp.rows
                if r.status != "success"]

    def section(self, items, ctx):
        lines = ["Error of the final state against run time (wall time of the call, best of the repeats, measured "
                 "in this run on this machine: compare rows with each other). heyoka's compile time is shown apart "
                 "as *build time* (0 when the integrator came from the cache); for scipy it is the compile time "
                 "of the right-hand side (heyoka cfunc). mpmath's odefun is capped to short spans: see *t*.", ""]
        multi = len(items) > 1
        h = (["model"] if multi else []) + ["method", "precision", "setting", "t", "error", "run time [s]",
                                            "build time [s]", "steps", "rhs evals", "order", "status"]
        rows = []
        for mlabel, wp in items:
            for r in wp.rows:
                rows.append(([mlabel] if multi else []) + [
                    r.label, r.precision, r.setting, fmt_num(r.t), fmt_sci(r.error), fmt_sci(r.run_time),
                    fmt_sci(r.build_time), fmt_int(r.steps), fmt_int(r.nfev), fmt_int(r.order), r.status])
        lines += [markdown_table(h, rows), ""]
        csvs = [("work_precision.csv", h, rows)]
        for mlabel, wp in items:
            lines.append(f"- Reference ({mlabel}): {wp.reference}.")
            for note in wp.notes:
                lines.append(f"- {note}")
            for r in wp.rows:
                if r.status not in ("success",):
                    lines.append(f"- {r.label} {r.setting}: {r.status}: {r.message}")
        lines.append("")
        if ctx.plotted:
            lines += ["![work-precision diagram](work_precision.png)", ""]
        return lines, csvs

    def plot(self, items, path, scene):
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(8.5, 6))
        series = {}
        for mlabel, wp in items:
            for r in wp.rows:
                if r.error is None or r.run_time is None:
                    continue
                key = r.label if len(items) == 1 else f"{mlabel}: {r.label}"
                series.setdefault(key, []).append(r)
        shown_build = False
        # errors a double cannot draw (a 400-digit run's 1e-402) were drawn at 1e-300: the axis then shows log10
        tiny = any(below_float_range(r.error) for rows in series.values() for r in rows)
        draw = ax.semilogx if tiny else ax.loglog

        def ys_of(rows):
            return log10_or_nan([r.error for r in rows]) if tiny else [max(r.error, 1e-300) for r in rows]

        for k, (key, rows) in enumerate(series.items()):
            color = f"C{k % 10}"
            marker = MARKERS[k % len(MARKERS)]
            xs = [r.run_time for r in rows]
            ys = ys_of(rows)
            t_study = items[0][1].t
            span = {r.t for r in rows}
            if span and all(abs(ts - t_study) > 1e-12 * max(1.0, abs(t_study)) for ts in span):
                key = f"{key} (to t = {max(span):.3g} only)"  # a capped method (odefun) must say so on the plot
            draw(xs, ys, marker=marker, color=color, linewidth=1, markersize=6, label=key)
            if rows[0].method == "taylor":
                bx = [r.run_time + (r.build_time or 0.0) for r in rows if r.build_time]
                by = ys_of([r for r in rows if r.build_time])
                if bx:
                    draw(bx, by, marker=marker, color=color, markerfacecolor="none", linestyle="none",
                         markersize=6, label=None if shown_build else "hollow: run + build time (heyoka)")
                    shown_build = True
        ax.set_xlabel("run time [s] (best of repeats; build time apart)")
        ax.set_ylabel("log10 of the max-abs error at the final time" if tiny else "max-abs error at the final time")
        t = items[0][1].t if items else 0
        ax.set_title(f"Work-precision diagram, t = {t:.4g}", fontsize=10)
        ax.legend(loc="best", fontsize=7)
        ax.grid(alpha=0.3, which="both")
        save_figure(plt, fig, path)

    def summary(self, items):
        out = []
        for mlabel, wp in items:
            ok = [r for r in wp.rows if r.error is not None]
            best = min(ok, key=lambda r: r.error) if ok else None
            out.append(f"work-precision ({mlabel}): {len(wp.rows)} runs" + (
                f", smallest error {fmt_sci(best.error)} ({best.label} {best.setting})" if best else ""))
        return out


register_study(WorkPrecisionStudy())
