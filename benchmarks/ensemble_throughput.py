"""Ensemble throughput: k rigid bodies to T = 20 in double, batch ensemble vs a loop of bare heyoka single runs.

The peer is the fastest plain-Python way to run k members with heyoka: one cached ``heyoka.taylor_adaptive``,
state and time reset per member, ``propagate_until``; no lieseries code. Both are measured in this process, in
this run, in turn (best of ``--repeat`` each), and only their ratio is reported; the compile time of either
integrator is excluded (both are built before timing).

Run:  PYTHONPATH=. python benchmarks/ensemble_throughput.py            (ratio at k = 4096)
      PYTHONPATH=. python benchmarks/ensemble_throughput.py --clock cpu  (CPU time: on a shared machine)
      PYTHONPATH=. python benchmarks/ensemble_throughput.py --rev main  (also main's ensemble, alternated with
                                                                         this one in the same process)
      PYTHONPATH=. python benchmarks/ensemble_throughput.py --plot     (also throughput vs k, the PNG and CSV
                                                                         in docs/reports/ensemble/)
      PYTHONPATH=. python benchmarks/ensemble_throughput.py --dask     (also a Dask LocalCluster of 2 worker
                                                                         processes against the local run)
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import heyoka as hy
import numpy as np

import lieseries as ls
from lieseries.ensemble import build_batch_integrator, integrate_ensemble

T = 20.0
COMMAND = "PYTHONPATH=. python benchmarks/ensemble_throughput.py"


def initial_states(k, seed=0):
    rng = np.random.default_rng(seed)
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    om = np.array([1.0, 0.1, 0.5]) + 0.01 * rng.standard_normal((k, 3))
    Y0 = np.zeros((k, 12))
    Y0[:, [0, 4, 8]] = 1.0
    Y0[:, 9:] = om * np.array([1.0, 2.0, 3.0])  # M = I omega
    return body, Y0


def bare_loop(ta, Y0):
    for y in Y0:
        ta.time = 0.0
        ta.state[:] = y
        ta.propagate_until(T)


def best(fn, repeat, clock=time.perf_counter):
    times = []
    for _ in range(repeat):
        t = clock()
        fn()
        times.append(clock() - t)
    return min(times)


def best_pair(f, g, repeat, clock):
    """The best times of ``f`` and of ``g``, called in turn ``repeat`` times each (a load that comes and goes
    falls on both)."""
    tf, tg = [], []
    for _ in range(repeat):
        tf.append(best(f, 1, clock))
        tg.append(best(g, 1, clock))
    return min(tf), min(tg)


def measure(k, repeat, workers=None, clock=time.perf_counter):
    body, Y0 = initial_states(k)
    ps = body.poisson
    ta = hy.taylor_adaptive(ps.ode_system, Y0[0], tol=2.0**-52, pars=[float(v) for v in ps.parameter_values])
    build_batch_integrator(body)  # compile once, outside the timing
    es = integrate_ensemble(body, Y0, T, workers=workers)
    assert es.success and es.stats["single_runs"] == 0, es
    t_bare, t_ens = best_pair(lambda: bare_loop(ta, Y0), lambda: integrate_ensemble(body, Y0, T, workers=workers),
                              repeat, clock)
    return t_bare, t_ens, es.stats


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=int, default=4096)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="wall time, or the process's CPU time over all its threads (less sensitive to other jobs "
                         "on the machine; the ensemble's threads' work is summed: a ratio of work, not of "
                         "throughput, unless --workers 1)")
    ap.add_argument("--rev", default=None,
                    help="also the ensemble of an earlier git revision (main, a commit), alternated with this one in "
                         "the same process (--pairs pairs): its time / this one's, and whether the results are equal")
    ap.add_argument("--pairs", type=int, default=15, help="alternated pairs for --rev (default 15)")
    ap.add_argument("--plot", action="store_true", help="throughput vs k into docs/reports/ensemble/")
    ap.add_argument("--dask", action="store_true", help="a local 2-process Dask cluster against the local run")
    args = ap.parse_args(argv)
    print(f"# {COMMAND} {' '.join(sys.argv[1:] if argv is None else argv)}".rstrip())
    print(f"# CPUs: {os.cpu_count()}, heyoka {hy.__version__}, SIMD batch size {hy.recommended_simd_size()}")
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    t_bare, t_ens, stats = measure(args.k, args.repeat, args.workers, clock)
    ratio = t_bare / t_ens
    print(f"k = {args.k} rigid bodies, I = (1, 2, 3), T = {T}, double, tol = eps; {args.clock} clock, load average "
          f"{os.getloadavg()[0]:.2f}")
    print(f"  bare heyoka loop : {t_bare * 1e3:8.1f} ms  ({args.k / t_bare:9.0f} members/s)")
    print(f"  integrate_ensemble: {t_ens * 1e3:8.1f} ms  ({args.k / t_ens:9.0f} members/s), "
          f"{stats['workers']} threads x batch {stats['batch_size']}")
    print(f"  ratio bare / ensemble = {ratio:.2f}  (bar: >= 3{'' if args.clock == 'wall' else ' on the wall clock'})")
    if args.rev:
        against_revision(args.rev, args.k, args.pairs, args.workers, clock, args.clock)
    if args.plot:
        plot(args.repeat, args.workers)
    if args.dask:
        dask_vs_local(args.k, args.repeat)
    return 0 if ratio >= 3 or args.clock == "cpu" else 1


def against_revision(rev, k, pairs, workers, clock, clock_name):
    """The ensemble of this checkout against the same call of git revision ``rev`` (its package extracted and
    imported beside this one: ``benchmarks/lie_vs_revision.py``), alternated ``pairs`` times, the order of each pair
    alternating; the end states, rows, statuses and steps compared bit for bit."""
    import statistics
    import tempfile
    from pathlib import Path

    from lie_vs_revision import load_revision

    body, Y0 = initial_states(k)
    with tempfile.TemporaryDirectory() as tmp:
        old = load_revision(rev, Path(tmp))
        body_old = old.EulerPoisson(inertia=(1, 2, 3))
        runs = {"this": lambda: integrate_ensemble(body, Y0, T, workers=workers),
                rev: lambda: old.integrate(body_old, Y0, t=T, workers=workers)}
        first = {name: fn() for name, fn in runs.items()}  # (compiles, outside the timing)
        a, b = first["this"], first[rev]
        same = (np.array_equal(a.y, b.y) and np.array_equal(a.y_reached, b.y_reached)
                and list(a.status) == list(b.status) and list(a.stats["steps"]) == list(b.stats["steps"]))
        times = {name: [] for name in runs}
        for j in range(pairs):
            for name in (list(runs) if j % 2 else list(runs)[::-1]):
                times[name].append(best(runs[name], 1, clock))
    ratios = [t_old / t_new for t_old, t_new in zip(times[rev], times["this"])]
    print(f"against {rev}, {pairs} alternated pairs, {clock_name} clock, load average {os.getloadavg()[0]:.2f}: "
          f"{rev} {statistics.median(times[rev]) * 1e3:.1f} ms, this {statistics.median(times['this']) * 1e3:.1f} ms "
          f"(medians); {rev} / this = {statistics.median(ratios):.3f} (median; {min(ratios):.3f} - "
          f"{max(ratios):.3f}); results bit-identical: {same}")


def dask_vs_local(k, repeat):
    from distributed import Client, LocalCluster

    body, Y0 = initial_states(k)
    local = integrate_ensemble(body, Y0, T)
    t_local = best(lambda: integrate_ensemble(body, Y0, T), repeat)
    with LocalCluster(processes=True, n_workers=2, threads_per_worker=1, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster) as client:
        t = time.perf_counter()
        first = integrate_ensemble(body, Y0, T, client=client)
        t_first = time.perf_counter() - t  # includes each worker's compilation
        t_dask = best(lambda: integrate_ensemble(body, Y0, T, client=client), repeat)
    same = np.array_equal(first.y, local.y) and list(first.status) == list(local.status)
    print(f"Dask LocalCluster (2 worker processes x 1 thread, loopback), k = {k}:")
    print(f"  first call {t_first * 1e3:.0f} ms (workers compile), then {t_dask * 1e3:.1f} ms; local "
          f"{t_local * 1e3:.1f} ms; ratio local / dask = {t_local / t_dask:.2f}; equal to local: {same}")


def plot(repeat, workers):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = os.path.join(os.path.dirname(__file__), "..", "docs", "reports", "ensemble")
    os.makedirs(out, exist_ok=True)
    ks = [1, 2, 4, 8, 16, 64, 256, 1024, 4096, 8192]
    rows = []
    for k in ks:
        rep = repeat if k >= 256 else 3 * repeat
        t_bare, t_ens, stats = measure(k, rep, workers)
        rows.append((k, k / t_bare, k / t_ens, t_bare / t_ens))
        print(f"  k = {k:5d}: bare {k / t_bare:9.0f}/s  ensemble {k / t_ens:9.0f}/s  ratio {t_bare / t_ens:5.2f}")
    with open(os.path.join(out, "throughput.csv"), "w") as f:
        f.write("k,bare_members_per_s,ensemble_members_per_s,ratio\n")
        for r in rows:
            f.write(f"{r[0]},{r[1]:.1f},{r[2]:.1f},{r[3]:.3f}\n")
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.loglog([r[0] for r in rows], [r[2] for r in rows], "o-", label="integrate_ensemble (batch, threads)")
    ax.loglog([r[0] for r in rows], [r[1] for r in rows], "s--", label="loop of bare heyoka single runs")
    ax.set_xlabel("members k")
    ax.set_ylabel("members per second")
    ax.set_title(f"Rigid body I = (1, 2, 3) to T = {T:g}, double ({os.cpu_count()} CPUs)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(out, "throughput.png"), dpi=120)
    print(f"  wrote {os.path.normpath(out)}/throughput.png and throughput.csv")


if __name__ == "__main__":
    sys.exit(main())
