"""The free particle on the sphere ``|x| = radius`` (a great circle) and the radius of convergence of the Lie
series of its 5-dimensional chart."""

from __future__ import annotations

from ..precision import check_dps, mp_context, to_mpf
from ..precision import thread_mp as mp
from .inputs import GUARD_DIGITS, exported, loose_tolerance, time_digits, to_real, vec3
from .linalg import dot, norm


def _sphere_setup(radius, x, v, dps):
    r = to_real(radius, "radius")
    if not r > 0:
        raise ValueError(f"`radius` must be positive; got {radius!r}")
    x0 = vec3(x, "x")
    v0 = vec3(v, "v")
    tol = loose_tolerance(dps)
    nx = norm(x0)
    if abs(nx - r) > tol * r:
        raise ValueError(
            f"`x` must lie on the sphere |x| = radius = {mp.nstr(r, 15)} to relative "
            f"tolerance {mp.nstr(tol, 3)}; got |x| = {mp.nstr(nx, 15)}. Project `x` onto the sphere.")
    nv = norm(v0)
    if abs(dot(x0, v0)) > tol * r * nv:
        raise ValueError(
            f"`v` must be tangent to the sphere at `x` (x.v = 0) to relative tolerance "
            f"{mp.nstr(tol, 3)}; got x.v = {mp.nstr(dot(x0, v0), 15)}. Remove the radial "
            f"component of `v`.")
    return r, x0, v0, nv


@exported
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
    dps = check_dps(dps)
    with mp.workdps(dps + GUARD_DIGITS + time_digits([to_mpf(t, "t", ctx=mp_context())])):
        r, x0, v0, nv = _sphere_setup(radius, x, v, dps)
        tt = to_real(t, "t")
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


@exported
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
    dps = check_dps(dps)
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
