"""Arb balls of validated runs, shown and checked at their own precision.

python-flint prints a ball at its context's precision (53 bits by default), whatever the ball's own: a 30-digit
enclosure of radius 5e-34 prints as ``[0.274553356446504 +/- 3.54e-16]``, and ``ball.contains(x)`` converts ``x``
at 53 bits too. :func:`ball_str` prints a ball at its own precision and :func:`contains` checks that balls
enclose reference values, both in exact arithmetic: the ball's midpoint and radius are binary numbers, read
exactly, and the reference is taken at its exact value (a decimal string, a Fraction, an mpf).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from .precision import bits_to_dps, thread_mp, to_fraction

__all__ = ["ball_str", "ball_bounds", "contains"]


def _is_ball(value) -> bool:
    return hasattr(value, "mid") and hasattr(value, "rad") and hasattr(value, "is_finite")


def ball_bounds(ball):
    """(midpoint, radius) of an Arb ball as exact Fractions (radius 0 for an exact value).

    Raises
    ------
    TypeError
        When ``ball`` is not an arb ball.
    ValueError
        When it is not finite.
    """
    if not _is_ball(ball):
        raise TypeError(f"`ball` must be an arb ball (flint.arb, as in a validated solution); got "
                        f"{type(ball).__name__}")
    if not ball.is_finite():
        raise ValueError(f"`ball` must be finite; got {ball}")
    man, exp = (int(v) for v in ball.mid().man_exp())
    rman, rexp = (int(v) for v in ball.rad().man_exp())
    return _binary(man, exp), _binary(rman, rexp)


def _binary(man: int, exp: int) -> Fraction:
    return Fraction(man << exp) if exp >= 0 else Fraction(man, 1 << -exp)


def _up3(x: Fraction) -> str:
    """A decimal upper bound of x >= 0 with 3 significant digits."""
    if x == 0:
        return "0"
    e = math.floor(math.log10(x.numerator) - math.log10(x.denominator)) - 2
    scaled = x / Fraction(10) ** e
    m = -((-scaled.numerator) // scaled.denominator)  # ceiling
    if m >= 1000:
        m, e = -((-m) // 10), e + 1
    return f"{m / 100:.2f}e{e + 2:+03d}".replace("e+00", "")


def ball_str(ball, digits: int | None = None) -> str:
    """``[midpoint +/- radius]`` at the ball's own precision.

    Parameters
    ----------
    ball : flint.arb
    digits : int, optional
        Significant digits of the midpoint. Default: those the ball certifies (its midpoint to the digit where
        the radius starts) plus two; all the midpoint's digits for an exact value.

    The radius shown is the ball's plus the rounding of the printed midpoint, rounded up (3 digits): the printed
    ball contains the ball.
    """
    mid, rad = ball_bounds(ball)
    if digits is not None:
        if isinstance(digits, bool) or not isinstance(digits, int) or digits < 1:
            raise ValueError(f"`digits` must be an integer >= 1; got {digits!r}")
    else:
        man = abs(int(ball.mid().man_exp()[0]))
        full = bits_to_dps(max(man.bit_length(), 1)) + 2
        if rad == 0 or mid == 0:
            digits = full
        else:
            digits = max(1, min(full, int(math.floor(math.log10(abs(mid) / rad))) + 2))
    ctx = thread_mp
    mid_mpf = ctx.make_mpf(ctx.libmp.from_man_exp(*(int(v) for v in ball.mid().man_exp())))
    shown = ctx.nstr(mid_mpf, digits, min_fixed=-5, max_fixed=digits + 1)
    # the printed midpoint's rounding is added to the radius: the printed ball contains the ball
    rad = rad + abs(mid - Fraction(shown))
    return f"[{shown} +/- {_up3(rad)}]" if rad else f"[{shown}]"


def contains(balls, reference, tol=0) -> bool:
    """True when every ball encloses the corresponding reference value, checked exactly.

    Parameters
    ----------
    balls : arb ball, a row of balls, or rows of them (``sol.y`` of a validated run, or ``sol.y[i]``)
    reference : the same shape: numbers as decimal strings, Fractions, ints, mpf (an exact closed form), or a
        model state built from exact input (its exact values); floats are taken at their binary values
    tol : number, optional
        The reference's own uncertainty (e.g. 10**-40 for a closed form at 40 digits): a value counts as enclosed
        when it lies within ``radius + tol`` of the midpoint. Default 0: the reference is exact.

    Raises
    ------
    ValueError
        When the shapes differ (naming ``reference``).
    """
    t = to_fraction(tol, "tol")
    if t < 0:
        raise ValueError(f"`tol` must be >= 0; got {tol!r}")
    pairs = _pairs(balls, reference, "reference")
    for ball, ref in pairs:
        mid, rad = ball_bounds(ball)
        if abs(ref - mid) > rad + t:
            return False
    return True


def _pairs(balls, reference, argname):
    if _is_ball(balls):
        return [(balls, _exact(reference, argname))]
    rows_b = list(balls)
    exact = getattr(reference, "exact", None)
    rows_r = list(exact) if exact is not None else (
        list(reference) if not isinstance(reference, (str, bytes)) and np.ndim(reference) > 0
        or isinstance(reference, (list, tuple)) else None)
    if rows_r is None or len(rows_r) != len(rows_b):
        raise ValueError(f"`{argname}` must have the shape of the balls ({len(rows_b)} entries); got "
                         f"{type(reference).__name__} {str(reference)[:60]}")
    out = []
    for i, (b, r) in enumerate(zip(rows_b, rows_r)):
        out += _pairs(b, r, f"{argname}[{i}]")
    return out


def _exact(value, argname) -> Fraction:
    return to_fraction(value, argname)
