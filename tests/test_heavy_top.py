"""HeavyTop: EulerPoisson's bracket with gravity in H, against a Taylor-series solution of the (M, Gamma)
Euler-Poisson equations written here in mpmath (independent of heyoka and of the model's bracket)."""

from fractions import Fraction

import numpy as np
import pytest

import lieseries as ls
from lieseries.precision import resolve_precision, to_fraction
from problems import ctx_mpf, private_ctx




def euler_poisson_reference(inertia, weight, M0, G0, ts, c, order=36, h="1/16"):
    """dM/dt = M x Omega + Gamma x w, dGamma/dt = Gamma x Omega, Omega = M / I (principal axes), w = mass g com:
    fixed-step Taylor series whose coefficients follow from the bilinear right-hand side (Cauchy products).
    Returns (M, Gamma) at each of the times ``ts`` (multiples of ``h``)."""
    step = to_fraction(h)
    h = ctx_mpf(c, h)
    Iinv = [1 / ctx_mpf(c, i) for i in inertia]
    w = [ctx_mpf(c, v) for v in weight]
    M = [ctx_mpf(c, v) for v in M0]
    G = [ctx_mpf(c, v) for v in G0]

    out, done = [], 0
    for t_end in ts:
        steps = int(to_fraction(t_end) / step) - done
        done += steps
        M, G = _taylor_steps(M, G, Iinv, w, h, steps, order, c)
        out.append((M, G))
    return out


def _taylor_steps(M, G, Iinv, w, h, steps, order, c):
    def cross_k(a, b, k):  # the order-k coefficient of a x b from the series a, b
        out = []
        for i in range(3):
            j, l = (i + 1) % 3, (i + 2) % 3
            out.append(c.fsum(a[j][m] * b[l][k - m] - a[l][m] * b[j][k - m] for m in range(k + 1)))
        return out

    for _ in range(steps):
        Ms = [[M[i]] for i in range(3)]
        Gs = [[G[i]] for i in range(3)]
        for k in range(order):
            Om = [[Iinv[i] * Ms[i][m] for m in range(k + 1)] for i in range(3)]
            dM = cross_k(Ms, Om, k)
            gw = [Gs[(i + 1) % 3][k] * w[(i + 2) % 3] - Gs[(i + 2) % 3][k] * w[(i + 1) % 3] for i in range(3)]
            dG = cross_k(Gs, Om, k)
            for i in range(3):
                Ms[i].append((dM[i] + gw[i]) / (k + 1))
                Gs[i].append(dG[i] / (k + 1))
        M = [c.polyval(Ms[i][::-1], h) for i in range(3)]
        G = [c.polyval(Gs[i][::-1], h) for i in range(3)]
    return M, G


TOP = dict(inertia=(3, 4, 5), com=("0.1", "-0.2", "0.3"), mass=1, g="9.81")
OMEGA = (1, "0.5", "-0.3")


def test_heavy_top_matches_the_euler_poisson_equations_at_44_digits():
    top = ls.HeavyTop(**TOP)
    y0 = top.initial_state(omega=OMEGA)
    sol = ls.integrate(top, y0, t=["0.5", 1], precision=160)
    assert sol.success
    c = private_ctx(55)
    weight = [Fraction(981, 100) * to_fraction(v) for v in TOP["com"]]
    M0 = [3 * 1, 4 * Fraction(1, 2), 5 * Fraction(-3, 10)]
    ref = euler_poisson_reference(TOP["inertia"], weight, M0, [0, 0, 1], ["0.5", 1], c)
    for t, row, (M, G) in zip(["0.5", 1], sol.y, ref):
        err = max(abs(ctx_mpf(c, a) - b) for a, b in zip(list(row[9:]) + list(row[6:9]), M + G))
        # 160 bits: 48 digits; measured 5.6e-48 at t = 1 (a reference of order 30, h = 1/32, was off by 1.4e-50)
        assert err < c.mpf(10) ** -44, (t, err)


@pytest.mark.parametrize("precision", ["double", "quad"])
def test_lagrange_top_conserves_M3_energy_and_vertical_momentum(precision):
    top = ls.HeavyTop(inertia=(2, 2, 1), com=(0, 0, "0.5"), mass=2, g="9.81")
    y0 = top.initial_state(omega=("0.3", "-0.2", 5), R0=[["0.6", 0, "-0.8"], [0, 1, 0], ["0.8", 0, "0.6"]])
    sol = ls.integrate(top, y0, t=np.linspace(0, 10, 6).tolist(), precision=precision)
    assert sol.success
    eps = float(resolve_precision(precision).eps)
    inv0 = top.invariants(y0)
    inv = top.invariants(sol.y)
    M3 = top.angular_momentum(sol.y)[:, 2]
    for i in range(len(sol.t)):
        assert abs(inv["energy"][i] - inv0["energy"]) < 100 * eps * abs(inv0["energy"])
        assert abs(inv["L3"][i] - inv0["L3"]) < 100 * eps * 5
        assert abs(float(M3[i]) - 5) < 100 * eps * 5
    # the top nutates: Gamma_3 = R33 moves (so gravity acts and the check above is not vacuous)
    assert max(abs(float(r) - 0.6) for r in np.asarray(sol.y)[:, 8]) > 1e-3


def test_heavy_top_energy_is_kinetic_plus_potential():
    top = ls.HeavyTop(inertia=(3, 4, 5), com=(1, 2, 3), mass=2, g=10)
    y0 = top.initial_state(omega=(1, 1, 1))
    c = private_ctx(50)
    assert abs(ctx_mpf(c, top.invariants(y0)["energy"]) - (Fraction(12, 2) + 2 * 10 * 3)) < c.mpf(10) ** -40


def test_bad_heavy_top_input_names_the_argument():
    with pytest.raises(ValueError, match="`com`"):
        ls.HeavyTop(com=(0, 1))
    with pytest.raises(ValueError, match="`mass`"):
        ls.HeavyTop(mass=0)
    with pytest.raises(ValueError, match="`inertia`"):
        ls.HeavyTop(inertia=(1, -2, 3))
