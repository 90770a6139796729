"""Geodesics on a triaxial ellipsoid: Joachimsthal's integral conserved to each precision's epsilon, and the path
against a Taylor-series solution, written here, of the Cartesian equations with the Lagrange multiplier."""

from fractions import Fraction

import numpy as np
import pytest

import lieseries as ls
from lieseries.precision import dps_to_bits, resolve_precision, to_fraction
from problems import ctx_mpf, private_ctx

AXES = (1, 2, 3)
Q0 = ("2/7", "6/7", "18/7")  # (x/a, y/b, z/c) = (2, 3, 6)/7
V0 = (1, 0, -1)  # tangent: (x/a^2, y/b^2, z/c^2) . v = 2/7 - 2/7 = 0


def geodesic_reference(c, times, order=32, h="1/32"):
    """x(t) from x'' = -mu (x/a^2, y/b^2, z/c^2), mu = (sum v_i^2/a_i^2) / (sum x_i^2/a_i^4) (the multiplier that
    keeps d^2G/dt^2 = 0), written polynomial with D = 1 / sum x_i^2/a_i^4, D' = -2 D^2 sum x_i v_i / a_i^4, and
    solved by a fixed-step Taylor series (Cauchy products)."""
    w2 = [1 / ctx_mpf(c, a) ** 2 for a in AXES]
    w4 = [v * v for v in w2]
    x = [ctx_mpf(c, v) for v in Q0]
    v = [ctx_mpf(c, u) for u in V0]
    u = x + v + [1 / c.fsum(xi * xi * w for xi, w in zip(x, w4))]
    step, hh = to_fraction(h), ctx_mpf(c, h)

    def mul(a, b, k):
        return c.fdot(a[:k + 1], b[k::-1])

    out, done = [], 0
    for t_end in times:
        for _ in range(int(to_fraction(t_end) / step) - done):
            s = [[e] for e in u]  # x1..3, v1..3, D
            N, D2, XV, MU = [], [], [], []
            for k in range(order):
                N.append(c.fsum(w2[i] * mul(s[3 + i], s[3 + i], k) for i in range(3)))
                D2.append(mul(s[6], s[6], k))
                XV.append(c.fsum(w4[i] * mul(s[i], s[3 + i], k) for i in range(3)))
                MU.append(mul(N, s[6], k))
                rhs = [s[3 + i][k] for i in range(3)] + [-w2[i] * mul(MU, s[i], k) for i in range(3)]
                rhs.append(-2 * mul(D2, XV, k))
                for ser, r in zip(s, rhs):
                    ser.append(r / (k + 1))
            u = [c.polyval(ser[::-1], hh) for ser in s]
            done += 1
        out.append(u[:3])
    return out


@pytest.mark.parametrize("precision", ["double", "quad", dps_to_bits(50)])
def test_joachimsthal_integral_is_conserved(precision):
    ell = ls.EllipsoidGeodesic(axes=AXES)
    y0 = ell.initial_state(q=Q0, qdot=V0)
    inv0 = ell.invariants(y0)
    c = private_ctx(70)
    # J = (x^2/a^4 + y^2/b^4 + z^2/c^4)(xdot^2/a^2 + ydot^2/b^2 + zdot^2/c^2), from the exact data
    J0 = (to_fraction("4/49") + to_fraction("36/49") / 16 + to_fraction("324/49") / 81) * (1 + Fraction(1, 9))
    assert abs(ctx_mpf(c, inv0["joachimsthal"]) - ctx_mpf(c, J0)) < c.mpf(10) ** -60
    sol = ls.integrate(ell, y0, t=np.linspace(0, 6, 7).tolist()[1:], precision=precision)
    assert sol.success
    inv = ell.invariants(sol.y)
    eps = ctx_mpf(c, resolve_precision(precision).eps)
    for i in range(len(sol.t)):
        drift = abs(ctx_mpf(c, inv["joachimsthal"][i]) - ctx_mpf(c, J0))
        # measured: 5.8 eps J0 (double), 5.0 eps J0 (quad), 5.3 eps J0 (169 bits) by t = 6
        assert drift < 50 * eps * ctx_mpf(c, J0), (precision, i, drift)
        assert abs(ctx_mpf(c, inv["energy"][i]) - 1) < 50 * eps
        assert abs(ctx_mpf(c, inv["G1"][i])) < 50 * eps
    # the motion goes round the ellipsoid (not a trivial check)
    assert float(np.ptp(np.asarray(ell.configuration(sol), dtype=float)[:, 2])) > 1


TIMES = ["0.5", 1]


@pytest.fixture(scope="module")
def geodesic_ref():
    c = private_ctx(45)
    return c, geodesic_reference(c, TIMES)  # 1.4e-36 from a run of order 46 with h = 1/64


@pytest.mark.parametrize("precision", ["double", dps_to_bits(30)])
def test_geodesic_follows_the_cartesian_equations(precision, geodesic_ref):
    c, ref = geodesic_ref
    times = TIMES
    ell = ls.EllipsoidGeodesic(axes=AXES)
    sol = ls.integrate(ell, ell.initial_state(q=Q0, qdot=V0), t=times, precision=precision)
    assert sol.success
    eps = ctx_mpf(c, resolve_precision(precision).eps)
    for row, x_ref in zip(ell.configuration(sol), ref):
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(row, x_ref))
        # measured: 5.0e-16 (double, eps 2.2e-16), 8.8e-32 (103 bits, eps 2.0e-31)
        assert err < 20 * eps * 3, (precision, err)


def test_ellipsoid_input_is_checked():
    with pytest.raises(ValueError, match=r"`axes\[1\]`"):
        ls.EllipsoidGeodesic(axes=(1, 0, 3))
    with pytest.raises(ValueError, match="`axes`"):
        ls.EllipsoidGeodesic(axes=(1, 2))
    ell = ls.EllipsoidGeodesic(axes=AXES)
    with pytest.raises(ValueError, match="`q`"):
        ell.initial_state(q=(1, 1, 1), qdot=(0, 0, 0))
    with pytest.raises(ValueError, match="`qdot`"):
        ell.initial_state(q=Q0, qdot=(1, 0, 0))
    assert ls.EllipsoidGeodesic(axes=AXES).system is ell.system  # derived once
