"""Built-in models: each a PoissonSystem plus state helpers, invariants and input checks."""

from .base import Model
from .constrained import ConstrainedDirac, ConstrainedSystem
from . import constrained_kind  # noqa: F401  (registers the scene kind `constrained`)
from .euler_poisson import DampedEulerPoisson, EulerPoisson
from .ellipsoid import EllipsoidGeodesic
from .heavy_top import HeavyTop
from .pendulum import DoubleSphericalPendulum, PlanarPendulum, SphericalPendulum
from .sphere import Sphere, SphereDirac

__all__ = ["Model", "EulerPoisson", "DampedEulerPoisson", "HeavyTop", "Sphere", "SphereDirac", "ConstrainedSystem",
           "ConstrainedDirac", "SphericalPendulum", "PlanarPendulum", "DoubleSphericalPendulum",
           "EllipsoidGeodesic"]
