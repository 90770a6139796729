"""Model kinds of scenes: what ``[model] kind = "..."`` builds, its fields, and the initial data it reads.

A model file registers its kind with :func:`register_model_kind` (and, when its initial data are new, an
:class:`InitialFamily` with :func:`register_initial_family`); :mod:`lieseries.scenes` reads the registry, so a new
model is its own file plus one registration. The ``python`` kind (a Python file whose function returns a model or
a bare PoissonSystem) and the ``state`` family (``initial.y0``: the state itself) are defined here.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .. import fields as F
from ..poisson import as_poisson_system
from .base import make_state

__all__ = ["ModelKind", "InitialFamily", "register_model_kind", "register_initial_family", "unregister_model_kind",
           "unregister_initial_family", "model_kinds",
           "initial_families", "model_kind", "initial_family"]


@dataclass(frozen=True)
class InitialFamily:
    """The ``[initial]`` table shared by some model kinds.

    ``fields``: the scene schema ``{name: (checker, default)}``; ``docs``: ``{name: (type, meaning)}``;
    ``state(model, initial, precision)``: the initial state of ``model`` (an ExactState when ``precision`` is None).
    """

    name: str
    fields: dict
    docs: dict
    state: Callable


@dataclass(frozen=True)
class ModelKind:
    """One ``kind`` of ``[model]``.

    ``build(params, base)`` makes the model from the validated fields (``base``: the scene file's folder);
    ``family``: the name of its :class:`InitialFamily`; ``label``: the default label; ``data_fields``: the fields
    that are data of the problem (binary floats there are reported); ``docs``: ``{field: (type, meaning)}``.
    """

    name: str
    fields: dict
    docs: dict
    build: Callable
    family: str
    label: str
    data_fields: tuple = ()
    comment: str = field(default="")


_KINDS: dict = {}
_FAMILIES: dict = {}


def register_model_kind(kind: ModelKind) -> ModelKind:
    """Make ``kind`` available to scenes (``[model] kind = kind.name``); a later registration of the same name
    replaces the earlier one."""
    if not isinstance(kind, ModelKind):
        raise TypeError(f"`kind` must be a ModelKind; got {type(kind).__name__}")
    if set(kind.fields) != set(kind.docs):
        raise ValueError(f"model kind {kind.name!r}: `docs` must describe exactly its fields {sorted(kind.fields)}")
    _KINDS[kind.name] = kind
    return kind


def register_initial_family(family: InitialFamily) -> InitialFamily:
    """Make the ``[initial]`` table ``family`` available to model kinds."""
    if not isinstance(family, InitialFamily):
        raise TypeError(f"`family` must be an InitialFamily; got {type(family).__name__}")
    if set(family.fields) != set(family.docs):
        raise ValueError(f"initial family {family.name!r}: `docs` must describe exactly its fields")
    _FAMILIES[family.name] = family
    return family


def unregister_model_kind(name: str) -> None:
    """Forget the model kind ``name`` (a plug-in's tests clean up with it; ``python`` stays)."""
    if name != "python":
        _KINDS.pop(name, None)


def unregister_initial_family(name: str) -> None:
    """Forget the initial family ``name`` (``state`` stays)."""
    if name != "state":
        _FAMILIES.pop(name, None)


def model_kinds() -> dict:
    """{name: ModelKind} in registration order (the ``python`` kind last)."""
    out = {k: v for k, v in _KINDS.items() if k != "python"}
    out["python"] = _KINDS["python"]
    return out


def initial_families() -> dict:
    """{name: InitialFamily} in registration order (the ``state`` family last)."""
    out = {k: v for k, v in _FAMILIES.items() if k != "state"}
    out["state"] = _FAMILIES["state"]
    return out


def model_kind(name: str) -> ModelKind:
    return _KINDS[name]


def initial_family(name: str) -> InitialFamily:
    return _FAMILIES[name]


# -- the python kind and the state family ----------------------------------------------------------------------
def _python_model(params, base):
    """The model or PoissonSystem that ``factory()`` in the Python file ``file`` returns (the file runs as code:
    scenes that name one are as trusted as the file)."""
    file, factory = params["file"], params["factory"]
    p = Path(file) if Path(file).is_absolute() else Path(base or os.getcwd()) / file
    if not p.is_file():
        raise F.SceneError(f"`model.file`: {str(p)!r} not found (a path relative to the scene file)")
    spec = importlib.util.spec_from_file_location(f"lieseries_scene_model_{p.stem}", p)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as err:  # the user's file: whatever it raises is a bad scene, said in one line
        raise F.SceneError(f"`model.file`: running {p.name} raised {type(err).__name__}: {err}") from None
    fn = getattr(module, factory, None)
    if not callable(fn):
        raise F.SceneError(f"`model.factory`: {p.name} has no function {factory!r}")
    try:
        model = fn()
        as_poisson_system(model)
    except Exception as err:
        raise F.SceneError(f"`model.factory`: {factory}() in {p.name} must return a lieseries model or "
                           f"PoissonSystem; {type(err).__name__}: {err}") from None
    return model


def _state_initial(model, ini, precision):
    n = as_poisson_system(model).dimension
    if len(ini["y0"]) != n:
        raise ValueError(f"`initial.y0` must have {n} numbers, one per variable; got {len(ini['y0'])}")
    return make_state(ini["y0"], precision, inputs={"initial.y0": ini["y0"]})


register_initial_family(InitialFamily(
    "state",
    fields={"y0": (F.list_of(F.number, allow_scalar=False), F.REQUIRED)},
    docs={"y0": ("list of numbers", "the state itself, one number per variable (python models)")},
    state=_state_initial,
))

register_model_kind(ModelKind(
    "python",
    fields={"file": (F.string, F.REQUIRED), "factory": (F.identifier, "make")},
    docs={"file": ("path", "a Python file (relative to the scene file) defining the model; it runs as code"),
          "factory": ("Python name", "the function of that file returning a lieseries model or PoissonSystem")},
    build=_python_model, family="state", label="model",
))
