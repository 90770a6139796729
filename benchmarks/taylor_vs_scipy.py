"""Rigid body to T = 20: ls.integrate (heyoka, double) against scipy's DOP853 at equal final accuracy.

Both runs must reach a final error <= 1e-12 against a 256-bit heyoka reference; the tolerances are tightened
until they do. Run times are the best of several repetitions, measured in this one run; the ratio is what
counts (the machine is shared and noisy). Build (compile) time is reported apart, with the time of a second
build of the same integrator (served by the cache).

    .venv/bin/python benchmarks/taylor_vs_scipy.py
"""

from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp

import lieseries as ls
from lieseries.precision import to_fraction
from lieseries.taylor import build_integrator, clear_cache

T = 20.0
TARGET = 1e-12
INERTIA = np.array([1.0, 2.0, 3.0])


def rhs(t, z):
    R = z[:9].reshape(3, 3)
    M = z[9:]
    om = M / INERTIA
    hat = np.array([[0.0, -om[2], om[1]], [om[2], 0.0, -om[0]], [-om[1], om[0], 0.0]])
    return np.concatenate([(R @ hat).ravel(), np.cross(M, om)])


def best_of(fn, repeat):
    best = float("inf")
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(repeat: int = 7) -> dict:
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state((1, "0.1", "0.5"))
    ref = ls.integrate(body, y0, t=T, precision=256, tol=2.0**-240)
    yref = np.array([float(to_fraction(v)) for v in ref.y[-1]])

    clear_cache()
    t0 = time.perf_counter()
    build_integrator(body, "double", None)
    first_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    build_integrator(body, "double", None)
    second_build = time.perf_counter() - t0

    ls_time, sol = best_of(lambda: ls.integrate(body, y0, t=T), repeat)
    ls_err = float(np.max(np.abs(sol.y[-1] - yref)))

    rtol = 1e-10
    while True:
        sp_time, res = best_of(lambda: solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=rtol, atol=rtol), 1)
        sp_err = float(np.max(np.abs(res.y[:, -1] - yref)))
        if sp_err <= TARGET or rtol < 1e-15:
            break
        rtol /= 3
    sp_time, res = best_of(lambda: solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=rtol, atol=rtol), 3)

    out = {
        "lieseries_run_s": ls_time,
        "lieseries_heyoka_only_s": sol.stats.run_time,
        "lieseries_error": ls_err,
        "lieseries_steps": sol.stats.steps,
        "scipy_run_s": sp_time,
        "scipy_error": sp_err,
        "scipy_rtol": rtol,
        "scipy_steps": int(res.t.size - 1),
        "speedup": sp_time / ls_time,
        "first_build_s": first_build,
        "second_build_s": second_build,
    }
    print(f"rigid body I = (1, 2, 3), omega0 = (1, 0.1, 0.5), T = {T}, target final error <= {TARGET:g}")
    print(f"  lieseries (heyoka, double): {ls_time * 1e3:8.3f} ms per call ({sol.stats.steps} steps, "
          f"error {ls_err:.2e}; heyoka alone {sol.stats.run_time * 1e3:.3f} ms)")
    print(f"  scipy DOP853 rtol={rtol:.1e}:  {sp_time * 1e3:8.3f} ms ({out['scipy_steps']} steps, error {sp_err:.2e})")
    print(f"  run-time ratio scipy / lieseries: {out['speedup']:.0f}x   (target >= 50x)")
    print(f"  build: first {first_build * 1e3:.1f} ms, second (cache) {second_build * 1e3:.3f} ms   (target < 10 ms)")
    return out


if __name__ == "__main__":
    main()
