"""Run every benchmark (`make bench`). Each prints its own ratios, measured within its own run.

    .venv/bin/python benchmarks/run_all.py           # full size (mpmath.odefun at 100 digits takes minutes)
    .venv/bin/python benchmarks/run_all.py --quick   # shorter spans
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import ensemble_throughput  # noqa: E402
import lie_vs_odefun  # noqa: E402
import overhead  # noqa: E402
import taylor_vs_scipy  # noqa: E402
import validated_vs_lie  # noqa: E402
import wrapper_speed  # noqa: E402

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter time spans for the mpmath comparison")
    args = ap.parse_args()
    print("== heyoka (double) vs scipy DOP853 ==")
    taylor_vs_scipy.main()
    print("\n== the wrapper's cost: ls.integrate vs the bare heyoka integrator vs DOP853 ==")
    overhead.main()
    print("\n== ls.integrate vs bare heyoka at T = 1, 5, 15, 100 and on a grid of output times ==")
    wrapper_speed.main(["--pairs", "1000"] if args.quick else [])
    print("\n== lie_integrate vs mpmath.odefun vs heyoka, arbitrary precision ==")
    lie_vs_odefun.main(T=2 if args.quick else 10)
    print("\n== certified digits: validated_integrate (Arb balls) vs lie_integrate ==")
    validated_vs_lie.main(["--T", "2"] if args.quick else [])
    print("\n== ensembles: heyoka batch mode vs a loop of single runs ==")
    ensemble_throughput.main(["--repeat", "2"] if args.quick else [])
