"""The residual checks of a configuration and a velocity against holonomic constraints G_alpha(q) = 0, and the
checks of a user's chart (it solves the constraints) and frame (tangent to them, of full rank) at sample points.

One check for every model on (q^A, ...) with constraints (the formulations of
:class:`~lieseries.models.constrained.ConstrainedSystem` and the double spherical pendulum): a point is on the
surface when |G_alpha(q)| is at most a tolerance times the sum of the absolute values of G_alpha's terms (a
relative residual, so that 1e-50 means the same for a sphere of radius 1e-3 and of 1e3), a velocity is tangent when
|dG_alpha/dq . qdot| is, relative to the sum of |dG_alpha/dq^A qdot^A|. Residuals are summed at RESIDUAL_DPS
digits: at a context's 53 bits, mpf(8)/5 made the tangent velocity (0.8, 0, 0.6) at (0.6, 0, -0.8) miss tangency
by 6e-17 and an exact state was refused by its run.
"""

from __future__ import annotations

import random
from fractions import Fraction

import sympy as sp

from ..precision import thread_mp as mp
from .constrained_derive import exact_number, numeric_rank, show_number, to_mp

__all__ = ["RESIDUAL_DPS", "RESIDUAL_EXACT", "residual_tolerance", "check_surface_residuals", "check_chart",
           "check_frame"]

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


def check_surface_residuals(terms, gradients, qdot, bits, labels, qname="q", vname="qdot", loose=False,
                            coarse_model=None):
    """Refuse (ValueError naming ``qname`` or ``vname``) a point off the constraints or a velocity not tangent.

    ``terms[a]``: the values of the terms of G_a at the point (Fractions or mpf); ``gradients[a]``: dG_a/dq^A at
    the point; ``qdot``: the velocity (Fractions), or None to check the point only; ``bits``: the bits binary data
    carry (None: exact data); ``labels[a]``: how a message shows G_a (``"G1 = x**2 + y**2 - 1"``);
    ``coarse_model``: the model's inputs given as binary numbers, ``{argument: bits}`` (the surface is that of their
    binary values: a message names them)."""
    tol_exact = residual_tolerance(bits, loose)
    note = "" if bits is None else f"; binary floats carry {int(bits)} bits only" + (
        "" if loose else " (a point read from a run's state has drifted off by the run's rounding: continue from "
        "that state itself, whose check allows the square root of its precision, or from a body's "
        "surface_point(state))")
    model_bits = min(coarse_model.values()) if coarse_model else None
    blame = ""
    if coarse_model:
        shown = ", ".join(f"`{k}` ({int(b)} bits)" for k, b in coarse_model.items())
        blame = (f"the model was built from binary numbers, {shown}: its surface is that of their binary values "
                 "(the double 0.7 is 0.6999999999999999555...), which a point exact for the decimals misses. Build "
                 "the model from exact values (strings such as '0.7', Fractions)")
    with mp.workdps(RESIDUAL_DPS):
        tol = _mpf(tol_exact)
        for a, ts in enumerate(terms):
            vals = [_mpf(t) for t in ts]
            res = mp.fsum(vals)
            scale = mp.fsum(abs(t) for t in vals)
            if abs(res) > tol * scale:
                head = (f"`{qname}` is not on the constraint surface: {labels[a]} = {mp.nstr(res, 6)} at it (relative "
                        f"{mp.nstr(abs(res) / scale, 3)} > {mp.nstr(tol, 3)}). ")
                if blame and abs(res) <= scale * mp.mpf(2) ** (8 - int(model_bits)):  # as far off as the model's data
                    raise ValueError(head + blame[0].upper() + blame[1:] + note)
                raise ValueError(
                    head + "Give a point with G = 0 exactly (strings or Fractions: '3/5', '0.6')" + (
                        note or "; a point known to finite precision only (an irrational one): to 55 digits or more, "
                        "or as binary numbers (floats, heyoka.real128, heyoka.real), checked to the bits they carry")
                    + (f"; {blame}" if blame else ""))
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


def check_chart(constraints, q_symbols, vals, sol):
    """Refuse a chart ``sol`` ({dependent coordinate's symbol: expression of the free ones}) that does not solve
    the constraints (``vals``: the parameters' exact values). Each G_alpha must vanish identically once the chart
    is substituted. A nonzero analytic residual vanishes only on a thin set, so it is evaluated at pseudo-random
    rational points where the chart is real (at ``RESIDUAL_DPS`` digits, relative to the size of G's terms there), at
    scales from 1e-3 to 1e3 so that charts of small or large surfaces are sampled inside their domain (four points,
    or those found); sympy's ``simplify`` is not asked to prove the identity (it fails on true ones, e.g. nested
    radicals, and refused valid charts)."""
    free = [q for q in q_symbols if q not in sol]
    chart = {s: e.xreplace(vals) for s, e in sol.items()}
    terms = [[t.xreplace(chart) for t in sp.Add.make_args(g.xreplace(vals))] for g in constraints]
    rng = random.Random(6151 + len(q_symbols))
    checked = 0
    for scale in (1, sp.Rational(1, 10), 10, sp.Rational(1, 100), 100, sp.Rational(1, 1000), 1000):
        for _ in range(16):  # a chart real on a thin set only (a torus' half: a ring) is met rarely
            pt = {q: sp.Rational(rng.randint(-999, 999), 1000) * scale for q in free}
            try:
                for e in chart.values():
                    exact_number(e.xreplace(pt), RESIDUAL_DPS)  # the chart must be real and finite here
                parts = [[exact_number(t.xreplace(pt), RESIDUAL_DPS) for t in ts] for ts in terms]
            except (ValueError, TypeError, ZeroDivisionError):
                continue
            with mp.workdps(RESIDUAL_DPS):
                for i, ps in enumerate(parts):
                    res = mp.fsum(to_mp(v) for v in ps)
                    size = mp.fsum(abs(to_mp(v)) for v in ps)
                    if abs(res) > mp.mpf(10) ** (20 - RESIDUAL_DPS) * (size or 1):
                        where = ", ".join(f"{q} = {pt[q]}" for q in free)
                        raise ValueError(
                            f"`chart` does not solve the constraints: G{i + 1} = {constraints[i]} is "
                            f"{mp.nstr(res, 8)} (not 0) with it at {where}; give the dependent coordinates as "
                            "the solution of G = 0 (e.g. x3 = sqrt(c**2 - x1**2 - x2**2))")
            checked += 1
            if checked == 4:
                return
    if checked:  # fewer points: still random ones, where a wrong chart's residual vanishes only by accident
        return
    raise ValueError("`chart`: found no point where the chart is real and finite (free coordinates sampled in "
                     "boxes from 1e-3 to 1e3), so it cannot be checked to solve the constraints; check its "
                     "expressions and the parameters' values")


def check_frame(constraints, q_symbols, vals, F):
    """Refuse a user frame ``F`` (rows: vector fields in ``q_symbols``; ``vals``: the parameters' exact values)
    that is not tangent to the constraints or not a basis. A user frame must be tangent to every level set of the constraints (G_alpha,A G_iA = 0, p9) and of full
    rank: checked exactly at pseudo-random rational points (numerically at 60 digits where irrational)."""
    k = len(constraints)
    d = F.shape[0]
    Gq = sp.Matrix([[sp.diff(g, qa) for qa in q_symbols] for g in constraints])
    rng = random.Random(4049 + len(q_symbols))
    checked = 0
    for _ in range(12):
        pt = {qa: sp.Rational(rng.randint(300, 1300), 1000) for qa in q_symbols}
        pt.update(vals)
        Fp = F.xreplace(pt)
        if any(e.has(sp.zoo, sp.nan, sp.oo) for e in Fp):
            continue
        Gp = Gq.xreplace(pt)
        prod = Gp * Fp.T
        for a in range(k):
            for i in range(d):
                val = exact_number(prod[a, i], RESIDUAL_DPS)
                if isinstance(val, Fraction):
                    bad = val != 0
                else:
                    with mp.workdps(RESIDUAL_DPS):
                        size = mp.fsum(abs(to_mp(exact_number(Gp[a, b] * Fp[i, b], RESIDUAL_DPS)))
                                       for b in range(Fp.shape[1]))
                        bad = abs(val) > mp.mpf(10) ** -45 * (size or 1)
                if bad:
                    raise ValueError(
                        f"`frame[{i}]` is not tangent to the constraint surfaces: dG{a + 1}/dq . frame[{i}] = "
                        f"{show_number(val)} at q = {[str(pt[s]) for s in q_symbols]} (it must vanish identically, paper "
                        "p9; e.g. for R^T R = 1 the fields R^-T E_k, E_k antisymmetric)")
        if numeric_rank(Fp) < d:
            raise ValueError(f"`frame` has rank {numeric_rank(Fp)} < {d} at q = {[str(pt[s]) for s in q_symbols]}: its "
                             "vector fields must be linearly independent (a basis of the tangent space)")
        checked += 1
        if checked == 2:
            return
    raise ValueError("`frame` is singular (infinite or undefined) at every sample point; give vector fields "
                     "defined on an open set")
