"""The layout: every module imports on its own in a fresh interpreter, and the layers point one way."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lieseries"

# Imports numpy, heyoka, mpmath, sympy once, then the package itself, then forks one child per module the package
# did not import: each child imports that module into an interpreter that has no other lieseries module than the
# package's own (a partially initialised module, the symptom of an import cycle, fails there), at a fraction of the
# cost of a new interpreter per module. `import lieseries.x` in a new interpreter first runs `import lieseries`, the
# same steps as here; for the modules that step already imports, it is the whole of their import.
CHILD = r"""
import importlib, os, sys
import heyoka, mpmath, numpy, sympy
assert not [m for m in sys.modules if m.split(".")[0] == "lieseries"]
bad = []
try:
    importlib.import_module("lieseries")
except BaseException as err:
    sys.stderr.write(f"lieseries: {type(err).__name__}: {err}\n")
    print("lieseries")
    sys.exit(0)
for name in sys.argv[1:]:
    if name in sys.modules:
        continue
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


#: The layers, lowest first: a module imports only from its own layer or the layers below it (lazy imports in
#: functions included). Every module of the package is in exactly one layer (a new module must be placed here).
LAYERS = [
    ("utilities", {"progress", "interrupts", "formatting", "folder", "cache", "caller"}),
    ("core", {"precision", "fields", "expr", "poisson", "solution", "events", "timegrid", "balls", "models"}),
    ("engines", {"energy", "atlas", "ensemble", "taylor", "heyoka_build", "lie", "ball_series", "exact", "validated",
                 "validated_step", "driver"}),
    ("api", {"api"}),
    ("methods", {"methods"}),
    ("studies", {"studies"}),
    ("scenes", {"scenes"}),
    ("run", {"run", "stability", "cost"}),
    ("report", {"report"}),
    ("command line", {"cli", "__main__", "__init__"}),
]


def _component(module: str) -> str:
    """lieseries.models.sphere -> models; lieseries -> __init__."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imported_components(path: Path, module: str, is_package: bool) -> set:
    """The package's top-level components that the file imports (anywhere in it)."""
    import ast

    pkg = module if is_package else module.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            # `from . import exact` names a module; `from .precision import x` names one too
            names = [f"{target}.{a.name}" for a in node.names] if target == "lieseries" else [target]
        else:
            continue
        out |= {_component(n) for n in names if n.split(".")[0] == "lieseries"}
    return out


def test_each_layer_imports_only_the_layers_below_it():
    layer_of = {}
    for i, (_name, comps) in enumerate(LAYERS):
        for c in comps:
            assert c not in layer_of, f"{c} is in two layers"
            layer_of[c] = i
    upward, unplaced = [], set()
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        module = ".".join(parts[:-1] if is_package else parts)
        own = _component(module)
        if own not in layer_of:
            unplaced.add(own)
            continue
        for other in _imported_components(p, module, is_package):
            if other not in layer_of:
                unplaced.add(other)
            elif layer_of[other] > layer_of[own]:
                upward.append(f"{module} ({LAYERS[layer_of[own]][0]}) imports {other} "
                              f"({LAYERS[layer_of[other]][0]})")
    assert not unplaced, f"modules in no layer of LAYERS (place them): {sorted(unplaced)}"
    assert not upward, "upward imports:\n" + "\n".join(upward)
