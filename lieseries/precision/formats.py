"""The one precision type (:class:`Precision`): heyoka's formats and decimal digits, with their bits, digits,
epsilon, name and guard digits; :func:`resolve_precision` and :func:`precision_of_dtype`."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from fractions import Fraction

import heyoka as hy
import mpmath as mp
import numpy as np

from .bounds import MAX_BITS
from .checks import check_dps
from .conversions import bits_to_dps, dps_to_bits, short_decimal, to_fraction

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
