"""The heavy top: the rigid body of :mod:`~lieseries.models.euler_poisson` with gravity acting on its centre of mass.

Same state (R row-major, then the body angular momentum M) and the same bracket (Chetaev, 11.20.2, or the
intermediate 11.20); only the Hamiltonian changes::

    H = 1/2 M . I^-1 M + mass g (R com)_3 = 1/2 M . I^-1 M + mass g Gamma . com,   Gamma = (R31, R32, R33)

R maps body to lab coordinates, so the third row of R is the upward vertical seen in the body frame, and ``com``
is the centre of mass in the body frame, measured from the fixed point. The motion is

    dR/dt = R hat(Omega),   dM/dt = M x Omega + mass g Gamma x com,   so  dGamma/dt = Gamma x Omega

(the Euler-Poisson equations of the heavy top). Conserved: H, the vertical angular momentum (R M)_3 = Gamma . M,
R R^T; and, in the two integrable cases with a body-frame inertia tensor diagonal:

- the Lagrange top (I1 = I2, com on the third axis): M3;
- the Kovalevskaya top (I1 = I2 = 2 I3, com in the equatorial plane com_3 = 0): Kovalevskaya's integral
  K = |(Omega1 + i Omega2)^2 - (mass g / I3) (com1 + i com2) (Gamma1 + i Gamma2)|^2, Omega = I^-1 M.
"""

from __future__ import annotations

import heyoka as hy
import numpy as np

from .. import fields as F
from ..poisson import PoissonSystem
from ..precision import data_bits, export_mpf, to_fraction
from ..precision import thread_mp as mp
from .euler_poisson import EulerPoisson
from .kinds import ModelKind, register_model_kind

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
        sources.update({f"mgc{i + 1}": "mass * g * com" for i in range(3)})  # "`com` gives" blamed com alone
        return PoissonSystem(
            z, base.tensor, base.hamiltonian + potential, parameters=params,
            name=f"heavy top ({self.bracket})", input_bits={**base.coarse_data(), **self._heavy_bits},
            parameter_sources=sources, jacobi=False)  # the bracket is EulerPoisson's, checked by its tests

    def potential_of_R(self) -> tuple:
        """mass g (R com)_3 = mass g (R31 com1 + R32 com2 + R33 com3), for the derived system."""
        axes = [i + 1 for i, c in enumerate(self._com) if c != 0]
        weight = {f"w{i}": self.mass_exact * self.g_exact * self._com[i - 1] for i in axes}
        return " + ".join(f"w{i}*R3{i}" for i in axes), weight

    @property
    def com_exact(self) -> list:
        """The centre of mass (body frame) as exact Fractions."""
        return list(self._com)

    @property
    def case(self) -> str | None:
        """``"lagrange"`` (I1 = I2, com on the third axis), ``"kovalevskaya"`` (I1 = I2 = 2 I3, com_3 = 0, com not
        0) or None (no integral beyond H and L3 known), for a diagonal inertia tensor (exact comparisons)."""
        I = self.inertia_exact
        if any(I[i][j] != 0 for i in range(3) for j in range(3) if i != j) or all(c == 0 for c in self._com):
            return None
        if I[0][0] == I[1][1] and self._com[0] == 0 and self._com[1] == 0:
            return "lagrange"
        if I[0][0] == I[1][1] == 2 * I[2][2] and self._com[2] == 0:
            return "kovalevskaya"
        return None

    def invariants(self, y) -> dict:
        """``energy`` (kinetic + mass g Gamma . com), ``L3`` = (R M)_3 = Gamma . M (the vertical angular momentum),
        ``orthogonality``, ``det_R``; ``M3`` for a Lagrange top, ``kovalevskaya`` (K, module docstring) for a
        Kovalevskaya top, ``M2`` = |M|^2 only when com = 0 (no torque) (mpf; lists for rows)."""
        out = super().invariants(y)
        rows, bits, was_1d = self._rows(y)
        energy = out["energy"] if not was_1d else [out["energy"]]
        total, extra = [], []
        case = self.case
        with mp.workprec(bits + 16):
            w = [mp.mpf(f.numerator) / f.denominator for f in (self.mass_exact * self.g_exact * c for c in self._com)]
            Iinv = [mp.mpf(r[i].numerator) / r[i].denominator for i, r in enumerate(self.inverse_inertia_exact)]
            for r, e in zip(rows, energy):
                z = [mp.mpf(v.numerator) / v.denominator for v in r]
                gam, M = z[6:9], z[9:]
                total.append(mp.mpf(e) + mp.fsum(a * b for a, b in zip(w, gam)))
                if case == "lagrange":
                    extra.append(M[2])
                elif case == "kovalevskaya":
                    # |(O1 + i O2)^2 - kappa (w1 + i w2)(G1 + i G2)|^2, w = mass g com, kappa = 1 / I3
                    o1, o2 = Iinv[0] * M[0], Iinv[1] * M[1]
                    re = o1 * o1 - o2 * o2 - Iinv[2] * (w[0] * gam[0] - w[1] * gam[1])
                    im = 2 * o1 * o2 - Iinv[2] * (w[0] * gam[1] + w[1] * gam[0])
                    extra.append(re * re + im * im)
        total = export_mpf(total)
        out["energy"] = total[0] if was_1d else total
        del out["L1"], out["L2"]
        if any(c != 0 for c in self._com):
            del out["M2"]
        if case is not None:
            extra = export_mpf(extra)
            out["M3" if case == "lagrange" else "kovalevskaya"] = extra[0] if was_1d else extra
        return out

    def __repr__(self) -> str:
        base = super().__repr__()[len("EulerPoisson("):-1]
        return (f"HeavyTop({base}, com={tuple(float(c) for c in self._com)}, mass={float(self.mass_exact)}, "
                f"g={float(self.g_exact)})")


# -- scenes: [model] kind = "heavy_top", [initial] omega, R0 (the rigid body's) ------------------------------------
def _inertia_field(value, path):
    """3 principal moments or a 3x3 tensor (the model checks symmetry and positivity)."""
    if isinstance(value, list) and value and all(isinstance(r, list) for r in value):
        return F.matrix3(value, path)
    return F.vector3(value, path)


register_model_kind(ModelKind(
    "heavy_top",
    fields={"inertia": (_inertia_field, F.REQUIRED), "com": (F.vector3, F.REQUIRED), "mass": (F.positive, 1),
            "g": (F.number, 1), "bracket": (F.choice("chetaev", "intermediate"), "chetaev")},
    docs={"inertia": ("3 numbers or 3x3 numbers", "the inertia tensor about the fixed point (body frame): principal "
                      "moments, or a symmetric positive-definite tensor"),
          "com": ("3 numbers", "the centre of mass in the body frame, from the fixed point"),
          "mass": ("positive number", "the mass"),
          "g": ("number", "the gravitational acceleration (the potential is mass g times the height of the centre "
                "of mass)"),
          "bracket": ("'chetaev' | 'intermediate'", "the Poisson structure (paper 11.20.2 or 11.20)")},
    build=lambda p, base: HeavyTop(p["inertia"], com=p["com"], mass=p["mass"], g=p["g"], bracket=p["bracket"]),
    family="rigid_body", label="heavy top", data_fields=("inertia", "com", "mass", "g"),
))
