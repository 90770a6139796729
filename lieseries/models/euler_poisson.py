"""The free asymmetric rigid body as a Hamiltonian system on the intermediate submanifold (Euler-Poisson equations).

State (12 numbers): the matrix R row-major (R11, R12, ..., R33), then the body angular momentum M = I Omega.
Hamiltonian H = 1/2 M . I^-1 M (paper, eq. 11.26). Two brackets:

``"chetaev"`` (default, paper eq. 11.20.2)
    {R_ij, R_ab} = 0, {M_i, M_j} = -eps_ijk M_k, {M_i, R_jk} = -eps_ikm R_jm.
``"intermediate"`` (paper eq. 11.20)
    {R_ij, R_ab} = 0, {M_i, M_j} = -eps_ijk ((R^T R)^-1 M)_k, {M_i, R_jk} = -eps_ikm (R^-T)_jm.

Both give dR/dt = R hat(Omega), dM/dt = M x Omega on R^T R = 1 (paper eq. p26). Physical motions start from
R(0) = identity (eq. 11.20.1); :meth:`EulerPoisson.initial_state` does that by default.

The inertia tensor may be diagonal (three principal moments) or a full symmetric positive-definite matrix (a lab
frame not aligned with the axes of inertia, the remark after eq. 11.26). The entries of I^-1 are heyoka runtime
parameters, computed exactly (rational arithmetic) and rounded once to the working precision.
"""

from __future__ import annotations

import math
import warnings
from decimal import Decimal, localcontext
from fractions import Fraction

import heyoka as hy
from ..precision import thread_mp as mp
import numpy as np

from ..caller import stacklevel
from ..poisson import PoissonSystem
from ..precision import (BinaryFraction, binary_inputs, data_bits, export_mpf, resolve_precision, short_decimal,
                         state_bits, to_fraction)
from .. import fields as F
from .base import Model, make_state
from .constrained import ConstrainedSystem
from .kinds import InitialFamily, ModelKind, register_initial_family, register_model_kind

__all__ = ["EulerPoisson", "DampedEulerPoisson", "levi_civita"]


def levi_civita(i: int, j: int, k: int) -> int:
    """The permutation symbol eps_ijk for indices in {0, 1, 2}."""
    return (i - j) * (j - k) * (k - i) // 2


def _parse_inertia(inertia):
    """Exact 3x3 inertia tensor (Fractions) from three moments or a 3x3 matrix, validated."""
    try:
        arr = np.asarray(inertia, dtype=object)
    except Exception:  # pragma: no cover - numpy refuses ragged input
        raise ValueError("`inertia` must be three principal moments or a 3x3 matrix") from None
    if arr.shape == (3,):
        d = [to_fraction(v, f"inertia[{i}]") for i, v in enumerate(arr)]
        if any(v <= 0 for v in d):
            raise ValueError(
                f"`inertia` principal moments must be positive; got {tuple(float(v) for v in d)}"
            )
        I = [[d[i] if i == j else Fraction(0) for j in range(3)] for i in range(3)]
    elif arr.shape == (3, 3):
        I = [[to_fraction(arr[i, j], f"inertia[{i}][{j}]") for j in range(3)] for i in range(3)]
        scale = max(abs(v) for r in I for v in r)
        asym = max(abs(I[i][j] - I[j][i]) for i in range(3) for j in range(3))
        if asym > scale * Fraction(1, 10**12):
            raise ValueError(
                "`inertia` must be symmetric; the largest |I_ij - I_ji| is "
                f"{float(asym):.3g} (relative {float(asym / scale):.3g}). Pass (I + I^T)/2 if that is what you mean."
            )
        # round-off asymmetry below 1e-12 relative: use the symmetric part, exactly
        I = [[(I[i][j] + I[j][i]) / 2 for j in range(3)] for i in range(3)]
    else:
        raise ValueError(
            f"`inertia` must be three principal moments or a 3x3 matrix; got shape {arr.shape}"
        )
    # the model's helpers (principal moments, the triangle inequality, saddle_rate) use doubles
    big = max(abs(v) for r in I for v in r)
    small = min(abs(v) for r in I for v in r if v != 0)
    if big > 10**300 or small < Fraction(1, 10**300):
        raise ValueError(
            f"`inertia` entries must lie within 1e-300 .. 1e300 in magnitude; got one of about "
            f"{short_decimal(big if big > 10**300 else small)}: the model computes its principal moments and checks "
            "in double. Rescale the unit of mass or length (the motion is the same with the inertia and the angular "
            "velocity rescaled)."
        )
    # Sylvester's criterion, exact
    m1 = I[0][0]
    m2 = I[0][0] * I[1][1] - I[0][1] * I[1][0]
    m3 = _det3(I)
    if not (m1 > 0 and m2 > 0 and m3 > 0):
        eig = np.linalg.eigvalsh(np.array([[float(v) for v in r] for r in I]))
        raise ValueError(
            f"`inertia` must be positive-definite; got eigenvalues {tuple(float(e) for e in eig)}"
        )
    return I


def _det3(A):
    return (
        A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1])
        - A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0])
        + A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0])
    )


#: Units of the last place a rotation given in binary numbers (or rounded to a precision) may miss R R^T = 1 by:
#: each of the 9 entries is rounded once, and each entry of R R^T sums three products of them.
ROTATION_ULPS = 16


def _rotation_tolerance(R0, precision) -> Fraction:
    """How far from a rotation ``R0`` may honestly be: 0 for exact entries (an exact state must be exactly a
    rotation), ROTATION_ULPS units of the last place of the least precision among its binary entries and the
    state's ``precision``."""
    bits = list(binary_inputs(R0, "R0").values())
    if precision is not None:
        bits.append(resolve_precision(precision).bits)
    return Fraction(ROTATION_ULPS, 2 ** min(bits)) if bits else Fraction(0)


def _check_rotation(R, tol, argname):
    """Refuse (naming ``argname``) a 3x3 matrix of Fractions that is not a rotation to ``tol``: max |R R^T - 1|
    above ``tol`` (the entries of a rotation are at most 1, so this is also relative), or det R <= 0."""
    defect = max(abs(sum(R[i][k] * R[j][k] for k in range(3)) - (i == j)) for i in range(3) for j in range(3))
    det = _det3(R)
    if defect > tol:
        how = ("exact entries (ints, Fractions, decimal strings) must form an exact rotation: give rational "
               "entries (e.g. 3/5, 4/5; rational rotations come arbitrarily close to any rotation), or pass "
               "`precision=` (bits) to round the state to a precision that the residual fits"
               if tol == 0 else
               f"the data's precision allows {float(tol):.2g}; orthonormalise it (e.g. "
               "scipy.spatial.transform.Rotation.from_matrix(R0).as_matrix()) or give it exactly")
        raise ValueError(
            f"`{argname}` must be a rotation matrix: max |{argname} {argname}^T - 1| = {_show(defect, 3)} and "
            f"det {argname} = {_show(det, 17)}. R R^T is conserved by the equations, so a non-orthogonal "
            f"{argname} never becomes a rigid motion; {how}."
        )
    if det <= 0:
        raise ValueError(f"`{argname}` must be a proper rotation (det {argname} = +1); got a reflection "
                         f"(det {argname} = {_show(det, 17)})")


def _show(x: Fraction, digits: int) -> str:
    """A Fraction in ``digits`` significant digits, also beyond the range of a float (entries of 1e200 made the
    message itself fail with OverflowError)."""
    try:
        return format(float(x), f".{digits}g")
    except OverflowError:
        with localcontext() as ctx:
            ctx.prec = digits + 5
            return format(Decimal(x.numerator) / Decimal(x.denominator), f".{digits}g")



def _inverse3(A):
    det = _det3(A)
    C = _cofactors(A)
    return [[C[j][i] / det for j in range(3)] for i in range(3)]


def _cofactors(R):
    """Cofactor matrix of a 3x3 matrix of expressions (cyclic-index form, signs built in)."""
    return [
        [
            R[(i + 1) % 3][(j + 1) % 3] * R[(i + 2) % 3][(j + 2) % 3]
            - R[(i + 1) % 3][(j + 2) % 3] * R[(i + 2) % 3][(j + 1) % 3]
            for j in range(3)
        ]
        for i in range(3)
    ]


class EulerPoisson(Model):
    """Free rigid body: R (3x3, row-major) and body angular momentum M; 12 variables.

    Parameters
    ----------
    inertia : sequence of 3 numbers, or 3x3 nested sequence
        Principal moments (I1, I2, I3), or a full symmetric positive-definite inertia tensor. Entries may be
        int, str ("0.1" is exact), Fraction, float or mpf. Moments violating the triangle inequality
        I_i + I_j >= I_k describe no physical body: the equations are still integrated, with a warning.
    bracket : {"chetaev", "intermediate"}
        The Poisson structure (module docstring). Both give the same motion on R^T R = 1.

    Examples
    --------
    >>> import lieseries as ls
    >>> body = ls.EulerPoisson(inertia=(1, 2, 3))
    >>> y0 = body.initial_state(omega=(1, "0.1", "0.5"))   # strings: exact decimals
    >>> sol = ls.integrate(body, y0, t=20.0)
    """

    def __init__(self, inertia=(1, 2, 3), bracket: str = "chetaev"):
        I = _parse_inertia(inertia)
        self._input_bits = {"inertia": data_bits(np.asarray(inertia, dtype=object).ravel())}
        self._I = I
        self._Iinv = _inverse3(I)
        self.diagonal = all(I[i][j] == 0 for i in range(3) for j in range(3) if i != j)
        eig = sorted(np.linalg.eigvalsh(np.array([[float(v) for v in r] for r in I])))
        self.principal_moments = tuple(float(e) for e in eig)
        if eig[0] + eig[1] < eig[2] * (1 - 1e-12):
            warnings.warn(
                f"`inertia` principal moments ({', '.join(f'{e:.6g}' for e in eig)}) violate the triangle "
                "inequality I1 + I2 >= I3: no "
                "physical body has them (the mass matrix g = tr(I)/2 - I has a negative entry). The equations are "
                "integrated as given.",
                UserWarning,
                stacklevel=stacklevel(),
            )
        if bracket not in ("chetaev", "intermediate"):
            raise ValueError(f"`bracket` must be 'chetaev' or 'intermediate'; got {bracket!r}")
        self.bracket = bracket
        self.poisson = self._build()

    # -- construction ------------------------------------------------------------------------------------------
    def _build(self) -> PoissonSystem:
        names = [f"R{i + 1}{j + 1}" for i in range(3) for j in range(3)] + ["M1", "M2", "M3"]
        z = hy.make_vars(*names)
        R = [[z[3 * i + j] for j in range(3)] for i in range(3)]
        M = z[9:]
        if self.diagonal:
            params = {f"Iinv{i + 1}": self._Iinv[i][i] for i in range(3)}
        else:
            idx = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
            params = {f"Iinv{a + 1}{b + 1}": self._Iinv[a][b] for a, b in idx}
            pmap = {}
            for n_, (a, b) in enumerate(idx):
                pmap[(a, b)] = pmap[(b, a)] = hy.par[n_]
        if self.diagonal:
            H = 0.5 * hy.sum([hy.par[i] * M[i] ** 2 for i in range(3)])
        else:
            H = hy.sum(
                [0.5 * pmap[(i, i)] * M[i] ** 2 for i in range(3)]
                + [pmap[(i, j)] * M[i] * M[j] for i in range(3) for j in range(i + 1, 3)]
            )

        n = 12
        P = [[0] * n for _ in range(n)]
        if self.bracket == "chetaev":
            Mvec = list(M)
            Rm = R
        else:
            C = _cofactors(R)
            det = hy.sum([R[0][m] * C[0][m] for m in range(3)])
            Rm = [[C[j][m] / det for m in range(3)] for j in range(3)]  # R^-T
            G = [[hy.sum([C[j][k] * C[j][l] for j in range(3)]) / det**2 for l in range(3)] for k in range(3)]
            Mvec = [hy.sum([G[k][l] * M[l] for l in range(3)]) for k in range(3)]
        for i in range(3):
            for j in range(3):
                if i == j:
                    continue
                k = 3 - i - j
                P[9 + i][9 + j] = -Mvec[k] if levi_civita(i, j, k) > 0 else Mvec[k]
        for i in range(3):
            for k in range(3):
                if i == k:
                    continue
                m = 3 - i - k
                sign = -levi_civita(i, k, m)  # {M_i, R_jk} = -eps_ikm R_jm (one m survives)
                for j in range(3):
                    P[9 + i][3 * j + k] = Rm[j][m] if sign > 0 else -Rm[j][m]
                    P[3 * j + k][9 + i] = -Rm[j][m] if sign > 0 else Rm[j][m]
        # Chetaev bracket: M_i moves R as R -> R exp(t A) with A antisymmetric and R commutes with R, so the entries
        # of R R^T are Casimirs (the energy guard checks them: a run can keep H and wreck R)
        casimirs = ({f"RRT{a + 1}{b + 1}": hy.sum([R[a][m] * R[b][m] for m in range(3)])
                     for a in range(3) for b in range(a, 3)} if self.bracket == "chetaev" else None)
        return PoissonSystem(z, P, H, parameters=params, name=f"Euler-Poisson ({self.bracket})",
                             input_bits=self._input_bits, parameter_sources={k: "inertia" for k in params},
                             casimirs=casimirs,
                             jacobi=False)  # the bracket is checked by the tests (tests/test_poisson.py)

    # -- state helpers -----------------------------------------------------------------------------------------
    @property
    def inertia(self) -> np.ndarray:
        """The inertia tensor as a float64 3x3 array."""
        return np.array([[float(v) for v in r] for r in self._I])

    @property
    def inertia_exact(self) -> list:
        """The inertia tensor as exact Fractions."""
        return [list(r) for r in self._I]

    def check_parameters(self, values, argname: str = "params") -> None:
        """The parameters are the entries of I^-1 (``poisson.parameter_names``): they must form a positive-definite
        matrix (a body with positive moments of inertia); checked exactly, by the leading minors."""
        if self.diagonal:
            A = [[values[0], 0, 0], [0, values[1], 0], [0, 0, values[2]]]
        else:
            a11, a12, a13, a22, a23, a33 = values[:6]
            A = [[a11, a12, a13], [a12, a22, a23], [a13, a23, a33]]
        minors = [A[0][0], A[0][0] * A[1][1] - A[0][1] * A[1][0], _det3(A)]
        if not all(m > 0 for m in minors):
            raise ValueError(
                f"`{argname}` gives the inverse inertia I^-1 = {[[float(v) for v in r] for r in A]} (entries in the "
                f"order {list(self.poisson.parameter_names)[:6 if not self.diagonal else 3]}), which is not "
                "positive definite: every moment of inertia must be positive and finite (a zero entry of I^-1 is "
                "an infinite moment); give the entries of I^-1, not of I"
            )

    @property
    def inverse_inertia_exact(self) -> list:
        """I^-1 as exact Fractions."""
        return [list(r) for r in self._Iinv]

    def initial_state(self, omega, R0=None, precision=None) -> np.ndarray:
        """The 12-number state with R(0) = ``R0`` (identity by default) and M = I ``omega``.

        Parameters
        ----------
        omega : sequence of 3 numbers
            Initial angular velocity in the body frame (exact input such as "0.1" or Fraction stays exact; a
            binary float such as 0.1 is the double nearest it: the state then carries 53 bits, ``data_bits``, and a
            run of more bits warns naming ``omega[i]``).
        R0 : 3x3, optional
            Initial orientation; must be a rotation (R0 R0^T = 1, det R0 = +1) to the precision the state carries:
            exactly for exact input (ints, Fractions, decimal strings such as "0.6", "0.8"), to ~16 units of the
            last place for binary numbers (1.8e-15 for doubles) or for a state rounded to ``precision``.
        precision : None, str or int
            None (default): an :class:`~lieseries.models.base.ExactState` that keeps the exact values (M = I omega
            formed exactly), so that a run at any precision starts from them. Otherwise the state rounded once
            to that precision ('double', 'long double', 'quad' or bits), which carries that precision only.
        """
        om = np.asarray(omega, dtype=object)
        if om.shape != (3,):
            raise ValueError(f"`omega` must be three numbers; got shape {om.shape}")
        w = [to_fraction(v, f"omega[{i}]") for i, v in enumerate(om)]
        if R0 is None:
            R = [[Fraction(int(i == j)) for j in range(3)] for i in range(3)]
        else:
            Ra = np.asarray(R0, dtype=object)
            if Ra.shape != (3, 3):
                raise ValueError(f"`R0` must be a 3x3 matrix; got shape {Ra.shape}")
            R = [[to_fraction(Ra[i, j], f"R0[{i}][{j}]") for j in range(3)] for i in range(3)]
            _check_rotation(R, _rotation_tolerance(R0, precision), "R0")
        M = [sum(self._I[i][j] * w[j] for j in range(3)) for i in range(3)]
        return make_state([R[i][j] for i in range(3) for j in range(3)] + M, precision,
                          inputs={"omega": omega, "R0": R0})

    def check_state(self, y, argname: str = "y0") -> list:
        """The state as exact Fractions. A state given directly (not from :meth:`initial_state`, which refuses an
        R0 that is not a rotation) whose R is not a rotation warns, naming ``argname``: the equations are those
        of the Poisson system on all 3x3 R, which keeps R R^T, so the run is of that system, not a rigid motion.
        The tolerance is loose (the square root of the state's precision; 1e-50 for exact numbers), so that a
        state a run ended in, drifted by rounding, continues silently."""
        z = super().check_state(y, argname)
        if getattr(y, "exact", None) is None:
            R = [z[3 * i:3 * i + 3] for i in range(3)]
            defect = max(abs(sum(R[i][k] * R[j][k] for k in range(3)) - (i == j))
                         for i in range(3) for j in range(3))
            det = _det3(R)
            bits = state_bits(y) if isinstance(y, np.ndarray) and y.dtype != object else data_bits(list(y))
            tol = Fraction(1, 10**50) if bits is None else Fraction(1, 2 ** (int(bits) // 2))
            if defect > tol or det <= 0:
                warnings.warn(
                    f"`{argname}` holds an R that is not a rotation: max |R R^T - 1| = {float(defect):.3g}, det R = "
                    f"{float(det):.17g}. The run keeps R R^T and det R, so it is not a rigid motion; start from "
                    "`model.initial_state(omega, R0)`, which checks R0, if you meant one.",
                    stacklevel=stacklevel(),
                )
        return z

    def check_rows(self, arr, argname: str = "Y0") -> None:
        """:meth:`check_state`'s warning for a float array of states (an ensemble's rows), at numpy speed: the first
        row whose R is not a rotation (beyond the square root of the format's precision) is named."""
        R = np.asarray(arr, dtype=np.float64)[:, :9].reshape(-1, 3, 3)
        defect = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero((defect > 2 * np.sqrt(np.finfo(np.asarray(arr).dtype).eps)) | (np.linalg.det(R) <= 0))
        if bad.size:
            i = int(bad[0])
            self.check_state(np.asarray(arr)[i], f"{argname}[{i}]")

    def rotation(self, y) -> np.ndarray:
        """R as a 3x3 array (one 3x3 per row for a 2-d array of states)."""
        y, _ = self._with_charts(y, None)
        arr = np.asarray(y) if not isinstance(y, np.ndarray) else y
        if arr.shape[-1] != 12:
            raise ValueError(f"`y` must have 12 entries per state; got shape {arr.shape}")
        return arr[..., :9].reshape(arr.shape[:-1] + (3, 3))

    def angular_momentum(self, y) -> np.ndarray:
        """Body angular momentum M."""
        y, _ = self._with_charts(y, None)
        arr = np.asarray(y) if not isinstance(y, np.ndarray) else y
        if arr.shape[-1] != 12:
            raise ValueError(f"`y` must have 12 entries per state; got shape {arr.shape}")
        return arr[..., 9:]

    def angular_velocity(self, y) -> np.ndarray:
        """Omega = I^-1 M, in the state's precision."""
        rows, bits, was_1d = self._rows(y)
        out = []
        with mp.workprec(bits + 16):
            Iinv = [[mp.mpf(v.numerator) / v.denominator for v in r] for r in self._Iinv]
            for r in rows:
                M = [mp.mpf(v.numerator) / v.denominator for v in r[9:]]
                out.append([mp.fsum(Iinv[i][j] * M[j] for j in range(3)) for i in range(3)])
        like = y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object)
        return self._out_array(out, bits, was_1d, like)

    def saddle_rate(self, momentum=1) -> float:
        """lambda = (|M| / I2) sqrt((I2 - I1)(I3 - I2) / (I1 I3)): the rate exp(lambda t) at which a perturbation of
        the rotation about the intermediate principal axis grows, for angular momentum ``|M| = momentum``
        (principal moments I1 <= I2 <= I3). Errors of a motion on the separatrix grow at this rate once it nears
        that rotation."""
        I1, I2, I3 = self.principal_moments
        return (abs(float(to_fraction(momentum, "momentum"))) / I2) * math.sqrt(max(0.0, (I2 - I1) * (I3 - I2)) / (I1 * I3))

    def invariants(self, y) -> dict:
        """Conserved quantities, evaluated in mpmath a little above the state's precision.

        Returns a dict of mpf (a dict of lists for a 2-d array of states): ``energy`` H, ``M2`` = |M|^2,
        ``L1, L2, L3`` the lab angular momentum R M, ``orthogonality`` = max |R R^T - 1| (conserved; equal to
        max |R^T R - 1| for a rotation), ``det_R``.
        """
        rows, bits, was_1d = self._rows(y)
        keys = ("energy", "M2", "L1", "L2", "L3", "orthogonality", "det_R")
        res = {k: [] for k in keys}
        with mp.workprec(bits + 16):
            Iinv = [[mp.mpf(v.numerator) / v.denominator for v in r] for r in self._Iinv]
            for r in rows:
                z = [mp.mpf(v.numerator) / v.denominator for v in r]
                R = [z[3 * i: 3 * i + 3] for i in range(3)]
                M = z[9:]
                Om = [mp.fsum(Iinv[i][j] * M[j] for j in range(3)) for i in range(3)]
                res["energy"].append(mp.fsum(M[i] * Om[i] for i in range(3)) / 2)
                res["M2"].append(mp.fsum(m * m for m in M))
                for i in range(3):
                    res[f"L{i + 1}"].append(mp.fsum(R[i][j] * M[j] for j in range(3)))
                # R R^T, the Casimirs of the bracket: conserved for any R. The entries of R^T R are not when R is
                # not exactly a rotation (R0 in doubles): their largest moved by 1.3e-17 over a quad run, reported
                # as that run's drift
                res["orthogonality"].append(
                    max(abs(mp.fsum(R[i][k] * R[j][k] for k in range(3)) - (i == j)) for i in range(3) for j in range(3))
                )
                res["det_R"].append(_det3(R))
        return export_mpf({k: v[0] for k, v in res.items()} if was_1d else res)

    # -- the same body as a constrained system (the paper's derivation) -----------------------------------------
    def potential_of_R(self) -> tuple:
        """(U(R) as a string in R11..R33 and parameter names, {name: exact value}): the potential energy of the
        body's configuration, for :meth:`constrained_system`: ``("", {})`` for the free body."""
        return "", {}

    def constrained_system(self) -> ConstrainedSystem:
        """The same body derived by the paper's method (section "Rotating asymmetric body"): the nine entries of
        R with the six constraints R^T R = 1 and L = 1/2 tr(Rdot J Rdot^T) - U(R), J = tr(I)/2 - I (so that
        I = tr(J) - J), and the frame R^-T E_k (3.7) with momenta M1, M2, M3, in which its ``intermediate()`` is
        this model's equations (11.20). Its ``dirac()`` form (18 variables) is what the formulations study
        compares with them; ``reduced()`` is not available (six constraints). Built once."""
        cached = self.__dict__.get("constrained")
        if cached is not None:
            return cached
        R = [[f"R{i + 1}{j + 1}" for j in range(3)] for i in range(3)]
        tr = sum(self._I[i][i] for i in range(3))
        J = [[(tr / 2 if i == j else 0) - self._I[i][j] for j in range(3)] for i in range(3)]
        minors = [J[0][0], J[0][0] * J[1][1] - J[0][1] * J[1][0], _det3(J)]
        if any(m <= 0 for m in minors):
            raise ValueError(
                "`inertia`: the mass tensor J = tr(I)/2 - I of this body is not positive definite (principal "
                f"moments {', '.join(f'{m:.6g}' for m in self.principal_moments)}: the largest is not below the sum of "
                "the other two, a flat body or none at all), so its Lagrangian in R is singular and the paper's "
                "derivation from R does not apply")
        params = {}
        terms = []
        for i in range(3):
            for j in range(i, 3):
                if J[i][j] != 0:
                    params[f"J{i + 1}{j + 1}"] = J[i][j]
                    factor = f"J{i + 1}{j + 1}/2" if i == j else f"J{i + 1}{j + 1}"
                    terms += [f"{factor}*{R[k][i]}_dot*{R[k][j]}_dot" for k in range(3)]
        potential, extra = self.potential_of_R()
        params.update(extra)
        lagrangian = " + ".join(terms) + (f" - ({potential})" if potential else "")
        constraints = [" + ".join(f"{R[k][i]}*{R[k][j]}" for k in range(3)) + (" - 1" if i == j else "")
                       for i in range(3) for j in range(i, 3)]

        def cofactor(a, b):  # of R, with its sign: (R^-T)_ab = cofactor(a, b) / det R
            r = [x for x in range(3) if x != a]
            c = [x for x in range(3) if x != b]
            minor = f"{R[r[0]][c[0]]}*{R[r[1]][c[1]]} - {R[r[0]][c[1]]}*{R[r[1]][c[0]]}"
            return f"({minor})" if (a + b) % 2 == 0 else f"(-({minor}))"

        det = "(" + " + ".join(f"{R[0][b]}*{cofactor(0, b)}" for b in range(3)) + ")"
        # (R^-T E_k)_ab = sum_i (R^-T)_ai (E_k)_ib with (E_k)_ib = -eps_kib
        frame = [[" + ".join(f"{-levi_civita(k, i, b)}*{cofactor(a, i)}" for i in range(3) if levi_civita(k, i, b))
                  for a in range(3) for b in range(3)] for k in range(3)]
        frame = [[f"({e})/{det}" if e else "0" for e in row] for row in frame]
        system = ConstrainedSystem(lagrangian, [e for row in R for e in row], constraints, parameters=params,
                                   name=f"{self.poisson.name} from R", frame=frame, momenta=["M1", "M2", "M3"])
        # J and the weights are exact functions of the body's data: binary data (inertia=(1.1, 2, 2.5), g=9.81)
        # carry their bits into every derived form, as they do into this model
        system.input_bits.update(self.poisson.coarse_data())
        self.__dict__["constrained"] = system
        return system

    def surface_point(self, y) -> tuple:
        """(q, qdot) of :meth:`constrained_system` at the state ``y``: q = R (row-major), qdot = R hat(Omega),
        Omega = I^-1 M; exact Fractions from the state's exact value (marked with the bits of a state of doubles,
        or of one built from binary input, as the state itself is)."""
        z = self.check_state(y, "y")
        R = [z[3 * i:3 * i + 3] for i in range(3)]
        om = [sum(self._Iinv[i][j] * z[9 + j] for j in range(3)) for i in range(3)]
        hat = [[0, -om[2], om[1]], [om[2], 0, -om[0]], [-om[1], om[0], 0]]
        qdot = [sum(R[i][k] * hat[k][j] for k in range(3)) for i in range(3) for j in range(3)]
        q = [R[i][j] for i in range(3) for j in range(3)]
        bits = data_bits(y)
        if bits is None:
            return q, qdot
        # a state of doubles (or one built from binary input) carries its bits into q and qdot, so that a form
        # started from them does not claim more digits than y has
        sources = getattr(bits, "sources", ()) or ("y",)
        return ([BinaryFraction(v, bits, sources) for v in q], [BinaryFraction(v, bits, sources) for v in qdot])

    # -- how studies, runs and reports treat it ----------------------------------------------------------------
    closed_form = "free_rigid_body"

    def plot_quantity(self) -> tuple:
        return "angular velocity Omega", ("Omega1", "Omega2", "Omega3")

    def plot_values(self, compared_row) -> list:
        Iinv = np.linalg.inv(self.inertia)
        return [float(c) for c in Iinv @ np.array([float(v) for v in compared_row[9:12]])]

    def error_groups(self, n: int) -> list:
        return [(range(0, 9), "unit"), (range(9, 12), "norm")]  # R (a rotation), M (scale |M|)

    def perturbable(self) -> set:
        """The momentum M only: a perturbed R would no longer be a rotation, and R^T R is conserved only on the
        rotation group."""
        return {9, 10, 11}

    def __repr__(self) -> str:
        if self.diagonal:
            return f"EulerPoisson(inertia={tuple(float(self._I[i][i]) for i in range(3))}, bracket={self.bracket!r})"
        return f"EulerPoisson(inertia={self.inertia.tolist()}, bracket={self.bracket!r})"


class DampedEulerPoisson(EulerPoisson):
    """The rigid body with an internal dissipative torque: a stiff test case for explicit methods.

    dM/dt = M x Omega + damping * M x (M x Omega),  dR/dt = R hat(Omega).

    The torque keeps |M|^2 and R R^T but not the lab angular momentum R M, and dissipates energy,
    dE/dt = -damping |M x Omega|^2, driving the body to steady rotation about its axis of largest inertia on the
    relaxation time scale ~ 1 / (damping |M|^2 (1/I_min - 1/I_max)). A large ``damping`` makes the problem stiff:
    an explicit (Taylor) method needs steps of that size for the whole run, which the engine detects and reports.
    """

    closed_form = None  # its motion is not the free body's

    def __init__(self, inertia=(1, 2, 3), damping=1, bracket: str = "chetaev"):
        d = to_fraction(damping, "damping")
        self._damping_bits = data_bits([damping])
        if d < 0:
            raise ValueError(f"`damping` must be >= 0 (a negative value pumps energy in); got {float(d)}")
        self.damping = d
        super().__init__(inertia, bracket)

    def constrained_system(self):
        """Refused: the damping torque dissipates energy, so the motion is not that of a Lagrangian with
        constraints."""
        raise ValueError("a damped rigid body has no constrained_system(): its internal torque dissipates energy, "
                         "so it is not a Lagrangian system with constraints")

    def _build(self) -> PoissonSystem:
        base = super()._build()
        z = base.variables
        M = z[9:]
        Om = [hy.diff(base.hamiltonian, M[i]) for i in range(3)]
        k = hy.par[len(base.parameter_values)]

        def cross(a, b):
            return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

        MxO = cross(M, Om)
        torque = [k * c for c in cross(M, MxO)]
        params = dict(zip(base.parameter_names, base.parameter_values))
        params["damping"] = self.damping
        return PoissonSystem(
            z, base.tensor, base.hamiltonian, parameters=params, extra_field=[0] * 9 + torque,
            name=f"damped Euler-Poisson ({self.bracket})",
            input_bits={**self._input_bits, "damping": self._damping_bits}, jacobi=False,
            parameter_sources={**{k: "inertia" for k in base.parameter_names}, "damping": "damping"},
        )

    def check_parameters(self, values, argname: str = "params") -> None:
        super().check_parameters(values, argname)
        if values[-1] < 0:
            raise ValueError(f"`{argname}`: damping must be >= 0 (a negative value pumps energy in); got "
                             f"{float(values[-1])}")

    def __repr__(self) -> str:
        return super().__repr__().replace("EulerPoisson(", "DampedEulerPoisson(", 1)[:-1] + \
            f", damping={float(self.damping)})"


# -- scenes: [model] kind = "euler_poisson" | "damped_euler_poisson", [initial] omega, R0 ---------------------------
def _inertia_field(value, path):
    what = "a list of 3 numbers or a 3x3 list"
    if not isinstance(value, list) or len(value) != 3:
        F.fail(path, what, value)
    if all(isinstance(r, list) for r in value):
        if not all(len(r) == 3 for r in value):
            F.fail(path, what, value)
        for i, r in enumerate(value):
            for j, v in enumerate(r):
                F.number(v, f"{path}[{i}][{j}]")
    else:
        for i, v in enumerate(value):
            if isinstance(v, list):
                F.fail(path, what, value)
            F.number(v, f"{path}[{i}]")
    return value


_BRACKET = (F.choice("chetaev", "intermediate"), "chetaev")

register_initial_family(InitialFamily(
    "rigid_body",
    fields={"omega": (F.vector3, F.REQUIRED), "R0": (F.matrix3, None)},
    docs={"omega": ("3 numbers", "the body angular velocity Omega(0); R(0) = 1"),
          "R0": ("3x3 numbers", "an initial rotation instead of the identity")},
    state=lambda model, ini, precision: model.initial_state(ini["omega"], R0=ini.get("R0"), precision=precision),
))

register_model_kind(ModelKind(
    "euler_poisson",
    fields={"inertia": (_inertia_field, F.REQUIRED), "bracket": _BRACKET},
    docs={"inertia": ("3 numbers or 3x3 numbers", "principal moments, or a symmetric positive-definite tensor"),
          "bracket": ("'chetaev' | 'intermediate'", "the Poisson structure (paper 11.20.2 or 11.20)")},
    build=lambda p, base: EulerPoisson(p["inertia"], bracket=p["bracket"]),
    family="rigid_body", label="rigid body", data_fields=("inertia",),
))

register_model_kind(ModelKind(
    "damped_euler_poisson",
    fields={"inertia": (_inertia_field, F.REQUIRED), "damping": (F.nonnegative, F.REQUIRED), "bracket": _BRACKET},
    docs={"inertia": ("3 numbers or 3x3 numbers", "as for euler_poisson"),
          "damping": ("number >= 0", "the internal damping: the torque damping * M x (M x Omega)"),
          "bracket": ("'chetaev' | 'intermediate'", "as for euler_poisson")},
    build=lambda p, base: DampedEulerPoisson(p["inertia"], damping=p["damping"], bracket=p["bracket"]),
    family="rigid_body", label="damped rigid body", data_fields=("inertia", "damping"),
))
