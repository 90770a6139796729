"""The layout: every module imports on its own in a fresh interpreter, and the layers point one way."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lieseries"

# Imports numpy, heyoka, mpmath, sympy once, then forks one child per module: each child imports one lieseries
# module into an interpreter that has no lieseries module yet (a partially initialised module, the symptom of an
# import cycle, fails there), at a fraction of the cost of a new interpreter per module.
CHILD = r"""
import importlib, os, sys
import heyoka, mpmath, numpy, sympy
assert not [m for m in sys.modules if m.split(".")[0] == "lieseries"]
bad = []
for name in sys.argv[1:]:
    pid = os.fork()
    if pid == 0:
        try:
            importlib.import_module(name)
        except BaseException as err:
            sys.stderr.write(f"{name}: {type(err).__name__}: {err}\n")
            os._exit(1)
        os._exit(0)
    if os.waitpid(pid, 0)[1]:
        bad.append(name)
print(" ".join(bad))
"""


def modules():
    out = []
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out.append(".".join(parts))
    return out


def test_every_module_imports_on_its_own(tmp_path):
    names = modules()
    assert "lieseries.run" in names and "lieseries.taylor" in names and len(names) > 25
    res = subprocess.run([sys.executable, "-c", CHILD, *names], cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "", f"modules that fail to import on their own: {res.stdout}\n{res.stderr}"


CHECKER = ROOT.parent / "shared" / "tools" / "import_check.py"


@pytest.mark.skipif(not CHECKER.is_file(), reason="the project's import checker lives beside the repository")
def test_layers_point_one_way():
    res = subprocess.run([sys.executable, str(CHECKER), "lieseries"], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0 and "no import cycle, no private name" in res.stdout, res.stdout + res.stderr
