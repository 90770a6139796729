"""A regular install (not editable), used from outside the repository: the built-in scenes ship as package data.

The package is installed without ``-e`` into a temporary folder (``pip install --no-deps --target``), and its
command line is run from another temporary folder, so nothing can come from the source tree.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    target = tmp_path_factory.mktemp("site")
    build = tmp_path_factory.mktemp("build")
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
           "--target", str(target), str(ROOT)]
    env = {**os.environ, "TMPDIR": str(build), "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    subprocess.run(cmd, check=True, cwd=build, env=env, capture_output=True, timeout=300)
    assert (target / "lieseries" / "data" / "scenes" / "default.toml").is_file()
    assert not (target / "lieseries" / "data" / "scenes").is_symlink()
    return target


def lieseries(installed, cwd, *args):
    env = {k: v for k, v in os.environ.items() if k not in ("LIESERIES_SCENES",)}
    env["PYTHONPATH"] = str(installed)
    code = "import sys, lieseries, lieseries.cli; print(lieseries.__file__, file=sys.stderr); " \
           "sys.exit(lieseries.cli.main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)


def test_regular_install_lists_and_runs_the_builtin_scenes(installed, tmp_path):
    res = lieseries(installed, tmp_path, "scenes")
    assert res.returncode == 0, res.stderr
    assert str(installed) in res.stderr  # the installed copy, not the source tree
    names = [line.split()[0] for line in res.stdout.splitlines() if line and not line.startswith(" ")]
    assert names[0] == "default" and "tennis-racket" in names and "damped-stiff" in names

    res = lieseries(installed, tmp_path, "run", "default", "--quick", "--no-progress", "--out", "rep")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "rep" / "report.md").is_file() and "heyoka double" in res.stdout

    # the CLI never loses a user's file: a folder with other files is refused (exit 2, one line), kept intact
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "trajectory.png").write_text("my plot")
    res = lieseries(installed, tmp_path, "run", "default", "--quick", "--no-progress", "--out", "mine")
    assert res.returncode == 2
    assert len([line for line in res.stderr.splitlines() if line.startswith("lieseries:")]) == 1
    assert "Traceback" not in res.stderr and "--overwrite" in res.stderr
    assert (mine / "trajectory.png").read_text() == "my plot"
