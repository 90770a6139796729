"""Numbers and tables as text, and the figure helpers the report's plots share (matplotlib is imported only when a
plot is drawn). Used by the report and by the studies' report sections."""

from __future__ import annotations

import math
import sys
import textwrap
from fractions import Fraction

__all__ = ["fmt_sci", "fmt_int", "fmt_num", "fmt_p", "markdown_table", "plain_table", "pyplot", "save_figure",
           "positive_or_nan", "wrap", "MARKERS", "file_tag"]


def fmt_sci(x, digits: int = 3) -> str:
    """Scientific notation with ``digits`` significant digits ("" for None, "0" for zero). A number beyond a
    double's range (an mpf, a long double, a Fraction) keeps its exponent (1e-402 is "1.00e-402", not the "0" of
    its float)."""
    if x is None:
        return ""
    try:
        f = float(x)
    except (TypeError, ValueError):
        return str(x)
    except OverflowError:  # a Fraction or an integer above 1.8e308
        f = math.inf
    if math.isnan(f):
        return "nan"
    if f == 0 or math.isinf(f):  # zero or beyond a double's range as a float: perhaps not as itself
        exact = _exact_value(x)
        if exact is not None and exact != 0:
            return _big_sci(exact, digits)
    if math.isinf(f):
        return "inf" if f > 0 else "-inf"
    if f == 0:
        return "0"
    return f"{f:.{digits - 1}e}"


def _exact_value(x):
    """The exact value of a finite number of any type (an mpf, a long double, a Fraction, an integer) as a
    Fraction; None for an infinity, a NaN or a type without an exact value."""
    try:
        if hasattr(x, "_mpf_"):
            sign, man, exp, _bc = x._mpf_  # (-1)^sign man 2^exp exactly (man_exp drops the sign: -1e5000 printed
            if not man:                    # "1.00e+5000"); man 0 for zero, inf and nan
                return None if exp else Fraction(0)
            return (-1) ** sign * Fraction(int(man)) * Fraction(2) ** int(exp)
        if hasattr(x, "as_integer_ratio"):  # ints, Fractions, floats, numpy's long double
            return Fraction(*x.as_integer_ratio())
        # heyoka's real and real128 print their value in decimal (a real of 1e-400 printed "0" through its float)
        text = str(x).strip()
        return Fraction(text) if text and text.lstrip("+-")[:1].isdigit() else None
    except (TypeError, ValueError, OverflowError, AttributeError, ZeroDivisionError):
        return None


def _big_sci(x, digits: int) -> str:
    """The Fraction ``x`` in scientific notation, in decimal integers (no float)."""
    sign = "-" if x < 0 else ""
    x = abs(x)
    e = math.floor((x.numerator.bit_length() - x.denominator.bit_length()) * math.log10(2))  # within 1 of log10 x
    while x < Fraction(10) ** e:
        e -= 1
    while x >= Fraction(10) ** (e + 1):
        e += 1
    scaled = x / Fraction(10) ** e  # in [1, 10)
    m = round(scaled * 10 ** (digits - 1))
    if m >= 10 ** digits:  # rounded up to 10.0
        m //= 10
        e += 1
    text = str(m)
    mant = text[0] + ("." + text[1:] if digits > 1 else "")
    return f"{sign}{mant}e{e:+03d}"


def fmt_int(x) -> str:
    return "" if x is None else f"{int(x):d}"


def fmt_num(x) -> str:
    """A plain number for parameters (times, fractions): up to 6 significant digits."""
    if x is None:
        return ""
    try:
        f = float(x)
    except (TypeError, ValueError):
        return str(x)
    except OverflowError:  # a Fraction or an integer above 1.8e308
        f = math.inf
    if (f == 0 or math.isinf(f)) and not math.isnan(f):  # beyond a double's range as a float, perhaps not itself
        exact = _exact_value(x)
        if exact is not None and exact != 0:
            mant, exp = _big_sci(exact, 6).split("e")
            return f"{mant.rstrip('0').rstrip('.')}e{exp}"  # as %g writes it: 1e-400, -2.5e+400
    return f"{f:.6g}"


def fmt_p(p) -> str:
    """A fitted exponent with two decimals ("n/a" for None)."""
    return "n/a" if p is None else f"{p:.2f}"


def _is_numeric(cell: str) -> bool:
    s = cell.strip()
    if not s:
        return False
    try:
        float(s)
        return True
    except ValueError:
        return s in ("nan", "inf", "-inf")


def markdown_table(headers, rows) -> str:
    """A Markdown table with padded columns; columns of numbers are right-aligned."""
    headers = [str(h) for h in headers]
    rows = [[("" if c is None else str(c)).replace("|", "\\|") for c in r] for r in rows]
    ncol = len(headers)
    widths = [max([len(headers[j])] + [len(r[j]) for r in rows] + [3]) for j in range(ncol)]
    blank = ("", "none", "n/a")
    numeric = [bool(rows) and all(_is_numeric(r[j]) or r[j].strip() in blank for r in rows)
               and any(_is_numeric(r[j]) for r in rows) for j in range(ncol)]

    def line(cells):
        out = []
        for j, c in enumerate(cells):
            out.append(c.rjust(widths[j]) if numeric[j] else c.ljust(widths[j]))
        return "| " + " | ".join(out) + " |"

    sep = "| " + " | ".join(("-" * (widths[j] - 1) + ":") if numeric[j] else "-" * widths[j]
                            for j in range(ncol)) + " |"
    return "\n".join([line(headers), sep] + [line(r) for r in rows])


def plain_table(headers, rows) -> str:
    """A plain-text table for the terminal."""
    widths = [max([len(str(h))] + [len(str(r[j])) for r in rows]) for j, h in enumerate(headers)]
    out = ["  ".join(str(h).ljust(widths[j]) for j, h in enumerate(headers))]
    out.append("  ".join("-" * w for w in widths))
    for r in rows:
        out.append("  ".join(str(c).ljust(widths[j]) for j, c in enumerate(r)))
    return "\n".join(out)


def file_tag(label: str, several: bool) -> str:
    """"" for a scene's only model, else "_" and the label with non-alphanumerics as "_" (CSV file names)."""
    return "" if not several else "_" + "".join(c if c.isalnum() else "_" for c in label)


def wrap(text: str, width: int) -> str:
    return "\n".join(textwrap.wrap(text, width))


# -- figures ---------------------------------------------------------------------------------------------------
#: Markers of successive series in a plot.
MARKERS = ["o", "s", "^", "D", "v", "P", "X", "*", "<", ">"]


def pyplot():
    """matplotlib.pyplot with the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def save_figure(plt, fig, path) -> None:
    """Lay out, write (PNG, 110 dpi) and close a figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def below_float_range(v) -> bool:
    """Whether ``v`` is a positive number a double cannot draw: below its normal range (an mpf of 1e-402 is 0.0 as
    a float, a subnormal keeps a few bits) or above it."""
    try:
        if v is None or not v > 0:
            return False
        f = float(v)
    except (TypeError, ValueError):
        return False
    except OverflowError:
        return True
    return f < sys.float_info.min or math.isinf(f) and _exact_value(v) is not None


def log10_or_nan(values):
    """log10 of each value, a float for a number of any size (an mpf of 1e-402 gives -402.0, through its exact
    value); NaN for None, non-positive and non-finite values. For axes whose values a double cannot draw."""
    out = []
    for v in values:
        if below_float_range(v):
            exact = _exact_value(v)
            out.append(math.log10(exact.numerator) - math.log10(exact.denominator) if exact else float("nan"))
            continue
        try:
            f = float(v) if v is not None and v > 0 else math.nan
        except (TypeError, ValueError):
            f = math.nan
        out.append(math.log10(f) if 0 < f < math.inf else float("nan"))
    return out


def positive_or_nan(values):
    """The values with None, non-positive and non-finite ones as NaN (for log axes)."""
    return [float(v) if (v is not None and v > 0 and math.isfinite(v) and float(v) > 0) else float("nan")
            for v in values]  # a value below a float's range cannot be drawn: left out, not drawn as 0
