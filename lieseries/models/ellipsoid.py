"""Geodesics on a triaxial ellipsoid (Jacobi's problem), in Cartesian coordinates with the Dirac bracket.

A free particle of unit mass on the ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 = 1::

    L = 1/2 |xdot|^2,   G = x^2/a^2 + y^2/b^2 + z^2/c^2 - 1,   H = |p|^2 / 2   (p = xdot)

derived by :class:`~lieseries.models.constrained.ConstrainedSystem` (its ``dirac()`` form). Its paths are the
geodesics, travelled at the constant speed |p|. Besides the energy and the Casimirs G and Phi = 2 (x/a^2, y/b^2,
z/c^2) . xdot, Joachimsthal's integral is conserved::

    J = (x^2/a^4 + y^2/b^4 + z^2/c^4) (xdot^2/a^2 + ydot^2/b^2 + zdot^2/c^2)

(for a geodesic, the product of the speed and the distance from the centre to the tangent plane, squared, over
that of the direction: Jacobi's problem is integrable).
"""

from __future__ import annotations

import numpy as np

from .. import fields as F
from ..precision import thread_mp as mp
from .constrained import ConstrainedSystem
from .kinds import ModelKind, register_model_kind
from .pendulum import ConstrainedModel, cached_system, positive

__all__ = ["EllipsoidGeodesic"]


class EllipsoidGeodesic(ConstrainedModel):
    """Geodesic motion on the ellipsoid with semi-axes ``axes`` = (a, b, c) along x, y, z (module docstring).

    State (x, y, z, p_x, p_y, p_z), p = xdot. ``invariants``: ``energy`` |p|^2/2, ``G1`` (the ellipsoid's
    equation), ``Phi1`` (its time derivative), ``joachimsthal`` (J of the module docstring).

    Examples
    --------
    >>> import lieseries as ls
    >>> ell = ls.EllipsoidGeodesic(axes=(1, 2, 3))
    >>> y0 = ell.initial_state(q=("2/7", "6/7", "18/7"), qdot=(1, 0, -1))
    """

    positive_parameters = ("a", "b", "c")

    def __init__(self, axes=(1, 2, 3)):
        arr = np.asarray(axes, dtype=object)
        if arr.shape != (3,):
            raise ValueError(f"`axes` must be the three semi-axes (a, b, c); got shape {arr.shape}")
        for i, v in enumerate(arr):
            positive(v, f"axes[{i}]")
        values = dict(zip(("a", "b", "c"), arr.tolist()))
        system = cached_system("ellipsoid geodesic", values, lambda: ConstrainedSystem(
            "(x_dot**2 + y_dot**2 + z_dot**2)/2", ["x", "y", "z"], ["x**2/a**2 + y**2/b**2 + z**2/c**2 - 1"],
            parameters=values, name="geodesic on an ellipsoid"))
        super().__init__(system)
        self.axes_exact = tuple(system.parameter_values[k] for k in ("a", "b", "c"))

    def extra_invariants(self, z) -> dict:
        inv2 = [1 / (mp.mpf(s.numerator) / s.denominator) ** 2 for s in self.axes_exact]
        n2 = mp.fsum((x * w) ** 2 for x, w in zip(z[:3], inv2))
        v2 = mp.fsum(v * v * w for v, w in zip(z[3:], inv2))
        return {"joachimsthal": n2 * v2}

    def __repr__(self) -> str:
        return f"EllipsoidGeodesic(axes={tuple(float(a) for a in self.axes_exact)})"


# -- scenes: [model] kind = "ellipsoid_geodesic", [initial] q, qdot ------------------------------------------------
def _axes_field(value, path):
    F.vector3(value, path)
    for i, v in enumerate(value):
        F.positive(v, f"{path}[{i}]")
    return value


register_model_kind(ModelKind(
    "ellipsoid_geodesic",
    fields={"axes": (_axes_field, [1, 2, 3])},
    docs={"axes": ("3 positive numbers", "the semi-axes (a, b, c) along x, y, z")},
    build=lambda p, base: EllipsoidGeodesic(axes=p["axes"]),
    family="configuration", label="ellipsoid geodesic", data_fields=("axes",),
))
