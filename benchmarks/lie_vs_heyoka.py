"""Rigid body to T = 10: ls.lie_integrate (fixed-point jets) against heyoka's MPFR Taylor integrator, same digits.

For each precision the two calls alternate in this one process (`--reps` pairs after one warm-up call each; heyoka's
integrator is compiled in the warm-up), and the ratio of each pair is printed with its range: other processes on
the machine slow both calls of a pair alike. Both errors are measured against the closed form (ls.exact).

    .venv/bin/python benchmarks/lie_vs_heyoka.py                     # 30, 50, 100, 200 digits
    .venv/bin/python benchmarks/lie_vs_heyoka.py --digits 50 --reps 3
    LIESERIES_BIGINT=int .venv/bin/python benchmarks/lie_vs_heyoka.py  # Python ints instead of gmpy2
    .venv/bin/python benchmarks/lie_vs_heyoka.py --clock cpu         # the process's CPU time (a shared machine)
"""

from __future__ import annotations

import argparse
import statistics
import time

import mpmath as mp

import lieseries as ls
from lieseries import exact
from lieseries.lie import fixed
from lieseries.precision import dps_to_bits, to_fraction

INERTIA = (1, 2, 3)
OMEGA = (1, "0.1", "0.5")


def err(state, ref, dps):
    with mp.workdps(dps + 20):
        out = mp.mpf(0)
        for a, b in zip(state, ref):
            q = to_fraction(a)
            out = max(out, abs(mp.mpf(q.numerator) / q.denominator - b))
        return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--digits", type=int, nargs="+", default=[30, 50, 100, 200])
    ap.add_argument("--reps", type=int, default=5, help="alternated pairs per precision (default 5)")
    ap.add_argument("--T", type=float, default=10)
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="wall time, or the process's CPU time (less sensitive to other jobs on the machine)")
    args = ap.parse_args(argv)
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    T = args.T
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(OMEGA)
    backend = f"{fixed.backend()} (mpmath backend {mp.libmp.BACKEND})"
    print(f"rigid body I = {INERTIA}, omega0 = {OMEGA}, T = {T}; big integers: {backend}; {args.clock} clock")
    rows = []
    for dps in args.digits:
        bits = dps_to_bits(dps)
        ref = exact.euler_poisson(INERTIA, OMEGA, T, dps=dps + 20)
        yb = body.initial_state(OMEGA, precision=bits)

        def lie():
            return ls.lie_integrate(body, y0, t=T, dps=dps)

        def hey():
            return ls.integrate(body, yb, t=T, precision=bits)

        sol, hs = lie(), hey()  # warm-up (heyoka compiles its integrator here)
        e_lie, e_hey = err(sol.y[-1], ref, dps), err(hs.y[-1], ref, dps)
        ratios, tl, th = [], [], []
        for _ in range(args.reps):
            t0 = clock()
            lie()
            t1 = clock()
            hey()
            t2 = clock()
            tl.append(t1 - t0)
            th.append(t2 - t1)
            ratios.append((t1 - t0) / (t2 - t1))
        rows.append((dps, min(ratios), statistics.median(ratios), max(ratios)))
        print(f"{dps:4d} digits: lie_integrate {statistics.median(tl):8.3f} s (error {mp.nstr(e_lie, 3)}, "
              f"{sol.stats.steps} steps, order {sol.stats.order}); heyoka {bits} bits {statistics.median(th):8.4f} s "
              f"(error {mp.nstr(e_hey, 3)}, {hs.stats.steps} steps, order {hs.stats.order})")
        print(f"      lie / heyoka = {min(ratios):.2f} - {max(ratios):.2f}x (median {statistics.median(ratios):.2f}, "
              f"{args.reps} alternated pairs)")
    return rows


if __name__ == "__main__":
    main()
