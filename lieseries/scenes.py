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
    samples = 101                # sample times, t = 0 included: 100 output times (drift, trajectory plot)
    quick_t = 2                  # optional: the final time in quick mode (default: t)
    methods = [
      { method = "taylor", precision = "double" },            # tol optional
      { method = "lie", dps = 30 },                           # tol, order optional
      { method = "scipy", rtol = 1e-12 },                     # atol optional
      { method = "mpmath", dps = 20, t_max = 1 },             # capped at |t| <= t_max
      { method = "validated", dps = 30 },                     # Arb balls; order optional
    ]

    [studies.error_vs_order]     # t or t_fraction (of the theoretical radius); orders or max_order (with
                                 # min_order, step); dps; fit_min_order (default: fit the upper half)
    [studies.work_precision]     # t (default run.t), methods (settings may be lists), repeat
    [studies.drift]              # t, precision, samples, tol, ensemble, perturbation, seed, first
    [studies.departure_map]      # grid = [n_theta, n_phi], T, samples, precisions, threshold, dps: how long each
                                 # precision stays on the closed form over |M0| = 1 (free rigid body, principal
                                 # inertia, Chetaev bracket; [initial] is not used by it)

    [report]
    plots = ["trajectory", "error_vs_order", "work_precision", "drift", "departure_map"]   # default: one per study

    [stability]                  # optional: how the stability study (lieseries.stability) reads the scene
    analysis = "saddle"          # "none" | "saddle" | "scaled" | "drift" | "stiff" | "divergence" | "atlas"
    headline = "heyoka double"   # the method (label) of the case's row in the one-row-per-case table
    expect = "success"           # the status that row should end with; expect_message: a text its message holds
                                 # invariants: the ones whose drift the row reports (default: all of the model's)
                                 # saddle: threshold; divergence: beyond, inside, orders, dps (see lieseries.stability)

Scenes with a [stability] table are the extreme and stiff cases. They live in ``lieseries/data/scenes/extreme/``
(:func:`extreme_scenes`), apart from the built-in scenes whose runs must all succeed; :func:`load_scene` finds them
by name too.

Validation is strict: an unknown model kind, a missing required field, a field of the wrong type or an unknown
field raises :class:`SceneError` naming the field by its dotted path (``run.methods[1].precision``).

Built-in scenes live in ``lieseries/data/scenes/*.toml`` (package data, shipped with every install) (override the folder with the
environment variable ``LIESERIES_SCENES``). :func:`run_scene` computes what a scene asks for and returns a
:class:`SceneResult` (data, :mod:`lieseries.run`); :func:`lieseries.report.write_report` writes it.
"""

from __future__ import annotations

import copy
import difflib
import math
import os
import tomllib
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from .precision import binary_inputs, bits_to_dps, resolve_precision, to_fraction

__all__ = [
    "FIELD_DOCS",
    "scene_reference",
    "jsonable",
    "orders_of",
    "SceneError",
    "Scene",
    "load_scene",
    "parse_scene",
    "builtin_scenes",
    "extreme_scenes",
    "scenes_dir",
    "MODEL_KINDS",
    "PLOTS",
    "STUDIES",
]

MODEL_KINDS = ("euler_poisson", "damped_euler_poisson", "sphere", "sphere_dirac", "python")
STUDIES = ("error_vs_order", "work_precision", "drift", "departure_map")
PLOTS = ("trajectory", "error_vs_order", "work_precision", "drift", "departure_map")
_FAMILY = {"euler_poisson": "rigid_body", "damped_euler_poisson": "rigid_body", "sphere": "sphere", "python": "state",
           "sphere_dirac": "sphere"}
#: Sub-folder of the scenes folder holding the extreme and stiff cases (scenes with a [stability] table).
EXTREME_FOLDER = "extreme"
#: What the stability study computes for a scene ([stability].analysis).
ANALYSES = ("none", "saddle", "scaled", "drift", "stiff", "divergence", "atlas")

#: Numbers in a scene lie within 1e-MAX_MAGNITUDE .. 1eMAX_MAGNITUDE in magnitude (or are 0).
MAX_MAGNITUDE = 300


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
    except TypeError:
        _fail(path, what + ' (a decimal string such as "0.1" is read exactly)', value)
    except ValueError as err:
        raise SceneError(str(err)) from None
    if q != 0 and not (Fraction(1, 10**MAX_MAGNITUDE) <= abs(q) <= 10**MAX_MAGNITUDE):
        _fail(path, f"a number of magnitude between 1e-{MAX_MAGNITUDE} and 1e{MAX_MAGNITUDE} (or 0)", value)
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


def _edge(value, path):
    """A sphere chart's edge: in (0, 1/sqrt(3)) (as ``Sphere``: every point has a coordinate with
    |x_k| >= |x|/sqrt(3), so below that every point lies inside the chart of its largest coordinate)."""
    _number(value, path, below_one=True, what="a number in (0, 0.577) (below 1/sqrt(3))")
    if to_fraction(value, path) ** 2 >= Fraction(1, 3):
        _fail(path, "a number in (0, 0.577): below 1/sqrt(3), since every point has a coordinate with "
                    "|x_k| >= |x|/sqrt(3) and so lies inside the chart of its largest coordinate", value)
    return value


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


_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-")


def _scene_name(value, path):
    """A scene name is a name, not a path: it becomes a folder name of reports."""
    if (not isinstance(value, str) or not value or len(value) > 64 or not set(value) <= _NAME_CHARS
            or value[0] in ".-" or ".." in value):
        _fail(path, "a name of at most 64 letters, digits, '_', '-' or '.' (not starting with '.' or '-'; "
                    "not a path)", value)
    return value


def _identifier(value, path):
    if not (isinstance(value, str) and value.isidentifier()):
        _fail(path, "a Python name (the function that builds the model)", value)
    return value


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


def _grid(value, path):
    """[n_theta, n_phi] of the departure map: at most 64 x 128 directions (as lieseries.studies.departure)."""
    if not isinstance(value, list) or len(value) != 2:
        _fail(path, "a list [n_theta, n_phi] of two integers", value)
    _integer(1, 64)(value[0], f"{path}[0]")
    _integer(1, 128)(value[1], f"{path}[1]")
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
_TOP_FIELDS = {
    "name": (_scene_name, _REQUIRED),
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
_MODEL_FIELDS = {
    "euler_poisson": {"inertia": (_inertia, _REQUIRED), "bracket": (_choice("chetaev", "intermediate"), "chetaev")},
    "damped_euler_poisson": {"inertia": (_inertia, _REQUIRED), "damping": (_nonnegative, _REQUIRED),
                             "bracket": (_choice("chetaev", "intermediate"), "chetaev")},
    "sphere": {"mass": (_positive, 1), "radius": (_positive, 1), "chart": (_integer(0, 2), 2),
               "edge": (_edge, 0.05), "atlas": (_boolean, True)},
    "sphere_dirac": {"mass": (_positive, 1), "radius": (_positive, 1)},
    "python": {"file": (_string, _REQUIRED), "factory": (_identifier, "make")},
}
#: The fields of each model kind that are data of the problem (binary floats there are reported).
_DATA_FIELDS = {"euler_poisson": ("inertia",), "damped_euler_poisson": ("inertia", "damping"),
                "sphere": ("mass", "radius"), "sphere_dirac": ("mass", "radius")}
_INITIAL_FIELDS = {
    "rigid_body": {"omega": (_vector3, _REQUIRED), "R0": (_matrix3, None)},
    "sphere": {"x": (_vector3, _REQUIRED), "v": (_vector3, _REQUIRED)},
    "state": {"y0": (_list_of(_number, allow_scalar=False), _REQUIRED)},
}


def _method_fields(lists: bool) -> dict:
    L = (lambda c: _list_of(c)) if lists else (lambda c: c)
    return {
        "taylor": {"precision": (L(_precision), "double"), "tol": (L(_tol), None)},
        "lie": {"dps": (L(_integer(10, 10_000)), 30), "tol": (L(_positive), None),
                "order": (_integer(1, 10_000), None)},
        "scipy": {"rtol": (L(_tol), 1e-10), "atol": (_positive, None)},
        "mpmath": {"dps": (L(_integer(5, 10_000)), 15), "t_max": (_positive, 2.0)},
        "validated": {"dps": (L(_integer(5, 10_000)), 30), "order": (_integer(1, 10_000), None)},
    }


def _method(data, path, lists: bool):
    if not isinstance(data, dict):
        raise SceneError(f"`{path}` must be a table such as {{ method = \"taylor\", precision = \"double\" }}; "
                         f"got {_show(data)}")
    if "method" not in data:
        raise SceneError(f"missing required field `{path}.method` (one of taylor, lie, scipy, mpmath, validated)")
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
    "departure_map": {
        "grid": (_grid, [8, 16]),
        "T": (_positive, 100),
        "samples": (_integer(2, 100_000), 100),
        "precisions": (_list_of(_precision, allow_scalar=False), ["double", "quad"]),
        "threshold": (_positive, "1e-6"),
        "dps": (_integer(15, 1000), 30),
    },
}


# -- the reference of the format (docs/scenes.md is generated from it and the schema above) -----------------------
#: Every field of the schema: (type, meaning). Defaults are read from the schema itself, so that the reference and
#: the checks cannot drift apart (tests/test_scenes.py compares docs/scenes.md with :func:`scene_reference`).
FIELD_DOCS = {
    "": {
        "name": ("name", "the scene's name: letters, digits, '_', '-', '.'; the default report folder reports/<name>"),
        "title": ("string", "the report's title"),
        "description": ("string", "a paragraph for the report"),
        "model": ("table", "the model (or `models`: an array of tables, each with a distinct `label`)"),
        "models": ("array of tables", "several models sharing [initial], each with a `label`"),
        "initial": ("table", "the initial state (fields by model family below)"),
        "run": ("table", "methods run side by side against the reference"),
        "studies": ("table of tables", "studies to run: error_vs_order, work_precision, drift, departure_map"),
        "report": ("table", "what the report plots"),
        "stability": ("table", "for the extreme and stiff cases: how lieseries.stability reads the scene"),
    },
    "model.euler_poisson": {
        "inertia": ("3 numbers or 3x3 numbers", "principal moments, or a symmetric positive-definite tensor"),
        "bracket": ("'chetaev' | 'intermediate'", "the Poisson structure (paper 11.20.2 or 11.20)"),
    },
    "model.damped_euler_poisson": {
        "inertia": ("3 numbers or 3x3 numbers", "as for euler_poisson"),
        "damping": ("number >= 0", "the internal damping: the torque damping * M x (M x Omega)"),
        "bracket": ("'chetaev' | 'intermediate'", "as for euler_poisson"),
    },
    "model.sphere": {
        "mass": ("positive number", "the particle's mass"),
        "radius": ("positive number", "the sphere's radius"),
        "chart": ("0 | 1 | 2", "the dependent coordinate of the chart the state is written in"),
        "edge": ("number in (0, 0.577)", "a chart ends where abs(x_chart) <= edge * abs(x); below 1/sqrt(3), "
                 "since every point has a coordinate with abs(x_k) >= abs(x)/sqrt(3)"),
        "atlas": ("boolean", "runs and studies switch charts (true) or stay in one and stop at its edge"),
    },
    "model.sphere_dirac": {
        "mass": ("positive number", "the particle's mass"),
        "radius": ("positive number", "the sphere's radius"),
    },
    "model.python": {
        "file": ("path", "a Python file (relative to the scene file) defining the model; it runs as code"),
        "factory": ("Python name", "the function of that file returning a lieseries model or PoissonSystem"),
    },
    "initial.rigid_body": {
        "omega": ("3 numbers", "the body angular velocity Omega(0); R(0) = 1"),
        "R0": ("3x3 numbers", "an initial rotation instead of the identity"),
    },
    "initial.sphere": {
        "x": ("3 numbers", "the position, on the sphere"),
        "v": ("3 numbers", "the velocity, tangent to it"),
    },
    "initial.state": {
        "y0": ("list of numbers", "the state itself, one number per variable (python models)"),
    },
    "run": {
        "t": ("number", "the final time"),
        "methods": ("array of method tables", "the methods run side by side (fields below)"),
        "samples": ("integer 2..100000", "equally spaced sample times from 0 to t, t = 0 included (so samples - 1 "
                    "output times after the start), for the invariant drift and the trajectory plot"),
        "repeat": ("integer 1..100", "best-of repeats of each timing"),
        "quick_t": ("number", "the final time in quick mode (default: t)"),
    },
    "method.taylor": {
        "precision": ("'double' | 'long double' | 'quad' | bits", "heyoka's precision (a list in work_precision)"),
        "tol": ("number in (0, 1)", "the tolerance (default: the precision's epsilon)"),
    },
    "method.lie": {
        "dps": ("integer", "decimal digits of lie_integrate (a list in work_precision)"),
        "tol": ("positive number", "the per-step tolerance (default 10^-dps)"),
        "order": ("integer", "a fixed series order (default: the automatic one)"),
    },
    "method.scipy": {
        "rtol": ("number in (0, 1)", "DOP853's relative tolerance (a list in work_precision)"),
        "atol": ("positive number", "its absolute tolerance (default rtol)"),
    },
    "method.mpmath": {
        "dps": ("integer", "digits of mpmath.odefun"),
        "t_max": ("positive number", "the run is capped at |t| <= t_max (odefun is slow)"),
    },
    "method.validated": {
        "dps": ("integer", "digits of validated_integrate's ball arithmetic (certified enclosures)"),
        "order": ("integer", "a fixed series order (default: the automatic one)"),
    },
    "studies.error_vs_order": {
        "t": ("number", "the time at which the truncated series is compared"),
        "t_fraction": ("number in (0, 1)", "or t as this fraction of the theoretical radius of convergence"),
        "orders": ("list of integers", "the orders (or max_order, min_order, step)"),
        "max_order": ("integer", "the largest order"),
        "min_order": ("integer", "the smallest order"),
        "step": ("integer", "the step between orders"),
        "dps": ("integer", "digits of the series and of the reference"),
        "fit_min_order": ("integer", "the smallest order in the rate fit (default: the upper half)"),
    },
    "studies.work_precision": {
        "t": ("number", "the final time (default run.t)"),
        "methods": ("array of method tables", "settings may be lists: one row per value"),
        "repeat": ("integer 1..100", "best-of repeats of each timing"),
    },
    "studies.drift": {
        "t": ("positive number", "the final time (long: 10^4 steps and more)"),
        "precision": ("'double' | 'long double' | 'quad' | bits", "heyoka's precision"),
        "samples": ("integer 6..100000", "log-spaced sample times"),
        "tol": ("number in (0, 1)", "heyoka's tolerance (default: epsilon)"),
        "ensemble": ("integer 1..1000", "runs from perturbed copies of the initial state"),
        "perturbation": ("positive number", "their size, relative to max |y0|"),
        "seed": ("integer >= 0", "the seed of the perturbations"),
        "first": ("positive number", "the first sample time (default t / 1000)"),
    },
    "studies.departure_map": {
        "grid": ("[integer 1..64, integer 1..128]", "n_theta x n_phi directions of M0 on abs(M) = 1 (polar angle "
                 "from axis 3, azimuth)"),
        "T": ("positive number", "the final time"),
        "samples": ("integer 2..100000", "equally spaced output times where the state is compared"),
        "precisions": ("list of precisions", "'double', 'long double', 'quad' or bits: one ensemble run each"),
        "threshold": ("positive number", "departure: the first output time with max abs(y - y_exact) > threshold"),
        "dps": ("integer 15..1000", "digits of the closed-form reference and of the exact initial data"),
    },
    "report": {
        "plots": ("list of names", "trajectory, error_vs_order, work_precision, drift, departure_map (default: one "
                  "per study)"),
    },
    "stability": {
        "analysis": ("name", "none | saddle | scaled | drift | stiff | divergence | atlas"),
        "headline": ("string", "the method (label) of the case's row in the one-row-per-case table"),
        "headline_model": ("string", "the model of that row"),
        "expect": ("status", "the status the headline row must end with"),
        "expect_message": ("string", "a text its message must hold"),
        "threshold": ("positive number", "saddle: the departure threshold"),
        "beyond": ("positive number", "divergence: t beyond the radius, as a multiple of it"),
        "inside": ("number in (0, 1)", "divergence: t inside the radius, as a fraction of it"),
        "orders": ("list of integers", "divergence: the orders"),
        "dps": ("integer", "divergence: the digits"),
        "invariants": ("list of names", "the invariants whose drift the row reports (default: all)"),
        "note": ("string", "a sentence for the report"),
    },
}


def _schema() -> dict:
    """The schema as {section: {field: default}} (None for no default, "required" for required fields)."""
    def defaults(spec):
        return {k: ("required" if d is _REQUIRED else d) for k, (_c, d) in spec.items()}

    out = {"": defaults(_TOP_FIELDS)}
    for kind, spec in _MODEL_FIELDS.items():
        out[f"model.{kind}"] = defaults(spec)
    for fam, spec in _INITIAL_FIELDS.items():
        out[f"initial.{fam}"] = defaults(spec)
    out["run"] = defaults(_RUN_FIELDS)
    for name, spec in _method_fields(False).items():
        out[f"method.{name}"] = defaults(spec)
    for name, spec in _STUDY_FIELDS.items():
        out[f"studies.{name}"] = defaults(spec)
    out["report"] = {"plots": None}
    out["stability"] = defaults(_stability_fields())
    return out


def scene_reference() -> str:
    """docs/scenes.md: every field of the scene format with its type, default and meaning."""
    heads = {"": "Top level", "run": "[run]", "report": "[report]", "stability": "[stability]"}
    lines = [
        "# Scene format",
        "",
        "A scene is a TOML file that says what to integrate, how, and which studies and plots its report needs;",
        "nothing more is computed. `lieseries run FILE.toml` runs one; `lieseries scenes` lists the built-in ones",
        "(`lieseries/data/scenes/`). Numbers may be strings, read exactly (`\"0.1\"` is 1/10); every number lies",
        f"within 1e-{MAX_MAGNITUDE} .. 1e{MAX_MAGNITUDE} in magnitude. An unknown or invalid field is refused with",
        "its dotted path (`run.methods[1].precision`). A TOML float such as `0.1` is a double (0.1000000000000000055...):",
        "the runs and the reference start from that binary value, and the scene's data list it",
        "(`Scene.binary_inputs()`: `initial.omega[1]`); `1`, `0.5` and other short binary numbers are exact.",
        "",
        "`lieseries run SCENE --quick` runs a scaled-down plan for CI (`effective_plan`: shorter times, fewer",
        "samples and orders, validated runs at most 30 digits); its report lists every setting it changed",
        "(`run.methods[0].dps: 50 -> 30`), since the scene's title and description speak of the full run.",
        "",
        "This page is generated from the schema in `lieseries/scenes.py` (`scene_reference()`), and a test checks",
        "that the two agree.",
        "",
    ]
    schema = _schema()
    for section, fields in schema.items():
        kind = section.split(".", 1)
        if section in heads:
            title = heads[section]
        elif kind[0] == "model":
            title = f"[model] kind = \"{kind[1]}\""
        elif kind[0] == "initial":
            title = f"[initial] for {kind[1].replace('_', ' ')} models"
        elif kind[0] == "method":
            title = f"a method table: method = \"{kind[1]}\" (`label` optional)"
        else:
            title = f"[{section}]"
        lines += [f"## {title}", "", "| field | type | default | meaning |", "|---|---|---|---|"]
        for field, default in fields.items():
            typ, meaning = FIELD_DOCS[section][field]
            shown = "required" if default == "required" else ("-" if default is None else f"`{default!r}`")
            lines.append(f"| `{field}` | {typ} | {shown} | {meaning} |")
        lines.append("")
    return "\n".join(lines)


@dataclass
class ModelSpec:
    """One model of a scene: its label, kind and parameters (as given, validated)."""

    label: str
    kind: str
    params: dict
    base: str | None = None  # the folder of the scene file (a python model's `file` is relative to it)

    def build(self):
        from .models import DampedEulerPoisson, EulerPoisson, Sphere, SphereDirac

        if self.kind == "python":
            return _python_model(self.params["file"], self.params["factory"], self.base)
        if self.kind == "euler_poisson":
            return EulerPoisson(self.params["inertia"], bracket=self.params["bracket"])
        if self.kind == "damped_euler_poisson":
            return DampedEulerPoisson(self.params["inertia"], damping=self.params["damping"],
                                      bracket=self.params["bracket"])
        if self.kind == "sphere":
            p = self.params
            return Sphere(mass=p["mass"], radius=p["radius"], chart=p["chart"], edge=float(to_fraction(p["edge"])),
                          atlas=p["atlas"])
        return SphereDirac(mass=self.params["mass"], radius=self.params["radius"])

    def to_dict(self) -> dict:
        return {"label": self.label, "kind": self.kind, **{k: jsonable(v, drop_none=True) for k, v in self.params.items()}}


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

    def initial_state(self, model, precision=None):
        """The initial state of ``model`` from the scene's [initial] table: exact (an ExactState, which every
        method rounds once to its own precision), or rounded to ``precision``."""
        ini = self.initial
        if self.family == "rigid_body":
            return model.initial_state(ini["omega"], R0=ini.get("R0"), precision=precision)
        if self.family == "state":
            from .models.base import make_state
            from .poisson import as_poisson_system

            n = as_poisson_system(model).dimension
            if len(ini["y0"]) != n:
                raise ValueError(f"`initial.y0` must have {n} numbers, one per variable; got {len(ini['y0'])}")
            return make_state(ini["y0"], precision, inputs={"initial.y0": ini["y0"]})
        return model.initial_state(ini["x"], ini["v"], precision=precision)

    def binary_inputs(self) -> dict:
        """``{dotted path: bits}`` of the scene's numbers written as binary floats that are not what a short decimal
        means (TOML reads ``omega = [1, 0.1, 0.5]`` as doubles: 0.1 is 0.1000000000000000055511151231257827...);
        ``1``, ``0.5``, ``0.375`` and strings such as ``"0.1"`` are exact and not listed. Every run and every
        reference of the scene starts from the binary values, so its errors are measured against the problem with
        these binary data, which agrees with the decimals as typed to about 16 digits only."""
        out = {}
        for i, m in enumerate(self.models):
            where = "model" if len(self.models) == 1 else f"models[{i}]"
            for key in _DATA_FIELDS.get(m.kind, ()):
                if m.params.get(key) is not None:
                    out.update(binary_inputs(m.params[key], f"{where}.{key}"))
        for key in ("omega", "R0", "x", "v", "y0"):
            if self.initial.get(key) is not None:
                out.update(binary_inputs(self.initial[key], f"initial.{key}"))
        for key in ("t", "t0"):  # the runs use the double 2.1 as their end time (and its messages say so)
            if (self.run or {}).get(key) is not None:
                out.update(binary_inputs(self.run[key], f"run.{key}"))
        return out

    def binary_note(self) -> str:
        """One sentence for the report when the scene holds binary floats (:meth:`binary_inputs`), else ""."""
        found = self.binary_inputs()
        if not found:
            return ""
        names = ", ".join(f"`{k}`" for k in found)
        bits = min(found.values())
        return (f"The scene gives {names} as binary floating-point numbers (TOML reads 0.1 as the double "
                "0.1000000000000000055511151231257827...): every run and the reference start from these binary "
                "values, so the errors shown are measured against the problem with the binary data; that problem "
                f"agrees with the decimals as written to about {bits_to_dps(bits)} digits only. Write the numbers as "
                'strings ("0.1") to mean the decimals exactly.')

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "title": self.title,
            "description": self.description,
            "models": [m.to_dict() for m in self.models],
            "initial": jsonable(self.initial, drop_none=True),
            "run": jsonable(self.run, drop_none=True),
            "studies": jsonable(self.studies, drop_none=True),
            "plots": list(self.plots),
            "path": self.path,
            "binary_inputs": self.binary_inputs(),
            **({"stability": jsonable(self.stability, drop_none=True)} if self.stability is not None else {}),
        }


def jsonable(v, drop_none: bool = False):
    """``v`` with only JSON types: numpy and mpmath numbers and Fractions as floats, non-finite floats as
    ``None``/``"inf"``, tuples as lists (``drop_none``: leave out dict entries that are None, as TOML has no null)."""
    if isinstance(v, dict):
        return {str(k): jsonable(x, drop_none) for k, x in v.items() if not (drop_none and x is None)}
    if isinstance(v, (list, tuple)):
        return [jsonable(x, drop_none) for x in v]
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, Fraction) or hasattr(v, "_mpf_"):
        return float(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
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
                                 "sphere": "sphere (5-d chart)", "sphere_dirac": "sphere (Dirac)",
                                 "python": "model"}[kind]
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
    d = _table(data, "", _TOP_FIELDS)
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
    _check_studies(studies, run, models, "model" if d["model"] is not None else "models")
    stability = None
    if d["stability"] is not None:
        stability = _table(d["stability"], "stability", _stability_fields())
        _check_stability(stability, run, studies, plots, models)
    for m in models:
        m.base = str(Path(path).resolve().parent) if path else os.getcwd()
    scene = Scene(
        name=d["name"], title=d["title"], description=d["description"].strip(), models=models, initial=initial,
        run=run, studies=studies, plots=list(dict.fromkeys(plots)), source=text, path=path, stability=stability,
    )
    _check_physics(scene, "model" if d["model"] is not None else "models")
    return scene


def _check_studies(studies, run, models, where="model"):
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
    if "departure_map" in studies:
        _check_departure_map(models, where)
    wp = studies.get("work_precision")
    if wp is not None and wp["t"] is None:
        if run is None:
            raise SceneError("missing required field `studies.work_precision.t` (there is no [run] to take it from)")
        wp["t"] = run["t"]


def _check_departure_map(models, where):
    """The departure map integrates the free rigid body with principal inertia against its closed form."""
    for i, m in enumerate(models):
        path = where if where == "model" else f"models[{i}]"
        if m.kind != "euler_poisson":
            raise SceneError(f"`studies.departure_map` needs a free rigid body: `{path}.kind` must be "
                             f"'euler_poisson'; got {_show(m.kind)}")
        if m.params["bracket"] != "chetaev":
            raise SceneError(f"`studies.departure_map` integrates the Chetaev form: `{path}.bracket` must be "
                             f"'chetaev'; got {_show(m.params['bracket'])}")
        inertia = m.params["inertia"]
        if isinstance(inertia[0], list) and any(to_fraction(inertia[r][c]) != 0
                                                for r in range(3) for c in range(3) if r != c):
            raise SceneError(f"`studies.departure_map` needs principal moments: `{path}.inertia` must be 3 "
                             "numbers or a diagonal 3x3 tensor; got one with off-diagonal entries")


def _check_stability(st, run, studies, plots, models):
    """The [stability] table must match what the scene computes (its headline is a run of the scene, ...)."""
    from .methods import method_label, normalize_method

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


def _python_model(file: str, factory: str, base):
    """The model or PoissonSystem that ``factory()`` in the Python file ``file`` returns (the file runs as code:
    scenes that name one are as trusted as the file)."""
    import importlib.util

    from .poisson import as_poisson_system

    p = Path(file) if Path(file).is_absolute() else Path(base or os.getcwd()) / file
    if not p.is_file():
        raise SceneError(f"`model.file`: {str(p)!r} not found (a path relative to the scene file)")
    spec = importlib.util.spec_from_file_location(f"lieseries_scene_model_{p.stem}", p)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as err:  # the user's file: whatever it raises is a bad scene, said in one line
        raise SceneError(f"`model.file`: running {p.name} raised {type(err).__name__}: {err}") from None
    fn = getattr(module, factory, None)
    if not callable(fn):
        raise SceneError(f"`model.factory`: {p.name} has no function {factory!r}")
    try:
        model = fn()
        as_poisson_system(model)
    except Exception as err:
        raise SceneError(f"`model.factory`: {factory}() in {p.name} must return a lieseries model or "
                         f"PoissonSystem; {type(err).__name__}: {err}") from None
    return model


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
    return Path(__file__).resolve().parent / "data" / "scenes"  # package data: the same in every install


def builtin_scenes() -> list:
    """[(name, title)] of the built-in scenes, sorted by name (``default`` first)."""
    out = _titles(scenes_dir())
    out.sort(key=lambda nt: (nt[0] != "default", nt[0]))
    return out


def extreme_scenes() -> list:
    """[(name, title)] of the extreme and stiff cases (``lieseries/data/scenes/extreme/*.toml``), sorted by name."""
    return _titles(scenes_dir() / EXTREME_FOLDER)


def _titles(folder: Path) -> list:
    """[(name, title)] of the scene files in ``folder``, sorted by name."""
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
    if p.is_dir():
        raise SceneError(f"`{s}` is a folder, not a scene file; pass a scene name (`lieseries scenes` lists them) "
                         "or the path of a .toml file")
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


def quick_changes(scene: Scene) -> list:
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


def effective_plan(scene: Scene, quick: bool = False):
    """(run, studies) tables as they will be run: ``quick`` scales the studies down for CI.

    Quick mode: at most 41 output times in the run, which ends at ``run.quick_t`` when the scene gives one (validated
    runs at most 30 digits); error
    vs order up to half the largest order (at least 12) and at most 40 digits; work-precision with at most three
    values per setting, one repeat and mpmath capped at t = 0.5; drift over a tenth of the time, at most 60
    samples and 4 ensemble members; the departure map on at most a 3 x 6 grid, over a tenth of the time with at
    most 20 output times.
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
            if m["method"] == "validated":
                m["dps"] = min(m["dps"], 30)
    ev = studies.get("error_vs_order")
    if ev is not None:
        orders = orders_of(ev)
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
    dm = studies.get("departure_map")
    if dm is not None:
        dm["grid"] = [min(dm["grid"][0], 3), min(dm["grid"][1], 6)]
        dm["T"] = float(to_fraction(dm["T"])) / 10
        dm["samples"] = min(dm["samples"], 20)
    return run, studies


def orders_of(ev) -> list:
    if ev.get("orders") is not None:
        return sorted(set(int(o) for o in ev["orders"]))
    top = ev.get("max_order") or 40
    return list(range(ev.get("min_order", 1), top + 1, ev.get("step", 1)))

