"""The rigid body's set-up: the inertia tensor reduced to sorted principal moments and a proper rotation, the
complete elliptic integral, and :class:`RigidBodyConstants` (the invariants and regime of a solution)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from ..precision import thread_mp as mp
from .inputs import CLASSIFY_DIGITS, fmt, is_sequence, loose_tolerance, to_real
from .linalg import det3


@dataclass(frozen=True)
class RigidBodyConstants:
    """Invariants and set-up of a free rigid-body solution.

    Attributes
    ----------
    energy : mpf
        ``E = M . I^-1 M / 2``.
    momentum_squared : mpf
        ``|M|^2``.
    branch : str
        ``'above'`` (``|M|^2 > 2 E I2``), ``'below'`` (``|M|^2 < 2 E I2``),
        ``'separatrix'``, ``'symmetric'`` (two equal moments, not steady),
        ``'spherical'`` (three equal moments) or ``'steady'`` (``Omega``
        parallel to a principal axis, including ``Omega = 0``).
    moments : tuple of 3 mpf
        Principal moments sorted increasingly, ``I1 <= I2 <= I3``.
    frame : tuple of 3 tuples of mpf
        Proper rotation ``Q`` with ``I = Q diag(moments) Q^T``; columns are
        the principal axes in the user's body frame.
    separatrix_gap : mpf
        ``|M|^2 - 2 E I2`` (0 for symmetric/spherical tops).
    m : mpf or None
        Elliptic parameter (``k^2``) of ``sn, cn, dn``; 1 on the separatrix;
        ``None`` otherwise.
    lam : mpf or None
        Frequency ``lam`` in ``u = u0 + lam t`` (elliptic and separatrix);
        for a symmetric top the body precession rate ``|Wb|``.
    u0 : mpf or None
        Phase ``u(0)`` (elliptic and separatrix branches).
    K, Kp : mpf or None
        Complete elliptic integrals ``K(m)`` and ``K'(m) = K(1 - m)``.
    period : mpf or None
        Period of ``Omega(t)`` (``4K/lam`` on the elliptic branches,
        ``2 pi/|Wb|`` for the symmetric top); ``None`` when not finite
        (separatrix) or not defined (``Omega`` constant).
    pole_distance : mpf
        Distance in complex time from ``t0 = 0`` to the nearest pole of
        ``Omega(t)``; ``mp.inf`` when ``Omega`` is entire (symmetric,
        spherical, steady).  Elliptic branches: the poles of ``sn, cn, dn``
        are at ``u = 2 j K + (2 k + 1) i K'``, so the distance is
        ``sqrt(d^2 + K'^2) / lam`` with ``d`` the distance of ``u0`` to the
        nearest multiple of ``2K``.  Separatrix: ``sech, tanh`` have poles at
        ``u = i (k + 1/2) pi``, so it is ``sqrt(u0^2 + pi^2/4) / lam``.
    pole_time : mpc or None
        One nearest pole (the one with positive imaginary part).
    working_dps : int
        Decimal digits used internally.
    """

    energy: object
    momentum_squared: object
    branch: str
    moments: tuple
    frame: tuple
    separatrix_gap: object
    m: Optional[object]
    lam: Optional[object]
    u0: Optional[object]
    K: Optional[object]
    Kp: Optional[object]
    period: Optional[object]
    pole_distance: object
    pole_time: Optional[object]
    working_dps: int


def parse_inertia(inertia, dps):
    """Return ``(d, Q, exact)``: sorted moments, proper rotation with I = Q diag(d) Q^T.

    ``exact`` is True when ``Q`` is a signed permutation (no diagonalisation
    round-off).
    """
    if not is_sequence(inertia):
        raise TypeError(
            "`inertia` must be three principal moments or a symmetric 3x3 matrix; "
            f"got {type(inertia).__name__}")
    if len(inertia) != 3:
        raise ValueError(
            "`inertia` must be three principal moments or a symmetric 3x3 matrix; "
            f"got a sequence of length {len(inertia)}")
    rows = list(inertia)
    nested = [is_sequence(r) for r in rows]
    if all(nested):
        for r in rows:
            if len(r) != 3:
                raise ValueError(f"`inertia` as a matrix must be 3x3; got a row of length {len(r)}")
        A = [[to_real(c, "inertia") for c in r] for r in rows]
        scale = max(abs(A[i][j]) for i in range(3) for j in range(3))
        if scale == 0:
            raise ValueError("`inertia` must be positive definite; got the zero matrix")
        asym = max(abs(A[i][j] - A[j][i]) for i in range(3) for j in range(3))
        tol = loose_tolerance(dps)
        if asym > tol * scale:
            raise ValueError(
                f"`inertia` must be symmetric (to relative tolerance {mp.nstr(tol, 3)}); got "
                f"max |I_ij - I_ji| = {mp.nstr(asym, 5)}. Pass a symmetric matrix.")
        A = [[(A[i][j] + A[j][i]) / 2 for j in range(3)] for i in range(3)]
        if A[0][1] == 0 and A[0][2] == 0 and A[1][2] == 0:
            return sort_moments([A[0][0], A[1][1], A[2][2]])
        evals, evecs = mp.eigsy(mp.matrix(A))
        ev = [evals[i] for i in range(3)]
        if not min(ev) > 0:
            raise ValueError(
                "`inertia` must be positive definite; got eigenvalues "
                f"({', '.join(mp.nstr(e, 8) for e in ev)})")
        order = sorted(range(3), key=lambda i: ev[i])
        d = [ev[i] for i in order]
        Q = [[evecs[r, order[c]] for c in range(3)] for r in range(3)]
        if det3(Q) < 0:
            for r in range(3):
                Q[r][1] = -Q[r][1]
        # merge eigenvalues equal to the classification tolerance
        eps = mp.mpf(10) ** -(dps + CLASSIFY_DIGITS) * d[2]
        if d[2] - d[0] <= eps:
            mean = (d[0] + d[1] + d[2]) / 3
            d = [mean, mean, mean]
        elif d[1] - d[0] <= eps:
            mean = (d[0] + d[1]) / 2
            d = [mean, mean, d[2]]
        elif d[2] - d[1] <= eps:
            mean = (d[1] + d[2]) / 2
            d = [d[0], mean, mean]
        return d, Q, False
    if any(nested):
        raise ValueError(
            "`inertia` must be three principal moments or a symmetric 3x3 matrix; "
            "got a mix of numbers and sequences")
    moments = [to_real(c, "inertia") for c in rows]
    return sort_moments(moments)


def sort_moments(moments):
    if not all(mi > 0 for mi in moments):
        raise ValueError(
            f"`inertia` must have three positive moments; got "
            f"({', '.join(fmt(mi) for mi in moments)})")
    order = sorted(range(3), key=lambda i: moments[i])  # stable
    d = [moments[i] for i in order]
    # column c of Q is the user axis e_{order[c]}
    Q = [[mp.mpf(1) if r == order[c] else mp.mpf(0) for c in range(3)] for r in range(3)]
    if det3(Q) < 0:  # odd permutation: flip the middle axis to stay right-handed
        for r in range(3):
            Q[r][1] = -Q[r][1]
    return d, Q, True


def complete_k(m, m1):
    """``(K(m), K'(m))`` from the parameter ``m`` and its complement ``m1 = 1 - m``, both given separately.

    ``K(m) = pi / (2 agm(1, sqrt(1 - m)))``, so ``K = pi / (2 agm(1, sqrt(m1)))`` and ``K' = K(m1) =
    pi / (2 agm(1, sqrt(m)))``: neither ``1 - m`` nor ``1 - m1`` is ever formed.  This matters at both ends of
    the elliptic branches.  Near a steady rotation about the major or minor axis ``m`` is tiny (``~ eps^2`` for a
    transverse component ``eps``) and ``m1 = 1 - m`` rounds to 1 at the working precision as soon as
    ``m < 10**-wp``; ``mp.ellipk(m1)`` then returns ``inf`` (or, for ``m`` just above ``10**-wp``, a ``K'`` with
    few correct digits), the nome ``exp(-pi K'/K)`` becomes exactly 0 and the theta quotients divide by zero.
    Near the separatrix the same happens to ``K(m)`` with ``m1`` tiny.  The AGM of ``1`` and the small square
    root keeps full relative accuracy for any positive ``m, m1`` (it needs only ``O(log log (1/m))`` more
    iterations).
    """
    half_pi = mp.pi / 2
    return half_pi / mp.agm(1, mp.sqrt(m1)), half_pi / mp.agm(1, mp.sqrt(m))
