"""Built-in models: each a PoissonSystem plus state helpers, invariants and input checks."""

from .base import Model
from .euler_poisson import DampedEulerPoisson, EulerPoisson
from .sphere import Sphere, SphereDirac

__all__ = ["Model", "EulerPoisson", "DampedEulerPoisson", "Sphere", "SphereDirac"]
