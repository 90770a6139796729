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

from .great_circle import sphere, sphere_pole_distance
from .inputs import CLASSIFY_DIGITS, GUARD_DIGITS, MAX_QUAD_DPS, MAX_RIGID_DPS
from .principal import RigidBodyConstants
from .rigid_body import angular_velocity, euler_poisson, euler_poisson_many, rigid_body_constants

__all__ = [
    "sphere",
    "sphere_pole_distance",
    "RigidBodyConstants",
    "rigid_body_constants",
    "euler_poisson",
    "euler_poisson_many",
    "angular_velocity",
]
