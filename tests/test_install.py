"""A regular install (not editable), used from outside the repository: the built-in scenes ship as package data.

The package is installed without ``-e`` into a temporary folder (``pip install --no-deps --target``), and its
command line is run from another temporary folder, so nothing can come from the source tree. The default suite
checks that every module and scene file of the source tree is installed, lists the scenes and sees a folder
refused; a full scene run from the installed copy (~10 s) is marked slow (`make test-all` runs it).
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    target = tmp_path_factory.mktemp("site")
    build = tmp_path_factory.mktemp("build")
    # from a copy of the source files: setuptools builds in the tree's build/ folder and keeps there what an earlier
    # install left (a module since removed would be installed again)
    source = build / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".git", ".venv", "build", "*.egg-info", "__pycache__",
                                                                 "reports", ".pytest_cache"))
    # --no-compile: the few modules a run imports are compiled when first imported, not all of them up front
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--no-compile",
           "--target", str(target), str(source)]
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


def shipped(folder):
    """The module and scene files under ``folder`` (a package folder), as relative paths."""
    return {p.relative_to(folder).as_posix() for ext in ("*.py", "*.toml") for p in folder.rglob(ext)
            if "__pycache__" not in p.parts}


def test_regular_install_ships_every_module_and_scene_and_lists_the_scenes(installed, tmp_path):
    source = shipped(ROOT / "lieseries")
    assert "data/scenes/default.toml" in source and "cli.py" in source
    assert shipped(installed / "lieseries") == source  # nothing left out of the install, nothing extra

    res = lieseries(installed, tmp_path, "scenes")
    assert res.returncode == 0, res.stderr
    assert str(installed) in res.stderr  # the installed copy, not the source tree
    names = [line.split()[0] for line in res.stdout.splitlines() if line and not line.startswith(" ")]
    assert names[0] == "default" and "tennis-racket" in names and "damped-stiff" in names
    # each scene's description is read from its file in the installed package data
    assert "Asymmetric rigid body to T = 20" in res.stdout

    # the CLI never loses a user's file: a folder with other files is refused (exit 2, one line), kept intact
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "trajectory.png").write_text("my plot")
    res = lieseries(installed, tmp_path, "run", "default", "--quick", "--no-progress", "--out", "mine")
    assert res.returncode == 2
    assert len([line for line in res.stderr.splitlines() if line.startswith("lieseries:")]) == 1
    assert "Traceback" not in res.stderr and "--overwrite" in res.stderr
    assert (mine / "trajectory.png").read_text() == "my plot"


@pytest.mark.slow  # ~10 s: a whole scene run in a fresh interpreter; the test above checks what it installs
def test_regular_install_runs_the_default_scene(installed, tmp_path):
    res = lieseries(installed, tmp_path, "run", "default", "--quick", "--no-progress", "--out", "rep")
    assert res.returncode == 0, res.stderr
    assert str(installed) in res.stderr
    assert (tmp_path / "rep" / "report.md").is_file() and "heyoka double" in res.stdout
