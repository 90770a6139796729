"""How long each precision stays on the exact motion, over the sphere of initial angular momenta |M| = 1.

For a free rigid body every initial angular momentum M0 on the sphere |M| = 1 (R(0) = 1) is one motion; the
separatrices through the intermediate axis split the sphere into rotations about the major and the minor axis.
On a separatrix the motion creeps towards the unstable rotation about the intermediate axis, where errors grow
like exp(lambda t): every precision departs from the closed form after about ln(threshold / eps) / lambda. Off it
errors grow about linearly, faster the closer the motion passes the saddle. This study measures how long each
precision stays within a threshold on a grid of M0, in one ensemble run per precision, against
:func:`lieseries.exact.euler_poisson_many`. The grid's directions are computed exactly (to the data's digits), so
a grid with n_theta an odd multiple of 3 and n_phi a multiple of 2 lands on the separatrix of I = (1, 2, 3) at
theta = 30 and 150 degrees, phi = 0 and 180 degrees (and n_theta odd on the intermediate axis itself).

Plain data: :func:`departure_map` returns a :class:`DepartureMap`; reports draw it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from .. import exact
from .. import fields as F
from ..formatting import file_tag, fmt_sci, markdown_table, pyplot, save_figure
from ..methods.pricing import CostPart
from ..models.euler_poisson import EulerPoisson
from ..precision import MAX_SAMPLES, MIN_DPS, check_count, check_time, resolve_precision, to_fraction
from ..precision import thread_mp as mp
from ..api import integrate
from .plugin import Study, register_study

#: Most digits of the map's closed-form reference and exact initial data (the API's and the scene's bound).
MAX_MAP_DPS = 1000

__all__ = ["DepartureMap", "departure_map", "plot_departure_map", "departure_map_table", "departure_map_reading",
           "DepartureMapStudy"]


@dataclass
class DepartureMap:
    """Departure times over a (theta, phi) grid of initial angular momenta on |M| = 1.

    Attributes
    ----------
    theta, phi : 1-d arrays
        Polar angle from the body's third axis and azimuth of M0 = (sin th cos ph, sin th sin ph, cos th).
    energy_ratio : 2-d array (theta x phi)
        2 H I2 / |M|^2: above 1 the body rotates about the minor axis (I1), below 1 about the major axis (I3);
        1 is the separatrix.
    departure : dict precision -> 2-d array
        The first output time at which the state differs from the closed form by more than ``threshold``
        (``T`` when it never did: see ``stayed``).
    stayed : dict precision -> 2-d bool array
        True where the run stayed within ``threshold`` up to ``T``.
    max_error : dict precision -> 2-d array
        The largest max-norm difference from the closed form over the output times reached.
    statuses : dict precision -> list of str
        The run's status per member (anything but ``success`` is reported, never hidden).
    run_time : dict precision -> float
        Wall time of that precision's ensemble run without compiling the integrator, in seconds (its members may
        share several threads).
    saddle_rate : float
        lambda of the body at |M| = 1 (:meth:`lieseries.EulerPoisson.saddle_rate`).
    predicted : dict precision -> float
        ln(threshold / eps) / lambda: when a motion on the separatrix departs, its error eps grown at rate lambda.
    """

    inertia: tuple
    T: float
    threshold: float
    theta: np.ndarray
    phi: np.ndarray
    energy_ratio: np.ndarray
    departure: dict = field(default_factory=dict)
    stayed: dict = field(default_factory=dict)
    max_error: dict = field(default_factory=dict)
    statuses: dict = field(default_factory=dict)
    run_time: dict = field(default_factory=dict)
    saddle_rate: float = math.nan
    predicted: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "inertia": list(self.inertia), "T": self.T, "threshold": self.threshold,
            "theta": self.theta.tolist(), "phi": self.phi.tolist(), "energy_ratio": self.energy_ratio.tolist(),
            "departure": {k: v.tolist() for k, v in self.departure.items()},
            "stayed": {k: v.tolist() for k, v in self.stayed.items()},
            "max_error": {k: v.tolist() for k, v in self.max_error.items()},
            "statuses": self.statuses, "run_time": self.run_time, "saddle_rate": self.saddle_rate,
            "predicted": self.predicted,
        }


def _directions(n_theta: int, n_phi: int, dps: int):
    """Grid angles theta_i = (i + 1/2) pi / n_theta, phi_j = 2 pi j / n_phi and the unit vectors M0 in those
    directions, computed from the exact angles and rounded once to ``dps`` digits (the rounded components are the
    exact data of the motion)."""
    out = []
    with mp.workdps(dps):
        ths = [(2 * i + 1) * mp.pi / (2 * n_theta) for i in range(n_theta)]
        phs = [2 * j * mp.pi / n_phi for j in range(n_phi)]
        for th in ths:
            for ph in phs:
                v = (mp.sin(th) * mp.cos(ph), mp.sin(th) * mp.sin(ph), mp.cos(th))
                out.append(tuple(to_fraction(+c) for c in v))
        return np.array([float(v) for v in ths]), np.array([float(v) for v in phs]), out


def departure_map(
    inertia=(1, 2, 3),
    *,
    grid=(8, 16),
    T=100,
    samples: int = 100,
    precisions=("double", "quad"),
    threshold="1e-6",
    dps: int = 30,
    progress=None,
) -> DepartureMap:
    """Measure, for each M0 on a (theta, phi) grid of the unit sphere and each precision, how long the Taylor
    integration stays within ``threshold`` (max norm of the 12-number state) of the closed form.

    Parameters
    ----------
    inertia : three principal moments (exact input stays exact)
    grid : (n_theta, n_phi)
        Grid of initial momentum directions (at most 64 x 128).
    T, samples :
        Final time and number of equally spaced output times at which the state is compared.
    precisions : sequence of precisions ('double', 'long double', 'quad', bits)
    threshold : number
        Departure is the first output time with max |y - y_exact| > threshold.
    dps : digits of the exact initial data (the grid's directions rounded once) and of the closed-form reference,
        whose digits are raised to the finest precision's + 10 (45 for quad) when fewer, so that the reference's
        own error stays far below every run's round-off and the digits kept that the map reports are the run's.
    progress : callable, optional
        ``progress(done, total, label)`` (the study convention, e.g. a :class:`lieseries.progress.ProgressBar`)
        after each member's closed-form reference and after each precision's ensemble run.
    """
    n_theta, n_phi = _check_grid(grid)
    samples = check_count(samples, "samples", low=2, high=MAX_SAMPLES)
    Tf = check_time(T, "T", positive=True)
    thr = to_fraction(threshold, "threshold")
    if thr <= 0:
        raise ValueError(f"`threshold` must be positive; got {float(thr)}")
    precs = _check_precisions(precisions)
    dps = check_count(dps, "dps", low=MIN_DPS, high=MAX_MAP_DPS)
    ref_dps = max(dps, max(math.ceil(p.bits * math.log10(2)) for p in precs) + 10)
    body = EulerPoisson(inertia)
    I = [body.inertia_exact[i][i] for i in range(3)]
    if not body.diagonal:
        raise ValueError("`inertia` must be three principal moments for the departure map")
    theta, phi, dirs = _directions(n_theta, n_phi, dps)
    times = [Tf * k / samples for k in range(1, samples + 1)]
    omegas = [tuple(m / Ii for m, Ii in zip(M, I)) for M in dirs]
    ratio = np.array([float(sum(m * m / Ii for m, Ii in zip(M, I)) * I[1] / sum(m * m for m in M))
                      for M in dirs]).reshape(n_theta, n_phi)

    n_work = len(omegas) + len(precs)
    done = [0]

    def step(label):
        done[0] += 1
        if progress is not None:
            progress(done[0], n_work, label)

    refs = []
    for k, om in enumerate(omegas):
        refs.append(exact.euler_poisson_many(inertia, om, times, dps=ref_dps))
        step(f"closed form {k + 1}/{len(omegas)}")
    result = DepartureMap(tuple(float(v) for v in I), float(Tf), float(thr), theta, phi, ratio,
                          saddle_rate=body.saddle_rate(1))
    if result.saddle_rate > 0:
        result.predicted = {p.name: math.log(float(thr) / p.eps) / result.saddle_rate for p in precs}
    # exact initial states: the ensemble rounds each once to the working precision, as a single run would
    y0s = [body.initial_state(omega=om) for om in omegas]
    for prec in precs:
        sol = integrate(body, y0s, t=times, precision=prec)
        statuses = [str(s) for s in sol.status]
        dep, worst, stayed = _departures(sol, refs, times, thr, ref_dps, Tf)
        step(f"{prec.name}: {len(omegas)} members")
        result.departure[prec.name] = dep.reshape(n_theta, n_phi)
        result.stayed[prec.name] = stayed.reshape(n_theta, n_phi)
        result.max_error[prec.name] = worst.reshape(n_theta, n_phi)
        result.statuses[prec.name] = statuses
        # the ensemble's clock includes compiling the integrator (build_time); the map reports the integration
        result.run_time[prec.name] = max(0.0, float(sol.stats["run_time"]) - float(sol.stats["build_time"]))
    return result


def _check_grid(grid):
    """(n_theta, n_phi) of the grid of directions, at most 64 x 128."""
    if not (isinstance(grid, (tuple, list)) and len(grid) == 2):
        raise ValueError(f"`grid` must be (n_theta, n_phi); got {grid!r}")
    return check_count(grid[0], "grid[0]", high=64), check_count(grid[1], "grid[1]", high=128)


def _check_precisions(precisions) -> list:
    """The map's precisions, at least one."""
    precs = [resolve_precision(p, "precisions") for p in precisions]
    if not precs:
        raise ValueError("`precisions` must name at least one precision ('double', 'long double', 'quad', bits)")
    return precs


def _departures(sol, refs, times, thr: Fraction, dps: int, Tf):
    """Per member of the ensemble solution ``sol``: its departure time (T when it stayed within ``thr``), its
    largest difference from its closed form ``refs[k]``, and whether it stayed (a run that succeeded)."""
    count = len(refs)
    dep = np.empty(count)
    worst = np.empty(count)
    stayed = np.zeros(count, dtype=bool)
    for k in range(count):
        member = sol.member(k)
        dep[k], worst[k] = _first_departure(member, refs[k], times, thr, dps)
        stayed[k] = member.success and dep[k] == math.inf
        if dep[k] == math.inf:
            dep[k] = float(Tf)
    return dep, worst, stayed


def _first_departure(sol, ref, times, thr: Fraction, dps: int):
    """(the first output time whose state is farther than ``thr`` from the reference -- inf if none, the first
    unreached time when the run stopped early --, the largest difference over the rows reached)."""
    first, worst = math.inf, 0.0
    with mp.workdps(dps):
        limit = mp.mpf(thr.numerator) / thr.denominator
        for k, tk in enumerate(times):
            if k >= len(sol.y):
                first = min(first, float(tk))
                break
            row = sol.y[k]
            err = max(abs(mp.mpf(to_fraction(a).numerator) / to_fraction(a).denominator - b)
                      for a, b in zip(row, ref[k]))
            worst = max(worst, float(err))
            if err > limit and first == math.inf:
                first = float(tk)
    return first, worst


# -- the study in scenes and reports ---------------------------------------------------------------------------
def _grid_field(value, path):
    """[n_theta, n_phi] of the departure map: at most 64 x 128 directions."""
    if not isinstance(value, list) or len(value) != 2:
        F.fail(path, "a list [n_theta, n_phi] of two integers", value)
    F.integer(1, 64)(value[0], f"{path}[0]")
    F.integer(1, 128)(value[1], f"{path}[1]")
    return value


def plot_departure_map(result, path) -> None:
    """Departure time and digits kept over the (azimuth, polar angle) grid of M0, one column per precision, the
    separatrix drawn. ``result``: a SceneResult with a departure_map study (its first model) or a DepartureMap."""
    m = result.studies["departure_map"][0][1] if hasattr(result, "studies") else result
    plt = pyplot()
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
    save_figure(plt, fig, path)


def departure_map_table(m):
    """(headers, rows): one row per precision of a DepartureMap."""
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


class DepartureMapStudy(Study):
    """``[studies.departure_map]``: how long each precision stays on the closed form over |M0| = 1 (the scene's
    free rigid bodies with principal inertia, Chetaev bracket; [initial] is not used)."""

    name = "departure_map"
    title = "Departure map"
    quick_doc = "the departure map on at most a 3 x 6 grid, over a tenth of the time with at most 20 output times"
    fields = {
        "grid": (_grid_field, [8, 16]),
        "T": (F.time(positive=True), 100),
        "samples": (F.count(2, MAX_SAMPLES), 100),
        "precisions": (F.list_of(F.precision, allow_scalar=False), ["double", "quad"]),
        "threshold": (F.positive, "1e-6"),
        "dps": (F.count(MIN_DPS, MAX_MAP_DPS), 30),
    }
    docs = {
        "grid": ("[integer 1..64, integer 1..128]", "n_theta x n_phi directions of M0 on abs(M) = 1 (polar angle "
                 "from axis 3, azimuth)"),
        "T": ("positive number", "the final time"),
        "samples": ("integer 2..100000", "equally spaced output times where the state is compared"),
        "precisions": ("list of precisions", "'double', 'long double', 'quad' or bits: one ensemble run each"),
        "threshold": ("positive number", "departure: the first output time with max abs(y - y_exact) > threshold"),
        "dps": ("integer 15..1000", "digits of the closed-form reference and of the exact initial data"),
    }

    def check(self, opts, run, models, where):
        """The map integrates the free rigid body with principal inertia, Chetaev form, against its closed form."""
        for path, spec, model, _y0 in models:
            if getattr(model, "closed_form", None) != "free_rigid_body":
                raise F.SceneError(f"`studies.departure_map` needs a free rigid body: `{path}.kind` must be "
                                   f"'euler_poisson'; got {F.show(spec.kind)}")
            if model.bracket != "chetaev":
                raise F.SceneError(f"`studies.departure_map` integrates the Chetaev form: `{path}.bracket` must be "
                                   f"'chetaev'; got {F.show(model.bracket)}")
            if not model.diagonal:
                raise F.SceneError(f"`studies.departure_map` needs principal moments: `{path}.inertia` must be 3 "
                                   "numbers or a diagonal 3x3 tensor; got one with off-diagonal entries")

    def quick(self, dm):
        dm["grid"] = [min(dm["grid"][0], 3), min(dm["grid"][1], 6)]
        dm["T"] = float(to_fraction(dm["T"])) / 10
        dm["samples"] = min(dm["samples"], 20)

    def cost(self, dm, ctx, pricer):
        cells = int(dm["grid"][0]) * int(dm["grid"][1])
        samples = int(dm["samples"])
        T = to_fraction(dm["T"])
        precs = [resolve_precision(p) for p in dm["precisions"]]
        ref_dps = max(int(dm["dps"]), max(math.ceil(p.bits * math.log10(2)) for p in precs) + 10)
        pricer.heyoka_builds += len(precs)
        parts = []
        for _lab, model in ctx.built:
            inertia = tuple(model.inertia_exact[j][j] for j in range(3))
            # a generic unit M0 (the grid's cells differ in their motion, not in the work of one closed form)
            M0 = (Fraction(3, 5), Fraction(0), Fraction(4, 5))
            omega = tuple(m / i for m, i in zip(M0, inertia))
            times = [T * k / samples for k in (1, 2)]
            _, secs = pricer.timed(lambda: exact.euler_poisson_many(inertia, omega, times, dps=ref_dps), quiet=False)
            parts.append(CostPart("studies.departure_map.grid", f"{cells} cells x {samples} closed-form times at "
                                  f"{ref_dps} digits", cells * samples, "closed-form time", secs / len(times),
                                  f"timed at {ref_dps} digits"))
            body = EulerPoisson(inertia)
            y0 = body.initial_state(omega=omega)
            for p in precs:
                per, lower, basis = pricer.heyoka_run(body, y0, T, p, samples)
                drivers = "studies.departure_map.grid" + ("` and `studies.departure_map.precisions" if p.bits > 113
                                                          else "")
                parts.append(CostPart(drivers, f"{cells} members to T = {float(T):g} in {p.name}", cells, "member",
                                      per, basis, lower))
        return parts

    def run(self, opts, ctx):
        out = []
        for i, (lab, model) in enumerate(ctx.built):
            inertia = tuple(model.inertia_exact[j][j] for j in range(3))
            out.append((lab, departure_map(inertia, grid=tuple(opts["grid"]), T=opts["T"], samples=opts["samples"],
                                           precisions=opts["precisions"], threshold=opts["threshold"],
                                           dps=opts["dps"], progress=ctx.model_progress(i, lab))))
        return out

    def unsuccessful(self, items):
        out = []
        for lab, dm in items:
            for prec, statuses in dm.statuses.items():
                bad = [s for s in statuses if s != "success"]
                if bad:
                    kinds = ", ".join(f"{k} x{bad.count(k)}" for k in sorted(set(bad)))
                    out.append(f"departure map ({lab}): {len(bad)} of {len(statuses)} {prec} members: {kinds}")
        return out

    def section(self, items, ctx):
        lines, csvs = [], []
        for mlabel, m in items:
            n_theta, n_phi = m.energy_ratio.shape
            lines.append(f"**{mlabel}**: I = {tuple(m.inertia)}, R(0) = 1, initial angular momentum M0 on |M| = 1 "
                         f"over a {n_theta} x {n_phi} grid of directions (both sides of the separatrix), one ensemble "
                         "run of `ls.integrate` at tol = eps per precision, compared up to "
                         f"T = {m.T:g} with the closed form (`ls.exact.euler_poisson_many`, at least 10 digits beyond "
                         "the finest precision). Departure: the first output time where the 12-number "
                         f"state differs from it by more than {m.threshold:g} (max norm).")
            lines.append("")
            h, rows = departure_map_table(m)
            lines += [markdown_table(h, rows), ""]
            csvs.append((f"departure_map{file_tag(mlabel, len(items) > 1)}.csv", h, rows))
            lines += [departure_map_reading(m), ""]
        if ctx.plotted:
            lines += ["![departure map](departure_map.png)", ""]
        return lines, csvs

    def plot(self, items, path, scene):
        plot_departure_map(items[0][1], path)

    def summary(self, items):
        out = []
        for mlabel, m in items:
            for name, dep in m.departure.items():
                gone = int((~m.stayed[name]).sum())
                bad = sum(1 for st in m.statuses[name] if st != "success")
                out.append(f"departure map ({mlabel}, {name}): {gone} / {dep.size} departed before T = {m.T:g}, "
                           f"earliest {dep.min():.4g}, worst error {fmt_sci(float(m.max_error[name].max()))}"
                           + (f", {bad} runs not successful" if bad else ""))
        return out


register_study(DepartureMapStudy())
