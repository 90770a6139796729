"""What certified digits cost: ls.validated_integrate (Arb balls) against ls.lie_integrate (mpmath), one process.

1. Taylor coefficients of one step, rigid body I = (1, 2, 3), omega0 = (1, 0.1, 0.5), order 59 (lie_integrate's
   order at 50 digits; the validated engine's default is 8 more): Picard iteration on Arb power series (balls,
   50 digits and 32 guard bits) against the centre polynomial both engines take from the fixed-point jets
   (``centre_coefficients``: the jets and their exact conversion), median of repeated calls.
2. The whole run to T = 10 at 50 digits (``--pairs`` alternated pairs, the ratio of each pair: other jobs on the
   machine slow both calls of a pair alike; ``--clock cpu`` times the process's CPU): the time of both, their steps,
   the validated run's certified digits and its widest final ball, and lie_integrate's actual error against the
   closed form (80 digits). ``--before PATH`` adds an earlier engine (a ``validated.py``, or a folder of a
   checkout's ``validated.py``, ``validated_step.py`` and ``ball_series.py``), loaded into the same process and
   alternated with the two, for before / after ratios in the same conditions.
3. How tight one step's remainder bound is: a single step of order 59 at 40 digits to t = h, its bound on the
   centre's solution minus the Taylor polynomial (``stats.extra["tail_bounds"]``) against the true difference
   (closed form minus the order-59 polynomial, both at 90 digits).

    .venv/bin/python benchmarks/validated_vs_lie.py [--T 10] [--dps 50] [--repeat 5] [--pairs 3] [--clock cpu]
        [--before ../main/lieseries/validated.py | --before FOLDER]
"""

from __future__ import annotations

import argparse
import importlib.util
import pathlib
import statistics
import sys
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


def load_before(path):
    """An earlier validated engine, loaded into this process beside the current one: ``path`` a ``validated.py``
    (its relative imports resolve in this checkout's package), or a folder holding ``validated.py`` and any of
    ``ball_series.py`` and ``validated_step.py`` of the same checkout (loaded as ``lieseries.<name>_before``, each
    importing the folder's others), e.g. from ``git show REV:lieseries/<name>.py``."""
    folder = pathlib.Path(path)
    files = {"validated": folder} if folder.is_file() else {
        name: folder / f"{name}.py" for name in ("ball_series", "validated_step", "validated")
        if (folder / f"{name}.py").exists()}
    saved = {}
    try:
        module = None
        for name, file in files.items():
            spec = importlib.util.spec_from_file_location(f"lieseries.{name}_before", file)
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module
            spec.loader.exec_module(module)
            # the later files' `from .name import ...` take this one
            saved.setdefault(name, sys.modules.get(f"lieseries.{name}"))
            sys.modules[f"lieseries.{name}"] = module
    finally:
        for name, original in saved.items():
            if original is None:
                del sys.modules[f"lieseries.{name}"]
            else:
                sys.modules[f"lieseries.{name}"] = original
    return module


def whole_runs(T, dps: int, pairs: int = 3, clock=time.perf_counter, before=None) -> dict:
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    ls.lie_integrate(body, y0, t=1, dps=dps)  # warm-up: compiled programs, jet plans
    validated_integrate(body, y0, t=1, dps=dps)
    if before is not None:
        before.validated_integrate(body, y0, t=1, dps=dps)
    ratios, t_lies, t_vals, ratios_before, t_befores = [], [], [], [], []
    for _ in range(pairs):
        tic = clock()
        lie = ls.lie_integrate(body, y0, t=T, dps=dps)
        t_lie = clock() - tic
        tic = clock()
        val = validated_integrate(body, y0, t=T, dps=dps)
        t_val = clock() - tic
        ratios.append(t_val / t_lie)
        t_lies.append(t_lie)
        t_vals.append(t_val)
        if before is not None:
            tic = clock()
            old = before.validated_integrate(body, y0, t=T, dps=dps)
            t_befores.append(clock() - tic)
            ratios_before.append(t_befores[-1] / t_lie)
    t_lie, t_val = statistics.median(t_lies), statistics.median(t_vals)
    extra = {}
    if before is not None:
        extra = {"before_s": statistics.median(t_befores), "before_ratio": statistics.median(ratios_before),
                 "before_ratio_min": min(ratios_before), "before_ratio_max": max(ratios_before),
                 "before_steps": old.stats.steps, "before_digits": float(certified_digits(old)[-1])}
    ref = exact.euler_poisson(INERTIA, OMEGA, T, dps=dps + 30)
    with mp.workdps(dps + 30):
        err = max(abs(mp.mpf(to_fraction(a).numerator) / to_fraction(a).denominator - b)
                  for a, b in zip(lie.y[-1], ref))
    return {
        "lie_s": t_lie, "validated_s": t_val, "ratio": statistics.median(ratios), "ratio_min": min(ratios),
        "ratio_max": max(ratios), "lie_steps": lie.stats.steps,
        "validated_steps": val.stats.steps, "validated_status": val.status,
        "certified_digits": float(certified_digits(val)[-1]), "widest_final_ball": float(max(radii(val)[-1])),
        "lie_error": float(err), **extra,
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
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="wall time, or the process's CPU time (a shared machine)")
    ap.add_argument("--before", default=None,
                    help="an earlier validated.py, or a folder of the validated engine's files, to alternate with "
                    "(before / after)")
    args = ap.parse_args(argv)
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    before = load_before(args.before) if args.before else None
    order = max(8, int(mp.ceil(mp.log(10) * args.dps / 2)) + 1)
    co = coefficient_times(args.dps, order, args.repeat)
    print(f"Taylor coefficients, order {order}, {args.dps} digits: Arb Picard iteration "
          f"{co['arb_picard_ms']:.1f} ms, fixed-point jets into Arb {co['fixed_jets_ms']:.1f} ms "
          f"(Arb / jets = {co['arb_picard_ms'] / co['fixed_jets_ms']:.2f})")
    run = whole_runs(args.T, args.dps, args.pairs, clock, before)
    print(f"T = {args.T}, {args.dps} digits: lie_integrate {run['lie_s']:.2f} s ({run['lie_steps']} steps, error "
          f"{run['lie_error']:.1e}), validated_integrate {run['validated_s']:.2f} s ({run['validated_steps']} "
          f"steps, {run['validated_status']}, {run['certified_digits']:.1f} certified digits, widest final ball "
          f"{run['widest_final_ball']:.1e})")
    print(f"validated / lie = {run['ratio_min']:.2f} - {run['ratio_max']:.2f}x (median {run['ratio']:.2f}, "
          f"{args.pairs} alternated pairs, {args.clock} clock; target <= 2)")
    if before is not None:
        print(f"before ({args.before}): {run['before_s']:.2f} s ({run['before_steps']} steps, "
              f"{run['before_digits']:.2f} certified digits), before / lie = {run['before_ratio_min']:.2f} - "
              f"{run['before_ratio_max']:.2f}x (median {run['before_ratio']:.2f}), in the same rounds")
    tight = remainder_tightness()
    for h, (bound, true) in tight.items():
        print(f"one step to t = {h} (order 59, 40 digits): remainder bound {bound:.2e}, true {true:.2e}, "
              f"bound / true = {bound / true:.2f}")
    return {**co, **run, "remainder": tight}


if __name__ == "__main__":
    main()
