"""The stability report (:mod:`lieseries.stability`): one row per case, the findings, the plots of
:data:`STABILITY_PLOTS`, and each case's scene report under ``scenes/<case>/``."""

from __future__ import annotations

import math
from pathlib import Path

from ..folder import ReportFolder
from ..formatting import fmt_int, fmt_num, fmt_p, fmt_sci, markdown_table, positive_or_nan, pyplot, save_figure
from .files import write_csv, write_json
from .scene_report import render_report

__all__ = ["write_stability_report", "stability_tables", "STABILITY_PLOTS"]


# -- the stability report --------------------------------------------------------------------------------------
#: Files the stability report writes (besides the scene reports under ``scenes/``).
STABILITY_PLOTS = ("overview", "error_growth", "drift", "divergence", "atlas")


def _precision_style(precision, method: str):
    """(marker, colour, family) of a run's precision (a Precision, or None), shared by the stability plots."""
    precision = getattr(precision, "name", precision)
    if method.startswith("Lie"):
        return "*", "C4", "Lie series (mpmath)"
    if method.startswith("scipy"):
        return "x", "C5", "scipy DOP853 (double)"
    if method.startswith("mpmath"):
        return "+", "C6", "mpmath odefun"
    return {"double": ("o", "C0", "heyoka double"), "long double": ("s", "C1", "heyoka long double"),
            "quad": ("^", "C2", "heyoka quad")}.get(precision, ("D", "C3", "heyoka arbitrary precision"))


def plot_stability_overview(stab, path: Path) -> None:
    plt = pyplot()
    cases = [c for c in stab.cases if c.rows]
    fig, ax = plt.subplots(figsize=(max(9.0, 0.75 * len(cases) + 3), 6))
    seen = set()
    for i, c in enumerate(cases):
        rows = c.rows
        for k, r in enumerate(rows):
            if r.scaled_error is None:
                continue
            marker, color, fam = _precision_style(r.precision, r.method)
            x = i + (k - (len(rows) - 1) / 2) * min(0.6 / max(len(rows), 1), 0.12)
            ok = r.status == "success"
            ax.semilogy([x], [max(r.scaled_error, 1e-300)], marker=marker, linestyle="none", markersize=7,
                        color=color, markerfacecolor=color if ok else "none",
                        label=None if fam in seen else fam)
            seen.add(fam)
    for eps, lab in ((2.0**-52, "eps double"), (2.0**-112, "eps quad")):
        ax.axhline(eps, color="grey", linewidth=0.7, linestyle=":")
        ax.annotate(lab, (len(cases) - 0.5, eps), fontsize=7, color="grey", va="bottom", ha="right")
    ax.set_xticks(range(len(cases)))
    ax.set_xticklabels([c.name for c in cases], rotation=35, ha="right", fontsize=8)
    ax.set_ylabel("final error relative to the natural scale")
    ax.set_title("Every run of every case (hollow: the run did not reach the final time)", fontsize=10)
    ax.legend(loc="best", fontsize=7)
    ax.grid(alpha=0.3, which="both", axis="y")
    save_figure(plt, fig, path)


def plot_stability_error_growth(stab, path: Path) -> None:
    plt = pyplot()
    cases = [c for c in stab.cases if c.analysis == "saddle" and c.details.get("errors")]
    n = len(cases)
    cols = min(n, 2)
    rows_ = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows_, cols, figsize=(7.5 * cols, 5 * rows_), squeeze=False)
    for j, c in enumerate(cases):
        ax = axes[j // cols][j % cols]
        d = c.details
        prec = {r.method: r.precision for r in c.rows if r.model == d["model"]}
        best = None
        for label, ser in d["errors"].items():
            marker, color, _ = _precision_style(prec.get(label, ""), label)
            ax.semilogy(ser["t"], positive_or_nan(ser["error"]), color=color, linewidth=1.2, label=label)
            dep = d["departure"].get(label)
            if dep is not None:
                ax.axvline(dep, color=color, linewidth=0.8, linestyle=":")
            if d["growth_rate"].get(label) is not None:
                best = (label, ser)  # the last fitted one is the most precise (methods are listed coarse first)
        ax.axhline(d["threshold"], color="k", linewidth=0.8, linestyle="--",
                   label=f"departure threshold {d['threshold']:g}")
        lam = d["lambda"]
        win = d.get("growth_window", {}).get(best[0]) if best is not None else None
        if best is not None and lam > 0 and win:
            # through the most precise run, over the window where its error grows fastest
            _, ser = best
            pts = [(t, e) for t, e in zip(ser["t"], ser["error"]) if e and e > 0 and win[0] <= t <= win[1]]
            if pts:
                tm, em = pts[len(pts) // 2]
                pad = 0.05 * (ser["t"][-1] - ser["t"][0])
                xs = [max(ser["t"][0], win[0] - pad), min(ser["t"][-1], win[1] + pad)]
                ax.semilogy(xs, [em * math.exp(lam * (x - tm)) for x in xs], color="grey", linewidth=1.5,
                            linestyle="-.", label=f"slope lambda = {lam:.4f} (the saddle's rate)")
        ax.set_xlabel("time t")
        ax.set_ylabel("max-abs error against the closed form")
        ax.set_title(f"{c.name}", fontsize=10)
        ax.legend(loc="lower right", fontsize=7)
        ax.grid(alpha=0.3, which="both")
    for j in range(n, rows_ * cols):
        axes[j // cols][j % cols].axis("off")
    fig.suptitle("Near the unstable axis round-off grows like e^(lambda t): error along the run; dotted: departure",
                 fontsize=10)
    save_figure(plt, fig, path)


def _case_row(stab, analysis: str, key: str):
    """A row of panels, one per stability case of ``analysis`` that has ``details[key]``."""
    plt = pyplot()
    cases = [c for c in stab.cases if c.analysis == analysis and c.details.get(key)]
    fig, axes = plt.subplots(1, len(cases), figsize=(7.5 * len(cases), 5.5), squeeze=False)
    return plt, cases, fig, axes


def plot_stability_drift(stab, path: Path) -> None:
    plt, cases, fig, axes = _case_row(stab, "drift", "errors")
    for j, c in enumerate(cases):
        ax = axes[0][j]
        d = c.details
        steps = d["steps"]
        for k, (name, errs) in enumerate(d["errors"].items()):
            p = d["exponents"].get(name)
            ax.loglog(steps, positive_or_nan(errs), color=f"C{k}", linewidth=1.2,
                      label=f"{name} (p = {fmt_p(p)})")
            scale = d["scales"].get(name, 1.0)
            ax.loglog(steps, [d["eps"] * math.sqrt(max(s, 1e-300)) * scale for s in steps], color=f"C{k}",
                      linestyle="--", linewidth=0.9, label=f"Brouwer eps sqrt(N) x {scale:.3g}")
            ax.loglog(steps, [d["eps"] * s * scale for s in steps], color=f"C{k}", linestyle=":", linewidth=0.9,
                      label=f"linear eps N x {scale:.3g}")
        ax.set_xlabel("steps N")
        ens = f", RMS over {d['ensemble']} runs" if d.get("ensemble", 1) > 1 else ""
        ax.set_ylabel("|I(t) - I(0)|" + ens)
        ax.set_title(f"{c.name}: {d['total_steps']} steps in double", fontsize=10)
        ax.legend(loc="best", fontsize=7)
        ax.grid(alpha=0.3, which="both")
    save_figure(plt, fig, path)


def plot_stability_divergence(stab, path: Path) -> None:
    plt, cases, fig, axes = _case_row(stab, "divergence", "orders")
    for j, c in enumerate(cases):
        ax = axes[0][j]
        d = c.details
        rho = d["radius_theory"]
        ax.semilogy(d["orders"], positive_or_nan(d["errors_inside"]), "o-", color="C0", markersize=4,
                    label=f"t = {d['t_inside']:.4g} = {d['t_inside'] / rho:.2g} rho (inside): falls")
        ax.semilogy(d["orders"], positive_or_nan(d["errors_beyond"]), "s-", color="C3", markersize=4,
                    label=f"t = {d['t_beyond']:.4g} = {d['t_beyond'] / rho:.2g} rho (beyond): grows")
        ax.set_xlabel("truncation order N")
        ax.set_ylabel("max-abs error of the truncated Lie series")
        est = d["error_estimate"]
        ax.set_title(f"{c.name}: rho = {rho:.4g} (pole distance), radius() = {d['radius_estimated']:.4g}\n"
                     f"error_estimate: {fmt_sci(est['inside'])} inside, {fmt_sci(est['beyond'])} beyond",
                     fontsize=9)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3, which="both")
    save_figure(plt, fig, path)


def plot_stability_atlas(stab, path: Path) -> None:
    plt = pyplot()
    cases = [c for c in stab.cases if c.analysis == "atlas" and c.details.get("series")]
    fig, axes = plt.subplots(2, len(cases), figsize=(8 * len(cases), 7), squeeze=False, sharex="col")
    for j, c in enumerate(cases):
        d = c.details
        ax, ax2 = axes[0][j], axes[1][j]
        with_charts = [label for label, ser in d["series"].items() if ser.get("charts") is not None]
        for k, (label, ser) in enumerate(d["series"].items()):
            ax2.semilogy(ser["t"], positive_or_nan(ser["error"]), color=f"C{k}", linewidth=1, label=label)
            if ser.get("charts") is not None:
                off = 0.12 * (with_charts.index(label) - (len(with_charts) - 1) / 2)
                ax.plot(ser["t"], [c + off for c in ser["charts"]], linestyle="none", marker="|", markersize=6,
                        color=f"C{k}", label=label)
        ax.set_yticks([0, 1, 2])
        ax.set_yticklabels(["x1", "x2", "x3"])
        ax.set_ylabel("dependent coordinate of the chart")
        sw = ", ".join(f"{v}" for v in d.get("switches", {}).values() if v is not None)
        ax.set_title(f"{c.name}: chart of each output row ({sw} switches)", fontsize=10)
        ax.legend(loc="best", fontsize=7)
        ax2.set_xlabel("time t")
        ax2.set_ylabel("error in (x, v) against the great circle")
        ax2.legend(loc="best", fontsize=7)
        ax2.grid(alpha=0.3, which="both")
    save_figure(plt, fig, path)


_STABILITY_PLOTTERS = {
    "overview": (plot_stability_overview, lambda s: any(c.rows for c in s.cases)),
    "error_growth": (plot_stability_error_growth,
                     lambda s: any(c.analysis == "saddle" and c.details.get("errors") for c in s.cases)),
    "drift": (plot_stability_drift, lambda s: any(c.analysis == "drift" and c.details.get("errors") for c in s.cases)),
    "divergence": (plot_stability_divergence,
                   lambda s: any(c.analysis == "divergence" and c.details.get("orders") for c in s.cases)),
    "atlas": (plot_stability_atlas, lambda s: any(c.analysis == "atlas" and c.details.get("series") for c in s.cases)),
}


def _expected_text(c) -> str:
    if c.as_expected is None:
        return "n/a"
    want = c.expect + (f' with "{c.expect_message}"' if c.expect_message else "")
    return ("yes" if c.as_expected else "**no**") + f" ({want})"


def stability_tables(stab):
    """(one-row-per-case table, every-row table) as (headers, rows) pairs."""
    h1 = ["case", "what it shows", "model", "method", "error", "relative error", "max invariant drift", "steps",
          "order", "run time [s]", "status", "as expected", "message"]
    rows1 = []
    for c in stab.cases:
        r = c.headline
        if r is None:
            rows1.append([c.name, c.title, "", "", "", "", "", "", "", "", "failed", _expected_text(c), c.finding])
            continue
        rows1.append([c.name, c.title, r.model, r.method, fmt_sci(r.error), fmt_sci(r.scaled_error),
                      fmt_sci(r.max_drift), fmt_int(r.steps), fmt_int(r.order), fmt_sci(r.run_time), r.status,
                      _expected_text(c), r.message])
    h2 = ["case", "model", "method", "precision", "setting", "t reached", "error", "relative error", "error / eps",
          "max invariant drift", "max relative drift", "steps", "order", "build time [s]", "run time [s]", "status"]
    rows2 = [[r.case, r.model, r.method, r.precision, r.setting, fmt_num(r.t), fmt_sci(r.error),
              fmt_sci(r.scaled_error), fmt_sci(r.error_over_eps), fmt_sci(r.max_drift), fmt_sci(r.max_rel_drift),
              fmt_int(r.steps), fmt_int(r.order), fmt_sci(r.build_time), fmt_sci(r.run_time), r.status]
             for r in stab.all_rows]
    return (h1, rows1), (h2, rows2)


def write_stability_report(stab, out_dir, scene_reports: bool = True, command: str | None = None,
                           overwrite: bool = False) -> Path:
    """Write the stability report of a :class:`lieseries.stability.Stability` into ``out_dir``.

    Writes ``report.md`` (one row per case, then a section per case), ``data.json``, ``stability.csv`` (one row
    per case), ``stability_all.csv`` (every run), the plots of :data:`STABILITY_PLOTS` that have data, and, with
    ``scene_reports``, each case's own scene report in ``scenes/<case>/`` (:func:`write_report`).

    Returns
    -------
    Path
        The path of ``report.md``.
    """
    with ReportFolder(out_dir, overwrite, names=("report.md", "data.json")) as folder:
        _render_stability_report(stab, folder.staging(), scene_reports, command)
        folder.commit()
        return folder.path / "report.md"


def _render_stability_report(stab, out: Path, scene_reports: bool, command) -> None:
    plotted = []
    for name, (fn, has) in _STABILITY_PLOTTERS.items():
        if has(stab):
            fn(stab, out / f"{name}.png")
            plotted.append(name)
    scene_links = {}
    if scene_reports:
        for c in stab.cases:
            if c.result is not None:
                p = render_report(c.result, out / "scenes" / c.name)
                scene_links[c.name] = p.relative_to(out).as_posix()

    (h1, r1), (h2, r2) = stability_tables(stab)
    lines = ["# Stability: extreme and stiff cases", ""]
    mode = (" in quick mode (each scene's quick plan: shorter runs; run without `--quick` for the full report)"
            if stab.quick else "")
    lines.append(f"Generated {stab.created}{mode} in {stab.wall_time:.1f} s"
                 + (f" by `{command}`" if command else "") + ". How to read it: `docs/reports/README.md`, section "
                 "*The stability report*.")
    lines.append("")
    lines.append("One row per case: the case's headline run (the method its scene names in `[stability].headline`). "
                 "*error*: max-abs error of the final state against the reference (closed form; heyoka at 256 bits "
                 "for the damped body), at the time the run reached; *relative error*: the same against the natural "
                 "scale of each quantity (R against 1, M against |M|; x against |x|, v against |v|); *max invariant "
                 "drift*: max |I(t) - I(0)| over the output times and over the case's invariants; *as expected*: "
                 "whether the run ended as the scene says it should.")
    lines += ["", markdown_table(h1, r1), ""]
    lines += ["## Findings", ""]
    for c in stab.cases:
        lines.append(f"- **{c.name}**: {c.finding}")
    lines.append("")
    if plotted:
        lines += ["## Plots", ""]
        captions = {
            "overview": "Every run of every case: final error relative to the natural scale.",
            "error_growth": "Separatrix and unstable axis: error along the run, the departure threshold, and the "
                            "slope of the saddle's rate lambda.",
            "drift": "Long run: invariant drift against steps, with Brouwer's eps sqrt(N) and linear eps N.",
            "divergence": "The truncated Lie series inside and beyond its radius of convergence.",
            "atlas": "The sphere's atlas: chart in use and error along the run.",
        }
        for name in plotted:
            lines += [f"{captions[name]}", "", f"![{name}]({name}.png)", ""]
    lines += ["## Cases", ""]
    for c in stab.cases:
        lines += [f"### {c.name}: {c.title}", ""]
        if c.description:
            lines += [c.description, ""]
        if c.rows:
            hh = ["model", "method", "t reached", "error", "relative error", "error / eps", "max invariant drift",
                  "steps", "order", "run time [s]", "status"]
            rr = [[r.model, r.method, fmt_num(r.t), fmt_sci(r.error), fmt_sci(r.scaled_error),
                   fmt_sci(r.error_over_eps), fmt_sci(r.max_drift), fmt_int(r.steps), fmt_int(r.order),
                   fmt_sci(r.run_time), r.status] for r in c.rows]
            lines += [markdown_table(hh, rr), ""]
            for r in c.rows:
                if r.status != "success":
                    lines.append(f"- {r.method} ({r.model}): {r.status}: {r.message}")
        lines.append(f"- Finding: {c.finding}")
        for note in c.notes:
            lines.append(f"- Note: {note}")
        if c.name in scene_links:
            link = scene_links[c.name]
            lines.append(f"- Scene report (run table, invariants, plots): [{link}]({link})")
        lines.append(f"- Wall time of the case: {c.wall_time:.1f} s.")
        lines.append("")
    env = stab.environment
    lines += ["## Environment", "", ", ".join(f"{k} {v}" for k, v in env.items()) + ".", "",
              "Raw data: `data.json`, tables: `stability.csv` (one row per case), `stability_all.csv` (every run).", ""]
    write_csv(out / "stability.csv", h1, r1)
    write_csv(out / "stability_all.csv", h2, r2)
    write_json(out / "data.json", stab.to_dict())
    (out / "report.md").write_text("\n".join(lines), encoding="utf-8")
