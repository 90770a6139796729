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

import numpy as np

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


def _plot(m, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(m.departure)
    fig, axes = plt.subplots(2, len(names), figsize=(5.2 * len(names), 8.2), squeeze=False)
    ph, th = np.degrees(m.phi), np.degrees(m.theta)
    for ax, name in zip(axes[1], names):
        digits = -np.log10(np.maximum(m.max_error[name], 1e-300))
        im = ax.pcolormesh(ph, th, digits, shading="nearest", cmap="magma")
        ax.contour(ph, th, m.energy_ratio, levels=[1.0], colors="c", linewidths=1.2)
        ax.set_title(f"{name}: digits kept, -log10 max |y - exact| on [0, {m.T:g}]")
        ax.set_xlabel("azimuth of M0 (deg)")
        ax.set_ylabel("polar angle of M0 from axis 3 (deg)")
        fig.colorbar(im, ax=ax, label="digits")
    for ax, name in zip(axes[0], names):
        dep = m.departure[name]
        im = ax.pcolormesh(ph, th, dep, shading="nearest", cmap="viridis", vmin=0, vmax=m.T)
        ax.contour(ph, th, m.energy_ratio, levels=[1.0], colors="w", linewidths=1.2)
        stayed = m.stayed[name]
        ys, xs = np.nonzero(stayed)
        ax.scatter(ph[xs], th[ys], s=4, c="k", marker=".", label=f"stayed within to T = {m.T:g}")
        ax.set_title(f"{name}: time before |y - exact| > {m.threshold:g}")
        ax.set_xlabel("azimuth of M0 (deg)")
        ax.set_ylabel("polar angle of M0 from axis 3 (deg)")
        fig.colorbar(im, ax=ax, label="departure time")
    axes[0][0].legend(loc="lower left", fontsize=7)
    fig.suptitle(f"Rigid body I = {tuple(m.inertia)}, |M| = 1, R(0) = 1 (white: the separatrix)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
    last = [0.0]

    def progress(f):
        if sys.stderr.isatty() and time.perf_counter() - last[0] > 0.5:
            last[0] = time.perf_counter()
            print(f"\r{100 * f:5.1f} %", end="", file=sys.stderr, flush=True)

    m = departure_map(grid=tuple(args.grid), T=args.T, samples=args.samples, precisions=precisions,
                      threshold=args.threshold, progress=progress)
    wall = time.perf_counter() - tic
    _plot(m, out / "departure.png")
    (out / "data.json").write_text(json.dumps(m.to_dict(), indent=1))
    lines = [
        "# Departure map: how long each precision stays on the exact motion",
        "",
        f"Rigid body I = {tuple(m.inertia)}, R(0) = 1, initial angular momentum M0 on |M| = 1 over a "
        f"{args.grid[0]} x {args.grid[1]} grid of directions (both sides of the separatrix), `ls.integrate` at "
        f"tol = eps in each precision, compared at {args.samples} output times up to T = {m.T:g} with the "
        "closed form (`ls.exact.euler_poisson_many`, 30 digits). Departure: the first output time where the "
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
        "| precision | members that departed before T | earliest departure | median departure (departed) | "
        "fewest digits kept (where) | most digits kept | statuses other than success | integration time |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, dep in m.departure.items():
        gone = ~m.stayed[name]
        bad = [s for s in m.statuses[name] if s != "success"]
        med = f"{np.median(dep[gone]):.1f}" if gone.any() else "-"
        err = m.max_error[name]
        i, j = np.unravel_index(np.argmax(err), err.shape)
        lines.append(f"| {name} | {int(gone.sum())} / {dep.size} | {dep.min():.1f} | {med} | "
                     f"{-np.log10(err.max()):.1f} (2 H I2 / abs(M)^2 = {m.energy_ratio[i, j]:.3f}) | "
                     f"{-np.log10(err.min()):.1f} | {len(bad)} | {m.run_time[name]:.2f} s |")
    lines += [
        "",
        "How to read it: near the separatrix (white curve, 2 H I2 = |M|^2) the motion passes close to the unstable "
        "rotation about the intermediate axis, where errors grow like exp(lambda t); there every precision departs, "
        "and a wider format buys only time proportional to its number of digits (ln(threshold / eps) / lambda). "
        "Away from it errors grow only linearly (a phase drift) and the runs stay within the threshold to T.",
        "",
    ]
    (out / "report.md").write_text("\n".join(lines))
    (out / MANIFEST).write_text("\n".join(FILES[:-1]))
    print(f"wrote {out} in {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
