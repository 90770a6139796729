"""The one owner of precision: names <-> bits <-> dps, exact conversions, the checks of arguments.

Every number that enters lieseries (a model parameter, an initial state, a time) is first turned into an exact
rational (:class:`fractions.Fraction`) or kept as an exact binary value, and only then rounded once, correctly, to
the working precision. This is what lets a 237-bit run reach 1e-70: nothing is folded through a double on the way.

Precision names
---------------
``"double"``       IEEE binary64 (53 bits), numpy ``float64``
``"long double"``  the platform's ``long double`` (64 bits on x86-64), numpy ``longdouble``
``"quad"``         IEEE binary128 (113 bits), ``heyoka.real128``
``int`` n          arbitrary precision with n bits, ``heyoka.real``

Modules
-------
:mod:`~lieseries.precision.bounds` (the bounds), :mod:`~lieseries.precision.conversions` (exact conversions),
:mod:`~lieseries.precision.checks` (argument checks), :mod:`~lieseries.precision.formats` (:class:`Precision`),
:mod:`~lieseries.precision.carried` (the precision data carry, :class:`PrecisionWarning`),
:mod:`~lieseries.precision.mpcontext` (thread-private mpmath). Import their names from ``lieseries.precision``.
"""

from .bounds import (MAX_BITS, MAX_DIGITS, MAX_DPS, MAX_EXPONENT, MAX_ORDER, MAX_SAMPLES, MAX_TIME_MAGNITUDE,
                     MIN_DPS)
from .carried import (EXACT_BITS, EXACT_STATE_BITS, BinaryFraction, CarriedBits, PrecisionWarning, binary_inputs,
                      carried_bits, data_bits, exact_states_read_at, infer_precision, state_bits, warn_if_coarse)
from .checks import (check_callable, check_count, check_dps, check_flag, check_order, check_progress, check_seconds,
                     check_time, check_tolerance)
from .conversions import bits_to_dps, dps_to_bits, float_or_mpf, short_decimal, to_fraction, to_mpf, to_raw
from .formats import (EXACT_GUARD_DIGITS, LIE_GUARD_DIGITS, VALIDATED_GUARD_BITS, NamedValues, Precision,
                      precision_of_dtype, resolve_precision)
from .mpcontext import export_mpf, mp_context, thread_mp

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
    # used across the package
    "EXACT_STATE_BITS",
    "state_bits",
    "check_callable",
    "check_progress",
    "check_seconds",
    "NamedValues",
    "precision_of_dtype",
    "infer_precision",
    "float_or_mpf",
]
