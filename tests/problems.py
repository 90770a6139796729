"""The shared registry of test problems: systems, initial states, references, and the exact-to-mpf helper.

Every test file takes its problems from here, so that one problem is written once: the asymmetric rigid body of
the tutorial (RIGID_INERTIA, RIGID_OMEGA) with its closed form, the great circle on the unit sphere (SPHERE_X0,
SPHERE_V0), and hand-written systems for the jet and literal engines.
"""

from fractions import Fraction

import heyoka as hy
import mpmath as mp

from lieseries import exact
from lieseries.precision import to_fraction

#: The tutorial's body: I = (1, 2, 3), Omega(0) = (1, 0.1, 0.5) exactly, R(0) = 1.
RIGID_INERTIA = (1, 2, 3)
RIGID_OMEGA = (1, "0.1", "0.5")
#: A great circle through the equators of the unit sphere: x(t) = x0 cos t + v0 sin t.
SPHERE_X0, SPHERE_V0 = ("0.6", "0", "0.8"), ("0", "1", "0")


def mpf(q):
    """The exact value of ``q`` (any number lieseries accepts) as an mpf at the current mpmath precision."""
    q = to_fraction(q)
    return mp.mpf(q.numerator) / q.denominator


def rigid_error(row, t, dps=80, inertia=RIGID_INERTIA, omega=RIGID_OMEGA):
    """Max |state - closed form| of the rigid body at t (the closed form from the exact data)."""
    ref = exact.euler_poisson(inertia, omega, t, dps=dps)
    with mp.workdps(dps):
        return max(abs(mpf(a) - b) for a, b in zip(row, ref))


RB_PARS = [Fraction(1), Fraction(1, 2), Fraction(1, 3)]  # 1/I for I = (1, 2, 3)
RB_Y0 = [1, 0, 0, 0, 1, 0, 0, 0, 1, 1, "0.2", "1.5"]  # R = 1, M = I (1, 0.1, 0.5)


def rigid_body():
    """Euler-Poisson: dR/dt = R hat(Omega), dM/dt = M x Omega, Omega_i = par[i] M_i."""
    R = hy.make_vars(*[f"R{i}{j}" for i in range(1, 4) for j in range(1, 4)])
    M = hy.make_vars("M1", "M2", "M3")
    om = [hy.par[i] * M[i] for i in range(3)]
    hat = [[None, -om[2], om[1]], [om[2], None, -om[0]], [-om[1], om[0], None]]
    dR = []
    for i in range(3):
        for j in range(3):
            dR.append(hy.sum([R[3 * i + k] * hat[k][j] for k in range(3) if hat[k][j] is not None]))
    dM = [M[1] * om[2] - M[2] * om[1], M[2] * om[0] - M[0] * om[2], M[0] * om[1] - M[1] * om[0]]
    return list(R) + list(M), dR + dM


def sphere():
    """Particle on a sphere in intermediate coordinates (x1, x2, x3, pi1, pi2), par[0] = m."""
    x1, x2, x3, p1, p2 = z = hy.make_vars("x1", "x2", "x3", "pi1", "pi2")
    m = hy.par[0]
    H = (p1**2 + p2**2 - (x1 * p1 + x2 * p2) ** 2 / (x1**2 + x2**2 + x3**2)) / (2 * m)
    B = [[None] * 5 for _ in range(5)]
    for a, b, v in [(0, 3, hy.expression(1.0)), (1, 4, hy.expression(1.0)),
                    (2, 3, -x1 / x3), (2, 4, -x2 / x3)]:
        B[a][b], B[b][a] = v, -v
    dH = [hy.diff(H, zi) for zi in z]
    rhs = [hy.sum([B[a][b] * dH[b] for b in range(5) if B[a][b] is not None]) for a in range(5)]
    return list(z), rhs


def sphere_initial(m):
    """x = (0.6, 0, 0.8), p = m v with v = (0, 1, 0); pi_a = p_a - x_a p_3 / x_3 (exact)."""
    x = [Fraction(3, 5), Fraction(0), Fraction(4, 5)]
    p = [Fraction(0), m, Fraction(0)]
    return x + [p[a] - x[a] * p[2] / x[2] for a in range(2)]


SPHERE_M = Fraction(3, 2)


def max_rel(a, b):
    """Largest |a_k,i - b_k,i| relative to the size of the order-k coefficients.

    The size of order k is the max norm of orders k-1, k, k+1 of `b`: some
    components vanish by symmetry at every other order, and a rounding-noise
    entry must not be compared with an exact zero alone.
    """
    with mp.workdps(150):
        return _max_rel(a, b)


def _max_rel(a, b):
    norms = [max(abs(mp.mpf(x)) for x in row) for row in b]
    worst = mp.mpf(0)
    for k, (ra, rb) in enumerate(zip(a, b)):
        scale = max(norms[max(0, k - 1):k + 2])
        if scale == 0:
            continue
        worst = max(worst, max(abs(mp.mpf(x) - mp.mpf(y)) for x, y in zip(ra, rb)) / scale)
    return worst


def nonlinear():
    """Exercises exp, log, sin, cos, sqrt, x**1.5, x**-2, division and parameters."""
    x, y, z = v = hy.make_vars("x", "y", "z")
    p = hy.par[0]
    rhs = [hy.sin(y) * hy.exp(-x) + hy.sqrt(z),
           hy.log(z) - x**1.5 / (1.0 + y * y) + p,
           hy.cos(x * y) - z**-2.0 * p]
    return list(v), rhs


def private_ctx(dps):
    """A private mpmath context at ``dps`` digits (mpmath's global one is never touched)."""
    c = mp.MPContext()
    c.dps = dps
    return c


def ctx_mpf(c, v):
    """The exact value of ``v`` (str, int, Fraction, float, mpf) as a number of the context ``c``."""
    f = to_fraction(v)
    return c.mpf(f.numerator) / f.denominator


def as_from_a_terminal():
    """A child process's ``preexec_fn``: SIGINT at its default and not blocked, as a terminal starts a program. A
    child inherits both from the process that starts it, and the test runner's worker process at times ignores
    SIGINT (a program started with SIGINT ignored, as a background job is, rightly keeps ignoring it)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
