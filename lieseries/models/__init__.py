"""Built-in models: each a PoissonSystem plus state helpers, invariants and input checks."""

from .base import Model
from .euler_poisson import EulerPoisson
from .sphere import Sphere, SphereDirac

__all__ = ["Model", "EulerPoisson", "Sphere", "SphereDirac"]
