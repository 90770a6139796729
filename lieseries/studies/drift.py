"""Drift of the invariants over a long run, against Brouwer's law eps * sqrt(steps).

With a method whose truncation error is below round-off, the error of a conserved quantity is a sum of one
rounding error per step: a random walk, whose typical size grows like eps * sqrt(steps) (Brouwer's law). A
systematic (biased) error grows like eps * steps instead. The study runs heyoka once on a grid of sample times
(log-spaced, so that every decade of steps has the same weight), measures |I(t) - I(0)| for each invariant of
the model, and fits the growth exponent p in drift ~ steps^p over the second half of the samples.

One trajectory is one draw of a random walk: its exponent scatters by +-0.3 around 1/2. ``ensemble > 1`` runs
copies from initial states perturbed by ``perturbation`` (relative to the state's size) and reports the root
mean square over the ensemble, whose exponent is much steadier. The exponent is fitted to the running maximum
of the curve (the envelope), which is monotone and less noisy than the curve itself.

Cumulative steps at the sample times are estimated as total steps x t / T (the step size of a periodic motion
is nearly uniform over long runs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from .. import fields as F
from ..formatting import file_tag, fmt_num, fmt_p, fmt_sci, markdown_table, positive_or_nan, pyplot, save_figure
from ..methods.pricing import CostPart
from ..models.base import as_model, state_fractions
from ..poisson import as_poisson_system
from ..precision import (MAX_SAMPLES, check_count, check_time, check_tolerance, dps_to_bits, exact_states_read_at,
                         resolve_precision, to_fraction)
from .plugin import Study, register_study
from .reference import loglog_slope

#: Fewest samples a drift fit uses, and the largest ensemble (the API's and the scene's bounds).
MIN_SAMPLES = 6
MAX_ENSEMBLE = 1000

__all__ = [
    "Drift", "drift", "growth_exponent", "invariant_function", "growth_verdict", "DriftStudy"]


@dataclass
class Drift:
    """Invariant drift over a long run.

    Attributes
    ----------
    times : list of float           sample times (log-spaced)
    steps : list of float           estimated cumulative steps at each sample
    errors : dict name -> list      |I(t) - I(0)| at each sample (RMS over the ensemble)
    initial : dict name -> float    I(0)
    brouwer : dict name -> list     eps * sqrt(steps) * scale, scale = |I(0)| (1 when I(0) = 0)
    exponents : dict name -> float or None
        Fitted p in drift ~ steps^p over the second half of the samples.
    precision : str
    eps : float                     machine epsilon of the precision
    tol : float                     the tolerance of the run
    total_steps : int
    order : int
    run_time : float                seconds (all ensemble members)
    ensemble : int
    status : str
    message : str
    system : str
    """

    times: list
    steps: list
    errors: dict
    initial: dict
    brouwer: dict
    exponents: dict
    precision: str
    eps: float
    tol: float
    total_steps: int
    order: int = 0
    run_time: float = 0.0
    ensemble: int = 1
    status: str = "success"
    message: str = ""
    system: str = ""
    scales: dict = field(default_factory=dict)

    @property
    def invariants(self) -> list:
        """Names of the invariants, in order."""
        return list(self.errors)

    def to_dict(self) -> dict:
        return {
            "times": list(self.times),
            "steps": list(self.steps),
            "errors": {k: list(v) for k, v in self.errors.items()},
            "initial": dict(self.initial),
            "brouwer": {k: list(v) for k, v in self.brouwer.items()},
            "exponents": dict(self.exponents),
            "scales": dict(self.scales),
            "precision": self.precision,
            "eps": self.eps,
            "tol": self.tol,
            "total_steps": self.total_steps,
            "order": self.order,
            "run_time": self.run_time,
            "ensemble": self.ensemble,
            "status": self.status,
            "message": self.message,
            "system": self.system,
        }


def growth_exponent(steps, errors) -> float | None:
    """Log-log slope of the running maximum of ``errors`` against ``steps`` over the second half of the samples."""
    s = np.asarray(steps, dtype=float)
    e = np.asarray(errors, dtype=float)
    if len(s) < 6:
        return None
    env = np.maximum.accumulate(np.where(np.isfinite(e), e, 0.0))
    h = len(s) // 2
    return loglog_slope(s[h:], env[h:])


def invariant_function(system, dps: int):
    """f(state or states) -> dict name -> mpf (list of mpf for a 2-d array), from the model's ``invariants`` or,
    for a bare PoissonSystem (a ``python`` scene's model), :meth:`PoissonSystem.invariants` (H and its declared
    Casimirs) at ``dps`` digits. Both read a state built from exact input at its exact values, at ``dps`` digits
    or more (:func:`~lieseries.precision.exact_states_read_at`)."""
    ps = as_poisson_system(system)
    if system is ps or not hasattr(system, "invariants"):

        def inv(y):
            return ps.invariants(y, dps)

        return inv
    bits = dps_to_bits(dps)

    def model_inv(y):
        with exact_states_read_at(bits):
            return system.invariants(y)

    return model_inv


def _perturbable(system, n: int) -> set:
    """Indices of the state that ensemble members perturb (the model's ``perturbable``: the momentum M of a rigid
    body; every entry otherwise)."""
    return set(as_model(system).perturbable()) & set(range(n))


def drift(system, y0, t, precision="double", samples: int = 200, tol=None, *, ensemble: int = 1,
          perturbation: float = 1e-9, seed: int = 0, first=None, progress=None) -> Drift:
    """Drift of the invariants of ``system`` over a heyoka run from ``y0`` to ``t``.

    Parameters
    ----------
    system : model or PoissonSystem
        A model's ``invariants(y)`` are measured (rigid body: energy, M2, L1..L3, orthogonality, det_R; sphere:
        energy, x2, L1..L3); a bare PoissonSystem gets H and its declared Casimirs (evaluated exactly from the
        states, at the run's digits plus 10).
    y0 : sequence of n numbers
    t : number
        Final time, positive; long enough for many steps (10^4 and more).
    precision : "double" | "long double" | "quad" | int bits
    samples : int
        Number of sample times, log-spaced from t/1000 to t (6 .. 100000).
    tol : float, optional
        heyoka tolerance; default the precision's epsilon (truncation error below round-off).
    ensemble : int
        Number of runs (1 .. 1000) (the first from ``y0`` itself, the others from perturbed copies); the drift curve is
        their root mean square.
    perturbation : float
        Size of the perturbations, relative to max |y0| (rigid body: only M is perturbed, so that R stays a
        rotation).
    seed : int
        Seed of the perturbations.
    first : number, optional
        First sample time (default t / 1000).
    progress : callable, optional
        Called as ``progress(done, total, label)`` after each ensemble member.

    Returns
    -------
    Drift
    """
    from ..api import integrate

    prec = resolve_precision(precision)
    tf = check_time(t, "t", positive=True)
    samples = check_count(samples, "samples", low=MIN_SAMPLES, high=MAX_SAMPLES)
    ensemble = check_count(ensemble, "ensemble", low=1, high=MAX_ENSEMBLE)
    seed = check_count(seed, "seed", low=0)
    perturbation = _check_perturbation(perturbation)
    ps = as_poisson_system(system)
    z0 = state_fractions(y0, ps.dimension, "y0")
    grid = _sample_times(tf, first, samples)
    inv_fn = invariant_function(system, prec.dps + 10)
    starts = _member_states(z0, int(ensemble), perturbation, seed, _perturbable(system, ps.dimension))
    sq = None
    total_steps = order = 0
    run_time = 0.0
    status, message = "success", ""
    initial = None
    n_done = len(grid)
    for member, zm in enumerate(starts):
        if progress:
            progress(member, int(ensemble), f"run {member + 1}/{ensemble}")
        y_init = prec.array(zm)
        sol = integrate(system, y_init, t=grid, tol=tol, precision=prec)
        run_time += sol.stats.run_time + sol.stats.build_time
        inv0 = inv_fn(y_init)
        if member == 0:
            initial = {k: float(v) for k, v in inv0.items()}
            total_steps, order = int(sol.stats.steps), int(sol.stats.order)
            status, message = sol.status, sol.message
            t_reached = float(sol.t_reached)
            sq = {k: np.zeros(len(grid)) for k in inv0}
        n_done = min(n_done, len(sol.y))
        if len(sol.y):
            _add_squared_drift(sq, inv_fn(sol.y), inv0)
    if progress:
        progress(int(ensemble), int(ensemble), "done")
    eps = prec.eps
    times, steps, errors, scales, brouwer, exponents = _curves(grid[:n_done], total_steps, t_reached, sq, ensemble,
                                                               initial, eps)
    tol_used = float(tol) if tol is not None else eps
    return Drift(
        times=times, steps=steps, errors=errors, initial=initial, brouwer=brouwer, exponents=exponents,
        precision=prec.name, eps=eps, tol=tol_used, total_steps=total_steps, order=order, run_time=run_time,
        ensemble=int(ensemble), status=status, message=message, system=ps.name, scales=scales,
    )


def _check_perturbation(perturbation) -> float:
    """The ensemble's perturbation, relative to max |y0|: a number in (0, 1)."""
    pert = to_fraction(perturbation, "perturbation")
    if not 0 < pert < 1:
        raise ValueError(f"`perturbation` must be a number in (0, 1) (relative to max |y0|); got {perturbation!r}")
    return float(pert)


def _sample_times(tf, first, samples):
    """The sample times: log-spaced from ``first`` (default t / 1000) to t, with denominators up to 2^40, the last
    one t itself, without repeats."""
    t_first = to_fraction(first, "first") if first is not None else tf / 1000
    if not (0 < t_first < tf):
        raise ValueError(f"`first` must lie in (0, t); got {float(t_first)}")
    grid = [Fraction(v).limit_denominator(2**40) for v in np.geomspace(float(t_first), float(tf), int(samples))]
    grid[-1] = tf
    return sorted(set(grid))


def _curves(grid, total_steps, t_reached, sq, ensemble, initial, eps):
    """At the sample times every run reached (``grid``): the times, the estimated cumulative steps, each invariant's
    RMS drift over the ensemble, its scale |I(0)| (1 when I(0) = 0), Brouwer's law and the fitted exponent."""
    n = len(grid)
    times = [float(v) for v in grid]
    # steps are nearly uniform in time: cumulative steps ~ total steps x t / (time reached)
    steps = [total_steps * tk / t_reached if t_reached > 0 else 0.0 for tk in times]
    errors = {k: [math.sqrt(v / ensemble) for v in sq[k][:n]] for k in sq}
    scales = {k: (abs(v) if v != 0 else 1.0) for k, v in initial.items()}
    brouwer = {k: [eps * math.sqrt(s) * scales[k] for s in steps] for k in errors}
    exponents = {k: growth_exponent(steps, errors[k]) for k in errors}
    return times, steps, errors, scales, brouwer, exponents


def _add_squared_drift(sq, inv, inv0):
    """Add one run's squared drifts |I(t) - I(0)|^2 (``inv`` at the rows it reached) to the sums ``sq``."""
    for k in sq:
        d = np.array([float(abs(v - inv0[k])) for v in inv[k]])
        sq[k][: len(d)] += d**2


def _member_states(z0, ensemble, perturbation, seed, free):
    """The initial states of the ensemble's runs, one at a time: ``z0`` itself, then copies whose entries in
    ``free`` get a normal kick of size ``perturbation`` x max |y0| (drawn from ``seed`` as each run starts)."""
    rng = np.random.default_rng(seed)
    scale_y = max(abs(float(v)) for v in z0) or 1.0
    for member in range(ensemble):
        if member == 0:
            yield z0
        else:
            kick = rng.standard_normal(len(z0)) * perturbation * scale_y
            yield [q + Fraction(float(k)) if i in free else q for i, (q, k) in enumerate(zip(z0, kick))]


# -- the study in scenes and reports ---------------------------------------------------------------------------
def growth_verdict(p) -> str:
    """How a fitted drift exponent reads: flat, Brouwer's sqrt(steps) or linear."""
    if p is None:
        return "too few points"
    if p < 0.75:
        return "~ steps^0.5 (Brouwer)" if p > 0.25 else "flat (bounded)"
    return "~ steps^1 (linear)"


class DriftStudy(Study):
    """``[studies.drift]``: the invariants' drift over a long heyoka run, per model."""

    name = "drift"
    title = "Invariant drift"
    quick_doc = "drift over a tenth of the time, at most 60 samples and 4 ensemble members"
    fields = {
        "t": (F.time(positive=True), F.REQUIRED),
        "precision": (F.precision, "double"),
        "samples": (F.count(MIN_SAMPLES, MAX_SAMPLES), 200),
        "tol": (F.tolerance, None),
        "ensemble": (F.count(1, MAX_ENSEMBLE), 1),
        "perturbation": (F.fraction01, 1e-9),
        "seed": (F.count(0), 0),
        "first": (F.positive, None),
    }
    docs = {
        "t": ("positive number", "the final time (long: 10^4 steps and more)"),
        "precision": ("'double' | 'long double' | 'quad' | bits", "heyoka's precision"),
        "samples": ("integer 6..100000", "log-spaced sample times"),
        "tol": ("number in (0, 1)", "heyoka's tolerance (default: epsilon)"),
        "ensemble": ("integer 1..1000", "runs from perturbed copies of the initial state"),
        "perturbation": ("number in (0, 1)", "their size, relative to max |y0|"),
        "seed": ("integer >= 0", "the seed of the perturbations"),
        "first": ("positive number", "the first sample time (default t / 1000)"),
    }

    def quick(self, dr):
        dr["t"] = float(to_fraction(dr["t"])) / 10
        dr["samples"] = min(dr["samples"], 60)
        dr["ensemble"] = min(dr["ensemble"], 4)
        if dr["first"] is not None:
            dr["first"] = min(float(to_fraction(dr["first"])), dr["t"] / 100)

    def check(self, opts, run, models, where):
        try:  # what drift() refuses of fields taken together
            check_tolerance(opts["tol"], resolve_precision(opts["precision"]))
        except ValueError as err:
            raise F.SceneError(f"`studies.{self.name}`: {err}") from None
        if opts["first"] is not None and not to_fraction(opts["first"]) < to_fraction(opts["t"]):
            raise F.SceneError(f"`studies.{self.name}.first` must lie in (0, t); got {F.show(opts['first'])}")

    def cost(self, dr, ctx, pricer):
        parts = []
        pricer.heyoka_builds += 1
        for _lab, model in ctx.built:
            per, lower, basis = pricer.heyoka_run(model, ctx.initial_state(model), dr["t"], dr["precision"],
                                                  dr["samples"])
            parts.append(CostPart("studies.drift.ensemble", f"{dr['ensemble']} drift members to t = "
                                  f"{float(to_fraction(dr['t'])):g} in {dr['precision']}", dr["ensemble"], "member",
                                  per, basis, lower))
        return parts

    def run(self, opts, ctx):
        return [(lab, drift(model, ctx.initial_state(model), opts["t"], precision=opts["precision"],
                            samples=opts["samples"], tol=opts["tol"], ensemble=opts["ensemble"],
                            perturbation=float(to_fraction(opts["perturbation"])), seed=opts["seed"],
                            first=opts["first"], progress=ctx.model_progress(i, lab)))
                for i, (lab, model) in enumerate(ctx.built)]

    def unsuccessful(self, items):
        return [f"drift ({lab}): {dr.status}" for lab, dr in items if dr.status != "success"]

    def section(self, items, ctx):
        lines = ["Drift |I(t) - I(0)| of each invariant over a long heyoka run at tolerance eps (truncation error "
                 "below round-off), at log-spaced sample times. Round-off that behaves like a random walk grows "
                 "like eps sqrt(steps) (Brouwer's law); a biased error grows like eps steps. *p* is the fitted "
                 "exponent of drift ~ steps^p (log-log slope of the running maximum over the second half of the "
                 "samples).", ""]
        csvs = []
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
                             fmt_sci(dr.brouwer[name][-1] if dr.brouwer[name] else None), fmt_p(p),
                             growth_verdict(p)])
            lines += [markdown_table(h, rows), ""]
            tag = file_tag(mlabel, len(items) > 1)
            csvs.append((f"drift_summary{tag}.csv", h, rows))
            h2 = ["t", "steps"] + [f"drift {k}" for k in dr.errors]
            rows2 = [[repr(t), f"{s:.6g}"] + [repr(dr.errors[k][i]) for k in dr.errors]
                     for i, (t, s) in enumerate(zip(dr.times, dr.steps))]
            csvs.append((f"drift{tag}.csv", h2, rows2))
        if ctx.plotted:
            lines += ["![invariant drift](drift.png)", ""]
        return lines, csvs

    def plot(self, items, path, scene):
        plt = pyplot()
        n = len(items)
        fig, axes = plt.subplots(1, n, figsize=(7.5 * n, 5.5), squeeze=False)
        for j, (mlabel, dr) in enumerate(items):
            ax = axes[0][j]
            for k, name in enumerate(dr.errors):
                ax.loglog(dr.times, positive_or_nan(dr.errors[name]), linewidth=1, color=f"C{k}",
                          label=f"{name} (p = {fmt_p(dr.exponents.get(name))})")
            ref = "energy" if "energy" in dr.errors else next(iter(dr.errors), None)
            if ref is not None:
                scale = dr.scales.get(ref, 1.0)
                ax.loglog(dr.times, [dr.eps * math.sqrt(max(s, 1e-300)) * scale for s in dr.steps], "k--",
                          linewidth=1.5, label=f"Brouwer: eps sqrt(steps) |{ref}(0)|")
                ax.loglog(dr.times, [dr.eps * s * scale for s in dr.steps], color="grey", linestyle=":",
                          linewidth=1.5, label=f"linear: eps steps |{ref}(0)|")
            ax.set_xlabel(f"time t ({dr.total_steps} steps in all, ~{dr.total_steps / dr.times[-1]:.3g} per unit)"
                          if dr.times else "time t")
            ylab = "|I(t) - I(0)|" + (f", RMS over {dr.ensemble} runs" if dr.ensemble > 1 else "")
            ax.set_ylabel(ylab)
            ax.set_title(f"{mlabel}: invariant drift, heyoka {dr.precision}", fontsize=10)
            ax.legend(loc="best", fontsize=7)
            ax.grid(alpha=0.3, which="both")
        save_figure(plt, fig, path)

    def summary(self, items):
        out = []
        for mlabel, dr in items:
            p = dr.exponents.get("energy")
            energy = dr.errors.get("energy") or []
            final = fmt_sci(energy[-1]) if energy else "n/a"
            out.append(f"drift ({mlabel}): {dr.total_steps} steps, energy drift {final}, "
                       f"exponent {fmt_p(p)} ({growth_verdict(p)})")
        return out


register_study(DriftStudy())
