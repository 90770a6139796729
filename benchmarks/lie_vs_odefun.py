"""Rigid body to T = 10 at 50 and 100 digits: ls.lie_integrate vs mpmath.odefun vs heyoka (same bits), one run.

All three are run to the same final accuracy (their error against the closed-form solution is printed beside the
time), timed in this one run; the ratios are what counts.

    .venv/bin/python benchmarks/lie_vs_odefun.py            # T = 10 (odefun takes minutes at 100 digits)
    .venv/bin/python benchmarks/lie_vs_odefun.py --quick    # T = 2
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


def main(T=10, digits=(50, 100)):
    body = ls.EulerPoisson((1, 2, 3))
    rows = []
    for dps in digits:
        ref = exact.euler_poisson((1, 2, 3), OMEGA, T, dps=dps + 20)
        y0 = body.initial_state(OMEGA, precision=dps_to_bits(dps) + 64)

        t0 = time.perf_counter()
        sol = ls.lie_integrate(body, y0, t=T, dps=dps)
        t_lie = time.perf_counter() - t0
        e_lie = err(sol.y[-1], ref, dps)

        bits = dps_to_bits(dps)
        yb = body.initial_state(OMEGA, precision=bits)
        ls.integrate(body, yb, t=T, precision=bits)  # build (compile) once, outside the timing
        t0 = time.perf_counter()
        hs = ls.integrate(body, yb, t=T, precision=bits)
        t_hey = time.perf_counter() - t0
        e_hey = err(hs.y[-1], ref, dps)

        with mp.workdps(dps):
            z0 = [mp.mpf(v) for v in (1, 0, 0, 0, 1, 0, 0, 0, 1)] + [mp.mpf(1), 2 * mp.mpf("0.1"), 3 * mp.mpf("0.5")]
            t0 = time.perf_counter()
            f = mp.odefun(rhs, 0, z0)
            yo = f(T)
            t_ode = time.perf_counter() - t0
        e_ode = err(yo, ref, dps)
        rows.append((dps, t_lie, e_lie, sol.stats.steps, sol.stats.order, t_ode, e_ode, t_hey, e_hey, hs.stats.steps))
        print(f"{dps} digits, T = {T}:")
        print(f"  lie_integrate  {t_lie:9.3f} s  error {mp.nstr(e_lie, 3):>9}  ({sol.stats.steps} steps, order "
              f"{sol.stats.order})")
        print(f"  mpmath.odefun  {t_ode:9.3f} s  error {mp.nstr(e_ode, 3):>9}")
        print(f"  heyoka {bits} bits {t_hey:7.4f} s  error {mp.nstr(e_hey, 3):>9}  ({hs.stats.steps} steps, order "
              f"{hs.stats.order}; compiled beforehand)")
        print(f"  odefun / lie_integrate = {t_ode / t_lie:.1f}x (target >= 20x);  "
              f"lie_integrate / heyoka = {t_lie / t_hey:.0f}x")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="T = 2 instead of 10")
    args = ap.parse_args()
    main(T=2 if args.quick else 10)
