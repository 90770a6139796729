"""Inputs of the closed forms: numbers converted exactly (with a warning for binary data coarser than the digits
asked for), vectors of three, times (complex where allowed), the digit limits, and results exported to mpmath's
global types."""

from __future__ import annotations

import dataclasses
import decimal
import fractions
import functools
import numbers

from ..precision import EXACT_GUARD_DIGITS, carried_bits, check_dps, dps_to_bits, export_mpf, mp_context, to_mpf, warn_if_coarse
from ..precision import thread_mp as mp


#: Guard digits added to the requested ``dps`` for all internal work (:data:`precision.EXACT_GUARD_DIGITS`).
GUARD_DIGITS = EXACT_GUARD_DIGITS

#: Relative tolerance exponent used to classify the rigid-body regime: with
#: ``dps`` requested digits, quantities below ``10**-(dps + CLASSIFY_DIGITS)``
#: (relative) are treated as exactly zero (separatrix test, equal moments of a
#: diagonalised tensor, vanishing momentum components after diagonalisation).
CLASSIFY_DIGITS = 15


def loose_tolerance(dps):
    """The relative tolerance of an input's geometric condition (a point on the sphere, a symmetric tensor):
    max(1e-12, 10**(-dps/2))."""
    return max(mp.mpf(10) ** -12, mp.mpf(10) ** (-mp.mpf(dps) / 2))


def fmt(x):
    """Short text for a number in an error message (integers without '.0')."""
    if hasattr(x, "_mpf_") and mp.isint(x) and abs(x) < 10 ** 15:
        return str(int(x))
    return mp.nstr(x, 15)


#: The most digits the rigid body's closed form is computed to: at 2000 digits one state takes ~20 s (three
#: incomplete elliptic integrals of the third kind, by Carlson's duplication, whose cost grows like dps^2.3), the
#: constants alone ~0.6 s; at 10000 digits the constants alone take minutes.
MAX_RIGID_DPS = 2000
#: The most digits with ``psi_method='quad'`` (mpmath.quad of psi' over the periods: ~25 s at 400 digits, ~450 s
#: at 1000).
MAX_QUAD_DPS = 400


def check_rigid_dps(dps, psi_method="elliptic"):
    dps = check_dps(dps)
    limit, what = (MAX_QUAD_DPS, "with `psi_method`='quad'") if psi_method == "quad" else (MAX_RIGID_DPS, "")
    if dps > limit:
        raise ValueError(
            f"`dps` = {dps} is above {limit}, the most digits the rigid body's closed form {what}"
            f"{' ' if what else ''}computes in reasonable time (its elliptic integrals' cost grows like dps^2.3: "
            f"about 20 s for a state at 2000 digits); ask for at most {limit} digits"
            + ("" if psi_method != "quad" else " or use psi_method='elliptic'"))
    return dps


def exported(fn):
    """Results leave in mpmath's global types (their values unchanged): the work is done in this thread's private
    mpmath context, so that calls from several threads never change each other's precision."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        res = fn(*args, **kwargs)
        if dataclasses.is_dataclass(res):
            return dataclasses.replace(res, **{f.name: export_mpf(getattr(res, f.name))
                                               for f in dataclasses.fields(res)})
        return export_mpf(res)

    return wrapper


def time_digits(ts) -> int:
    """Extra working digits that times as large as ``ts`` need: the argument reduction of the periodic and
    elliptic functions loses about log10 |t| digits."""
    big = 0
    for t in ts:
        try:
            a = abs(t)
        except TypeError:
            continue
        if hasattr(a, "_mpf_") or isinstance(a, (int, float, fractions.Fraction)):
            if a > 1:
                big = max(big, int(mp.log10(a)) + 1 if hasattr(a, "_mpf_") else len(str(int(a))))
    return big


def magnitude(t):
    """|t| for sizing the working precision, or 0 for input that the real conversion will refuse by name."""
    try:
        return abs(to_time(t, "t", allow_complex=True))
    except (TypeError, ValueError):
        return 0


def to_real(x, name):
    """Convert one real scalar exactly (at the current working precision); a binary float that carries fewer bits
    than the digits asked for (the double 0.1 in a 40-digit closed form) gives one PrecisionWarning naming it."""
    if isinstance(x, bool):
        raise TypeError(f"`{name}` must contain real numbers, not booleans; got {x!r}")
    if isinstance(x, numbers.Real) and not isinstance(x, (numbers.Rational, decimal.Decimal)) or hasattr(x, "_mpf_"):
        # the caller works GUARD_DIGITS above the digits asked for
        warn_if_coarse(carried_bits(x), mp_context().prec - dps_to_bits(GUARD_DIGITS), name)
    if isinstance(x, (str, float, decimal.Decimal, fractions.Fraction, numbers.Integral)) or hasattr(x, "_mpf_"):
        return to_mpf(x, name, ctx=mp_context())
    if isinstance(x, numbers.Rational):
        return mp.mpf(int(x.numerator)) / mp.mpf(int(x.denominator))
    if isinstance(x, numbers.Real):  # numpy float32 and the like: their exact binary value
        return to_mpf(float(x), name, ctx=mp_context())
    raise TypeError(
        f"`{name}` must be a real number (int, float, str, Fraction, Decimal or mpf); "
        f"got {type(x).__name__} {x!r}")


def to_time(t, name, allow_complex=False):
    if allow_complex and (isinstance(t, complex) or hasattr(t, "_mpc_")) and not isinstance(t, bool):
        z = mp.mpc(t)
        if not (mp.isfinite(z.real) and mp.isfinite(z.imag)):
            raise ValueError(f"`{name}` must be finite; got {t!r}")
        return z
    return to_real(t, name)


def is_sequence(x):
    if isinstance(x, (str, bytes)):
        return False
    try:
        len(x)
        iter(x)
    except TypeError:
        return False
    return True


def vec3(v, name):
    if not is_sequence(v):
        raise TypeError(f"`{name}` must be a sequence of 3 real numbers; got {type(v).__name__}")
    if len(v) != 3:
        raise ValueError(f"`{name}` must have 3 components; got {len(v)}")
    return [to_real(c, name) for c in v]
