"""Regenerate docs/reports/departure-map/: how long each precision stays on the exact rigid-body motion, over the
sphere of initial angular momenta |M| = 1 (both sides of the separatrix).

    .venv/bin/python validation/departure_map.py                       # 12 x 24 grid, T = 200 (a few minutes)
    .venv/bin/python validation/departure_map.py --grid 4 8 --T 60 --out /tmp/dm   # a quick look

Writes report.md, departure.png and data.json into the output folder (refusing a non-empty folder it did not
create unless --overwrite).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

from lieseries.progress import ProgressBar
from lieseries.report import departure_map_reading, departure_map_table, markdown_table, plot_departure_map
from lieseries.studies.departure import departure_map

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ".departure-map-files"
FILES = ("report.md", "departure.png", "data.json", MANIFEST)


def _prepare(out: Path, overwrite: bool) -> None:
    if out.exists() and any(out.iterdir()):
        ours = (out / MANIFEST).exists()
        if not (ours and overwrite):
            foreign = sorted(p.name for p in out.iterdir() if p.name not in FILES)
            if foreign or not overwrite:
                raise SystemExit(
                    f"{out} is not empty ({', '.join(sorted(p.name for p in out.iterdir())[:5])}); pass "
                    "--overwrite to replace this script's own files there (other files are never touched)"
                )
    out.mkdir(parents=True, exist_ok=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", nargs=2, type=int, default=[12, 24], metavar=("N_THETA", "N_PHI"))
    ap.add_argument("--T", type=float, default=200.0)
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--threshold", default="1e-6")
    ap.add_argument("--precisions", nargs="+", default=["double", "long double", "quad"])
    ap.add_argument("--out", default=str(ROOT / "docs" / "reports" / "departure-map"))
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    out = Path(args.out)
    _prepare(out, args.overwrite)
    precisions = [int(p) if p.isdigit() else p for p in args.precisions]

    tic = time.perf_counter()
    with ProgressBar("departure map") as bar:
        m = departure_map(grid=tuple(args.grid), T=args.T, samples=args.samples, precisions=precisions,
                          threshold=args.threshold, progress=bar)
    wall = time.perf_counter() - tic
    plot_departure_map(m, out / "departure.png")
    (out / "data.json").write_text(json.dumps(m.to_dict(), indent=1))
    lines = [
        "# Departure map: how long each precision stays on the exact motion",
        "",
        f"Rigid body I = {tuple(m.inertia)}, R(0) = 1, initial angular momentum M0 on |M| = 1 over a "
        f"{args.grid[0]} x {args.grid[1]} grid of directions (both sides of the separatrix), one ensemble run "
        f"of `ls.integrate` at tol = eps per precision, compared at {args.samples} output times up to T = {m.T:g} "
        "with the "
        "closed form (`ls.exact.euler_poisson_many`, at least 10 digits beyond the finest precision). Departure: "
        "the first output time where the "
        f"12-number state differs from it by more than {m.threshold:g} (max norm).",
        "",
        f"Regenerate: `.venv/bin/python validation/departure_map.py --grid {args.grid[0]} {args.grid[1]} "
        f"--T {m.T:g} --samples {args.samples} --threshold {args.threshold} --precisions "
        f"{' '.join(repr(p) if ' ' in str(p) else str(p) for p in args.precisions)} --overwrite` ({wall:.0f} s on "
        "the project's 2-core machine, "
        f"{platform.python_version()}).",
        "",
        "![departure map](departure.png)",
        "",
    ]
    lines += [markdown_table(*departure_map_table(m)), "", departure_map_reading(), ""]
    (out / "report.md").write_text("\n".join(lines))
    (out / MANIFEST).write_text("\n".join(FILES[:-1]))
    print(f"wrote {out} in {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
