"""The one registry of integration methods and their adapters: each method is run from a specification dict and
gives one :class:`RunRecord` (the one record of a run, used by studies, scenes and reports; ``MethodRun``,
``RunRow`` and ``WorkPrecisionRow`` are its other names).

Each method is a :class:`Method` (its scene fields, label, precision, setting, digits, run, atlas run and quick-mode
scaling) registered with :func:`register_method`; scenes, studies and the scene runner read the registry, so a new
method is one :class:`Method` and one registration.

Methods
-------
``{"method": "taylor", "precision": P, "tol": T}``
    heyoka's adaptive Taylor method through :func:`lieseries.integrate`, P = "double" | "long double" | "quad" |
    int bits; T a tolerance (default: the precision's epsilon).
``{"method": "lie", "dps": D, "tol": T, "order": N}``
    the Lie-series integrator :func:`lieseries.lie_integrate` (mpmath); ``tol`` and ``order`` optional.
``{"method": "scipy", "rtol": R, "atol": A}``
    scipy's ``solve_ivp(method="DOP853")`` on a right-hand side compiled from the system's heyoka vector field
    with ``heyoka.cfunc`` (parameters in double). ``atol`` defaults to ``rtol``.
``{"method": "validated", "dps": D, "order": N}``
    certified enclosures in Arb ball arithmetic, :func:`lieseries.validated_integrate`: the states are the balls'
    midpoints (as mpf) and ``extra`` holds ``certified_digits`` (at each output time) and ``max_radius``; the
    enclosures provably contain the exact solution, which the run's error against the reference confirms.
``{"method": "mpmath", "dps": D, "t_max": S}``
    ``mpmath.odefun`` (a Taylor method in pure mpmath) on a pure-mpmath right-hand side. It is slow: the run is
    capped at ``|t| <= t_max`` (default 2) and its error is measured at the time it reached.

Any of ``tol``, ``rtol``, ``dps`` (and ``precision``) may be a list in :func:`expand_methods`: one run per value.

Timing: ``run_time`` is the wall time of the call, best of ``repeat`` (repeats stop once a method has used two
seconds); heyoka's compile time (and the scipy right-hand side's) is kept apart in ``build_time``. Times are
measured in this one run on a shared machine: compare them with each other, not with other runs.
"""

from .builtin import clear_rhs_cache
from .registry import (LIST_KEYS, METHODS, REPEAT_BUDGET, Method, MethodRun, RunRecord, best_of, default_methods,
                       expand_methods, method_label, method_plugin, methods_registry, normalize_method, precision_name,
                       reference_bits, reference_dps, register_method, run_atlas_method, run_method, run_precision, scene_methods,
                       setting, thin, unregister_method)

__all__ = [
    "METHODS",
    "Method",
    "MethodRun",
    "RunRecord",
    "register_method",
    "unregister_method",
    "scene_methods",
    "method_plugin",
    "methods_registry",
    "best_of",
    "clear_rhs_cache",
    "default_methods",
    "expand_methods",
    "method_label",
    "normalize_method",
    "precision_name",
    "run_precision",
    "reference_bits",
    "reference_dps",
    "run_method",
    "run_atlas_method",
    "setting",
    "thin",
    "LIST_KEYS",
    "REPEAT_BUDGET",
]
