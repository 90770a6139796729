"""The paper's general solution of the rigid body (dt61) as an explicit series in t, built symbolically.

Apply exp(t L) with R0 symbolic, then substitute R0 = identity in every term (paper, eq. dt61): what is left is
R(t) = sum_k C_k t^k with matrices C_k that are exact functions of the initial body angular velocity Omega0
alone (and of the inertia tensor, kept exact).
"""

from __future__ import annotations

import sympy

from ..models.euler_poisson import EulerPoisson
from ..precision import check_order, to_fraction
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
        matrices. Omitted: they are sympy expressions in the symbols ``Omega1, Omega2, Omega3``.

    Returns
    -------
    list of sympy.Matrix (3x3)
        C_0 = 1, C_1 = hat(Omega0), C_2 = (hat(Omega0)^2 + hat(dOmega/dt))/2, ...

    Notes
    -----
    Cost grows polynomially with the order: about 0.4 s to order 12 with symbolic Omega0 (exact rational
    arithmetic; the inertia tensor enters as exact rationals).
    """

    if not isinstance(body, EulerPoisson):
        raise TypeError(f"`body` must be an EulerPoisson model; got {type(body).__name__}")
    order = check_order(order)
    ps = body.poisson
    I = [[sympy.Rational(v.numerator, v.denominator) for v in row] for row in body.inertia_exact]
    if omega is None:
        om = list(sympy.symbols("Omega1 Omega2 Omega3", real=True))
    else:
        if len(omega) != 3:
            raise ValueError(f"`omega` must be three numbers; got {len(omega)}")
        om = [sympy.Rational(f.numerator, f.denominator)
              for f in (to_fraction(w, f"omega[{i}]") for i, w in enumerate(omega))]
    M = [sum(I[i][j] * om[j] for j in range(3)) for i in range(3)]
    subs = {f"R{i + 1}{j + 1}": int(i == j) for i in range(3) for j in range(3)}
    subs.update({f"M{i + 1}": M[i] for i in range(3)})
    pars = [sympy.Rational(p.numerator, p.denominator) for p in ps.parameter_values]
    coeffs = literal_series_symbolic(ps.variables, ps.vector_field, order, substitute=subs, pars=pars)
    return [
        sympy.Matrix(3, 3, [sympy.simplify(coeffs[3 * i + j][k]) for i in range(3) for j in range(3)])
        for k in range(order + 1)
    ]
