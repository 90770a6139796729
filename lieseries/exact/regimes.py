"""The free rigid body's set-up (:class:`RigidBodySetup`): invariants, the regime (spherical, steady, symmetric,
the two elliptic branches, the separatrix), the elliptic parameter and phase, the working precision near the
separatrix, and the constants a solution reports."""

from __future__ import annotations

from ..precision import thread_mp as mp
from .inputs import CLASSIFY_DIGITS, GUARD_DIGITS, vec3
from .linalg import dot, matvec, norm, transpose
from .principal import RigidBodyConstants, complete_k, parse_inertia


class RigidBodySetup:
    """Set-up of the closed-form solution (the motion is :class:`lieseries.exact.motion.RigidBody`); methods must
    run at ``self.wp``."""

    def __init__(self, inertia, omega, dps):
        self.dps = dps
        wp = dps + GUARD_DIGITS
        with mp.workdps(wp):
            self.setup(inertia, omega, wp, elliptic=False)
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
                self.setup(inertia, omega, wp)
        else:
            with mp.workdps(wp):
                self.setup_elliptic()

    # -- set-up ---------------------------------------------------------------
    def setup(self, inertia, omega, wp, elliptic=True):
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
            self.setup_symmetric()
        else:
            tol = mp.mpf(10) ** -(dps + CLASSIFY_DIGITS)
            # The separatrix formulas match M1(0), M2(0) and put M3 on the separatrix: declare it only when that
            # moves M3 by at most tol |M| (d gap / d M3 = 2 M3 (I3 - I2) / I3).  A bound relative to |M|^2
            # alone would, near the intermediate axis (M1, M3 ~ eps), replace M3 by a value off by O(eps).
            if M[0] != 0 and M[2] != 0 and \
                    abs(self.gap) <= 2 * tol * self.L * abs(M[2]) * (I3 - I2) / I3:
                self.branch = "separatrix"
                self.setup_separatrix()
            else:
                self.branch = "above" if self.gap > 0 else "below"
                if elliptic:
                    self.setup_elliptic()

    def setup_symmetric(self):
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

    def setup_elliptic(self):
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
        self.Pi_complete = self.Pi0 = None
        self.period = 4 * K / lam
        jn = mp.nint(u0 / (2 * K))
        dist = u0 - 2 * K * jn
        self.pole_distance = mp.sqrt(dist ** 2 + Kp ** 2) / lam
        self.pole_time = mp.mpc(2 * K * jn - u0, Kp) / lam
        self.A0 = self.attitude_frame(self.M0)

    def setup_separatrix(self):
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
        self.A0 = self.attitude_frame(self.M0)

    # -- attitude frame ---------------------------------------------------------
    def attitude_frame(self, M):
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
