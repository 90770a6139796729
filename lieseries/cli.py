"""Command line: ``lieseries scenes`` and ``lieseries run SCENE [--out DIR] [--overwrite] [--quick] [--no-progress]
[--max-time SECONDS]``.

Exit status: 0 when every run of the scene succeeded, 1 when a run ended without success -- in the ``[run]`` table
or in a study (work-precision rows, departure-map members) -- or a study failed (listed after the summary, and in
the report), 2 for bad input (an unknown scene, an invalid scene file, a bad option, a report folder
holding files lieseries did not write, a scene whose estimated run time exceeds ``--max-time``): one line naming the
problem, no traceback; 130 when interrupted (Ctrl-C). Before computing, ``run`` estimates the scene's run time
(:mod:`lieseries.cost`) and prints the estimate when it exceeds 30 s.
Also runs as ``python -m lieseries``.

The report folder is never emptied: lieseries replaces or removes only files it wrote itself (listed with the
SHA-256 of their content in ``.lieseries-manifest.json``), refuses a folder holding other files unless
``--overwrite``, and never replaces a file it did not write, even with ``--overwrite``. A run locks its folder
before computing (a second run into it exits 2), writes the report into a staging folder and moves it into place
only when it is whole: an interrupted or failed run leaves the earlier report as it was.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

from .interrupts import held, ignore_from_now, is_command_line

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
                   help="write into a folder that holds other files (they are kept; only files lieseries wrote "
                        "itself are replaced)")
    r.add_argument("--quick", action="store_true", help="scale the studies down (fewer orders, samples, tolerances)")
    r.add_argument("--no-progress", action="store_true", help="no progress bars on stderr")
    r.add_argument("--max-time", metavar="SECONDS", type=_seconds,
                   help="refuse (exit 2), before computing, a scene whose estimated run time exceeds SECONDS "
                        "(default: no limit; the estimate is printed when it exceeds 30 s)")
    return p


def _seconds(text):
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds; got {text!r}")
    return v


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
    with held():  # Ctrl-C while an extension module initialises would surface as an unrelated ImportError
        from .cost import PRINT_ABOVE, check_scene_budget, estimate_scene
        from .folder import ReportFolder
        from .heyoka_build import use_own_disk_cache
        from .report import report_names, summary_text, write_report
        from .run import run_scene
        from .scenes import load_scene

        _check_requirements()  # before the work: a missing package must not cost the computation
    use_own_disk_cache()  # before anything is compiled: heyoka's shared cache may be gigabytes, read whole
    scene = load_scene(args.scene)
    out_dir = Path(args.out) if args.out else Path("reports") / scene.name
    # lock and check the folder before the work, not after it; the report is moved into place only when whole
    with ReportFolder(out_dir, args.overwrite, names=report_names(scene)) as folder:
        estimate = estimate_scene(scene, quick=args.quick)  # refused (exit 2) beyond --max-time; said when long
        check_scene_budget(estimate, args.max_time)
        if estimate.seconds > PRINT_ABOVE:
            print(f"lieseries: {estimate.summary()}", file=sys.stderr, flush=True)
        result = run_scene(scene, quick=args.quick, progress=not args.no_progress)
        path = write_report(result, folder)
    failed = result.unsuccessful()
    try:
        print(summary_text(result), file=out)
        print(f"report: {path}  ({result.wall_time:.1f} s)", file=out)
        if failed:
            print("not every run succeeded (exit status 1):\n  " + "\n  ".join(failed), file=out)
        out.flush()
    except BrokenPipeError:  # `lieseries run ... | head`: the report is written; the status still says how it went
        _stdout_to_devnull()
    return 1 if failed else 0


#: Packages `lieseries run` needs besides the library's own (dependencies of the package, pyproject.toml):
#: (module, pip requirement, what for).
RUN_REQUIREMENTS = (("scipy", "scipy>=1.10", "the scipy DOP853 runs and the report's environment"),
                    ("matplotlib", "matplotlib>=3.7", "the report's plots"))


def _check_requirements() -> None:
    missing = []
    for module, requirement, why in RUN_REQUIREMENTS:
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append((module, requirement, why))
    if missing:
        names = ", ".join(f"`{m}` ({why})" for m, _, why in missing)
        reqs = " ".join(f"'{r}'" for _, r, _ in missing)
        raise _MissingPackage(f"`lieseries run` needs {names}, which cannot be imported; install it: "
                              f"pip install {reqs} (it is a dependency of lieseries: a plain `pip install "
                              "lieseries` brings it)")


class _MissingPackage(Exception):
    pass


def _stdout_to_devnull() -> None:
    """After a broken pipe: send what is left of stdout (and the flush at exit) to the null device."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # a stdout without a file descriptor (tests)
        pass


def main(argv=None) -> int:
    """Entry point; returns the exit status (module docstring): 0 every run succeeded, 1 a run (or a study's run)
    ended without success or a study failed, 2 bad input, 130 interrupted."""
    try:
        with held():
            from .folder import FolderError
            from .scenes import SceneError
    except KeyboardInterrupt:
        print("lieseries: interrupted", file=sys.stderr)
        return 130
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
            status = _cmd_scenes(out)
            out.flush()
            return status
        if args.command == "run":
            return _cmd_run(args, out)
        parser.print_help(sys.stderr)
        return 2
    except (SceneError, FolderError, _MissingPackage) as err:
        print(f"lieseries: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if is_command_line():
            ignore_from_now()  # the process ends here: a second Ctrl-C must not cut the message and status 130
        print("lieseries: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `lieseries scenes | head`: the reader has what it wanted
        _stdout_to_devnull()
        return 0
    except OSError as err:  # e.g. the report folder cannot be written
        print(f"lieseries: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
