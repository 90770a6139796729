"""The free rigid body's closed forms, public: :func:`rigid_body_constants`, :func:`euler_poisson`,
:func:`euler_poisson_many`, :func:`angular_velocity`."""

from __future__ import annotations

from ..precision import thread_mp as mp
from .inputs import check_rigid_dps, exported, is_sequence, magnitude, time_digits, to_real, to_time
from .motion import RigidBody, check_psi_method


@exported
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
    dps = check_rigid_dps(dps)
    return RigidBody(inertia, omega, dps).constants()


@exported
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
    check_psi_method(psi_method)
    dps = check_rigid_dps(dps, psi_method)
    return euler_poisson_many(inertia, omega, [t], dps, psi_method)[0]


@exported
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
    check_psi_method(psi_method)
    dps = check_rigid_dps(dps, psi_method)
    if not is_sequence(ts):
        raise TypeError(f"`ts` must be a sequence of real times; got {type(ts).__name__}")
    with mp.workdps(15):
        extra = time_digits([magnitude(t) for t in ts])
    body = RigidBody(inertia, omega, dps + extra) if extra else RigidBody(inertia, omega, dps)
    out = []
    with mp.workdps(body.wp):
        raw = [body.state(to_real(t, "t"), psi_method) for t in ts]
    with mp.workdps(dps):
        for s in raw:
            out.append(tuple(+x for x in s))
    return out


@exported
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
    dps = check_rigid_dps(dps)
    with mp.workdps(15):
        tt = to_time(t, "t", allow_complex=True)
        extra = time_digits([abs(tt)])
    body = RigidBody(inertia, omega, dps + extra)
    with mp.workdps(body.wp):
        tt = to_time(t, "t", allow_complex=True)
        w = body.angular_velocity(tt)
    with mp.workdps(dps):
        return tuple(+x for x in w)
