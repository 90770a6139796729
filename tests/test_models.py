"""Models: vector fields from the brackets equal the hand-written equations; input checks name the argument."""

import warnings

import heyoka as hy
import numpy as np
import pytest

import lieseries as ls


def hat(w):
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def eval_double(model, exprs, z):
    ps = model.poisson
    cf = hy.cfunc(exprs, vars=ps.variables)
    npar = len(hy.get_params(exprs))  # a compiled function takes the parameters it uses
    return cf(np.asarray(z, dtype=float), pars=np.array([float(v) for v in ps.parameter_values[:npar]]))


def field_at(model, z):
    return eval_double(model, model.poisson.vector_field, z)


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


@pytest.mark.parametrize("bracket", ["chetaev", "intermediate"])
@pytest.mark.parametrize(
    "inertia",
    [(1.0, 2.0, 3.0), [[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 3.0]]],
    ids=["diagonal", "full"],
)
def test_euler_poisson_field_matches_hand_written(inertia, bracket):
    """dR/dt = R hat(Omega), I dOmega/dt = (I Omega) x Omega, at random states with R a rotation."""
    body = ls.EulerPoisson(inertia, bracket=bracket)
    I = np.diag(inertia) if np.ndim(inertia) == 1 else np.array(inertia)
    rng = np.random.default_rng(1)
    for _ in range(5):
        R = random_rotation(rng)
        M = rng.normal(size=3)
        Om = np.linalg.solve(I, M)
        expected = np.concatenate([(R @ hat(Om)).ravel(), np.cross(M, Om)])
        got = field_at(body, np.concatenate([R.ravel(), M]))
        np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13)


def test_chetaev_field_off_the_rotation_group():
    """With the Chetaev bracket dR/dt = R hat(Omega) holds for any matrix R, orthogonal or not."""
    body = ls.EulerPoisson((1.0, 2.0, 3.0))
    rng = np.random.default_rng(2)
    R = rng.normal(size=(3, 3))
    M = rng.normal(size=3)
    Om = M / np.array([1.0, 2.0, 3.0])
    got = field_at(body, np.concatenate([R.ravel(), M]))
    np.testing.assert_allclose(got[:9], (R @ hat(Om)).ravel(), rtol=1e-13, atol=1e-13)


def test_sphere_field_is_tangent_and_matches_dirac():
    """The 5-d field moves x like the 6-d Dirac field (x' = p/m) at the same physical state."""
    sph = ls.Sphere(mass=2.0, radius=1.5)
    dirac = ls.SphereDirac(mass=2.0, radius=1.5)
    x = np.array([0.3, -0.6, 1.2])
    x *= 1.5 / np.linalg.norm(x)
    v = np.cross(x, [0.2, 1.0, -0.4])
    z5 = sph.initial_state(x, v)
    z6 = dirac.initial_state(x, v)
    f5 = field_at(sph, z5)
    f6 = field_at(dirac, z6)
    np.testing.assert_allclose(f5[:3], v, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(f6[:3], v, rtol=1e-13, atol=1e-14)
    # acceleration: centripetal, -|v|^2 x / r^2
    np.testing.assert_allclose(f6[3:] / 2.0, -np.dot(v, v) * x / 1.5**2, rtol=1e-13, atol=1e-14)


def test_sphere_hamiltonian_is_kinetic_energy():
    """Corrected (dm6): H(x, pi) = |p|^2 / 2m with p from (dm4) -- the paper's version lacks a square."""
    sph = ls.Sphere(mass=3.0, radius=2.0)
    x = np.array([1.2, 0.0, 1.6])
    v = np.array([0.0, 0.7, 0.0]) + 0.3 * np.cross(x, [0, 1.0, 0]) / 2
    z = sph.initial_state(x, v)
    val = eval_double(sph, [sph.poisson.hamiltonian], z)[0]
    assert val == pytest.approx(0.5 * 3.0 * np.dot(v, v), rel=1e-14)
    np.testing.assert_allclose(sph.velocity(z), v, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(sph.position(z), x, rtol=0, atol=0)


def test_euler_poisson_state_helpers():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1.0, 0.1, 0.5))
    np.testing.assert_array_equal(body.rotation(y0), np.eye(3))
    np.testing.assert_allclose(body.angular_velocity(y0), [1.0, 0.1, 0.5], rtol=1e-15)
    inv = body.invariants(y0)
    assert float(inv["energy"]) == pytest.approx(0.5 * (1 * 1 + 2 * 0.01 + 3 * 0.25), rel=1e-15)
    assert float(inv["det_R"]) == 1.0 and float(inv["orthogonality"]) == 0.0
    assert [float(inv[k]) for k in ("L1", "L2", "L3")] == pytest.approx([1.0, 0.2, 1.5], rel=1e-15)


def test_initial_state_in_every_precision_is_exact():
    body = ls.EulerPoisson((1, 2, 3))
    for p in ("double", "long double", "quad", 237):
        y = body.initial_state(omega=(1, "0.1", "0.5"), precision=p)
        prec = ls.resolve_precision(p)
        from lieseries.precision import to_fraction

        assert abs(to_fraction(y[10]) - to_fraction("0.2")) <= to_fraction("0.2") * prec.eps


# -- bad input --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "inertia,match",
    [
        ((1, 2, -3), "positive"),
        ((1, 0, 3), "positive"),
        ((1, 2), "three principal moments or a 3x3"),
        ([[1, 0.5, 0], [0, 2, 0], [0, 0, 3]], "symmetric"),
        ([[1, 2, 0], [2, 1, 0], [0, 0, 3]], "positive-definite"),
        ((1, float("nan"), 3), "finite"),
        ((1, "x", 3), "inertia"),
    ],
)
def test_bad_inertia(inertia, match):
    with pytest.raises(ValueError, match=match) as err:
        ls.EulerPoisson(inertia)
    assert "`inertia" in str(err.value)


def test_nonphysical_inertia_warns():
    with pytest.warns(UserWarning, match="triangle inequality"):
        ls.EulerPoisson((1, 1, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ls.EulerPoisson((1, 2, 3))  # flat limit I1 + I2 = I3 is physical (a lamina)


def test_bad_bracket():
    with pytest.raises(ValueError, match="`bracket`"):
        ls.EulerPoisson((1, 2, 3), bracket="dirac")


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(omega=(1, 2)), "`omega`"),
        (dict(omega=(1, 2, float("inf"))), "`omega"),
        (dict(omega=(1, 2, 3), R0=np.ones((3, 3))), "`R0` must be a rotation"),
        (dict(omega=(1, 2, 3), R0=np.diag([1.0, 1.0, -1.0])), "det R0"),
        (dict(omega=(1, 2, 3), R0=np.eye(2)), "`R0` must be a 3x3"),
    ],
)
def test_bad_initial_state(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ls.EulerPoisson((1, 2, 3)).initial_state(**kwargs)


@pytest.mark.parametrize(
    "x,v,match",
    [
        ((0.6, 0.0, 0.9), (0, 1, 0), "`x` must lie on the sphere"),
        ((0.6, 0.0, 0.8), (0.6, 1, 0.8), "`v` must be tangent"),
        ((0.6, 0.0), (0, 1, 0), "`x` must be three"),
        ((1.0, 0.0, 0.0), (0, 1, 0), "edge of the chart"),
    ],
)
def test_bad_sphere_state(x, v, match):
    with pytest.raises(ValueError, match=match):
        ls.Sphere().initial_state(x, v)


@pytest.mark.parametrize("kwargs,match", [(dict(mass=0), "`mass`"), (dict(radius=-1), "`radius`"),
                                          (dict(chart=3), "`chart`"), (dict(edge=0.6), "`edge`")])
def test_bad_sphere_model(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ls.Sphere(**kwargs)


def test_dirac_initial_state_removes_radial_velocity():
    d = ls.SphereDirac(radius=1.0, rtol=1e-6)
    y = d.initial_state((0.6, 0.0, 0.8), (1e-8, 1.0, 0.0))
    from lieseries.precision import to_fraction

    xp = sum(to_fraction(y[i]) * to_fraction(y[3 + i]) for i in range(3))
    assert abs(float(xp)) < 1e-17
