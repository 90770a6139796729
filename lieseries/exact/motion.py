"""The free rigid body's motion in closed form (:class:`RigidBody`): Jacobi elliptic functions for the momentum,
the attitude from the precession angle (elliptic integrals of the third kind, or a quadrature)."""

from __future__ import annotations

from ..precision import thread_mp as mp
from .inputs import CLASSIFY_DIGITS, GUARD_DIGITS, vec3
from .linalg import axis_rotation, dot, expm_hat, matmul, matvec, norm, rz, transpose
from .principal import RigidBodyConstants, complete_k, parse_inertia


class RigidBody:
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
        d, Q, exact = parse_inertia(inertia, dps)
        om = vec3(omega, "omega")
        self.d = d
        self.Q = Q
        self.QT = transpose(Q)
        I1, I2, I3 = d
        Om = matvec(self.QT, om)  # body angular velocity in the principal frame
        M = [d[i] * Om[i] for i in range(3)]
        if not exact:
            # components that are round-off of the diagonalisation
            nM = norm(M)
            eps = mp.mpf(10) ** -(dps + CLASSIFY_DIGITS) * nM
            M = [mi if abs(mi) > eps else mp.mpf(0) for mi in M]
            Om = [M[i] / d[i] for i in range(3)]
        self.M0 = M
        self.Om0 = Om
        self.M2 = dot(M, M)
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
        K, Kp = complete_k(m, m1)
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
            return matvec(axis_rotation(self.sym_e, -self.Wb * t), self.M0)
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
        A = self._attitude_frame(M)
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


def check_psi_method(psi_method):
    if psi_method not in ("elliptic", "quad"):
        raise ValueError(f"`psi_method` must be 'elliptic' or 'quad'; got {psi_method!r}")
