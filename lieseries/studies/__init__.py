"""Studies: error against order, error against run time, invariant drift, departure maps. Plain data, no plotting,
no file I/O. (The stability study runs scenes, so it lives above them: :mod:`lieseries.stability`.)

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
    max_difference,
    observable_names,
    observables,
    reference_solution,
    reference_solutions,
    state_error,
    theoretical_radius,
)
from .convergence import ErrorVsOrder, error_vs_order
from .drift import Drift, drift
from .work_precision import WorkPrecision, WorkPrecisionRow, work_precision
from .departure import DepartureMap, departure_map

__all__ = reference.__all__ + [
    "ErrorVsOrder",
    "error_vs_order",
    "WorkPrecision",
    "WorkPrecisionRow",
    "work_precision",
    "Drift",
    "drift",
    "DepartureMap",
    "departure_map",
]
