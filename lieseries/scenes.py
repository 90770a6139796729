"""Scenes: what to integrate, how, and which studies and plots a report needs; nothing more is computed.

A scene is a TOML file::

    name = "default"
    title = "Asymmetric rigid body, T = 20"
    description = "..."

    [model]                      # or several [[models]] with a `label` each, sharing [initial]
    kind = "euler_poisson"       # "euler_poisson" | "damped_euler_poisson" | "sphere" | "sphere_dirac"
    inertia = [1, 2, 3]          # euler_poisson: 3 moments or a 3x3 list; bracket = "chetaev" | "intermediate"
                                 # damped_euler_poisson: the same and `damping` (>= 0)
                                 # sphere: mass, radius, chart (0, 1, 2), edge, atlas (true: runs switch charts,
                                 #   ls.integrate(..., atlas=True));  sphere_dirac: mass, radius
    [initial]
    omega = [1, "0.1", "0.5"]    # euler_poisson: omega, optional R0 (3x3);  spheres: x, v
                                 # numbers may be strings: "0.1" is exactly 1/10
    [run]
    t = 20
    samples = 101                # output times (invariant drift and the trajectory plot)
    quick_t = 2                  # optional: the final time in quick mode (default: t)
    methods = [
      { method = "taylor", precision = "double" },            # tol optional
      { method = "lie", dps = 30 },                           # tol, order optional
      { method = "scipy", rtol = 1e-12 },                     # atol optional
      { method = "mpmath", dps = 20, t_max = 1 },             # capped at |t| <= t_max
    ]

    [studies.error_vs_order]     # t or t_fraction (of the theoretical radius); orders or max_order (with
                                 # min_order, step); dps; fit_min_order (default: fit the upper half)
    [studies.work_precision]     # t (default run.t), methods (settings may be lists), repeat
    [studies.drift]              # t, precision, samples, tol, ensemble, perturbation, seed, first

    [report]
    plots = ["trajectory", "error_vs_order", "work_precision", "drift"]   # default: one per study present

    [stability]                  # optional: how the stability study (lieseries.studies.stability) reads the scene
    analysis = "saddle"          # "none" | "saddle" | "scaled" | "drift" | "stiff" | "divergence" | "atlas"
    headline = "heyoka double"   # the method (label) of the case's row in the one-row-per-case table
    expect = "success"           # the status that row should end with; expect_message: a text its message holds
                                 # invariants: the ones whose drift the row reports (default: all of the model's)
                                 # saddle: threshold; divergence: beyond, inside, orders, dps (see studies.stability)

Scenes with a [stability] table are the extreme and stiff cases. They live in ``validation/scenes/extreme/``
(:func:`extreme_scenes`), apart from the built-in scenes whose runs must all succeed; :func:`load_scene` finds them
by name too.

Validation is strict: an unknown model kind, a missing required field, a field of the wrong type or an unknown
field raises :class:`SceneError` naming the field by its dotted path (``run.methods[1].precision``).

Built-in scenes live in ``validation/scenes/*.toml`` of the repository (override the folder with the
environment variable ``LIESERIES_SCENES``). :func:`run_scene` computes what a scene asks for and returns a
:class:`SceneResult` (data); :func:`lieseries.report.write_report` writes it.
"""

from __future__ import annotations

import copy
import difflib
import os
import platform
import time as _time
import tomllib
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import mpmath as mp
import numpy as np

from .precision import resolve_precision, to_fraction

__all__ = [
    "SceneError",
    "Scene",
    "SceneResult",
    "load_scene",
    "parse_scene",
    "builtin_scenes",
    "extreme_scenes",
    "scenes_dir",
    "run_scene",
    "MODEL_KINDS",
    "PLOTS",
    "STUDIES",
]

MODEL_KINDS = ("euler_poisson", "damped_euler_poisson", "sphere", "sphere_dirac")
STUDIES = ("error_vs_order", "work_precision", "drift")
PLOTS = ("trajectory", "error_vs_order", "work_precision", "drift")
_FAMILY = {"euler_poisson": "rigid_body", "damped_euler_poisson": "rigid_body", "sphere": "sphere",
           "sphere_dirac": "sphere"}
#: Sub-folder of the scenes folder holding the extreme and stiff cases (scenes with a [stability] table).
EXTREME_FOLDER = "extreme"
#: What the stability study computes for a scene ([stability].analysis).
ANALYSES = ("none", "saddle", "scaled", "drift", "stiff", "divergence", "atlas")

#: Bits of the initial state handed to every method (each rounds it once to its own precision).
INITIAL_BITS = 256


class SceneError(ValueError):
    """A scene file is invalid; the message names the field by its dotted path."""


# -- field checkers --------------------------------------------------------------------------------------------
def _show(v) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def _fail(path: str, what: str, value):
    raise SceneError(f"`{path}` must be {what}; got {_show(value)}")


def _number(value, path, *, positive=False, nonzero=False, below_one=False, what="a number"):
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        _fail(path, what + ' (a decimal string such as "0.1" is read exactly)', value)
    try:
        q = to_fraction(value, path)
    except (TypeError, ValueError):
        _fail(path, what + ' (a decimal string such as "0.1" is read exactly)', value)
    if positive and q <= 0:
        _fail(path, "a positive number", value)
    if nonzero and q == 0:
        _fail(path, "a nonzero number", value)
    if below_one and not (0 < q < 1):
        _fail(path, "a number between 0 and 1", value)
    return value


def _positive(value, path):
    return _number(value, path, positive=True)


def _nonnegative(value, path):
    _number(value, path)
    if to_fraction(value, path) < 0:
        _fail(path, "a number >= 0", value)
    return value


def _fraction01(value, path):
    return _number(value, path, below_one=True)


def _tol(value, path):
    return _number(value, path, below_one=True, what="a tolerance (a number between 0 and 1)")


def _integer(lo=None, hi=None):
    def check(value, path):
        if isinstance(value, bool) or not isinstance(value, int):
            _fail(path, "an integer", value)
        if lo is not None and value < lo:
            _fail(path, f"an integer >= {lo}", value)
        if hi is not None and value > hi:
            _fail(path, f"an integer <= {hi}", value)
        return value

    return check


def _boolean(value, path):
    if not isinstance(value, bool):
        _fail(path, "true or false", value)
    return value


def _string(value, path):
    if not isinstance(value, str):
        _fail(path, "a string", value)
    return value


def _choice(*choices):
    def check(value, path):
        if value not in choices:
            raise SceneError(f"`{path}` must be one of {', '.join(repr(c) for c in choices)}; got {_show(value)}")
        return value

    return check


def _vector3(value, path):
    if not isinstance(value, list) or len(value) != 3:
        _fail(path, "a list of 3 numbers", value)
    for i, v in enumerate(value):
        _number(v, f"{path}[{i}]")
    return value


def _matrix3(value, path):
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) and len(r) == 3 for r in value)):
        _fail(path, "a 3x3 list of numbers", value)
    for i, r in enumerate(value):
        for j, v in enumerate(r):
            _number(v, f"{path}[{i}][{j}]")
    return value


def _inertia(value, path):
    what = "a list of 3 numbers or a 3x3 list"
    if not isinstance(value, list) or len(value) != 3:
        _fail(path, what, value)
    if all(isinstance(r, list) for r in value):
        if not all(len(r) == 3 for r in value):
            _fail(path, what, value)
        for i, r in enumerate(value):
            for j, v in enumerate(r):
                _number(v, f"{path}[{i}][{j}]")
    else:
        for i, v in enumerate(value):
            if isinstance(v, list):
                _fail(path, what, value)
            _number(v, f"{path}[{i}]")
    return value


def _precision(value, path):
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise SceneError(f"`{path}`: unknown precision {_show(value)}; use 'double', 'long double', 'quad' or an "
                         "integer number of bits")
    try:
        resolve_precision(value, path)
    except (TypeError, ValueError) as err:
        raise SceneError(f"`{path}`: unknown precision {_show(value)}; use 'double', 'long double', 'quad' or an "
                         f"integer number of bits ({err})") from None
    return value


def _list_of(check, *, allow_scalar=True, nonempty=True):
    """A checker accepting ``check``-valid values or (in studies) lists of them."""

    def wrapped(value, path):
        if isinstance(value, list):
            if nonempty and not value:
                _fail(path, "a non-empty list", value)
            return [check(v, f"{path}[{i}]") for i, v in enumerate(value)]
        if not allow_scalar:
            _fail(path, "a list", value)
        return check(value, path)

    return wrapped


def _orders(value, path):
    if not isinstance(value, list) or not value:
        _fail(path, "a non-empty list of non-negative integers", value)
    for i, v in enumerate(value):
        _integer(0, 10_000)(v, f"{path}[{i}]")
    return value


def _plots(value, path):
    if not isinstance(value, list):
        _fail(path, f"a list of plot names ({', '.join(PLOTS)})", value)
    for i, v in enumerate(value):
        if v not in PLOTS:
            raise SceneError(f"`{path}[{i}]`: unknown plot {_show(v)}; known: {', '.join(PLOTS)}")
    return value


_REQUIRED = object()


def _table(data, path: str, spec: dict, what: str = "a table") -> dict:
    """Check a table against ``spec`` (name -> (checker, default or _REQUIRED)); return it with defaults."""
    if not isinstance(data, dict):
        raise SceneError(f"`{path}` must be {what}; got {_show(data)}")
    for key in data:
        if key not in spec:
            full = f"{path}.{key}" if path else key
            near = difflib.get_close_matches(key, list(spec), n=1)
            hint = f" (did you mean `{near[0]}`?)" if near else ""
            raise SceneError(f"unknown field `{full}`{hint}; known: {', '.join(spec)}")
    out = {}
    for key, (check, default) in spec.items():
        full = f"{path}.{key}" if path else key
        if key in data:
            out[key] = check(data[key], full) if check is not None else data[key]
        elif default is _REQUIRED:
            raise SceneError(f"missing required field `{full}`")
        else:
            out[key] = copy.deepcopy(default)
    return out


# -- schema ----------------------------------------------------------------------------------------------------
_MODEL_FIELDS = {
    "euler_poisson": {"inertia": (_inertia, _REQUIRED), "bracket": (_choice("chetaev", "intermediate"), "chetaev")},
    "damped_euler_poisson": {"inertia": (_inertia, _REQUIRED), "damping": (_nonnegative, _REQUIRED),
                             "bracket": (_choice("chetaev", "intermediate"), "chetaev")},
    "sphere": {"mass": (_positive, 1), "radius": (_positive, 1), "chart": (_integer(0, 2), 2),
               "edge": (_fraction01, 0.05), "atlas": (_boolean, False)},
    "sphere_dirac": {"mass": (_positive, 1), "radius": (_positive, 1)},
}
_INITIAL_FIELDS = {
    "rigid_body": {"omega": (_vector3, _REQUIRED), "R0": (_matrix3, None)},
    "sphere": {"x": (_vector3, _REQUIRED), "v": (_vector3, _REQUIRED)},
}


def _method_fields(lists: bool) -> dict:
    L = (lambda c: _list_of(c)) if lists else (lambda c: c)
    return {
        "taylor": {"precision": (L(_precision), "double"), "tol": (L(_tol), None)},
        "lie": {"dps": (L(_integer(10, 10_000)), 30), "tol": (L(_positive), None),
                "order": (_integer(1, 10_000), None)},
        "scipy": {"rtol": (L(_tol), 1e-10), "atol": (_positive, None)},
        "mpmath": {"dps": (L(_integer(5, 10_000)), 15), "t_max": (_positive, 2.0)},
    }


def _method(data, path, lists: bool):
    if not isinstance(data, dict):
        raise SceneError(f"`{path}` must be a table such as {{ method = \"taylor\", precision = \"double\" }}; "
                         f"got {_show(data)}")
    if "method" not in data:
        raise SceneError(f"missing required field `{path}.method` (one of taylor, lie, scipy, mpmath)")
    name = data["method"]
    fields = _method_fields(lists)
    if name not in fields:
        raise SceneError(f"`{path}.method`: unknown method {_show(name)}; known: {', '.join(fields)}")
    spec = {"method": (None, _REQUIRED), "label": (_string, None)}
    spec.update(fields[name])
    out = _table(data, path, spec)
    if out["label"] is None:
        del out["label"]
    return out


def _methods(lists: bool):
    def check(value, path):
        if not isinstance(value, list) or not value:
            _fail(path, "a non-empty list of method tables", value)
        return [_method(m, f"{path}[{i}]", lists) for i, m in enumerate(value)]

    return check


_RUN_FIELDS = {
    "t": (lambda v, p: _number(v, p, nonzero=True), _REQUIRED),
    "methods": (_methods(False), _REQUIRED),
    "samples": (_integer(2, 100_000), 101),
    "repeat": (_integer(1, 100), 3),
    "quick_t": (lambda v, p: _number(v, p, nonzero=True), None),
}


def _statuses():
    from .solution import STATUSES

    return tuple(STATUSES)


def _stability_fields() -> dict:
    return {
        "analysis": (_choice(*ANALYSES), "none"),
        "headline": (_string, None),
        "headline_model": (_string, None),
        "expect": (_choice(*_statuses()), "success"),
        "expect_message": (_string, None),
        "threshold": (_positive, 1e-3),
        "beyond": (_positive, 1.5),
        "inside": (_fraction01, 0.5),
        "orders": (_orders, None),
        "dps": (_integer(15, 1000), 40),
        "invariants": (_list_of(_string, allow_scalar=False), None),
        "note": (_string, ""),
    }


_STUDY_FIELDS = {
    "error_vs_order": {
        "t": (lambda v, p: _number(v, p, nonzero=True), None),
        "t_fraction": (_fraction01, None),
        "orders": (_orders, None),
        "max_order": (_integer(1, 10_000), None),
        "min_order": (_integer(0, 10_000), 1),
        "step": (_integer(1, 1000), 1),
        "dps": (_integer(15, 10_000), 60),
        "fit_min_order": (_integer(0, 10_000), None),
    },
    "work_precision": {
        "t": (lambda v, p: _number(v, p, nonzero=True), None),
        "methods": (_methods(True), None),
        "repeat": (_integer(1, 100), 3),
    },
    "drift": {
        "t": (_positive, _REQUIRED),
        "precision": (_precision, "double"),
        "samples": (_integer(6, 100_000), 200),
        "tol": (_tol, None),
        "ensemble": (_integer(1, 1000), 1),
        "perturbation": (_positive, 1e-9),
        "seed": (_integer(0), 0),
        "first": (_positive, None),
    },
}


@dataclass
class ModelSpec:
    """One model of a scene: its label, kind and parameters (as given, validated)."""

    label: str
    kind: str
    params: dict

    def build(self):
        from .models import DampedEulerPoisson, EulerPoisson, Sphere, SphereDirac

        if self.kind == "euler_poisson":
            return EulerPoisson(self.params["inertia"], bracket=self.params["bracket"])
        if self.kind == "damped_euler_poisson":
            return DampedEulerPoisson(self.params["inertia"], damping=self.params["damping"],
                                      bracket=self.params["bracket"])
        if self.kind == "sphere":
            p = self.params
            return Sphere(mass=p["mass"], radius=p["radius"], chart=p["chart"], edge=float(to_fraction(p["edge"])))
        return SphereDirac(mass=self.params["mass"], radius=self.params["radius"])

    def to_dict(self) -> dict:
        return {"label": self.label, "kind": self.kind, **{k: _jsonable(v) for k, v in self.params.items()}}


@dataclass
class Scene:
    """A validated scene (see the module docstring).

    Attributes
    ----------
    name, title, description : str
    models : list of ModelSpec
    initial : dict               initial data shared by the models
    run : dict or None           the [run] table with defaults, None when absent
    studies : dict               study name -> options (only the studies the scene asks for)
    plots : list of str          the plots the report draws
    source : str                 the TOML text as given
    path : str or None
    stability : dict or None     the [stability] table with defaults (extreme and stiff cases), else None
    """

    name: str
    title: str
    description: str
    models: list
    initial: dict
    run: dict | None
    studies: dict
    plots: list
    source: str = ""
    path: str | None = None
    stability: dict | None = None

    @property
    def family(self) -> str:
        return _FAMILY[self.models[0].kind]

    def build_models(self) -> list:
        """[(label, model)] for every model of the scene."""
        return [(m.label, m.build()) for m in self.models]

    def initial_state(self, model, precision=INITIAL_BITS):
        """The initial state of ``model`` from the scene's [initial] table, in ``precision``."""
        ini = self.initial
        if self.family == "rigid_body":
            return model.initial_state(ini["omega"], R0=ini.get("R0"), precision=precision)
        return model.initial_state(ini["x"], ini["v"], precision=precision)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "title": self.title,
            "description": self.description,
            "models": [m.to_dict() for m in self.models],
            "initial": _jsonable(self.initial),
            "run": _jsonable(self.run),
            "studies": _jsonable(self.studies),
            "plots": list(self.plots),
            "path": self.path,
            **({"stability": _jsonable(self.stability)} if self.stability is not None else {}),
        }


def _jsonable(v):
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items() if x is not None}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, Fraction):
        return float(v)
    return v


def _model_spec(data, path, label_required=False) -> ModelSpec:
    if not isinstance(data, dict):
        raise SceneError(f"`{path}` must be a table with a `kind`; got {_show(data)}")
    if "kind" not in data:
        raise SceneError(f"missing required field `{path}.kind` (one of {', '.join(MODEL_KINDS)})")
    kind = data["kind"]
    if kind not in MODEL_KINDS:
        raise SceneError(f"`{path}.kind`: unknown model kind {_show(kind)}; known: {', '.join(MODEL_KINDS)}")
    spec = {"kind": (None, _REQUIRED), "label": (_string, _REQUIRED if label_required else None)}
    spec.update(_MODEL_FIELDS[kind])
    out = _table(data, path, spec)
    label = out.pop("label") or {"euler_poisson": "rigid body", "damped_euler_poisson": "damped rigid body",
                                 "sphere": "sphere (5-d chart)", "sphere_dirac": "sphere (Dirac)"}[kind]
    out.pop("kind")
    return ModelSpec(label=label, kind=kind, params=out)


def parse_scene(data, source: str = "<scene>", path: str | None = None) -> Scene:
    """Validate a scene given as TOML text or as a parsed dict.

    Raises
    ------
    SceneError
        Naming the offending field by its dotted path.
    """
    text = ""
    if isinstance(data, (str, bytes)):
        text = data.decode() if isinstance(data, bytes) else data
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise SceneError(f"{source} is not valid TOML: {err}") from None
    if not isinstance(data, dict):
        raise SceneError(f"{source}: a scene must be a TOML table; got {_show(data)}")
    top = {
        "name": (_string, _REQUIRED),
        "title": (_string, _REQUIRED),
        "description": (_string, ""),
        "model": (None, None),
        "models": (None, None),
        "initial": (None, _REQUIRED),
        "run": (None, None),
        "studies": (None, None),
        "report": (None, None),
        "stability": (None, None),
    }
    d = _table(data, "", top)
    # models
    if (d["model"] is None) == (d["models"] is None):
        raise SceneError("a scene needs exactly one of `model` (a table) or `models` (an array of tables); "
                         + ("got both" if d["model"] is not None else "missing required field `model`"))
    if d["model"] is not None:
        models = [_model_spec(d["model"], "model")]
    else:
        if not isinstance(d["models"], list) or not d["models"]:
            _fail("models", "a non-empty array of model tables ([[models]])", d["models"])
        models = [_model_spec(m, f"models[{i}]", label_required=True) for i, m in enumerate(d["models"])]
        labels = [m.label for m in models]
        if len(set(labels)) != len(labels):
            raise SceneError(f"`models[*].label` must be distinct; got {labels}")
    families = {_FAMILY[m.kind] for m in models}
    if len(families) > 1:
        raise SceneError("`models` must all share the initial data: mix of rigid-body and sphere kinds "
                         f"({', '.join(m.kind for m in models)})")
    family = families.pop()
    initial = _table(d["initial"], "initial", _INITIAL_FIELDS[family])
    run = _table(d["run"], "run", _RUN_FIELDS) if d["run"] is not None else None
    studies = {}
    if d["studies"] is not None:
        if not isinstance(d["studies"], dict):
            _fail("studies", "a table of study tables", d["studies"])
        for key, val in d["studies"].items():
            if key not in _STUDY_FIELDS:
                near = difflib.get_close_matches(key, list(_STUDY_FIELDS), n=1)
                hint = f" (did you mean `{near[0]}`?)" if near else ""
                raise SceneError(f"unknown field `studies.{key}`{hint}; known: {', '.join(_STUDY_FIELDS)}")
            studies[key] = _table(val, f"studies.{key}", _STUDY_FIELDS[key])
    # report
    rep = _table(d["report"] if d["report"] is not None else {}, "report", {"plots": (_plots, None)})
    plots = rep["plots"] if rep["plots"] is not None else [p for p in PLOTS if p in studies]
    for i, p in enumerate(plots):
        if p == "trajectory" and run is None:
            raise SceneError(f"`report.plots[{i}]` asks for 'trajectory' but the scene has no [run] table")
        if p in STUDIES and p not in studies:
            raise SceneError(f"`report.plots[{i}]` asks for {p!r} but the scene has no [studies.{p}] table")
    if run is None and not studies:
        raise SceneError("the scene asks for nothing: add a [run] table or a [studies.*] table")
    _check_studies(studies, run, models)
    stability = None
    if d["stability"] is not None:
        stability = _table(d["stability"], "stability", _stability_fields())
        _check_stability(stability, run, studies, plots, models)
    scene = Scene(
        name=d["name"], title=d["title"], description=d["description"].strip(), models=models, initial=initial,
        run=run, studies=studies, plots=list(dict.fromkeys(plots)), source=text, path=path, stability=stability,
    )
    _check_physics(scene, "model" if d["model"] is not None else "models")
    return scene


def _check_studies(studies, run, models):
    ev = studies.get("error_vs_order")
    if ev is not None:
        if (ev["t"] is None) == (ev["t_fraction"] is None):
            raise SceneError("`studies.error_vs_order` needs exactly one of `t` (a time) or `t_fraction` (a fraction "
                             "of the theoretical radius of convergence)" + (
                                 "; got both" if ev["t"] is not None else "; missing required field "
                                 "`studies.error_vs_order.t`"))
        if ev["orders"] is not None and ev["max_order"] is not None:
            raise SceneError("`studies.error_vs_order` takes `orders` or `max_order`, not both")
        if ev["t_fraction"] is not None and all(m.kind == "sphere_dirac" for m in models):
            raise SceneError("`studies.error_vs_order.t_fraction` needs a theoretical radius, which the Dirac form "
                             "does not have; give `t` instead")
    wp = studies.get("work_precision")
    if wp is not None and wp["t"] is None:
        if run is None:
            raise SceneError("missing required field `studies.work_precision.t` (there is no [run] to take it from)")
        wp["t"] = run["t"]


def _check_stability(st, run, studies, plots, models):
    """The [stability] table must match what the scene computes (its headline is a run of the scene, ...)."""
    from .studies.work_precision import method_label, normalize_method

    if run is None:
        raise SceneError("`stability` needs a [run] table: the stability row of a case is one of its runs")
    labels = [method_label(normalize_method(m, f"run.methods[{i}]")) for i, m in enumerate(run["methods"])]
    if st["headline"] is None:
        st["headline"] = labels[0]
    elif st["headline"] not in labels:
        raise SceneError(f"`stability.headline` must be the label of one of the run's methods ({', '.join(labels)}); "
                         f"got {_show(st['headline'])}")
    mlabels = [m.label for m in models]
    if st["headline_model"] is None:
        st["headline_model"] = mlabels[0]
    elif st["headline_model"] not in mlabels:
        raise SceneError(f"`stability.headline_model` must be one of the model labels ({', '.join(mlabels)}); got "
                         f"{_show(st['headline_model'])}")
    if st["invariants"] is not None:
        known = {"euler_poisson": ("energy", "M2", "L1", "L2", "L3", "orthogonality", "det_R"),
                 "damped_euler_poisson": ("energy", "M2", "L1", "L2", "L3", "orthogonality", "det_R"),
                 "sphere": ("energy", "x2", "L1", "L2", "L3"), "sphere_dirac": ("energy", "x2", "L1", "L2", "L3")}
        for i, name in enumerate(st["invariants"]):
            if any(name not in known[m.kind] for m in models):
                raise SceneError(f"`stability.invariants[{i}]`: unknown invariant {_show(name)}; known: "
                                 f"{', '.join(known[models[0].kind])}")
    analysis = st["analysis"]
    if analysis == "saddle":
        if "trajectory" not in plots:
            raise SceneError("`stability.analysis` = 'saddle' reads the errors along the run: add 'trajectory' to "
                             "`report.plots`")
        if any(m.kind not in ("euler_poisson",) for m in models):
            raise SceneError("`stability.analysis` = 'saddle' is for the free rigid body (kind 'euler_poisson')")
    if analysis == "drift" and "drift" not in studies:
        raise SceneError("`stability.analysis` = 'drift' needs a [studies.drift] table")
    if analysis == "divergence":
        if "error_vs_order" not in studies:
            raise SceneError("`stability.analysis` = 'divergence' needs a [studies.error_vs_order] table (the error "
                             "of the truncated series beyond the radius)")
        if any(m.kind not in ("euler_poisson", "sphere") for m in models):
            raise SceneError("`stability.analysis` = 'divergence' needs a model with a known radius of convergence "
                             "(kind 'euler_poisson' or 'sphere')")
    if analysis == "atlas" and not any(m.kind == "sphere" for m in models):
        raise SceneError("`stability.analysis` = 'atlas' needs a model of kind 'sphere'")


def _check_physics(scene: Scene, where: str):
    for i, spec in enumerate(scene.models):
        path = where if where == "model" else f"models[{i}]"
        try:
            model = spec.build()
        except (TypeError, ValueError) as err:
            raise SceneError(f"`{path}`: {err}") from None
        try:
            scene.initial_state(model, precision="double")
        except (TypeError, ValueError) as err:
            raise SceneError(f"`initial` ({spec.label}): {err}") from None


# -- finding scenes --------------------------------------------------------------------------------------------
def scenes_dir() -> Path:
    """The folder of the built-in scenes (``LIESERIES_SCENES`` overrides it)."""
    env = os.environ.get("LIESERIES_SCENES")
    if env:
        return Path(env)
    import lieseries

    return Path(lieseries.__file__).resolve().parents[1] / "validation" / "scenes"


def builtin_scenes() -> list:
    """[(name, title)] of the built-in scenes, sorted by name (``default`` first)."""
    folder = scenes_dir()
    out = []
    if folder.is_dir():
        for p in sorted(folder.glob("*.toml")):
            try:
                data = tomllib.loads(p.read_text(encoding="utf-8"))
                out.append((p.stem, str(data.get("title", ""))))
            except (OSError, tomllib.TOMLDecodeError):
                out.append((p.stem, "(unreadable scene file)"))
    out.sort(key=lambda nt: (nt[0] != "default", nt[0]))
    return out


def extreme_scenes() -> list:
    """[(name, title)] of the extreme and stiff cases (``validation/scenes/extreme/*.toml``), sorted by name."""
    folder = scenes_dir() / EXTREME_FOLDER
    out = []
    if folder.is_dir():
        for p in sorted(folder.glob("*.toml")):
            try:
                data = tomllib.loads(p.read_text(encoding="utf-8"))
                out.append((p.stem, str(data.get("title", ""))))
            except (OSError, tomllib.TOMLDecodeError):
                out.append((p.stem, "(unreadable scene file)"))
    return out


def load_scene(name_or_path) -> Scene:
    """A built-in scene (or an extreme case, see :func:`extreme_scenes`) by name, or a scene file by path.

    Raises
    ------
    SceneError
        Unknown name, unreadable file, invalid scene.
    """
    if isinstance(name_or_path, Scene):
        return name_or_path
    s = str(name_or_path)
    p = Path(s)
    looks_like_path = s.endswith(".toml") or os.sep in s or "/" in s
    if not looks_like_path:
        cand = scenes_dir() / f"{s}.toml"
        extreme = scenes_dir() / EXTREME_FOLDER / f"{s}.toml"
        if cand.is_file():
            p = cand
        elif extreme.is_file():
            p = extreme
        else:
            names = [n for n, _ in builtin_scenes()] + [n for n, _ in extreme_scenes()]
            near = difflib.get_close_matches(s, names, n=1)
            hint = f" (did you mean '{near[0]}'?)" if near else ""
            known = ", ".join(names) or f"none found in {scenes_dir()}"
            raise SceneError(f"unknown scene {s!r}{hint}; built-in scenes: {known}; or give the path of a .toml file")
    if not p.is_file():
        raise SceneError(f"scene file {s!r} not found")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise SceneError(f"cannot read scene file {s!r}: {err}") from None
    return parse_scene(text, source=str(p), path=str(p))


# -- quick mode ------------------------------------------------------------------------------------------------
def _thin(values, keep=3):
    if not isinstance(values, list) or len(values) <= keep:
        return values
    idx = sorted({0, len(values) // 2, len(values) - 1}) if keep >= 3 else [0, len(values) - 1]
    return [values[i] for i in idx]


def effective_plan(scene: Scene, quick: bool = False):
    """(run, studies) tables as they will be run: ``quick`` scales the studies down for CI.

    Quick mode: at most 41 output times in the run, which ends at ``run.quick_t`` when the scene gives one; error
    vs order up to half the largest order (at least 12) and at most 40 digits; work-precision with at most three
    values per setting, one repeat and mpmath capped at t = 0.5; drift over a tenth of the time, at most 60
    samples and 4 ensemble members.
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
            if m["method"] == "mpmath":
                m["t_max"] = min(float(to_fraction(m["t_max"])), 0.5)
    ev = studies.get("error_vs_order")
    if ev is not None:
        orders = _orders_of(ev)
        top = max(12, max(orders) // 2)
        ev["orders"] = [o for o in orders if o <= top]
        ev["max_order"] = None
        ev["dps"] = min(ev["dps"], 40)
    wp = studies.get("work_precision")
    if wp is not None:
        wp["repeat"] = 1
        if wp["methods"] is not None:
            for m in wp["methods"]:
                for k in ("tol", "rtol", "precision"):
                    if isinstance(m.get(k), list):
                        m[k] = _thin(m[k])
                if m["method"] == "mpmath":
                    m["t_max"] = min(float(to_fraction(m["t_max"])), 0.5)
                    if isinstance(m.get("dps"), list):
                        m["dps"] = m["dps"][:1]
    dr = studies.get("drift")
    if dr is not None:
        dr["t"] = float(to_fraction(dr["t"])) / 10
        dr["samples"] = min(dr["samples"], 60)
        dr["ensemble"] = min(dr["ensemble"], 4)
        if dr["first"] is not None:
            dr["first"] = min(float(to_fraction(dr["first"])), dr["t"] / 100)
    return run, studies


def _orders_of(ev) -> list:
    if ev.get("orders") is not None:
        return sorted(set(int(o) for o in ev["orders"]))
    top = ev.get("max_order") or 40
    return list(range(ev.get("min_order", 1), top + 1, ev.get("step", 1)))


# -- running ---------------------------------------------------------------------------------------------------
@dataclass
class RunRow:
    """One method of the [run] table on one model."""

    model: str
    method: str
    label: str
    precision: str
    setting: str
    t: float
    error: float | None
    max_error: float | None
    drift: dict
    steps: int | None
    order: int | None
    build_time: float | None
    run_time: float | None
    status: str
    message: str
    final_state: list | None = None
    scaled_error: float | None = None
    extra: dict = field(default_factory=dict)

    @property
    def max_drift(self) -> float | None:
        vals = [v for v in self.drift.values() if v is not None]
        return max(vals) if vals else None

    def to_dict(self) -> dict:
        return {
            "model": self.model, "method": self.method, "label": self.label, "precision": self.precision,
            "setting": self.setting, "t": self.t, "error": self.error, "max_error": self.max_error,
            "drift": dict(self.drift), "max_drift": self.max_drift, "steps": self.steps, "order": self.order,
            "build_time": self.build_time, "run_time": self.run_time, "status": self.status,
            "message": self.message, "scaled_error": self.scaled_error, "extra": dict(self.extra),
        }


@dataclass
class SceneResult:
    """Everything a scene run computed (plain data; :func:`lieseries.report.write_report` writes it).

    Attributes
    ----------
    scene : Scene
    quick : bool
    run : dict or None         {"t", "reference", "rows": [RunRow], "invariants": [...]} or None
    trajectories : dict        model label -> {"quantity", "names", "times", "values", "errors": {label: [...]}}
    studies : dict             study name -> list of (model label, study result)
    notes : list of str        what was left out and why
    wall_time : float
    environment : dict
    report_path : str or None  set when the report was written
    """

    scene: Scene
    quick: bool
    run: dict | None = None
    trajectories: dict = field(default_factory=dict)
    studies: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    wall_time: float = 0.0
    environment: dict = field(default_factory=dict)
    report_path: str | None = None
    created: str = ""

    def to_dict(self) -> dict:
        run = None
        if self.run is not None:
            run = {k: v for k, v in self.run.items() if k != "rows"}
            run["rows"] = [r.to_dict() for r in self.run["rows"]]
        return {
            "scene": self.scene.to_dict(),
            "quick": self.quick,
            "run": run,
            "trajectories": self.trajectories,
            "studies": {name: [{"model": lab, **res.to_dict()} for lab, res in items]
                        for name, items in self.studies.items()},
            "notes": list(self.notes),
            "wall_time": self.wall_time,
            "environment": dict(self.environment),
            "created": self.created,
        }


def _environment() -> dict:
    import heyoka
    import numpy
    import scipy

    import lieseries

    return {
        "lieseries": getattr(lieseries, "__version__", "?"),
        "python": platform.python_version(),
        "heyoka": getattr(heyoka, "__version__", "?"),
        "numpy": numpy.__version__,
        "mpmath": mp.__version__,
        "scipy": scipy.__version__,
        "platform": platform.platform(),
    }


def _make_progress(progress, title):
    from .progress import ProgressBar, null_progress

    if progress is True:
        return ProgressBar(title)
    if progress in (False, None):
        return _Null(null_progress)
    return _Null(progress)


class _Null:
    """Wraps a plain callable into the bar interface (call + close)."""

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, done, total, label=""):
        self.fn(done, total, label)

    def close(self):
        pass


def _needed_bits(specs) -> int:
    bits = INITIAL_BITS
    for s in specs:
        if s["method"] == "taylor":
            for p in (s["precision"] if isinstance(s["precision"], list) else [s["precision"]]):
                bits = max(bits, resolve_precision(p).bits + 64)
        if s["method"] in ("lie", "mpmath"):
            for d in (s["dps"] if isinstance(s["dps"], list) else [s["dps"]]):
                bits = max(bits, int(d * 3.33) + 64)
    return bits


def _invariants_of(model, states, digits: int):
    """model.invariants of a list of states in any number type (mpf states evaluated with ``digits``)."""
    if not states:
        return None
    first = states[0]
    if isinstance(first, np.ndarray) and first.dtype != object:
        arr = np.stack(states)
        return model.invariants(arr)
    # mpf (or Fraction) states: hand them over exactly as a heyoka real array (the model reads their precision)
    prec = resolve_precision(int(digits * 3.33) + 32)
    arr = np.stack([prec.array([to_fraction(v) for v in s]) for s in states])
    return model.invariants(arr)


def _trajectory_quantity(model, label):
    from .models import EulerPoisson

    if isinstance(model, EulerPoisson):
        return "angular velocity Omega", ("Omega1", "Omega2", "Omega3")
    return "position x", ("x1", "x2", "x3")


def _plot_values(model, ref_rows):
    """Float values of the plotted quantity (Omega, or the position) at the output times, from the reference."""
    from .models import EulerPoisson

    if isinstance(model, EulerPoisson):
        Iinv = np.linalg.inv(model.inertia)
        return [[float(c) for c in Iinv @ np.array([float(v) for v in row[9:12]])] for row in ref_rows]
    return [[float(v) for v in row[:3]] for row in ref_rows]


def _has_closed_form(model) -> bool:
    """True when the studies' closed-form references describe ``model`` (the damped body has none: it is an
    EulerPoisson subclass, but its motion is not the free body's)."""
    from .models import DampedEulerPoisson
    from .studies import has_exact_solution

    return has_exact_solution(model) and not isinstance(model, DampedEulerPoisson)


def _numerical_reference(model, y0, t, dps, bits):
    """The studies' numerical reference (heyoka, >= 256 bits, tol 2^-250) at ``t``, as a Reference."""
    from .studies import (NUMERICAL_REFERENCE_BITS, NUMERICAL_REFERENCE_TOL, Reference, observable_names,
                          observables)
    from .taylor import integrate

    bits = max(NUMERICAL_REFERENCE_BITS, bits)
    sol = integrate(model, y0, t=t, precision=bits, tol=NUMERICAL_REFERENCE_TOL)
    if not sol.success:
        raise RuntimeError(f"the numerical reference (heyoka, {bits} bits) did not reach t = {float(t)}: "
                           f"{sol.message}")
    return Reference(float(t), observables(model, sol.y[-1], dps), observable_names(model), "numerical",
                     f"heyoka, {bits} bits, tol 2^-250", dps)


def _reference_at(model, y0, t, dps, bits):
    from .studies import reference_solution

    if _has_closed_form(model):
        return reference_solution(model, y0, t, dps=dps)
    return _numerical_reference(model, y0, t, dps, bits)


def _error_groups(model, n):
    """[(indices, kind)] of the compared quantities, for errors relative to their natural scale."""
    from .models import EulerPoisson, Sphere, SphereDirac

    if isinstance(model, EulerPoisson):
        return [(range(0, 9), "unit"), (range(9, 12), "norm")]  # R (a rotation), M (scale |M|)
    if isinstance(model, (Sphere, SphereDirac)):
        return [(range(0, 3), "norm"), (range(3, 6), "norm")]  # x (scale |x|), v (scale |v|)
    return [(range(n), "norm")]


def scaled_error(model, values, reference) -> float:
    """Largest error relative to the natural scale of each compared quantity.

    Rigid body: R against 1 (a rotation), M against |M_ref|. Sphere: x against |x_ref|, v against |v_ref|. Other
    systems: the state against its max-norm (1 when it vanishes). ``values`` and ``reference`` are the
    :func:`lieseries.studies.observables` of a run and of the reference (mpf).
    """
    worst = mp.mpf(0)
    for idx, kind in _error_groups(model, len(values)):
        idx = list(idx)
        err = max(abs(values[i] - reference[i]) for i in idx)
        scale = mp.mpf(1) if kind == "unit" else mp.sqrt(mp.fsum(reference[i] ** 2 for i in idx))
        if scale == 0:
            scale = mp.mpf(1)
        worst = max(worst, err / scale)
    return float(worst)


def _dirac_twin(sphere):
    """The Dirac form of the same sphere: atlas rows are compared and measured as (x, p) states of it."""
    from .models import SphereDirac

    return SphereDirac(mass=sphere.mass_exact, radius=sphere.radius_exact, rtol=sphere.rtol)


def _as_dirac_state(sphere, row, chart, bits):
    """A sphere state written in ``chart``, as the (x, p) state of the Dirac form (``bits`` bits)."""
    from .models.base import state_fractions

    prec = resolve_precision(bits)
    arr = prec.array(state_fractions(row, sphere.dimension, "y"))
    x = sphere.position(arr, chart=int(chart))
    v = sphere.velocity(arr, chart=int(chart))
    m = sphere.mass_exact
    return prec.array([to_fraction(c) for c in x] + [m * to_fraction(c) for c in v])


def _run_atlas_method(sphere, y0, tf, spec, grid, repeat, bits):
    """One method across the sphere's atlas (``atlas=True``): a MethodRun whose states are the Dirac (x, p) of
    each output row (rows of an atlas run are written in different charts), with the chart of each row and the
    number of switches in ``extra``."""
    import lieseries as ls

    from .studies.work_precision import MethodRun, _best_of, _precision_name, _setting, method_label

    m = spec["method"]
    label = method_label(spec)
    if m == "taylor":
        prec = resolve_precision(spec["precision"])

        def call():
            return ls.integrate(sphere, y0, t=grid, tol=spec["tol"], precision=prec, atlas=True)
    elif m == "lie":
        kwargs = {"dps": int(spec["dps"])}
        if spec.get("tol") is not None:
            kwargs["tol"] = spec["tol"]
        if spec.get("order") is not None:
            kwargs["order"] = int(spec["order"])

        def call():
            return ls.lie_integrate(sphere, y0, grid, atlas=True, **kwargs)
    else:
        return MethodRun(m, label, _precision_name(spec), _setting(spec), float(tf), float(tf), status="skipped",
                         message=f"method {m!r} has no atlas runs (use taylor or lie)"), None
    try:
        sol, walls = _best_of(call, repeat)
    except Exception as err:  # a failing method is a row, not the end of the run
        return MethodRun(m, label, _precision_name(spec), _setting(spec), float(tf), float(tf), status="error",
                         message=f"{type(err).__name__}: {err}"), None
    times = [to_fraction(v) for v in sol.t]
    rows = list(sol.y)
    charts = [int(c) for c in sol.charts]
    if sol.y_reached is not None and (not times or times[-1] != to_fraction(sol.t_reached)):
        times.append(to_fraction(sol.t_reached))
        rows.append(sol.y_reached)
        charts.append(int(getattr(sol, "chart_reached", charts[-1] if charts else sphere.chart)))
    states = [_as_dirac_state(sphere, r, c, bits) for r, c in zip(rows, charts)]
    st = sol.stats
    build = float(st.build_time or 0.0)
    run = MethodRun(
        m, label, _precision_name(spec), _setting(spec), float(times[-1]), float(tf), t_exact=times[-1],
        times=[float(v) for v in times], states=states, steps=int(st.steps), order=int(st.order) if st.order else None,
        build_time=build if m == "taylor" else None, run_time=float(min([walls[0] - build] + walls[1:])),
        core_time=float(st.run_time), status=sol.status, message=sol.message,
    )
    extra = {"chart_switches": int(st.extra.get("chart_switches", 0)), "charts": charts}
    if "max_step_over_radius" in st.extra:
        extra["max_step_over_radius"] = float(st.extra["max_step_over_radius"])
    return run, extra


def _do_run(scene, runp, built, bar, notes):
    from .studies import observables, reference_solutions
    from .studies.work_precision import method_label, normalize_method, reference_dps, run_method

    tf = to_fraction(runp["t"], "run.t")
    n_out = runp["samples"]
    grid = [tf * k / (n_out - 1) for k in range(1, n_out)]
    specs = [normalize_method(m, f"run.methods[{i}]") for i, m in enumerate(runp["methods"])]
    dps = reference_dps(specs)
    bits = _needed_bits(specs)
    want_traj = "trajectory" in scene.plots
    rows, trajectories = [], {}
    total = len(built) * (len(specs) + 1)
    done = 0
    inv_names = None
    ref_label = ""
    initial_invariants = {}
    atlas_of = {m.label: bool(m.params.get("atlas", False)) for m in scene.models}
    for mlabel, model in built:
        y0 = scene.initial_state(model, precision=bits)
        bar(done, total, f"{mlabel}: reference")
        refs = {}
        atlas = atlas_of.get(mlabel, False)
        # an atlas run's rows are in several charts: they are measured as (x, p) states of the Dirac form
        measured = _dirac_twin(model) if atlas else model

        def ref_at(time_, _model=model, _y0=y0, _refs=refs):
            # computed when a run needs it: a run that stops early is measured where it stopped, and a
            # numerical reference is not asked to cross the stiff part a run could not cross
            if time_ not in _refs:
                _refs[time_] = _reference_at(_model, _y0, time_, dps, bits)
            return _refs[time_]

        if _has_closed_form(model):
            ref_label = f"{ref_at(tf).label}, {dps} digits"
        else:
            ref_label = f"heyoka, {max(256, bits)} bits, tol 2^-250, {dps} digits"
        refs_grid = None
        if want_traj:
            refs_grid = reference_solutions(model, y0, grid, dps=dps) if _has_closed_form(model) else None
            if refs_grid is None:  # no closed form: heyoka at 256+ bits on the grid
                from .taylor import integrate

                sol = integrate(model, y0, t=grid, precision=max(256, bits), tol=Fraction(1, 2**250))
                refs_grid = [observables(model, y, dps) for y in sol.y]
        done += 1
        inv0 = model.invariants(y0)
        inv_names = list(inv0)
        initial_invariants[mlabel] = {k: float(v) for k, v in inv0.items()}
        traj = None
        if want_traj:
            qname, names = _trajectory_quantity(model, mlabel)
            traj = {"quantity": qname, "names": list(names),
                    "times": [0.0] + [float(g) for g in grid[: len(refs_grid)]],
                    "values": [], "errors": {}, "error_times": {}}
        for spec in specs:
            bar(done, total, f"{mlabel}: {method_label(spec)}")
            extra = {}
            if atlas:
                run, extra = _run_atlas_method(model, y0, tf, spec, grid, runp["repeat"], bits)
                extra = extra or {}
            else:
                run = run_method(model, y0, tf, spec, times=grid, repeat=runp["repeat"])
            done += 1
            if run.status == "skipped":
                note = f"run: {run.label} skipped ({run.message})."
                if note not in notes:
                    notes.append(note)
                continue
            err = max_err = scaled = None
            drift = {k: None for k in inv_names}
            if run.ok:
                ref = ref_at(run.t_exact)
                obs = observables(measured, run.y_final, ref.dps)
                with mp.workdps(ref.dps):
                    err = float(max(abs(a - b) for a, b in zip(obs, ref.values)))
                    scaled = scaled_error(model, obs, ref.values)
                digits = int(spec.get("dps", 16)) if run.method in ("lie", "mpmath") else 40
                inv = _invariants_of(measured, run.states, digits)
                if inv is not None:
                    with mp.workdps(max(dps, digits) + 10):
                        drift = {k: float(max(abs(v - inv0[k]) for v in inv[k])) for k in inv_names}
                if refs_grid is not None:
                    errs, etimes, echarts = [], [], []
                    charts = extra.get("charts")
                    # the k-th output of a run is at grid[k] (a run that stopped early has fewer outputs,
                    # plus the state where it stopped, which is not on the grid)
                    for k, (tk, yk) in enumerate(zip(run.times, run.states)):
                        if k >= len(grid) or abs(tk - float(grid[k])) > 1e-9 * (1 + abs(tk)):
                            continue
                        obs = observables(measured, yk, dps)
                        with mp.workdps(dps):
                            errs.append(float(max(abs(a - b) for a, b in zip(obs, refs_grid[k]))))
                        etimes.append(float(grid[k]))
                        if charts is not None:
                            echarts.append(charts[k])
                    if errs:
                        max_err = max(errs)
                        traj["errors"][run.label] = errs
                        traj["error_times"][run.label] = etimes
                        if charts is not None:
                            traj.setdefault("charts", {})[run.label] = echarts
            rows.append(RunRow(
                model=mlabel, method=run.method, label=run.label, precision=run.precision, setting=run.setting,
                t=run.t, error=err, max_error=max_err, drift=drift, steps=run.steps, order=run.order,
                build_time=run.build_time, run_time=run.run_time, status=run.status, message=run.message,
                final_state=[float(to_fraction(v)) for v in run.y_final] if run.ok else None,
                scaled_error=scaled, extra={k: v for k, v in extra.items() if k != "charts"},
            ))
        if traj is not None:
            traj["values"] = _plot_values(model, [observables(model, y0, dps)] + list(refs_grid))
            trajectories[mlabel] = traj
    bar(total, total, "run done")
    return {"t": float(tf), "samples": n_out, "reference": ref_label, "invariants": inv_names or [],
            "initial_invariants": initial_invariants, "rows": rows}, trajectories


def _study_error_vs_order(opts, built, scene, bar, notes):
    import lieseries as ls

    from .studies import theoretical_radius
    from .studies.convergence import error_vs_order

    if getattr(ls, "lie_series", None) is None:
        notes.append("error vs order: not computed, `lieseries.lie_series` is not available in this installation.")
        return []
    orders = _orders_of(opts)
    dps = opts["dps"]
    bits = int(dps * 3.33) + 64
    states = [(lab, model, scene.initial_state(model, precision=max(bits, INITIAL_BITS))) for lab, model in built]
    if opts["t"] is not None:
        t = to_fraction(opts["t"])
    else:
        radii = [theoretical_radius(model, y0) for _, model, y0 in states]
        radii = [r for r in radii if r is not None]
        if not radii:
            raise SceneError("`studies.error_vs_order.t_fraction`: no model of this scene has a known radius of "
                             "convergence; give `t`")
        t = to_fraction(opts["t_fraction"]) * to_fraction(min(radii))
        t = Fraction(t).limit_denominator(10**12)
    out = []
    for i, (lab, model, y0) in enumerate(states):
        def prog(done, total, label, _i=i, _lab=lab):
            bar(_i * total + done, len(states) * total, f"{_lab}: {label}")

        try:
            res = error_vs_order(model, y0, t, orders, dps=dps, fit_min_order=opts["fit_min_order"], progress=prog)
        except Exception as err:  # one failing model must not take the rest of the report with it
            notes.append(f"error vs order ({lab}): failed: {type(err).__name__}: {err}")
            continue
        out.append((lab, res))
    return out


def _study_work_precision(opts, built, scene, bar, notes, quick):
    from .studies.work_precision import default_methods, expand_methods, work_precision

    methods = opts["methods"] if opts["methods"] is not None else default_methods(quick)
    bits = _needed_bits(expand_methods(methods))
    out = []
    for i, (lab, model) in enumerate(built):
        y0 = scene.initial_state(model, precision=bits)

        def prog(done, total, label, _i=i, _lab=lab):
            bar(_i * total + done, len(built) * total, f"{_lab}: {label}")

        res = work_precision(model, y0, opts["t"], methods=methods, repeat=opts["repeat"], progress=prog)
        for note in res.notes:
            line = f"work-precision: {note}"
            if line not in notes:
                notes.append(line)
        out.append((lab, res))
    return out


def _study_drift(opts, built, scene, bar, notes):
    from .studies.drift import drift

    out = []
    for i, (lab, model) in enumerate(built):
        y0 = scene.initial_state(model, precision=INITIAL_BITS)

        def prog(done, total, label, _i=i, _lab=lab):
            bar(_i * total + done, len(built) * total, f"{_lab}: {label}")

        out.append((lab, drift(model, y0, opts["t"], precision=opts["precision"], samples=opts["samples"],
                               tol=opts["tol"], ensemble=opts["ensemble"],
                               perturbation=float(to_fraction(opts["perturbation"])), seed=opts["seed"],
                               first=opts["first"], progress=prog)))
    return out


def run_scene(scene, out_dir=None, quick: bool = False, progress=True) -> SceneResult:
    """Compute what ``scene`` asks for, and nothing else.

    Parameters
    ----------
    scene : Scene, or a built-in name or path
    out_dir : str or Path, optional
        When given, the report is written there (:func:`lieseries.report.write_report`).
    quick : bool
        Scale the studies down for CI (see :func:`effective_plan`).
    progress : bool or callable
        True: progress bars on stderr (only when it is a terminal); False: silent; a callable
        ``progress(done, total, label)`` receives the updates.

    Notes
    -----
    The integrator cache of :mod:`lieseries.taylor` is cleared first, so that the build times reported are
    those of this scene.

    Returns
    -------
    SceneResult
    """
    from .studies.work_precision import clear_rhs_cache
    from .taylor import clear_cache

    scene = load_scene(scene)
    # build times in the report are this scene's: start without integrators compiled by earlier work in this
    # process (heyoka's own LLVM memory cache is left alone)
    clear_cache()
    clear_rhs_cache()
    start = _time.perf_counter()
    runp, studies = effective_plan(scene, quick)
    built = scene.build_models()
    result = SceneResult(scene=scene, quick=bool(quick), environment=_environment(),
                         created=_time.strftime("%Y-%m-%d %H:%M:%S %Z"))
    if runp is not None:
        bar = _make_progress(progress, "run")
        try:
            result.run, result.trajectories = _do_run(scene, runp, built, bar, result.notes)
        finally:
            bar.close()
    for name in STUDIES:
        if name not in studies:
            continue
        bar = _make_progress(progress, name.replace("_", " "))
        try:
            if name == "error_vs_order":
                items = _study_error_vs_order(studies[name], built, scene, bar, result.notes)
            elif name == "work_precision":
                items = _study_work_precision(studies[name], built, scene, bar, result.notes, quick)
            else:
                items = _study_drift(studies[name], built, scene, bar, result.notes)
        finally:
            bar.close()
        result.studies[name] = items
    result.wall_time = _time.perf_counter() - start
    if out_dir is not None:
        from .report import write_report

        result.report_path = str(write_report(result, out_dir))
    return result
