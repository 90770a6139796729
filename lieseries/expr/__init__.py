"""Compile heyoka expressions into flat evaluation programs for mpmath.

heyoka expressions have no Python traversal API, but :func:`heyoka.to_sympy`
gives a faithful sympy tree of them: variables become ``sympy.Symbol(name,
real=True)``, runtime parameters ``hy.par[i]`` become ``Symbol("par[i]",
real=True)`` and double constants become ``sympy.Float`` objects with 53 bits
of precision holding the *exact* binary value of the double.  This module
turns a list of such expressions into a :class:`Program`: a flat list of
elementary operations over numbered *slots*, in topological order, with the
common subexpressions of all the expressions shared (``sympy.cse`` plus
structural hashing).

Slots are laid out as

* ``0 .. nvars-1``: the state variables, in the order given;
* ``nvars .. nvars+npars-1``: the runtime parameters ``par[0] ..``;
* then constants and intermediate results, in creation order.

A slot is *constant* when it does not depend on the variables (numbers,
parameters, and operations on them only); the Taylor-mode engine in
:mod:`lieseries.lie.jets` uses this to turn ``p * x`` into a scaling instead
of a Cauchy product.

Numbers are kept exact inside a program and rounded only when a program is run
at a given precision, so one compiled program serves every precision:

* sympy ``Integer``/``Rational`` -> the exact rational, rounded once at the
  working precision (``Rational(1, 3)`` -> ``mpf(1)/3``);
* sympy ``Float`` (a heyoka double) -> its exact binary value;
* ``pi`` and ``E`` -> computed at the working precision.

Note that heyoka folds numeric constants into doubles when it builds
expressions (``x / 3`` becomes ``0.333... * x`` in heyoka itself), so exact
rational coefficients of a vector field must be passed as runtime parameters.

All numeric work uses mpmath's raw representation (``mpmath.libmp`` tuples
``(sign, mantissa, exponent, bitcount)``), which avoids the cost of creating
``mpf`` objects; public functions take and return ordinary ``mpmath.mpf``.

The package compiles (this module: :func:`compile_expressions`,
:func:`compile_system`; the walk over sympy trees in :mod:`~lieseries.expr.builder`)
and evaluates (:mod:`~lieseries.expr.program`: :class:`Program`, its constants
and pointwise operations on raw numbers).
"""

from __future__ import annotations

import hashlib
import numbers
import pickle
import time

import heyoka as hy
import sympy

from .. import cache
from .builder import PAR_RE, Builder, sympy_forms
from .program import (EVAL_GUARD_BITS, POINTWISE, RND, SUPPORTED_OPS, Constant, Node, Program, convert_vector,
                      eval_nodes, rounded_mpf, to_raw)

__all__ = [
    "Program",
    "Node",
    "Constant",
    "compile_expressions",
    "compile_system",
    "expressions_digest",
    "SUPPORTED_OPS",
    "uses_time",
    # used across the package
    "EVAL_GUARD_BITS",
    "POINTWISE",
    "RND",
    "PAR_RE",
    "as_expression",
    "compile_program",
    "convert_vector",
    "eval_nodes",
    "rounded_mpf",
    "to_raw",
    "variable_names",
]


def expressions_digest(exprs) -> str:
    """A text that tells heyoka expressions apart in full: the SHA-256 of their pickled forms, in order.

    ``str`` of a heyoka expression stops after ~1000 characters (``... * ...``): two fields that differ only further
    on print the same, and a cache keyed by that text would run one system with the other's compiled code. Equal
    expressions built with other sharing of their subexpressions may get different digests (a cache miss, never a
    wrong hit)."""
    h = hashlib.sha256()
    for e in exprs:
        data = pickle.dumps(e, protocol=pickle.HIGHEST_PROTOCOL)
        h.update(len(data).to_bytes(8, "little"))
        h.update(data)
    return h.hexdigest()


#: A variable name no system uses: heyoka's time is substituted by it to find out whether an expression uses time.
_TIME_PROBE = "__lieseries_time_probe__"


def uses_time(expr) -> bool:
    """True when the heyoka expression ``expr`` (or any of a list of them) contains heyoka's time
    (``heyoka.time``, printed ``t``); a state variable named ``t`` is a variable, not time."""
    if isinstance(expr, (list, tuple)):
        exprs = [e for e in expr if isinstance(e, hy.expression)]
        if not exprs:
            return False
    elif isinstance(expr, hy.expression):
        exprs = expr
    else:
        return False
    probe = hy.expression(_TIME_PROBE)
    return _TIME_PROBE in hy.get_variables(hy.subs(exprs, {hy.time: probe}))


def variable_names(variables, name="variables"):
    """Names of a list of heyoka variables (or of plain strings)."""
    if isinstance(variables, (str, hy.expression)) or not hasattr(variables, "__iter__"):
        raise TypeError(f"`{name}` must be a list of heyoka variables")
    names = []
    for i, v in enumerate(variables):
        if isinstance(v, str):
            nm = v
        elif isinstance(v, hy.expression):
            s = hy.to_sympy(v)
            if not isinstance(s, sympy.Symbol) or PAR_RE.match(s.name):
                raise TypeError(f"`{name}[{i}]` must be a heyoka variable; got {v}")
            nm = s.name
        else:
            raise TypeError(
                f"`{name}[{i}]` must be a heyoka variable (hy.make_vars); got {type(v).__name__}"
            )
        names.append(nm)
    if len(set(names)) != len(names):
        raise ValueError(f"`{name}` contains duplicate variables: {names}")
    if not names:
        raise ValueError(f"`{name}` must not be empty")
    return names


def as_expression(e, name):
    """Coerce `e` to a heyoka expression (numbers are accepted)."""
    if isinstance(e, hy.expression):
        return e
    if isinstance(e, (numbers.Real,)) and not isinstance(e, bool):
        return hy.expression(float(e))
    raise TypeError(f"`{name}` must be a heyoka expression; got {type(e).__name__}")


#: Compiled programs by (variables, expressions, npars, cse), in the shared cache (:mod:`lieseries.cache`).
_PROGRAMS = cache.region("expr.programs", 32)


def compile_expressions(variables, exprs, npars=None, cse=True, as_written=False):
    """Compile heyoka expressions into a :class:`Program`.

    The expressions are converted with :func:`heyoka.to_sympy`, their common
    subexpressions are shared with :func:`sympy.cse` and structural hashing,
    and the result is flattened into elementary operations in topological
    order.  Compilation is cached (on the variables, the expressions and
    `npars`), so compiling the same system twice is free.

    Parameters
    ----------
    variables : sequence of heyoka.expression
        The state variables (from :func:`heyoka.make_vars`), or their names.
    exprs : sequence of heyoka.expression
        Expressions in these variables and in runtime parameters
        ``heyoka.par[i]``.  Plain numbers are accepted too.
    npars : int, optional
        Number of runtime parameters the program takes.  Default: one more
        than the largest parameter index used (0 if none).
    cse : bool, optional
        Run :func:`sympy.cse` before flattening (default).  Identical
        subtrees are always shared; ``cse=False`` skips the (superlinear)
        search for common sub-sums/sub-products, which is worthwhile only for
        very large one-shot expressions.
    as_written : bool, optional
        Keep the expressions' arithmetic as heyoka evaluates it: converted without sympy's automatic
        simplification (``0.5 (2 (q + 1e12)) - 1e12`` stays as it is, not ``q``) and without ``cse``. For bounds of
        heyoka's roundings (:mod:`lieseries.expr.rounding`), not for evaluation.

    Returns
    -------
    Program

    Raises
    ------
    NotImplementedError
        If an expression uses an unsupported function (the message names it)
        or depends on time.
    ValueError
        If an expression uses a variable not in `variables`, or a parameter
        index >= `npars`.
    """
    names = variable_names(variables)
    if isinstance(exprs, hy.expression) or not hasattr(exprs, "__iter__"):
        raise TypeError("`exprs` must be a list of heyoka expressions")
    exprs = [as_expression(e, f"exprs[{i}]") for i, e in enumerate(exprs)]
    if npars is not None and (
        isinstance(npars, bool) or not isinstance(npars, numbers.Integral) or npars < 0
    ):
        raise ValueError(f"`npars` must be None or an integer >= 0; got {npars!r}")
    key = (tuple(names), expressions_digest(exprs), npars, bool(cse) and not as_written, bool(as_written))
    prog = _PROGRAMS.get(key)
    if prog is not None:
        _PROGRAMS.touch(key)
        return prog
    start = time.perf_counter()
    prog = compile_program(names, exprs, npars, bool(cse) and not as_written, bool(as_written))
    return _PROGRAMS.put(key, prog, cost=time.perf_counter() - start)


def compile_program(names, exprs, npars, use_cse, as_written=False):
    """The :class:`Program` of heyoka expressions ``exprs`` in the variables ``names`` (checked, uncached: what
    :func:`compile_expressions` caches); ``as_written``: sympy's automatic simplification off."""
    sym = sympy_forms(exprs, as_written)
    if npars is None:
        used = set()
        for s in sym:
            for f in s.free_symbols:
                m = PAR_RE.match(f.name)
                if m:
                    used.add(int(m.group(1)))
        npars = max(used) + 1 if used else 0
    b = Builder(names, int(npars))
    if use_cse:
        repl, reduced = sympy.cse(
            sym, symbols=sympy.numbered_symbols("_cse", cls=sympy.Dummy), order="none"
        )
    else:
        repl, reduced = [], sym
    for s, e in repl:
        b.cse_map[s] = b.build(e)
    outputs = [b.build(e) for e in reduced]
    return Program(names, npars, b.constants, b.nodes, outputs, b.is_const)


def compile_system(variables, rhs, npars=None):
    """Compile the right-hand side of ``dz/dt = rhs(z)``.

    Same as ``compile_expressions(variables, rhs, npars)`` after checking
    that there is one right-hand side per variable.  The outputs of the
    program are the components of `rhs`, in order.
    """
    names = variable_names(variables)
    if isinstance(rhs, hy.expression) or not hasattr(rhs, "__len__"):
        raise TypeError("`rhs` must be a list of heyoka expressions")
    if len(rhs) != len(names):
        raise ValueError(
            f"`rhs` must have one expression per variable ({len(names)}); got {len(rhs)}"
        )
    return compile_expressions(variables, rhs, npars)

