"""The literal Lie operator (lieseries.lie.literal) against Taylor-mode jets and by hand."""

from fractions import Fraction

import heyoka as hy
import mpmath as mp
import pytest
import sympy

from lieseries.lie import compile_system, taylor_coefficients
from lieseries.lie.literal import (
    is_rational_system,
    lie_derivatives,
    literal_coefficients,
    literal_series_symbolic,
)

from problems import SPHERE_M, max_rel, nonlinear, rigid_body, sphere, sphere_initial  # test systems

# the rigid body's data as exact Fractions (test_jets uses decimal strings for the same numbers)
RB_INERTIA = (1, 2, 3)
RB_PARS = [Fraction(1, i) for i in RB_INERTIA]
RB_OMEGA = (Fraction(1), Fraction(1, 10), Fraction(1, 2))
RB_M0 = [i * w for i, w in zip(RB_INERTIA, RB_OMEGA)]
RB_Y0 = [1, 0, 0, 0, 1, 0, 0, 0, 1] + RB_M0


# --------------------------------------------------------------------------
# Literal vs jets
# --------------------------------------------------------------------------

def test_rigid_body_literal_vs_jets():
    variables, rhs = rigid_body()
    assert is_rational_system(variables, rhs)
    lit = literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 14, 40)
    jet = taylor_coefficients(compile_system(variables, rhs), RB_Y0, RB_PARS, 14, 40)
    with mp.workdps(50):
        assert max_rel(jet, lit) < mp.mpf(10) ** -35


def test_sphere_literal_vs_jets():
    variables, rhs = sphere()
    y0 = sphere_initial(SPHERE_M)
    lit = literal_coefficients(variables, rhs, y0, [SPHERE_M], 12, 40)
    jet = taylor_coefficients(compile_system(variables, rhs), y0, [SPHERE_M], 12, 40)
    with mp.workdps(50):
        assert max_rel(jet, lit) < mp.mpf(10) ** -35
    # a generic point (pi1 != 0, x2 != 0) exercises every term
    y0 = ["0.48", "0.6", "0.64", "0.3", "-1.1"]
    lit = literal_coefficients(variables, rhs, y0, ["0.7"], 12, 40)
    jet = taylor_coefficients(compile_system(variables, rhs), y0, ["0.7"], 12, 40)
    with mp.workdps(50):
        assert max_rel(jet, lit) < mp.mpf(10) ** -35


def test_heyoka_route_agrees_with_exact_route_and_jets():
    variables, rhs = rigid_body()
    a = literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 4, 40, method="heyoka")
    b = literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 4, 40, method="exact")
    with mp.workdps(50):
        assert max_rel(a, b) < mp.mpf(10) ** -37
    variables, rhs = sphere()
    y0 = ["0.48", "0.6", "0.64", "0.3", "-1.1"]
    a = literal_coefficients(variables, rhs, y0, ["0.7"], 3, 40, method="heyoka")
    b = literal_coefficients(variables, rhs, y0, ["0.7"], 3, 40, method="exact")
    with mp.workdps(50):
        assert max_rel(a, b) < mp.mpf(10) ** -37


def test_nonlinear_literal_vs_jets():
    variables, rhs = nonlinear()
    assert not is_rational_system(variables, rhs)
    y0, pars = ["0.3", "-0.7", "1.2"], [Fraction(2, 3)]
    lit = literal_coefficients(variables, rhs, y0, pars, 4, 40)  # auto -> heyoka route
    jet = taylor_coefficients(list(zip(variables, rhs)), y0, pars, 4, 40)
    with mp.workdps(50):
        assert max_rel(jet, lit) < mp.mpf(10) ** -36
    with pytest.raises(ValueError, match="method='heyoka'"):
        literal_coefficients(variables, rhs, y0, pars, 2, 20, method="exact")


def test_oscillator_lie_derivatives():
    x, v = hy.make_vars("x", "v")
    w = hy.par[0]
    L = lie_derivatives([x, v], [v, -w * w * x], x, 4)
    assert len(L) == 5
    X, V, W = (sympy.Symbol(n, real=True) for n in ("x", "v", "par[0]"))
    want = [X, V, -W**2 * X, -W**2 * V, W**4 * X]
    for got, ref in zip(L, want):
        assert sympy.expand(hy.to_sympy(got) - ref) == 0
    both = lie_derivatives([x, v], [v, -w * w * x], [x, v], 2)
    assert len(both) == 3 and len(both[2]) == 2
    lit = literal_coefficients([x, v], [v, -w * w * x], [1, 0], ["1.5"], 20, 30)
    with mp.workdps(40):
        for k in range(0, 21, 2):
            ref = (-1) ** (k // 2) * mp.mpf("1.5") ** k / mp.factorial(k)
            assert abs(lit[k][0] - ref) <= mp.mpf(10) ** -29 * abs(ref)


def test_exact_route_is_correctly_rounded():
    variables, rhs = rigid_body()
    a = literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 6, 25)
    b = literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 6, 60)
    with mp.workdps(25):
        assert all(x == +y for ra, rb in zip(a, b) for x, y in zip(ra, rb))


# --------------------------------------------------------------------------
# Symbolic rigid body series
# --------------------------------------------------------------------------

def _hat(w):
    return sympy.Matrix([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def _identity_subs():
    return {f"R{i}{j}": int(i == j) for i in range(1, 4) for j in range(1, 4)}


def test_symbolic_rigid_body_first_coefficients_by_hand():
    variables, rhs = rigid_body()
    subs = _identity_subs()
    subs.update({f"M{i + 1}": m for i, m in enumerate(RB_M0)})
    pars = [sympy.Rational(p.numerator, p.denominator) for p in RB_PARS]
    series = literal_series_symbolic(variables, rhs, 3, subs, pars=pars)
    Om = [sympy.Rational(w.numerator, w.denominator) for w in RB_OMEGA]
    M0 = sympy.Matrix([sympy.Rational(m.numerator, m.denominator) for m in RB_M0])
    Iinv = sympy.diag(*pars)
    dOm = Iinv * M0.cross(sympy.Matrix(Om))
    c1 = _hat(Om)
    c2 = (_hat(Om) ** 2 + _hat(dOm)) / 2
    for i in range(3):
        for j in range(3):
            s = series[3 * i + j]
            assert s[0] == int(i == j)
            assert s[1] == c1[i, j]
            assert s[2] == c2[i, j]
            assert isinstance(s[3], sympy.Rational)  # exact rationals throughout
    # dM/dt = M x Omega
    dM = M0.cross(sympy.Matrix(Om))
    for i in range(3):
        assert series[9 + i][1] == dM[i]


def test_symbolic_rigid_body_reproduces_jets():
    variables, rhs = rigid_body()
    pars = [sympy.Rational(p.numerator, p.denominator) for p in RB_PARS]
    order = 8
    series = literal_series_symbolic(variables, rhs, order, _identity_subs(), pars=pars)
    Ms = [sympy.Symbol(f"M{i}", real=True) for i in (1, 2, 3)]
    free = set().union(*(e.free_symbols for s in series for e in s))
    assert free == set(Ms)  # coefficients are functions of M0 only
    c1 = [series[k][1] for k in range(9)]
    Om = [pars[i] * Ms[i] for i in range(3)]
    assert sympy.Matrix(3, 3, c1) == _hat(Om)
    sample = {m: sympy.Rational(v.numerator, v.denominator) for m, v in zip(Ms, RB_M0)}
    jet = taylor_coefficients(compile_system(variables, rhs), RB_Y0, RB_PARS, order, 40)
    with mp.workdps(50):
        lit = []
        for k in range(order + 1):
            row = []
            for i in range(12):
                v = series[i][k].xreplace(sample)
                assert isinstance(v, sympy.Rational)
                row.append(mp.mpf(v.p) / v.q)
            lit.append(row)
        assert max_rel(jet, lit) < mp.mpf(10) ** -38


def test_symbolic_with_symbolic_parameters_and_heyoka_route():
    x, v = hy.make_vars("x", "v")
    rhs = [v, -hy.par[0] * x]
    W = sympy.Symbol("par[0]", real=True)
    X0 = sympy.Symbol("x", real=True)
    s = literal_series_symbolic([x, v], rhs, 4, {"v": 0})
    assert sympy.expand(s[0][4] - W**2 * X0 / 24) == 0
    h = literal_series_symbolic([x, v], rhs, 4, {"v": 0}, method="heyoka")
    for a, b in zip(s, h):
        for ea, eb in zip(a, b):
            assert sympy.expand(ea - eb) == 0


def test_literal_bad_input():
    variables, rhs = rigid_body()
    with pytest.raises(ValueError, match="`y0` must have length 12"):
        literal_coefficients(variables, rhs, RB_Y0[:5], RB_PARS, 3, 20)
    with pytest.raises(ValueError, match="`pars` must have length 3; got 1"):
        literal_coefficients(variables, rhs, RB_Y0, RB_PARS[:1], 3, 20)
    with pytest.raises(ValueError, match="`order` must be an integer >= 1; got 0"):
        literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 0, 20)
    with pytest.raises(ValueError, match="`dps` must be at least 15 decimal digits; got 2"):
        literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 3, 2)
    with pytest.raises(ValueError, match="`method`"):
        literal_coefficients(variables, rhs, RB_Y0, RB_PARS, 3, 20, method="fast")
    with pytest.raises(ValueError, match="`rhs` must have one expression per variable"):
        lie_derivatives(variables, rhs[:-1], variables[0], 2)
    with pytest.raises(ValueError, match="`substitute` names `Q`"):
        literal_series_symbolic(variables, rhs, 2, {"Q": 1})
    with pytest.raises(ValueError, match="singular"):
        x3, p = hy.make_vars("x3", "p")
        literal_coefficients([x3, p], [p / x3, x3], [0, 1], [], 2, 20)
