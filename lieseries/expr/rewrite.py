"""Rewrites and scans of heyoka expressions through their sympy form: integer powers written as products (what
heyoka's Taylor recurrences need from a base at 0), the binary constants an expression carries, and a walk that
visits each distinct subexpression once (a derived field is a small graph but a huge tree)."""

from __future__ import annotations

from fractions import Fraction

import heyoka as hy
import mpmath as mp

from ..precision import carried_bits
from .builder import sympy_forms

__all__ = ["binary_constants", "powers_as_products", "distinct_nodes", "expand_integer_powers"]


def binary_constants(expr) -> list:
    """The float constants of the heyoka expression ``expr`` that are not short dyadic numbers, as the doubles
    heyoka stores (0.1 in ``q - 0.1`` is 0.1000000000000000055...), in increasing order."""
    import sympy

    floats = {float(n) for n in distinct_nodes(hy.to_sympy(expr)) if isinstance(n, sympy.Float)}
    return [v for v in sorted(floats) if carried_bits(v) is not None]



def powers_as_products(exprs) -> list:
    """The heyoka expressions ``exprs``, each with its integer powers ``b**n``, ``|n| >= 3``, written as products
    (:func:`_power_as_products`), converted to sympy together (shared subexpressions built once)."""
    return [_power_as_products(e, s) for e, s in zip(exprs, sympy_forms(exprs))]


def _power_as_products(expr, s):
    """``expr`` (its sympy form ``s``) with every integer power ``b**n``, ``|n| >= 3``, written as a product of
    ``|n|`` factors ``b``.

    heyoka's Taylor recurrence for ``pow`` divides by the base, so ``q**3`` (the force of a quartic potential) is
    NaN from the first step wherever ``q`` starts at 0; ``q*q*q`` is not. The rewrite goes through sympy and is kept
    only when it reads back as the same expression (names, parameters and numbers unchanged); otherwise ``expr``
    is returned as it is. Every walk over the sympy form visits each distinct subexpression once: a large field
    (a derived rigid body's) shares subexpressions that a tree walk visits millions of times.
    """
    has_power, free = _scan(s)
    if not has_power:
        return expr
    symbols = {}
    for sym in free:
        name = sym.name
        if name.startswith("par[") and name.endswith("]") and name[4:-1].isdigit():
            symbols[sym] = hy.par[int(name[4:-1])]
        else:
            symbols[sym] = hy.expression(name)
    try:
        out = hy.from_sympy(expand_integer_powers(s), s_dict=symbols)
        back = hy.to_sympy(out)
    except (TypeError, ValueError):  # a node sympy and heyoka do not translate both ways
        return expr
    if _scan(back)[1] != free:
        return expr
    # the same function: equal at a point where every symbol is a distinct rational, at 100 digits (a number
    # rounded on the way, a long double or quad constant read as a double, would differ by 1e-20 or more), by the
    # project's own compiler, which keeps shared subexpressions shared
    from . import compile_expressions

    par_index = [int(sym.name[4:-1]) for sym in symbols if sym.name.startswith("par[")]
    names = sorted(sym.name for sym in symbols if not sym.name.startswith("par["))
    npars = 1 + max(par_index, default=-1)
    values = [Fraction(k + 2, k + 3 + len(symbols)) for k in range(len(names))]
    pars = [Fraction(k + 2, k + 5 + len(symbols) + npars) for k in range(npars)]
    try:
        a, b = compile_expressions(names, [expr, out], npars, cse=False).evaluate(values, pars, 100)
    except (NotImplementedError, ValueError, ZeroDivisionError):
        return expr
    if not (mp.isfinite(a) and mp.isfinite(b)) or abs(a - b) > Fraction(1, 10**60) * (1 + abs(a)):
        return expr
    return out


def _is_big_power(e) -> bool:
    return e.is_Pow and e.exp.is_Integer and abs(int(e.exp)) >= 3


def distinct_nodes(s):
    """The distinct subexpressions of the sympy expression ``s``, each once. A field with shared subexpressions (a
    derived rigid body's, from heyoka) is a small graph but a huge tree: sympy's own walks (``atoms``,
    ``preorder_traversal``) visit the tree and take minutes where this takes milliseconds."""
    seen = set()
    stack = [s]
    while stack:
        e = stack.pop()
        if e in seen:
            continue
        seen.add(e)
        yield e
        stack.extend(e.args)


def _scan(s):
    """(whether the sympy expression ``s`` has an integer power with ``|n| >= 3``, its set of symbols), each
    distinct subexpression visited once."""
    free, has_power = set(), False
    for e in distinct_nodes(s):
        if e.is_Symbol:
            free.add(e)
        has_power = has_power or _is_big_power(e)
    return has_power, free


def expand_integer_powers(e, memo=None):
    """The sympy expression ``e`` with every integer power ``b**n``, ``|n| >= 3``, an unevaluated product of
    ``|n|`` factors (its reciprocal for ``n < 0``): what heyoka needs to run it from ``b = 0``. Each distinct
    subexpression is rewritten once (``memo``)."""
    if e.is_Atom:
        return e
    memo = {} if memo is None else memo
    done = memo.get(e)
    if done is not None:
        return done
    import sympy as sp

    args = [expand_integer_powers(a, memo) for a in e.args]
    if e.is_Pow:
        base, ex = args
        if ex.is_Integer and abs(int(ex)) >= 3:
            prod = sp.Mul(*([base] * abs(int(ex))), evaluate=False)
            out = prod if int(ex) > 0 else sp.Pow(prod, -1, evaluate=False)
        else:
            out = sp.Pow(base, ex, evaluate=False)
    elif e.is_Mul:
        out = sp.Mul(*args, evaluate=False)
    elif e.is_Add:
        out = sp.Add(*args, evaluate=False)
    else:
        out = e.func(*args)
    memo[e] = out
    return out
