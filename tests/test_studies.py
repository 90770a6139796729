"""Studies: error vs order measures the radius of convergence; work-precision errors follow the tolerance;
drift follows Brouwer's law. Every number is checked against an independent reference (closed forms, heyoka at
256 bits, heyoka's own Taylor coefficients)."""

from types import SimpleNamespace

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.precision import to_fraction
from lieseries.studies import (
    drift,
    error_vs_order,
    reference_solution,
    state_error,
    theoretical_radius,
    work_precision,
)
from lieseries.studies.convergence import fit_geometric_rate
from lieseries.studies.drift import growth_exponent
from problems import mpf


#: Two rigid-body motions on the two elliptic branches: (omega, branch)
RIGID_CASES = [((1, "0.1", "0.5"), "below"), (("0.5", "0.1", 1), "above")]


def heyoka_series(system, y0, order, dps):
    """Stand-in for ls.lie_series built from an independent source: the Taylor coefficients heyoka computes
    at t = 0 in 256-bit arithmetic (order ~88 at tolerance 2^-250)."""
    ps = system.poisson
    prec = ls.resolve_precision(256)
    npar = len(hy.get_params([e for _, e in ps.ode_system]))
    ta = hy.taylor_adaptive(ps.ode_system, prec.array([to_fraction(v) for v in y0]), tol=hy.real(2.0**-250, 256),
                            fp_type=hy.real, prec=256, pars=prec.array(ps.parameter_values[:npar]),
                            compact_mode=True)
    assert ta.order >= order
    ta.step(hy.real(1e-30, 256), write_tc=True)
    tc = ta.tc
    with mp.workdps(dps):
        coeffs = [[+mpf(tc[i, k]) for i in range(tc.shape[0])] for k in range(order + 1)]
    return SimpleNamespace(coefficients=coeffs)


# -- references ----------------------------------------------------------------------------------------------
def test_rigid_reference_with_rotated_start_matches_256_bit_run():
    """R(t) = R0 R_id(t): the closed form composed with a general R0, against heyoka at 256 bits."""
    body = ls.EulerPoisson((1, 2, 3))
    R0 = [[1, 0, 0], [0, "0.6", "-0.8"], [0, "0.8", "0.6"]]  # an exact rotation about x
    y0 = body.initial_state((1, "0.1", "0.5"), R0=R0, precision=256)
    ref = reference_solution(body, y0, 3, dps=60)
    assert ref.kind == "exact"
    sol = ls.integrate(body, y0, t=3, precision=256, tol=2.0**-240)
    with mp.workdps(70):
        err = max(abs(mpf(a) - b) for a, b in zip(sol.y[-1], ref.values))
    assert err < 1e-60


@pytest.mark.parametrize("form", ["intermediate", "dirac"])
def test_sphere_reference_compares_position_and_velocity(form):
    """The great-circle reference in (x, v), against heyoka at 256 bits, for both forms."""
    model = ls.Sphere(mass=2, radius="1.5") if form == "intermediate" else ls.SphereDirac(mass=2, radius="1.5")
    y0 = model.initial_state(("0.9", 0, "1.2"), (0, "0.75", 0), precision=256)
    ref = reference_solution(model, y0, 2, dps=60)
    assert ref.names == ("x1", "x2", "x3", "v1", "v2", "v3")
    sol = ls.integrate(model, y0, t=2, precision=256, tol=2.0**-240)
    assert state_error(model, sol.y[-1], ref) < 1e-60
    # a double run is at double accuracy against it, and the error grows with a wrong final time
    y0d = model.initial_state(("0.9", 0, "1.2"), (0, "0.75", 0))
    assert state_error(model, ls.integrate(model, y0d, t=2).y[-1], ref) < 1e-14
    assert state_error(model, ls.integrate(model, y0d, t="2.001").y[-1], ref) > 1e-4


def test_theoretical_radius_sources():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1, "0.1", "0.5"), precision=256)
    rho = theoretical_radius(body, y0)
    assert float(rho) == pytest.approx(float(exact.rigid_body_constants((1, 2, 3), (1, "0.1", "0.5")).pole_distance))
    sphere = ls.Sphere()
    ys = sphere.initial_state(("0.6", 0, "0.8"), (0, 1, 0), precision=256)
    assert float(theoretical_radius(sphere, ys)) == pytest.approx(np.pi / 2, rel=1e-12)
    assert theoretical_radius(ls.SphereDirac(), ls.SphereDirac().initial_state(("0.6", 0, "0.8"), (0, 1, 0))) is None


# -- error vs order ------------------------------------------------------------------------------------------
def test_fit_geometric_rate_recovers_slope_and_skips_floor():
    orders = list(range(0, 40))
    errors = [3.0 * 0.5**n if 3.0 * 0.5**n > 1e-9 else 1e-12 for n in orders]
    slope, intercept, used = fit_geometric_rate(orders, errors, floor=1e-10, min_order=5)
    assert slope == pytest.approx(np.log10(0.5), rel=1e-12)
    assert intercept == pytest.approx(np.log10(3.0), rel=1e-12)
    assert min(used) == 5 and max(used) == 31  # 3 * 0.5**31 = 1.4e-9 is the last point above the floor


@pytest.mark.parametrize("omega,branch", RIGID_CASES, ids=[b for _, b in RIGID_CASES])
def test_error_vs_order_radius_with_heyoka_coefficients(monkeypatch, omega, branch):
    """The study's partial sums and fit, fed the Taylor coefficients of heyoka (256 bits): the measured radius is
    the pole distance of the elliptic functions within 10% (observed: 0.3%)."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega, precision=256)
    const = exact.rigid_body_constants((1, 2, 3), omega)
    assert const.branch == branch
    monkeypatch.setattr(ls, "lie_series", lambda s, y, order, dps: heyoka_series(s, y, order, dps), raising=False)
    t = 0.6 * float(const.pole_distance)
    res = error_vs_order(body, y0, t, orders=range(1, 51), dps=60)
    assert res.radius_theory == pytest.approx(float(const.pole_distance), rel=1e-12)
    assert abs(res.radius_measured / res.radius_theory - 1) < 0.1
    # the errors really fall: 0.6^50 ~ 8e-12 below the first ones
    assert res.errors[-1] < 1e-9 * res.errors[0]
    assert len(res.fit_orders) >= 20  # the upper half of the 50 orders
    d = res.to_dict()
    assert d["radius_ratio"] == pytest.approx(res.radius_measured / res.radius_theory)


def test_error_vs_order_sphere_chart_radius_with_heyoka_coefficients(monkeypatch):
    """5-d chart: the series converges only up to the zero of x3 at t = pi/2."""
    sphere = ls.Sphere()
    y0 = sphere.initial_state(("0.6", 0, "0.8"), (0, 1, 0), precision=256)
    monkeypatch.setattr(ls, "lie_series", lambda s, y, order, dps: heyoka_series(s, y, order, dps), raising=False)
    res = error_vs_order(sphere, y0, 0.6 * np.pi / 2, orders=range(1, 51), dps=60)
    assert res.radius_theory == pytest.approx(np.pi / 2, rel=1e-12)
    assert abs(res.radius_measured / res.radius_theory - 1) < 0.1


@pytest.mark.parametrize("omega,branch", RIGID_CASES, ids=[b for _, b in RIGID_CASES])
def test_lie_series_radius_matches_pole_distance(omega, branch):
    """The real Lie series of the rigid body: measured radius within 10% of the pole distance, on both branches."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega, precision=256)
    rho = float(exact.rigid_body_constants((1, 2, 3), omega).pole_distance)
    res = error_vs_order(body, y0, 0.6 * rho, orders=range(1, 46), dps=60)
    assert abs(res.radius_measured / rho - 1) < 0.1, res.to_dict()


@pytest.mark.slow
@pytest.mark.parametrize("fraction", [0.5, 0.8])
def test_lie_series_radius_high_order(fraction):
    """Orders up to 80 at 100 digits, closer to and further from the radius."""
    body = ls.EulerPoisson((1, 2, 3))
    omega = ("0.01", 1, "0.01")  # near the separatrix, m = 0.9998
    y0 = body.initial_state(omega, precision=400)
    rho = float(exact.rigid_body_constants((1, 2, 3), omega).pole_distance)
    res = error_vs_order(body, y0, fraction * rho, orders=range(1, 81), dps=100)
    assert abs(res.radius_measured / rho - 1) < 0.05, res.to_dict()


# -- work-precision ------------------------------------------------------------------------------------------
def test_work_precision_errors_follow_the_tolerance():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1, "0.1", "0.5"), precision=256)
    methods = [
        {"method": "taylor", "precision": "double", "tol": [1e-6, 1e-8, 1e-10, 1e-12]},
        {"method": "taylor", "precision": "quad", "tol": [1e-15, 1e-25]},
        {"method": "scipy", "rtol": [1e-5, 1e-8, 1e-11]},
        {"method": "mpmath", "dps": 15, "t_max": "0.5"},
        {"method": "lie", "dps": 30, "tol": 1e-20},
    ]
    wp = work_precision(body, y0, 10, methods=methods, repeat=1)
    assert "closed form" in wp.reference
    by = {}
    for r in wp.rows:
        by.setdefault(r.label, []).append(r)
        assert r.status == "success", (r.label, r.message)
        assert r.run_time > 0
    for label in ("heyoka double", "heyoka quad", "scipy DOP853"):
        errs = [r.error for r in by[label]]
        assert all(b < a for a, b in zip(errs, errs[1:])), (label, errs)
    dbl = by["heyoka double"]
    for r, tol in zip(dbl, [1e-6, 1e-8, 1e-10, 1e-12]):
        assert r.error < 1000 * tol  # error at T = 10 is a modest multiple of the tolerance
        assert r.build_time is not None and r.steps > 0 and r.order > 0
    assert by["heyoka quad"][-1].error < 1e-22
    odefun = by["mpmath odefun 15 dps"][0]
    assert odefun.t == 0.5 and odefun.error < 1e-12  # capped span, measured at the time it reached
    assert by["Lie series 30 dps"][0].error < 1e-15


def test_work_precision_numerical_reference_for_a_plain_poisson_system():
    """A system without a closed form is measured against heyoka at 256 bits (the pendulum)."""
    q, p = hy.make_vars("q", "p")
    pend = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - hy.par[0] * hy.cos(q), parameters={"g": 1},
                            name="pendulum")
    wp = work_precision(pend, ["0.5", 0], 5, methods=[{"method": "taylor", "tol": [1e-6, 1e-12]}], repeat=1)
    assert "256 bits" in wp.reference
    e = [r.error for r in wp.rows]
    assert e[1] < e[0] < 1e-4 and e[1] < 1e-11


# -- drift -------------------------------------------------------------------------------------------------------
def test_growth_exponent_of_synthetic_curves():
    steps = np.geomspace(10, 1e5, 100)
    assert growth_exponent(steps, 1e-16 * np.sqrt(steps)) == pytest.approx(0.5, abs=1e-9)
    assert growth_exponent(steps, 1e-16 * steps) == pytest.approx(1.0, abs=1e-9)


def test_drift_energy_follows_brouwer_not_linear():
    """Rigid body, double, 10^4 time units (~2.4e4 steps), ensemble of 8: the RMS energy drift grows like
    steps^p with p well below 1 (observed 0.57) and stays within a small factor of eps sqrt(steps) |E|."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1, "0.1", "0.5"), precision=256)
    dr = drift(body, y0, 1e4, precision="double", samples=100, ensemble=8)
    assert dr.status == "success"
    assert dr.total_steps > 20000
    assert set(dr.errors) == {"energy", "M2", "L1", "L2", "L3", "orthogonality", "det_R"}
    p = dr.exponents["energy"]
    assert 0.2 < p < 0.8, p
    E0 = dr.initial["energy"]
    assert E0 == pytest.approx(0.5 * (1 + 2 * 0.01 + 3 * 0.25))
    eps = 2.0**-52
    assert dr.brouwer["energy"][-1] == pytest.approx(eps * np.sqrt(dr.steps[-1]) * abs(E0))
    final = dr.errors["energy"][-1]
    assert 0.02 * dr.brouwer["energy"][-1] < final < 20 * dr.brouwer["energy"][-1]
    # the cumulative step estimate ends at the run's total
    assert dr.steps[-1] == pytest.approx(dr.total_steps)
    # R stays a rotation: the perturbed ensemble members change only M
    assert max(dr.errors["orthogonality"]) < 1e-13


def test_drift_checks_arguments():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state((1, "0.1", "0.5"))
    with pytest.raises(ValueError, match="`t`"):
        drift(body, y0, -1.0)
    with pytest.raises(ValueError, match="`samples`"):
        drift(body, y0, 10.0, samples=3)
    with pytest.raises(ValueError, match="`ensemble`"):
        drift(body, y0, 10.0, ensemble=0)


def test_damped_body_is_measured_against_a_numerical_reference():
    """The damped body has no closed form: its reference is heyoka at 256 bits, never the free body's formula."""
    from lieseries.studies import has_exact_solution

    damped = ls.DampedEulerPoisson((1, 2, 3), damping="0.1")
    y0 = damped.initial_state((1, "0.1", "0.5"))
    assert not has_exact_solution(damped) and has_exact_solution(ls.EulerPoisson((1, 2, 3)))
    ref = reference_solution(damped, y0, 2, dps=30)
    assert ref.kind == "numerical"
    free = reference_solution(ls.EulerPoisson((1, 2, 3)), y0, 2, dps=30)
    assert max(abs(a - b) for a, b in zip(ref.values, free.values)) > 1e-3
    assert theoretical_radius(damped, y0) is None


def test_drift_of_a_bare_poisson_system_measures_h_and_its_casimirs():
    """A bare PoissonSystem gets H and its declared Casimirs (before: a TypeError), evaluated exactly."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    d = ls.studies.drift(body.poisson, y0, 50, samples=12)
    assert d.status == "success"
    assert d.initial["energy"] == 0.885  # (1 + 2 * 0.1^2 + 3 * 0.5^2) / 2, exactly
    assert max(d.errors["energy"]) < 1e-13

    M1, M2, M3 = hy.make_vars("M1", "M2", "M3")
    so3 = ls.PoissonSystem([M1, M2, M3], [[0, -M3, M2], [M3, 0, -M1], [-M2, M1, 0]],
                           (M1**2 + M2**2 / 2 + M3**2 / 4) / 2, casimirs={"M2": M1**2 + M2**2 + M3**2})
    d = ls.studies.drift(so3, [1, 2, 3], 50, samples=12, precision="quad")
    assert d.initial == {"energy": (1 + 2 + 9 / 4) / 2, "M2": 14.0}
    assert max(d.errors["M2"]) < 1e-30 and max(d.errors["energy"]) < 1e-30


def test_heavy_top_is_measured_against_its_own_motion_not_the_free_body():
    """A HeavyTop is an EulerPoisson subclass, but gravity changes its motion: its reference is a numerical run of
    its own equations (the free body's closed form, which it used to get, misses by the torque's effect)."""
    from lieseries.studies import has_exact_solution

    top = ls.HeavyTop(inertia=(1, 2, 3), com=(0, 0, 1), mass=1, g=10)
    y0 = top.initial_state(omega=(1, "0.1", "0.5"))
    assert not has_exact_solution(top)
    ref = reference_solution(top, y0, 1, dps=30)
    assert ref.kind == "numerical"
    # independent: the Lie-series integrator at 40 digits (another engine, another method)
    other = ls.lie_integrate(top, y0, 1, dps=40).y[-1]
    with mp.workdps(40):
        assert max(abs(mp.mpf(a) - b) for a, b in zip(other, ref.values)) < mp.mpf(10) ** -25
    assert theoretical_radius(top, y0) is None


@pytest.fixture(scope="module")
def rigid_error_vs_order_400():
    """The rigid body's error against order at t = 0.1 and 400 digits (errors down to 2.5e-402), once for the
    module."""
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    return body, y0, error_vs_order(body, y0, "0.1", [40, 80, 120, 160, 200, 240, 280], dps=400)


def test_error_against_order_above_300_digits_fits_down_to_its_own_floor(rigid_error_vs_order_400):
    """At 400 digits the floor 100 x 10^-400 and errors of 1e-352 are below a float's range: as floats they were
    0.0 (the floor) and dropped (the errors), so the fit stopped at 1e-294. Independent check: the rate of the
    rigid body's series at t = 0.1 against the distance of the closed form's nearest complex-time pole."""
    body, y0, ev = rigid_error_vs_order_400
    assert 0 < ev.floor < mp.mpf(10) ** -397
    assert 240 in ev.fit_orders and 280 not in ev.fit_orders  # 1.1e-352 above the floor; 2.5e-402 below it
    from lieseries.studies.reference import theoretical_radius

    rho = theoretical_radius(body, y0)  # from ls.exact's elliptic functions: 2.9098
    assert abs(0.1 * 10 ** (-ev.rate) / rho - 1) < 0.01


def test_error_against_order_plot_draws_errors_below_a_doubles_range(monkeypatch, tmp_path, rigid_error_vs_order_400):
    """The plot of a 400-digit error-against-order study left out every error below 1e-308 (0.0 as a float on a
    log axis): the orders 240 and 280 (1e-352, 2.5e-402) were not drawn. The axis shows log10 there."""
    from lieseries.studies import convergence

    ev = rigid_error_vs_order_400[2]
    assert ev.errors[-2] < mp.mpf(10) ** -340 and ev.errors[-1] < mp.mpf(10) ** -400  # the orders 240 and 280
    figures = []
    monkeypatch.setattr(convergence, "save_figure", lambda plt, fig, path: figures.append(fig))
    convergence.ErrorVsOrderStudy().plot([("rigid body", ev)], tmp_path / "x.png", None)
    ax = figures[0].axes[0]
    points = next(ln for ln in ax.get_lines() if ln.get_label().startswith("rigid body"))
    log_axis = ax.get_yscale() == "log"  # the value drawn, or its log10 on a linear axis
    drawn = {x: float(np.log10(y)) if log_axis else y for x, y in zip(points.get_xdata(), points.get_ydata())}
    for order, err in zip(ev.orders, ev.errors):
        want = float(mp.log10(err))
        assert abs(drawn[order] - want) < 1e-6 * abs(want), (order, err, drawn[order])


def _so3(inertia):
    M1, M2, M3 = hy.make_vars("M1", "M2", "M3")
    return ls.PoissonSystem(variables=[M1, M2, M3], tensor=[[0, -M3, M2], [M3, 0, -M1], [-M2, M1, 0]],
                            hamiltonian=0.5 * (hy.par[0] * M1**2 + hy.par[1] * M2**2 + hy.par[2] * M3**2),
                            parameters={f"1/I{i + 1}": 1 / to_fraction(v) for i, v in enumerate(inertia)})


def test_numerical_reference_resolves_runs_of_more_than_256_bits():
    """A system without a closed form is measured against a numerical reference: its tolerance was 2^-250 at any
    precision (130 digits asked, 1e-77 given: every run more precise than that was reported with the reference's
    error), and above 1024 bits heyoka refused it with a traceback. The free body on so(3)* against the closed
    form of M = I Omega(t)."""
    from lieseries.studies import reference_solution
    from problems import ctx_mpf, private_ctx

    inertia, omega = (1, 2, "2.5"), (1, "0.1", "0.5")
    so3 = _so3(inertia)
    M0 = [to_fraction(i) * to_fraction(w) for i, w in zip(inertia, omega)]
    for dps in (130, 350):
        ref = reference_solution(so3, M0, "0.5", dps=dps)
        c = private_ctx(dps + 20)
        om = exact.angular_velocity(inertia, omega, "0.5", dps=dps + 20)
        want = [ctx_mpf(c, i) * ctx_mpf(c, w) for i, w in zip(inertia, om)]
        assert max(abs(ctx_mpf(c, a) - b) for a, b in zip(ref.values, want)) < c.mpf(10) ** (5 - dps), ref.label


def test_formulations_study_above_300_digits_keeps_its_small_numbers():
    """A 320-digit Lie run of the pendulum's Dirac form: its energy drift was measured from the exact initial
    state read at 256 bits (1e-87 for every run), and |G|, |Phi| and the drift, about 1e-322, were subnormal
    floats of a few bits (or 0.0 further down). They are mpf there, below 1e-300."""
    from lieseries.studies import compare_formulations

    pend = ls.ConstrainedSystem("m/2*(x_dot**2 + y_dot**2) - m*g*y", ["x", "y"], ["x**2 + y**2 - l**2"],
                                parameters={"m": 1, "g": "9.81", "l": 1})
    row, = compare_formulations(pend, ("0.6", "-0.8"), ("0.8", "0.6"), "0.05", [{"method": "lie", "dps": 320}],
                                formulations=["dirac"], samples=2).rows
    assert row.status == "success"
    for value in (row.error, row.G, row.Phi, row.energy):
        assert 0 <= value < mp.mpf(10) ** -300 and not (isinstance(value, float) and 0 < value < 1e-307), row


def test_work_precision_plot_draws_errors_below_a_doubles_range(monkeypatch, tmp_path):
    """A 400-digit run's error (1e-402) was drawn at 1e-300 (clamped for the log axis): a point 100 orders of
    magnitude off. The axis shows log10 of the errors then."""
    import importlib
    from types import SimpleNamespace

    work_precision = importlib.import_module("lieseries.studies.work_precision")  # the package's name is the function
    row = dict(t=1.0, method="lie", build_time=None)
    rows = [SimpleNamespace(label="Lie series", error=mp.mpf("1e-402"), run_time=0.5, **row),
            SimpleNamespace(label="Lie series", error=mp.mpf("1e-60"), run_time=0.01, **row)]
    figures = []
    monkeypatch.setattr(work_precision, "save_figure", lambda plt, fig, path: figures.append(fig))
    work_precision.WorkPrecisionStudy().plot([("rigid body", SimpleNamespace(rows=rows, t=1.0))], tmp_path / "x.png",
                                             None)
    ax = figures[0].axes[0]
    line, = [ln for ln in ax.get_lines() if ln.get_label() == "Lie series"]
    ys = [float(mp.log10(y)) if ax.get_yscale() == "log" else y for y in line.get_ydata()]
    assert abs(ys[0] + 402) < 1e-9 and abs(ys[1] + 60) < 1e-9
