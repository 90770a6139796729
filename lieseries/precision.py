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

import contextlib
import contextvars
import decimal
import math
import numbers
import re
import threading
import warnings
from dataclasses import dataclass
from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np

__all__ = [
    "check_flag",
    "MIN_DPS",
    "MAX_DPS",
    "MAX_BITS",
    "MAX_ORDER",
    "MAX_SAMPLES",
    "MAX_TIME_MAGNITUDE",
    "check_time",
    "check_count",
    "MAX_EXPONENT",
    "MAX_DIGITS",
    "EXACT_BITS",
    "PrecisionWarning",
    "carried_bits",
    "CarriedBits",
    "BinaryFraction",
    "binary_inputs",
    "data_bits",
    "warn_if_coarse",
    "mp_context",
    "thread_mp",
    "export_mpf",
    "check_dps",
    "check_tolerance",
    "check_order",
    "Precision",
    "LIE_GUARD_DIGITS",
    "EXACT_GUARD_DIGITS",
    "VALIDATED_GUARD_BITS",
    "resolve_precision",
    "to_fraction",
    "short_decimal",
    "to_mpf",
    "to_raw",
    "exact_states_read_at",
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


#: Fewest decimal digits an mpmath computation (Lie series, references) accepts: below double's 15 digits an
#: mpmath run has nothing to offer over heyoka in double.
MIN_DPS = 15
#: Most decimal digits an mpmath computation accepts (about 33,000 bits).
MAX_DPS = 10_000
#: Most bits heyoka's arbitrary precision is used with: its Taylor order grows like 0.35 bits, and compiling an
#: order-350 integrator of the rigid body already takes seconds (docs/api.md, "Limits").
MAX_BITS = 1024
#: Highest series order the Lie engine computes (the cost grows like order^2 per node of the field).
MAX_ORDER = 2000
#: Times lie within 1e-MAX_TIME_MAGNITUDE .. 1eMAX_TIME_MAGNITUDE in magnitude: runs report the times they reached,
#: and reports plot them, as doubles.
MAX_TIME_MAGNITUDE = 300
#: Most output samples (times) a run or a study keeps.
MAX_SAMPLES = 100_000
#: Largest decimal exponent of an input number (|x| < 10**MAX_EXPONENT, nonzero |x| > 10**-MAX_EXPONENT).
MAX_EXPONENT = 4000
#: Most digits of a number written as a decimal string (a run uses at most MAX_DPS of them).
MAX_DIGITS = 2 * MAX_DPS
#: A binary number whose significand has at most this many significant bits (0.5, 1.25, 3.0, 0.375, ...) is taken
#: as exact: it is what was meant. Anything longer (0.1 as a double) carries its format's precision only.
EXACT_BITS = 32


class PrecisionWarning(UserWarning):
    """A run at a higher precision than its input data carry (binary floats where exact values were meant)."""


def check_dps(dps, argname: str = "dps") -> int:
    """Validate a number of decimal digits (an integer in [MIN_DPS, MAX_DPS]) and return it as an int."""
    if isinstance(dps, bool) or not isinstance(dps, numbers.Integral):
        raise TypeError(
            f"`{argname}` must be an integer number of decimal digits in [{MIN_DPS}, {MAX_DPS}]; got {dps!r}"
        )
    if dps < MIN_DPS:
        raise ValueError(
            f"`{argname}` must be at least {MIN_DPS} decimal digits; got {dps}. For fewer digits use "
            "`lieseries.integrate` in double."
        )
    if dps > MAX_DPS:
        raise ValueError(f"`{argname}` must be at most {MAX_DPS} decimal digits; got {dps}")
    return int(dps)


def check_order(order, argname: str = "order") -> int:
    """Validate a series order (an integer in [1, MAX_ORDER]) and return it as an int."""
    if isinstance(order, bool) or not isinstance(order, numbers.Integral):
        raise TypeError(f"`{argname}` must be an integer >= 1; got {type(order).__name__} {order!r}")
    if order < 1:
        raise ValueError(f"`{argname}` must be an integer >= 1; got {order}")
    if order > MAX_ORDER:
        raise ValueError(
            f"`{argname}` must be at most {MAX_ORDER} (the cost grows like order^2); got {order}. Shorter steps "
            "with a lower order reach the same accuracy."
        )
    return int(order)


def check_count(value, argname: str, *, low: int = 1, high: int | None = None) -> int:
    """Validate an integer count (numpy integers accepted) in [low, high] and return it as an int."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"`{argname}` must be an integer >= {low}; got {type(value).__name__} {value!r}")
    value = int(value)
    if value < low or (high is not None and value > high):
        bound = f"in [{low}, {high}]" if high is not None else f">= {low}"
        raise ValueError(f"`{argname}` must be an integer {bound}; got {value}")
    return value


def check_tolerance(tol, prec: "Precision") -> Fraction:
    """A tolerance in (0, 1), at least the epsilon of ``prec`` (default: that epsilon), as an exact Fraction."""
    eps = Fraction(1, 2 ** (prec.bits - 1))
    if tol is None:
        return eps
    f = to_fraction(tol, "tol")
    if f <= 0:
        raise ValueError(f"`tol` must be positive; got {short_decimal(f)}. Leave it out to use the precision's "
                         "epsilon.")
    if f >= 1:
        raise ValueError(f"`tol` must be below 1 (it is a relative and absolute tolerance); got {short_decimal(f)}")
    if f < eps:
        raise ValueError(
            f"`tol` = {float(f):.3g} is below the epsilon of {prec.name} ({float(eps):.3g}): no run in that "
            "precision can reach it. Raise `tol`, or choose a higher `precision`."
        )
    return f


def check_time(value, argname: str = "t", *, positive: bool = False) -> Fraction:
    """A nonzero (``positive``: positive) time within 1e-MAX_TIME_MAGNITUDE .. 1eMAX_TIME_MAGNITUDE in magnitude,
    as an exact Fraction."""
    f = to_fraction(value, argname)
    if f == 0 or (positive and f < 0):
        raise ValueError(f"`{argname}` must be a {'positive' if positive else 'nonzero'} time; got {value!r}")
    if not Fraction(1, 10**MAX_TIME_MAGNITUDE) <= abs(f) <= 10**MAX_TIME_MAGNITUDE:
        raise ValueError(f"`{argname}` = {short_decimal(f)} must lie within 1e-{MAX_TIME_MAGNITUDE} .. "
                         f"1e{MAX_TIME_MAGNITUDE} in magnitude (runs report their times as doubles)")
    return f


def check_seconds(value, argname: str):
    """Validate an optional positive, finite number of seconds (None passes through) and return a float."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"`{argname}` must be a positive number of seconds; got {type(value).__name__} {value!r}")
    v = float(value)
    if not (v > 0 and math.isfinite(v)):
        raise ValueError(f"`{argname}` must be a positive, finite number of seconds; got {value!r}")
    return v


def check_callable(value, argname: str):
    """Validate an optional callable (None passes through)."""
    if value is not None and not callable(value):
        raise TypeError(f"`{argname}` must be callable (or None); got {type(value).__name__} {value!r}")
    return value


class _FractionBar:
    """``progress(fraction_done)`` drawn as a bar of 1000 steps (closed when the run is done or forgotten)."""

    def __init__(self, title):
        from .progress import ProgressBar

        self._bar = ProgressBar(title)

    def __call__(self, fraction) -> None:
        done = min(1000, max(0, int(round(1000 * float(fraction)))))
        self._bar(done, 1000)
        if done >= 1000:
            self._bar.close()

    def __del__(self):
        try:
            self._bar.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass


def check_progress(value, argname: str = "progress", title: str = "run"):
    """A run's ``progress`` argument as a callable ``progress(fraction_done)`` or None: a callable passes through,
    True shows a bar (:class:`lieseries.progress.ProgressBar`: drawn on a terminal, silent in CI), None and False
    show nothing."""
    if value is True:
        return _FractionBar(title)
    if value is None or value is False:
        return None
    if not callable(value):
        raise TypeError(f"`{argname}` must be callable (progress(fraction_done)), True (show a bar) or None; got "
                        f"{type(value).__name__} {value!r}")
    return value


def dps_to_bits(dps: int) -> int:
    """Bits needed to hold ``dps`` decimal digits (mpmath's own rule)."""
    return mp.libmp.dps_to_prec(int(dps))


def bits_to_dps(bits: int) -> int:
    """Decimal digits held by ``bits`` bits (mpmath's own rule)."""
    return mp.libmp.prec_to_dps(int(bits))


#: Guard digits and bits the engines carry above the precision a user asks for, in one place. They differ because
#: each covers a different loss:
#: the Lie series carries LIE_GUARD_DIGITS between steps (its partial sums cancel a few digits per step; 10 keeps
#: the last digit of a ``dps``-digit result);
LIE_GUARD_DIGITS = 10
#: the closed forms carry EXACT_GUARD_DIGITS (elliptic functions and theta series lose more: the argument reduction
#: of a large time costs digits in proportion to its size, and 20 covers the times a run reaches);
EXACT_GUARD_DIGITS = 20
#: the validated (Arb) engine carries VALIDATED_GUARD_BITS (counted in bits, as Arb's radii are: 32 bits, about
#: 9.6 digits, the Lie engine's margin).
VALIDATED_GUARD_BITS = 32


@dataclass(frozen=True)
class Precision:
    """The one precision type: a floating-point format heyoka integrates in ("double", "long double", "quad",
    ``real<bits>``) or a number of decimal digits of an mpmath/Arb engine ("30 dps").

    Make one with :meth:`of` (or :func:`resolve_precision`, for heyoka's formats only).

    Attributes
    ----------
    name : str
        Its label: ``"double"``, ``"long double"``, ``"quad"``, ``"real<bits>"`` or ``"<dps> dps"``.
    bits : int
        Significand bits (53, 64, 113, the arbitrary-precision setting, or what ``dps`` digits need).
    digits : int or None
        The decimal digits of a decimal precision (None for a binary format).
    guard_digits, guard_bits : int
        What the engine carries above it between steps (:data:`LIE_GUARD_DIGITS`, :data:`VALIDATED_GUARD_BITS`).
    """

    name: str
    bits: int
    digits: int | None = None
    guard_digits: int = 0
    guard_bits: int = 0

    @classmethod
    def of(cls, precision=None, *, dps=None, guard_digits: int = 0, guard_bits: int = 0,
           argname: str = "precision") -> "Precision":
        """A Precision from a name ("double", "long double", "quad"), a number of bits, a Precision, or (``dps=``)
        a number of decimal digits, checked like the API checks them (:func:`check_dps`)."""
        if dps is not None:
            if precision is not None:
                raise TypeError("give `precision` or `dps`, not both")
            d = check_dps(dps, "dps")
            return cls(f"{d} dps", dps_to_bits(d), d, int(guard_digits), int(guard_bits))
        return resolve_precision(precision, argname)

    @property
    def is_decimal(self) -> bool:
        """True for a number of decimal digits (mpmath, Arb); False for a binary format heyoka integrates in."""
        return self.digits is not None

    @property
    def working_dps(self) -> int:
        """The decimal digits an mpmath engine works with: :attr:`dps` and the guard digits."""
        return self.dps + self.guard_digits

    @property
    def working_bits(self) -> int:
        """The bits an engine works with: what :attr:`working_dps` digits need (mpmath's rule) for a decimal
        precision, :attr:`bits` and the guard digits' bits for a binary one; and the guard bits."""
        if self.digits is not None:
            return dps_to_bits(self.working_dps) + self.guard_bits
        return self.bits + math.ceil(self.guard_digits * math.log2(10)) + self.guard_bits

    @property
    def working_eps(self) -> float:
        """The unit round-off of the numbers the engine carries between steps: :attr:`eps` reduced by the guard
        digits and bits (the size of a perturbation an instability amplifies)."""
        if self.digits is not None:
            return 10.0 ** -(self.digits + self.guard_digits) * 2.0 ** -self.guard_bits
        return self.eps * 10.0 ** -self.guard_digits * 2.0 ** -self.guard_bits

    def __str__(self) -> str:
        return self.name

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
        """Unit round-off: 10**-digits for a decimal precision, else machine epsilon 2**(1 - bits), as a Python
        float (underflows to 0 only beyond 1074 bits, or 323 digits)."""
        if self.digits is not None:
            return 10.0 ** -self.digits
        return math.ldexp(1.0, 1 - self.bits)

    @property
    def eps_mpf(self) -> mp.mpf:
        """Machine epsilon as an exact mpmath number."""
        return mp.mpf(2) ** (1 - self.bits)

    @property
    def dps(self) -> int:
        """Decimal digits carried by this precision."""
        return self.digits if self.digits is not None else bits_to_dps(self.bits)

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
    @property
    def max_exponent(self) -> int:
        """Binary exponent of the largest finite number of this format (MPFR's range for ``real``)."""
        return {"double": 1024, "long double": 16384, "quad": 16384}.get(self.name, 1 << 30)

    def to_native(self, value, argname: str = "value"):
        """Round ``value`` (exact input of any supported kind) once, correctly, to this precision.

        Raises ValueError, naming ``argname``, when the value overflows the format (or underflows to zero).
        """
        frac = value if isinstance(value, Fraction) else to_fraction(value, argname)
        if self.name == "double":
            try:
                x = float(frac)  # correctly rounded
            except OverflowError:
                x = math.inf
            if math.isinf(x) or (x == 0 and frac != 0):
                pass  # out of range: the general path below says so
            else:
                return x
        if frac == 0:
            return self._raw_to_native(mp.libmp.fzero)
        raw = mp.libmp.from_rational(frac.numerator, frac.denominator, self.bits, mp.libmp.round_nearest)
        exp = raw[2] + raw[3]  # |x| < 2**exp
        if exp > self.max_exponent:
            raise ValueError(
                f"`{argname}` = {short_decimal(frac)} overflows {self.name} (largest about 2**{self.max_exponent}); "
                "rescale the problem or use a wider precision"
            )
        if exp < -self.max_exponent - self.bits + 2:
            raise ValueError(
                f"`{argname}` = {short_decimal(frac)} underflows to zero in {self.name}; rescale the problem or use a "
                "wider precision"
            )
        return self._raw_to_native(raw)

    def _raw_to_native(self, raw):
        """A native number from a raw mpf (sign, man, exp, bc) already rounded to this precision."""
        sign, man, exp, _ = raw
        if self.name == "double":
            return mp.libmp.to_float(raw)
        if self.name == "long double":
            # split the (<= 64-bit) significand so that each piece converts to long double exactly
            hi, lo = divmod(int(man), 1 << 32)
            v = np.ldexp(np.longdouble(hi), 32) + np.longdouble(lo)
            v = np.ldexp(v, int(exp))
            return -v if sign else v
        text = mp.libmp.to_str(raw, bits_to_dps(self.bits) + 10)
        if self.name == "quad":
            return hy.real128(text)
        return hy.real(text, self.bits)

    def array(self, values, argname: str = "value") -> np.ndarray:
        """A 1-d (or n-d) numpy array of ``values`` rounded to this precision.

        Values that know where they come from (a system's ``parameter_values``, :class:`NamedValues`) are named
        by it in errors (an overflow names `inertia`, not a runtime parameter the user never wrote)."""
        exact = getattr(values, "exact", None)
        labels = getattr(values, "labels", None)
        arr = np.asarray(exact if exact is not None else values, dtype=object)
        out = []
        for i, v in enumerate(arr.ravel()):
            try:
                out.append(self.to_native(v, argname))
            except ValueError as err:
                if labels is None or i >= len(labels):
                    raise
                text = str(err)
                raise ValueError(f"{labels[i]} {text.split('= ', 1)[-1]}") from None
        if self.is_real:
            res = np.empty(len(out), dtype=hy.real)
            for i, v in enumerate(out):
                res[i] = v
        else:
            res = np.array(out, dtype=self.numpy_dtype)
        return res.reshape(arr.shape)

    def time(self, t):
        """A time value in this precision (what heyoka's propagate functions take)."""
        return self.to_native(t, "t")



class NamedValues(tuple):
    """A tuple of numbers with a label for each (``labels``), saying in errors where each came from."""

    def __new__(cls, values, labels):
        obj = super().__new__(cls, values)
        obj.labels = tuple(labels)
        return obj

    def __reduce__(self):
        return (NamedValues, (tuple(self), self.labels))


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
    lo = max(2, hy.real_prec_min())
    if bits < lo or bits > MAX_BITS:
        raise ValueError(
            f"`{argname}` as a number of bits must lie in [{lo}, {MAX_BITS}]; got {bits}. Above {MAX_BITS} bits "
            "use the Lie-series engine (`lieseries.lie_integrate(..., dps=...)`)."
        )
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
            raise ValueError(f"`{argname}` is a {bits}-bit number; lieseries takes numbers of at most {4 * MAX_DPS} bits")
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


# -- precision carried by data ---------------------------------------------------------------------------------------
class CarriedBits(int):
    """A number of bits (an int) that also names the inputs carrying it (``sources``, e.g. ``("omega[1]",)``), so
    that a warning about a state can name the argument the binary number was typed in."""

    def __new__(cls, bits, sources=()):
        obj = super().__new__(cls, int(bits))
        obj.sources = tuple(dict.fromkeys(str(s) for s in sources))
        return obj

    def __reduce__(self):
        return (CarriedBits, (int(self), self.sources))


class BinaryFraction(Fraction):
    """The exact value of a binary number (0.1 as a double is 3602879701896397/2**55) that remembers it carries
    ``bits`` bits only, and the inputs it came from (``sources``, e.g. ``("omega[1]",)``).

    A model state built from binary input keeps its exact values as BinaryFractions: every engine that reads the
    exact values (``state.exact``) sees, through :func:`carried_bits`, the same precision an array of doubles
    carries. Arithmetic on them gives plain Fractions (a derived number is no longer marked).
    """

    def __new__(cls, value, bits, sources=()):
        obj = super().__new__(cls, value)
        obj.bits = int(bits)
        obj.sources = (sources,) if isinstance(sources, str) else tuple(sources)
        return obj

    def __reduce__(self):
        return (BinaryFraction, (Fraction(self.numerator, self.denominator), self.bits, self.sources))

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self


def binary_inputs(values, argname: str) -> dict:
    """``{"argname[i]": bits}`` for the entries of ``values`` (a number, or nested sequences/arrays of them) that
    are binary numbers carrying finite precision (:func:`carried_bits`); empty when all are exact."""
    out = {}

    def walk(v, name):
        if isinstance(v, np.ndarray) and v.ndim > 0:
            v = list(v)  # numpy scalars keep their format: tolist() made float32 entries Python floats, read exact
        if isinstance(v, (list, tuple)):
            for i, x in enumerate(v):
                walk(x, f"{name}[{i}]")
            return
        if isinstance(v, BinaryFraction):
            return  # already marked, with the inputs it came from
        try:
            b = carried_bits(v)
        except (TypeError, ValueError):
            b = None
        if b is not None:
            out[name] = int(b)

    if values is not None:
        walk(values, argname)
    return out


def carried_bits(value):
    """The precision (bits) a number carries, or None for an exact value.

    Exact: int, Fraction, decimal strings, Decimal, sympy numbers, mpmath mpf (it has no format of its own: its
    value is what the user computed), and binary numbers whose significand has at most :data:`EXACT_BITS`
    significant bits (0.5, 3.0, 1.25: what was typed is what is stored). A longer binary significand carries its
    format's precision: 53 for a float64 (0.1 as a double), 64 for a long double, 113 for real128, ``prec`` for
    heyoka.real. An :class:`ExactState`-like object (with an ``exact`` attribute) is exact.
    """
    if isinstance(value, BinaryFraction):
        return CarriedBits(value.bits, value.sources)
    if getattr(value, "exact", None) is not None and not isinstance(value, (str, bytes)):
        return getattr(value, "data_bits", None)  # an ExactState built from binary input knows its precision
    if isinstance(value, (Fraction, numbers.Integral, str, decimal.Decimal)) or value is None:
        return None
    if type(value).__module__.startswith("sympy") or hasattr(value, "_mpf_"):
        return None
    if isinstance(value, np.longdouble) and np.dtype(np.longdouble) != np.float64:
        f = to_fraction(value)
        return _significand_bits(f.numerator * f.denominator, _BUILTIN["long double"].bits)
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            return None  # not a number's precision: refused by the checks of the argument itself
        n, _d = float(value).as_integer_ratio() if not isinstance(value, np.longdouble) else value.as_integer_ratio()
        return _significand_bits(n, np.finfo(value.dtype).nmant + 1 if isinstance(value, np.floating) else 53)
    if isinstance(value, hy.real128):
        return _significand_bits(to_fraction(value).numerator, 113)
    if isinstance(value, hy.real):
        return _significand_bits(to_fraction(value).numerator, int(value.prec))
    return None


def _significand_bits(man: int, fmt_bits: int):
    man = abs(int(man))
    if man == 0:
        return None
    man >>= (man & -man).bit_length() - 1  # drop trailing zero bits
    # a narrow format (float32: 24 bits, float16: 11) holds every number in at most its own bits: there, a number
    # is taken as what was meant only when it leaves 8 of them unused (float32 0.5 and 0.375 are; 0.1 is not)
    return None if man.bit_length() <= min(EXACT_BITS, int(fmt_bits) - 8) else int(fmt_bits)


#: Bits at which helpers evaluate an exact state (it has no format of its own; well above quad).
EXACT_STATE_BITS = 256
_EXACT_STATE_BITS = contextvars.ContextVar("exact_state_bits", default=EXACT_STATE_BITS)


@contextlib.contextmanager
def exact_states_read_at(bits: int):
    """Within the block (this thread or task only), a state that carries its exact values is read at ``bits`` bits
    (at least ``EXACT_STATE_BITS``) by everything that asks :func:`state_bits`: the invariants of a run's exact
    initial state compared with those of a run at 400 digits must carry 400 digits, not 77."""
    token = _EXACT_STATE_BITS.set(max(int(bits), EXACT_STATE_BITS))
    try:
        yield
    finally:
        _EXACT_STATE_BITS.reset(token)


def state_bits(y) -> int:
    """The precision (bits) a state is stored in: 53 for float64, 113 for quad, the ``real`` precision, ...;
    EXACT_STATE_BITS for a state that carries its exact values (``y.exact``, an ExactState), or the bits of an
    enclosing :func:`exact_states_read_at`."""
    if getattr(y, "exact", None) is not None:
        return _EXACT_STATE_BITS.get()
    arr = np.asarray(y) if not isinstance(y, np.ndarray) else y
    prec = precision_of_dtype(arr.dtype)
    if prec is not None:
        return prec.bits
    flat = arr.ravel()
    if len(flat) and hasattr(flat[0], "prec"):
        p = flat[0].prec
        return int(p() if callable(p) else p)
    if len(flat) and hasattr(flat[0], "_mpf_"):
        # mpf carries no precision of its own: use the longest significand in the state
        return max([53] + [int(v._mpf_[3]) for v in flat if hasattr(v, "_mpf_")])
    return 53


def data_bits(values):
    """The least precision carried by any of ``values`` (None when all are exact), as a :class:`CarriedBits`
    naming the inputs that carry it when they are known (a state from ``model.initial_state(omega=(1, 0.1, 0.5))``
    names ``omega[1]``)."""
    bits = [b for b in map(carried_bits, _leaves(values)) if b is not None]
    if not bits:
        return None
    low = min(bits)
    return CarriedBits(low, [s for b in bits if b == low for s in getattr(b, "sources", ())])


def _leaves(values):
    """The numbers in ``values``: a number, or nested sequences and arrays of them (ragged ones too). A state
    that carries its exact values (``exact``) is one leaf: its exact values are its data (their precision is its
    ``data_bits``), not the doubles numpy shows."""
    if getattr(values, "exact", None) is not None and not isinstance(values, (str, bytes)):
        yield values
        return
    if isinstance(values, np.ndarray):
        if values.dtype != object:
            yield from values.ravel()
            return
        values = values.ravel().tolist()
    if isinstance(values, (list, tuple)):
        for v in values:
            yield from _leaves(v)
    else:
        yield values


def warn_if_coarse(bits, work_bits: int, argname: str, *, stacklevel: int = 3) -> None:
    """Emit one :class:`PrecisionWarning` when data carrying ``bits`` bits feed a run at ``work_bits`` bits."""
    if bits is None or bits >= work_bits:
        return
    sources = [s for s in getattr(bits, "sources", ()) if s and s != argname]
    if sources:
        shown = ", ".join(f"`{s}`" for s in sources[:6]) + (", ..." if len(sources) > 6 else "")
        what = (f"`{argname}` was built from binary numbers ({shown}) and carries only {bits} bits "
                f"({bits_to_dps(bits)} digits: the double 0.1 is 0.1000000000000000055511151231257827...)")
        how = (f"Pass the exact values to the function that built it: {shown} as strings ('0.1'), ints or "
               "Fractions (Fraction(1, 10)).")
    elif argname.startswith("the constant "):
        what = (f"`{argname}` carries only {bits} bits (heyoka stores a number written in an expression as the "
                "nearest double)")
        how = ("Make it a runtime parameter: `hy.par[i]` in the expression and its exact value (a string such as "
               "'0.1', or a Fraction) in `parameters`.")
    else:
        what = (f"`{argname}` carries only {bits} bits ({bits_to_dps(bits)} digits: binary numbers such as the "
                "double 0.1 are roundings of what was typed)")
        how = ("Pass exact values (strings like '0.1', ints, Fractions), or a state from `model.initial_state(...)` "
               "built from exact input.")
    warnings.warn(
        f"{what}, but the run works with {work_bits} bits: it is exact for those binary values, not for the "
        f"decimals you may have meant, and agrees with the intended problem to about {bits_to_dps(bits)} digits "
        f"only. {how}",
        PrecisionWarning,
        stacklevel=stacklevel,
    )


# -- thread-private mpmath ---------------------------------------------------------------------------------------------
_LOCAL = threading.local()


def mp_context():
    """This thread's private mpmath context.

    mpmath's global context ``mpmath.mp`` is process-wide: a ``workdps`` block in one thread changes the precision
    of every other thread's arithmetic. lieseries computes in a context of its own per thread, and hands results out
    as ordinary ``mpmath.mpf`` (:func:`export_mpf`).
    """
    ctx = getattr(_LOCAL, "ctx", None)
    if ctx is None:
        ctx = _LOCAL.ctx = mp.MPContext()
    return ctx


class _ThreadMP:
    """mpmath's API on this thread's private context (:func:`mp_context`): ``thread_mp.workdps(50)``,
    ``thread_mp.mpf``, ``thread_mp.ellipk``, ... behave like ``mpmath.mp``'s but touch no other thread."""

    def __getattr__(self, name):
        try:
            return getattr(mp_context(), name)
        except AttributeError:
            return getattr(mp, name)


#: Use as ``from lieseries.precision import thread_mp as mp`` inside the engines.
thread_mp = _ThreadMP()


def export_mpf(value, prec: int | None = None):
    """``value`` (an mpf/mpc of any context, or nested lists/tuples/dicts/object arrays of them) as mpmath's global
    ``mpf``/``mpc``, with its value unchanged (or rounded to ``prec`` bits when given), without touching the global
    precision."""
    if hasattr(value, "_mpf_"):
        raw = value._mpf_ if prec is None else mp.libmp.mpf_pos(value._mpf_, prec, mp.libmp.round_nearest)
        return mp.make_mpf(raw)
    if hasattr(value, "_mpc_"):
        re_, im_ = value._mpc_
        if prec is not None:
            re_ = mp.libmp.mpf_pos(re_, prec, mp.libmp.round_nearest)
            im_ = mp.libmp.mpf_pos(im_, prec, mp.libmp.round_nearest)
        return mp.make_mpc((re_, im_))
    if isinstance(value, np.ndarray) and value.dtype == object:
        out = np.empty(value.shape, dtype=object)
        for idx, v in np.ndenumerate(value):
            out[idx] = export_mpf(v, prec)
        return out
    if isinstance(value, list):
        return [export_mpf(v, prec) for v in value]
    if isinstance(value, tuple):
        return tuple(export_mpf(v, prec) for v in value)
    if isinstance(value, dict):
        return {k: export_mpf(v, prec) for k, v in value.items()}
    return value


def check_flag(value, argname, allow_none=True):
    """A switch must be True or False (or None for the default): 'yes' or 0 would silently pick one."""
    if (value is None and allow_none) or isinstance(value, (bool, np.bool_)):
        return
    raise TypeError(f"`{argname}` must be True or False{' (or None for the default)' if allow_none else ''}; got "
                    f"{type(value).__name__} {value!r}")
