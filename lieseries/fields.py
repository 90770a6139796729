"""Scene fields: the checkers every part of a scene is validated with, and :class:`SceneError`.

A checker is ``check(value, path) -> value``; it raises :class:`SceneError` naming the field by its dotted path
(``run.methods[1].precision``). A table's schema is ``{name: (checker, default or REQUIRED)}``, checked by
:func:`table`. Models (:mod:`lieseries.models.kinds`), methods (:mod:`lieseries.methods`) and studies
(:mod:`lieseries.studies.plugin`) declare their scene fields with these; :mod:`lieseries.scenes` reads them.
"""

from __future__ import annotations

import copy
import difflib

from .precision import MAX_EXPONENT, MAX_ORDER, check_count, check_time, check_dps, check_order, resolve_precision, to_fraction

__all__ = ["SceneError", "REQUIRED", "MAX_MAGNITUDE", "show", "fail", "table", "number", "positive", "nonnegative",
           "fraction01", "tolerance", "nonzero", "integer", "boolean", "string", "choice", "identifier", "vector3",
           "matrix3", "precision", "list_of", "orders", "api", "dps", "order", "count", "time"]

#: Numbers in a scene lie within 1e-MAX_MAGNITUDE .. 1eMAX_MAGNITUDE in magnitude (or are 0): the API's bound
#: (:data:`lieseries.precision.MAX_EXPONENT`, what :func:`~lieseries.precision.to_fraction` accepts).
MAX_MAGNITUDE = MAX_EXPONENT


class SceneError(ValueError):
    """A scene file is invalid; the message names the field by its dotted path."""


class _Required:
    def __repr__(self):
        return "REQUIRED"


#: The default of a field that must be given.
REQUIRED = _Required()


def show(v) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def fail(path: str, what: str, value):
    hint = ""
    if isinstance(value, float) and (value == 0 or value in (float("inf"), float("-inf"))):
        # (TOML reads a number beyond a double's range as 0.0 or inf before the scene sees it)
        hint = ('; a TOML number beyond a double\'s range (1e-400, 1e400) reads as 0.0 or inf: write it as a string '
                '("1e-400"), which is read exactly')
    raise SceneError(f"`{path}` must be {what}; got {show(value)}{hint}")


def number(value, path, *, positive=False, nonzero=False, below_one=False, what="a number"):
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        fail(path, what + ' (a decimal string such as "0.1" is read exactly)', value)
    try:
        q = to_fraction(value, path)
    except TypeError:
        fail(path, what + ' (a decimal string such as "0.1" is read exactly)', value)
    except ValueError as err:
        raise SceneError(str(err)) from None
    # its magnitude is bounded by to_fraction, as in the API (MAX_MAGNITUDE)
    if positive and q <= 0:
        fail(path, "a positive number", value)
    if nonzero and q == 0:
        fail(path, "a nonzero number", value)
    if below_one and not (0 < q < 1):
        fail(path, "a number between 0 and 1", value)
    return value


def time(positive=False):
    """A time: a nonzero (``positive``: a positive) number within the doubles' range (the API's check_time)."""
    return api(check_time, positive=positive)


def positive(value, path):
    return number(value, path, positive=True)


def nonzero(value, path):
    return number(value, path, nonzero=True)


def nonnegative(value, path):
    number(value, path)
    if to_fraction(value, path) < 0:
        fail(path, "a number >= 0", value)
    return value


def fraction01(value, path):
    return number(value, path, below_one=True)


def tolerance(value, path):
    return number(value, path, below_one=True, what="a tolerance (a number between 0 and 1)")


def integer(lo=None, hi=None):
    def check(value, path):
        if isinstance(value, bool) or not isinstance(value, int):
            fail(path, "an integer", value)
        if lo is not None and value < lo:
            fail(path, f"an integer >= {lo}", value)
        if hi is not None and value > hi:
            fail(path, f"an integer <= {hi}", value)
        return value

    return check


def boolean(value, path):
    if not isinstance(value, bool):
        fail(path, "true or false", value)
    return value


def string(value, path):
    if not isinstance(value, str):
        fail(path, "a string", value)
    return value


def choice(*choices):
    def check(value, path):
        if value not in choices:
            raise SceneError(f"`{path}` must be one of {', '.join(repr(c) for c in choices)}; got {show(value)}")
        return value

    return check


def identifier(value, path):
    if not (isinstance(value, str) and value.isidentifier()):
        fail(path, "a Python name (the function that builds the model)", value)
    return value


def vector3(value, path):
    if not isinstance(value, list) or len(value) != 3:
        fail(path, "a list of 3 numbers", value)
    for i, v in enumerate(value):
        number(v, f"{path}[{i}]")
    return value


def matrix3(value, path):
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) and len(r) == 3 for r in value)):
        fail(path, "a 3x3 list of numbers", value)
    for i, r in enumerate(value):
        for j, v in enumerate(r):
            number(v, f"{path}[{i}][{j}]")
    return value


def precision(value, path):
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise SceneError(f"`{path}`: unknown precision {show(value)}; use 'double', 'long double', 'quad' or an "
                         "integer number of bits")
    try:
        resolve_precision(value, path)
    except (TypeError, ValueError) as err:
        raise SceneError(f"`{path}`: unknown precision {show(value)}; use 'double', 'long double', 'quad' or an "
                         f"integer number of bits ({err})") from None
    return value


def list_of(check, *, allow_scalar=True, nonempty=True):
    """A checker accepting ``check``-valid values or (in studies) lists of them."""

    def wrapped(value, path):
        if isinstance(value, list):
            if nonempty and not value:
                fail(path, "a non-empty list", value)
            return [check(v, f"{path}[{i}]") for i, v in enumerate(value)]
        if not allow_scalar:
            fail(path, "a list", value)
        return check(value, path)

    return wrapped


def api(check, *args, **kwargs):
    """The scene checker of an API argument: ``check(value, path, *args, **kwargs)`` is the validator the API itself
    calls (:func:`~lieseries.precision.check_dps`, ...), so the scene's bound is the API's bound; its TypeError or
    ValueError (which names the argument, here the field's dotted path) becomes a :class:`SceneError`."""

    def checker(value, path):
        try:
            check(value, path, *args, **kwargs)
        except (TypeError, ValueError) as err:
            raise SceneError(str(err)) from None
        return value

    checker.api = check
    return checker


#: Decimal digits of an mpmath computation (Lie series, validated, mpmath, references): the API's check_dps.
dps = api(check_dps)
#: A series order: the API's check_order (1 .. MAX_ORDER).
order = api(check_order)


def count(low: int = 1, high: int | None = None):
    """An integer count in [low, high], checked as the API checks its counts (samples, repeat, ensemble, ...)."""
    return api(check_count, low=low, high=high)


def orders(value, path):
    """A non-empty list of series orders, each in 0 .. MAX_ORDER (the series is built at the largest, which is an
    API order: at least 1)."""
    if not isinstance(value, list) or not value:
        fail(path, "a non-empty list of non-negative integers", value)
    for i, v in enumerate(value):
        integer(0, MAX_ORDER)(v, f"{path}[{i}]")
    if max(value) < 1:
        fail(path, "a list of orders whose largest is at least 1", value)
    return value


def table(data, path: str, spec: dict, what: str = "a table") -> dict:
    """Check a table against ``spec`` (name -> (checker, default or REQUIRED)); return it with defaults."""
    if not isinstance(data, dict):
        raise SceneError(f"`{path}` must be {what}; got {show(data)}")
    for key in data:
        if key not in spec:
            full = f"{path}.{key}" if path else key
            near = difflib.get_close_matches(key, list(spec), n=1)
            hint = f" (did you mean `{near[0]}`?)" if near else ""
            raise SceneError(f"unknown field `{full}`{hint}; known: {', '.join(spec)}")
    out = {}
    for key, (check, default) in spec.items():
        full = f"{path}.{key}" if path else key
        if key in data:
            out[key] = check(data[key], full) if check is not None else data[key]
        elif default is REQUIRED:
            raise SceneError(f"missing required field `{full}`")
        else:
            out[key] = copy.deepcopy(default)
    return out
