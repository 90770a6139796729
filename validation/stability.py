"""Regenerate the stability report: every extreme and stiff case, full size, into docs/reports/stability/.

    .venv/bin/python validation/stability.py                         # every case in lieseries/data/scenes/extreme/
    .venv/bin/python validation/stability.py separatrix-exact damped-stiff
    .venv/bin/python validation/stability.py --quick --out /tmp/stability

Writes report.md (one row per case), the plots, data.json, CSV tables and each case's scene report under
scenes/<case>/. Two lines per case on stdout (its headline run and what the case found); a progress bar on stderr
when it is a terminal. Exits with status 1 when a case failed or did not end as its scene expects, 2 on an
unknown case name.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from lieseries.heyoka_build import use_own_disk_cache
from lieseries.progress import ProgressBar
from lieseries.report import write_stability_report
from lieseries.scenes import SceneError, extreme_scenes, load_scene
from lieseries.stability import stability

ROOT = Path(__file__).resolve().parents[1]


def _print_case(case):
    h = case.headline
    head = f"{h.method}: {h.status}" if h is not None else "no headline run"
    flag = "" if case.as_expected else "  (NOT as expected)"
    print(f"{case.name}: {case.wall_time:.1f} s, {head}{flag}", flush=True)
    print(f"    {case.finding}", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="cases to run (default: every scene in lieseries/data/scenes/extreme/)")
    parser.add_argument("--out", default=str(ROOT / "docs" / "reports" / "stability"), help="report folder")
    parser.add_argument("--quick", action="store_true", help="each scene's quick plan (a smoke test)")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--no-scene-reports", action="store_true", help="skip the per-case scene reports")
    args = parser.parse_args(argv)
    use_own_disk_cache()  # the command line's heyoka cache, not the user's shared one (read whole by each process)

    names = args.names or [name for name, _ in extreme_scenes()]
    try:
        scenes = [load_scene(n) for n in names]
    except SceneError as err:
        print(f"stability: {err}", file=sys.stderr)
        return 2
    bad = [s.name for s in scenes if s.stability is None]
    if bad:
        print(f"stability: {', '.join(bad)}: no [stability] table, not a stability case", file=sys.stderr)
        return 2
    start = time.perf_counter()
    bar = ProgressBar("stability", enabled=False if args.no_progress else None)

    def on_case(case):
        bar.close()  # clear the bar's line before printing
        _print_case(case)

    try:
        stab = stability(scenes, quick=args.quick, progress=bar, on_case=on_case)
    finally:
        bar.close()
    cmd = "python validation/stability.py" + (" --quick" if args.quick else "") + (
        " " + " ".join(args.names) if args.names else "")
    path = write_stability_report(stab, args.out, scene_reports=not args.no_scene_reports, command=cmd,
                                  overwrite=True)
    total = time.perf_counter() - start
    failed = [c.name for c in stab.cases if not c.as_expected]
    print(f"{len(stab.cases) - len(failed)}/{len(stab.cases)} cases as expected in {total:.1f} s -> {path}"
          + (f"; not as expected: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
