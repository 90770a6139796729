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

from ..models.base import state_fractions
from ..poisson import as_poisson_system
from ..precision import check_count, resolve_precision, to_fraction
from .reference import loglog_slope

__all__ = [
    "Drift", "drift", "growth_exponent", "invariant_function"]


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
    Casimirs) at ``dps`` digits. Both read a state built from exact input at its exact values."""
    ps = as_poisson_system(system)
    if system is ps or not hasattr(system, "invariants"):

        def inv(y):
            return ps.invariants(y, dps)

        return inv
    return system.invariants


def _perturbable(system, n: int) -> set:
    """Indices of the state that ensemble members perturb: the momentum M of a rigid body (a perturbed R would
    no longer be a rotation, and R^T R is conserved only on the rotation group); every entry otherwise."""
    from ..models.euler_poisson import EulerPoisson

    if isinstance(system, EulerPoisson):
        return {9, 10, 11}
    return set(range(n))


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
    from ..taylor import integrate

    prec = resolve_precision(precision)
    tf = to_fraction(t, "t")
    if tf <= 0:
        raise ValueError(f"`t` must be a positive final time; got {float(tf)}")
    samples = check_count(samples, "samples", low=6, high=100_000)
    ensemble = check_count(ensemble, "ensemble", low=1, high=1000)
    seed = check_count(seed, "seed", low=0)
    pert = to_fraction(perturbation, "perturbation")
    if not pert > 0:
        raise ValueError(f"`perturbation` must be a positive number; got {perturbation!r}")
    perturbation = float(pert)
    ps = as_poisson_system(system)
    z0 = state_fractions(y0, ps.dimension, "y0")
    t_first = to_fraction(first, "first") if first is not None else tf / 1000
    if not (0 < t_first < tf):
        raise ValueError(f"`first` must lie in (0, t); got {float(t_first)}")
    grid = [Fraction(v).limit_denominator(2**40) for v in np.geomspace(float(t_first), float(tf), int(samples))]
    grid[-1] = tf
    grid = sorted(set(grid))
    inv_fn = invariant_function(system, prec.dps + 10)
    free = _perturbable(system, ps.dimension)
    rng = np.random.default_rng(seed)
    scale_y = max(abs(float(v)) for v in z0) or 1.0
    sq = None
    total_steps = order = 0
    run_time = 0.0
    status, message = "success", ""
    initial = None
    n_done = len(grid)
    for member in range(int(ensemble)):
        if progress:
            progress(member, int(ensemble), f"run {member + 1}/{ensemble}")
        if member == 0:
            zm = z0
        else:
            kick = rng.standard_normal(len(z0)) * perturbation * scale_y
            zm = [q + Fraction(float(k)) if i in free else q for i, (q, k) in enumerate(zip(z0, kick))]
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
            inv = inv_fn(sol.y)
            for k in sq:
                d = np.array([float(abs(v - inv0[k])) for v in inv[k]])
                sq[k][: len(d)] += d**2
    if progress:
        progress(int(ensemble), int(ensemble), "done")
    n = n_done
    times = [float(v) for v in grid[:n]]
    # steps are nearly uniform in time: cumulative steps ~ total steps x t / (time reached)
    steps = [total_steps * tk / t_reached if t_reached > 0 else 0.0 for tk in times]
    errors = {k: [math.sqrt(v / ensemble) for v in sq[k][:n]] for k in sq}
    eps = prec.eps
    scales = {k: (abs(v) if v != 0 else 1.0) for k, v in initial.items()}
    brouwer = {k: [eps * math.sqrt(s) * scales[k] for s in steps] for k in errors}
    exponents = {k: growth_exponent(steps, errors[k]) for k in errors}
    tol_used = float(tol) if tol is not None else eps
    return Drift(
        times=times, steps=steps, errors=errors, initial=initial, brouwer=brouwer, exponents=exponents,
        precision=prec.name, eps=eps, tol=tol_used, total_steps=total_steps, order=order, run_time=run_time,
        ensemble=int(ensemble), status=status, message=message, system=ps.name, scales=scales,
    )
