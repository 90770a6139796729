"""The scene estimate prices heyoka runs by the steps they will take: a stiff run stops after a few chunks
(status step_collapse), a long run that is not stiff takes all its steps. The references are the runs themselves
(their step counts), not the estimator."""

from fractions import Fraction

import lieseries as ls
from lieseries.methods.pricing import Pricer, heyoka_step_seconds
from lieseries.taylor import STIFF_STEPS


def _priced_steps(model, y0, t, precision="double"):
    per, _lower, _basis, _ = Pricer().span(model, y0, {"method": "taylor", "precision": precision}, t, 1)
    return per / heyoka_step_seconds(precision, len(y0))


def test_a_stiff_run_is_priced_at_the_steps_it_takes_before_it_stops():
    body = ls.DampedEulerPoisson((1, 2, 3), damping=10**5)
    y0 = body.initial_state(omega=(1, Fraction(1, 10), Fraction(1, 2)))
    run = ls.integrate(body, y0, t=10, precision="double")
    assert run.status == "step_collapse"
    priced = _priced_steps(body, y0, 10)
    assert run.stats.steps / 3 <= priced <= 3 * run.stats.steps + 100, (priced, run.stats.steps)


def test_a_long_run_that_is_not_stiff_is_priced_at_all_its_steps():
    body = ls.EulerPoisson((1, 2, 3))
    y0 = body.initial_state(omega=(100, 10, 50))  # fast: ~100x the steps per unit time of omega ~ 1
    per_time = ls.integrate(body, y0, t=1, precision="double").stats.steps  # periodic motion: steps grow with t
    t = 3 * STIFF_STEPS // per_time + 1
    priced = _priced_steps(body, y0, t)  # it used to be capped at STIFF_STEPS (an under-estimate)
    assert per_time * t / 2 <= priced <= 2 * per_time * t, (priced, per_time * t)


def _damped_scene(t):
    from lieseries.scenes import parse_scene

    return parse_scene('name = "d"\ntitle = "d"\n[model]\nkind = "damped_euler_poisson"\ninertia = [1, 2, 3]\n'
                       f'damping = 100000\n[initial]\nomega = [1, "0.1", "0.5"]\n[run]\nt = {t}\n'
                       'methods = [{ method = "taylor" }]\n')


def test_a_model_without_closed_form_has_its_numerical_reference_priced():
    """The scene measures a damped body against heyoka at 256 bits: that run is part of the estimate (it was left
    out: a 2-minute scene was estimated at 6 s); where heyoka stops as stiff, so do the reference runs."""
    from lieseries.cost import estimate_scene

    long_run = [p for p in estimate_scene(_damped_scene(1)).parts if p.what.startswith("the reference (heyoka")]
    assert len(long_run) == 1 and long_run[0].seconds > 10
    stiff = [p for p in estimate_scene(_damped_scene(20)).parts if p.what.startswith("the reference (heyoka")]
    assert len(stiff) == 1 and stiff[0].lower_bound and "stops as stiff" in stiff[0].basis
    body = ls.DampedEulerPoisson((1, 2, 3), damping=10**5)
    y0 = body.initial_state(omega=(1, Fraction(1, 10), Fraction(1, 2)))
    assert ls.integrate(body, y0, t=20, precision="double").status == "step_collapse"  # what the pricer relies on
    assert stiff[0].seconds < long_run[0].seconds
