"""The paper's general solution of the rigid body (dt61) as an explicit series in t, built symbolically.

Apply exp(t L) with R0 symbolic, then substitute R0 = identity in every term (paper, eq. dt61): what is left is
R(t) = sum_k C_k t^k with matrices C_k that are exact functions of the initial body angular velocity Omega0
alone (and of the inertia tensor, kept exact).
"""

from __future__ import annotations

import warnings

import sympy

from ..models.euler_poisson import EulerPoisson
from ..precision import PrecisionWarning, bits_to_dps, check_order, data_bits, to_fraction
from .literal import literal_series_symbolic

__all__ = ["rigid_body_series"]


def rigid_body_series(body, order: int, omega=None):
    """Coefficients C_0..C_order of R(t) = sum_k C_k t^k for the body starting from R(0) = identity.

    Parameters
    ----------
    body : EulerPoisson
    order : int >= 1
    omega : three numbers, optional
        Initial body angular velocity. Given (exact decimals, Fractions, ints): the C_k are exact rational
        matrices. Omitted: they are sympy expressions in the symbols ``Omega1, Omega2, Omega3``. Binary floats
        (0.1 as a double) are taken at their binary values, with a :class:`~lieseries.PrecisionWarning`, as are
        a body's binary moments of inertia.

    Returns
    -------
    list of sympy.Matrix (3x3)
        C_0 = 1, C_1 = hat(Omega0), C_2 = (hat(Omega0)^2 + hat(dOmega/dt))/2, ...

    Notes
    -----
    Cost grows polynomially with the order: about 0.4 s to order 12 with symbolic Omega0 (exact rational
    arithmetic; the inertia tensor enters as exact rationals). A body with the intermediate bracket moves as with
    Chetaev's from R(0) = identity (both give the Euler-Poisson equations on the orthogonal matrices, which the
    motion keeps): its series is computed from Chetaev's form.
    """

    if not isinstance(body, EulerPoisson):
        raise TypeError(f"`body` must be an EulerPoisson model; got {type(body).__name__}")
    order = check_order(order)
    coarse = []
    for name, bits in body.poisson.coarse_data().items():
        coarse.append((f"the body's `{name}`", bits))
    if omega is None:
        om = list(sympy.symbols("Omega1 Omega2 Omega3", real=True))
    else:
        if isinstance(omega, (str, bytes)) or not hasattr(omega, "__len__") or len(omega) != 3:
            raise ValueError(f"`omega` must be three numbers (the initial body angular velocity); got {omega!r}")
        om = [sympy.Rational(f.numerator, f.denominator)
              for f in (to_fraction(w, f"omega[{i}]") for i, w in enumerate(omega))]
        bits = data_bits(list(omega))
        if bits is not None:
            coarse.append(("`omega`", int(bits)))
    for what, bits in coarse:
        warnings.warn(f"{what} carries only {bits} bits ({bits_to_dps(bits)} digits: binary numbers such as the double "
                      "0.1 are roundings of what was typed): the C_k are exact for those binary values, not for the "
                      "decimals you may have meant. Pass exact values (strings like '0.1', ints, Fractions).",
                      PrecisionWarning, stacklevel=2)
    if body.bracket != "chetaev":  # the same motion from R(0) = identity (docstring)
        body = EulerPoisson(body.inertia_exact, bracket="chetaev")
    ps = body.poisson
    I = [[sympy.Rational(v.numerator, v.denominator) for v in row] for row in body.inertia_exact]
    M = [sum(I[i][j] * om[j] for j in range(3)) for i in range(3)]
    subs = {f"R{i + 1}{j + 1}": int(i == j) for i in range(3) for j in range(3)}
    subs.update({f"M{i + 1}": M[i] for i in range(3)})
    pars = [sympy.Rational(p.numerator, p.denominator) for p in ps.parameter_values]
    coeffs = literal_series_symbolic(ps.variables, ps.vector_field, order, substitute=subs, pars=pars)
    return [
        sympy.Matrix(3, 3, [sympy.simplify(coeffs[3 * i + j][k]) for i in range(3) for j in range(3)])
        for k in range(order + 1)
    ]
