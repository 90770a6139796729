"""ls.lie_integrate at orders N = JZ + c above the Jorba-Zou order JZ = ceil(-ln(tol) / 2) + 1: time and error.

The data behind the automatic order's offset (module docstring of ``lieseries/lie/integrator.py``): for each
precision, the runs at every offset ``c`` alternate in one process (``--reps`` rounds after one warm-up call each,
the order of a round alternating), on the process's CPU time by default; each line gives the steps, the median time,
its ratio to the Jorba-Zou order's (c = 0) and the final error against the closed form (``ls.exact``, at 20 more
digits), which must not grow beyond the tolerance: never fewer digits for a faster run. ``(auto)`` marks the offset
the automatic order takes.

    .venv/bin/python benchmarks/lie_order.py                                  # rigid body to T = 40
    .venv/bin/python benchmarks/lie_order.py --system sphere --T 10 --digits 30 50 100 200
    .venv/bin/python benchmarks/lie_order.py --digits 50 --offsets 0 8 14 16 24 --reps 5 --T 10
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import mpmath as mp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import lieseries as ls  # noqa: E402
from lieseries import exact  # noqa: E402
from lieseries.lie.integrator import default_order, jorba_zou_order  # noqa: E402
from lieseries.precision import to_fraction  # noqa: E402

OMEGA = (1, "0.1", "0.5")
X0, V0 = ("0.6", "0", "0.8"), ("0", "1", "0")  # a great circle through the poles (charts change on the way)


def _mpf(x):
    q = to_fraction(x)
    return mp.mpf(q.numerator) / q.denominator


def rigid(dps, N, T):
    """(run, error of a run's end state) for the rigid body I = (1, 2, 3), omega0 = (1, 0.1, 0.5)."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(OMEGA)

    def error(sol):
        ref = exact.euler_poisson((1, 2, 3), OMEGA, T, dps=dps + 20)
        with mp.workdps(dps + 20):
            return max(abs(_mpf(a) - b) for a, b in zip(sol.y[-1], ref))

    return (lambda: ls.lie_integrate(body, y0, t=T, dps=dps, order=N)), error


def sphere(dps, N, T):
    """(run, error of a run's end state: position and velocity) for the free particle on the unit sphere."""
    s = ls.Sphere()
    y0 = s.initial_state(X0, V0)

    def error(sol):
        xe, ve = exact.sphere(1, X0, V0, T, dps=dps + 20)
        x = s.position(sol.y[-1], chart=sol.charts[-1])
        v = s.velocity(sol.y[-1], chart=sol.charts[-1])
        with mp.workdps(dps + 20):
            return max(abs(_mpf(a) - b) for a, b in zip(list(x) + list(v), list(xe) + list(ve)))

    return (lambda: ls.lie_integrate(s, y0, t=T, dps=dps, order=N)), error


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--system", choices=["rigid", "sphere"], default="rigid")
    ap.add_argument("--T", type=float, default=40)
    ap.add_argument("--digits", type=int, nargs="+", default=[30, 50, 100, 200])
    ap.add_argument("--offsets", type=int, nargs="+", default=[0, 8, 16, 24, 32, 48])
    ap.add_argument("--reps", type=int, default=3, help="alternated rounds per precision (default 3)")
    ap.add_argument("--clock", choices=["wall", "cpu"], default="cpu")
    args = ap.parse_args(argv)
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    make = {"rigid": rigid, "sphere": sphere}[args.system]
    offsets = sorted(set(args.offsets) | {0})
    for dps in args.digits:
        tol = mp.mpf(10) ** -dps
        jz = jorba_zou_order(tol)
        auto = default_order(tol) - jz
        runs = {}
        for c in offsets:
            run, error = make(dps, jz + c, args.T)
            sol = run()  # warm-up
            runs[c] = (run, sol.stats.steps, error(sol))
        times = {c: [] for c in offsets}
        for r in range(args.reps):
            for c in (offsets if r % 2 == 0 else offsets[::-1]):
                t0 = clock()
                runs[c][0]()
                times[c].append(clock() - t0)
        base = statistics.median(times[0])
        with open("/proc/loadavg") as f:
            load = f.read().split()[0]
        print(f"{args.system} to T = {args.T}, {dps} digits, Jorba-Zou order {jz}, automatic offset {auto}; "
              f"{args.clock} clock, load {load}")
        for c in offsets:
            m = statistics.median(times[c])
            print(f"  N = JZ + {c:<3d}= {jz + c:4d}  {runs[c][1]:4d} steps  {m * 1e3:9.1f} ms  {m / base:6.3f}  "
                  f"error {mp.nstr(runs[c][2], 3):>9}{'  (auto)' if c == auto else ''}", flush=True)


if __name__ == "__main__":
    main()
