"""The residual checks of a configuration and a velocity against holonomic constraints G_alpha(q) = 0.

One check for every model on (q^A, ...) with constraints (the formulations of
:class:`~lieseries.models.constrained.ConstrainedSystem` and the double spherical pendulum): a point is on the
surface when |G_alpha(q)| is at most a tolerance times the sum of the absolute values of G_alpha's terms (a
relative residual, so that 1e-50 means the same for a sphere of radius 1e-3 and of 1e3), a velocity is tangent when
|dG_alpha/dq . qdot| is, relative to the sum of |dG_alpha/dq^A qdot^A|. Residuals are summed at RESIDUAL_DPS
digits: at a context's 53 bits, mpf(8)/5 made the tangent velocity (0.8, 0, 0.6) at (0.6, 0, -0.8) miss tangency
by 6e-17 and an exact state was refused by its run.
"""

from __future__ import annotations

from fractions import Fraction

from ..precision import thread_mp as mp

__all__ = ["RESIDUAL_DPS", "RESIDUAL_EXACT", "residual_tolerance", "check_surface_residuals"]

#: Digits at which the constraint residuals of a state are measured.
RESIDUAL_DPS = 60
#: Largest relative residual |G| (and |Phi|) of a point built from exact data, at RESIDUAL_DPS digits.
RESIDUAL_EXACT = Fraction(1, 10**50)


def residual_tolerance(bits, loose: bool = False) -> Fraction:
    """Relative residual allowed for data carrying ``bits`` bits (None: exact data). ``loose``: the square root of
    their precision, for a state a run ended in (it has drifted by the run's rounding)."""
    if bits is None:
        return RESIDUAL_EXACT
    b = int(bits) - 4
    return max(RESIDUAL_EXACT, Fraction(1, 2 ** max(1, b // 2 if loose else b)))


def _mpf(v):
    return mp.mpf(v.numerator) / v.denominator if isinstance(v, Fraction) else mp.mpf(v)


def check_surface_residuals(terms, gradients, qdot, bits, labels, qname="q", vname="qdot", loose=False):
    """Refuse (ValueError naming ``qname`` or ``vname``) a point off the constraints or a velocity not tangent.

    ``terms[a]``: the values of the terms of G_a at the point (Fractions or mpf); ``gradients[a]``: dG_a/dq^A at
    the point; ``qdot``: the velocity (Fractions), or None to check the point only; ``bits``: the bits binary data
    carry (None: exact data); ``labels[a]``: how a message shows G_a (``"G1 = x**2 + y**2 - 1"``)."""
    tol_exact = residual_tolerance(bits, loose)
    note = "" if bits is None else f"; binary floats carry {int(bits)} bits only"
    with mp.workdps(RESIDUAL_DPS):
        tol = _mpf(tol_exact)
        for a, ts in enumerate(terms):
            vals = [_mpf(t) for t in ts]
            res = mp.fsum(vals)
            scale = mp.fsum(abs(t) for t in vals)
            if abs(res) > tol * scale:
                raise ValueError(
                    f"`{qname}` is not on the constraint surface: {labels[a]} = {mp.nstr(res, 6)} at it (relative "
                    f"{mp.nstr(abs(res) / scale, 3)} > {mp.nstr(tol, 3)}). Give a point with G = 0 exactly (strings "
                    "or Fractions: '3/5', '0.6')" + note)
        if qdot is None:
            return
        for a, grad in enumerate(gradients):
            vals = [_mpf(g) * _mpf(v) for g, v in zip(grad, qdot)]
            res = mp.fsum(vals)
            scale = mp.fsum(abs(t) for t in vals)
            if abs(res) > tol * scale:
                label = labels[a].split(" = ")[0]
                raise ValueError(
                    f"`{vname}` is not tangent to the constraint surface: d{label}/dq . qdot = {mp.nstr(res, 6)} "
                    f"(relative {mp.nstr(abs(res) / scale, 3)} > {mp.nstr(tol, 3)}). Remove its normal part (the "
                    "motion keeps dG/dt = 0)" + note)
