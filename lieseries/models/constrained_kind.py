"""The scene kind ``constrained``: a Lagrangian with holonomic constraints, written in the scene, in one of the
paper's formulations (:class:`~lieseries.models.constrained.ConstrainedSystem`)::

    [model]
    kind = "constrained"
    lagrangian = "m/2*(x_dot**2 + y_dot**2 + z_dot**2) - m*g*z"
    coordinates = ["x", "y", "z"]
    constraints = ["x**2 + y**2 + z**2 - l**2"]
    parameters = { m = 1, g = "9.81", l = 1 }
    formulation = "dirac"          # "dirac" | "reduced" | "intermediate" | "local"
    # dependent = ["z"]            # reduced / intermediate: the coordinates whose momenta are eliminated
    # chart = { z = "-sqrt(l**2 - x**2 - y**2)" }   # local: the dependent coordinates as functions of the others

    [initial]
    q = ["0.6", 0, "-0.8"]         # on the surface
    qdot = [0, 1, 0]               # tangent to it

Everything the derivation assumes is checked when the scene is read, before any computation: an expression sympy
cannot read, a symbol that is neither a coordinate, a velocity nor a parameter, a velocity in a constraint, a
singular or indefinite velocity Hessian, dependent constraints, a chart that does not solve the constraints. The
message names the scene field (``model.lagrangian``, ``model.constraints[0]``, ...).
"""

from __future__ import annotations

import re

from .. import fields as F
from .constrained import ConstrainedSystem
from .kinds import ModelKind, register_model_kind

__all__ = ["FORMULATIONS", "build_constrained"]

#: The formulations a scene may ask for, in the paper's order.
FORMULATIONS = ("dirac", "reduced", "intermediate", "local")


def _names(value, path):
    if not isinstance(value, list) or not value:
        F.fail(path, "a non-empty list of names such as [\"x\", \"y\"]", value)
    for i, v in enumerate(value):
        if not (isinstance(v, str) and v.isidentifier()):
            F.fail(f"{path}[{i}]", "a name (a Python identifier such as \"x1\")", v)
    return value


def _expressions(value, path):
    if not isinstance(value, list) or not value:
        F.fail(path, "a non-empty list of expressions (strings) such as [\"x**2 + y**2 - 1\"]", value)
    for i, v in enumerate(value):
        if not isinstance(v, str):
            F.fail(f"{path}[{i}]", "an expression written as a string", v)
    return value


def _parameters(value, path):
    if not isinstance(value, dict):
        F.fail(path, "a table name = number, such as { m = 1, g = \"9.81\" }", value)
    for k, v in value.items():
        if not k.isidentifier():
            F.fail(f"{path}.{k}", "keyed by a name (a Python identifier)", k)
        F.number(v, f"{path}.{k}")
    return value


def _chart(value, path):
    if not isinstance(value, dict) or not value:
        F.fail(path, "a table {dependent coordinate = \"expression of the others\"}, such as "
                     "{ z = \"sqrt(1 - x**2 - y**2)\" }", value)
    for k, v in value.items():
        if not isinstance(v, str):
            F.fail(f"{path}.{k}", "an expression written as a string", v)
    return value


#: ConstrainedSystem's argument names -> the scene's field names (``parameters['m']`` is ``parameters.m``).
_ARGUMENTS = ("lagrangian", "coordinates", "constraints", "parameters", "chart", "dependent", "edge")


def _scene_message(err: Exception) -> str:
    """The error's text with the derivation's argument names written as the scene's fields (``model.<field>``)."""
    msg = str(err)
    msg = re.sub(r"`(parameters|chart)\['([A-Za-z_]\w*)'\]`", r"`model.\1.\2`", msg)
    return re.sub(r"`(" + "|".join(_ARGUMENTS) + r")(\[\d+\])?`", r"`model.\1\2`", msg)


def build_constrained(params: dict, base=None):
    """The formulation ``params["formulation"]`` of the ConstrainedSystem the fields describe; any refusal of the
    derivation becomes a :class:`~lieseries.fields.SceneError` naming the field."""
    form = params["formulation"]
    chart, dependent = params.get("chart"), params.get("dependent")
    if form == "local" and chart is None:
        raise F.SceneError("`model.chart` is required for formulation = 'local': a table {dependent coordinate = "
                           "\"expression of the others\"} solving the constraints, such as "
                           "{ z = \"sqrt(1 - x**2 - y**2)\" }")
    if form != "local" and chart is not None:
        raise F.SceneError(f"`model.chart` is for formulation = 'local' only; formulation = {form!r} takes "
                           "`dependent` (optional) instead")
    if form in ("dirac", "local") and dependent is not None:
        raise F.SceneError(f"`model.dependent` is for formulation = 'reduced' or 'intermediate'; formulation = "
                           f"{form!r} has no dependent momenta" + (" (its chart names them)" if form == "local" else ""))
    try:
        system = ConstrainedSystem(params["lagrangian"], params["coordinates"], params["constraints"],
                                   parameters=params["parameters"])
        if form == "dirac":
            return system.dirac()
        if form == "reduced":
            return system.reduced(dependent)
        if form == "intermediate":
            return system.intermediate(dependent)
        return system.local(chart)
    except (TypeError, ValueError) as err:
        raise F.SceneError(_scene_message(err)) from None


register_model_kind(ModelKind(
    "constrained",
    fields={"lagrangian": (F.string, F.REQUIRED), "coordinates": (_names, F.REQUIRED),
            "constraints": (_expressions, F.REQUIRED), "parameters": (_parameters, {}),
            "formulation": (F.choice(*FORMULATIONS), "dirac"), "dependent": (_names, None),
            "chart": (_chart, None)},
    docs={"lagrangian": ("string", "L(q, qdot), quadratic in the velocities with a positive-definite Hessian; the "
                         "velocity of coordinate x is x_dot; ^ or ** for powers; sin, cos, exp, log, sqrt, ... and pi"),
          "coordinates": ("list of names", "the coordinates q^A"),
          "constraints": ("list of strings", "the holonomic constraints G(q) = 0 (no velocities), independent"),
          "parameters": ("table name = number", "the values of the other names in the expressions (kept exact)"),
          "formulation": ("'dirac' | 'reduced' | 'intermediate' | 'local'",
                          "(q, p) with the Dirac bracket; (q, p_i) on Phi = 0 (p8.13); (q, pi_i), the intermediate "
                          "formalism (p9-p14); canonical local coordinates of a chart"),
          "dependent": ("list of names", "reduced / intermediate: the k coordinates whose momenta are eliminated "
                        "(default: the last k)"),
          "chart": ("table name = string", "local (required): each dependent coordinate as an expression of the "
                    "others, solving the constraints")},
    build=build_constrained, family="configuration", label="constrained system", data_fields=("parameters",),
))
