"""The precision data carry: binary inputs that carry fewer bits than a run (:func:`carried_bits`,
:func:`data_bits`, :class:`BinaryFraction`) and the :class:`PrecisionWarning` about them; the bits a state is read
at (:func:`state_bits`, :func:`exact_states_read_at`)."""

from __future__ import annotations

import contextlib
import contextvars
import decimal
import numbers
import warnings
from fractions import Fraction

import heyoka as hy
import numpy as np

from ..caller import stacklevel
from .conversions import bits_to_dps, to_fraction
from .formats import precision_of_dtype, resolve_precision

#: A binary number whose significand has at most this many significant bits (0.5, 1.25, 3.0, 0.375, ...) is taken
#: as exact: it is what was meant. Anything longer (0.1 as a double) carries its format's precision only.
EXACT_BITS = 32


class PrecisionWarning(UserWarning):
    """A run at a higher precision than its input data carry (binary floats where exact values were meant)."""


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
    """``{"argname[i]": bits}`` for the entries of ``values`` (a number, or nested sequences/arrays of them, or a
    table of them: ``"argname.key"``) that are binary numbers carrying finite precision (:func:`carried_bits`);
    empty when all are exact."""
    out = {}

    def walk(v, name):
        if isinstance(v, dict):  # (a constrained scene's parameters = { g = 9.81 })
            for k, x in v.items():
                walk(x, f"{name}.{k}")
            return
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
        return _significand_bits(f.numerator * f.denominator, resolve_precision("long double").bits)
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


def infer_precision(precision, y0, argname: str = "y0"):
    """The precision of a heyoka run: ``precision`` when given, else the format of the data ``y0`` (one state or
    the rows of an ensemble).

    A numeric array runs in its dtype's format; an :class:`~lieseries.models.base.ExactState`, ints, Fractions,
    strings and floats in double; heyoka.real entries in their bits, real128 in quad, long double scalars in long
    double (where it is wider than double). mpmath numbers carry no format: refused, naming ``precision=`` (read
    as double, a 100-digit mpf would lose its digits silently).
    """
    if precision is not None:
        return resolve_precision(precision)
    if getattr(y0, "exact", None) is not None:
        return resolve_precision("double")
    prec = precision_of_dtype(y0.dtype) if isinstance(y0, np.ndarray) and y0.dtype != object else None
    if prec is not None:
        return prec  # (an array of heyoka.real has a dtype of no fixed precision: its entries say)
    try:
        flat = np.asarray(y0, dtype=object).ravel()
    except ValueError:  # ragged rows: the run's own checks say what is wrong
        return resolve_precision("double")
    first = flat[0] if flat.size else None
    if isinstance(first, hy.real):
        return resolve_precision(int(first.prec), argname)
    if isinstance(first, hy.real128):
        return resolve_precision("quad")
    if isinstance(first, np.longdouble) and np.finfo(np.longdouble).nmant > 52:
        return resolve_precision("long double")
    if any(hasattr(ty, "_mpf_") for ty in set(map(type, flat))):
        raise ValueError(
            f"`{argname}` holds mpmath numbers, which carry no precision of their own: pass `precision=` ('double', "
            "'long double', 'quad' or a number of bits)"
        )
    return resolve_precision("double")


def warn_if_coarse(bits, work_bits: int, argname: str) -> None:
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
    elif argname.startswith("the constant"):
        several = argname.startswith("the constants ")
        what = (f"`{argname}` carr{'y' if several else 'ies'} only {bits} bits (heyoka stores a number written in "
                "an expression as the nearest double)")
        how = (f"Make {'each' if several else 'it'} a runtime parameter: `hy.par[i]` in the expression and its "
               "exact value (a string such as '0.1', or a Fraction) in `parameters`.")
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
        stacklevel=stacklevel(),
    )
