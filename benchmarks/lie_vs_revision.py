"""ls.lie_integrate of this checkout against the same call of an earlier git revision, alternated in one process.

The revision's package is extracted (`git archive`) into a temporary folder under another name and imported beside
this one; the rigid body I = (1, 2, 3), omega0 = (1, 0.1, 0.5) is integrated to T by each in turn (`--reps` pairs
after one warm-up call each, the order of the pair alternating), and the ratio of each pair is printed with its
range, on the process's CPU time by default. The final states are compared bit for bit, and when they differ (a
change of the steps or the order) both errors against the closed form (``ls.exact``, 20 more digits) are printed.

    .venv/bin/python benchmarks/lie_vs_revision.py main                 # 50 digits, this checkout against main
    .venv/bin/python benchmarks/lie_vs_revision.py HEAD~3 --digits 50 100 --reps 9
    LIESERIES_BIGINT=int .venv/bin/python benchmarks/lie_vs_revision.py main   # Python ints in both
    .venv/bin/python benchmarks/lie_vs_revision.py f60ff67~1 --digits 1000 --max-steps 1 --reps 2   # one step
    .venv/bin/python benchmarks/lie_vs_revision.py 94b65d4 --model heavy-top-dirac --T 2 --digits 30 --reps 5

With ``--max-steps 1`` each call is one step (at 1000 digits one step of order 1153, the time-scale probe
included); the states are then compared at the times each run reached.
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import mpmath as mp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import lieseries as ls  # noqa: E402
from lieseries.precision import to_fraction  # noqa: E402


def load_revision(rev: str, folder: Path):
    """The package as it was at ``rev``, imported as ``lieseries_rev`` (its imports are relative)."""
    archive = folder / "rev.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), rev, "lieseries"], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(folder / "x", filter="data")
    (folder / "x" / "lieseries").rename(folder / "lieseries_rev")
    sys.path.insert(0, str(folder))
    return importlib.import_module("lieseries_rev")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev", help="the git revision to compare against (main, HEAD~3, a commit)")
    ap.add_argument("--digits", type=int, nargs="+", default=[50])
    ap.add_argument("--reps", type=int, default=7, help="alternated pairs per precision (default 7)")
    ap.add_argument("--T", type=float, default=10)
    ap.add_argument("--clock", choices=["wall", "cpu"], default="cpu")
    ap.add_argument("--max-steps", type=int, default=None, help="steps per call (default: as many as T needs)")
    ap.add_argument("--model", choices=sorted(MODELS), default="rigid-body",
                    help="the system (default: the rigid body; errors against a closed form only for it)")
    args = ap.parse_args(argv)
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    with tempfile.TemporaryDirectory() as tmp:
        old = load_revision(args.rev, Path(tmp))
        print(f"lie_integrate, {args.model} to T = {args.T}: this checkout against {args.rev}; {args.clock} clock")
        for dps in args.digits:
            runs = {}
            for name, pkg in (("rev", old), ("this", ls)):
                body, y0 = MODELS[args.model](pkg)
                extra = {} if args.max_steps is None else {"max_steps": args.max_steps}
                runs[name] = (lambda pkg=pkg, body=body, y0=y0: pkg.lie_integrate(body, y0, t=args.T, dps=dps,
                                                                                 **extra))
            sols = {name: run() for name, run in runs.items()}  # warm-up
            end = {name: sol.y[-1] for name, sol in sols.items()}
            same = (all(a == b for a, b in zip(end["rev"], end["this"]))
                    and float(sols["rev"].t[-1]) == float(sols["this"].t[-1]))
            errors = "" if same or args.model != "rigid-body" else "; errors " + ", ".join(
                f"{name} {mp.nstr(_error(end[name], dps, sols[name].t[-1]), 3)} at t = {mp.nstr(sols[name].t[-1], 6)}"
                for name in ("rev", "this"))
            times = {"rev": [], "this": []}
            for r in range(args.reps):
                for name in (("rev", "this") if r % 2 == 0 else ("this", "rev")):
                    t0 = clock()
                    runs[name]()
                    times[name].append(clock() - t0)
            ratios = [b / a for a, b in zip(times["rev"], times["this"])]
            print(f"  {dps} digits: {args.rev} {statistics.median(times['rev']):.4f} s, this "
                  f"{statistics.median(times['this']):.4f} s; this / {args.rev} = {min(ratios):.3f} - "
                  f"{max(ratios):.3f} (median {statistics.median(ratios):.3f}, {args.reps} alternated pairs); final "
                  f"states {'bit-identical' if same else 'DIFFERENT'}{errors}")


def _rigid_body(pkg):
    body = pkg.EulerPoisson((1, 2, 3))
    return body, body.initial_state((1, "0.1", "0.5"))


def _heavy_top(form):
    def build(pkg):
        top = pkg.HeavyTop((2, 2, 1), com=(0, 0, "0.5"), g="9.81")
        q, qdot = top.surface_point(top.initial_state(omega=(1, "0.5", 5)))
        system = getattr(top.constrained_system(), form)()
        return system, system.initial_state(q=q, qdot=qdot)
    return build


#: the systems a run can time (each built by the checkout's package and by the revision's)
MODELS = {"rigid-body": _rigid_body, "heavy-top-dirac": _heavy_top("dirac"),
          "heavy-top-intermediate": _heavy_top("intermediate")}


def _error(state, dps, T):
    """The largest error of a final state against the closed form."""
    ref = ls.exact.euler_poisson((1, 2, 3), (1, "0.1", "0.5"), T, dps=dps + 20)
    with mp.workdps(dps + 20):
        return max(abs(mp.mpf(q.numerator) / q.denominator - b) for q, b in zip(map(to_fraction, state), ref))


if __name__ == "__main__":
    main()
