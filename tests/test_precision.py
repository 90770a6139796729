from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np
import pytest

from lieseries.precision import Precision, bits_to_dps, dps_to_bits, resolve_precision, to_fraction, to_mpf


@pytest.mark.parametrize(
    "name,bits",
    [("double", 53), ("long double", int(np.finfo(np.longdouble).nmant) + 1), ("quad", 113), (237, 237), (64, 64)],
)
def test_resolve_names_and_bits(name, bits):
    p = resolve_precision(name)
    assert p.bits == bits
    assert p.eps == 2.0 ** (1 - bits)


@pytest.mark.parametrize("bad", ["single", "float32", "", "doubles"])
def test_unknown_precision_name(bad):
    with pytest.raises(ValueError, match="`precision`"):
        resolve_precision(bad)


@pytest.mark.parametrize("bad", [1.5, None, True, [53]])
def test_precision_wrong_type(bad):
    with pytest.raises(TypeError, match="`precision`"):
        resolve_precision(bad)


def test_precision_bits_out_of_range():
    with pytest.raises(ValueError, match="`precision`"):
        resolve_precision(1)


@pytest.mark.parametrize("prec", ["double", "long double", "quad", 237, 400])
def test_correct_rounding_of_exact_input(prec):
    """0.1 and 1/3 are rounded once, to within half an ulp of the exact rational."""
    p = resolve_precision(prec)
    for exact in (Fraction(1, 10), Fraction(-1, 3), Fraction(22, 7) * 10**5):
        v = p.to_native(exact)
        err = abs(to_fraction(v) - exact) / abs(exact)
        assert err <= Fraction(1, 2 ** p.bits)  # half an ulp, relative
        # the round trip native -> exact -> native is the identity
        assert to_fraction(p.to_native(to_fraction(v))) == to_fraction(v)


def test_to_fraction_kinds():
    assert to_fraction("0.1") == Fraction(1, 10)
    assert to_fraction(0.5) == Fraction(1, 2)
    assert to_fraction(np.float64(0.1)) == Fraction(*0.1.as_integer_ratio())
    assert to_fraction(mp.mpf(-0.75)) == Fraction(-3, 4)
    assert to_fraction(hy.real("-0.75", 100)) == Fraction(-3, 4)
    assert to_fraction(hy.real128("0.375")) == Fraction(3, 8)
    with mp.workdps(50):
        third = mp.mpf(1) / 3
        assert abs(to_fraction(third) - Fraction(1, 3)) < Fraction(1, 10**49)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "nan", mp.inf])
def test_to_fraction_non_finite(bad):
    with pytest.raises(ValueError, match="`x`"):
        to_fraction(bad, "x")


def test_to_fraction_not_a_number():
    with pytest.raises(TypeError, match="`x`"):
        to_fraction(object(), "x")
    with pytest.raises(ValueError, match="`x`"):
        to_fraction("abc", "x")


def test_to_mpf_respects_working_precision():
    with mp.workdps(60):
        x = to_mpf("0.1")
        assert abs(x - mp.mpf(1) / 10) < mp.mpf(10) ** -59
    assert mp.mp.dps == 15  # nothing leaked


def test_dps_bits_roundtrip():
    for dps in (15, 30, 50, 70, 100):
        assert bits_to_dps(dps_to_bits(dps)) >= dps


def test_to_mpf_of_every_kind_is_an_mpf():
    import decimal

    import sympy

    with mp.workdps(40):
        for v in (decimal.Decimal("0.1"), sympy.Rational(1, 10), "0.1", Fraction(1, 10)):
            x = to_mpf(v)
            assert isinstance(x, mp.mpf) and abs(x - mp.mpf(1) / 10) < mp.mpf(10) ** -39


def test_an_mpf_of_many_bits_is_read_exactly():
    """An mpf held at 50000 bits is an ordinary number: its exact value is read (1/24 rounded at 50000 bits differs
    from 1/24 by less than 2^-50000), and the range check looks at its magnitude, not its binary exponent."""
    with mp.workprec(50000):
        x = mp.mpf(1) / 24
    f = to_fraction(x)
    assert abs(f - Fraction(1, 24)) < Fraction(1, 2**49990)
    with mp.workprec(200):
        with pytest.raises(ValueError, match="out of range"):
            to_fraction(mp.mpf(2) ** 14000)


def test_a_grid_of_doubles_is_read_exactly_as_any_other_grid():
    """The fast path for float64 arrays gives the same exact times, direction and refusals as the general path
    (a list of the same doubles), and names a non-finite entry."""
    from lieseries.timegrid import parse_times
    for t in (np.linspace(0, 7, 50)[1:], np.linspace(-1, -3, 9), np.array([0.1, 0.2, 0.3])):
        assert parse_times(t) == parse_times(t.tolist())
        assert all(g == Fraction(*float(v).as_integer_ratio()) for g, v in zip(parse_times(t)[0], t))
    for bad, msg in ((np.array([0.5, np.nan]), r"`t\[1\]` must be finite"),
                     (np.array([0.5, 0.25, 1.0]), "strictly increasing"),
                     (np.array([-0.5, 1.0]), "starts before t0")):
        with pytest.raises(ValueError, match=msg):
            parse_times(bad)


def test_working_digits_and_bits():
    # what the engines work with: the Lie engine's guard digits, the validated engine's guard bits
    lie = Precision.of(dps=50, guard_digits=10)
    assert (lie.working_dps, lie.working_bits) == (60, mp.libmp.dps_to_prec(60))
    arb = Precision.of(dps=50, guard_bits=32)
    assert (arb.working_dps, arb.working_bits) == (50, mp.libmp.dps_to_prec(50) + 32)
    assert Precision.of("quad").working_bits == 113
