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
from ..models.euler_poisson import EulerPoisson
from ..precision import check_count, resolve_precision, to_fraction
from ..precision import thread_mp as mp
from ..taylor import integrate

__all__ = ["DepartureMap", "departure_map"]


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
    if not (isinstance(grid, (tuple, list)) and len(grid) == 2):
        raise ValueError(f"`grid` must be (n_theta, n_phi); got {grid!r}")
    n_theta = check_count(grid[0], "grid[0]", high=64)
    n_phi = check_count(grid[1], "grid[1]", high=128)
    samples = check_count(samples, "samples", low=2, high=100_000)
    Tf = to_fraction(T, "T")
    if Tf <= 0:
        raise ValueError(f"`T` must be positive; got {float(Tf)}")
    thr = to_fraction(threshold, "threshold")
    if thr <= 0:
        raise ValueError(f"`threshold` must be positive; got {float(thr)}")
    precs = [resolve_precision(p, "precisions") for p in precisions]
    if not precs:
        raise ValueError("`precisions` must name at least one precision ('double', 'long double', 'quad', bits)")
    dps = check_count(dps, "dps", low=15, high=1000)
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
        dep = np.empty(len(omegas))
        worst = np.empty(len(omegas))
        stayed = np.zeros(len(omegas), dtype=bool)
        statuses = [str(s) for s in sol.status]
        for k in range(len(omegas)):
            member = sol.member(k)
            dep[k], worst[k] = _first_departure(member, refs[k], times, thr, ref_dps)
            stayed[k] = member.success and dep[k] == math.inf
            if dep[k] == math.inf:
                dep[k] = float(Tf)
        step(f"{prec.name}: {len(omegas)} members")
        result.departure[prec.name] = dep.reshape(n_theta, n_phi)
        result.stayed[prec.name] = stayed.reshape(n_theta, n_phi)
        result.max_error[prec.name] = worst.reshape(n_theta, n_phi)
        result.statuses[prec.name] = statuses
        # the ensemble's clock includes compiling the integrator (build_time); the map reports the integration
        result.run_time[prec.name] = max(0.0, float(sol.stats["run_time"]) - float(sol.stats["build_time"]))
    return result


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
