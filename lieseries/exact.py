"""Closed-form reference solutions in mpmath, at any precision.

This module provides exact (closed-form) solutions of two model problems,
evaluated with :mod:`mpmath` at a user-chosen number of decimal digits:

* :func:`sphere` -- a free particle on the sphere ``|x| = radius`` (great
  circle motion), and :func:`sphere_pole_distance`, the radius of
  convergence of the Lie series of the 5-dimensional chart
  ``(x1, x2, x3, pi1, pi2)`` whose vector field has ``1/x3`` terms.
* :func:`euler_poisson` / :func:`euler_poisson_many` -- the free rigid body
  (Euler--Poisson equations) from ``R(0) = identity``, for an arbitrary
  positive-definite inertia tensor, in all regimes: the two elliptic branches
  ``|M|^2 > 2 E I2`` and ``|M|^2 < 2 E I2``, the separatrix, the unstable
  axis, symmetric and spherical tops and steady rotations.
  :func:`rigid_body_constants` exposes the set-up (energy, branch, elliptic
  parameter, period, distance to the nearest complex-time pole) and
  :func:`angular_velocity` evaluates ``Omega(t)`` in closed form, also at
  complex ``t``.

Rigid-body conventions (they match the rest of ``lieseries``): the state is
``R`` row-major (9 numbers) followed by the body angular momentum ``M``
(3 numbers); ``M = I Omega``, ``H = M . I^-1 M / 2``,
``dR/dt = R hat(Omega)``, ``dM/dt = M x Omega``, where ``hat(w) u = w x u``.
The lab angular momentum ``R M`` is conserved.

Precision policy: mpmath's global precision is never modified.  Every public
function works inside ``mp.workdps(dps + guard)`` (``guard`` >= 20 digits;
raised automatically near the separatrix and the intermediate axis, see
:func:`rigid_body_constants`)
and rounds its results to ``dps`` digits with unary ``+`` before returning.
Inputs may be ``int``, ``float`` (converted exactly), ``str`` (rounded at the
working precision), :class:`fractions.Fraction` (``mpf(num) / mpf(den)``),
:class:`decimal.Decimal` or ``mpf``.

Closed forms used (principal frame, moments sorted ``I1 < I2 < I3``), see
Landau & Lifshitz, *Mechanics*, section 37, and for the precession angle van
Zon & Schofield, J. Comput. Phys. 225 (2007) 145, and Celledoni, Fasso,
Safstrom & Zanna, SIAM J. Sci. Comput. 30 (2008) 2084 -- the formulas here
were re-derived from the equations of motion above and are verified against
numerical integration in ``tests/test_exact.py``.

* ``|M|^2 > 2 E I2`` ("above", ``M`` circulates around axis 3)::

      M = (a cn u, b sn u, c dn u),   u = u0 + lam t,
      a^2 = I1 (2 E I3 - |M|^2) / (I3 - I1),  b^2 = I2 (2 E I3 - |M|^2) / (I3 - I2),
      c^2 = I3 (|M|^2 - 2 E I1) / (I3 - I1),
      lam^2 = (|M|^2 - 2 E I1)(I3 - I2) / (I1 I2 I3),
      m = (2 E I3 - |M|^2)(I2 - I1) / ((|M|^2 - 2 E I1)(I3 - I2)),

  with ``a > 0``, ``sign(b) = sign(c) = sign(M3)``, and the phase
  ``u0 = F(phi0 | m)``, ``phi0 = atan2(M2(0)/b, M1(0)/a)``.
* ``|M|^2 < 2 E I2`` ("below", around axis 1): the same with the roles of
  axes 1 and 3 exchanged, ``M = (c dn u, b sn u, a cn u)``, ``a > 0``,
  ``sign(b) = sign(c) = sign(M1)``.
* separatrix: ``M = (a sech u, b tanh u, c sech u)``, ``sign(a) = sign(M1)``,
  ``sign(c) = sign(M3)``, ``sign(b) = sign(M1 M3)``, ``sinh u0 =
  (M2(0)/b) (a/M1(0))``.

The attitude is ``R(t) = A(0)^T Rz(psi(t)) A(t)``, where ``A(t)`` is the
rotation whose third row is ``n = M(t)/|M|`` built from the Euler angles of
``n`` about the reference axis ``k`` (``k = 3`` above and on the separatrix,
``k = 1`` below, via a cyclic relabelling of the axes), and
``psi' = |M| (2E - M_k^2/I_k) / (|M|^2 - M_k^2)``.  Integrated in closed
form::

    above:      psi = |M| t/I3 + |M| (I3-I1)/(I1 I3 lam) [Pi(n3; am u | m) - Pi(n3; am u0 | m)],
                n3 = -I3 (I2-I1) / (I1 (I3-I2)),
    below:      psi = |M| t/I1 - |M| (I3-I1)/(I1 I3 lam) [Pi(n1; am u | m) - Pi(n1; am u0 | m)],
                n1 = -I1 (I3-I2) / (I3 (I2-I1)),
    separatrix: psi = |M| t/I2 + |M| (I3-I2) sqrt(nu)/(I2 I3 lam)
                      [atan(sqrt(nu) tanh u) - atan(sqrt(nu) tanh u0)],  nu = -n3,

where ``am`` is continued beyond ``+-K`` by ``am(u + 2K) = am(u) + pi`` and
``Pi(n; phi + pi) = Pi(n; phi) + 2 Pi(n)``.  The characteristic is negative,
so ``Pi`` has no singularity.  The alternative ``psi_method='quad'`` integrates
``psi'`` with :func:`mpmath.quad` over whole periods of ``M`` (used to
cross-check the elliptic-integral form).

Symmetric top (``I_perp`` twice, ``I_s`` on the unit symmetry axis ``e``):
``M(t) = exp(-t Wb hat(e)) M(0)`` and ``R(t) = exp(t hat(L)/I_perp)
exp(t Wb hat(e))`` with ``Wb = M.e (1/I_s - 1/I_perp)`` and ``L = M(0)``.
Spherical top and steady rotations: ``R(t) = exp(t hat(Omega))``.

A full tensor ``I = Q diag(d) Q^T`` (``Q`` a proper rotation) is reduced to
the diagonal problem: with ``omega' = Q^T omega`` and ``R', M'`` its solution,
``R = Q R' Q^T`` and ``M = Q M'``.  Three principal moments in any order are
handled the same way with ``Q`` a signed permutation of determinant +1 (an
odd permutation is made proper by flipping the sign of one axis).
"""

from __future__ import annotations

import decimal
import fractions
import numbers
from dataclasses import dataclass
from typing import Optional

import dataclasses
import functools

from .precision import carried_bits, check_dps, dps_to_bits, export_mpf, mp_context, to_mpf, warn_if_coarse
from .precision import thread_mp as mp

__all__ = [
    "sphere",
    "sphere_pole_distance",
    "RigidBodyConstants",
    "rigid_body_constants",
    "euler_poisson",
    "euler_poisson_many",
    "angular_velocity",
]

#: Guard digits added to the requested ``dps`` for all internal work.
GUARD_DIGITS = 20

#: Relative tolerance exponent used to classify the rigid-body regime: with
#: ``dps`` requested digits, quantities below ``10**-(dps + CLASSIFY_DIGITS)``
#: (relative) are treated as exactly zero (separatrix test, equal moments of a
#: diagonalised tensor, vanishing momentum components after diagonalisation).
CLASSIFY_DIGITS = 15


# ----------------------------------------------------------------------------
# input conversion
# ----------------------------------------------------------------------------

def _fmt(x):
    """Short text for a number in an error message (integers without '.0')."""
    if hasattr(x, "_mpf_") and mp.isint(x) and abs(x) < 10 ** 15:
        return str(int(x))
    return mp.nstr(x, 15)


def _check_dps(dps):
    return check_dps(dps)


#: The most digits the rigid body's closed form is computed to: at 2000 digits one state takes ~20 s (three
#: incomplete elliptic integrals of the third kind, by Carlson's duplication, whose cost grows like dps^2.3), the
#: constants alone ~0.6 s; at 10000 digits the constants alone take minutes.
MAX_RIGID_DPS = 2000
#: The most digits with ``psi_method='quad'`` (mpmath.quad of psi' over the periods: ~25 s at 400 digits, ~450 s
#: at 1000).
MAX_QUAD_DPS = 400


def _check_rigid_dps(dps, psi_method="elliptic"):
    dps = check_dps(dps)
    limit, what = (MAX_QUAD_DPS, "with `psi_method`='quad'") if psi_method == "quad" else (MAX_RIGID_DPS, "")
    if dps > limit:
        raise ValueError(
            f"`dps` = {dps} is above {limit}, the most digits the rigid body's closed form {what}"
            f"{' ' if what else ''}computes in reasonable time (its elliptic integrals' cost grows like dps^2.3: "
            f"about 20 s for a state at 2000 digits); ask for at most {limit} digits"
            + ("" if psi_method != "quad" else " or use psi_method='elliptic'"))
    return dps


def _public(fn):
    """Results leave in mpmath's global types (their values unchanged): the work is done in this thread's private
    mpmath context, so that calls from several threads never change each other's precision."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        res = fn(*args, **kwargs)
        if dataclasses.is_dataclass(res):
            return dataclasses.replace(res, **{f.name: export_mpf(getattr(res, f.name))
                                               for f in dataclasses.fields(res)})
        return export_mpf(res)

    return wrapper


def _time_digits(ts) -> int:
    """Extra working digits that times as large as ``ts`` need: the argument reduction of the periodic and
    elliptic functions loses about log10 |t| digits."""
    big = 0
    for t in ts:
        try:
            a = abs(t)
        except TypeError:
            continue
        if hasattr(a, "_mpf_") or isinstance(a, (int, float, fractions.Fraction)):
            if a > 1:
                big = max(big, int(mp.log10(a)) + 1 if hasattr(a, "_mpf_") else len(str(int(a))))
    return big


def _magnitude(t):
    """|t| for sizing the working precision, or 0 for input that the real conversion will refuse by name."""
    try:
        return abs(_to_time(t, "t", allow_complex=True))
    except (TypeError, ValueError):
        return 0


def _to_mpf(x, name):
    """Convert one real scalar exactly (at the current working precision); a binary float that carries fewer bits
    than the digits asked for (the double 0.1 in a 40-digit closed form) gives one PrecisionWarning naming it."""
    if isinstance(x, bool):
        raise TypeError(f"`{name}` must contain real numbers, not booleans; got {x!r}")
    if isinstance(x, numbers.Real) and not isinstance(x, (numbers.Rational, decimal.Decimal)) or hasattr(x, "_mpf_"):
        # the caller works GUARD_DIGITS above the digits asked for
        warn_if_coarse(carried_bits(x), mp_context().prec - dps_to_bits(GUARD_DIGITS), name, stacklevel=5)
    if isinstance(x, (str, float, decimal.Decimal, fractions.Fraction, numbers.Integral)) or hasattr(x, "_mpf_"):
        return to_mpf(x, name, ctx=mp_context())
    if isinstance(x, numbers.Rational):
        return mp.mpf(int(x.numerator)) / mp.mpf(int(x.denominator))
    if isinstance(x, numbers.Real):  # numpy float32 and the like: their exact binary value
        return to_mpf(float(x), name, ctx=mp_context())
    raise TypeError(
        f"`{name}` must be a real number (int, float, str, Fraction, Decimal or mpf); "
        f"got {type(x).__name__} {x!r}")


def _to_time(t, name, allow_complex=False):
    if allow_complex and (isinstance(t, complex) or hasattr(t, "_mpc_")) and not isinstance(t, bool):
        z = mp.mpc(t)
        if not (mp.isfinite(z.real) and mp.isfinite(z.imag)):
            raise ValueError(f"`{name}` must be finite; got {t!r}")
        return z
    return _to_mpf(t, name)


def _is_sequence(x):
    if isinstance(x, (str, bytes)):
        return False
    try:
        len(x)
        iter(x)
    except TypeError:
        return False
    return True


def _vec3(v, name):
    if not _is_sequence(v):
        raise TypeError(f"`{name}` must be a sequence of 3 real numbers; got {type(v).__name__}")
    if len(v) != 3:
        raise ValueError(f"`{name}` must have 3 components; got {len(v)}")
    return [_to_mpf(c, name) for c in v]


# ----------------------------------------------------------------------------
# small linear algebra on lists of mpf
# ----------------------------------------------------------------------------

def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(a):
    return mp.sqrt(_dot(a, a))


def _matvec(A, v):
    return [A[i][0] * v[0] + A[i][1] * v[1] + A[i][2] * v[2] for i in range(3)]


def _matmul(A, B):
    return [[A[i][0] * B[0][j] + A[i][1] * B[1][j] + A[i][2] * B[2][j] for j in range(3)]
            for i in range(3)]


def _transpose(A):
    return [[A[j][i] for j in range(3)] for i in range(3)]


def _identity():
    return [[mp.mpf(1) if i == j else mp.mpf(0) for j in range(3)] for i in range(3)]


def _axis_rotation(axis, angle):
    """exp(angle hat(axis)) for a unit vector ``axis`` (Rodrigues)."""
    x, y, z = axis
    c = mp.cos(angle)
    s = mp.sin(angle)
    C = 2 * mp.sin(angle / 2) ** 2  # 1 - cos, without cancellation
    return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]


def _expm_hat(w, t):
    """exp(t hat(w)) for any vector ``w``."""
    nw = _norm(w)
    if nw == 0:
        return _identity()
    return _axis_rotation([wi / nw for wi in w], nw * t)


def _rz(angle):
    c = mp.cos(angle)
    s = mp.sin(angle)
    z = mp.mpf(0)
    return [[c, -s, z], [s, c, z], [z, z, mp.mpf(1)]]


def _det3(A):
    return (A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1])
            - A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0])
            + A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0]))


# ----------------------------------------------------------------------------
# sphere
# ----------------------------------------------------------------------------

def _sphere_tolerance(dps):
    return max(mp.mpf(10) ** -12, mp.mpf(10) ** (-mp.mpf(dps) / 2))


def _sphere_setup(radius, x, v, dps):
    r = _to_mpf(radius, "radius")
    if not r > 0:
        raise ValueError(f"`radius` must be positive; got {radius!r}")
    x0 = _vec3(x, "x")
    v0 = _vec3(v, "v")
    tol = _sphere_tolerance(dps)
    nx = _norm(x0)
    if abs(nx - r) > tol * r:
        raise ValueError(
            f"`x` must lie on the sphere |x| = radius = {mp.nstr(r, 15)} to relative "
            f"tolerance {mp.nstr(tol, 3)}; got |x| = {mp.nstr(nx, 15)}. Project `x` onto the sphere.")
    nv = _norm(v0)
    if abs(_dot(x0, v0)) > tol * r * nv:
        raise ValueError(
            f"`v` must be tangent to the sphere at `x` (x.v = 0) to relative tolerance "
            f"{mp.nstr(tol, 3)}; got x.v = {mp.nstr(_dot(x0, v0), 15)}. Remove the radial "
            f"component of `v`.")
    return r, x0, v0, nv


@_public
def sphere(radius, x, v, t, dps=30):
    """Free motion on the sphere ``|x| = radius``: a great circle.

    Parameters
    ----------
    radius : real
        Radius of the sphere, positive.
    x : sequence of 3 reals
        Initial position, on the sphere.
    v : sequence of 3 reals
        Initial velocity, tangent to the sphere at `x`.
    t : real
        Time (may be negative).
    dps : int, optional
        Decimal digits of the result (default 30).

    Returns
    -------
    x_t, v_t : tuple of 3 mpf each
        Position and velocity at time `t`::

            x(t) = x0 cos(w t) + (v0/w) sin(w t),
            v(t) = -x0 w sin(w t) + v0 cos(w t),     w = |v0| / radius.

        For ``v0 = 0`` the particle stays at rest.

    Raises
    ------
    ValueError
        If ``|x|`` differs from `radius`, or ``x.v`` from 0, by more than the
        relative tolerance ``max(1e-12, 10**(-dps/2))`` (relative to `radius`
        and to ``radius |v|`` respectively), or if a vector has the wrong length.
    TypeError
        If an input is not a real number.

    Notes
    -----
    The inputs are used as given (not projected onto the sphere); within the
    tolerance the formula is still the exact solution of ``x'' = -w^2 x``.
    """
    dps = _check_dps(dps)
    with mp.workdps(dps + GUARD_DIGITS + _time_digits([to_mpf(t, "t", ctx=mp_context())])):
        r, x0, v0, nv = _sphere_setup(radius, x, v, dps)
        tt = _to_mpf(t, "t")
        if nv == 0:
            xt, vt = list(x0), [mp.mpf(0)] * 3
        else:
            w = nv / r
            c = mp.cos(w * tt)
            s = mp.sin(w * tt)
            xt = [x0[i] * c + v0[i] / w * s for i in range(3)]
            vt = [-x0[i] * w * s + v0[i] * c for i in range(3)]
    with mp.workdps(dps):
        return tuple(+a for a in xt), tuple(+a for a in vt)


@_public
def sphere_pole_distance(radius, x, v, axis=2, dps=30):
    """Distance in complex time to the chart boundary ``x[axis] = 0``.

    In the intermediate coordinates ``(x1, x2, x3, pi1, pi2)`` the vector field
    of the particle on the sphere contains ``1/x3``; its Lie (Taylor) series
    about ``t0 = 0`` therefore converges in the disc ``|t| < rho`` where
    ``rho`` is the distance to the nearest complex zero of ``x3(t)``.

    Parameters
    ----------
    radius, x, v : see :func:`sphere`
    axis : {0, 1, 2}, optional
        Coordinate whose vanishing ends the chart (default 2, i.e. ``x3``).
    dps : int, optional
        Decimal digits of the result.

    Returns
    -------
    mpf
        ``rho``; ``mp.inf`` if ``x[axis]`` never vanishes (particle at rest
        off the boundary), ``0`` if it vanishes at ``t = 0``.

    Notes
    -----
    Along the great circle ``x3(t) = a cos(w t) + b sin(w t) = A cos(w (t - t*))``
    with ``a = x3(0)``, ``b = v3(0)/w``, ``A = sqrt(a^2 + b^2)``, ``w = |v|/radius``.
    ``cos`` has only real zeros, so the complex zeros of ``x3`` are the real
    times ``t* + (k + 1/2) pi / w``; the nearest one is at distance
    ``asin(|a| / A) / w`` (the phase ``w t*`` reduced to ``[-pi/2, pi/2]``
    has ``cos = |a|/A``).  If ``A = 0`` (the orbit lies in the plane
    ``x3 = 0``) the distance is 0.
    """
    dps = _check_dps(dps)
    if axis not in (0, 1, 2) or isinstance(axis, bool):
        raise ValueError(f"`axis` must be 0, 1 or 2; got {axis!r}")
    with mp.workdps(dps + GUARD_DIGITS):
        r, x0, v0, nv = _sphere_setup(radius, x, v, dps)
        a = x0[axis]
        if a == 0:
            res = mp.mpf(0)
        elif nv == 0:
            res = mp.inf
        else:
            w = nv / r
            b = v0[axis] / w
            A = mp.sqrt(a * a + b * b)
            res = mp.asin(min(abs(a) / A, mp.mpf(1))) / w
    with mp.workdps(dps):
        return +res


# ----------------------------------------------------------------------------
# rigid body: constants
# ----------------------------------------------------------------------------

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


# ----------------------------------------------------------------------------
# rigid body: solver
# ----------------------------------------------------------------------------

def _parse_inertia(inertia, dps):
    """Return ``(d, Q, exact)``: sorted moments, proper rotation with I = Q diag(d) Q^T.

    ``exact`` is True when ``Q`` is a signed permutation (no diagonalisation
    round-off).
    """
    if not _is_sequence(inertia):
        raise TypeError(
            "`inertia` must be three principal moments or a symmetric 3x3 matrix; "
            f"got {type(inertia).__name__}")
    if len(inertia) != 3:
        raise ValueError(
            "`inertia` must be three principal moments or a symmetric 3x3 matrix; "
            f"got a sequence of length {len(inertia)}")
    rows = list(inertia)
    nested = [_is_sequence(r) for r in rows]
    if all(nested):
        for r in rows:
            if len(r) != 3:
                raise ValueError(f"`inertia` as a matrix must be 3x3; got a row of length {len(r)}")
        A = [[_to_mpf(c, "inertia") for c in r] for r in rows]
        scale = max(abs(A[i][j]) for i in range(3) for j in range(3))
        if scale == 0:
            raise ValueError("`inertia` must be positive definite; got the zero matrix")
        asym = max(abs(A[i][j] - A[j][i]) for i in range(3) for j in range(3))
        tol = _sphere_tolerance(dps)
        if asym > tol * scale:
            raise ValueError(
                f"`inertia` must be symmetric (to relative tolerance {mp.nstr(tol, 3)}); got "
                f"max |I_ij - I_ji| = {mp.nstr(asym, 5)}. Pass a symmetric matrix.")
        A = [[(A[i][j] + A[j][i]) / 2 for j in range(3)] for i in range(3)]
        if A[0][1] == 0 and A[0][2] == 0 and A[1][2] == 0:
            return _sort_moments([A[0][0], A[1][1], A[2][2]])
        evals, evecs = mp.eigsy(mp.matrix(A))
        ev = [evals[i] for i in range(3)]
        if not min(ev) > 0:
            raise ValueError(
                "`inertia` must be positive definite; got eigenvalues "
                f"({', '.join(mp.nstr(e, 8) for e in ev)})")
        order = sorted(range(3), key=lambda i: ev[i])
        d = [ev[i] for i in order]
        Q = [[evecs[r, order[c]] for c in range(3)] for r in range(3)]
        if _det3(Q) < 0:
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
    moments = [_to_mpf(c, "inertia") for c in rows]
    return _sort_moments(moments)


def _sort_moments(moments):
    if not all(mi > 0 for mi in moments):
        raise ValueError(
            f"`inertia` must have three positive moments; got "
            f"({', '.join(_fmt(mi) for mi in moments)})")
    order = sorted(range(3), key=lambda i: moments[i])  # stable
    d = [moments[i] for i in order]
    # column c of Q is the user axis e_{order[c]}
    Q = [[mp.mpf(1) if r == order[c] else mp.mpf(0) for c in range(3)] for r in range(3)]
    if _det3(Q) < 0:  # odd permutation: flip the middle axis to stay right-handed
        for r in range(3):
            Q[r][1] = -Q[r][1]
    return d, Q, True


def _complete_k(m, m1):
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


class _RigidBody:
    """Set-up of the closed-form solution; methods must run at ``self.wp``."""

    def __init__(self, inertia, omega, dps):
        self.dps = dps
        wp = dps + GUARD_DIGITS
        with mp.workdps(wp):
            self._setup(inertia, omega, wp, elliptic=False)
        if self.branch not in ("above", "below"):
            return
        # Near the separatrix (close to a rotation about the intermediate axis) the relative accuracy of 1 - m
        # is limited by the cancellation in |M|^2 - 2 E I2: add the digits lost and redo.  This is decided
        # before any elliptic function is evaluated: at the first precision 1 - m may round to 0 (then
        # F(pi/2 | m) and K(m) are infinite).
        with mp.workdps(wp):
            r = abs(self.gap) / self.M2
            lost = int(mp.ceil(-mp.log10(r))) if r < 1 else 0
        if lost > 5:
            wp += lost
            with mp.workdps(wp):
                self._setup(inertia, omega, wp)
        else:
            with mp.workdps(wp):
                self._setup_elliptic()

    # -- set-up ---------------------------------------------------------------
    def _setup(self, inertia, omega, wp, elliptic=True):
        """Invariants and regime at ``wp`` digits; with ``elliptic=False`` the elliptic branches stop after the
        classification (``__init__`` first chooses their working precision)."""
        self.wp = wp
        dps = self.dps
        d, Q, exact = _parse_inertia(inertia, dps)
        om = _vec3(omega, "omega")
        self.d = d
        self.Q = Q
        self.QT = _transpose(Q)
        I1, I2, I3 = d
        Om = _matvec(self.QT, om)  # body angular velocity in the principal frame
        M = [d[i] * Om[i] for i in range(3)]
        if not exact:
            # components that are round-off of the diagonalisation
            nM = _norm(M)
            eps = mp.mpf(10) ** -(dps + CLASSIFY_DIGITS) * nM
            M = [mi if abs(mi) > eps else mp.mpf(0) for mi in M]
            Om = [M[i] / d[i] for i in range(3)]
        self.M0 = M
        self.Om0 = Om
        self.M2 = _dot(M, M)
        self.L = mp.sqrt(self.M2)
        self.E = (M[0] ** 2 / I1 + M[1] ** 2 / I2 + M[2] ** 2 / I3) / 2
        self.gap = (M[2] ** 2 * (I3 - I2) / I3 - M[0] ** 2 * (I2 - I1) / I1)
        self.m = self.lam = self.u0 = self.K = self.Kp = None
        self.period = None
        self.pole_distance = mp.inf
        self.pole_time = None

        nzero = sum(1 for mi in M if mi == 0)
        if I1 == I3:
            self.branch = "spherical"
            self.gap = mp.mpf(0)
        elif nzero >= 2 or (I1 == I2 and (M[2] == 0 or (M[0] == 0 and M[1] == 0))) \
                or (I2 == I3 and (M[0] == 0 or (M[1] == 0 and M[2] == 0))):
            self.branch = "steady"
        elif I1 == I2 or I2 == I3:
            self.branch = "symmetric"
            self.gap = mp.mpf(0)
            self._setup_symmetric()
        else:
            tol = mp.mpf(10) ** -(dps + CLASSIFY_DIGITS)
            # The separatrix formulas match M1(0), M2(0) and put M3 on the separatrix: declare it only when that
            # moves M3 by at most tol |M| (d gap / d M3 = 2 M3 (I3 - I2) / I3).  A bound relative to |M|^2
            # alone would, near the intermediate axis (M1, M3 ~ eps), replace M3 by a value off by O(eps).
            if M[0] != 0 and M[2] != 0 and \
                    abs(self.gap) <= 2 * tol * self.L * abs(M[2]) * (I3 - I2) / I3:
                self.branch = "separatrix"
                self._setup_separatrix()
            else:
                self.branch = "above" if self.gap > 0 else "below"
                if elliptic:
                    self._setup_elliptic()

    def _setup_symmetric(self):
        d = self.d
        if d[0] == d[1]:
            s, Iperp, Is = 2, d[0], d[2]
        else:
            s, Iperp, Is = 0, d[1], d[0]
        self.sym_axis = s
        self.Iperp = Iperp
        e = [mp.mpf(0)] * 3
        e[s] = mp.mpf(1)
        self.sym_e = e
        self.Wb = self.M0[s] * (1 / Is - 1 / Iperp)
        self.lam = abs(self.Wb)
        self.period = 2 * mp.pi / abs(self.Wb)

    def _setup_elliptic(self):
        I1, I2, I3 = self.d
        M1, M2, M3 = self.M0
        # 2 E I3 - |M|^2 and |M|^2 - 2 E I1 as sums of positive terms
        P31 = M1 ** 2 * (I3 - I1) / I1 + M2 ** 2 * (I3 - I2) / I2
        P13 = M2 ** 2 * (I2 - I1) / I2 + M3 ** 2 * (I3 - I1) / I3
        self.P31, self.P13 = P31, P13
        if self.branch == "above":
            s = mp.sign(M3)
            a = mp.sqrt(I1 * P31 / (I3 - I1))          # amplitude of cn (M1)
            b = s * mp.sqrt(I2 * P31 / (I3 - I2))      # amplitude of sn (M2)
            c = s * mp.sqrt(I3 * P13 / (I3 - I1))      # amplitude of dn (M3)
            lam = mp.sqrt(P13 * (I3 - I2) / (I1 * I2 * I3))
            m = P31 * (I2 - I1) / (P13 * (I3 - I2))
            m1 = (I3 - I1) * self.gap / (P13 * (I3 - I2))
            phi0 = mp.atan2(M2 / b, M1 / a)
            self.nchar = -I3 * (I2 - I1) / (I1 * (I3 - I2))
            self.psi_rate = self.L / I3
            self.psi_coef = self.L * (I3 - I1) / (I1 * I3 * lam)
            self.ref_axis = 2
        else:
            s = mp.sign(M1)
            a = mp.sqrt(I3 * P13 / (I3 - I1))          # amplitude of cn (M3)
            b = s * mp.sqrt(I2 * P13 / (I2 - I1))      # amplitude of sn (M2)
            c = s * mp.sqrt(I1 * P31 / (I3 - I1))      # amplitude of dn (M1)
            lam = mp.sqrt(P31 * (I2 - I1) / (I1 * I2 * I3))
            m = P13 * (I3 - I2) / (P31 * (I2 - I1))
            m1 = -(I3 - I1) * self.gap / (P31 * (I2 - I1))
            phi0 = mp.atan2(M2 / b, M3 / a)
            self.nchar = -I1 * (I3 - I2) / (I3 * (I2 - I1))
            self.psi_rate = self.L / I1
            self.psi_coef = -self.L * (I3 - I1) / (I1 * I3 * lam)
            self.ref_axis = 0
        self.amp = (a, b, c)
        self.lam = lam
        self.m = m
        self.m1 = m1
        K, Kp = _complete_k(m, m1)
        self.K, self.Kp = K, Kp
        # nome: ~ m/16 near a stable axis (tiny but never 0: mpf exponents do not underflow)
        q = mp.exp(-mp.pi * Kp / K)
        self.q = q
        self.th2 = mp.jtheta(2, 0, q)
        self.th3 = mp.jtheta(3, 0, q)
        self.th4 = mp.jtheta(4, 0, q)
        # phase u0 = F(phi0 | m), phi0 in (-pi, pi]
        if phi0 > mp.pi / 2:
            u0 = 2 * K + mp.ellipf(phi0 - mp.pi, m)
        elif phi0 < -mp.pi / 2:
            u0 = -2 * K + mp.ellipf(phi0 + mp.pi, m)
        else:
            u0 = mp.ellipf(phi0, m)
        self.u0 = u0
        # Pi(n | m) and Pi(n; am(u0) | m) are computed on first use (only the precession angle needs them; the
        # incomplete elliptic integrals of the third kind are the costliest part at high precision)
        self._Pi_complete = self._Pi0 = None
        self.period = 4 * K / lam
        jn = mp.nint(u0 / (2 * K))
        dist = u0 - 2 * K * jn
        self.pole_distance = mp.sqrt(dist ** 2 + Kp ** 2) / lam
        self.pole_time = mp.mpc(2 * K * jn - u0, Kp) / lam
        self.A0 = self._attitude_frame(self.M0)

    def _setup_separatrix(self):
        I1, I2, I3 = self.d
        M1, M2, M3 = self.M0
        P31 = M1 ** 2 * (I3 - I1) / I1 + M2 ** 2 * (I3 - I2) / I2
        P13 = M2 ** 2 * (I2 - I1) / I2 + M3 ** 2 * (I3 - I1) / I3
        s1, s3 = mp.sign(M1), mp.sign(M3)
        a = s1 * mp.sqrt(I1 * P31 / (I3 - I1))         # sech amplitude of M1
        b = s1 * s3 * mp.sqrt(I2 * P31 / (I3 - I2))    # tanh amplitude of M2
        c = s3 * mp.sqrt(I3 * P13 / (I3 - I1))         # sech amplitude of M3
        lam = mp.sqrt(P13 * (I3 - I2) / (I1 * I2 * I3))
        self.amp = (a, b, c)
        self.lam = lam
        self.m = mp.mpf(1)
        self.m1 = mp.mpf(0)
        self.u0 = mp.asinh((M2 / b) * (a / M1))
        self.nu = I3 * (I2 - I1) / (I1 * (I3 - I2))
        self.sqnu = mp.sqrt(self.nu)
        self.psi_rate = self.L / I2
        self.psi_coef = self.L * (I3 - I2) * self.sqnu / (I2 * I3 * lam)
        self.atan0 = mp.atan(self.sqnu * mp.tanh(self.u0))
        self.ref_axis = 2
        self.pole_distance = mp.sqrt(self.u0 ** 2 + mp.pi ** 2 / 4) / lam
        self.pole_time = mp.mpc(-self.u0, mp.pi / 2) / lam
        self.A0 = self._attitude_frame(self.M0)

    # -- elliptic functions ---------------------------------------------------
    def _sncndn(self, u):
        """Jacobi (sn, cn, dn) of ``u`` (real or complex) and the amplitude data.

        Returns ``(sn(u), cn(u), dn(u), j, ur)`` with ``u = 2 j K + ur`` and
        ``Re(ur)`` in ``[-K, K]``; evaluated through theta functions with the
        nome, ``K`` and the theta constants computed once in the set-up.
        """
        K = self.K
        j = mp.nint(mp.re(u) / (2 * K))
        ur = u - 2 * K * j
        z = ur / self.th3 ** 2
        q = self.q
        t1 = mp.jtheta(1, z, q)
        t2 = mp.jtheta(2, z, q)
        t3 = mp.jtheta(3, z, q)
        t4 = mp.jtheta(4, z, q)
        sgn = -1 if int(j) % 2 else 1  # sn, cn are 2K-antiperiodic, dn 2K-periodic
        sn = sgn * (self.th3 / self.th2) * t1 / t4
        cn = sgn * (self.th4 / self.th2) * t2 / t4
        dn = (self.th4 / self.th3) * t3 / t4
        return sn, cn, dn, j, ur

    def _Pi_am(self, u):
        """Pi(n; am(u) | m) for real u, continued through am(u + 2K) = am(u) + pi."""
        sn, cn, dn, j, ur = self._sncndn(u)
        sgn = -1 if int(j) % 2 else 1
        phi = mp.atan2(sgn * sn, sgn * cn)  # am(ur) in [-pi/2, pi/2]
        if j == 0:
            return mp.ellippi(self.nchar, phi, self.m)
        if self._Pi_complete is None:
            self._Pi_complete = mp.ellippi(self.nchar, self.m)
        return 2 * j * self._Pi_complete + mp.ellippi(self.nchar, phi, self.m)

    # -- momentum -------------------------------------------------------------
    def momentum(self, t):
        """Principal-frame M(t); ``t`` may be complex."""
        br = self.branch
        if br in ("above", "below"):
            a, b, c = self.amp
            sn, cn, dn, _, _ = self._sncndn(self.u0 + self.lam * t)
            if br == "above":
                return [a * cn, b * sn, c * dn]
            return [c * dn, b * sn, a * cn]
        if br == "separatrix":
            a, b, c = self.amp
            u = self.u0 + self.lam * t
            sech = mp.sech(u)
            return [a * sech, b * mp.tanh(u), c * sech]
        if br == "symmetric":
            return _matvec(_axis_rotation(self.sym_e, -self.Wb * t), self.M0)
        return list(self.M0)

    # -- attitude -------------------------------------------------------------
    def _attitude_frame(self, M):
        """Rotation A with third row M/|M| (Euler angles about the reference axis)."""
        L = self.L
        n = [mi / L for mi in M]
        if self.ref_axis == 0:
            n = [n[1], n[2], n[0]]  # cyclic relabelling (2, 3, 1) -> (x, y, z)
        n1, n2, n3 = n
        rho = mp.sqrt(n1 ** 2 + n2 ** 2)
        A = [[n2 / rho, -n1 / rho, mp.mpf(0)],
             [n3 * n1 / rho, n3 * n2 / rho, -rho],
             [n1, n2, n3]]
        if self.ref_axis == 0:
            # A = A0(P n) P with (P v) = (v2, v3, v1): column j of A is column j-1 of A0
            A = [[row[2], row[0], row[1]] for row in A]
        return A

    def _psi_elliptic(self, t):
        if self.branch == "separatrix":
            u = self.u0 + self.lam * t
            return self.psi_rate * t + self.psi_coef * (
                mp.atan(self.sqnu * mp.tanh(u)) - self.atan0)
        u = self.u0 + self.lam * t
        if self._Pi0 is None:
            self._Pi0 = self._Pi_am(self.u0)
        return self.psi_rate * t + self.psi_coef * (self._Pi_am(u) - self._Pi0)

    def _psi_dot(self, s):
        M = self.momentum(s)
        I = self.d
        i, j = (0, 1) if self.ref_axis == 2 else (1, 2)
        return self.L * (M[i] ** 2 / I[i] + M[j] ** 2 / I[j]) / (M[i] ** 2 + M[j] ** 2)

    def _psi_quad(self, t):
        f = self._psi_dot
        if t == 0:
            return mp.mpf(0)
        if self.branch == "separatrix":
            npieces = int(mp.ceil(abs(t) * self.lam)) + 1
            pts = [t * k / npieces for k in range(npieces + 1)]
            return mp.quad(f, pts)
        # psi' has period P = 2K/lam: whole periods plus a remainder
        P = 2 * self.K / self.lam
        nper = mp.floor(t / P)
        rem = t - nper * P
        total = mp.mpf(0)
        if nper != 0:
            if not hasattr(self, "_psi_period"):
                self._psi_period = mp.quad(f, [0, P / 4, P / 2, 3 * P / 4, P])
            total = nper * self._psi_period
        if rem != 0:
            npieces = int(mp.ceil(4 * rem / P))
            pts = [rem * k / npieces for k in range(npieces + 1)]
            total += mp.quad(f, pts)
        return total

    def principal_state(self, t, psi_method="elliptic"):
        """(R', M') in the principal frame at real time ``t``."""
        br = self.branch
        if br == "spherical":
            return _expm_hat([mi / self.d[0] for mi in self.M0], t), list(self.M0)
        if br == "steady":
            return _expm_hat(self.Om0, t), list(self.M0)
        if br == "symmetric":
            R = _matmul(_expm_hat([mi / self.Iperp for mi in self.M0], t),
                        _axis_rotation(self.sym_e, self.Wb * t))
            return R, self.momentum(t)
        M = self.momentum(t)
        if psi_method == "elliptic":
            psi = self._psi_elliptic(t)
        else:
            psi = self._psi_quad(t)
        A = self._attitude_frame(M)
        R = _matmul(_matmul(_transpose(self.A0), _rz(psi)), A)
        return R, M

    def state(self, t, psi_method="elliptic"):
        Rp, Mp = self.principal_state(t, psi_method)
        R = _matmul(_matmul(self.Q, Rp), self.QT)
        M = _matvec(self.Q, Mp)
        return [R[i][j] for i in range(3) for j in range(3)] + M

    def angular_velocity(self, t):
        Mp = self.momentum(t)
        return _matvec(self.Q, [Mp[i] / self.d[i] for i in range(3)])

    def constants(self):
        with mp.workdps(self.dps):
            opt = lambda x: None if x is None else +x  # noqa: E731
            return RigidBodyConstants(
                energy=+self.E,
                momentum_squared=+self.M2,
                branch=self.branch,
                moments=tuple(+x for x in self.d),
                frame=tuple(tuple(+x for x in row) for row in self.Q),
                separatrix_gap=+self.gap,
                m=opt(self.m),
                lam=opt(self.lam),
                u0=opt(self.u0),
                K=opt(self.K),
                Kp=opt(self.Kp),
                period=opt(self.period),
                pole_distance=+self.pole_distance,
                pole_time=opt(self.pole_time),
                working_dps=self.wp,
            )


def _check_psi_method(psi_method):
    if psi_method not in ("elliptic", "quad"):
        raise ValueError(f"`psi_method` must be 'elliptic' or 'quad'; got {psi_method!r}")


# ----------------------------------------------------------------------------
# rigid body: public API
# ----------------------------------------------------------------------------

@_public
def rigid_body_constants(inertia, omega, dps=30):
    """Invariants, regime and singularity data of the free rigid body.

    Parameters
    ----------
    inertia : sequence of 3 reals, or 3x3 nested sequence
        Principal moments in any order, or the full symmetric positive-definite
        inertia tensor.
    omega : sequence of 3 reals
        Initial body angular velocity ``Omega(0)``.
    dps : int, optional
        Decimal digits of the returned numbers (default 30; at most ``MAX_RIGID_DPS`` = 2000).

    Returns
    -------
    RigidBodyConstants
        See the class documentation for the fields.

    Notes
    -----
    A full tensor must be symmetric to the relative tolerance
    ``max(1e-12, 10**(-dps/2))`` (it is then symmetrised) and is diagonalised
    with :func:`mpmath.eigsy`; a tensor with zero off-diagonal entries is
    treated exactly like three moments.

    Regime classification (with ``tol = 10**-(dps + 15)``): the moments of a
    diagonalised full tensor closer than ``tol`` relative are merged, and the
    principal-frame components of ``M`` smaller than ``tol |M|`` are set to
    zero (they are round-off of the diagonalisation; principal moments given
    directly are used exactly).  The separatrix is declared when
    ``M1, M3 != 0`` and putting ``M`` exactly on it moves ``M3`` by at most
    ``tol |M|``, i.e. ``| |M|^2 - 2 E I2 | <= 2 tol |M| |M3| (I3 - I2) / I3``;
    the separatrix formulas (which match ``M1(0)`` and ``M2(0)``) then give the
    exact motion of that input, within ``tol |M|`` of the one given.  Otherwise
    the elliptic branches are used, with the working precision raised by the
    number of digits lost in ``|M|^2 - 2 E I2`` (about
    ``log10(|M|^2 / | |M|^2 - 2 E I2 |)``) so that ``1 - m`` keeps full
    relative accuracy.

    Near the steady rotations:

    * about the minor or major axis (stable; ``Omega = (1, 0, eps)`` and the
      like): ``m`` is of order ``eps^2`` and may be far below the working
      precision; ``K`` and ``K'`` are computed by the AGM from ``m`` and
      ``1 - m`` separately, the nome ``~ m/16`` stays positive, and the
      result keeps ``dps`` digits with no extra precision (the small
      components of ``M`` even to ``dps`` digits relative to ``eps``; those
      of ``R`` are sums of products of O(1) numbers, guaranteed to about
      ``10**-(dps + 20)`` absolute).  Only ``Omega`` exactly along the axis
      is ``'steady'``.
    * about the intermediate axis (unstable): every nearby motion is close to
      the separatrix.  Exactly on it (to the tolerance above) the separatrix
      formulas are used; off it the elliptic formulas at the raised precision
      (``working_dps`` grows like ``log10(|M|^2 / gap)``, ``K`` like
      ``ln(1 / gap)``, and the theta series take longer as the nome nears 1).
      The result is the exact motion of the input as given, but the motion
      itself is ill-conditioned: input errors grow like ``exp(lam |t|)``
      while it stays near the axis.
    """
    dps = _check_rigid_dps(dps)
    return _RigidBody(inertia, omega, dps).constants()


@_public
def euler_poisson(inertia, omega, t, dps=30, psi_method="elliptic"):
    """Closed-form state of the free rigid body at time `t`, from ``R(0) = 1``.

    Parameters
    ----------
    inertia : sequence of 3 reals, or 3x3 nested sequence
        Principal moments in any order (not necessarily sorted), or the full
        symmetric positive-definite inertia tensor in the body frame.
    omega : sequence of 3 reals
        Initial body angular velocity ``Omega(0)``.
    t : real
        Time (may be negative).
    dps : int, optional
        Decimal digits of the result (default 30; at most ``MAX_RIGID_DPS`` = 2000, ``MAX_QUAD_DPS`` = 400
        with ``psi_method='quad'``: the elliptic integrals' cost grows like dps^2.3).
    psi_method : {'elliptic', 'quad'}, optional
        How the precession angle is computed on the elliptic and separatrix
        branches: closed form with the incomplete elliptic integral of the
        third kind (default), or :func:`mpmath.quad` of ``psi'`` over whole
        periods of ``M``.  Ignored for the other regimes.

    Returns
    -------
    tuple of 12 mpf
        ``R(t)`` row-major followed by the body angular momentum ``M(t)``.

    Raises
    ------
    ValueError, TypeError
        For malformed input; the message names the offending argument.

    Notes
    -----
    Accuracy: all work is done with at least ``dps + 20`` digits, so the
    result is correct to about ``dps`` digits for moderate ``|t|`` (the
    argument reduction of the trigonometric and theta functions costs about
    ``log10 |t|`` digits).  Inputs are taken as exact; this holds arbitrarily
    close to (and at) steady rotations about the minor and major axes.  Near
    the separatrix (and the unstable intermediate axis) the motion itself is
    ill-conditioned and the result is the exact motion of the input as
    given, computed with extra digits.  See :func:`rigid_body_constants` for
    the classification tolerances and the regimes near the axes.

    See Also
    --------
    euler_poisson_many : several times with one set-up.
    rigid_body_constants : regime, period and pole distance.
    """
    _check_psi_method(psi_method)
    dps = _check_rigid_dps(dps, psi_method)
    return euler_poisson_many(inertia, omega, [t], dps, psi_method)[0]


@_public
def euler_poisson_many(inertia, omega, ts, dps=30, psi_method="elliptic"):
    """Closed-form states of the free rigid body at several times.

    The set-up (diagonalisation, invariants, elliptic parameter, periods,
    phase, complete integrals) is done once and reused for every time.

    Parameters
    ----------
    inertia, omega, dps, psi_method
        As in :func:`euler_poisson`.
    ts : sequence of reals
        Times.

    Returns
    -------
    list of tuple of 12 mpf
        One state (``R`` row-major, then ``M``) per time.
    """
    _check_psi_method(psi_method)
    dps = _check_rigid_dps(dps, psi_method)
    if not _is_sequence(ts):
        raise TypeError(f"`ts` must be a sequence of real times; got {type(ts).__name__}")
    with mp.workdps(15):
        extra = _time_digits([_magnitude(t) for t in ts])
    body = _RigidBody(inertia, omega, dps + extra) if extra else _RigidBody(inertia, omega, dps)
    out = []
    with mp.workdps(body.wp):
        raw = [body.state(_to_mpf(t, "t"), psi_method) for t in ts]
    with mp.workdps(dps):
        for s in raw:
            out.append(tuple(+x for x in s))
    return out


@_public
def angular_velocity(inertia, omega, t, dps=30):
    """Body angular velocity ``Omega(t)`` in closed form, for real or complex `t`.

    Parameters
    ----------
    inertia, omega, dps
        As in :func:`euler_poisson`.
    t : real or complex
        Time; complex values give the analytic continuation (used to locate
        the poles reported by :func:`rigid_body_constants`).

    Returns
    -------
    tuple of 3 mpf or mpc
        ``Omega(t)`` in the user's body frame.
    """
    dps = _check_rigid_dps(dps)
    with mp.workdps(15):
        tt = _to_time(t, "t", allow_complex=True)
        extra = _time_digits([abs(tt)])
    body = _RigidBody(inertia, omega, dps + extra)
    with mp.workdps(body.wp):
        tt = _to_time(t, "t", allow_complex=True)
        w = body.angular_velocity(tt)
    with mp.workdps(dps):
        return tuple(+x for x in w)
