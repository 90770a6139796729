"""Bad input at every public entry point: an error that names the argument (and says what to do)."""

import numpy as np
import pytest

import lieseries as ls
from lieseries import exact, studies, validated
from lieseries.scenes import SceneError, load_scene


def _enter(make):
    """Enter the context manager ``make()`` gives (its checks run on entering)."""
    with make():
        pass


BODY = ls.EulerPoisson((1, 2, 3))
Y0 = BODY.initial_state((1, 0.1, 0.5))
NAN_STATE = np.r_[Y0[:11], np.nan]
SPHERE = ls.Sphere()
S0 = SPHERE.initial_state((0.6, 0, 0.8), (0, 1, 0))

CASES = {
    # wrong shapes
    "integrate: short state": (lambda: ls.integrate(BODY, Y0[:5], t=1), ValueError, "`y0`"),
    "integrate: state is a string": (lambda: ls.integrate(BODY, "abc", t=1), ValueError, "`y0`"),
    "lie_series: 2-d state": (lambda: ls.lie_series(BODY, np.stack([Y0, Y0])), ValueError, "`y0`"),
    "lie_integrate: short state": (lambda: ls.lie_integrate(BODY, Y0[:3], t=1), ValueError, "`y0`"),
    "rotation: wrong length": (lambda: BODY.rotation(np.zeros(5)), ValueError, "`y`"),
    # NaN / inf
    "integrate: NaN state": (lambda: ls.integrate(BODY, NAN_STATE, t=1), ValueError, r"`y0\[11\]`"),
    "lie_series: NaN state": (lambda: ls.lie_series(BODY, NAN_STATE), ValueError, r"`y0\[11\]`"),
    "lie_integrate: inf time": (lambda: ls.lie_integrate(BODY, Y0, t=float("inf")), ValueError, "`t`"),
    "initial_state: NaN omega": (lambda: BODY.initial_state((1, np.nan, 0)), ValueError, "`omega"),
    "Sphere: inf mass": (lambda: ls.Sphere(mass=np.inf), ValueError, "`mass`"),
    # inertia: non-SPD, non-symmetric
    "inertia: not positive-definite": (lambda: ls.EulerPoisson([[1, 2, 0], [2, 1, 0], [0, 0, 1]]), ValueError,
                                       "`inertia` must be positive-definite"),
    "inertia: not symmetric": (lambda: ls.EulerPoisson([[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]), ValueError,
                               "`inertia` must be symmetric"),
    "inertia: negative moment": (lambda: ls.EulerPoisson((1, -2, 3)), ValueError, "`inertia`"),
    # R0 not orthogonal: refused (R R^T is conserved, so it would never become a rigid motion)
    "R0 not orthogonal": (lambda: BODY.initial_state((1, 0, 0), R0=np.diag([1, 2, 1])), ValueError, "`R0`"),
    # sphere state off the sphere, or with x . v != 0
    "sphere: off the sphere": (lambda: SPHERE.initial_state((0.6, 0, 0.9), (0, 1, 0)), ValueError, "`x`"),
    "sphere: x.v != 0": (lambda: SPHERE.initial_state((0.6, 0, 0.8), (0.8, 0, -0.5)), ValueError, "`v`"),
    "Dirac: off the sphere": (lambda: ls.SphereDirac().initial_state((2, 0, 0), (0, 1, 0)), ValueError, "`x`"),
    "exact.sphere: x.v != 0": (lambda: exact.sphere(1, (1, 0, 0), (1, 0, 0), 1), ValueError, "`v`"),
    # order < 1, dps too small, tol <= 0
    "lie_series: order 0": (lambda: ls.lie_series(BODY, Y0, order=0), ValueError, "`order`"),
    "lie_integrate: order -1": (lambda: ls.lie_integrate(BODY, Y0, t=1, order=-1), ValueError, "`order`"),
    "lie_series: dps 3": (lambda: ls.lie_series(BODY, Y0, dps=3), ValueError, "`dps`"),
    "lie_integrate: dps 2.5": (lambda: ls.lie_integrate(BODY, Y0, t=1, dps=2.5), TypeError, "`dps`"),
    "exact: dps 2": (lambda: exact.euler_poisson((1, 2, 3), (1, 0, 0), 1, dps=2), ValueError, "`dps`"),
    "error_vs_order: dps 2": (lambda: studies.error_vs_order(BODY, Y0, 0.5, [1, 3], dps=2), ValueError, "`dps`"),
    "integrate: tol 0": (lambda: ls.integrate(BODY, Y0, t=1, tol=0), ValueError, "`tol`"),
    "integrate: tol -1e-9": (lambda: ls.integrate(BODY, Y0, t=1, tol=-1e-9), ValueError, "`tol`"),
    "lie_integrate: tol 0": (lambda: ls.lie_integrate(BODY, Y0, t=1, tol=0), ValueError, "`tol`"),
    "lie_integrate: tol below dps": (lambda: ls.lie_integrate(BODY, Y0, t=1, dps=20, tol=1e-40), ValueError,
                                     "raise `dps`"),
    # unknown names
    "integrate: unknown precision": (lambda: ls.integrate(BODY, Y0, t=1, precision="half"), ValueError,
                                     "`precision`"),
    "EulerPoisson: unknown bracket": (lambda: ls.EulerPoisson((1, 2, 3), bracket="lie"), ValueError, "`bracket`"),
    "work_precision: unknown method": (lambda: studies.work_precision(BODY, Y0, 1, methods=[{"method": "rk4"}]),
                                       ValueError, "`methods\\[0\\].method`"),
    "load_scene: unknown scene": (lambda: load_scene("no-such-scene"), SceneError, "unknown scene"),
    # budgets and options
    "integrate: max_steps 0": (lambda: ls.integrate(BODY, Y0, t=1, max_steps=0), ValueError, "`max_steps`"),
    "lie_integrate: max_time -1": (lambda: ls.lie_integrate(BODY, Y0, t=1, max_time=-1), ValueError, "`max_time`"),
    "DampedEulerPoisson: negative damping": (lambda: ls.DampedEulerPoisson((1, 2, 3), damping=-1), ValueError,
                                             "`damping`"),
    "atlas on a global model": (lambda: ls.integrate(BODY, Y0, t=1, atlas=True), ValueError, "`atlas`"),
    "not a model": (lambda: ls.lie_series({"a": 1}, Y0), TypeError, "`system`"),
}

# refusals added with the precision model, the hard limits and the statuses that tell the truth
CASES.update({
    "Sphere: chart 2.0": (lambda: ls.Sphere(chart=2.0), TypeError, "`chart` must be the int"),
    "Sphere: edge string": (lambda: ls.Sphere(edge="x"), TypeError, "`edge`"),
    "Sphere: edge None": (lambda: ls.Sphere(edge=None), TypeError, "`edge`"),
    "Sphere: rtol string": (lambda: ls.Sphere(rtol="small"), TypeError, "`rtol`"),
    "Sphere: rtol None": (lambda: ls.SphereDirac(rtol=None), TypeError, "`rtol`"),
    "integrate: max_time string": (lambda: ls.integrate(BODY, Y0, t=1, max_time="x"), TypeError, "`max_time`"),
    "integrate: max_time nan": (lambda: ls.integrate(BODY, Y0, t=1, max_time=float("nan")), ValueError,
                                "`max_time`"),
    "integrate: progress not callable": (lambda: ls.integrate(BODY, Y0, t=1, progress=3), TypeError,
                                         "`progress` must be callable"),
    "lie_integrate: progress not callable": (lambda: ls.lie_integrate(BODY, Y0, t=1, progress="bar"), TypeError,
                                             "`progress`"),
    "lie_integrate: max_steps 1.5": (lambda: ls.lie_integrate(BODY, Y0, t=1, max_steps=1.5), TypeError,
                                     "`max_steps`"),
    "working_precision: bits 2.5": (lambda: _enter(lambda: validated.working_precision(2.5)), TypeError, "`bits`"),
    "working_precision: cap 0": (lambda: _enter(lambda: validated.working_precision(100, cap=0)), ValueError,
                                 "`cap`"),
    "LieSeries(t): string": (lambda: ls.lie_series(BODY, Y0, order=4, dps=20)("soon"), ValueError, "`t`"),
    "LieSeries(t): nan": (lambda: ls.lie_series(BODY, Y0, order=4, dps=20)(float("nan")), ValueError, "`t`"),
    "exact: nan + 1j": (lambda: exact.angular_velocity((1, 2, 3), (1, 0, 0), complex(float("nan"), 1)),
                        ValueError, "`t` must be finite"),
    "lie_series: dps 5": (lambda: ls.lie_series(BODY, Y0, dps=5), ValueError, "`dps` must be at least 15"),
    "integrate: tol below eps": (lambda: ls.integrate(BODY, Y0, t=1, tol=1e-20), ValueError, "`tol`"),
    "integrate: 4000 bits": (lambda: ls.integrate(BODY, Y0, t=1, precision=4000), ValueError, "`precision`"),
    "lie_series: order 5000": (lambda: ls.lie_series(BODY, Y0, order=5000), ValueError, "`order`"),
    "integrate: t '1e99999999'": (lambda: ls.integrate(BODY, Y0, t="1e99999999"), ValueError, "`t`"),
    "integrate: t '1e400' in double": (lambda: ls.integrate(BODY, Y0, t="1e400"), ValueError, "`t`.*overflows"),
    "integrate: t '1/0'": (lambda: ls.integrate(BODY, Y0, t="1/0"), ValueError, "`t`.*divides by zero"),
    "integrate: y0 '1e400'": (lambda: ls.integrate(BODY, [1, 0, 0, 0, 1, 0, 0, 0, 1, "1e400", 0, 0], t=1),
                              ValueError, r"`y0`.*overflows"),
    "mpf state without precision": (lambda: ls.integrate(BODY, [ls.precision.mp_context().mpf(1)] * 12, t=1),
                                    ValueError, "`precision=`"),
    "drift: perturbation nan": (lambda: studies.drift(BODY, Y0, 10, perturbation=float("nan")), ValueError,
                                "`perturbation`"),
    "drift: seed string": (lambda: studies.drift(BODY, Y0, 10, seed="x"), TypeError, "`seed`"),
    "drift: a billion samples": (lambda: studies.drift(BODY, Y0, 10, samples=10**9), ValueError, "`samples`"),
    "work_precision: repeat 0": (lambda: studies.work_precision(BODY, Y0, 1, repeat=0), ValueError, "`repeat`"),
    "atlas rows that lost their charts": (lambda: SPHERE.position(_derived_atlas_rows()), ValueError,
                                          "no longer knows their charts"),
})

# budgets that bound: refused up front, naming the argument and the limit
def _ensemble(*args, **kwargs):
    from lieseries.ensemble import integrate_ensemble

    return integrate_ensemble(*args, **kwargs)


_HUGE_GRID = np.broadcast_to(np.float64(1), (10**10,))  # 10^10 output times, no memory of its own
CASES.update({
    "exact: rigid body above its digits limit": (lambda: exact.euler_poisson((1, 2, 3), (1, 0.1, 0.5), 1, dps=2001),
                                                 ValueError, r"`dps` = 2001 is above 2000"),
    "exact: quadrature above its digits limit": (lambda: exact.euler_poisson((1, 2, 3), (1, 0.1, 0.5), 1, dps=401,
                                                                             psi_method="quad"),
                                                 ValueError, r"`dps` = 401 is above 400"),
    "exact: angular velocity at 10000 digits": (lambda: exact.angular_velocity((1, 2, 3), (1, 0.1, 0.5), 1,
                                                                               dps=10000), ValueError, "`dps`"),
    "ensemble: batch_size 64": (lambda: _ensemble(BODY, np.stack([Y0, Y0]), t=1, batch_size=64),
                                ValueError, "`batch_size` must be at most 16"),
    "ensemble: 10^10 output times": (lambda: _ensemble(BODY, np.stack([Y0, Y0]), t=_HUGE_GRID),
                                     ValueError, r"`t` asks for 10000000000 output times: about .* GiB"),
    "validated: 10^10 output times": (lambda: ls.validated_integrate(BODY, Y0, t=_HUGE_GRID), ValueError,
                                      r"`t` asks for 10000000000 output times"),
})

def _select_field():
    """An extra field with heyoka's ``select``, which has no sympy form (it raised a TypeError from the converter)."""
    import heyoka as hy

    q, p = hy.make_vars("q", "p")
    return ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2, extra_field=[0, hy.select(hy.gt(q, 0.0), q, 0.5 * q)])


# messages that name the user's argument (not an internal value, not numpy's or heyoka's words)
CASES.update({
    "lie_series: dps above the limit names the user's dps": (lambda: ls.lie_series(BODY, Y0, order=3, dps=10001),
                                                             ValueError, r"`dps` .* got 10001$"),
    "ensemble: ragged Y0 names the row": (lambda: _ensemble(BODY, [list(Y0), list(Y0)[:11]], t=1), ValueError,
                                          r"`Y0\[1\]` has 11 numbers"),
    "integrate: ragged Y0 names the row": (lambda: ls.integrate(BODY, [list(Y0), list(Y0)[:11]], t=1), ValueError,
                                           r"`Y0\[1\]` has 11 numbers"),
    "ensemble: params overflowing double name the entry": (
        lambda: _ensemble(BODY, np.stack([Y0, Y0]), t=1, params=[["1e400", 1, 1], [1, 1, 1]]), ValueError,
        r"`params\[0\]\[0\]` = ~1e400 overflows double"),
    "ensemble: compact_mode 'yes'": (lambda: _ensemble(BODY, np.stack([Y0, Y0]), t=1, compact_mode="yes"),
                                     TypeError, "`compact_mode` must be True or False"),
    "integrate: compact_mode 'yes'": (lambda: ls.integrate(BODY, Y0, t=1, compact_mode="yes"),
                                      TypeError, "`compact_mode` must be True or False"),
    "integrate: high_accuracy 1": (lambda: ls.integrate(BODY, Y0, t=1, high_accuracy=1),
                                   TypeError, "`high_accuracy` must be True or False"),
    "integrate: a field heyoka cannot give sympy says what to write": (lambda: ls.integrate(_select_field(), ["0.3", 0],
                                                                                        t=1),
                                                                         ValueError, r"select.*`extra_field`"),
    "validated: max_width -1": (lambda: ls.validated_integrate(BODY, Y0, t=1, max_width=-1), ValueError,
                                "`max_width` must be a positive radius"),
    "validated: max_width 0": (lambda: ls.validated_integrate(BODY, Y0, t=1, max_width=0), ValueError,
                               "`max_width` must be a positive radius"),
})


def _derived_atlas_rows():
    rows = ls.integrate(SPHERE, S0, t=[1, 4]).y
    derived = rows.view(type(rows))  # a view that lost the charts
    return derived


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_names_the_argument(name):
    call, exc, match = CASES[name]
    with pytest.raises(exc, match=match):
        call()


def test_unknown_scene_field_is_named(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(
        'name = "x"\ntitle = "x"\ndescription = "x"\n[model]\nkind = "euler_poisson"\ninertia = [1, 2, 3]\n'
        'colour = "red"\n[initial]\nomega = [1, 0, 0]\n[run]\nt = 1\nmethods = [{ method = "taylor" }]\n'
    )
    with pytest.raises(SceneError, match="`model.colour`"):
        load_scene(str(p))


def test_nonphysical_inertia_warns_and_is_documented():
    """Moments violating I1 + I2 >= I3 describe no body: integrated anyway, with a warning (documented)."""
    with pytest.warns(UserWarning, match="triangle inequality"):
        ls.EulerPoisson((1, 1, 5))
    assert "triangle inequality" in ls.EulerPoisson.__doc__


SMALL_CASES = {
    # the documented range 1e-4000 .. 1e4000 holds exactly (the estimate from bit lengths let 1e-4001 through)
    "inertia 1e-4001": (lambda: ls.EulerPoisson(("1e-4001", 1, 1)), ValueError, r"`inertia\[0\]`.*out of range"),
    # within the input range but not the model's (it works in double): refused naming inertia, not OverflowError
    "inertia 1e400": (lambda: ls.EulerPoisson(inertia=("1e400",) * 3), ValueError, "`inertia` entries must lie"),
    # an overflow of a derived runtime parameter names the argument it came from
    "damping 1e400 in double": (lambda: ls.integrate(ls.DampedEulerPoisson((1, 2, 3), damping="1e400"), Y0, t=1),
                                ValueError, r"`damping` gives the runtime parameter 'damping'.*overflows double"),
    "mass 1e-320 in double": (lambda: ls.integrate(ls.SphereDirac(mass="1e-320"),
                                                   ls.SphereDirac().initial_state((1, 0, 0), (0, 1, 0)), t=1),
                              ValueError, r"`mass` gives the runtime parameter 'inv_mass'"),
    # a 100000-digit string: the argument and lieseries' own limit, not Python's int-string limit
    "100000 digits": (lambda: ls.EulerPoisson(("1" * 100_000, 2, 3)), ValueError,
                      r"`inertia\[0\]` is written with 100000 digits.*at most 20000 digits"),
    "saddle_rate momentum True": (lambda: BODY.saddle_rate(True), TypeError, "`momentum`"),
    "progress not callable": (lambda: ls.integrate(BODY, Y0, t=1, progress=3), TypeError, r"`progress`.*True"),
    "sphere edge beyond 1/sqrt(3)": (lambda: ls.Sphere(edge="0.6"), ValueError, r"`edge`.*1/sqrt\(3\)"),
}


@pytest.mark.parametrize("name", sorted(SMALL_CASES))
def test_more_bad_input_names_the_argument(name):
    call, exc, match = SMALL_CASES[name]
    with pytest.raises(exc, match=match):
        call()


def test_long_decimal_strings_within_the_limit_are_read_exactly():
    from fractions import Fraction

    text = "0." + "3" * 6000  # beyond Python's 4300-digit int-string limit, within lieseries' 20000
    assert ls.precision.to_fraction(text) == Fraction(int("3" * 4000) * 10**2000 + int("3" * 2000), 10**6000)
    assert ls.precision.to_fraction("1e-4000") == Fraction(1, 10**4000)


def test_progress_true_shows_a_bar_and_edge_strings_are_read():
    sol = ls.integrate(BODY, Y0, t=1, progress=True)
    assert sol.success
    assert ls.lie_integrate(BODY, BODY.initial_state((1, "0.1", "0.5")), t="0.5", dps=20, progress=True).success
    assert ls.Sphere(edge="0.1").edge == 0.1


def test_mixed_precision_real_state_warns_naming_the_entry():
    import heyoka as hy

    y = np.array([hy.real(v, 100) for v in (1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 0)] + [hy.real("0.1", 200)],
                 dtype=hy.real)
    with pytest.warns(ls.PrecisionWarning, match=r"`y0\[11\]` is a 200-bit heyoka.real but `y0\[0\]` has 100 bits"):
        ls.integrate(BODY, y, t="0.1")


def test_fast_motion_is_not_called_only_stiff():
    """Moments 1e-4 : 1 : 1e4 (no physical body) give a rotation 1e8 times faster than the run: the message says
    that a time scale far shorter than the run is one explanation, not that the problem is stiff."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        body = ls.EulerPoisson(("1e-4", 1, "1e4"))
    sol = ls.integrate(body, body.initial_state((1, 1, 1)), t=1)
    assert sol.status == "step_collapse"
    assert "The problem is stiff" not in sol.message and "time scale far shorter than the run" in sol.message


def test_bools_are_not_numbers_of_digits_or_momenta():
    with pytest.raises(TypeError, match="`dps`"):
        studies.observables(BODY, Y0, True)
    with pytest.raises(TypeError, match="`momentum`"):
        BODY.saddle_rate(True)


PENDULUM_CASES = {
    "SphericalPendulum: negative length": (lambda: ls.SphericalPendulum(length=-1), ValueError, "`length`"),
    "SphericalPendulum: NaN mass": (lambda: ls.SphericalPendulum(mass=float("nan")), ValueError, "`mass`"),
    "PlanarPendulum: infinite g": (lambda: ls.PlanarPendulum(g=float("inf")), ValueError, "`g`"),
    "DoubleSphericalPendulum: zero m2": (lambda: ls.DoubleSphericalPendulum(m2=0), ValueError, "`m2`"),
    "EllipsoidGeodesic: negative axis": (lambda: ls.EllipsoidGeodesic(axes=(1, 2, "-3")), ValueError,
                                         r"`axes\[2\]`"),
    "EllipsoidGeodesic: two axes": (lambda: ls.EllipsoidGeodesic(axes=(1, 2)), ValueError, "`axes`"),
    "SphericalPendulum: point off the sphere": (
        lambda: ls.SphericalPendulum(length=2).initial_state(q=("0.6", 0, "-0.8"), qdot=(0, 1, 0)), ValueError,
        "`q` is not on the constraint surface"),
}


@pytest.mark.parametrize("name", sorted(PENDULUM_CASES))
def test_bad_pendulum_input_names_the_argument(name):
    call, exc, match = PENDULUM_CASES[name]
    with pytest.raises(exc, match=match):
        call()


# R0 must be a rotation to the precision its data carry: exactly for exact input, ~16 ulps for binary numbers
_OFF = [["0.6", "0.8", 0], ["-0.8", "0.6000000000001", 0], [0, 0, 1]]  # |R R^T - 1| = 1.2e-13
R0_CASES = {
    "R0 exact, 1.2e-13 off": (lambda: BODY.initial_state((1, 0, 0), R0=_OFF), ValueError,
                              r"`R0` must be a rotation matrix: max \|R0 R0\^T - 1\| = 1.2e-13 and det R0 = 1.0000"),
    "R0 doubles, 1e-13 off": (lambda: BODY.initial_state((1, 0, 0), R0=np.diag([1, 1, 1 + 1e-13])), ValueError,
                              r"`R0`.*precision allows 1.8e-15"),
    "R0 exact, 1.2e-13 off, rounded to 200 bits": (lambda: BODY.initial_state((1, 0, 0), R0=_OFF, precision=200),
                                                   ValueError, "`R0` must be a rotation"),
    "HeavyTop R0 exact, 1.2e-13 off": (lambda: ls.HeavyTop((1, 2, 3), (0, 0, 1), 1, 1).initial_state((1, 0, 0),
                                                                                                       R0=_OFF),
                                       ValueError, "`R0` must be a rotation"),
    "R0 a reflection": (lambda: BODY.initial_state((1, 0, 0), R0=[[0, 1, 0], [1, 0, 0], [0, 0, 1]]), ValueError,
                        r"`R0` must be a proper rotation.*det R0 = -1"),
}


@pytest.mark.parametrize("name", sorted(R0_CASES))
def test_r0_that_is_not_a_rotation_is_refused(name):
    call, exc, match = R0_CASES[name]
    with pytest.raises(exc, match=match):
        call()


def test_r0_rotations_are_accepted_to_their_precision():
    import math

    c, s = math.cos(0.3), math.sin(0.3)
    for R0, precision in [([[0, -1, 0], [1, 0, 0], [0, 0, 1]], None),
                          ([["0.6", "0.8", 0], ["-0.8", "0.6", 0], [0, 0, 1]], None),
                          ([[c, -s, 0], [s, c, 0], [0, 0, 1]], None),  # doubles: their own 53 bits
                          (_OFF, 32)]:  # rounded to 32 bits, the 1.2e-13 residual is within the format
        y = BODY.initial_state((1, 0, 0), R0=R0, precision=precision)
        assert BODY.rotation(np.asarray(y, dtype=float)).shape == (3, 3)


def test_raw_state_whose_r_is_not_a_rotation_warns_naming_y0():
    raw = [1, 0, 0, 0, 2, 0, 0, 0, 1, 1, "0.1", "0.5"]
    for run in (lambda: ls.integrate(BODY, raw, t="0.1"), lambda: ls.lie_integrate(BODY, raw, t="0.1", dps=20)):
        with pytest.warns(UserWarning, match=r"`y0` holds an R that is not a rotation: max \|R R\^T - 1\| = 3, det R = 2"):
            run()
    ens = np.tile(np.asarray(Y0, dtype=float), (3, 1))
    ens[1, 4] = 2
    with pytest.warns(UserWarning, match=r"`Y0\[1\]` holds an R that is not a rotation"):
        ls.integrate(BODY, ens, t="0.1")


def test_r0_with_huge_entries_is_refused_naming_it():
    """An entry of 1e200 made the refusal's own message fail (OverflowError from float of R0 R0^T - 1 = 1e400)."""
    with pytest.raises(ValueError, match=r"`R0` must be a rotation matrix: max \|R0 R0\^T - 1\| = 1\.00e\+400"):
        BODY.initial_state((1, 0, 0), R0=[[1e200, 0, 0], [0, 1, 0], [0, 0, 1]])


def test_float32_rotation_is_binary_data_of_24_bits():
    """A float32 rotation carries 24 bits: accepted within 16 units of its last place (it was read as exact and
    refused, its 5e-8 residual compared with 0), and reported as 24-bit data when a run works with more."""
    import math

    c, s = math.cos(0.3), math.sin(0.3)
    R32 = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32)
    rr = R32.astype(float) @ R32.astype(float).T - np.eye(3)
    assert 1e-9 < np.max(np.abs(rr)) < 16 * 2.0 ** -24  # not a rotation in binary, one to float32's precision
    y = BODY.initial_state((1, 0, 0), R0=R32)
    with pytest.warns(ls.PrecisionWarning, match=r"carries only 24 bits"):
        ls.integrate(BODY, y, t="0.1")
