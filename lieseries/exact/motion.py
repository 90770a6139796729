"""The free rigid body's motion in closed form (:class:`RigidBody`): Jacobi elliptic functions for the momentum,
the attitude from the precession angle (elliptic integrals of the third kind, or a quadrature)."""

from __future__ import annotations

from ..precision import thread_mp as mp
from .linalg import axis_rotation, expm_hat, matmul, matvec, rz, transpose
from .regimes import RigidBodySetup


class RigidBody(RigidBodySetup):
    """The closed-form solution: momentum, attitude and angular velocity at any time (set up by
    :class:`~lieseries.exact.regimes.RigidBodySetup`); methods must run at ``self.wp``."""

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
        if self.Pi_complete is None:
            self.Pi_complete = mp.ellippi(self.nchar, self.m)
        return 2 * j * self.Pi_complete + mp.ellippi(self.nchar, phi, self.m)

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
            return matvec(axis_rotation(self.sym_e, -self.Wb * t), self.M0)
        return list(self.M0)

    # -- attitude -------------------------------------------------------------
    def _psi_elliptic(self, t):
        if self.branch == "separatrix":
            u = self.u0 + self.lam * t
            return self.psi_rate * t + self.psi_coef * (
                mp.atan(self.sqnu * mp.tanh(u)) - self.atan0)
        u = self.u0 + self.lam * t
        if self.Pi0 is None:
            self.Pi0 = self._Pi_am(self.u0)
        return self.psi_rate * t + self.psi_coef * (self._Pi_am(u) - self.Pi0)

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
            return expm_hat([mi / self.d[0] for mi in self.M0], t), list(self.M0)
        if br == "steady":
            return expm_hat(self.Om0, t), list(self.M0)
        if br == "symmetric":
            R = matmul(expm_hat([mi / self.Iperp for mi in self.M0], t),
                        axis_rotation(self.sym_e, self.Wb * t))
            return R, self.momentum(t)
        M = self.momentum(t)
        if psi_method == "elliptic":
            psi = self._psi_elliptic(t)
        else:
            psi = self._psi_quad(t)
        A = self.attitude_frame(M)
        R = matmul(matmul(transpose(self.A0), rz(psi)), A)
        return R, M

    def state(self, t, psi_method="elliptic"):
        Rp, Mp = self.principal_state(t, psi_method)
        R = matmul(matmul(self.Q, Rp), self.QT)
        M = matvec(self.Q, Mp)
        return [R[i][j] for i in range(3) for j in range(3)] + M

    def angular_velocity(self, t):
        Mp = self.momentum(t)
        return matvec(self.Q, [Mp[i] / self.d[i] for i in range(3)])


def check_psi_method(psi_method):
    if psi_method not in ("elliptic", "quad"):
        raise ValueError(f"`psi_method` must be 'elliptic' or 'quad'; got {psi_method!r}")
