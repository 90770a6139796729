"""Command line: ``lieseries scenes`` and ``lieseries run SCENE [--out DIR] [--overwrite] [--quick] [--no-progress]``.

Exit status: 0 when every run of the scene succeeded, 1 when a run ended without success -- in the ``[run]`` table
or in a study (work-precision rows, departure-map members) -- or a study failed (listed after the summary, and in
the report), 2 for bad input (an unknown scene, an invalid scene file, a bad option, a report folder
holding files lieseries did not write): one line naming the problem, no traceback; 130 when interrupted (Ctrl-C).
Also runs as ``python -m lieseries``.

The report folder is never emptied: lieseries replaces only the files it writes itself (listed in
``.lieseries-manifest.json``), and refuses a folder holding other files unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors raise instead of exiting (main turns them into status 2)."""

    def error(self, message):
        raise _UsageError(f"{self.prog}: {message}")


class _UsageError(Exception):
    pass


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="lieseries", description="Run lieseries scenes and write their reports.")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.add_parser("scenes", help="list the built-in scenes")
    r = sub.add_parser("run", help="run a scene and write its report")
    r.add_argument("scene", metavar="SCENE", help="a built-in scene name (see `lieseries scenes`) or a .toml path")
    r.add_argument("--out", metavar="DIR", help="report folder (default: reports/<scene name>)")
    r.add_argument("--overwrite", action="store_true",
                   help="write into a folder that holds other files (only the report's own files are replaced)")
    r.add_argument("--quick", action="store_true", help="scale the studies down (fewer orders, samples, tolerances)")
    r.add_argument("--no-progress", action="store_true", help="no progress bars on stderr")
    return p


def _cmd_scenes(out) -> int:
    from .scenes import builtin_scenes, extreme_scenes, scenes_dir

    items = builtin_scenes()
    extreme = extreme_scenes()
    if not items:
        print(f"lieseries: no built-in scenes found in {scenes_dir()}", file=sys.stderr)
        return 2
    width = max(len(n) for n, _ in items + extreme)
    for name, title in items:
        print(f"{name.ljust(width)}  {title}", file=out)
    if extreme:
        print("\nextreme and stiff cases (validation/stability.py runs them all):", file=out)
        for name, title in extreme:
            print(f"{name.ljust(width)}  {title}", file=out)
    return 0


def _cmd_run(args, out) -> int:
    from .report import claim_folder, summary_text, write_report
    from .run import run_scene
    from .scenes import load_scene

    scene = load_scene(args.scene)
    out_dir = Path(args.out) if args.out else Path("reports") / scene.name
    claim_folder(out_dir, args.overwrite)  # refuse before the work, not after it
    result = run_scene(scene, quick=args.quick, progress=not args.no_progress)
    path = write_report(result, out_dir, overwrite=args.overwrite)
    print(summary_text(result), file=out)
    print(f"report: {path}  ({result.wall_time:.1f} s)", file=out)
    failed = result.unsuccessful()
    if failed:
        print("not every run succeeded (exit status 1):\n  " + "\n  ".join(failed), file=out)
    return 1 if failed else 0


def main(argv=None) -> int:
    """Entry point; returns the exit status (module docstring): 0 every run succeeded, 1 a run (or a study's run)
    ended without success or a study failed, 2 bad input, 130 interrupted."""
    from .report import FolderError
    from .scenes import SceneError

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as err:
        print(str(err), file=sys.stderr)
        return 2
    except SystemExit as err:  # --help
        return int(err.code or 0)
    out = sys.stdout
    try:
        if args.command == "scenes":
            return _cmd_scenes(out)
        if args.command == "run":
            return _cmd_run(args, out)
        parser.print_help(sys.stderr)
        return 2
    except (SceneError, FolderError) as err:
        print(f"lieseries: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lieseries: interrupted", file=sys.stderr)
        return 130
    except OSError as err:  # e.g. the report folder cannot be written
        print(f"lieseries: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
