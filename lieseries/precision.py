"""The one owner of precision: names <-> bits <-> dps, and exact conversions.

Every number that enters lieseries (a model parameter, an initial state, a time) is first turned into an exact
rational (:class:`fractions.Fraction`) or kept as an exact binary value, and only then rounded once, correctly, to
the working precision. This is what lets a 237-bit run reach 1e-70: nothing is folded through a double on the way.

Precision names
---------------
``"double"``       IEEE binary64 (53 bits), numpy ``float64``
``"long double"``  the platform's ``long double`` (64 bits on x86-64), numpy ``longdouble``
``"quad"``         IEEE binary128 (113 bits), ``heyoka.real128``
``int`` n          arbitrary precision with n bits, ``heyoka.real``
"""

from __future__ import annotations

import decimal
import math
import numbers
from dataclasses import dataclass
from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np

__all__ = [
    "MIN_DPS",
    "check_dps",
    "check_order",
    "Precision",
    "resolve_precision",
    "to_fraction",
    "to_mpf",
    "dps_to_bits",
    "bits_to_dps",
]

_ALIASES = {
    "double": "double",
    "float64": "double",
    "binary64": "double",
    "long double": "long double",
    "longdouble": "long double",
    "quad": "quad",
    "binary128": "quad",
    "real128": "quad",
}


#: Fewest decimal digits an mpmath computation (Lie series, references) accepts.
MIN_DPS = 5


def check_dps(dps, argname: str = "dps") -> int:
    """Validate a number of decimal digits (an integer >= MIN_DPS) and return it as an int."""
    if isinstance(dps, bool) or not isinstance(dps, numbers.Integral):
        raise TypeError(f"`{argname}` must be an integer number of decimal digits >= {MIN_DPS}; got {dps!r}")
    if dps < MIN_DPS:
        raise ValueError(f"`{argname}` must be at least {MIN_DPS} decimal digits; got {dps}")
    return int(dps)


def check_order(order, argname: str = "order") -> int:
    """Validate a series order (an integer >= 1) and return it as an int."""
    if isinstance(order, bool) or not isinstance(order, numbers.Integral):
        raise TypeError(f"`{argname}` must be an integer >= 1; got {type(order).__name__} {order!r}")
    if order < 1:
        raise ValueError(f"`{argname}` must be an integer >= 1; got {order}")
    return int(order)


def dps_to_bits(dps: int) -> int:
    """Bits needed to hold ``dps`` decimal digits (mpmath's own rule)."""
    return mp.libmp.dps_to_prec(int(dps))


def bits_to_dps(bits: int) -> int:
    """Decimal digits held by ``bits`` bits (mpmath's own rule)."""
    return mp.libmp.prec_to_dps(int(bits))


@dataclass(frozen=True)
class Precision:
    """A floating-point format that heyoka integrates in.

    Attributes
    ----------
    name : str
        ``"double"``, ``"long double"``, ``"quad"`` or ``"real<bits>"``.
    bits : int
        Significand bits (53, 64, 113, or the arbitrary-precision setting).
    """

    name: str
    bits: int

    @property
    def is_real(self) -> bool:
        """True for heyoka's arbitrary-precision ``real``."""
        return self.name.startswith("real")

    @property
    def fp_type(self):
        """The type heyoka's ``taylor_adaptive`` takes as ``fp_type``."""
        if self.name == "double":
            return float
        if self.name == "long double":
            return np.longdouble
        if self.name == "quad":
            return hy.real128
        return hy.real

    @property
    def eps(self) -> float:
        """Machine epsilon 2**(1 - bits), as a Python float (underflows to 0 only beyond 1074 bits)."""
        return math.ldexp(1.0, 1 - self.bits)

    @property
    def eps_mpf(self) -> mp.mpf:
        """Machine epsilon as an exact mpmath number."""
        return mp.mpf(2) ** (1 - self.bits)

    @property
    def dps(self) -> int:
        """Decimal digits carried by this precision."""
        return bits_to_dps(self.bits)

    @property
    def numpy_dtype(self):
        """The numpy dtype of state arrays in this precision."""
        if self.name == "double":
            return np.dtype(np.float64)
        if self.name == "long double":
            return np.dtype(np.longdouble)
        if self.name == "quad":
            return np.dtype(hy.real128)
        return np.dtype(hy.real)

    # -- conversions -------------------------------------------------------------------------------------------
    def to_native(self, value):
        """Round ``value`` (exact input of any supported kind) once, correctly, to this precision."""
        frac = value if isinstance(value, Fraction) else to_fraction(value, "value")
        if self.name == "double":
            return float(frac)  # Fraction -> float is correctly rounded
        with mp.workprec(self.bits):
            x = mp.mpf(frac.numerator) / frac.denominator  # correctly rounded to `bits`
        return self._mpf_to_native(x)

    def _mpf_to_native(self, x: mp.mpf):
        if self.name == "double":
            return float(x)
        if self.name == "long double":
            if not mp.isfinite(x):
                return np.longdouble(float(x))
            sign, man, exp, _ = x._mpf_
            # split the (<= 64-bit) significand so that each piece converts to long double exactly
            hi, lo = divmod(int(man), 1 << 32)
            v = np.ldexp(np.longdouble(hi), 32) + np.longdouble(lo)
            v = np.ldexp(v, int(exp))
            return -v if sign else v
        digits = bits_to_dps(self.bits) + 10
        s = mp.nstr(x, digits, strip_zeros=False, min_fixed=1, max_fixed=0) if mp.isfinite(x) else str(float(x))
        if self.name == "quad":
            return hy.real128(s)
        return hy.real(s, self.bits)

    def array(self, values) -> np.ndarray:
        """A 1-d (or n-d) numpy array of ``values`` rounded to this precision."""
        arr = np.asarray(values, dtype=object)
        out = [self.to_native(v) for v in arr.ravel()]
        if self.is_real:
            res = np.empty(len(out), dtype=hy.real)
            for i, v in enumerate(out):
                res[i] = v
        else:
            res = np.array(out, dtype=self.numpy_dtype)
        return res.reshape(arr.shape)

    def time(self, t):
        """A time value in this precision (what heyoka's propagate functions take)."""
        return self.to_native(t)

    def __str__(self) -> str:  # pragma: no cover - trivial
        return self.name


_BUILTIN = {
    "double": Precision("double", 53),
    "long double": Precision("long double", int(np.finfo(np.longdouble).nmant) + 1),
    "quad": Precision("quad", 113),
}


def resolve_precision(precision, argname: str = "precision") -> Precision:
    """Turn a user's precision (name, int bits, or Precision) into a :class:`Precision`.

    Raises
    ------
    ValueError, TypeError
        Naming ``argname``, with the accepted values.
    """
    if isinstance(precision, Precision):
        return precision
    if isinstance(precision, str):
        key = _ALIASES.get(precision.strip().lower())
        if key is None:
            raise ValueError(
                f"`{argname}` must be 'double', 'long double', 'quad' or an int number of bits; got {precision!r}"
            )
        return _BUILTIN[key]
    if isinstance(precision, bool) or not isinstance(precision, numbers.Integral):
        raise TypeError(
            f"`{argname}` must be 'double', 'long double', 'quad' or an int number of bits; "
            f"got {type(precision).__name__} {precision!r}"
        )
    bits = int(precision)
    lo, hi = hy.real_prec_min(), min(hy.real_prec_max(), 1 << 20)
    if bits < 2 or bits < lo or bits > hi:
        raise ValueError(f"`{argname}` as a number of bits must lie in [{max(2, lo)}, {hi}]; got {bits}")
    return Precision(f"real{bits}", bits)


def precision_of_dtype(dtype) -> Precision | None:
    """The precision whose state arrays have this numpy dtype (None when none does)."""
    dtype = np.dtype(dtype)
    if dtype == np.float64:
        return _BUILTIN["double"]
    if dtype == np.longdouble and dtype != np.float64:
        return _BUILTIN["long double"]
    if dtype == np.dtype(hy.real128):
        return _BUILTIN["quad"]
    return None


# -- exact conversions ---------------------------------------------------------------------------------------------
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
    if isinstance(value, Fraction):
        return value
    if isinstance(value, bool):
        raise TypeError(f"`{argname}` must be a real number; got bool {value!r}")
    if isinstance(value, numbers.Integral):
        return Fraction(int(value))
    if isinstance(value, str):
        try:
            return Fraction(value.strip())
        except ValueError:
            try:
                return Fraction(float(value))
            except ValueError:
                raise ValueError(f"`{argname}` must be a number; could not read the string {value!r}") from None
            except OverflowError:
                raise ValueError(f"`{argname}` must be finite; got {value!r}") from None
    if isinstance(value, decimal.Decimal):
        if not value.is_finite():
            raise ValueError(f"`{argname}` must be finite; got {value}")
        return Fraction(value)
    if type(value).__module__.startswith("sympy"):
        return _sympy_to_fraction(value, argname)
    if isinstance(value, mp.mpf):
        if not mp.isfinite(value):
            raise ValueError(f"`{argname}` must be finite; got {value}")
        sign, man, exp, _ = value._mpf_  # (mpf.man_exp drops the sign)
        f = Fraction(int(man)) * (Fraction(2) ** int(exp))
        return -f if sign else f
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
        # the printed digits identify the binary value uniquely; round them back to its precision exactly
        with mp.workprec(bits + 64):
            approx = mp.mpf(s)
        with mp.workprec(bits):
            return to_fraction(+approx, argname)
    if isinstance(value, np.ndarray) and value.ndim == 0:
        return to_fraction(value.item() if value.dtype != object else value[()], argname)
    raise TypeError(f"`{argname}` must be a real number; got {type(value).__name__} {value!r}")


def _sympy_to_fraction(value, argname):
    import sympy

    if isinstance(value, sympy.Rational):
        return Fraction(int(value.p), int(value.q))
    if isinstance(value, sympy.Float):
        return to_fraction(mp.mpf(value._mpf_), argname)
    raise TypeError(f"`{argname}` must be an exact number; got the sympy expression {value!r}")


def to_mpf(value, argname: str = "value") -> mp.mpf:
    """``value`` as an mpf rounded once to the current mpmath working precision."""
    if isinstance(value, mp.mpf):
        if not mp.isfinite(value):
            raise ValueError(f"`{argname}` must be finite; got {value}")
        return +value
    f = to_fraction(value, argname)
    return mp.mpf(f.numerator) / f.denominator
