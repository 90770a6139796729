"""What certified digits cost: ls.validated_integrate (Arb balls) against ls.lie_integrate (mpmath), one process.

1. Taylor coefficients of one step, rigid body I = (1, 2, 3), omega0 = (1, 0.1, 0.5), order 59 (the order both
   engines use at 50 digits): Picard iteration on Arb power series (balls, 50 digits and 32 guard bits) against
   the centre polynomial both engines now take from the fixed-point jets (``centre_coefficients``: the jets and
   their exact conversion to Arb), median of repeated calls.
2. The whole run to T = 10 at 50 digits (``--pairs`` alternated pairs, the ratio of each pair: other jobs on the
   machine slow both calls of a pair alike): wall time of both, their steps, the validated run's certified digits and
   its widest final ball, and lie_integrate's actual error against the closed form (80 digits).
3. How tight one step's remainder bound is: a single step of order 59 at 40 digits to t = h, its bound on the
   centre's solution minus the Taylor polynomial (``stats.extra["tail_bounds"]``) against the true difference
   (closed form minus the order-59 polynomial, both at 90 digits).

    .venv/bin/python benchmarks/validated_vs_lie.py [--T 10] [--dps 50] [--repeat 5] [--pairs 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import mpmath as mp

import lieseries as ls
from lieseries import exact
from lieseries.precision import to_fraction
from lieseries.validated import (
    ball_taylor_coefficients,
    centre_coefficients,
    certified_digits,
    radii,
    validated_integrate,
)

INERTIA, OMEGA = (1, 2, 3), (1, "0.1", "0.5")


def coefficient_times(dps: int, order: int, repeat: int) -> dict:
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    arb_t, jet_t = [], []
    for _ in range(repeat):
        tic = time.perf_counter()
        ball_taylor_coefficients(body, y0, order, dps)
        arb_t.append(time.perf_counter() - tic)
        tic = time.perf_counter()
        centre_coefficients(body, y0, order, dps, step="0.34")
        jet_t.append(time.perf_counter() - tic)
    return {"arb_picard_ms": 1e3 * statistics.median(arb_t), "fixed_jets_ms": 1e3 * statistics.median(jet_t)}


def whole_runs(T, dps: int, pairs: int = 3) -> dict:
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    ls.lie_integrate(body, y0, t=1, dps=dps)  # warm-up: compiled programs, jet plans
    validated_integrate(body, y0, t=1, dps=dps)
    ratios, t_lies, t_vals = [], [], []
    for _ in range(pairs):
        tic = time.perf_counter()
        lie = ls.lie_integrate(body, y0, t=T, dps=dps)
        t_lie = time.perf_counter() - tic
        tic = time.perf_counter()
        val = validated_integrate(body, y0, t=T, dps=dps)
        t_val = time.perf_counter() - tic
        ratios.append(t_val / t_lie)
        t_lies.append(t_lie)
        t_vals.append(t_val)
    t_lie, t_val = statistics.median(t_lies), statistics.median(t_vals)
    ref = exact.euler_poisson(INERTIA, OMEGA, T, dps=dps + 30)
    with mp.workdps(dps + 30):
        err = max(abs(mp.mpf(to_fraction(a).numerator) / to_fraction(a).denominator - b)
                  for a, b in zip(lie.y[-1], ref))
    return {
        "lie_s": t_lie, "validated_s": t_val, "ratio": statistics.median(ratios), "ratio_min": min(ratios),
        "ratio_max": max(ratios), "lie_steps": lie.stats.steps,
        "validated_steps": val.stats.steps, "validated_status": val.status,
        "certified_digits": float(certified_digits(val)[-1]), "widest_final_ball": float(max(radii(val)[-1])),
        "lie_error": float(err),
    }


def remainder_tightness(hs=("2/5", "9/20", "1/2"), order: int = 59, dps: int = 40) -> dict:
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    ctx = mp.MPContext()
    ctx.dps = 90
    coeffs = ls.lie.taylor_coefficients(body.poisson.program, list(y0.exact), list(body.poisson.parameter_values),
                                        order, 90, ctx=ctx)
    out = {}
    for h in hs:
        sol = validated_integrate(body, y0, t=h, dps=dps, order=order)
        assert sol.stats.steps == 1, "t must lie below the step the run chooses"
        q = to_fraction(h)
        hq = ctx.mpf(q.numerator) / q.denominator
        ref = exact.euler_poisson(INERTIA, OMEGA, h, dps=90)
        true = max(abs(ctx.mpf(r) - sum(c[i] * hq**k for k, c in enumerate(coeffs))) for i, r in enumerate(ref))
        out[h] = (sol.stats.extra["tail_bounds"][0], float(true))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--T", default="10")
    ap.add_argument("--dps", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--pairs", type=int, default=3, help="alternated lie / validated pairs (default 3)")
    args = ap.parse_args(argv)
    order = max(8, int(mp.ceil(mp.log(10) * args.dps / 2)) + 1)
    co = coefficient_times(args.dps, order, args.repeat)
    print(f"Taylor coefficients, order {order}, {args.dps} digits: Arb Picard iteration "
          f"{co['arb_picard_ms']:.1f} ms, fixed-point jets into Arb {co['fixed_jets_ms']:.1f} ms "
          f"(Arb / jets = {co['arb_picard_ms'] / co['fixed_jets_ms']:.2f})")
    run = whole_runs(args.T, args.dps, args.pairs)
    print(f"T = {args.T}, {args.dps} digits: lie_integrate {run['lie_s']:.2f} s ({run['lie_steps']} steps, error "
          f"{run['lie_error']:.1e}), validated_integrate {run['validated_s']:.2f} s ({run['validated_steps']} "
          f"steps, {run['validated_status']}, {run['certified_digits']:.1f} certified digits, widest final ball "
          f"{run['widest_final_ball']:.1e})")
    print(f"validated / lie = {run['ratio_min']:.2f} - {run['ratio_max']:.2f}x (median {run['ratio']:.2f}, "
          f"{args.pairs} alternated pairs; target <= 2)")
    tight = remainder_tightness()
    for h, (bound, true) in tight.items():
        print(f"one step to t = {h} (order 59, 40 digits): remainder bound {bound:.2e}, true {true:.2e}, "
              f"bound / true = {bound / true:.2f}")
    return {**co, **run, "remainder": tight}


if __name__ == "__main__":
    main()
