"""Studies: error against order, error against run time, invariant drift, departure maps. Each computes plain data
(a dataclass with a ``to_dict()``: JSON-ready floats, ints, strings, lists, dicts) and is a plug-in
(:class:`Study`, :mod:`lieseries.studies.plugin`): its scene fields, quick mode, run, report section, plot and
summary live in its own module, and scenes, the scene runner and the report iterate the registry. (The stability
study runs scenes, so it lives above them: :mod:`lieseries.stability`.)

What the studies share (reference solutions, the quantities compared, the error measure) lives in
:mod:`lieseries.studies.reference` and is re-exported here.
"""

from . import reference
from .reference import (  # noqa: F401
    ClosedForm,
    register_closed_form,
    unregister_closed_form,
    NUMERICAL_REFERENCE_BITS,
    NUMERICAL_REFERENCE_TOL,
    numerical_reference,
    numerical_reference_label,
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
# the built-in studies register themselves in this order (the order of a report's sections)
from .convergence import ErrorVsOrder, error_vs_order
from .work_precision import WorkPrecision, WorkPrecisionRow, work_precision
from .drift import Drift, drift
from .departure import DepartureMap, departure_map
from .formulations import FormulationComparison, FormulationRadius, compare_formulations, formulation_radii
from .plugin import ReportContext, Study, StudyContext, register_study, studies_registry, unregister_study

__all__ = reference.__all__ + [
    "Study",
    "StudyContext",
    "ReportContext",
    "register_study",
    "unregister_study",
    "studies_registry",
    "ErrorVsOrder",
    "error_vs_order",
    "WorkPrecision",
    "WorkPrecisionRow",
    "work_precision",
    "Drift",
    "drift",
    "DepartureMap",
    "departure_map",
    "FormulationComparison",
    "compare_formulations",
    "FormulationRadius",
    "formulation_radii",
]
