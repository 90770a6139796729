"""Certified enclosures (Arb balls): they contain the exact solution, they are not vacuous, and they fail loudly.

Every containment is checked exactly: the reference (closed form at many more digits) is turned into an exact
rational and asked to lie in the ball. A reference moved by a little more than the ball's radius must not lie in it.
"""

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from fractions import Fraction

import flint
import heyoka as hy
import mpmath as mp
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.balls import contains
from lieseries.precision import to_fraction
from lieseries.validated import certified_digits, radii, validated_integrate, working_precision
from problems import RIGID_INERTIA, RIGID_OMEGA



def inside(ball, value) -> bool:
    """The real number ``value`` (any exact or mpf number) lies in ``ball``, decided exactly."""
    q = to_fraction(value)
    # exact, or far narrower than any enclosure here
    with working_precision(max(512, 64 + q.numerator.bit_length() + q.denominator.bit_length())):
        return ball.contains(flint.arb(flint.fmpq(q.numerator, q.denominator)))


def test_rigid_body_enclosures_contain_the_closed_form(bigint):
    body = ls.EulerPoisson(RIGID_INERTIA)
    times = [Fraction(k, 4) for k in range(1, 9)]
    sol = validated_integrate(body, body.initial_state(omega=RIGID_OMEGA), t=times, dps=30)
    assert sol.status == "success", sol.message
    refs = exact.euler_poisson_many(RIGID_INERTIA, RIGID_OMEGA, times, dps=70)
    assert all(inside(b, v) for row, ref in zip(sol.y, refs) for b, v in zip(row, ref))
    # not vacuous: the balls are far narrower than the coefficients' size, and a slightly wrong value is outside
    assert max(radii(sol)[-1]) < 1e-24 and min(certified_digits(sol)) > 24
    r = sol.y[-1][10].rad()
    assert not inside(sol.y[-1][10], refs[-1][10] + 4 * mp.mpf(float(r)))
    # R^T R = 1 is certified within the enclosure's own width: the ball of R^T R - 1 contains 0
    R = [[sol.y[-1][3 * i + j] for j in range(3)] for i in range(3)]
    with working_precision(200):
        for i in range(3):
            for j in range(3):
                e = sum(R[k][i] * R[k][j] for k in range(3)) - (1 if i == j else 0)
                assert e.contains(flint.arb(0)) and e.rad() < 1e-22


def test_uncertain_initial_data_enclose_every_solution_from_the_box():
    body = ls.EulerPoisson(RIGID_INERTIA)
    exact_y0 = list(body.initial_state(omega=RIGID_OMEGA).exact)
    rad = Fraction(1, 10**12)
    y0 = exact_y0[:9] + [(m, rad) for m in exact_y0[9:]]  # M known to 1e-12
    sol = validated_integrate(body, y0, t=[Fraction(1, 2), Fraction(1)], dps=30)
    assert sol.status == "success"
    assert 1e-13 < max(radii(sol)[-1]) < 1e-9  # the uncertainty, propagated, not the arithmetic's 1e-30
    for dM in ([rad, -rad, rad], [-rad, rad, 0], [0, 0, -rad]):
        omega = [(exact_y0[9 + i] + dM[i]) / RIGID_INERTIA[i] for i in range(3)]
        for tk, row in zip([Fraction(1, 2), Fraction(1)], sol.y):
            ref = exact.euler_poisson(RIGID_INERTIA, omega, tk, dps=40)
            assert all(inside(b, v) for b, v in zip(row, ref))


def test_a_blow_up_is_validation_failed_and_what_was_proved_stays_true():
    """dq/dt = q^2 from q = 1: q = 1 / (1 - t) blows up at t = 1; no enclosure can pass it."""
    q, p = hy.make_vars("q", "p")
    sys_ = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * q**2, name="blow-up")
    times = [Fraction(1, 4), Fraction(1, 2), Fraction(3, 2)]
    sol = validated_integrate(sys_, [1, 0], t=times, dps=20)
    assert sol.status == "validation_failed" and "t = " in sol.message
    assert float(sol.t_reached) < 1
    for tk, row in zip(sol.t, sol.y):
        assert inside(row[0], 1 / (1 - to_fraction(tk)))  # q(t) = 1 / (1 - t), exactly


def test_bad_input_is_named():
    body = ls.EulerPoisson(RIGID_INERTIA)
    y0 = body.initial_state(omega=RIGID_OMEGA)
    with pytest.raises(ValueError, match="`dps`"):
        validated_integrate(body, y0, t=1, dps=3)
    with pytest.raises(ValueError, match=r"`y0\[9\]` radius"):
        validated_integrate(body, list(y0.exact[:9]) + [(1, -1), 0, 0], t=1)
    with pytest.raises(ValueError, match="`y0`"):
        validated_integrate(body, [1, 2], t=1)
    with pytest.raises(ValueError, match="`y0` must be a sequence"):
        validated_integrate(body, 5, t=1)


def test_binary_data_in_a_longer_run_warn_by_name():
    """0.2 as a double is enclosed at its binary value; at 30 digits that is not the decimal meant: say so."""
    body = ls.EulerPoisson(RIGID_INERTIA)
    with pytest.warns(ls.PrecisionWarning, match="`y0`"):
        validated_integrate(body, [1, 0, 0, 0, 1, 0, 0, 0, 1, 1.0, 0.2, 1.5], t=Fraction(1, 4), dps=30)
    tilted = ls.EulerPoisson((1.1, 2, 3))
    with pytest.warns(ls.PrecisionWarning, match="`inertia`"):
        validated_integrate(tilted, tilted.initial_state(omega=RIGID_OMEGA), t=Fraction(1, 4), dps=30)


def great_circle(tk):
    """x(t) = (0.6 cos t, sin t, 0.8 cos t): the great circle of the sphere tests, at 40 digits."""
    q = to_fraction(tk)
    with mp.workdps(40):
        t = mp.mpf(q.numerator) / q.denominator
        return [mp.mpf("0.6") * mp.cos(t), mp.sin(t), mp.mpf("0.8") * mp.cos(t)]


def test_sphere_chart_encloses_the_great_circle_and_stops_before_its_edge():
    """In one chart (``atlas=False``) the run stops where the chart x3 != 0 ends: 0.8 cos t = 0.05."""
    s = ls.Sphere(atlas=False)
    y0 = s.initial_state(("0.6", "0", "0.8"), ("0", "1", "0"))
    # order 12, not the default 19: the steps shorten near the edge either way, at two thirds of the cost
    sol = validated_integrate(s, y0, t=[Fraction(1, 2), Fraction(1), Fraction(8, 5)], dps=15, order=12)
    assert sol.status == "chart_edge" and "x3" in sol.message
    edge = mp.acos(mp.mpf(1) / 16)
    reached = mp.mpf(sol.t_reached.numerator) / sol.t_reached.denominator
    assert edge - mp.mpf("1e-3") < reached <= edge
    assert len(sol.t) == 2  # t = 1.6 lies beyond the edge: never claimed
    for tk, row in zip(sol.t, sol.y):
        assert all(inside(b, v) for b, v in zip(row[:3], great_circle(tk)))
    assert max(radii(sol)[-1]) < 1e-10


def test_sphere_across_the_atlas_encloses_the_great_circle():
    """By default a Sphere switches charts (the chart map evaluated on balls) and the enclosures go on."""
    s = ls.Sphere()
    y0 = s.initial_state(("0.6", "0", "0.8"), ("0", "1", "0"))
    times = [Fraction(1), Fraction(2)]
    sol = validated_integrate(s, y0, t=times, dps=15)
    assert sol.status == "success" and sol.stats.extra["chart_switches"] >= 1, sol.message
    # |x3| = 0.8 cos t falls to |x| / 2 at t = 0.90, where x2 = sin t is the largest coordinate
    assert list(sol.charts) == [1, 1] and sol.chart_reached == 1
    for tk, row in zip(times, sol.y):
        assert all(inside(b, v) for b, v in zip(row[:3], great_circle(tk)))  # x is x in every chart
    assert min(certified_digits(sol)) > 8


@pytest.mark.parametrize("inertia, omega", [
    ((1, 2, 3), ("0.001", 1, "0.001")),  # near the separatrix: close to the unstable rotation about axis 2
    ([[2, "1/2", 0], ["1/2", 3, "1/4"], [0, "1/4", 4]], (1, "0.1", "0.5")),  # a full inertia tensor
])
def test_hard_rigid_bodies_are_enclosed(bigint, inertia, omega):
    body = ls.EulerPoisson(inertia)
    times = [Fraction(1), Fraction(2)]
    sol = validated_integrate(body, body.initial_state(omega=omega), t=times, dps=20)
    assert sol.status == "success", sol.message
    refs = exact.euler_poisson_many(inertia, omega, times, dps=50)
    assert all(inside(b, v) for row, ref in zip(sol.y, refs) for b, v in zip(row, ref))
    assert min(certified_digits(sol)) > 15


def test_an_operation_without_a_ball_version_is_refused_by_name():
    q, p = hy.make_vars("q", "p")
    sys_ = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + q * hy.erf(q), name="erf")
    with pytest.raises(NotImplementedError, match="`erf`"):
        validated_integrate(sys_, [1, 0], t=1)


def test_validated_is_a_method_of_the_registry():
    """``{"method": "validated"}`` in studies and scenes: midpoints as states, certified digits in ``extra``."""
    from lieseries.methods import run_method
    from problems import rigid_error

    body = ls.EulerPoisson(RIGID_INERTIA)
    run = run_method(body, body.initial_state(omega=RIGID_OMEGA), 1, {"method": "validated", "dps": 20})
    assert run.status == "success" and run.label == "validated (Arb) 20 dps"
    digits = run.extra["certified_digits"][-1]
    assert digits > 15
    # the midpoint is within the certified radius (relative to max(1, |z|) <= 2) of the closed form
    assert rigid_error(run.y_final, 1, dps=50) <= 2 * 10.0 ** -digits


def test_a_scene_reports_the_invariant_drift_of_a_validated_run_at_its_own_digits(tmp_path):
    """The drift of a 60-digit validated run is measured on its states at 60 digits, not on states rounded to 40
    (which reported the rounding, 1e-51, for a run whose error against the closed form is 1e-70)."""
    from lieseries.run import run_scene
    from lieseries.scenes import load_scene

    path = tmp_path / "v60.toml"
    path.write_text('name = "v60"\ntitle = "validated at 60 digits"\n[model]\nkind = "euler_poisson"\n'
                    'inertia = [1, 2, 3]\n[initial]\nomega = [1, "0.1", "0.5"]\n[run]\nt = "0.5"\nsamples = 2\n'
                    'repeat = 1\n'
                    'methods = [{ method = "validated", dps = 60 }]\n')
    result = run_scene(load_scene(str(path)), progress=False)
    row = result.run["rows"][0]
    assert row.status == "success" and row.error < 1e-55  # against the closed form
    drifts = [d for d in row.drift.values() if d is not None]
    assert drifts and max(drifts) < 1e-55


@pytest.mark.parametrize("h", ["9/20", "1/2"])
def test_a_step_remainder_bound_is_close_to_the_true_truncation_error(h):
    """One step of order 59 (t below the step the run would choose, so the run takes exactly one step): the bound
    on the centre's solution minus its Taylor polynomial is at least the true difference (closed form minus the
    order-59 polynomial, both at 90 digits) and at most 10 times it -- a looser bound would shorten every step."""
    body = ls.EulerPoisson(RIGID_INERTIA)
    y0 = body.initial_state(omega=RIGID_OMEGA)
    sol = validated_integrate(body, y0, t=h, dps=40, order=59)
    assert sol.status == "success" and sol.stats.steps == 1
    bound = sol.stats.extra["tail_bounds"][0]
    ctx = mp.MPContext()
    ctx.dps = 90
    coeffs = ls.lie.taylor_coefficients(body.poisson.program, list(y0.exact), list(body.poisson.parameter_values),
                                        59, 90, ctx=ctx)
    hq = ctx.mpf(Fraction(h).numerator) / Fraction(h).denominator
    ref = exact.euler_poisson(RIGID_INERTIA, RIGID_OMEGA, h, dps=90)
    true = max(abs(ctx.mpf(r) - sum(c[i] * hq**k for k, c in enumerate(coeffs))) for i, r in enumerate(ref))
    assert true <= bound <= 10 * true


def test_more_digits_than_a_float_can_hold_are_certified_and_counted():
    """At 330 digits the step tolerance, the radii and the certified digits lie below a float's range (1e-308):
    the oscillator's balls contain (cos t, -sin t) at 400 digits, their float radii stay upper bounds (not 0), and
    the digits are counted from the balls (not capped at 300)."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p * p + q * q) / 2, name="oscillator")
    sol = validated_integrate(osc, [1, 0], t="1/2", dps=330)
    assert sol.status == "success", sol.message
    ctx = mp.MPContext()
    ctx.dps = 400
    half = ctx.mpf(1) / 2
    assert inside(sol.y[-1][0], ctx.cos(half)) and inside(sol.y[-1][1], -ctx.sin(half))
    assert 320 < certified_digits(sol)[-1] < 345
    assert all(r > 0 for r in radii(sol)[-1])


@pytest.mark.parametrize("order", [1, 2])
def test_very_low_orders_run_and_stay_proven(order):
    """Orders below 13 (an earlier a priori box's) once stopped on an internal assertion (the series length cap):
    they run, with short steps, and what they prove contains the oscillator's (cos t, -sin t)."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p * p + q * q) / 2, name="oscillator")
    sol = validated_integrate(osc, [1, 0], t=["1/100000000", "1/100"], dps=15, order=order, max_steps=60)
    assert sol.status == "step_budget" and len(sol.t) == 1
    ctx = mp.MPContext()
    ctx.dps = 40
    tk = ctx.mpf(1) / 100000000
    assert inside(sol.y[0][0], ctx.cos(tk)) and inside(sol.y[0][1], -ctx.sin(tk))


# -- singular fields: the run ends with validation_failed and keeps what it proved ----------------------------------
def _canonical(variables, hamiltonian, name):
    n = len(variables) // 2
    tensor = [[(1 if j == i + n else -1 if i == j + n else 0) for j in range(2 * n)] for i in range(2 * n)]
    return ls.PoissonSystem(variables, tensor, hamiltonian, name=name)


def _root_closed_form(t, ctx):
    """H = p^2/2 + sqrt(q) from (q, p) = (1, 0): with s = sqrt(1 - sqrt(q)), t = sqrt(2) (2 s - 2 s^3 / 3), so
    q = (1 - s^2)^2, p = -sqrt(2) s, until q reaches 0 (the field's singularity) at t = 4 sqrt(2) / 3."""
    t = ctx.mpf(t.numerator) / t.denominator
    s = ctx.findroot(lambda s: ctx.sqrt(2) * (2 * s - 2 * s**3 / 3) - t, (ctx.mpf(0), ctx.mpf(1)),
                     solver="anderson")
    return [(1 - s**2) ** 2, -ctx.sqrt(2) * s]


def test_a_root_field_reaching_its_branch_point_ends_as_validation_failed_with_the_rows_proved():
    q, p = hy.make_vars("q", "p")
    system = _canonical([q, p], p**2 / 2 + hy.sqrt(q), "root potential")
    times = [Fraction(k, 4) for k in range(1, 11)]  # q reaches 0 at t = 4 sqrt(2) / 3 = 1.8856...
    # order 20, not the default 36: the steps shrink onto the branch point either way, at half the cost
    sol = validated_integrate(system, ["1", "0"], times, dps=30, order=20)
    assert sol.status == "validation_failed" and "t = 1.88" in sol.message and "singular" in sol.message
    assert len(sol.t) == 7 and float(sol.t_reached) < 4 * 2**0.5 / 3
    ctx = mp.MPContext()
    ctx.dps = 60
    for tk, row in zip(times, sol.y):
        assert all(inside(b, v) for b, v in zip(row, _root_closed_form(tk, ctx)))
    assert max(radii(sol)[-1]) < 1e-14


def _kepler_closed_form(t, ctx):
    """Kepler's problem from (q, p) = (1, 0, 0, 1/10), the apocentre of the orbit with a = 100/199, e = 99/100 (the
    energy is -199/200, the angular momentum 1/10): Kepler's equation E - e sin E = pi + n t, n = a^(-3/2),
    turned by pi (the apocentre on the positive q1 axis)."""
    a, e = ctx.mpf(100) / 199, ctx.mpf(99) / 100
    n = a ** ctx.mpf(-1.5)
    M = ctx.pi + n * (ctx.mpf(t.numerator) / t.denominator)
    E = ctx.findroot(lambda E: E - e * ctx.sin(E) - M, M)
    b = a * ctx.sqrt(1 - e**2)
    dE = n / (1 - e * ctx.cos(E))
    return [-a * (ctx.cos(E) - e), -b * ctx.sin(E), a * ctx.sin(E) * dE, -b * ctx.cos(E) * dE]


@pytest.mark.slow
def test_kepler_near_collision_ends_with_a_status_and_every_row_it_gives_is_proved():
    """Through the pericentre (r = 1/199) the enclosures either pass (every row) or the run ends as
    ``validation_failed`` with the rows proved before it (it once raised flint's ValueError there); what it gives
    is contained in the closed form either way."""
    q1, q2, p1, p2 = hy.make_vars("q1", "q2", "p1", "p2")
    system = _canonical([q1, q2, p1, p2], (p1**2 + p2**2) / 2 - 1 / hy.sqrt(q1**2 + q2**2), "kepler")
    times = [Fraction(k, 4) for k in range(1, 13)]  # pericentre (r = 1/199) at half the period, t = 1.119...
    sol = validated_integrate(system, ["1", "0", "0", "0.1"], times, dps=30)
    if sol.status == "success":
        assert len(sol.t) == 12
    else:
        assert sol.status == "validation_failed" and "Validation failed at t = " in sol.message
        assert 4 <= len(sol.t) < 12
    ctx = mp.MPContext()
    ctx.dps = 60
    for tk, row in zip(times, sol.y):
        assert all(inside(b, v) for b, v in zip(row, _kepler_closed_form(tk, ctx)))


def test_initial_data_at_a_pole_are_refused_by_name():
    q, p = hy.make_vars("q", "p")
    with pytest.raises(ValueError, match=r"`y0` .* singular point"):
        validated_integrate(_canonical([q, p], p**2 / 2 + 1 / q, "pole"), ["0", "1"], 1, dps=20)
    with pytest.raises(ValueError, match=r"`y0` .* singular point"):
        validated_integrate(_canonical([q, p], p**2 / 2 + hy.sqrt(q), "root"), ["0", "1"], 1, dps=20)


def test_the_shortest_step_is_a_time_not_a_state_size():
    # a large state (10^15) moving on a time scale of 1: steps of ~1 are right, whatever the state's size
    q, p = hy.make_vars("q", "p")
    osc = _canonical([q, p], (p**2 + q**2) / 2, "oscillator")
    times = [Fraction(1, 2), Fraction(2)]
    sol = validated_integrate(osc, [10**15, 0], times, dps=20)
    assert sol.status == "success", sol.message
    ctx = mp.MPContext()
    ctx.dps = 60
    for tk, row in zip(times, sol.y):
        tt = ctx.mpf(tk.numerator) / tk.denominator
        assert inside(row[0], 10**15 * ctx.cos(tt)) and inside(row[1], -(10**15) * ctx.sin(tt))
    assert max(radii(sol)[-1]) < 1e-3


def _same_ball(a, b) -> bool:
    """b is a: the same midpoint, exactly, and the same radius -- or, where python-flint's constructor cannot set
    a radius whose 30-bit mantissa is odd (it rounds it up by one unit), one unit of the radius's 30th bit more:
    b then contains a."""
    if not a.is_finite():
        return str(a) == str(b)
    if a.mid().man_exp() != b.mid().man_exp():
        return False
    ra, rb = a.rad(), b.rad()
    return ra.man_exp() == rb.man_exp() or (b.contains(a) and rb <= ra * (1 + flint.arb(2) ** -28))


@pytest.mark.parametrize("kind", ["body", "sphere"])
def test_a_validated_solution_pickles_with_every_ball_identical(kind):
    import pickle

    if kind == "body":
        system = ls.EulerPoisson(RIGID_INERTIA)
        y0 = system.initial_state(omega=RIGID_OMEGA)
    else:
        system = ls.Sphere()
        y0 = system.initial_state(("0.6", 0, "0.8"), (0, 1, 0))
    sol = validated_integrate(system, y0, t=[Fraction(1, 4), Fraction(1, 2)], dps=40)
    assert sol.status == "success", sol.message
    with working_precision(53):  # unpickling does not depend on the working precision
        back = pickle.loads(pickle.dumps(sol))
    assert back.status == sol.status and list(back.t) == list(sol.t)
    assert all(_same_ball(a, b) for ra, rb in zip(sol.y, back.y) for a, b in zip(ra, rb))
    assert all(_same_ball(a, b) for a, b in zip(sol.y_reached, back.y_reached))
    assert sol.y.shape == back.y.shape and max(radii(back)[-1]) < 1e-30


def test_a_badly_scaled_oscillator_is_enclosed_with_more_jacobian_pieces():
    # H = (p^2 + 10^4 q^2) / 2: |Df| = 10^4 in the max norm while the motion's rate is 100; with a fixed number of
    # pieces per step the Jacobian's enclosure exploded (radius 5.7e28 by t = 0.023)
    q, p = hy.make_vars("q", "p")
    osc = _canonical([q, p], (p**2 + 10000 * q**2) / 2, "fast oscillator")
    times = [Fraction(1, 8), Fraction(1, 4)]
    sol = validated_integrate(osc, [0, 1], times, dps=20)
    assert sol.status == "success", sol.message
    ctx = mp.MPContext()
    ctx.dps = 60
    for tk, row in zip(times, sol.y):
        wt = 100 * ctx.mpf(tk.numerator) / tk.denominator
        assert inside(row[0], ctx.sin(wt) / 100) and inside(row[1], ctx.cos(wt))
    assert max(radii(sol)[-1]) < 1e-15


@pytest.mark.parametrize("step", [None, "1/2", "1/4", "1/64"])
def test_centre_coefficients_match_a_jet_at_three_times_the_precision(bigint, step):
    # the centre polynomial of a step comes from the fixed-point jets (integers M with c_k = M 2^(u - s k)): every
    # coefficient, scaled by the time scale the jets hold it for (sigma^k, sigma >= the step), must agree with the
    # Taylor coefficients of an independent mpmath jet at three times the digits to the run's digits
    from lieseries.validated import centre_coefficients

    body = ls.EulerPoisson(RIGID_INERTIA)
    y0 = body.initial_state(omega=RIGID_OMEGA)
    dps, order = 30, 36
    C = centre_coefficients(body, y0, order, dps, step=step)
    ctx = mp.MPContext()
    ctx.dps = 3 * dps
    ps = body.poisson
    ref = ls.lie.taylor_coefficients(ps.program, list(y0.exact), list(ps.parameter_values), order, 3 * dps, ctx=ctx)
    # the jets' time scale: 2^(ceil(log2 step) + 1) after a step, a quarter of the radius of convergence (about 1
    # here, so at most 1) at a first step
    sigma = Fraction(1)
    if step is not None:
        q = Fraction(step)
        e = 0
        while Fraction(2) ** e < q:
            e += 1
        while Fraction(2) ** (e - 1) >= q:
            e -= 1
        sigma = Fraction(2) ** (e + 1)
    assert all(c.rad().is_zero() for row in C for c in row)
    worst = max(abs(to_fraction(C[i][k].mid()) - to_fraction(ref[k][i])) * sigma ** k
                for i in range(ps.dimension) for k in range(order + 1))
    assert worst < Fraction(1, 10 ** (dps + 5))


def test_lagrange_majorant_bounds_the_shifted_coefficient_at_every_point_of_the_step(bigint):
    # the Lagrange term of a step's defect bound needs |[f(p(xi + tau))]_L| for every xi in [0, h]: the float
    # majorant must bound it at sample points (computed exactly enough in 300-bit balls), and stay within a small
    # factor of the ball evaluation over the whole step (not vacuous)
    from lieseries import validated as V
    from lieseries import validated_step as S

    body = ls.EulerPoisson(RIGID_INERTIA)
    ps = body.poisson
    prog = ps.program
    dps, order = 30, 36
    with V.working_precision(V.dps_to_bits(dps) + V.GUARD_BITS, cap=order + 20) as fl:
        z = V._initial_balls(body, body.initial_state(omega=RIGID_OMEGA), ps.dimension, fl)
        _, prog, pars, consts, *_ = V._chart_context(body, fl)
        stepper = S.jet_stepper(ps, order, dps)
        centre, jets = S.centre_polynomial(stepper, prog, [fl.arb(v.mid()) for v in z], pars, consts, order, fl, 10)
        C = centre.unscaled()
        L = order + S.DEFECT_EXTRA
        for h in (Fraction(3, 8), Fraction(-7, 8), Fraction(1, 1000)):
            bound = S.lagrange_majorant(prog, C, jets, h, ps.parameter_values, L, fl)
            assert bound is not None
            hb = fl.arb(fl.fmpq(h.numerator, h.denominator))
            span = hb / 2 + fl.arb(0, abs(hb) / 2)
            fl.ctx.prec = 300
            for xi in (0, h / 3, h / 2, h):
                point = fl.arb(fl.fmpq(xi.numerator, xi.denominator))
                true = [row[-1] for row in S.field_series(prog, C, pars, consts, L + 1, fl, base=point)]
                assert all(abs(t).upper() <= b for t, b in zip(true, bound))
            fl.ctx.prec = 64
            balls = [row[-1] for row in S.field_series(prog, C, pars, consts, L + 1, fl, base=span)]
            assert all(b <= 100 * abs(x).upper() for b, x in zip(bound, balls))
            fl.ctx.prec = V.dps_to_bits(dps) + V.GUARD_BITS
        # a field that is not a polynomial (the sphere's charts divide) is left to the ball evaluation
        s = ls.Sphere(atlas=False)
        sprog = s.poisson.program
        assert S.lagrange_majorant(sprog, C, jets, Fraction(1, 4), s.poisson.parameter_values, L, fl) is None


def test_exact_defect_holds_the_centre_polynomials_defect(bigint):
    # a polynomial field's defect g = f(p) - p' is computed in exact rational arithmetic from the jets' integers:
    # its bound below order N must hold every |g_k| and its balls from N on must hold g_k, both against the
    # defect on 600-bit ball series; the bound below N stays within a factor 2 of the largest |g_k| (the jets'
    # rounding), far below the tolerance of a step
    from lieseries import validated as V
    from lieseries import validated_step as S

    body = ls.EulerPoisson(RIGID_INERTIA)
    ps = body.poisson
    dps, order = 30, 40
    with V.working_precision(V.dps_to_bits(dps) + V.GUARD_BITS, cap=order + 20) as fl:
        _, prog, pars, consts, *_ = V._chart_context(body, fl)
        exact = S.exact_data(ps, prog, fl)
        assert exact is not None
        assert S.exact_data(ls.Sphere(atlas=False).poisson, ls.Sphere(atlas=False).poisson.program, fl) is None
        stepper = S.jet_stepper(ps, order, dps)
        for omega in (RIGID_OMEGA, ("-0.3", "2.5", "1e-3")):
            z = V._initial_balls(body, body.initial_state(omega=omega), ps.dimension, fl)
            m = [fl.arb(v.mid()) for v in z]
            centre, jets = S.centre_polynomial(stepper, prog, m, pars, consts, order, fl, 10)
            assert jets is not None and centre.exact is not None
            lows, highs = S.defect_coefficients(prog, centre, pars, consts, fl, exact)
            per_order = S.defect_coefficients(prog, centre, pars, consts, fl, exact, fine=fl.arb(0))[0]
            saved, fl.ctx.prec = fl.ctx.prec, 600
            try:
                _, _, pars6, consts6, *_ = V._chart_context(body, fl)  # the parameters' balls at 600 bits
                ref = S.defect_coefficients(prog, centre, pars6, consts6, fl)
                full = S.field_series(prog, centre.rows, pars6, consts6, order, fl)
                for i in range(ps.dimension):
                    g_low = [abs(f - centre.rows[i][k + 1] * (k + 1) * centre.down) for k, f in enumerate(full[i])]
                    assert max(x.rad() for x in g_low) < fl.arb(2) ** -500
                    assert all(x.upper() <= lows[i] for x in g_low)
                    assert lows[i] <= 2 * max(x.upper() for x in g_low) + fl.arb(2) ** -500
                    assert lows[i] < fl.arb(10) ** -(dps + 8)
                    # the bounds per order (where one bound would not be fine enough): each holds its |g_k|
                    assert len(per_order[i]) == order and all(b <= lows[i] for b in per_order[i])
                    assert all(x.upper() <= b + fl.arb(2) ** -500 for x, b in zip(g_low, per_order[i]))
                    assert all(a.overlaps(b) for a, b in zip(highs[i], ref[1][i]))
                    assert all(a.rad() < abs(a.mid()) * 2.0 ** -50 for a in highs[i] if a.mid() != 0)
            finally:
                fl.ctx.prec = saved


def test_ball_taylor_coefficients_contain_those_from_every_point_of_the_box():
    # Picard iteration on Arb series (64 bits) encloses the Taylor coefficients from points of a box, computed at
    # 90 digits
    from lieseries import validated as V

    body = ls.EulerPoisson(RIGID_INERTIA)
    ps = body.poisson
    y0 = body.initial_state(omega=RIGID_OMEGA)
    order, dps = 14, 30
    ctx = mp.MPContext()
    ctx.dps = 90

    def reference(point):  # reference[k][i]: coefficient k of component i
        return ls.lie.taylor_coefficients(ps.program, point, list(ps.parameter_values), order, 90, ctx=ctx)

    centre = [to_fraction(v) for v in y0.exact]
    got = V.ball_taylor_coefficients(body, y0, order, dps)
    assert all(inside(got[i][k], c) for k, cs in enumerate(reference(centre)) for i, c in enumerate(cs))
    delta = Fraction(1, 10**20)
    points = [centre, [c + delta for c in centre], [c - delta for c in centre]]
    points += [[c + (delta if j == i else 0) for j, c in enumerate(centre)] for i in range(0, len(centre), 3)]
    with V.working_precision(V.dps_to_bits(dps) + V.GUARD_BITS, cap=order + 20) as fl:
        z = [fl.arb(fl.fmpq(c.numerator, c.denominator)) + fl.arb(0, fl.arb(fl.fmpq(1, 10**20))) for c in centre]
        _, prog, pars, consts, *_ = V._chart_context(body, fl)
        balls = V.taylor_coefficients(prog, z, pars, consts, order, fl, bits=64)
        assert all(len(row) == order + 1 for row in balls)
        for point in points:
            ref = reference(point)
            assert all(inside(balls[i][k], ref[k][i]) for k in range(order + 1) for i in range(len(centre)))
        # not vacuous: 64-bit balls
        assert max(float(b.rad()) for row in balls for b in row) < 1e-10


def test_the_remainder_factor_exp_times_bounds_the_matrix_exponential_from_above():
    # exp(|tau| L) G in each step's remainder bound, summed by matrix-vector products with a bounded tail: at
    # least the exact value (a 300-bit matrix exponential) and within a part in 10^9 of it
    import random

    from lieseries import validated as V
    from lieseries import validated_step as S

    rng = random.Random(7)
    n = 12
    with V.working_precision(64) as fl:
        for scale in (0.01, 0.5, 1, 3, 10, 40):
            M = fl.arb_mat([[fl.arb(rng.random() * scale / n) for _ in range(n)] for _ in range(n)])
            g = fl.arb_mat([[fl.arb(rng.random())] for _ in range(n)])
            got = [S.exp_times(M, g, fl)[i, 0].upper() for i in range(n)]
            fl.ctx.prec = 300
            exact = fl.arb_mat([[M[i, j] for j in range(n)] for i in range(n)]).exp() * g
            assert all(b >= exact[i, 0].upper() for i, b in enumerate(got))
            assert all(b <= exact[i, 0].lower() * (1 + fl.arb(10) ** -9) for i, b in enumerate(got))
            fl.ctx.prec = 64


def test_the_flow_jacobian_of_a_step_holds_the_flows_jacobian(monkeypatch):
    # the Jacobian of the flow over a step, which moves the set by the mean-value theorem: for the rigid body, whose
    # Df is affine in the state, each piece's first term comes from the mean of the solutions over the piece; the
    # enclosure must hold D phi_tau(y0) from central differences of 60-digit lie_integrate runs (errors near 1e-40,
    # far below its radii), and be narrower than the enclosure without that term over as many pieces
    from lieseries import validated as V
    from lieseries import validated_step as S

    body = ls.EulerPoisson(RIGID_INERTIA)
    y0 = body.initial_state(omega=RIGID_OMEGA)
    assert S.affine_in_state(S.jacobian_program(body.poisson))
    assert not S.affine_in_state(S.jacobian_program(ls.Sphere(atlas=False).poisson))
    got = []

    def spy(jprog, centre, reach, L, pars, consts, tau, fl, pieces):
        J = S.flow_jacobian(jprog, centre, reach, L, pars, consts, tau, fl, pieces)
        if not got:
            with monkeypatch.context() as m:
                m.setattr(S, "affine_in_state", lambda prog: False)
                generic = S.flow_jacobian(jprog, centre, reach, L, pars, consts, tau, fl, pieces)
            got.append((to_fraction(tau.mid()), pieces, J, generic))
        return J

    monkeypatch.setattr(V, "flow_jacobian", spy)
    sol = validated_integrate(body, y0, t=1, dps=30)
    assert sol.status == "success", sol.message
    tau, pieces, J, generic = got[0]
    assert pieces == S.AFFINE_JACOBIAN_PIECES and 0 < tau <= 1
    n = body.poisson.dimension
    delta = Fraction(1, 10**20)
    cols = []
    for j in range(n):
        ends = []
        for sign in (1, -1):
            y = list(y0.exact)
            y[j] += sign * delta
            ends.append(ls.lie_integrate(body.poisson, y, t=tau, dps=60).y[-1])
        cols.append([(to_fraction(a) - to_fraction(b)) / (2 * delta) for a, b in zip(*ends)])
    assert all(inside(J[i, j], cols[j][i]) for i in range(n) for j in range(n))
    widest = max(float(J[i, j].rad()) for i in range(n) for j in range(n))
    assert 0 < widest < 1e-2
    assert widest < max(float(generic[i, j].rad()) for i in range(n) for j in range(n)) / 2


def test_backward_runs_enclose_the_closed_form_from_exact_and_uncertain_data():
    # the a priori enclosure and the Jacobian's pieces for negative steps (the ball [h, 0], pieces towards -h)
    body = ls.EulerPoisson(RIGID_INERTIA)
    y0 = body.initial_state(omega=RIGID_OMEGA)
    times = [Fraction(-k, 2) for k in range(1, 7)]
    refs = exact.euler_poisson_many(RIGID_INERTIA, RIGID_OMEGA, times, dps=60)
    for data in (y0, [(q, abs(q) / 2**40) for q in y0.exact]):
        sol = validated_integrate(body, data, t=times, dps=30)
        assert sol.status == "success", sol.message
        assert all(inside(b, v) for row, ref in zip(sol.y, refs) for b, v in zip(row, ref))
        assert max(radii(sol)[-1]) < (1e-25 if data is y0 else 1e-9)


def test_a_piece_of_the_flow_jacobian_holds_its_exact_matrix_when_mu_exceeds_three(monkeypatch):
    # the Peano-Baker tail bound mu^(K+1) / (K+1)! / (1 - mu / (K+2)) holds only for mu < K + 2: past 1024 pieces
    # (|tau| ||Df|| > 3072) mu may reach 12, and a K chosen for mu > K + 2 made the quotient negative (for mu = 9,
    # K = 1 with a "tail" of 20.3, where the piece's term (tau A)^3 / 6 is 121.5). One piece of a linear chain
    # (q2' = 9 q1, q1' = 9 p1, p1' = -9 p2: Df constant and nilpotent) must hold exp(tau A) exactly
    from lieseries import validated_step as S
    from lieseries.ball_series import ball_constant, working_precision

    q1, q2, p1, p2 = hy.make_vars("q1", "q2", "p1", "p2")
    tensor = [[0, 0, 1, 0], [0, 0, 0, 1], [-1, 0, 0, 0], [0, -1, 0, 0]]
    chain = ls.PoissonSystem([q1, q2, p1, p2], tensor, 9 * p1**2 / 2 + 9 * q1 * p2, name="chain")
    jprog = S.jacobian_program(chain)
    A = [[0, 0, 9, 0], [9, 0, 0, 0], [0, 0, 0, -9], [0, 0, 0, 0]]  # d(q1', q2', p1', p2') / d(q1, q2, p1, p2)
    monkeypatch.setattr(S, "MAX_JACOBIAN_PIECES", 1)  # one piece with mu = 9, as a piece of 1024 with mu = 9
    with working_precision(128, cap=20) as fl:
        n, arb = 4, fl.arb
        centre = S.Centre([fl.arb_poly([0])] * n, [arb(0)] * n, 0, 1, fl)  # every solution from 0 stays at 0
        L = fl.arb_mat([[abs(x) for x in row] for row in A])
        consts = [(slot, ball_constant(c, fl)) for slot, c in jprog.constants]
        J = S.flow_jacobian(jprog, centre, lambda tau: [arb(0)] * n, L, [], consts, arb(1), fl, pieces=1)
        exact = fl.arb_mat(A).exp()  # I + A + A^2 / 2 + A^3 / 6, exactly (A^4 = 0)
        assert all(J[i, j].contains(exact[i, j]) for i in range(n) for j in range(n))


def test_a_fast_rigid_body_takes_steps_below_two_to_the_minus_fifty():
    # the tutorial's body spinning 10^15 times faster: its steps (~1e-15) are below 2^-50, which the steps' binary
    # rounding once took to 0 (validation_failed at t = 0); the run is the slow one with time scaled, as many
    # steps and digits
    body = ls.EulerPoisson(RIGID_INERTIA)
    s = 10**15
    omega = [to_fraction(w) * s for w in RIGID_OMEGA]
    times = [Fraction(3, s), Fraction(7, s)]
    sol = validated_integrate(body, body.initial_state(omega=omega), t=times, dps=20)
    assert sol.status == "success", sol.message
    refs = exact.euler_poisson_many(RIGID_INERTIA, omega, times, dps=50)
    assert all(inside(b, v) for row, ref in zip(sol.y, refs) for b, v in zip(row, ref))
    slow = validated_integrate(body, body.initial_state(omega=RIGID_OMEGA), t=[3, 7], dps=20)
    assert sol.stats.steps == slow.stats.steps and min(certified_digits(sol)) > 21


def test_certified_digits_never_claim_more_than_the_balls_carry():
    # -log10(widest radius / max(1, |z|)) from the balls' exact midpoints and radii at 60 digits: the float given
    # is at most that (its midpoint rounded to nearest claimed up to a part in 10^16 more on 19 rows of 64)
    from lieseries.balls import ball_bounds

    body = ls.EulerPoisson(RIGID_INERTIA)
    y0 = body.initial_state(omega=RIGID_OMEGA)
    ctx = mp.MPContext()
    ctx.dps = 60
    for data in (y0, [(q, Fraction(1, 10**12)) for q in y0.exact]):
        sol = validated_integrate(body, data, t=[Fraction(k, 4) for k in range(1, 9)], dps=30)
        for row, digits in zip(sol.y, certified_digits(sol)):
            widest = max(ball_bounds(b)[1] for b in row)
            scale = max([Fraction(1)] + [abs(ball_bounds(b)[0]) for b in row])
            exact_digits = -ctx.log10(ctx.mpf(widest.numerator) / widest.denominator
                                      * scale.denominator / scale.numerator)
            assert digits <= exact_digits and digits > exact_digits - 1e-12


def test_a_first_step_far_shorter_than_the_jets_time_scale_is_proved():
    # a relativistic oscillator, H = sqrt(1 + p^2) + a q^2 / 2: from this point the first centre's jets keep the
    # time scale 1 while the radius of convergence is near 1/2, so their rounding grows like 2^k up to 6e-11 at
    # order 39; one bound of the defect for every order below N was then that, and no step down to the shortest
    # was proved (validation_failed at t = 0). With the bounds per order, the run goes through
    q, p = hy.make_vars("q", "p")
    relosc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], hy.sqrt(1 + p**2) + hy.par[0] * q**2 / 2,
                              parameters=["1159/500"], name="relosc")
    y0, times = [Fraction(-471, 500), Fraction(-81, 200)], [Fraction(-1251, 2000), Fraction(-1251, 1000)]
    sol = validated_integrate(relosc, y0, times, dps=20, order=40)
    assert sol.status == "success", sol.message
    ref = ls.lie_integrate(relosc, y0, times, dps=60)
    assert all(contains(row, [to_fraction(v) for v in rrow], tol=Fraction(1, 10**40))
               for row, rrow in zip(sol.y, ref.y))
    assert min(certified_digits(sol)) > 20


def test_a_failure_names_the_shortest_step_tried_beyond_a_doubles_range():
    """A run over a span of 1e-400 whose state is beyond what the step search's floats hold (M1 = 1e400) fails at
    t = 0, loud; its message said "no step down to 0" (the shortest step, 2^-40 of the span, was a float): it
    names 1e-400 / 2^40 = 9.09e-413."""
    body = ls.EulerPoisson((1, 2, 3))
    sol = ls.validated_integrate(body, body.initial_state(omega=("1e400", "0.1", "0.5")), t="1e-400", dps=20)
    assert sol.status == "validation_failed"
    assert "no step down to 9.09e-413 " in sol.message and "down to 0 " not in sol.message


def test_validated_runs_in_threads_beside_another_python_flint_user_give_what_they_give_alone():
    """python-flint's working precision and series cap are process-wide (``flint.ctx``): two validated runs at 30
    and 150 digits in two threads, beside a third thread that keeps computing at 20 bits with a series cap of 3
    (through ``working_precision``, as every user of python-flint in the process must), give every ball, radius
    and certified digit of the same runs done alone, and enclose the closed form; the third thread sees its own
    precision and cap throughout, and is not kept out for a whole run."""
    body = ls.EulerPoisson(RIGID_INERTIA)
    y0 = body.initial_state(omega=RIGID_OMEGA)
    times = [Fraction(k, 8) for k in range(1, 5)]  # two steps at 150 digits (order 182, 0.13 s)

    def run(dps):
        before = rounds[0]
        sol = validated_integrate(body, y0, t=times, dps=dps)
        during[dps] = rounds[0] - before
        readings = []
        for _ in range(20):  # read many times over, letting the other threads run between the readings
            readings.append((certified_digits(sol).tolist(), radii(sol).tolist()))
            time.sleep(0.001)
        return sol, readings

    stop, wrong, rounds, during = threading.Event(), [], [0], {}
    alone = {dps: run(dps) for dps in (30, 150)}

    def other_user():
        while not stop.is_set():
            with working_precision(20) as fl:
                fl.ctx.cap = 3
                for _ in range(50):
                    third = fl.arb(1) / 3
                    series = fl.arb_series([1, 1]).exp()
                    if fl.ctx.prec != 20 or not 2**-22 < third.rad() < 2**-18 or len(series) != 3:
                        wrong.append((fl.ctx.prec, fl.ctx.cap, third.rad(), len(series)))
            rounds[0] += 1

    other = threading.Thread(target=other_user, daemon=True)
    other.start()
    try:
        with ThreadPoolExecutor(max_workers=2) as pool:
            futures = {dps: pool.submit(run, dps) for dps in (150, 30)}
            together = {dps: f.result() for dps, f in futures.items()}
    finally:
        stop.set()
        other.join()
    assert not wrong, wrong[:3]
    assert during[150] > 0  # the other thread computed while the long run went on (between its steps)
    refs = exact.euler_poisson_many(RIGID_INERTIA, RIGID_OMEGA, times, dps=180)
    for dps in (30, 150):
        (sol, readings), (sol_alone, readings_alone) = together[dps], alone[dps]
        assert sol.status == "success", sol.message
        assert contains(sol.y, refs, tol=Fraction(1, 10**175))
        assert all(a.mid().man_exp() == b.mid().man_exp() and a.rad().man_exp() == b.rad().man_exp()
                   for row, row_alone in zip(sol.y, sol_alone.y) for a, b in zip(row, row_alone))
        assert readings == [readings_alone[0]] * len(readings) == readings_alone
        assert min(readings[0][0]) > dps - 5


@pytest.mark.parametrize("error", [KeyboardInterrupt, ValueError])
def test_working_precision_restores_the_callers_precision_and_cap_and_frees_the_lock_on_an_error(error):
    before = flint.ctx.prec, flint.ctx.cap
    with pytest.raises(error):
        with working_precision(99, cap=before[1] + 7):
            with working_precision(300):  # nested: the cap stays
                assert (flint.ctx.prec, flint.ctx.cap) == (300, before[1] + 7)
                raise error()
    assert (flint.ctx.prec, flint.ctx.cap) == before

    def other_thread():
        with working_precision(64) as fl:
            got.append(fl.ctx.prec)

    got = []
    other = threading.Thread(target=other_thread, daemon=True)
    other.start()
    other.join(60)
    assert got == [64]  # the lock was released


def test_a_series_cut_by_a_cap_lowered_meanwhile_raises_and_is_never_read_as_zeros(monkeypatch):
    """python-flint cuts every series at its process-wide cap: code in another thread that lowers
    ``flint.ctx.cap`` without ``working_precision`` while a step evaluates the field on series must make the run
    fail loudly; the missing terms of the defect and of the Lagrange term must not read as zeros (a remainder bound
    far too small, and enclosures that miss the solution)."""
    from lieseries import validated_step

    real = validated_step.evaluate

    def evaluate_while_cut(prog, values, *args):
        old = flint.ctx.cap
        flint.ctx.cap = 3  # as another thread would, between two operations
        try:
            return real(prog, values, *args)
        finally:
            flint.ctx.cap = old

    monkeypatch.setattr(validated_step, "evaluate", evaluate_while_cut)
    body = ls.EulerPoisson(RIGID_INERTIA)
    with pytest.raises(RuntimeError, match=r"flint\.ctx\.cap"):
        validated_integrate(body, body.initial_state(omega=RIGID_OMEGA), t=Fraction(1, 4), dps=30)
