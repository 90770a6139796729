"""What the lieseries wrapper costs on a short run, against the bare heyoka integrator it wraps and scipy DOP853.

Rigid body I = (1, 2, 3), omega0 = (1, 0.1, 0.5), R(0) = 1, T = 20, double, tol = eps. All three are timed in
this one process as the median of many calls (``ls.integrate`` and bare heyoka alternating, DOP853 in a block
of its own after them); the ratios are what counts (the machine is shared).

- ``ls.integrate``: every guarantee on (exact input rounded once, status, last finite state, stiffness and
  budget checks between chunks, the energy check of a successful run);
- bare heyoka: the same compiled integrator, time/state/parameters reset, one ``propagate_until``;
- scipy ``solve_ivp(DOP853)`` at rtol = atol = 1e-13 (final error ~1e-12, against heyoka's ~1e-15).

    .venv/bin/python benchmarks/overhead.py [--calls N]
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
from scipy.integrate import solve_ivp

import lieseries as ls
from lieseries.taylor import build_integrator
from taylor_vs_scipy import T, rhs  # the same body, span and right-hand side as the accuracy benchmark


def main(calls: int = 2000) -> dict:
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    assert ls.integrate(body, y0, t=T).success
    ta = copy.deepcopy(build_integrator(body, "double")[0])
    y0n = np.asarray(y0, dtype=float)
    pars = np.asarray(body.poisson.native_parameters(ls.resolve_precision("double")), dtype=float)

    def bare():
        ta.time = 0.0
        ta.state[:] = y0n
        ta.pars[:] = pars
        return ta.propagate_until(T)

    def wrapped():
        return ls.integrate(body, y0, t=T)

    def dop853():
        return solve_ivp(rhs, (0.0, T), y0n, method="DOP853", rtol=1e-13, atol=1e-13)

    times = {"bare": [], "integrate": [], "dop853": []}
    # the two heyoka calls alternate, so that both see the same machine state; DOP853 (~500x slower, and heavy on
    # the Python heap and caches) is timed in its own block, so that it does not sit between them
    for _ in range(calls):
        for name, fn in (("bare", bare), ("integrate", wrapped)):
            tic = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - tic)
    for _ in range(max(5, calls // 20)):
        tic = time.perf_counter()
        dop853()
        times["dop853"].append(time.perf_counter() - tic)
    med = {k: float(np.median(v)) for k, v in times.items()}
    out = {
        "median_ms": {k: v * 1e3 for k, v in med.items()},
        "integrate_over_bare": med["integrate"] / med["bare"],
        "dop853_over_integrate": med["dop853"] / med["integrate"],
        "dop853_over_bare": med["dop853"] / med["bare"],
    }
    print(f"median per call: ls.integrate {out['median_ms']['integrate']:.3f} ms, bare heyoka "
          f"{out['median_ms']['bare']:.3f} ms, DOP853 {out['median_ms']['dop853']:.2f} ms")
    print(f"ls.integrate / bare heyoka = {out['integrate_over_bare']:.2f}  (target <= 1.3)")
    print(f"DOP853 / ls.integrate = {out['dop853_over_integrate']:.0f}x   DOP853 / bare heyoka = "
          f"{out['dop853_over_bare']:.0f}x")
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000)
    main(ap.parse_args().calls)
