"""The report of a scene run: report.md (the scene, the run, each study's section), its plots, CSV tables and
data.json; the studies' sections, plots and summary lines come from their plug-ins."""

from __future__ import annotations

import json
from pathlib import Path

from ..folder import ReportFolder
from ..formatting import (MARKERS, below_float_range, fmt_int, fmt_num, fmt_sci, log10_or_nan, markdown_table,
                          plain_table, positive_or_nan, pyplot, save_figure, wrap)
from ..scenes import quick_changes
from ..studies.plugin import ReportContext, studies_registry
from .files import json_default, write_csv, write_json

__all__ = ["write_report", "render_report", "report_names", "summary_text", "section_titles", "run_tables",
           "plot_trajectory"]


def section_titles() -> dict:
    """The H2 headings of the report, by section (a study's is its ``title``)."""
    return {"scene": "Scene", "run": "Run", "trajectory": "Trajectory",
            **{name: st.title for name, st in studies_registry().items()},
            "notes": "Notes", "environment": "Environment"}


def plot_trajectory(result, path: Path) -> None:
    plt = pyplot()
    trajs = result.trajectories
    n = len(trajs)
    fig, axes = plt.subplots(2, n, figsize=(6.5 * n, 7), squeeze=False, sharex="col")
    for j, (mlabel, tr) in enumerate(trajs.items()):
        ax = axes[0][j]
        times = tr["times"]
        vals = tr["values"]
        for i, name in enumerate(tr["names"]):
            ax.plot(times, [v[i] for v in vals], label=name)
        ax.set_ylabel(tr["quantity"])
        ax.set_title(f"{mlabel}: reference solution")
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
        ax2 = axes[1][j]
        # errors a double cannot draw (a 400-digit run's 1e-402 is 0.0: its line was left out, its legend kept):
        # the axis shows their log10 instead
        tiny = any(below_float_range(v) for errs in tr["errors"].values() for v in errs)
        for k, (lab, errs) in enumerate(tr["errors"].items()):
            draw = ax2.plot if tiny else ax2.semilogy
            draw(tr["error_times"][lab], log10_or_nan(errs) if tiny else positive_or_nan(errs),
                 marker=MARKERS[k % len(MARKERS)], markersize=3, linewidth=1, label=lab)
        ax2.set_xlabel("time t")
        ax2.set_ylabel("log10 of the max-abs error against the reference" if tiny
                       else "max-abs error against the reference")
        ax2.set_title(f"{mlabel}: error along the run")
        if tr["errors"]:
            ax2.legend(loc="best", fontsize=8)
        ax2.grid(alpha=0.3, which="both")
    fig.suptitle(wrap(result.scene.title, 60 * n), fontsize=10)
    save_figure(plt, fig, path)


def run_tables(result):
    """(final-state table, invariant-drift table) as (headers, rows) pairs."""
    run = result.run
    multi = len({r.model for r in run["rows"]}) > 1
    # the extreme cases (scenes with a [stability] table) also give the error relative to the natural scale
    scaled = getattr(result.scene, "stability", None) is not None
    h1 = (["model"] if multi else []) + ["method", "precision", "setting", "t reached", "final error"] + (
        ["relative error"] if scaled else []) + ["max error", "steps", "order", "build time [s]", "run time [s]",
                                                 "status"]
    rows1 = []
    for r in run["rows"]:
        rows1.append(([r.model] if multi else []) + [
            _row_label(r), r.precision, r.setting, fmt_num(r.t), fmt_sci(r.error)] + (
            [fmt_sci(getattr(r, "scaled_error", None))] if scaled else []) + [
            fmt_sci(r.max_error), fmt_int(r.steps), fmt_int(r.order), fmt_sci(r.build_time), fmt_sci(r.run_time),
            r.status,
        ])
    invs = run["invariants"]
    h2 = (["model"] if multi else []) + ["method"] + invs
    rows2 = [([r.model] if multi else []) + [_row_label(r)] + [fmt_sci(r.drift.get(k)) for k in invs]
             for r in run["rows"]]
    return (h1, rows1), (h2, rows2)


def _row_label(r) -> str:
    """A run row's method label, with what quick mode changed in a method the scene labelled itself (its label
    may name digits or times quick mode did not use)."""
    quick = r.extra.get("quick_mode") if isinstance(getattr(r, "extra", None), dict) else None
    return f"{r.label} (quick mode: {quick})" if quick else r.label


def _section_run(result, lines, csvs):
    run = result.run
    lines += [f"## {section_titles()['run']}", ""]
    n = run["samples"]
    lines.append(f"Final time t = {fmt_num(run['t'])}; {n} samples: t = 0 and {n - 1} equally spaced output times "
                 f"(every {fmt_num(run['t'] / (n - 1))}). Reference: "
                 f"{run['reference']}. *final error*: max-abs error at the final time; *max error*: the largest "
                 "over the output times (when a trajectory is asked for). Errors compare the state (rigid body) "
                 "or position and velocity (sphere). *build time*: compiling the run's heyoka integrator; 0 when "
                 "it had been built earlier in the process (by an earlier row, or an earlier scene)."
                 + (" *relative error*: the final error of each quantity over its natural scale (R against 1, M "
                    "against |M|; x against |x|, v against |v|), the largest of them."
                    if getattr(result.scene, "stability", None) is not None else ""))
    lines.append("")
    (h1, r1), (h2, r2) = run_tables(result)
    lines += [markdown_table(h1, r1), ""]
    csvs.append(("run.csv", h1, r1))
    lines.append("Invariant drift: max |I(t) - I(0)| over the output times, I(0) of the exact initial state "
                 "(so the rounding of the initial state into each precision is included).")
    lines += ["", markdown_table(h2, r2), ""]
    csvs.append(("run_invariants.csv", h2, r2))
    certified = [r for r in run["rows"] if r.extra.get("certified_digits")]
    for r in certified:
        lines.append(f"- **{r.label}** ({r.model}): every component is proven to lie in its ball; certified "
                     f"digits at the final time {r.extra['certified_digits'][-1]:.1f} (widest ball "
                     f"{fmt_sci(r.extra.get('max_radius'))}), so its error above is at most that.")
    bad = [r for r in run["rows"] if r.status != "success"]
    for r in bad:
        lines.append(f"- **{r.label}** ({r.model}): {r.status}: {r.message}")
    if bad or certified:
        lines.append("")


def _section_trajectory(result, lines):
    lines += [f"## {section_titles()['trajectory']}", ""]
    lines.append("Top: the reference solution at the output times. Bottom: the error of each run along the way.")
    lines += ["", "![trajectory](trajectory.png)", ""]


def report_names(scene) -> tuple:
    """Files a scene's report certainly writes (checked before the computation): report.md, data.json and the
    plots the scene asks for."""
    return ("report.md", "data.json") + tuple(f"{p}.png" for p in getattr(scene, "plots", ()))


# -- the report ------------------------------------------------------------------------------------------------
def write_report(result, out_dir, overwrite: bool = False) -> Path:
    """Write ``report.md``, the plots, ``data.json`` and CSV tables of ``result`` into ``out_dir``.

    ``out_dir`` is a path, or a :class:`ReportFolder` already held (the command line locks and checks the folder
    before computing). The report is rendered into a staging folder and moved into place whole: files
    lieseries did not write are never replaced or removed, a folder holding any is refused unless ``overwrite``,
    and an interrupted or failed write leaves the earlier report as it was.

    Returns
    -------
    Path
        The path of ``report.md``.
    """
    if isinstance(out_dir, ReportFolder):
        render_report(result, out_dir.staging())
        out_dir.commit()
        return out_dir.path / "report.md"
    with ReportFolder(out_dir, overwrite, names=report_names(result.scene)) as folder:
        return write_report(result, folder)


def render_report(result, out: Path) -> Path:
    """Write the report files of ``result`` into the folder ``out`` as they are (no manifest, no check): the
    building block of :func:`write_report`, which renders into a fresh staging folder."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene = result.scene
    registry = studies_registry()
    titles = section_titles()
    plotted = []
    for name in scene.plots:
        if name == "trajectory":
            if not result.trajectories:
                continue
            plot_trajectory(result, out / "trajectory.png")
        else:
            if not result.studies.get(name):
                continue
            registry[name].plot(result.studies[name], out / f"{name}.png", scene)
        plotted.append(name)

    lines = [f"# {scene.title}", ""]
    if scene.description:
        lines += [scene.description, ""]
    mode = (" (quick mode: studies scaled down for CI; run without `--quick` for the full report)"
            if result.quick else "")
    lines.append(f"Scene `{scene.name}`{mode}. Generated {result.created} in {result.wall_time:.1f} s.")
    lines.append("")
    if result.quick:

        changes = quick_changes(scene)
        if changes:
            lines += ["Quick mode ran the scene below with these settings changed (the title and description speak "
                      "of the full scene):", ""] + [f"- `{c}`" for c in changes] + [""]
    lines += [f"## {titles['scene']}", ""]
    if scene.source:
        lines += ["```toml", scene.source.strip(), "```", ""]
    else:
        lines += ["```json", json.dumps(scene.to_dict(), indent=2, default=json_default), "```", ""]
    csvs = []
    if result.run is not None:
        _section_run(result, lines, csvs)
    if "trajectory" in plotted:
        _section_trajectory(result, lines)
    for name, study in registry.items():
        if name in result.studies:
            body, tables = study.section(result.studies[name], ReportContext(scene, name in plotted, result.quick))
            lines += [f"## {study.title}", ""] + list(body)
            csvs += list(tables)
    if result.notes:
        lines += [f"## {titles['notes']}", ""] + [f"- {n}" for n in result.notes] + [""]
    env = result.environment
    lines += [f"## {titles['environment']}", ""]
    lines.append(", ".join(f"{k} {v}" for k, v in env.items()) + ".")
    lines += ["", "Raw data: `data.json`" + (", tables: " + ", ".join(f"`{c[0]}`" for c in csvs) if csvs else "")
              + ".", ""]
    for name, h, rows in csvs:
        write_csv(out / name, h, rows)
    write_json(out / "data.json", result.to_dict())
    path = out / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def summary_text(result) -> str:
    """A short plain-text summary for the terminal."""
    lines = [f"{result.scene.title}"]
    if result.run is not None:
        run = result.run
        multi = len({r.model for r in run["rows"]}) > 1
        h = (["model"] if multi else []) + ["method", "t reached", "final error", "max invariant drift", "steps",
                                            "order", "build [s]", "run [s]", "status"]
        rows = [([r.model] if multi else []) + [
            _row_label(r), fmt_num(r.t), fmt_sci(r.error), fmt_sci(r.max_drift), fmt_int(r.steps), fmt_int(r.order),
            fmt_sci(r.build_time), fmt_sci(r.run_time), r.status] for r in run["rows"]]
        lines.append(plain_table(h, rows))
        short = [r for r in run["rows"] if r.t is not None and _short_of(r.t, run["t"])]
        for r in short:  # a capped method (mpmath's t_max) says success: its error is at the time it reached
            lines.append(f"{r.label}: ran to t = {fmt_num(r.t)} only, not t = {fmt_num(run['t'])}"
                         + (f": {r.message}" if r.message else "") + "; its errors are at the time it reached")
        first = next((r for r in run["rows"] if r.final_state is not None), None)
        if first is not None:
            vals = " ".join(f"{v:.12g}" for v in first.final_state)
            lines.append(f"final state at t = {first.t:g} ({first.label}): {vals}")
    for name, study in studies_registry().items():
        lines += study.summary(result.studies.get(name, []))
    for n in result.notes:
        lines.append(f"note: {n}")
    return "\n".join(lines)


def _short_of(t, t_end) -> bool:
    """True when a run reached ``t`` short of the requested end ``t_end`` (beyond the rounding of a float)."""
    return abs(float(t) - float(t_end)) > 1e-12 * max(1.0, abs(float(t_end)))


