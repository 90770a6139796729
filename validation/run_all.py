"""Regenerate the report of every built-in scene, full size, into docs/reports/<name>/.

    .venv/bin/python validation/run_all.py                  # every built-in scene (make validate)
    .venv/bin/python validation/run_all.py default tennis-racket
    .venv/bin/python validation/run_all.py --quick --out /tmp/reports

One line per scene on stdout (name, time, report path); progress bars on stderr when it is a terminal.
Exits with status 1 when a scene fails (the others still run), 2 on an unknown scene name.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

from lieseries.heyoka_build import use_own_disk_cache
from lieseries.report import summary_text, write_report
from lieseries.run import run_scene
from lieseries.scenes import SceneError, builtin_scenes, load_scene

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="scenes to run (default: every built-in scene)")
    parser.add_argument("--out", default=str(ROOT / "docs" / "reports"), help="parent folder of the reports")
    parser.add_argument("--quick", action="store_true", help="scaled-down studies (for a smoke test)")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--summary", action="store_true", help="print each scene's summary table")
    args = parser.parse_args(argv)
    use_own_disk_cache()  # the command line's heyoka cache, not the user's shared one (read whole by each process)

    names = args.names or [name for name, _ in builtin_scenes()]
    try:
        scenes = [load_scene(n) for n in names]
    except SceneError as err:
        print(f"run_all: {err}", file=sys.stderr)
        return 2
    out = Path(args.out)
    failed = []
    start = time.perf_counter()
    for i, scene in enumerate(scenes, 1):
        print(f"[{i}/{len(scenes)}] {scene.name}: {scene.title}", flush=True)
        t0 = time.perf_counter()
        try:
            res = run_scene(scene, quick=args.quick, progress=not args.no_progress)
            path = write_report(res, out / scene.name, overwrite=True)
        except Exception:  # keep going: one broken scene must not hide the others
            failed.append(scene.name)
            traceback.print_exc()
            print(f"    FAILED after {time.perf_counter() - t0:.1f} s", flush=True)
            continue
        print(f"    {time.perf_counter() - t0:.1f} s -> {path}", flush=True)
        for note in res.notes:
            print(f"    note: {note}", flush=True)
        if args.summary:
            print(summary_text(res), flush=True)
    total = time.perf_counter() - start
    print(f"{len(scenes) - len(failed)}/{len(scenes)} scenes done in {total:.1f} s"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
