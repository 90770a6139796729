"""The radius of convergence of the Lie series in each formulation of a constrained system (the formulations
study's ``radius_t``): measured against independent references (the Maclaurin series of closed forms in mpmath, the
pole of the great circle's local momentum), and refused where the data show no geometric rate."""

import math

import mpmath
import pytest

import lieseries as ls
from lieseries.run import run_scene
from lieseries.scenes import SceneError, parse_scene
from lieseries.studies.convergence import FLOOR_FACTOR, fit_geometric_rate
from lieseries.studies.formulations import RADIUS_AGREEMENT, radius_verdict


def _truncation_errors(f, t, max_order, dps=60):
    """|f(t) - sum_{k <= N} c_k t^k| for N = 1..max_order, the c_k the Maclaurin coefficients of f by mpmath."""
    with mpmath.workdps(dps):
        c = mpmath.taylor(f, 0, max_order)
        tm = mpmath.mpf(t)
        exact = f(tm)
        out, acc = [], c[0]
        for k in range(1, max_order + 1):
            acc += c[k] * tm**k
            out.append(float(abs(exact - acc)))
    return list(range(1, max_order + 1)), out


def _verdict(orders, errors, t, dps=60):
    floor = FLOOR_FACTOR * 10.0 ** (-dps)
    slope, _i, used = fit_geometric_rate(orders, errors, floor)
    return radius_verdict(t, orders, errors, floor, used, slope)


@pytest.mark.parametrize("f, rho", [
    (mpmath.sec, math.pi / 2),                      # poles at +-pi/2, an even function: errors come in pairs
    (lambda t: 1 / (1 + t**2), 1.0),                # complex poles at +-i
    (lambda t: mpmath.log(2 - t), 2.0),             # a branch point: coefficients ~ 1 / (k 2^k)
])
def test_a_geometric_rate_gives_the_radius_of_the_closed_form(f, rho):
    orders, errors = _truncation_errors(f, 0.6 * rho, 40)
    verdict, radius, *_ = _verdict(orders, errors, 0.6 * rho)
    assert radius is not None and verdict.startswith("geometric"), verdict
    # an algebraic prefactor k^-a of the errors tilts the fitted slope by ~ a / (N ln 10): a few per cent at N ~ 30
    assert abs(radius / rho - 1) < 0.05, (radius, rho)


def test_an_entire_series_gets_no_radius():
    """exp and cos have no singularity: their errors fall like t^N / N!, faster than any geometric rate; the
    mean slope over the orders would suggest a finite 'radius', which must not be claimed."""
    for f in (mpmath.exp, mpmath.cos):
        orders, errors = _truncation_errors(f, 1, 40)
        verdict, radius, fit, low, high = _verdict(orders, errors, 1)
        assert radius is None and "steepens" in verdict, verdict
        assert fit is not None and high > RADIUS_AGREEMENT * low


def test_too_few_errors_above_the_floor_give_no_radius():
    orders, errors = _truncation_errors(mpmath.exp, "0.1", 30, dps=30)
    verdict, radius, *_ = _verdict(orders, errors, "0.1", dps=15)
    assert radius is None and verdict.startswith("not measured") and "floor" in verdict


SCENE = """name = "t"
title = "t"
[model]
kind = "constrained"
lagrangian = "(x_dot**2 + y_dot**2 + z_dot**2)/2"
coordinates = ["x", "y", "z"]
constraints = ["x**2 + y**2 + z**2 - 1"]
[initial]
q = ["0.6", 0, "0.8"]
qdot = [0, 1, 0]
[studies.formulations]
t = "0.5"
samples = 2
methods = [{ method = "taylor", precision = "double" }]
formulations = ["dirac", "local"]
chart = { z = "sqrt(1 - x**2 - y**2)" }
radius_t = 1
radius_max_order = 24
radius_dps = 30
"""


@pytest.mark.slow  # two derivations and two series with their 256-bit references: ~5 s
def test_great_circle_radius_per_formulation_in_a_scene_report(tmp_path):
    """x = (0.6 cos t, sin t, 0.8 cos t). In the local chart z = sqrt(1 - x^2 - y^2) the canonical momentum
    p_y = ydot + y (x xdot + y ydot) / z^2 = 1 / cos t has poles at t = +-pi/2: the chart's series has radius pi/2
    (also ls.exact.sphere_pole_distance, the zero of z). The Dirac form's variables are sines and cosines: entire,
    no radius."""
    from lieseries.report import write_report

    res = run_scene(parse_scene(SCENE), progress=False)
    (_lab, comp), = res.studies["formulations"]
    radii = {r.formulation: r for r in comp.radii}
    with mpmath.workdps(30):
        pole = ls.exact.sphere_pole_distance(1, [mpmath.mpf("0.6"), 0, mpmath.mpf("0.8")], [0, 1, 0], axis=2)
    assert abs(float(pole) - math.pi / 2) < 1e-12
    assert abs(radii["local"].radius / (math.pi / 2) - 1) < 0.03, radii["local"]
    assert radii["dirac"].radius is None and "steepens" in radii["dirac"].verdict
    write_report(res, tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "radius of convergence of the Lie series" in md
    row = next(line for line in md.splitlines() if "| dirac " in line and "steepens" in line)
    assert [c.strip() for c in row.split("|")][10] == "none"  # the radius column
    assert (tmp_path / "rep" / "formulations_radius.csv").exists()


def test_a_radius_time_beyond_the_chart_is_reported_not_claimed():
    """t beyond the local chart's edge (t = 1.508): the reference cannot reach it; the row says so, no radius."""
    from lieseries.studies.formulations import formulation_radii

    sphere = ls.ConstrainedSystem("(x_dot**2 + y_dot**2 + z_dot**2)/2", ["x", "y", "z"], ["x**2 + y**2 + z**2 - 1"])
    r, = formulation_radii(sphere, ("0.6", 0, "0.8"), (0, 1, 0), 2, max_order=8, dps=20, formulations=("local",),
                           chart={"z": "sqrt(1 - x**2 - y**2)"})
    assert r.radius is None and r.verdict.startswith("not measured") and "chart" in r.verdict


def test_radius_fields_are_checked():
    with pytest.raises(SceneError, match="`studies.formulations.radius_max_order`"):
        parse_scene(SCENE.replace("radius_max_order = 24", "radius_max_order = 0"))
    with pytest.raises(SceneError, match="`studies.formulations.radius_t`"):
        parse_scene(SCENE.replace("radius_t = 1", "radius_t = -1"))


def test_quick_mode_halves_the_radius_orders_but_never_raises_them():
    from lieseries.scenes import effective_plan

    for given, quick in ((40, 20), (20, 12), (8, 8)):
        sc = parse_scene(SCENE.replace("radius_max_order = 24", f"radius_max_order = {given}"))
        _run, studies = effective_plan(sc, quick=True)
        assert studies["formulations"]["radius_max_order"] == quick
        assert studies["formulations"]["radius_dps"] == 30


@pytest.mark.parametrize("f, rho", [
    (mpmath.sec, math.pi / 2),
    (lambda t: 1 / (1 + t**2), 1.0),
    (lambda t: mpmath.log(2 - t), 2.0),
    (lambda t: 1 / (1 - t / 2) ** 3, 2.0),          # a pole of order 3: coefficients ~ k^2 / 2^k, a slow tilt
])
def test_the_radius_shows_only_digits_the_fits_agree_on(f, rho):
    """The radius column keeps the two significant digits such a fit carries: the shown number is within one unit
    of its last digit of the closed form's rho (the last digit uncertain)."""
    from lieseries.studies.formulations import radius_text

    orders, errors = _truncation_errors(f, 0.6 * rho, 40)
    _verdict_text, radius, _fit, low, high = _verdict(orders, errors, 0.6 * rho)
    shown = radius_text(radius)
    digits = len(shown.replace(".", "").lstrip("0"))
    unit = 10.0 ** (math.floor(math.log10(float(shown))) - digits + 1)
    assert abs(float(shown) - rho) <= unit * (1 + 1e-9), (shown, rho, low, high)
    assert radius_text(None) == "none"


def test_a_growing_series_has_the_same_radius_at_any_scale():
    """Coefficients C 2^k (radius 1/2) for C = 1 and C = 1e400: the radius is 1/2 for both (the root test on the
    last coefficient gave 1e-34 for the second, and a run of momenta of 1e400 collapsed at its first step)."""
    from lieseries.lie.plan import radius_from_logs

    for lnC in (0.0, 400 * math.log(10), -400 * math.log(10)):
        pts = [(k, lnC + k * math.log(2)) for k in range(6, 13)]
        assert abs(radius_from_logs(pts) - 0.5) < 1e-12
