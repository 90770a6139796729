"""Reports: Markdown tables, PNG plots and raw data of a scene run. The only module that writes files or draws.

``write_report(result, out_dir)`` writes::

    out_dir/report.md            title, description, the scene as given, one section per run/study
    out_dir/data.json            everything computed (SceneResult.to_dict())
    out_dir/<table>.csv          one CSV per table
    out_dir/<plot>.png           the plots the scene asks for (trajectory, error_vs_order, work_precision, drift,
                                 departure_map)

``write_stability_report(stability, out_dir)`` writes the stability report (:mod:`lieseries.stability`):
``report.md`` with one row per case, ``data.json``, ``stability.csv``, ``stability_all.csv``, the plots of
:data:`STABILITY_PLOTS` and each case's scene report under ``scenes/<case>/``.

Numbers in the report are the ones computed in that run. Errors are printed in scientific notation with three
significant digits; times in seconds.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from .folder import ReportFolder

__all__ = ["write_report", "render_report", "write_stability_report", "report_names",
           "markdown_table", "summary_text", "fmt_sci", "SECTION_TITLES",
           "plot_departure_map", "departure_map_table", "departure_map_reading"]

#: The H2 headings of the report, by section.
SECTION_TITLES = {
    "scene": "Scene",
    "run": "Run",
    "trajectory": "Trajectory",
    "error_vs_order": "Error vs order",
    "work_precision": "Work-precision",
    "drift": "Invariant drift",
    "departure_map": "Departure map",
    "notes": "Notes",
    "environment": "Environment",
}


# -- formatting ------------------------------------------------------------------------------------------------
def fmt_sci(x, digits: int = 3) -> str:
    """Scientific notation with ``digits`` significant digits ("" for None, "0" for zero)."""
    if x is None:
        return ""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return str(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0:
        return "0"
    return f"{x:.{digits - 1}e}"


def fmt_int(x) -> str:
    return "" if x is None else f"{int(x):d}"


def fmt_num(x) -> str:
    """A plain number for parameters (times, fractions): up to 6 significant digits."""
    if x is None:
        return ""
    try:
        return f"{float(x):.6g}"
    except (TypeError, ValueError):
        return str(x)


def _is_numeric(cell: str) -> bool:
    s = cell.strip()
    if not s:
        return False
    try:
        float(s)
        return True
    except ValueError:
        return s in ("nan", "inf", "-inf")


def markdown_table(headers, rows) -> str:
    """A Markdown table with padded columns; columns of numbers are right-aligned."""
    headers = [str(h) for h in headers]
    rows = [[("" if c is None else str(c)).replace("|", "\\|") for c in r] for r in rows]
    ncol = len(headers)
    widths = [max([len(headers[j])] + [len(r[j]) for r in rows] + [3]) for j in range(ncol)]
    blank = ("", "none", "n/a")
    numeric = [bool(rows) and all(_is_numeric(r[j]) or r[j].strip() in blank for r in rows)
               and any(_is_numeric(r[j]) for r in rows) for j in range(ncol)]

    def line(cells):
        out = []
        for j, c in enumerate(cells):
            out.append(c.rjust(widths[j]) if numeric[j] else c.ljust(widths[j]))
        return "| " + " | ".join(out) + " |"

    sep = "| " + " | ".join(("-" * (widths[j] - 1) + ":") if numeric[j] else "-" * widths[j]
                            for j in range(ncol)) + " |"
    return "\n".join([line(headers), sep] + [line(r) for r in rows])


def _write_csv(path: Path, headers, rows) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(headers)
        for r in rows:
            w.writerow(["" if c is None else c for c in r])


def _json_default(o):
    try:
        return float(o)
    except (TypeError, ValueError):
        return str(o)


# -- plots -----------------------------------------------------------------------------------------------------
def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


_MARKERS = ["o", "s", "^", "D", "v", "P", "X", "*", "<", ">"]


def _save(plt, fig, path) -> None:
    """Lay out, write (PNG, 110 dpi) and close a figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _positive(values):
    return [v if (v is not None and v > 0 and math.isfinite(v)) else float("nan") for v in values]


def plot_trajectory(result, path: Path) -> None:
    plt = _pyplot()
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
        for k, (lab, errs) in enumerate(tr["errors"].items()):
            ax2.semilogy(tr["error_times"][lab], _positive(errs), marker=_MARKERS[k % len(_MARKERS)],
                         markersize=3, linewidth=1, label=lab)
        ax2.set_xlabel("time t")
        ax2.set_ylabel("max-abs error against the reference")
        ax2.set_title(f"{mlabel}: error along the run")
        if tr["errors"]:
            ax2.legend(loc="best", fontsize=8)
        ax2.grid(alpha=0.3, which="both")
    fig.suptitle(_wrap(result.scene.title, 60 * n), fontsize=10)
    _save(plt, fig, path)


def plot_error_vs_order(result, path: Path) -> None:
    plt = _pyplot()
    items = result.studies["error_vs_order"]
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    for k, (mlabel, ev) in enumerate(items):
        color = f"C{k}"
        ax.semilogy(ev.orders, _positive(ev.errors), marker=_MARKERS[k % len(_MARKERS)], linestyle="none",
                    color=color, markersize=4, label=f"{mlabel}: truncation error at t = {ev.t:.4g}")
        if ev.rate is not None and ev.fit_orders:
            xs = [min(ev.fit_orders), max(ev.fit_orders)]
            ax.semilogy(xs, [10 ** (ev.intercept + ev.rate * x) for x in xs], "-", color=color, linewidth=1,
                        label=f"fit: rho = {ev.radius_measured:.4g}")
            if ev.radius_theory:
                slope = math.log10(abs(ev.t) / ev.radius_theory)
                mid = 0.5 * (xs[0] + xs[1])
                anchor = ev.intercept + ev.rate * mid
                ax.semilogy(xs, [10 ** (anchor + slope * (x - mid)) for x in xs], ":", color="k", linewidth=1.2,
                            label=f"theory: (t / rho)^N, rho = {ev.radius_theory:.4g}")
    floor = min(ev.floor for _, ev in items)
    smallest = min((e for _, ev in items for e in ev.errors if e and e > 0), default=floor)
    if floor > smallest * 1e-4:  # drawn when the data come near it (it would only stretch the axis otherwise)
        ax.axhline(floor, color="grey", linestyle="--", linewidth=0.8, label=f"precision floor {floor:.0e}")
    ax.set_xlabel("truncation order N")
    ax.set_ylabel("max-abs error of the truncated Lie series")
    ax.set_title("Lie series: error against order (slope gives the radius of convergence)", fontsize=10)
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3, which="both")
    _save(plt, fig, path)


def plot_work_precision(result, path: Path) -> None:
    plt = _pyplot()
    items = result.studies["work_precision"]
    fig, ax = plt.subplots(figsize=(8.5, 6))
    series = {}
    for mlabel, wp in items:
        for r in wp.rows:
            if r.error is None or r.run_time is None:
                continue
            key = r.label if len(items) == 1 else f"{mlabel}: {r.label}"
            series.setdefault(key, []).append(r)
    shown_build = False
    for k, (key, rows) in enumerate(series.items()):
        color = f"C{k % 10}"
        marker = _MARKERS[k % len(_MARKERS)]
        xs = [r.run_time for r in rows]
        ys = [max(r.error, 1e-300) for r in rows]
        t_study = items[0][1].t
        span = {r.t for r in rows}
        if span and all(abs(ts - t_study) > 1e-12 * max(1.0, abs(t_study)) for ts in span):
            key = f"{key} (to t = {max(span):.3g} only)"  # a capped method (odefun) must say so on the plot
        ax.loglog(xs, ys, marker=marker, color=color, linewidth=1, markersize=6, label=key)
        if rows[0].method == "taylor":
            bx = [r.run_time + (r.build_time or 0.0) for r in rows if r.build_time]
            by = [max(r.error, 1e-300) for r in rows if r.build_time]
            if bx:
                ax.loglog(bx, by, marker=marker, color=color, markerfacecolor="none", linestyle="none",
                          markersize=6, label=None if shown_build else "hollow: run + build time (heyoka)")
                shown_build = True
    ax.set_xlabel("run time [s] (best of repeats; build time apart)")
    ax.set_ylabel("max-abs error at the final time")
    t = items[0][1].t if items else 0
    ax.set_title(f"Work-precision diagram, t = {t:.4g}", fontsize=10)
    ax.legend(loc="best", fontsize=7)
    ax.grid(alpha=0.3, which="both")
    _save(plt, fig, path)


def plot_drift(result, path: Path) -> None:
    plt = _pyplot()
    items = result.studies["drift"]
    n = len(items)
    fig, axes = plt.subplots(1, n, figsize=(7.5 * n, 5.5), squeeze=False)
    for j, (mlabel, dr) in enumerate(items):
        ax = axes[0][j]
        for k, name in enumerate(dr.errors):
            ax.loglog(dr.times, _positive(dr.errors[name]), linewidth=1, color=f"C{k}",
                      label=f"{name} (p = {_fmt_p(dr.exponents.get(name))})")
        ref = "energy" if "energy" in dr.errors else next(iter(dr.errors), None)
        if ref is not None:
            scale = dr.scales.get(ref, 1.0)
            ax.loglog(dr.times, [dr.eps * math.sqrt(max(s, 1e-300)) * scale for s in dr.steps], "k--", linewidth=1.5,
                      label=f"Brouwer: eps sqrt(steps) |{ref}(0)|")
            ax.loglog(dr.times, [dr.eps * s * scale for s in dr.steps], color="grey", linestyle=":", linewidth=1.5,
                      label=f"linear: eps steps |{ref}(0)|")
        ax.set_xlabel(f"time t ({dr.total_steps} steps in all, ~{dr.total_steps / dr.times[-1]:.3g} per unit)"
                      if dr.times else "time t")
        ylab = "|I(t) - I(0)|" + (f", RMS over {dr.ensemble} runs" if dr.ensemble > 1 else "")
        ax.set_ylabel(ylab)
        ax.set_title(f"{mlabel}: invariant drift, heyoka {dr.precision}", fontsize=10)
        ax.legend(loc="best", fontsize=7)
        ax.grid(alpha=0.3, which="both")
    _save(plt, fig, path)


def plot_departure_map(result, path: Path) -> None:
    """Departure time and digits kept over the (azimuth, polar angle) grid of M0, one column per precision, the
    separatrix drawn. ``result``: a SceneResult with a departure_map study (its first model) or a DepartureMap."""
    import numpy as np

    m = result.studies["departure_map"][0][1] if hasattr(result, "studies") else result
    plt = _pyplot()
    names = list(m.departure)
    fig, axes = plt.subplots(2, len(names), figsize=(5.2 * len(names), 8.2), squeeze=False)
    ph, th = np.degrees(m.phi), np.degrees(m.theta)
    contour = min(m.energy_ratio.shape) >= 2 and m.energy_ratio.min() < 1 < m.energy_ratio.max()
    for ax, name in zip(axes[1], names):
        digits = -np.log10(np.maximum(m.max_error[name], 1e-300))
        im = ax.pcolormesh(ph, th, digits, shading="nearest", cmap="magma")
        if contour:
            ax.contour(ph, th, m.energy_ratio, levels=[1.0], colors="c", linewidths=1.2)
        ax.set_title(f"{name}: digits kept, -log10 max |y - exact| on [0, {m.T:g}]")
        ax.set_xlabel("azimuth of M0 (deg)")
        ax.set_ylabel("polar angle of M0 from axis 3 (deg)")
        fig.colorbar(im, ax=ax, label="digits")
    for ax, name in zip(axes[0], names):
        im = ax.pcolormesh(ph, th, m.departure[name], shading="nearest", cmap="viridis", vmin=0, vmax=m.T)
        if contour:
            ax.contour(ph, th, m.energy_ratio, levels=[1.0], colors="w", linewidths=1.2)
        ys, xs = np.nonzero(m.stayed[name])
        ax.scatter(ph[xs], th[ys], s=4, c="k", marker=".", label=f"stayed within to T = {m.T:g}")
        ax.set_title(f"{name}: time before |y - exact| > {m.threshold:g}")
        ax.set_xlabel("azimuth of M0 (deg)")
        ax.set_ylabel("polar angle of M0 from axis 3 (deg)")
        fig.colorbar(im, ax=ax, label="departure time")
    axes[0][0].legend(loc="lower left", fontsize=7)
    fig.suptitle(f"Rigid body I = {tuple(m.inertia)}, |M| = 1, R(0) = 1 (white: the separatrix)")
    _save(plt, fig, path)


def departure_map_table(m):
    """(headers, rows): one row per precision of a DepartureMap."""
    import numpy as np

    h = ["precision", "members that departed before T", "earliest departure", "median departure (departed)",
         "fewest digits kept (where)", "most digits kept", "statuses other than success", "integration time"]
    rows = []
    for name, dep in m.departure.items():
        gone = ~m.stayed[name]
        bad = [s for s in m.statuses[name] if s != "success"]
        med = f"{np.median(dep[gone]):.1f}" if gone.any() else "-"
        err = m.max_error[name]
        i, j = np.unravel_index(np.argmax(err), err.shape)
        rows.append([name, f"{int(gone.sum())} / {dep.size}", f"{dep.min():.1f}", med,
                     f"{-np.log10(err.max()):.1f} (2 H I2 / abs(M)^2 = {m.energy_ratio[i, j]:.3f})",
                     f"{-np.log10(err.min()):.1f}" if err.min() > 0 else "all (no difference)", str(len(bad)),
                     f"{m.run_time[name]:.2f} s"])
    return h, rows


def departure_map_reading(m) -> str:
    """How to read the DepartureMap ``m`` (a paragraph for reports), with what its data show: per precision the
    departures measured, and on the separatrix the shift between precisions beside ln(eps ratio) / lambda."""
    import numpy as np

    growth = ", ".join(f"{name} {t:.0f}" for name, t in m.predicted.items())
    text = ("How to read it: the white curve is the separatrix (2 H I2 = |M|^2) through the unstable rotation about "
            "the intermediate axis. A motion on it creeps towards that rotation, where its errors grow like "
            f"exp(lambda t), lambda = {m.saddle_rate:.4f}: it departs once it is near that rotation plus "
            f"ln(threshold / eps) / lambda ({growth}), so a wider format buys a time shift of ln(eps ratio) / "
            "lambda, not a factor. Off the separatrix errors grow about linearly (a phase drift), the faster the "
            "closer the motion passes the saddle; the digits-kept panels show where digits were lost.")
    gap = np.abs(m.energy_ratio - 1)
    on = gap < 1e-9
    if on.any():
        text += f" {int(on.sum())} grid directions lie on the separatrix (energy ratio 1 within 1e-9)."
    else:
        text += (f" No grid direction lies on the separatrix (the closest has energy ratio "
                 f"{m.energy_ratio.flat[int(np.argmin(gap))]:.4f})"
                 + (": n_theta an odd multiple of 3 and n_phi even put some on it for I = (1, 2, 3)."
                    if tuple(m.inertia) == (1.0, 2.0, 3.0) else "."))
    first = None  # (precision, median departure on the separatrix) of the first precision that departed there
    for name, dep in m.departure.items():
        gone = ~m.stayed[name]
        if not gone.any():
            worst = float(m.max_error[name].max())
            text += (f" {name}: no direction departed by T = {m.T:g} ("
                     + (f"at least {-np.log10(worst):.1f} digits kept everywhere)." if worst > 0 else
                        "no difference from the closed form at all)."))
            continue
        text += f" {name}: {int(gone.sum())} of {dep.size} departed, the earliest at {dep[gone].min():.1f}"
        if (gone & on).any():
            med = float(np.median(dep[gone & on]))
            text += f"; on the separatrix at {med:.1f} (median)"
            if first is None:
                first = (name, med)
            elif name in m.predicted and first[0] in m.predicted:
                text += (f", {med - first[1]:.1f} after {first[0]} (ln(eps ratio) / lambda: "
                         f"{m.predicted[name] - m.predicted[first[0]]:.1f})")
        off = gone & ~on
        text += (f"; {int(off.sum())} off it." if off.any() else "; none off it.")
    return text


def _section_departure_map(result, lines, csvs, plotted):
    items = result.studies.get("departure_map", [])
    lines += [f"## {SECTION_TITLES['departure_map']}", ""]
    for mlabel, m in items:
        n_theta, n_phi = m.energy_ratio.shape
        lines.append(f"**{mlabel}**: I = {tuple(m.inertia)}, R(0) = 1, initial angular momentum M0 on |M| = 1 over "
                     f"a {n_theta} x {n_phi} grid of directions (both sides of the separatrix), one ensemble run "
                     f"of `ls.integrate` at tol = eps per precision, compared up to T = {m.T:g} with the closed "
                     "form (`ls.exact.euler_poisson_many`, at least 10 digits beyond the finest precision). "
                     "Departure: the first output time where the 12-number "
                     f"state differs from it by more than {m.threshold:g} (max norm).")
        lines.append("")
        h, rows = departure_map_table(m)
        lines += [markdown_table(h, rows), ""]
        tag = "" if len(items) == 1 else "_" + "".join(c if c.isalnum() else "_" for c in mlabel)
        csvs.append((f"departure_map{tag}.csv", h, rows))
        lines += [departure_map_reading(m), ""]
    if "departure_map" in plotted:
        lines += ["![departure map](departure_map.png)", ""]


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def _fmt_p(p):
    return "n/a" if p is None else f"{p:.2f}"


_CSV_NAMES = ("run.csv", "run_invariants.csv", "error_vs_order.csv", "error_vs_order_fit.csv", "work_precision.csv",
              "drift.csv", "departure_map.csv")

_PLOTTERS = {
    "trajectory": plot_trajectory,
    "error_vs_order": plot_error_vs_order,
    "work_precision": plot_work_precision,
    "drift": plot_drift,
    "departure_map": plot_departure_map,
}


# -- tables ----------------------------------------------------------------------------------------------------
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


def _verdict(p):
    if p is None:
        return "too few points"
    if p < 0.75:
        return "~ steps^0.5 (Brouwer)" if p > 0.25 else "flat (bounded)"
    return "~ steps^1 (linear)"


def _section_run(result, lines, csvs):
    run = result.run
    lines += [f"## {SECTION_TITLES['run']}", ""]
    n = run["samples"]
    lines.append(f"Final time t = {fmt_num(run['t'])}; {n} samples: t = 0 and {n - 1} equally spaced output times "
                 f"(every {fmt_num(run['t'] / (n - 1))}). Reference: "
                 f"{run['reference']}. *final error*: max-abs error at the final time; *max error*: the largest "
                 "over the output times (when a trajectory is asked for). Errors compare the state (rigid body) "
                 "or position and velocity (sphere)."
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
    lines += [f"## {SECTION_TITLES['trajectory']}", ""]
    lines.append("Top: the reference solution at the output times. Bottom: the error of each run along the way.")
    lines += ["", "![trajectory](trajectory.png)", ""]


def _section_error_vs_order(result, lines, csvs, plotted):
    items = result.studies.get("error_vs_order", [])
    lines += [f"## {SECTION_TITLES['error_vs_order']}", ""]
    if not items:
        lines += ["Not computed (see the notes).", ""]
        return
    lines.append("Error of the Lie series truncated at order N, at a fixed time t. Inside the disc of convergence "
                 "error_N ~ C (|t| / rho)^N: the least-squares slope of log10(error) against N (over the orders "
                 "listed, above the precision floor 100 x 10^-dps; by default the upper half of them, since low "
                 "orders can be pre-asymptotic) gives rho = |t| 10^(-slope), compared with the distance to the "
                 "nearest singularity of the exact solution.")
    lines.append("")
    h = ["model", "t", "dps", "fitted slope [log10/order]", "rho measured", "rho theory", "measured / theory",
         "orders fitted"]
    rows = []
    for mlabel, ev in items:
        fit = f"{min(ev.fit_orders)}-{max(ev.fit_orders)}" if ev.fit_orders else ""
        rows.append([mlabel, fmt_num(ev.t), str(ev.dps), fmt_sci(ev.rate, 4), fmt_sci(ev.radius_measured, 4),
                     fmt_sci(ev.radius_theory, 4) if ev.radius_theory else "none",
                     f"{ev.radius_ratio:.4f}" if ev.radius_ratio else "", fit])
    lines += [markdown_table(h, rows), ""]
    csvs.append(("error_vs_order_fit.csv", h, rows))
    orders = sorted({o for _, ev in items for o in ev.orders})
    h2 = ["order"] + [f"error ({m})" if len(items) > 1 else "error" for m, _ in items]
    maps = [dict(zip(ev.orders, ev.errors)) for _, ev in items]
    rows2 = [[str(o)] + [fmt_sci(mp.get(o)) for mp in maps] for o in orders]
    csvs.append(("error_vs_order.csv", h2, rows2))
    for mlabel, ev in items:
        if ev.radius_theory is None:
            lines.append(f"- {mlabel}: no finite theoretical radius (no singularity at finite complex time), so "
                         "the fitted 'radius' only describes the orders shown; an entire series falls faster than "
                         "any geometric rate.")
    lines.append(f"- Reference: {items[0][1].reference}. Full error table: `error_vs_order.csv`.")
    lines.append("")
    lines += ["<details><summary>Error against order</summary>", "", markdown_table(h2, rows2), "", "</details>", ""]
    if "error_vs_order" in plotted:
        lines += ["![error vs order](error_vs_order.png)", ""]


def _section_work_precision(result, lines, csvs, plotted):
    items = result.studies.get("work_precision", [])
    lines += [f"## {SECTION_TITLES['work_precision']}", ""]
    lines.append("Error of the final state against run time (wall time of the call, best of the repeats, measured "
                 "in this run on this machine: compare rows with each other). heyoka's compile time is shown apart "
                 "as *build time* (0 when the integrator came from the cache); for scipy it is the compile time "
                 "of the right-hand side (heyoka cfunc). mpmath's odefun is capped to short spans: see *t*.")
    lines.append("")
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
    csvs.append(("work_precision.csv", h, rows))
    for mlabel, wp in items:
        lines.append(f"- Reference ({mlabel}): {wp.reference}.")
        for note in wp.notes:
            lines.append(f"- {note}")
        for r in wp.rows:
            if r.status not in ("success",):
                lines.append(f"- {r.label} {r.setting}: {r.status}: {r.message}")
    lines.append("")
    if "work_precision" in plotted:
        lines += ["![work-precision diagram](work_precision.png)", ""]


def _section_drift(result, lines, csvs, plotted):
    items = result.studies.get("drift", [])
    lines += [f"## {SECTION_TITLES['drift']}", ""]
    lines.append("Drift |I(t) - I(0)| of each invariant over a long heyoka run at tolerance eps (truncation error "
                 "below round-off), at log-spaced sample times. Round-off that behaves like a random walk grows "
                 "like eps sqrt(steps) (Brouwer's law); a biased error grows like eps steps. *p* is the fitted "
                 "exponent of drift ~ steps^p (log-log slope of the running maximum over the second half of the "
                 "samples).")
    lines.append("")
    for mlabel, dr in items:
        ens = f", RMS over an ensemble of {dr.ensemble} runs" if dr.ensemble > 1 else ""
        t_end = fmt_num(dr.times[-1]) if dr.times else ""
        lines.append(f"**{mlabel}**: heyoka {dr.precision}, tol {fmt_sci(dr.tol)}, t = {t_end}, "
                     f"{dr.total_steps} steps, order {dr.order}, run time {fmt_sci(dr.run_time)} s{ens}; "
                     f"status {dr.status}.")
        if dr.status != "success":
            reach = f"up to t = {fmt_num(dr.times[-1])}" if dr.times else "at no sample time"
            lines.append(f"The run stopped early ({dr.message}); the drift below is measured {reach}, and empty "
                         "cells mean no sample was reached.")
        lines.append("")
        h = ["invariant", "I(0)", "final drift", "max drift", "Brouwer eps sqrt(N) |I(0)|", "exponent p",
             "growth"]
        rows = []
        for name, errs in dr.errors.items():
            p = dr.exponents.get(name)
            rows.append([name, fmt_sci(dr.initial.get(name), 6), fmt_sci(errs[-1] if errs else None),
                         fmt_sci(max(errs) if errs else None),
                         fmt_sci(dr.brouwer[name][-1] if dr.brouwer[name] else None), _fmt_p(p), _verdict(p)])
        lines += [markdown_table(h, rows), ""]
        tag = "" if len(items) == 1 else "_" + "".join(c if c.isalnum() else "_" for c in mlabel)
        csvs.append((f"drift_summary{tag}.csv", h, rows))
        h2 = ["t", "steps"] + [f"drift {k}" for k in dr.errors]
        rows2 = [[repr(t), f"{s:.6g}"] + [repr(dr.errors[k][i]) for k in dr.errors]
                 for i, (t, s) in enumerate(zip(dr.times, dr.steps))]
        csvs.append((f"drift{tag}.csv", h2, rows2))
    if "drift" in plotted:
        lines += ["![invariant drift](drift.png)", ""]


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
    plotted = []
    for name in scene.plots:
        if name == "trajectory" and not result.trajectories:
            continue
        if name in result.studies and not result.studies[name]:
            continue
        _PLOTTERS[name](result, out / f"{name}.png")
        plotted.append(name)

    lines = [f"# {scene.title}", ""]
    if scene.description:
        lines += [scene.description, ""]
    mode = (" (quick mode: studies scaled down for CI; run without `--quick` for the full report)"
            if result.quick else "")
    lines.append(f"Scene `{scene.name}`{mode}. Generated {result.created} in {result.wall_time:.1f} s.")
    lines.append("")
    if result.quick:
        from .scenes import quick_changes

        changes = quick_changes(scene)
        if changes:
            lines += ["Quick mode ran the scene below with these settings changed (the title and description speak "
                      "of the full scene):", ""] + [f"- `{c}`" for c in changes] + [""]
    lines += [f"## {SECTION_TITLES['scene']}", ""]
    if scene.source:
        lines += ["```toml", scene.source.strip(), "```", ""]
    else:
        lines += ["```json", json.dumps(scene.to_dict(), indent=2, default=_json_default), "```", ""]
    csvs = []
    if result.run is not None:
        _section_run(result, lines, csvs)
    if "trajectory" in plotted:
        _section_trajectory(result, lines)
    if "error_vs_order" in result.studies:
        _section_error_vs_order(result, lines, csvs, plotted)
    if "work_precision" in result.studies:
        _section_work_precision(result, lines, csvs, plotted)
    if "drift" in result.studies:
        _section_drift(result, lines, csvs, plotted)
    if "departure_map" in result.studies:
        _section_departure_map(result, lines, csvs, plotted)
    if result.notes:
        lines += [f"## {SECTION_TITLES['notes']}", ""] + [f"- {n}" for n in result.notes] + [""]
    env = result.environment
    lines += [f"## {SECTION_TITLES['environment']}", ""]
    lines.append(", ".join(f"{k} {v}" for k, v in env.items()) + ".")
    lines += ["", "Raw data: `data.json`" + (", tables: " + ", ".join(f"`{c[0]}`" for c in csvs) if csvs else "")
              + ".", ""]
    for name, h, rows in csvs:
        _write_csv(out / name, h, rows)
    with open(out / "data.json", "w", encoding="utf-8") as f:
        json.dump(result.to_dict(), f, separators=(",", ":"), default=_json_default)
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
        lines.append(_plain_table(h, rows))
        short = [r for r in run["rows"] if r.t is not None and _short_of(r.t, run["t"])]
        for r in short:  # a capped method (mpmath's t_max) says success: its error is at the time it reached
            lines.append(f"{r.label}: ran to t = {fmt_num(r.t)} only, not t = {fmt_num(run['t'])}"
                         + (f": {r.message}" if r.message else "") + "; its errors are at the time it reached")
        first = next((r for r in run["rows"] if r.final_state is not None), None)
        if first is not None:
            vals = " ".join(f"{v:.12g}" for v in first.final_state)
            lines.append(f"final state at t = {first.t:g} ({first.label}): {vals}")
    for mlabel, ev in result.studies.get("error_vs_order", []):
        th = f", theory {ev.radius_theory:.4g}" if ev.radius_theory else ""
        rm = "n/a" if ev.radius_measured is None else f"{ev.radius_measured:.4g}"
        lines.append(f"error vs order ({mlabel}): radius measured {rm}{th}")
    for mlabel, wp in result.studies.get("work_precision", []):
        ok = [r for r in wp.rows if r.error is not None]
        best = min(ok, key=lambda r: r.error) if ok else None
        lines.append(f"work-precision ({mlabel}): {len(wp.rows)} runs" + (
            f", smallest error {fmt_sci(best.error)} ({best.label} {best.setting})" if best else ""))
    for mlabel, dr in result.studies.get("drift", []):
        p = dr.exponents.get("energy")
        energy = dr.errors.get("energy") or []
        final = fmt_sci(energy[-1]) if energy else "n/a"
        lines.append(f"drift ({mlabel}): {dr.total_steps} steps, energy drift {final}, "
                     f"exponent {_fmt_p(p)} ({_verdict(p)})")
    for mlabel, m in result.studies.get("departure_map", []):
        for name, dep in m.departure.items():
            gone = int((~m.stayed[name]).sum())
            bad = sum(1 for st in m.statuses[name] if st != "success")
            lines.append(f"departure map ({mlabel}, {name}): {gone} / {dep.size} departed before T = {m.T:g}, "
                         f"earliest {dep.min():.4g}, worst error {fmt_sci(float(m.max_error[name].max()))}"
                         + (f", {bad} runs not successful" if bad else ""))
    for n in result.notes:
        lines.append(f"note: {n}")
    return "\n".join(lines)


def _short_of(t, t_end) -> bool:
    """True when a run reached ``t`` short of the requested end ``t_end`` (beyond the rounding of a float)."""
    return abs(float(t) - float(t_end)) > 1e-12 * max(1.0, abs(float(t_end)))


def _plain_table(headers, rows) -> str:
    widths = [max([len(str(h))] + [len(str(r[j])) for r in rows]) for j, h in enumerate(headers)]
    out = ["  ".join(str(h).ljust(widths[j]) for j, h in enumerate(headers))]
    out.append("  ".join("-" * w for w in widths))
    for r in rows:
        out.append("  ".join(str(c).ljust(widths[j]) for j, c in enumerate(r)))
    return "\n".join(out)


# -- the stability report --------------------------------------------------------------------------------------
#: Files the stability report writes (besides the scene reports under ``scenes/``).
STABILITY_PLOTS = ("overview", "error_growth", "drift", "divergence", "atlas")


def _precision_style(precision: str, method: str):
    """(marker, colour, family) of a run's precision, shared by the stability plots."""
    if method.startswith("Lie"):
        return "*", "C4", "Lie series (mpmath)"
    if method.startswith("scipy"):
        return "x", "C5", "scipy DOP853 (double)"
    if method.startswith("mpmath"):
        return "+", "C6", "mpmath odefun"
    return {"double": ("o", "C0", "heyoka double"), "long double": ("s", "C1", "heyoka long double"),
            "quad": ("^", "C2", "heyoka quad")}.get(precision, ("D", "C3", "heyoka arbitrary precision"))


def plot_stability_overview(stab, path: Path) -> None:
    plt = _pyplot()
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
    _save(plt, fig, path)


def plot_stability_error_growth(stab, path: Path) -> None:
    plt = _pyplot()
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
            ax.semilogy(ser["t"], _positive(ser["error"]), color=color, linewidth=1.2, label=label)
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
    _save(plt, fig, path)


def _case_row(stab, analysis: str, key: str):
    """A row of panels, one per stability case of ``analysis`` that has ``details[key]``."""
    plt = _pyplot()
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
            ax.loglog(steps, _positive(errs), color=f"C{k}", linewidth=1.2,
                      label=f"{name} (p = {_fmt_p(p)})")
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
    _save(plt, fig, path)


def plot_stability_divergence(stab, path: Path) -> None:
    plt, cases, fig, axes = _case_row(stab, "divergence", "orders")
    for j, c in enumerate(cases):
        ax = axes[0][j]
        d = c.details
        rho = d["radius_theory"]
        ax.semilogy(d["orders"], _positive(d["errors_inside"]), "o-", color="C0", markersize=4,
                    label=f"t = {d['t_inside']:.4g} = {d['t_inside'] / rho:.2g} rho (inside): falls")
        ax.semilogy(d["orders"], _positive(d["errors_beyond"]), "s-", color="C3", markersize=4,
                    label=f"t = {d['t_beyond']:.4g} = {d['t_beyond'] / rho:.2g} rho (beyond): grows")
        ax.set_xlabel("truncation order N")
        ax.set_ylabel("max-abs error of the truncated Lie series")
        est = d["error_estimate"]
        ax.set_title(f"{c.name}: rho = {rho:.4g} (pole distance), radius() = {d['radius_estimated']:.4g}\n"
                     f"error_estimate: {fmt_sci(est['inside'])} inside, {fmt_sci(est['beyond'])} beyond",
                     fontsize=9)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3, which="both")
    _save(plt, fig, path)


def plot_stability_atlas(stab, path: Path) -> None:
    plt = _pyplot()
    cases = [c for c in stab.cases if c.analysis == "atlas" and c.details.get("series")]
    fig, axes = plt.subplots(2, len(cases), figsize=(8 * len(cases), 7), squeeze=False, sharex="col")
    for j, c in enumerate(cases):
        d = c.details
        ax, ax2 = axes[0][j], axes[1][j]
        with_charts = [label for label, ser in d["series"].items() if ser.get("charts") is not None]
        for k, (label, ser) in enumerate(d["series"].items()):
            ax2.semilogy(ser["t"], _positive(ser["error"]), color=f"C{k}", linewidth=1, label=label)
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
    _save(plt, fig, path)


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
    _write_csv(out / "stability.csv", h1, r1)
    _write_csv(out / "stability_all.csv", h2, r2)
    with open(out / "data.json", "w", encoding="utf-8") as f:
        json.dump(stab.to_dict(), f, separators=(",", ":"), default=_json_default)
    (out / "report.md").write_text("\n".join(lines), encoding="utf-8")
