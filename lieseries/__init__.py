"""lieseries: high-order Taylor and Lie-series integration of Hamiltonian systems with non-canonical brackets.

Public API (stable names)::

    ls.EulerPoisson, ls.Sphere, ls.SphereDirac     models
    ls.HeavyTop                                    the rigid body with gravity (EulerPoisson's layout)
    ls.SphericalPendulum, ls.PlanarPendulum,       pendulums in Cartesian coordinates (Dirac bracket)
    ls.DoubleSphericalPendulum
    ls.EllipsoidGeodesic                           geodesics on a triaxial ellipsoid (Jacobi's problem)
    ls.PoissonSystem                               write your own from a bracket and a Hamiltonian
    ls.ConstrainedSystem                           a Lagrangian and holonomic constraints -> Dirac-bracket model
    ls.integrate                                   heyoka's adaptive Taylor method, any precision
    ls.Event                                       zero crossings to record or stop at (both engines)
    ls.PrecisionWarning                            binary data fed to a run above their precision
    ls.lie_series, ls.LieSeries                    the truncated operator exp(t X_H) at a point, in mpmath
    ls.lie_integrate                               adaptive Lie-series stepping, same Solution type
    ls.validated_integrate                         certified enclosures (Arb balls) of the solution
    ls.rigid_body_series                           R(t) from R0 = 1 as an exact series in t (paper, dt61)
    ls.Solution, ls.Stats                          what integrators return
    ls.exact                                       closed-form references in mpmath
    ls.studies                                     error vs order, work-precision, drift (plain data)
"""

from .interrupts import hold_while_importing, release_after_import

hold_while_importing(__name__)  # Ctrl-C now would break a C extension half way: it waits for the end of the import

from . import exact, studies  # noqa: E402
from .events import Event
from .models import (ConstrainedSystem, DampedEulerPoisson, DoubleSphericalPendulum, EllipsoidGeodesic, EulerPoisson,
                     HeavyTop, Model, PlanarPendulum, Sphere, SphereDirac, SphericalPendulum)
from .poisson import PoissonSystem
from .precision import Precision, PrecisionWarning, resolve_precision
from .solution import EnsembleSolution, Solution, Stats
from .lie.integrator import lie_integrate
from .lie.operator import LieSeries, lie_series
from .lie.symbolic import rigid_body_series
from .api import integrate
from .validated import validated_integrate

__all__ = [
    "exact",
    "studies",
    "DampedEulerPoisson",
    "EulerPoisson",
    "Model",
    "Sphere",
    "SphereDirac",
    "ConstrainedSystem",
    "HeavyTop",
    "SphericalPendulum",
    "PlanarPendulum",
    "DoubleSphericalPendulum",
    "EllipsoidGeodesic",
    "PoissonSystem",
    "Event",
    "PrecisionWarning",
    "Precision",
    "resolve_precision",
    "Solution",
    "EnsembleSolution",
    "Stats",
    "integrate",
    "lie_series",
    "LieSeries",
    "lie_integrate",
    "rigid_body_series",
    "validated_integrate",
]

__version__ = "0.1.0"

release_after_import(__name__)
del hold_while_importing, release_after_import
