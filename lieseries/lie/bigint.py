"""Big integers for the fixed-point jets: the backend (gmpy2's ``mpz`` or Python ``int``) and integer helpers.

Big integers are gmpy2's ``mpz`` when gmpy2 imports, Python ``int`` otherwise; the environment variable
``LIESERIES_BIGINT=int`` (or :func:`set_backend`) forces Python ints.
"""

from __future__ import annotations

import math
import os
from operator import add as _add
from operator import mul as _mul

from mpmath.libmp import from_man_exp, fzero

from ..expr import RND

__all__ = ["backend", "set_backend", "integer_type"]

try:  # pragma: no cover - depends on the installation
    from gmpy2 import bit_length as _gmpy_bit_length
    from gmpy2 import mpz as _mpz
except ImportError:  # pragma: no cover
    _mpz = _gmpy_bit_length = None

# The backend's one state: the integer type, rebound by set_backend. Other modules call integer_type() (once per
# expansion or per evaluation) instead of binding the type at import, so that they follow set_backend.
_Z = int


def set_backend(name=None):
    """Choose the big integers: ``"gmpy"`` (gmpy2's mpz), ``"int"`` (Python ints) or None (gmpy2 when it imports,
    unless the environment variable ``LIESERIES_BIGINT`` is ``int``).  Returns the backend now in use."""
    global _Z
    if name is None:
        name = "int" if os.environ.get("LIESERIES_BIGINT", "").strip().lower() == "int" else "gmpy"
    if name not in ("gmpy", "int"):
        raise ValueError(f"`name` must be 'gmpy', 'int' or None; got {name!r}")
    _Z = _mpz if (name == "gmpy" and _mpz is not None) else int
    return backend()


def backend():
    """The big integers in use: ``"gmpy"`` or ``"int"``."""
    return "int" if _Z is int else "gmpy"


def integer_type():
    """The big-integer type in use (gmpy2's ``mpz`` or ``int``)."""
    return _Z


def bit_length_function():
    """The bit length of the integers in use as a function (for ``map``): gmpy2's, which takes ints too, or
    ``int.bit_length``."""
    return int.bit_length if _Z is int else _gmpy_bit_length


set_backend()


# --------------------------------------------------------------------------
# Integer helpers
# --------------------------------------------------------------------------

def round_shift(x, n):
    """round(x / 2**n) (a left shift for n <= 0)."""
    if n <= 0:
        return x << -n
    return (x + (1 << (n - 1))) >> n


def div_round(num, den, d):
    """round(num * 2**d / den), den > 0."""
    if d >= 0:
        num = num << d
    else:
        den = den << -d
    return ((num << 1) + den) // (den << 1)


def ebits(m, u):
    """Binary exponent of m * 2**u (|x| < 2**e), None for zero."""
    return u + m.bit_length() if m else None


def eraw(raw):
    return raw[2] + raw[3] if raw[1] else None


def emax(*es):
    es = [e for e in es if e is not None]
    return max(es) if es else None


def to_int(raw, u):
    """round(raw / 2**u) as a big integer."""
    s, m, e, _ = raw
    if not m:
        return _Z(0)
    m = _Z(m)
    m = round_shift(m, u - e)
    return -m if s else m


def to_raw(m, u, prec=None):
    if not m:
        return fzero
    return from_man_exp(m, u, prec, RND) if prec else from_man_exp(m, u)


def sum_products(a, b):
    return sum(map(_mul, a, b))


#: Working precisions (bits) from which Cauchy products pair their terms (:class:`Cauchy`): half the big-integer
#: multiplications for a few more additions, a gain once multiplications dominate.
PAIR_BITS = 300


class Cauchy:
    """sum_{j<=k} A_j B_{k-j} at k = 0, 1, 2, ... (called for every k in turn, A and B holding k + 1 terms).

    With ``paired``, the terms j and k - j go into one product: A_j B_{k-j} + A_{k-j} B_j =
    (A_j + A_{k-j}) (B_j + B_{k-j}) - A_j B_j - A_{k-j} B_{k-j}, and the diagonal products A_j B_j, summed once
    as they arrive (S_k = sum_{j<=k} A_j B_j), account for every correction: the sum is
    sum_{j<k/2} (A_j + A_{k-j}) (B_j + B_{k-j}) - S_k + 2 A_{k/2} B_{k/2} (the last for even k), exact in
    integers with about k/2 + 2 multiplications instead of k + 1."""

    __slots__ = ("A", "B", "S", "paired")

    def __init__(self, A, B, paired):
        self.A, self.B, self.S, self.paired = A, B, 0, paired

    def reset(self, B, k):
        """Use B from now on (the partners repacked) with its diagonal sum through k - 1."""
        self.B = B
        A = self.A
        self.S = sum(map(_mul, A[:k], B[:k]))

    def __call__(self, k):
        A, B = self.A, self.B
        if not self.paired:
            return sum(map(_mul, A, reversed(B)))
        self.S += A[k] * B[k]
        h = (k + 1) >> 1
        v = sum(map(_mul, map(_add, A[:h], A[k:k - h:-1]), map(_add, B[:h], B[k:k - h:-1]))) - self.S
        if not k & 1:
            v += (A[h] * B[h]) << 1
        return v



def sqr_sum(A, k):
    h = (k + 1) >> 1
    r = sum_products(A[:h], A[k:k - h:-1]) << 1 if h else 0
    if not k & 1:
        x = A[k >> 1]
        r += x * x
    return r



def log2_abs(m):
    """log2 |m| of a nonzero big integer, in floating point."""
    b = m.bit_length()
    if b > 1000:
        return math.log2(abs(m) >> (b - 64)) + (b - 64)
    return math.log2(abs(m))


def greater_abs(m1, u1, m2, u2):
    """|m1| 2**u1 > |m2| 2**u2."""
    m1, m2 = abs(m1), abs(m2)
    if u1 >= u2:
        return (m1 << (u1 - u2)) > m2
    return m1 > (m2 << (u2 - u1))
