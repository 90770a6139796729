"""The heavy top: the rigid body of :mod:`~lieseries.models.euler_poisson` with gravity acting on its centre of mass.

Same state (R row-major, then the body angular momentum M) and the same bracket (Chetaev, 11.20.2, or the
intermediate 11.20); only the Hamiltonian changes::

    H = 1/2 M . I^-1 M + mass g (R com)_3 = 1/2 M . I^-1 M + mass g Gamma . com,   Gamma = (R31, R32, R33)

R maps body to lab coordinates, so the third row of R is the upward vertical seen in the body frame, and ``com``
is the centre of mass in the body frame, measured from the fixed point. The motion is

    dR/dt = R hat(Omega),   dM/dt = M x Omega + mass g Gamma x com,   so  dGamma/dt = Gamma x Omega

(the Euler-Poisson equations of the heavy top). Conserved: H, the vertical angular momentum (R M)_3 = Gamma . M,
R R^T; for the Lagrange top (I1 = I2, com on the third axis) also M3.
"""

from __future__ import annotations

import heyoka as hy
import numpy as np

from ..poisson import PoissonSystem
from ..precision import data_bits, export_mpf, to_fraction
from ..precision import thread_mp as mp
from .euler_poisson import EulerPoisson

__all__ = ["HeavyTop"]


class HeavyTop(EulerPoisson):
    """A rigid body with a fixed point in a uniform gravity field (module docstring); 12 variables.

    Parameters
    ----------
    inertia : 3 numbers or a symmetric positive-definite 3x3
        The inertia tensor about the fixed point, in the body frame (as :class:`EulerPoisson`).
    com : 3 numbers
        The centre of mass in the body frame, from the fixed point.
    mass : positive number
    g : number
        The gravitational acceleration (the potential is ``mass g`` times the height of the centre of mass).
    bracket : {"chetaev", "intermediate"}

    All numbers are kept exact (str such as "9.81", int, Fraction); the products ``mass g com_i`` are runtime
    parameters rounded once to each working precision. ``initial_state(omega, R0=None)`` as for EulerPoisson.
    """

    closed_form = None  # gravity: the free body's closed form does not describe it

    def __init__(self, inertia=(1, 2, 3), com=(0, 0, 1), mass=1, g=1, bracket: str = "chetaev"):
        arr = np.asarray(com, dtype=object)
        if arr.shape != (3,):
            raise ValueError(f"`com` must be three numbers (the centre of mass in the body frame); got shape "
                             f"{arr.shape}")
        self._com = [to_fraction(v, f"com[{i}]") for i, v in enumerate(arr)]
        self.mass_exact = to_fraction(mass, "mass")
        if self.mass_exact <= 0:
            raise ValueError(f"`mass` must be positive; got {float(self.mass_exact)}")
        self.g_exact = to_fraction(g, "g")
        self._heavy_bits = {"com": data_bits(list(arr)), "mass": data_bits([mass]), "g": data_bits([g])}
        super().__init__(inertia, bracket)

    def _build(self) -> PoissonSystem:
        base = super()._build()
        z = base.variables
        npar = len(base.parameter_values)
        weight = [self.mass_exact * self.g_exact * c for c in self._com]
        potential = hy.sum([hy.par[npar + i] * z[6 + i] for i in range(3)])
        params = dict(zip(base.parameter_names, base.parameter_values))
        params.update({f"mgc{i + 1}": w for i, w in enumerate(weight)})
        sources = {k: "inertia" for k in base.parameter_names}
        sources.update({f"mgc{i + 1}": "com" for i in range(3)})
        return PoissonSystem(
            z, base.tensor, base.hamiltonian + potential, parameters=params,
            name=f"heavy top ({self.bracket})", input_bits={**base.coarse_data(), **self._heavy_bits},
            parameter_sources=sources, jacobi=False)  # the bracket is EulerPoisson's, checked by its tests

    @property
    def com_exact(self) -> list:
        """The centre of mass (body frame) as exact Fractions."""
        return list(self._com)

    def invariants(self, y) -> dict:
        """``energy`` (kinetic + mass g Gamma . com), ``L3`` = (R M)_3 = Gamma . M (the vertical angular momentum),
        ``M2`` = |M|^2 (conserved only without torque), ``orthogonality``, ``det_R`` (mpf; lists for rows)."""
        out = super().invariants(y)
        rows, bits, was_1d = self._rows(y)
        energy = out["energy"] if not was_1d else [out["energy"]]
        total = []
        with mp.workprec(bits + 16):
            w = [mp.mpf(f.numerator) / f.denominator for f in (self.mass_exact * self.g_exact * c for c in self._com)]
            for r, e in zip(rows, energy):
                gam = [mp.mpf(v.numerator) / v.denominator for v in r[6:9]]
                total.append(mp.mpf(e) + mp.fsum(a * b for a, b in zip(w, gam)))
        total = export_mpf(total)
        out["energy"] = total[0] if was_1d else total
        del out["L1"], out["L2"]
        return out

    def __repr__(self) -> str:
        base = super().__repr__()[len("EulerPoisson("):-1]
        return (f"HeavyTop({base}, com={tuple(float(c) for c in self._com)}, mass={float(self.mass_exact)}, "
                f"g={float(self.g_exact)})")
