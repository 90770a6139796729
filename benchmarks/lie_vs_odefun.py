"""Rigid body to T = 10 at 50 and 100 digits: ls.lie_integrate vs mpmath.odefun vs heyoka (same bits), one run.

All three are run to the same final accuracy (their error against the closed-form solution is printed beside the
time), timed in this one run; the ratios are what counts.

    .venv/bin/python benchmarks/lie_vs_odefun.py            # T = 10 (odefun takes minutes at 100 digits)
    .venv/bin/python benchmarks/lie_vs_odefun.py --quick    # T = 2
    .venv/bin/python benchmarks/lie_vs_odefun.py --T 2 --digits 50 --clock cpu   # CPU time (a shared machine)

lie_integrate and heyoka are called once before they are timed (compiled programs, jet plans, heyoka's JIT).
"""

from __future__ import annotations

import argparse
import time

import mpmath as mp

import lieseries as ls
from lieseries import exact
from lieseries.precision import dps_to_bits, to_fraction

OMEGA = (1, "0.1", "0.5")


def rhs(t, z):
    """The Euler-Poisson equations by hand in mpmath arithmetic (odefun's right-hand side)."""
    R, M = z[:9], z[9:]
    om = [M[0], M[1] / 2, M[2] / 3]
    out = []
    for i in range(3):
        r = R[3 * i: 3 * i + 3]
        out += [r[1] * om[2] - r[2] * om[1], r[2] * om[0] - r[0] * om[2], r[0] * om[1] - r[1] * om[0]]
    out += [M[1] * om[2] - M[2] * om[1], M[2] * om[0] - M[0] * om[2], M[0] * om[1] - M[1] * om[0]]
    return out


def err(state, ref, dps):
    with mp.workdps(dps + 20):
        return max(abs(mp.mpf(to_fraction(a).numerator) / to_fraction(a).denominator - b) for a, b in zip(state, ref))


def main(T=10, digits=(50, 100), clock=time.perf_counter):
    body = ls.EulerPoisson((1, 2, 3))
    rows = []
    for dps in digits:
        ref = exact.euler_poisson((1, 2, 3), OMEGA, T, dps=dps + 20)
        y0 = body.initial_state(OMEGA, precision=dps_to_bits(dps) + 64)

        ls.lie_integrate(body, y0, t=T, dps=dps)  # warm-up
        t0 = clock()
        sol = ls.lie_integrate(body, y0, t=T, dps=dps)
        t_lie = clock() - t0
        e_lie = err(sol.y[-1], ref, dps)

        bits = dps_to_bits(dps)
        yb = body.initial_state(OMEGA, precision=bits)
        ls.integrate(body, yb, t=T, precision=bits)  # build (compile) once, outside the timing
        t0 = clock()
        hs = ls.integrate(body, yb, t=T, precision=bits)
        t_hey = clock() - t0
        e_hey = err(hs.y[-1], ref, dps)

        with mp.workdps(dps):
            z0 = [mp.mpf(v) for v in (1, 0, 0, 0, 1, 0, 0, 0, 1)] + [mp.mpf(1), 2 * mp.mpf("0.1"), 3 * mp.mpf("0.5")]
            t0 = clock()
            f = mp.odefun(rhs, 0, z0)
            yo = f(T)
            t_ode = clock() - t0
        e_ode = err(yo, ref, dps)
        rows.append((dps, t_lie, e_lie, sol.stats.steps, sol.stats.order, t_ode, e_ode, t_hey, e_hey, hs.stats.steps))
        print(f"{dps} digits, T = {T}:")
        print(f"  lie_integrate  {t_lie:9.3f} s  error {mp.nstr(e_lie, 3):>9}  ({sol.stats.steps} steps, order "
              f"{sol.stats.order})")
        print(f"  mpmath.odefun  {t_ode:9.3f} s  error {mp.nstr(e_ode, 3):>9}")
        print(f"  heyoka {bits} bits {t_hey:7.4f} s  error {mp.nstr(e_hey, 3):>9}  ({hs.stats.steps} steps, order "
              f"{hs.stats.order}; compiled beforehand)")
        print(f"  odefun / lie_integrate = {t_ode / t_lie:.1f}x (target >= 100x at 50 digits);  "
              f"lie_integrate / heyoka = {t_lie / t_hey:.0f}x")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="T = 2 instead of 10")
    ap.add_argument("--T", type=float, default=None, help="end time (default 10)")
    ap.add_argument("--digits", type=int, nargs="+", default=[50, 100])
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="wall time, or the process's CPU time (less sensitive to other jobs on the machine)")
    args = ap.parse_args()
    T = args.T if args.T is not None else (2 if args.quick else 10)
    main(T=T, digits=args.digits, clock=time.perf_counter if args.clock == "wall" else time.process_time)
