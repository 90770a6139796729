"""Studies: error against order, error against run time, invariant drift. Plain data, no plotting, no file I/O.

Every study returns a dataclass with a ``to_dict()`` (JSON-ready: floats, ints, strings, lists, dicts); the
report layer (:mod:`lieseries.report`) turns it into tables and plots.

What the studies share (reference solutions, the quantities compared, the error measure) lives in
:mod:`lieseries.studies.reference` and is re-exported here.
"""

from . import reference
from .reference import (  # noqa: F401
    NUMERICAL_REFERENCE_BITS,
    NUMERICAL_REFERENCE_TOL,
    Reference,
    has_exact_solution,
    loglog_slope,
    observable_names,
    observables,
    reference_solution,
    reference_solutions,
    state_error,
    theoretical_radius,
)
from .convergence import ErrorVsOrder, error_vs_order
from .drift import Drift, drift
from .work_precision import (
    MethodRun,
    WorkPrecision,
    WorkPrecisionRow,
    default_methods,
    run_method,
    work_precision,
)
from .stability import Stability, StabilityCase, StabilityRow, stability

__all__ = reference.__all__ + [
    "ErrorVsOrder",
    "error_vs_order",
    "WorkPrecision",
    "WorkPrecisionRow",
    "MethodRun",
    "run_method",
    "work_precision",
    "default_methods",
    "Drift",
    "drift",
    "Stability",
    "StabilityCase",
    "StabilityRow",
    "stability",
]
