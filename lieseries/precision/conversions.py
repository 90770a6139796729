"""Exact conversions: any number the package reads as an exact rational (:func:`to_fraction`), within the bounds
of :mod:`lieseries.precision.bounds`; as mpmath's raw number or an mpf rounded once to a working precision
(:func:`to_raw`, :func:`to_mpf`); digits <-> bits (:func:`dps_to_bits`, :func:`bits_to_dps`)."""

from __future__ import annotations

import decimal
import math
import numbers
import re
import sys
from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np

from .bounds import MAX_DIGITS, MAX_DPS, MAX_EXPONENT


def dps_to_bits(dps: int) -> int:
    """Bits needed to hold ``dps`` decimal digits (mpmath's own rule)."""
    return mp.libmp.dps_to_prec(int(dps))


def bits_to_dps(bits: int) -> int:
    """Decimal digits held by ``bits`` bits (mpmath's own rule)."""
    return mp.libmp.prec_to_dps(int(bits))


def to_fraction(value, argname: str = "value") -> Fraction:
    """The exact rational value of a number.

    Accepts int, :class:`fractions.Fraction`, a decimal or "p/q" string ("0.1" is exactly 1/10),
    :class:`decimal.Decimal`, float and numpy floats (their exact binary value), :class:`mpmath.mpf`,
    sympy Rational/Float, ``heyoka.real`` and ``heyoka.real128``.

    Raises
    ------
    TypeError
        When ``value`` is not a real number, naming ``argname``.
    ValueError
        When ``value`` is NaN or infinite, naming ``argname``.
    """
    if type(value) is float and math.isfinite(value):  # the common case, within bounds by construction
        return Fraction(*value.as_integer_ratio())
    return _bounded(_exact_value(value, argname), argname)


def short_decimal(f: Fraction) -> str:
    """A short decimal rendering of a possibly huge exact value (for messages)."""
    if f == 0:
        return "0"
    e = _log10_abs(f)
    if abs(e) < 300:
        return f"{float(f):.6g}"
    return f"{'-' if f < 0 else ''}~1e{int(round(e))}"


def _log10_abs(f: Fraction) -> float:
    n, d = abs(f.numerator), f.denominator
    return (n.bit_length() - d.bit_length()) * math.log10(2)


_HUGE = 10**MAX_EXPONENT


def _bounded(f: Fraction, argname: str) -> Fraction:
    """``f`` when 10**-MAX_EXPONENT <= |f| <= 10**MAX_EXPONENT or f == 0 (exactly: the estimate from bit lengths
    only decides far from the bounds), else a ValueError naming ``argname``."""
    if f == 0:
        return f
    e = abs(_log10_abs(f))
    if e > MAX_EXPONENT + 1 or (e > MAX_EXPONENT - 1 and not (
            abs(f.numerator) * _HUGE >= f.denominator and abs(f.numerator) <= _HUGE * f.denominator)):
        raise ValueError(
            f"`{argname}` = {short_decimal(f)} is out of range: numbers must lie within 1e-{MAX_EXPONENT} .. "
            f"1e{MAX_EXPONENT} in magnitude (or be 0)"
        )
    return f


_DECIMAL = re.compile(r"^\s*[+-]?(\d+\.?\d*|\.\d+)([eE]([+-]?\d+))?\s*$")
_RATIO = re.compile(r"^\s*[+-]?\d+\s*/\s*[+-]?\d+\s*$")


def _string_fraction(value: str, argname: str) -> Fraction:
    text = value.strip()
    m = _DECIMAL.match(text)
    if m:
        digits = len(m.group(1)) - ("." in m.group(1))
        if digits > MAX_DIGITS:
            raise ValueError(
                f"`{argname}` is written with {digits} digits ({text[:20]}...); lieseries reads numbers of at most "
                f"{MAX_DIGITS} digits (a run uses at most {MAX_DPS}). Round it to the digits you need, or pass a "
                "Fraction."
            )
        if m.group(3) is not None and (len(m.group(3)) > 12 or abs(int(m.group(3))) > MAX_EXPONENT + len(m.group(1))):
            raise ValueError(
                f"`{argname}` = {value[:40]!r} is out of range: numbers must lie within 1e-{MAX_EXPONENT} .. "
                f"1e{MAX_EXPONENT} in magnitude (or be 0)"
            )
        return Fraction(decimal.Decimal(text))  # exact, and not limited by Python's int-string conversion limit
    if _RATIO.match(text):
        if len(text) > 2 * MAX_EXPONENT:
            raise ValueError(f"`{argname}` = {value[:40]!r}... is too long a ratio (at most {2 * MAX_EXPONENT} "
                             "characters); pass a Fraction")
        num, den = (int(decimal.Decimal(part)) for part in text.split("/"))
        if den == 0:
            raise ValueError(f"`{argname}` = {value!r} divides by zero")
        return Fraction(num, den)
    lowered = text.lower()
    if lowered.lstrip("+-") in ("inf", "infinity", "nan"):
        raise ValueError(f"`{argname}` must be finite; got {value!r}")
    raise ValueError(
        f"`{argname}` must be a number; could not read the string {value!r} (use decimals like '0.1', "
        "'1e-3' or ratios like '1/3')"
    )


def _exact_value(value, argname: str) -> Fraction:
    if isinstance(value, Fraction):
        return value
    if isinstance(value, bool):
        raise TypeError(f"`{argname}` must be a real number; got bool {value!r}")
    if isinstance(value, numbers.Integral):
        return Fraction(int(value))
    if isinstance(value, str):
        return _string_fraction(value, argname)
    if isinstance(value, decimal.Decimal):
        if not value.is_finite():
            raise ValueError(f"`{argname}` must be finite; got {value}")
        if abs(value.adjusted()) > MAX_EXPONENT + 1:
            raise ValueError(f"`{argname}` = {value} is out of range (|exponent| > {MAX_EXPONENT})")
        return Fraction(value)
    if type(value).__module__.startswith("sympy"):
        return _sympy_to_fraction(value, argname)
    if hasattr(value, "_mpf_"):  # an mpf of any mpmath context
        sign, man, exp, _ = value._mpf_  # (mpf.man_exp drops the sign)
        if not man:
            if exp:
                raise ValueError(f"`{argname}` must be finite; got {value}")
            return Fraction(0)
        if abs(exp + int(man).bit_length()) > 4 * MAX_EXPONENT:  # the magnitude, whatever the mantissa's length
            raise ValueError(f"`{argname}` = {value} is out of range (|x| beyond 1e{MAX_EXPONENT})")
        f = Fraction(int(man) << exp) if exp >= 0 else Fraction(int(man), 1 << -exp)
        return _bounded(-f if sign else f, argname)
    if hasattr(value, "_mpc_"):
        raise TypeError(f"`{argname}` must be a real number; got the complex {value}")
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            raise ValueError(f"`{argname}` must be finite; got {value}")
        n, d = value.as_integer_ratio()
        return Fraction(int(n), int(d))
    if isinstance(value, (hy.real, hy.real128)):
        s = str(value)
        if any(c in s.lower() for c in ("nan", "inf")):
            raise ValueError(f"`{argname}` must be finite; got {s}")
        bits = value.prec if isinstance(value, hy.real) else 113
        if bits > 4 * MAX_DPS:
            raise ValueError(f"`{argname}` is a {bits}-bit number; lieseries takes numbers of at most {4 * MAX_DPS} "
                             "bits")
        # the printed digits identify the binary value uniquely; round them back to its precision exactly
        raw = mp.libmp.from_str(s, bits + 64, mp.libmp.round_nearest)
        raw = mp.libmp.mpf_pos(raw, bits, mp.libmp.round_nearest)
        return _exact_value(mp.make_mpf(raw), argname)
    if isinstance(value, np.ndarray) and value.ndim == 0:
        return _exact_value(value.item() if value.dtype != object else value[()], argname)
    if isinstance(value, complex) or (isinstance(value, np.generic) and np.iscomplexobj(value)):
        raise TypeError(f"`{argname}` must be a real number; got the complex {value}")
    raise TypeError(f"`{argname}` must be a real number; got {type(value).__name__} {value!r}")


def _sympy_to_fraction(value, argname):
    import sympy

    if isinstance(value, sympy.Rational):
        return Fraction(int(value.p), int(value.q))
    if isinstance(value, sympy.Float):
        return _exact_value(mp.make_mpf(value._mpf_), argname)
    raise TypeError(f"`{argname}` must be an exact number; got the sympy expression {value!r}")


def to_raw(value, bits: int, argname: str = "value") -> tuple:
    """``value`` (an mpf, or anything :func:`to_fraction` reads exactly: ints, Fractions, decimal strings, floats
    at their binary values) as mpmath's raw number, rounded once to ``bits`` bits."""
    if hasattr(value, "_mpf_"):
        raw = value._mpf_
        if not raw[1] and raw[2]:  # inf or nan
            raise ValueError(f"`{argname}` must be finite; got {value}")
        return mp.libmp.mpf_pos(raw, bits, mp.libmp.round_nearest)
    f = to_fraction(value, argname)
    return mp.libmp.from_rational(f.numerator, f.denominator, bits, mp.libmp.round_nearest)


def to_mpf(value, argname: str = "value", ctx=None) -> mp.mpf:
    """``value`` as an mpf of context ``ctx`` (mpmath's global one by default; the engines pass their thread's
    :func:`mp_context`), rounded once to that context's working precision (:func:`to_raw`)."""
    ctx = mp.mp if ctx is None else ctx
    return ctx.make_mpf(to_raw(value, ctx.prec, argname))


def float_or_mpf(x):
    """A float from a number (an mpf, a Fraction); the number itself when it is not zero but lies below a float's normal range (an error of 1e-402
    read as 0.0 would claim an exact result; :func:`lieseries.formatting.fmt_sci` prints it with its exponent)."""
    try:
        f = float(x)
    except (TypeError, ValueError, OverflowError):  # pragma: no cover - defensive
        return float("nan")
    # a subnormal float keeps a few bits only (a G of 5e-322 is 1e-322 +- 5e-324): below the normal range too
    return x if (f == 0 and x != 0) or 0 < abs(f) < sys.float_info.min else f
