"""Quick mode: a scene's run and studies scaled down for CI, and what that changed."""

from __future__ import annotations

import copy

from ..methods import method_plugin
from ..studies.plugin import studies_registry

__all__ = ["effective_plan", "quick_changes"]


def effective_plan(scene, quick: bool = False):
    """(run, studies) tables as they will be run: ``quick`` scales them down for CI.

    Quick mode: at most 41 output times in the run, which ends at ``run.quick_t`` when the scene gives one; each
    method scales itself down (validated runs at most 30 digits, mpmath capped at t = 0.5, lists of settings thinned
    to three values in work-precision studies); each study scales itself down (its ``quick``: error vs order up to
    half the largest order (at least 12) and at most 40 digits; work-precision with one repeat; drift over a tenth
    of the time, at most 60 samples and 4 ensemble members; the departure map on at most a 3 x 6 grid, over a tenth
    of the time with at most 20 output times).
    """
    run = copy.deepcopy(scene.run)
    studies = copy.deepcopy(scene.studies)
    if not quick:
        return run, studies
    if run is not None:
        run["samples"] = min(run["samples"], 41)
        run["repeat"] = 1
        if run.get("quick_t") is not None:
            run["t"] = run["quick_t"]
        for m in run["methods"]:
            hook = method_plugin(m["method"]).quick_run
            if hook is not None:
                hook(m)
    registry = studies_registry()
    for name, opts in studies.items():
        registry[name].quick(opts)
    return run, studies


def quick_changes(scene) -> list:
    """What quick mode changes in ``scene``, one ``"path: before -> after"`` per changed setting (run, studies), so
    that a quick report says which digits, times and sizes it really used."""
    run, studies = effective_plan(scene, quick=True)
    out = []

    def walk(path, a, b):
        if isinstance(a, dict) and isinstance(b, dict):
            for k in a:
                if k in b:
                    walk(f"{path}.{k}" if path else k, a[k], b[k])
        elif (isinstance(a, list) and isinstance(b, list) and len(a) == len(b)
              and any(isinstance(v, dict) for v in a)):
            for i, (x, y) in enumerate(zip(a, b)):
                walk(f"{path}[{i}]", x, y)
        elif a != b:
            out.append(f"{path}: {_setting(a)} -> {_setting(b)}")

    walk("run", scene.run or {}, run or {})
    walk("", {"studies": scene.studies}, {"studies": studies})
    return out


def _setting(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, list):
        shown = ", ".join(_setting(x) for x in v[:3 if len(v) > 8 else len(v)])
        return f"[{shown}, ... ({len(v)} values)]" if len(v) > 8 else f"[{shown}]"
    return str(v)
