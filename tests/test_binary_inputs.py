"""Model states built from binary floats (the double 0.1) carry that fact into every engine, as arrays of doubles do."""

import pickle
import warnings
from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest

import lieseries as ls
from lieseries import exact

BODY = (1, 2, 3)


def _precision_warnings(fn):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = fn()
    return out, [str(x.message) for x in w if issubclass(x.category, ls.PrecisionWarning)]


def _max_err(rows, ref):
    return max(abs(mp.mpf(a) - mp.mpf(b)) for a, b in zip(rows, ref))


def test_binary_omega_state_carries_53_bits_and_names_the_argument():
    body = ls.EulerPoisson(BODY)
    y0 = body.initial_state(omega=(1, 0.1, 0.5))
    assert y0.data_bits == 53
    assert y0.binary_inputs == ("omega[1]",)
    # the exact values the engines read say so too, and survive pickling
    assert all(ls.precision.carried_bits(v) == 53 for v in y0.exact)
    assert pickle.loads(pickle.dumps(y0)).data_bits == 53
    # 1.0 and 0.5 are what was typed: exact; so are strings and Fractions
    for om in ((1, "0.1", 0.5), (1.0, Fraction(1, 10), 0.5), (1, 2, 0.375)):
        s = body.initial_state(omega=om)
        assert s.data_bits is None and s.binary_inputs == ()


def test_binary_state_error_estimate_covers_the_error_against_the_intended_problem():
    body = ls.EulerPoisson(BODY)
    y0 = body.initial_state(omega=(1, 0.1, 0.5))
    series, msgs = _precision_warnings(lambda: ls.lie_series(body, y0, order=30, dps=70))
    assert len(msgs) == 1 and "`omega[1]`" in msgs[0] and "'0.1'" in msgs[0] and "Fraction" in msgs[0]
    assert series.data_bits == 53
    # the intended problem (omega_2 = 1/10 exactly), from the closed form at 80 digits
    ref = exact.euler_poisson(BODY, (1, "0.1", "0.5"), "0.1", dps=80)
    with mp.workdps(80):
        err = _max_err(series("0.1"), ref)
        est = series.error_estimate("0.1")
    assert 1e-18 < err < 1e-16  # the binary 0.1 differs from 1/10 by 5.6e-18
    assert est >= err  # was 4.3e-45
    # the same as the array of doubles gives
    arr = np.asarray(y0, dtype=float)
    s2, _ = _precision_warnings(lambda: ls.lie_series(body, arr, order=30, dps=70))
    assert s2.data_bits == series.data_bits


@pytest.mark.parametrize("engine", ["lie_integrate", "validated_integrate", "integrate"])
def test_every_engine_warns_once_naming_omega(engine):
    body = ls.EulerPoisson(BODY)
    y0 = body.initial_state(omega=(1, 0.1, 0.5))
    run = {
        "lie_integrate": lambda: ls.lie_integrate(body, y0, t="0.1", dps=40),
        "validated_integrate": lambda: ls.validated_integrate(body, y0, t="0.05", dps=30),
        "integrate": lambda: ls.integrate(body, y0, t="0.1", precision="quad"),
    }[engine]
    _sol, msgs = _precision_warnings(run)
    assert len(msgs) == 1, msgs
    assert "`omega[1]`" in msgs[0]
    # exact input: no warning
    y1 = body.initial_state(omega=(1, "0.1", 0.5))
    run2 = {
        "lie_integrate": lambda: ls.lie_integrate(body, y1, t="0.1", dps=40),
        "validated_integrate": lambda: ls.validated_integrate(body, y1, t="0.05", dps=30),
        "integrate": lambda: ls.integrate(body, y1, t="0.1", precision="quad"),
    }[engine]
    assert _precision_warnings(run2)[1] == []


def test_ensemble_of_binary_states_warns():
    body = ls.EulerPoisson(BODY)
    y0 = body.initial_state(omega=(1, 0.1, 0.5))
    _sol, msgs = _precision_warnings(lambda: ls.integrate(body, [y0, y0], t="0.1", precision="quad"))
    assert len(msgs) == 1 and "`omega[1]`" in msgs[0]
    y1 = body.initial_state(omega=(1, "0.1", 0.5))
    assert _precision_warnings(lambda: ls.integrate(body, [y1, y1], t="0.1", precision="quad"))[1] == []


def test_sphere_state_from_binary_position_names_it():
    sph = ls.SphereDirac()
    y0 = sph.initial_state(x=(0.6, 0, 0.8), v=(0, 1, 0))
    assert y0.data_bits == 53 and set(y0.binary_inputs) == {"x[0]", "x[2]"}
    assert sph.initial_state(x=("0.6", 0, "0.8"), v=(0, 1, 0)).data_bits is None


def test_state_rounded_to_a_wider_format_from_binary_input_says_so():
    """A quad state of the double 0.1 has a 53-bit significand that looks like 113 bits of data: said at once."""
    body = ls.EulerPoisson(BODY)
    with pytest.warns(ls.PrecisionWarning, match=r"rounded to quad.*`omega\[1\]`.*53 bits"):
        body.initial_state(omega=(1, 0.1, 0.5), precision="quad")
    with warnings.catch_warnings():
        warnings.simplefilter("error", ls.PrecisionWarning)
        body.initial_state(omega=(1, 0.1, 0.5), precision="double")  # nothing lost, nothing to say
        body.initial_state(omega=(1, "0.1", 0.5), precision="quad")


@pytest.mark.parametrize("dtype, bits", [(np.float32, 24), (np.float16, 11)])
def test_narrow_float_arrays_carry_their_own_bits(dtype, bits):
    """A float32 (float16) array holds every number in at most 24 (11) bits, so its 0.1 is no more exact than a
    double's: lie_series carries its bits and never estimates below them (the truth, against the closed form of
    the decimals, is about 2^-bits), and single runs, validated runs and ensembles warn naming the argument, even
    in double."""
    body = ls.EulerPoisson(BODY)
    y = np.asarray(body.initial_state(omega=(1, "0.1", "0.5")), dtype=dtype)
    series, msgs = _precision_warnings(lambda: ls.lie_series(body, y, order=30, dps=40))
    assert series.data_bits == bits and any(f"{bits} bits" in m for m in msgs)
    truth = _max_err(series("0.01"), exact.euler_poisson(BODY, (1, "0.1", "0.5"), "0.01", dps=50))
    assert truth > mp.mpf(2) ** (-bits - 8) and series.error_estimate("0.01") >= truth / 16
    _, msgs = _precision_warnings(lambda: ls.integrate(body, y, t=1))
    assert any("`y0`" in m and f"{bits} bits" in m for m in msgs)
    _, msgs = _precision_warnings(lambda: ls.integrate(body, np.stack([y, y]), t=1, precision="quad"))
    assert any("`Y0`" in m and f"{bits} bits" in m for m in msgs)
    _, msgs = _precision_warnings(lambda: ls.validated_integrate(body, y, t="0.01", dps=20))
    assert any("`y0`" in m and f"{bits} bits" in m for m in msgs)
    exact_y0 = body.initial_state(omega=(1, "0.1", "0.5"))  # output times of the narrow type, in double too
    for t in (np.array([0.1, 0.2], dtype=dtype), dtype(0.1)):
        _, msgs = _precision_warnings(lambda: ls.integrate(body, exact_y0, t=t))
        assert any("`t`" in m and f"{bits} bits" in m for m in msgs), msgs


def test_energy_check_compares_energies_in_the_working_format():
    """The float32 state (1, 0.2, 1.5) gives an H whose 237-bit value lies on a double's rounding midpoint: the
    check rounded H(y0) and H(end) to doubles first and called a sound 3-step run invariant_drift. The run agrees
    with a 400-bit run from the same binary data."""
    body = ls.EulerPoisson(BODY)
    y = np.asarray(body.initial_state(omega=(1, "0.1", "0.5")), dtype=np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ls.PrecisionWarning)
        sol = ls.integrate(body, y, t=1, precision=237)
        ref = ls.integrate(body, y, t=1, precision=400, tol=mp.mpf(2) ** -390)
    assert sol.status == "success", sol.message
    diff = max(abs(ls.precision.to_fraction(a) - ls.precision.to_fraction(b)) for a, b in zip(sol.y[-1], ref.y[-1]))
    assert diff < Fraction(1, 2**225)


def test_every_warning_names_the_callers_line():
    """A warning names the user's line, whatever the path through the library (a fixed stacklevel named a line of
    lieseries for ls.integrate, so `warnings.filterwarnings(module=...)` and the printed line pointed inside it)."""
    body = ls.EulerPoisson(BODY)
    y0 = body.initial_state(omega=(1, 0.1, 0.5))
    not_rotation = np.array([1, 0, 0, 0, 1, 0, 0, 0, 2, 1, 0.2, 1.5])
    calls = {
        "integrate": lambda: ls.integrate(body, y0, t="0.1", precision="quad"),
        "integrate, not a rotation": lambda: ls.integrate(body, not_rotation, t="0.1"),
        "lie_integrate": lambda: ls.lie_integrate(body, y0, t="0.1", dps=40),
        "lie_integrate, low order": lambda: ls.lie_integrate(body, body.initial_state((1, "0.1", "0.5")), t=20,
                                                             dps=30, order=6, max_steps=1),
        "validated_integrate": lambda: ls.validated_integrate(body, y0, t="0.05", dps=30),
        "ensemble": lambda: ls.integrate(body, [y0, y0], t="0.1", precision="quad"),
        "lie_series": lambda: ls.lie_series(body, y0, order=5, dps=40),
        "closed form": lambda: exact.euler_poisson(BODY, (1, 0.1, 0.5), "0.1", dps=30),
        "triangle inequality": lambda: ls.EulerPoisson((1, 1, 3)),
    }
    for what, call in calls.items():
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            call()
        assert w, what
        assert {x.filename for x in w} == {__file__}, (what, [(x.filename, x.lineno) for x in w])


def test_dense_output_at_a_binary_time_says_so():
    """sol(0.3) of a 40-digit Lie run or a quad heyoka run is the state at the double 0.29999999999999998889...:
    one PrecisionWarning naming `t`, as `t=0.3` in the call gives; none for '0.3' or a Fraction, nor in double."""
    body = ls.EulerPoisson(BODY)
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    lie = ls.lie_integrate(body, y0, t=1, dps=40, dense=True)
    quad = ls.integrate(body, y0, t=1, precision="quad", dense=True)
    double = ls.integrate(body, y0, t=1, dense=True)
    for sol in (lie, quad):
        _out, msgs = _precision_warnings(lambda: sol(0.3))
        assert len(msgs) == 1 and "`t`" in msgs[0], msgs
        _out, msgs = _precision_warnings(lambda: sol([0.25, 0.3]))  # 0.25 is exact: 0.3 is not
        assert len(msgs) == 1, msgs
        assert _precision_warnings(lambda: sol("0.3"))[1] == []
        assert _precision_warnings(lambda: sol(Fraction(3, 10)))[1] == []
    assert _precision_warnings(lambda: double(0.3))[1] == []


def test_dense_output_beside_a_large_t0_says_what_its_times_keep_of_t_minus_t0():
    # from t0 = 1e6, sol('1000000.1') in double read the state 0.0999999999767 after t0 (2.3e-11 off the oscillator's
    # closed form) without a word, where the same time in the grid warns; at times the format holds exactly, and
    # from t0 = 0, no warning
    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p * p + q * q) / 2, name="osc")
    for prec, off in (("double", 1e-12), ("quad", 1e-30)):
        sol = ls.integrate(osc, [1, 0], "1000010", t0="1e6", dense=True, precision=prec)
        y, msgs = _precision_warnings(lambda: sol("1000000.1"))
        assert len(msgs) == 1 and "`t` - `t0` = 0.1" in msgs[0] and "dense output" in msgs[0], msgs
        with mp.workdps(40):  # the warning's premise: the state is that of another time
            assert abs(mp.mpf(str(y[0])) - mp.cos(mp.mpf("0.1"))) > off
        assert _precision_warnings(lambda: sol(1000001))[1] == []
        # each time against its own span, whatever else the call asks (a later time hid it)
        assert len(_precision_warnings(lambda: sol(["1000000.1", "1000010"]))[1]) == 1
    sol = ls.integrate(osc, [1, 0], "10", dense=True)
    assert _precision_warnings(lambda: sol("0.1"))[1] == []


def test_a_binary_constant_in_an_event_says_so():
    """q = sin t and the event q - 0.1: the crossing is asin of the double 0.1, 5.6e-18 after asin(1/10). A quad
    or 30-digit run found it to its own precision without a word, where the same 0.1 in the Hamiltonian warns: one
    PrecisionWarning naming `events[0]`, on the caller's line; none in double, none for 10 q - 1."""
    import heyoka as hy

    q, p = hy.make_vars("q", "p")
    osc = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (q**2 + p**2) / 2, name="oscillator")
    with mp.workdps(60):
        binary = mp.asin(mp.mpf(0.1))
    for run in (lambda ev: ls.integrate(osc, [0, 1], t=1, events=[ev], precision="quad"),
                lambda ev: ls.lie_integrate(osc, [0, 1], t=1, events=[ev], dps=30)):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            sol = run(ls.Event(q - 0.1, name="z"))
        msgs = [str(x.message) for x in w if issubclass(x.category, ls.PrecisionWarning)]
        assert len(msgs) == 1 and "`the constant -0.1 in events[0]`" in msgs[0], msgs
        assert {x.filename for x in w} == {__file__}
        with mp.workdps(60):
            t_cross = ls.precision.to_fraction(sol.events["z"]["t"][0])
            assert abs(mp.mpf(t_cross.numerator) / t_cross.denominator - binary) < mp.mpf(10) ** -29
        assert _precision_warnings(lambda: run(ls.Event(10 * q - 1, name="z")))[1] == []
    assert _precision_warnings(lambda: ls.integrate(osc, [0, 1], t=1, events=[ls.Event(q - 0.1)]))[1] == []
