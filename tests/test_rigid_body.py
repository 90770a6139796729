"""The rigid body with heyoka in every precision against the closed-form solution (elliptic functions)."""

import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries import exact
from problems import mpf

TIMES = [5, 10, 15, 20]
OMEGA = (1, "0.1", "0.5")


@pytest.fixture(scope="module")
def reference():
    return exact.euler_poisson_many((1, 2, 3), OMEGA, TIMES, dps=80)


def max_error(sol, ref):
    with mp.workdps(90):
        return max(abs(mpf(a) - b) for yk, rk in zip(sol.y, ref) for a, b in zip(yk, rk))


def test_rigid_body_matches_closed_form_over_20_time_units(precision, reference):
    """Error ~ a modest multiple of epsilon at T = 20 (double: ~1e-13), invariants to ~1e-14 (double)."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(OMEGA, precision=precision)
    sol = ls.integrate(body, y0, t=TIMES, precision=precision)
    assert sol.success, sol.message
    eps = ls.resolve_precision(precision).eps
    err = max_error(sol, reference)
    assert err < 100 * eps
    if precision == "double":
        assert err < 1e-13
    inv0 = body.invariants(y0)
    inv = body.invariants(sol.y)
    for key in inv0:
        drift = max(abs(v - inv0[key]) for v in inv[key])
        assert drift < 40 * eps, (key, float(drift / eps))


def test_237_bits_reach_1e60(reference):
    """Parameters carried at the working precision: a 237-bit run agrees with a 70-digit reference to < 1e-60.

    (I2 - I3)/I1 folded into a double would cap this near 1e-16.
    """
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(OMEGA, precision=237)
    sol = ls.integrate(body, y0, t=TIMES[:2], precision=237)
    ref70 = exact.euler_poisson_many((1, 2, 3), OMEGA, TIMES[:2], dps=70)
    assert max_error(sol, ref70) < 1e-60


def test_double_rounded_parameters_would_be_caught():
    """Control: feeding the 237-bit run a double-rounded 1/3 (inertia 3.0000000000000004) misses by ~1e-16."""
    body = ls.EulerPoisson((1, 2, 3.0000000000000004))
    y0 = body.initial_state(OMEGA, precision=237)
    sol = ls.integrate(body, y0, t=[5], precision=237)
    ref = exact.euler_poisson_many((1, 2, 3), OMEGA, [5], dps=70)
    assert max_error(sol, ref) > 1e-20


@pytest.mark.parametrize("bracket", ["chetaev", "intermediate"])
def test_full_inertia_tensor_and_both_brackets(bracket):
    """A lab frame not aligned with the axes of inertia: diag(1, 2, 3) rotated; both brackets, same motion."""
    c, s = np.cos(0.4), np.sin(0.4)
    Q = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    inertia = Q @ np.diag([1.0, 2.0, 3.0]) @ Q.T
    inertia = (inertia + inertia.T) / 2
    body = ls.EulerPoisson(inertia, bracket=bracket)
    omega = (0.3, -1.0, 0.4)
    y0 = body.initial_state(omega)
    sol = ls.integrate(body, y0, t=[2.0, 6.0])
    ref = exact.euler_poisson_many(body.inertia_exact, omega, [2.0, 6.0], dps=40)
    assert sol.success
    assert max_error(sol, ref) < 1e-13


def test_physical_motion_stays_on_rotation_group():
    body = ls.EulerPoisson((1, 2, 3))
    sol = ls.integrate(body, body.initial_state((0.1, 1.0, 0.1)), t=np.linspace(0, 50, 11))
    R = body.rotation(sol.y)
    for Rk in R:
        np.testing.assert_allclose(Rk.T @ Rk, np.eye(3), atol=5e-14)
        assert np.linalg.det(Rk) == pytest.approx(1.0, abs=5e-14)
