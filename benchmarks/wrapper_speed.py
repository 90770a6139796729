"""``ls.integrate`` against the bare heyoka integrator it runs, at several time spans and on an output grid.

Rigid body I = (1, 2, 3), omega0 = (1, 0.1, 0.5), R(0) = 1, double, tol = eps. For each span T the wrapped call
(``ls.integrate(body, y0, t=T)``, every guard on) and the bare integrator (the same compiled heyoka object, time,
state and parameters reset, one ``propagate_until(T)``) alternate in this one process; the figure is the median
of each (the 2-core machine is shared and noisy: the pairs see the same load), in wall time and in the thread's
CPU time. Both give the same number of steps and bit-identical final states (checked).

Grid: ``ls.integrate(body, y0, t=grid)`` with ``grid`` = 200 output times in [0, T] against bare heyoka's
``propagate_grid`` over the same times (the rows checked against each other).

    .venv/bin/python benchmarks/wrapper_speed.py [--pairs N] [--rounds R]
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

import lieseries as ls
from lieseries.taylor import build_integrator

SPANS = (1.0, 5.0, 15.0, 100.0)
GRID_SPANS = (15.0, 100.0)
GRID_POINTS = 200


def _setup():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    ta = copy.deepcopy(build_integrator(body, "double")[0])
    y0n = np.asarray(y0, dtype=float)
    pars = np.asarray(body.poisson.native_parameters(ls.resolve_precision("double")), dtype=float)
    return body, y0, ta, y0n, pars


def _pairs(fa, fb, pairs):
    """Median over alternated pairs of (time of fa) / (time of fb), and the two medians in microseconds: wall
    time, and the thread's CPU time (what the call itself costs when the shared cores are oversubscribed)."""
    wall = {fa: [], fb: []}
    cpu = {fa: [], fb: []}
    for i in range(pairs):
        for fn in ((fa, fb) if i % 2 == 0 else (fb, fa)):
            c0, w0 = time.thread_time(), time.perf_counter()
            fn()
            w1, c1 = time.perf_counter(), time.thread_time()
            wall[fn].append(w1 - w0)
            cpu[fn].append(c1 - c0)
    out = []
    for d in (wall, cpu):
        ra, rb = np.asarray(d[fa]), np.asarray(d[fb])
        out.append((float(np.median(ra) / np.median(rb)), float(np.median(ra)) * 1e6, float(np.median(rb)) * 1e6))
    return out


def spans(pairs: int = 3000) -> dict:
    body, y0, ta, y0n, pars = _setup()
    out = {}
    for T in SPANS:
        def bare(T=T):
            ta.time = 0.0
            ta.state[:] = y0n
            ta.pars[:] = pars
            return ta.propagate_until(T)

        def wrapped(T=T):
            return ls.integrate(body, y0, t=T)

        sol = wrapped()
        res = bare()
        assert sol.success and sol.stats.steps == int(res[3]), (sol.stats.steps, res[3])
        assert np.array_equal(sol.y[-1], ta.state), "the wrapper's state differs from bare heyoka's"
        for _ in range(200):  # warm up
            bare(), wrapped()
        (ratio, us_w, us_b), (cratio, cus_w, cus_b) = _pairs(wrapped, bare, pairs)
        out[T] = (ratio, cratio)
        print(f"T = {T:>5g} ({sol.stats.steps:4d} steps): ls.integrate {us_w:7.1f} us, bare heyoka {us_b:7.1f} us, "
              f"ratio {ratio:.2f} (CPU time: {cus_w:.1f} / {cus_b:.1f} us = {cratio:.2f})")
    return out


def grid(pairs: int = 1000) -> dict:
    body, y0, ta, y0n, pars = _setup()
    out = {}
    for T in GRID_SPANS:
        g = np.linspace(0.0, T, GRID_POINTS)

        def bare(g=g):
            ta.time = 0.0
            ta.state[:] = y0n
            ta.pars[:] = pars
            return ta.propagate_grid(g)

        def wrapped(g=g):
            return ls.integrate(body, y0, t=g)

        sol = wrapped()
        res = bare()
        assert sol.success and len(sol.y) == GRID_POINTS
        err = float(np.max(np.abs(sol.y - res[-1])))
        assert err < 1e-13, err
        for _ in range(50):
            bare(), wrapped()
        (ratio, us_w, us_b), (cratio, cus_w, cus_b) = _pairs(wrapped, bare, pairs)
        out[T] = (ratio, cratio)
        print(f"grid of {GRID_POINTS} times to T = {T:>5g} ({sol.stats.steps:4d} steps): ls.integrate {us_w:7.1f} us, "
              f"bare propagate_grid {us_b:7.1f} us, ratio {ratio:.2f} (CPU time: {cratio:.2f}; rows agree to "
              f"{err:.1e})")
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=3000)
    ap.add_argument("--rounds", type=int, default=1)
    args = ap.parse_args(argv)
    res = {}
    for r in range(args.rounds):
        print(f"-- round {r + 1}: final time (targets: <= 1.5 at T = 1, <= 1.1 at T = 15 and T = 100)")
        res["spans"] = spans(args.pairs)
        print(f"-- round {r + 1}: output grid")
        res["grid"] = grid(max(100, args.pairs // 3))
    return res


if __name__ == "__main__":
    main()
