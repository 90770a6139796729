"""The scene schema and the validated scene: the top-level, [run], [report] and [stability] tables here; the
tables of model kinds and initial data (:mod:`lieseries.models.kinds`), of methods (:mod:`lieseries.methods`) and
of studies (:mod:`lieseries.studies.plugin`) come from their registries."""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from .. import fields as F
from ..fields import REQUIRED, SceneError, show
from ..methods import method_label, methods_registry, normalize_method, scene_methods
from ..models.kinds import initial_families, initial_family, model_kind, model_kinds
from ..precision import MAX_SAMPLES, MIN_DPS, binary_inputs, bits_to_dps
from ..solution import STATUSES
from ..studies import has_exact_solution, theoretical_radius
from ..studies.convergence import MAX_STUDY_DPS
from ..studies.drift import invariant_function
from ..studies.plugin import studies_registry

__all__ = ["ModelSpec", "Scene", "parse_scene", "jsonable", "field_docs", "schema_defaults", "model_kind_names",
           "study_names", "plot_names", "EXTREME_FOLDER", "ANALYSES"]

#: Sub-folder of the scenes folder holding the extreme and stiff cases (scenes with a [stability] table).
EXTREME_FOLDER = "extreme"
#: What the stability study computes for a scene ([stability].analysis).
ANALYSES = ("none", "saddle", "scaled", "drift", "stiff", "divergence", "atlas")


def model_kind_names() -> tuple:
    """The registered model kinds (``[model] kind``)."""
    return tuple(model_kinds())


def study_names() -> tuple:
    """The registered studies (``[studies.<name>]``), in the order of the report's sections."""
    return tuple(studies_registry())


def plot_names() -> tuple:
    """The plots a report can draw: the trajectory and one per study that has a plot."""
    return ("trajectory",) + tuple(n for n, st in studies_registry().items() if st.has_plot)


# -- the tables of this module ---------------------------------------------------------------------------------
def _scene_name(value, path):
    """A scene name is a name, not a path: it becomes a folder name of reports."""
    chars = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-")
    if (not isinstance(value, str) or not value or len(value) > 64 or not set(value) <= chars
            or value[0] in ".-" or ".." in value):
        F.fail(path, "a name of at most 64 letters, digits, '_', '-' or '.' (not starting with '.' or '-'; "
                     "not a path)", value)
    return value


def _plots(value, path):
    plots = plot_names()
    if not isinstance(value, list):
        F.fail(path, f"a list of plot names ({', '.join(plots)})", value)
    for i, v in enumerate(value):
        if v not in plots:
            raise SceneError(f"`{path}[{i}]`: unknown plot {show(v)}; known: {', '.join(plots)}")
    return value


_TOP_FIELDS = {
    "name": (_scene_name, REQUIRED),
    "title": (F.string, REQUIRED),
    "description": (F.string, ""),
    "model": (None, None),
    "models": (None, None),
    "initial": (None, REQUIRED),
    "run": (None, None),
    "studies": (None, None),
    "report": (None, None),
    "stability": (None, None),
}
_RUN_FIELDS = {
    "t": (F.time(), REQUIRED),
    "methods": (scene_methods(lists=False), REQUIRED),
    "samples": (F.count(2, MAX_SAMPLES), 101),
    "repeat": (F.integer(1, 100), 3),
    "quick_t": (F.time(), None),
}


def section_fields() -> dict:
    """The scene's own tables' fields: {"run": {...}, "stability": {...}} (the other fields are the registries')."""
    return {"run": dict(_RUN_FIELDS), "stability": _stability_fields()}


def _statuses():
    return tuple(STATUSES)


def _stability_fields() -> dict:
    return {
        "analysis": (F.choice(*ANALYSES), "none"),
        "headline": (F.string, None),
        "headline_model": (F.string, None),
        "expect": (F.choice(*_statuses()), "success"),
        "expect_message": (F.string, None),
        "threshold": (F.positive, 1e-3),
        "beyond": (F.positive, 1.5),
        "inside": (F.fraction01, 0.5),
        "orders": (F.orders, None),
        "dps": (F.count(MIN_DPS, MAX_STUDY_DPS), 40),
        "invariants": (F.list_of(F.string, allow_scalar=False), None),
        "note": (F.string, ""),
    }


_TOP_DOCS = {
    "name": ("name", "the scene's name: letters, digits, '_', '-', '.'; the default report folder reports/<name>"),
    "title": ("string", "the report's title"),
    "description": ("string", "a paragraph for the report"),
    "model": ("table", "the model (or `models`: an array of tables, each with a distinct `label`)"),
    "models": ("array of tables", "several models sharing [initial], each with a `label`"),
    "initial": ("table", "the initial state (fields by model family below)"),
    "run": ("table", "methods run side by side against the reference"),
    "studies": ("table of tables", "studies to run: {studies}"),
    "report": ("table", "what the report plots"),
    "stability": ("table", "for the extreme and stiff cases: how lieseries.stability reads the scene"),
}
_RUN_DOCS = {
    "t": ("number", "the final time"),
    "methods": ("array of method tables", "the methods run side by side (fields below)"),
    "samples": ("integer 2..100000", "equally spaced sample times from 0 to t, t = 0 included (so samples - 1 "
                "output times after the start), for the invariant drift and the trajectory plot"),
    "repeat": ("integer 1..100", "best-of repeats of each timing"),
    "quick_t": ("number", "the final time in quick mode (default: t)"),
}
_STABILITY_DOCS = {
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
}


def field_docs() -> dict:
    """Every field of the schema: ``{section: {field: (type, meaning)}}``, from this module and the registries of
    model kinds, initial data, methods and studies (docs/scenes.md is generated from it)."""
    studies = studies_registry()
    top = dict(_TOP_DOCS)
    top["studies"] = (top["studies"][0], top["studies"][1].format(studies=", ".join(studies)))
    out = {"": top}
    for name, kind in model_kinds().items():
        out[f"model.{name}"] = dict(kind.docs)
    for name, fam in initial_families().items():
        out[f"initial.{name}"] = dict(fam.docs)
    out["run"] = dict(_RUN_DOCS)
    for name, m in methods_registry().items():
        out[f"method.{name}"] = dict(m.docs)
    for name, st in studies.items():
        out[f"studies.{name}"] = dict(st.docs)
    out["report"] = {"plots": ("list of names", f"{', '.join(plot_names())} (default: one per study)")}
    out["stability"] = dict(_STABILITY_DOCS)
    return out


def schema_defaults() -> dict:
    """The schema as {section: {field: default}} (None for no default, "required" for required fields)."""
    def defaults(spec):
        return {k: ("required" if d is REQUIRED else d) for k, (_c, d) in spec.items()}

    out = {"": defaults(_TOP_FIELDS)}
    for name, kind in model_kinds().items():
        out[f"model.{name}"] = defaults(kind.fields)
    for name, fam in initial_families().items():
        out[f"initial.{name}"] = defaults(fam.fields)
    out["run"] = defaults(_RUN_FIELDS)
    for name, m in methods_registry().items():
        out[f"method.{name}"] = defaults(m.fields)
    for name, st in studies_registry().items():
        out[f"studies.{name}"] = defaults(st.fields)
    out["report"] = {"plots": None}
    out["stability"] = defaults(_stability_fields())
    return out


# -- the validated scene ---------------------------------------------------------------------------------------
@dataclass
class ModelSpec:
    """One model of a scene: its label, kind and parameters (as given, validated)."""

    label: str
    kind: str
    params: dict
    base: str | None = None  # the folder of the scene file (a python model's `file` is relative to it)

    @property
    def family(self) -> str:
        """The name of the [initial] table the model reads."""
        return model_kind(self.kind).family

    def build(self):
        return model_kind(self.kind).build(self.params, self.base)

    def to_dict(self) -> dict:
        return {"label": self.label, "kind": self.kind, **{k: jsonable(v, drop_none=True) for k, v in self.params.items()}}


@dataclass
class Scene:
    """A validated scene (see :mod:`lieseries.scenes`).

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
        return self.models[0].family

    def build_models(self) -> list:
        """[(label, model)] for every model of the scene."""
        return [(m.label, m.build()) for m in self.models]

    def initial_state(self, model, precision=None):
        """The initial state of ``model`` from the scene's [initial] table: exact (an ExactState, which every
        method rounds once to its own precision), or rounded to ``precision``."""
        return initial_family(self.family).state(model, self.initial, precision)

    def binary_inputs(self) -> dict:
        """``{dotted path: bits}`` of the scene's numbers written as binary floats that are not what a short decimal
        means (TOML reads ``omega = [1, 0.1, 0.5]`` as doubles: 0.1 is 0.1000000000000000055511151231257827...);
        ``1``, ``0.5``, ``0.375`` and strings such as ``"0.1"`` are exact and not listed. Every run and every
        reference of the scene starts from the binary values, so its errors are measured against the problem with
        these binary data, which agrees with the decimals as typed to about 16 digits only."""
        out = {}
        for i, m in enumerate(self.models):
            where = "model" if len(self.models) == 1 else f"models[{i}]"
            for key in model_kind(m.kind).data_fields:
                if m.params.get(key) is not None:
                    out.update(binary_inputs(m.params[key], f"{where}.{key}"))
        for key in initial_family(self.family).fields:
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


# -- parsing ---------------------------------------------------------------------------------------------------
def _model_spec(data, path, label_required=False) -> ModelSpec:
    kinds = model_kinds()
    if not isinstance(data, dict):
        raise SceneError(f"`{path}` must be a table with a `kind`; got {show(data)}")
    if "kind" not in data:
        raise SceneError(f"missing required field `{path}.kind` (one of {', '.join(kinds)})")
    kind = data["kind"]
    if kind not in kinds:
        raise SceneError(f"`{path}.kind`: unknown model kind {show(kind)}; known: {', '.join(kinds)}")
    spec = {"kind": (None, REQUIRED), "label": (F.string, REQUIRED if label_required else None)}
    spec.update(kinds[kind].fields)
    out = F.table(data, path, spec)
    label = out.pop("label") or kinds[kind].label
    out.pop("kind")
    return ModelSpec(label=label, kind=kind, params=out)


def _studies(data) -> dict:
    registry = studies_registry()
    studies = {}
    if data is None:
        return studies
    if not isinstance(data, dict):
        F.fail("studies", "a table of study tables", data)
    for key, val in data.items():
        if key not in registry:
            import difflib

            near = difflib.get_close_matches(key, list(registry), n=1)
            hint = f" (did you mean `{near[0]}`?)" if near else ""
            raise SceneError(f"unknown field `studies.{key}`{hint}; known: {', '.join(registry)}")
        studies[key] = F.table(val, f"studies.{key}", registry[key].fields)
    return studies


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
        raise SceneError(f"{source}: a scene must be a TOML table; got {show(data)}")
    d = F.table(data, "", _TOP_FIELDS)
    # models
    if (d["model"] is None) == (d["models"] is None):
        raise SceneError("a scene needs exactly one of `model` (a table) or `models` (an array of tables); "
                         + ("got both" if d["model"] is not None else "missing required field `model`"))
    if d["model"] is not None:
        models = [_model_spec(d["model"], "model")]
    else:
        if not isinstance(d["models"], list) or not d["models"]:
            F.fail("models", "a non-empty array of model tables ([[models]])", d["models"])
        models = [_model_spec(m, f"models[{i}]", label_required=True) for i, m in enumerate(d["models"])]
        labels = [m.label for m in models]
        if len(set(labels)) != len(labels):
            raise SceneError(f"`models[*].label` must be distinct; got {labels}")
    families = {m.family for m in models}
    if len(families) > 1:
        raise SceneError("`models` must all share the initial data: mix of kinds with different [initial] tables "
                         f"({', '.join(m.kind for m in models)})")
    initial = F.table(d["initial"], "initial", initial_family(families.pop()).fields)
    run = F.table(d["run"], "run", _RUN_FIELDS) if d["run"] is not None else None
    studies = _studies(d["studies"])
    # report
    rep = F.table(d["report"] if d["report"] is not None else {}, "report", {"plots": (_plots, None)})
    plots = rep["plots"] if rep["plots"] is not None else [p for p in plot_names() if p in studies]
    for i, p in enumerate(plots):
        if p == "trajectory" and run is None:
            raise SceneError(f"`report.plots[{i}]` asks for 'trajectory' but the scene has no [run] table")
        if p in studies_registry() and p not in studies:
            raise SceneError(f"`report.plots[{i}]` asks for {p!r} but the scene has no [studies.{p}] table")
    if run is None and not studies:
        raise SceneError("the scene asks for nothing: add a [run] table or a [studies.*] table")
    where = "model" if d["model"] is not None else "models"
    for m in models:
        m.base = str(Path(path).resolve().parent) if path else os.getcwd()
    scene = Scene(
        name=d["name"], title=d["title"], description=d["description"].strip(), models=models, initial=initial,
        run=run, studies=studies, plots=list(dict.fromkeys(plots)), source=text, path=path, stability=None,
    )
    built = _build(scene, where)
    registry = studies_registry()
    for name, opts in studies.items():
        registry[name].check(opts, run, built, where)
    if d["stability"] is not None:
        scene.stability = F.table(d["stability"], "stability", _stability_fields())
        _check_stability(scene.stability, run, studies, scene.plots, built)
    return scene


def _build(scene: Scene, where: str) -> list:
    """[(path, spec, model, exact initial state)]: every model built and its initial state made (physics errors
    name the table)."""
    out = []
    for i, spec in enumerate(scene.models):
        path = where if where == "model" else f"models[{i}]"
        try:
            model = spec.build()
        except (TypeError, ValueError) as err:
            if isinstance(err, SceneError):  # a kind names its fields `model.<field>`: this model's table here
                raise SceneError(str(err).replace("`model.", f"`{path}.")) from None
            raise SceneError(f"`{path}`: {err}") from None
        try:
            scene.initial_state(model, precision="double")
            y0 = scene.initial_state(model)
        except (TypeError, ValueError) as err:
            raise SceneError(f"`initial` ({spec.label}): {err}") from None
        out.append((path, spec, model, y0))
    return out


def _check_stability(st, run, studies, plots, built):
    """The [stability] table must match what the scene computes (its headline is a run of the scene, ...)."""
    if run is None:
        raise SceneError("`stability` needs a [run] table: the stability row of a case is one of its runs")
    labels = [method_label(normalize_method(m, f"run.methods[{i}]")) for i, m in enumerate(run["methods"])]
    if st["headline"] is None:
        st["headline"] = labels[0]
    elif st["headline"] not in labels:
        raise SceneError(f"`stability.headline` must be the label of one of the run's methods ({', '.join(labels)}); "
                         f"got {show(st['headline'])}")
    mlabels = [spec.label for _p, spec, _m, _y in built]
    if st["headline_model"] is None:
        st["headline_model"] = mlabels[0]
    elif st["headline_model"] not in mlabels:
        raise SceneError(f"`stability.headline_model` must be one of the model labels ({', '.join(mlabels)}); got "
                         f"{show(st['headline_model'])}")
    if st["invariants"] is not None:
        known = [list(invariant_function(model, 20)(y0)) for _p, _s, model, y0 in built]
        for i, name in enumerate(st["invariants"]):
            if any(name not in k for k in known):
                raise SceneError(f"`stability.invariants[{i}]`: unknown invariant {show(name)}; known: "
                                 f"{', '.join(known[0])}")
    analysis = st["analysis"]
    models = [model for _p, _s, model, _y in built]
    if analysis == "saddle":
        if "trajectory" not in plots:
            raise SceneError("`stability.analysis` = 'saddle' reads the errors along the run: add 'trajectory' to "
                             "`report.plots`")
        if any(getattr(m, "closed_form", None) != "free_rigid_body" for m in models):
            raise SceneError("`stability.analysis` = 'saddle' is for the free rigid body (kind 'euler_poisson')")
    if analysis == "drift" and "drift" not in studies:
        raise SceneError("`stability.analysis` = 'drift' needs a [studies.drift] table")
    if analysis == "divergence":
        if "error_vs_order" not in studies:
            raise SceneError("`stability.analysis` = 'divergence' needs a [studies.error_vs_order] table (the error "
                             "of the truncated series beyond the radius)")
        if any(not has_exact_solution(m) or theoretical_radius(m, y0) is None for _p, _s, m, y0 in built):
            raise SceneError("`stability.analysis` = 'divergence' needs a model with a known radius of convergence "
                             "(kind 'euler_poisson' or 'sphere')")
    if analysis == "atlas" and not any(getattr(m, "runs_on_atlas", False) for m in models):
        raise SceneError("`stability.analysis` = 'atlas' needs a model of kind 'sphere' that runs on its atlas")
