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

Model kinds, methods and studies are plug-ins: each registers its own scene fields (:mod:`lieseries.models.kinds`,
:mod:`lieseries.methods`, :mod:`lieseries.studies.plugin`), and this package reads the registries. The package:
``schema`` (the tables and the validated :class:`Scene`), ``finding`` (built-in scenes, files), ``quick`` (quick
mode), ``docs`` (docs/scenes.md).

Validation is strict: an unknown model kind, a missing required field, a field of the wrong type or an unknown
field raises :class:`SceneError` naming the field by its dotted path (``run.methods[1].precision``).

Built-in scenes live in ``lieseries/data/scenes/*.toml`` (package data, shipped with every install) (override the folder with the
environment variable ``LIESERIES_SCENES``). :func:`run_scene` computes what a scene asks for and returns a
:class:`SceneResult` (data, :mod:`lieseries.run`); :func:`lieseries.report.write_report` writes it.
"""

from ..fields import MAX_MAGNITUDE, SceneError
from ..studies.convergence import orders_of
from .docs import scene_reference
from .finding import builtin_scenes, extreme_scenes, load_scene, scenes_dir
from .quick import effective_plan, quick_changes
from .schema import (ANALYSES, EXTREME_FOLDER, ModelSpec, Scene, field_docs, jsonable, model_kind_names,
                     parse_scene, plot_names, schema_defaults, study_names)

__all__ = [
    "FIELD_DOCS",
    "scene_reference",
    "jsonable",
    "orders_of",
    "SceneError",
    "Scene",
    "ModelSpec",
    "load_scene",
    "parse_scene",
    "builtin_scenes",
    "extreme_scenes",
    "scenes_dir",
    "effective_plan",
    "quick_changes",
    "MODEL_KINDS",
    "PLOTS",
    "STUDIES",
    "MAX_MAGNITUDE",
    "EXTREME_FOLDER",
    "ANALYSES",
]

#: The schema as {section: {field: default}} (the name the tests read).
_schema = schema_defaults

_DYNAMIC = {
    "MODEL_KINDS": model_kind_names,  # the registered model kinds
    "STUDIES": study_names,  # the registered studies, in report order
    "PLOTS": plot_names,  # "trajectory" and the studies' plots
    "FIELD_DOCS": field_docs,  # every field: (type, meaning)
}


def __getattr__(name):
    """MODEL_KINDS, STUDIES, PLOTS and FIELD_DOCS follow the registries (a plug-in registered later is in them)."""
    if name in _DYNAMIC:
        return _DYNAMIC[name]()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
