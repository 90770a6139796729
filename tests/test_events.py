"""Events in both engines, against crossings computed independently from the closed forms."""

from fractions import Fraction

import heyoka as hy
import mpmath as mp
import pytest

import lieseries as ls
from lieseries import exact
from lieseries.precision import to_fraction

from problems import RIGID_INERTIA as INERTIA
from problems import RIGID_OMEGA as OMEGA
T = 16


def closed_form_crossings(omega, axis, level, ts, dps):
    """Where M_axis(t) = level between the points of `ts`, from the closed form alone, with each crossing's
    direction (+1 up, -1 down): a scan at 20 digits, then a root solve at `dps` digits. M_i = I_i Omega_i, and
    the closed form's Omega(t) needs no attitude (no elliptic integral of the third kind), so it is cheap."""
    def g(t, digits):
        return INERTIA[axis] * exact.angular_velocity(INERTIA, omega, t, dps=digits)[axis] - level

    vals = [g(t, 20) for t in ts]
    with mp.workdps(dps):
        return [(mp.findroot(lambda t: g(t, dps), (a, b), solver="anderson"), 1 if fb > fa else -1)
                for a, b, fa, fb in zip(ts, ts[1:], vals, vals[1:]) if fa * fb < 0]


@pytest.fixture(scope="module")
def m2_zeros():
    """Zeros of M2(t) on (0, T] from the closed form alone: a scan, then a root solve at 80 digits."""
    return closed_form_crossings(OMEGA, 1, 0, [mp.mpf(k) / 4 for k in range(0, 4 * T + 1)], dps=80)


def m2(body):
    return body.poisson.variables[10]


@pytest.mark.parametrize("engine, bound", [("double", 1e-12), (237, 1e-60), ("lie", 1e-25)])
def test_rigid_body_m2_crossings(engine, bound, m2_zeros):
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    events = [ls.Event(m2, name="m2"), ls.Event(m2, direction="negative", name="down")]
    if engine == "lie":
        sol = ls.lie_integrate(body, y0, t=T, dps=30, events=events)
    else:
        sol = ls.integrate(body, y0, t=T, precision=engine, events=events)
    assert sol.success, sol.message
    assert len(m2_zeros) >= 2
    got = sol.events["m2"]
    assert len(got["t"]) == len(m2_zeros)
    with mp.workdps(80):
        for (t_ref, _), t_got, y_got in zip(m2_zeros, got["t"], got["y"]):
            assert abs(to_fraction(t_got) - to_fraction(t_ref)) < bound
            assert abs(to_fraction(y_got[10])) < bound  # the state at the crossing has M2 = 0
    downs = [t for t, d in m2_zeros if d < 0]
    assert len(sol.events["down"]["t"]) == len(downs)
    assert all(abs(to_fraction(a) - to_fraction(b)) < bound for a, b in zip(sol.events["down"]["t"], downs))


@pytest.mark.parametrize("engine", ["double", "lie"])
def test_terminal_event_stops_the_run_with_its_name(engine, m2_zeros):
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    ev = [ls.Event(m2, terminal=True, name="flip")]
    sol = (ls.lie_integrate(body, y0, t=[1, 5, T], dps=30, events=ev) if engine == "lie"
           else ls.integrate(body, y0, t=[1, 5, T], events=ev))
    assert sol.status == "event" and "'flip'" in sol.message
    first = m2_zeros[0][0]
    assert abs(float(sol.t_reached) - float(first)) < 1e-12
    assert len(sol.t) == sum(1 for t in (1, 5, T) if t < first)  # rows up to the stop only
    assert abs(float(sol.y_final[10])) < 1e-12


@pytest.mark.parametrize("engine", ["double", "quad", "lie"])
def test_sphere_crosses_the_equator_where_the_great_circle_does(engine):
    """x3(t) = 0.8 cos t on the unit sphere: crossings at pi/2 + k pi, across the atlas's chart changes."""
    s = ls.Sphere()
    y0 = s.initial_state(("0.6", "0", "0.8"), (0, 1, 0))
    x3 = hy.make_vars("x3")
    events = [ls.Event(x3, name="equator")]
    sol = (ls.lie_integrate(s, y0, t=8, dps=30, events=events) if engine == "lie"
           else ls.integrate(s, y0, t=8, precision=engine, events=events))
    assert sol.success
    got = sol.events["equator"]
    assert len(got["t"]) == 3
    bound = {"double": 1e-13, "quad": 1e-30, "lie": 1e-25}[engine]
    with mp.workdps(50):
        ref = [mp.pi / 2 + k * mp.pi for k in range(3)]
        assert max(abs(to_fraction(a) - to_fraction(b)) for a, b in zip(got["t"], ref)) < bound
    # the states are written in the charts the run was in
    X = s.position(got["y"], chart=got["charts"])
    assert max(abs(float(x[2])) for x in X) < 1e-12


def test_event_input_is_checked():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    q = hy.make_vars("q")
    with pytest.raises(ValueError, match=r"`events\[0\]` uses variables \['q'\]"):
        ls.integrate(body, y0, t=1, events=[ls.Event(q)])
    with pytest.raises(TypeError, match=r"`events\[0\]` must be an ls.Event"):
        ls.integrate(body, y0, t=1, events=["M2"])
    with pytest.raises(ValueError, match="`direction`"):
        ls.Event(m2(body), direction=2)
    with pytest.raises(ValueError, match="used twice"):
        ls.lie_integrate(body, y0, t=1, events=[ls.Event(m2(body), name="a"), ls.Event(m2(body), name="a")])
    # a callable builds the expression from the model
    sol = ls.integrate(body, y0, t=T, events=[ls.Event(lambda b: b.poisson.variables[10], name="m2")])
    assert len(sol.events["m2"]["t"]) >= 2


def test_ensemble_members_record_their_own_crossings():
    """Four bodies at once: each member's M2 = 0 crossings are those of its own closed form (found as above) and
    exactly its single run's; a terminal event ends only the members that reach it, at their first crossing."""
    body = ls.EulerPoisson(INERTIA)
    # crossings by t = 8: one, two (a tilted spin about axis 3), none (close to the intermediate axis), two
    omegas = [OMEGA, ("0.2", "0.1", 1), ("0.01", 1, "0.005"), (1, "-0.3", "0.2")]
    Y0 = [body.initial_state(omega=w) for w in omegas]
    Tm = 8
    sol = ls.integrate(body, Y0, t=Tm, events=[ls.Event(m2, name="m2")])
    assert sol.success and len(sol.events) == 4
    with pytest.raises(KeyError, match=r"use `events\[i\]\['m2'\]` for member i"):
        sol.events["m2"]  # a natural slip: the events of an ensemble are per member
    firsts = []
    for i, w in enumerate(omegas):
        refs = [t for t, _ in closed_form_crossings(w, 1, 0, [mp.mpf(k) / 8 for k in range(0, 8 * Tm + 1)], dps=40)]
        firsts.append(refs[0] if refs else None)
        got = sol.events[i]["m2"]["t"]
        assert len(got) == len(refs), (i, got, refs)
        assert all(abs(float(a) - float(b)) < 1e-12 for a, b in zip(got, refs))
        assert sol.member(i).events["m2"]["t"].tolist() == list(got)
        single = ls.integrate(body, Y0[i], t=Tm, events=[ls.Event(m2, name="m2")])
        assert [to_fraction(v) for v in got] == [to_fraction(v) for v in single.events["m2"]["t"]]
    grid = [1, 2, 4, Tm]
    stop = ls.integrate(body, Y0, t=grid, events=[ls.Event(m2, terminal=True, name="flip")])
    crossed = [f is not None for f in firsts]
    assert crossed == [True, True, False, True]
    assert [s == "event" for s in stop.status] == crossed
    for i, first in enumerate(firsts):
        if first is None:
            assert stop.rows[i] == len(grid)
            continue
        assert "'flip'" in stop.message[i] and abs(float(stop.t_reached[i]) - float(first)) < 1e-12
        assert stop.rows[i] == sum(1 for t in grid if t < first)  # rows after the stop are not reached
        assert abs(float(stop.y_reached[i][10])) < 1e-12


@pytest.mark.parametrize("engine", ["double", "lie"])
def test_a_run_starting_on_the_surface_counts_crossings_after_its_start(engine):
    """M3(0) = 3 * 0.5 = 1.5 exactly: the event M3 - 3/2 is zero at t0. That is where the run begins (a Poincare
    section's usual start), not a crossing: both engines give the closed form's later zeros of M3 - 3/2, and the
    terminal event stops at the first of them; a run with t = t0 has no crossings."""
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    g = body.poisson.variables[11] - 1.5
    refs = [t for t, _ in closed_form_crossings(OMEGA, 2, mp.mpf(3) / 2,
                                                [mp.mpf(k) / 4 for k in range(1, 4 * T + 1)], dps=40)]
    assert len(refs) >= 2

    def run(t, **kw):
        if engine == "lie":
            return ls.lie_integrate(body, y0, t=t, dps=25, **kw)
        return ls.integrate(body, y0, t=t, **kw)

    sol = run(T, events=[ls.Event(g, name="s")])
    got = sol.events["s"]["t"]
    assert sol.success and len(got) == len(refs)
    assert all(abs(float(a) - float(b)) < 1e-12 for a, b in zip(got, refs))
    stop = run(T, events=[ls.Event(g, terminal=True, name="s")])
    assert stop.status == "event" and abs(float(stop.t_reached) - float(refs[0])) < 1e-12
    still = run(0, events=[ls.Event(g, name="s"), ls.Event(g, terminal=True, name="t")])
    assert still.success and len(still.events["s"]["t"]) == 0 and len(still.events["t"]["t"]) == 0


def test_an_event_that_is_a_function_of_the_state_is_refused_naming_it():
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(OMEGA)
    for engine in (ls.integrate, ls.lie_integrate):
        kw = {"dps": 20} if engine is ls.lie_integrate else {}
        with pytest.raises(TypeError, match=r"`events\[1\]`.*heyoka expression in the system's variables"):
            engine(body, y0, t=1, events=[ls.Event(m2(body)), ls.Event(lambda y: y[10])], **kw)


def test_an_event_using_time_is_refused_when_a_variable_is_named_t():
    t, p = hy.make_vars("t", "p")
    osc = ls.PoissonSystem([t, p], [[0, 1], [-1, 0]], (t * t + p * p) / 2)
    with pytest.raises(ValueError, match=r"`events\[0\]` depends on time"):
        ls.integrate(osc, ["0.5", 0], t=1, events=[ls.Event(p + hy.time)])
    # the variable t itself is fine: crossings of t = 0 at pi/2 (t(s) = cos(s) / 2)
    sol = ls.integrate(osc, ["0.5", 0], t=2, events=[ls.Event(t)])
    assert abs(float(sol.events["event0"]["t"][0]) - float(mp.pi / 2)) < 1e-12


@pytest.mark.parametrize("bits", [64, 200, 512])
@pytest.mark.parametrize("engine", ["taylor", "lie"])
def test_crossings_of_a_run_starting_on_the_section(engine, bits):
    """q(t) = sin t from (q, p) = (0, 1): crossings at k pi, k = 1..9, to the run's precision. The run starts on
    the zero at t = 0; heyoka's own root finding (at >= 180 bits) reports that zero twice and misses pi."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + q**2) / 2)
    events = [ls.Event(q, name="q"), ls.Event(q, direction="negative", name="down")]
    if engine == "lie":
        dps = int(bits * 0.30103)
        sol = ls.lie_integrate(osc, [0, 1], t=30, dps=dps, events=events)
        bound = 10 ** (3 - dps)
    else:
        sol = ls.integrate(osc, [0, 1], t=30, precision=bits, events=events)
        bound = 2.0 ** (12 - bits)  # the orbit's own error at tol = eps: ~1700 units of 2^-bits by t = 6 pi at 512 bits
    assert sol.success, sol.message
    ctx = mp.MPContext()  # a private context: the global mpmath precision stays as it is
    ctx.prec = bits + 64
    for name, ks in (("q", range(1, 10)), ("down", range(1, 10, 2))):
        got = sol.events[name]["t"]
        assert len(got) == len(ks), (name, [float(t) for t in got])
        for k, t_got, y_got in zip(ks, got, sol.events[name]["y"]):
            tf, qf = to_fraction(t_got), to_fraction(y_got[0])
            assert abs(ctx.mpf(tf.numerator) / tf.denominator - k * ctx.pi) < bound
            assert abs(qf) < bound


@pytest.mark.parametrize("engine", ["taylor", "lie"])
def test_every_crossing_of_an_event_that_changes_sign_many_times_in_a_step(engine):
    """sin(40 q) along q(t) = sin t crosses zero where sin t = k pi / 40: 81 times by t = 10, up to seven times
    within one of lie_integrate's six steps. Sampling each step at 8 points found 26 (with 400 q: 28 of 834), with
    `success`; every one is found, each once, at the exact time."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + q**2) / 2)
    events = [ls.Event(hy.sin(40 * q), name="s")]
    if engine == "lie":
        sol, bound = ls.lie_integrate(osc, [0, 1], t=10, dps=30, events=events), 1e-28
    else:
        sol, bound = ls.integrate(osc, [0, 1], t=10, precision=113, events=events), 1e-30
    assert sol.success, sol.message
    ctx = mp.MPContext()
    ctx.prec = 200
    exact_t = set()
    for k in range(-12, 13):  # |k pi / 40| <= 1
        a = ctx.asin(k * ctx.pi / 40)
        for base in (a, ctx.pi - a):
            for n in range(-1, 3):
                if 0 < base + 2 * n * ctx.pi <= 10:
                    exact_t.add(base + 2 * n * ctx.pi)
    exact_t = sorted(exact_t)
    got = [ctx.mpf(to_fraction(t).numerator) / to_fraction(t).denominator for t in sol.events["s"]["t"]]
    assert len(got) == len(exact_t) == 81
    assert max(abs(a - b) for a, b in zip(got, exact_t)) < bound


@pytest.mark.parametrize("above", ["1e-8", "1e-20", "1e-29", "0", "-1e-20"])
def test_a_pair_of_crossings_around_a_shallow_dip(above):
    """q = p0 sin t reaches q = 1 when p0 > 1: two crossings of q - 1, 2 sqrt(2 (p0 - 1)) apart, at asin(1/p0) and
    pi - asin(1/p0); none when p0 <= 1. A dip of 1e-20 lies below the accuracy of the step's interpolant (2^-40 of
    the event's size) and was missed (heyoka in quad found it); its bottom is now looked at on the event itself."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + q**2) / 2)
    p0 = 1 + Fraction(above)
    sol = ls.lie_integrate(osc, [0, p0], t=3, dps=30, events=[ls.Event(q - 1.0, name="top")])
    assert sol.success, sol.message
    ctx = mp.MPContext()
    ctx.prec = 200
    got = [ctx.mpf(to_fraction(t).numerator) / to_fraction(t).denominator for t in sol.events["top"]["t"]]
    if p0 <= 1:
        assert got == []
        return
    first = ctx.asin(ctx.mpf(p0.denominator) / p0.numerator)
    assert len(got) == 2
    assert abs(got[0] - first) < 1e-19 and abs(got[1] - (ctx.pi - first)) < 1e-19


def test_an_event_through_a_pole_is_no_crossing_and_is_said_to_be_unresolved():
    """1/M2 changes sign through poles, never through zero: lie_integrate reports no crossing, and says that near
    them no piece of a step resolved it (its warning and `stats.extra["events_unresolved"]`)."""
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    with pytest.warns(RuntimeWarning, match=r"not resolved on some steps \('event0': [0-9]+\).*a pole"):
        sol = ls.lie_integrate(body, y0, t=16, dps=20, events=[ls.Event(lambda b: 1 / b.poisson.variables[10])])
    assert sol.success, sol.message
    assert len(sol.events["event0"]["t"]) == 0 and sol.stats.extra["events_unresolved"]["event0"] >= 1


@pytest.mark.parametrize("engine", ["double", 200, "lie"])
def test_a_tangency_is_not_a_crossing_and_does_not_stop_a_run(engine, m2_zeros):
    """M2**2 touches zero where M2 crosses (t = 7.25..., 14.69...) but never changes sign: both engines report
    crossings (sign changes) only, so none, and a terminal M2**2 does not stop the run. heyoka alone reported 14.69
    twice (9e-10 off) and missed 7.25; as a terminal event it stopped at 14.69 in double and at 7.25 at 200 bits
    (lie_integrate ran to the end). The non-terminal and terminal events are checked in one run: a stop at a
    tangency would also cut the M2 crossings short."""
    body = ls.EulerPoisson(INERTIA)
    y0 = body.initial_state(omega=OMEGA)
    events = [ls.Event(lambda b: m2(b) ** 2, name="touch"), ls.Event(m2, name="m2"),
              ls.Event(lambda b: m2(b) ** 2, terminal=True, name="stop")]
    if engine == "lie":
        sol = ls.lie_integrate(body, y0, t=T, dps=20, events=events)
    else:
        sol = ls.integrate(body, y0, t=T, precision=engine, events=events)
    assert sol.success, sol.message
    assert to_fraction(sol.t_reached) == T
    assert len(sol.events["touch"]["t"]) == 0 and len(sol.events["stop"]["t"]) == 0
    assert len(sol.events["m2"]["t"]) == len(m2_zeros) >= 2  # the crossings of M2 itself stay
    for (t_ref, _), t_got in zip(m2_zeros, sol.events["m2"]["t"]):
        assert abs(to_fraction(t_got) - to_fraction(t_ref)) < 1e-12


@pytest.mark.parametrize("precision", ["double", "quad"])
def test_a_terminal_event_zero_without_a_rate_at_the_start_ends_the_run_instead_of_hanging(precision):
    """H = p^2/2 - q + q^2/2 from rest at q = 0: q = 1 - cos t touches 0 at t = 0 with q' = 0 too. heyoka deduces
    the cooldown of a terminal event from the expression's rate there: 0, so it stopped at t = 0 again at once,
    and the run (which goes on from a zero at t0) looped for ever. Now it ends step_collapse at t = 0, saying what
    to do; the non-terminal event runs right (against the closed form), and lie_integrate goes through."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - q + q**2 / 2)
    sol = ls.integrate(osc, [0, 0], t=3, precision=precision, events=[ls.Event(q, terminal=True, name="zero")])
    assert sol.status == "step_collapse" and sol.t_reached == 0
    assert "'zero' is zero there without crossing" in sol.message and "non-terminal" in sol.message
    sol = ls.integrate(osc, [0, 0], t=3, precision=precision, events=[ls.Event(q, name="zero")])
    assert sol.status == "success" and len(sol.events["zero"]["t"]) == 0
    exact = [1 - mp.cos(3), mp.sin(3)]
    assert max(abs(float(a) - float(b)) for a, b in zip(sol.y_reached, exact)) < 1e-14
    lie = ls.lie_integrate(osc, [0, 0], t=3, dps=20, events=[ls.Event(q, terminal=True, name="zero")])
    assert lie.status == "success"


@pytest.mark.parametrize("bits", [113, 200, 333])
@pytest.mark.parametrize("p0, direction, first", [(1, "negative", 1), (-1, "positive", 1), (1, "positive", 2)])
def test_a_one_way_terminal_event_from_a_run_starting_on_its_zero_stops_at_its_first_crossing(bits, p0, direction,
                                                                                               first):
    """q = p0 sin t from q = 0: a terminal event on q that takes one direction stops at the first crossing that
    way, k pi with k = `first`. At >= 179 bits heyoka's root finding misses the crossing in a step that starts on a
    zero, and the run stopped at 3 pi instead of pi, status `event`; lie_integrate is the reference."""
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + q**2) / 2)
    ev = [ls.Event(q, direction=direction, terminal=True, name="stop")]
    sol = ls.integrate(osc, [0, p0], t=20, precision=bits, events=ev)
    assert sol.status == "event" and len(sol.events["stop"]["t"]) == 1
    ctx = mp.MPContext()
    ctx.prec = bits + 32
    tf = to_fraction(sol.t_reached)
    assert abs(ctx.mpf(tf.numerator) / tf.denominator - first * ctx.pi) < 2.0 ** (16 - bits)
    assert to_fraction(sol.events["stop"]["t"][0]) == tf
