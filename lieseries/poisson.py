"""PoissonSystem: variables, a Poisson tensor P(z) and a Hamiltonian H, as heyoka expressions.

From these three the engine derives everything it integrates: the Hamiltonian vector field
``X_H = P(z) grad H`` (one heyoka expression per variable, built with ``hy.diff``), the bracket
``{F, G} = grad F . P grad G`` of any two expressions, and numerical checks of the structure (antisymmetry, the
Jacobi identity, Casimirs) evaluated in mpmath at sample points.

A new model needs nothing but a bracket and a Hamiltonian::

    import heyoka as hy
    import lieseries as ls

    q, p = hy.make_vars("q", "p")
    pendulum = ls.PoissonSystem(
        variables=[q, p],
        tensor=[[0, 1], [-1, 0]],                  # canonical bracket {q, p} = 1
        hamiltonian=p**2 / 2 - hy.par[0] * hy.cos(q),
        parameters={"g_over_l": 1},
        name="pendulum",
    )
    sol = ls.integrate(pendulum, [0.5, 0.0], t=10.0)

Model parameters are heyoka runtime parameters ``hy.par[i]`` (in the order of ``parameters``); their values are
kept exact and rounded once to each working precision, so a constant like 1/3 costs no accuracy at 237 bits.
Numeric literals inside expressions are doubles in heyoka: keep them dyadic (0.5, 2, -1), and pass anything else
as a parameter.
"""

from __future__ import annotations

import copy
from fractions import Fraction
from typing import Mapping, Sequence

import heyoka as hy
import mpmath as mp

import numpy as np

from . import cache
from .expr.rewrite import binary_constants, powers_as_products
from .precision import NamedValues, bits_to_dps, carried_bits, check_dps, state_bits, to_fraction

__all__ = ["PoissonSystem", "as_poisson_system"]

#: Largest dimension whose Jacobi identity is checked at construction by default (the check grows like n^4).
JACOBI_AUTO_DIMENSION = 6

#: The ranges (in thousandths) of the sample states' entries tried after [0.3, 1.3], where a tensor is undefined.
WIDER_SAMPLES = ((-1300, 1300), (-130, 130), (1300, 13000), (-13000, 13000), (13000, 130000), (-130000, 130000))

#: Compiled mpmath programs of vector fields, by structural key (shared by equal structures).
_PROGRAMS = cache.region("poisson.programs", 128)  # per structure: the field as simplified and as written


def _is_zero(e) -> bool:
    if isinstance(e, (int, float, Fraction)):
        return e == 0
    return isinstance(e, hy.expression) and e == hy.expression(0.0)


def _as_expr(e, argname: str) -> hy.expression:
    if isinstance(e, hy.expression):
        return e
    if isinstance(e, bool):
        raise TypeError(f"`{argname}` must be a heyoka expression or a number; got bool")
    if isinstance(e, (int, float)):
        return hy.expression(float(e))
    if isinstance(e, Fraction):
        if e.denominator & (e.denominator - 1):
            raise ValueError(
                f"`{argname}` = {e} is not exact in binary; pass it as a runtime parameter (`parameters=`)"
            )
        return hy.expression(float(e))
    raise TypeError(f"`{argname}` must be a heyoka expression or a number; got {type(e).__name__}")


def _read_variables(variables) -> list:
    """The state variables as heyoka variables (names made into variables), checked non-empty and distinct."""
    if isinstance(variables, (str, bytes)) or not hasattr(variables, "__len__"):
        raise TypeError("`variables` must be a sequence of names or heyoka variables")
    if len(variables) == 0:
        raise ValueError("`variables` must not be empty")
    vs = []
    for i, v in enumerate(variables):
        if isinstance(v, str):
            v = hy.make_vars(v)
        if not isinstance(v, hy.expression):
            raise TypeError(f"`variables[{i}]` must be a name or a heyoka variable; got {type(v).__name__}")
        vs.append(v)
    names = [str(v) for v in vs]
    if len(set(names)) != len(names):
        raise ValueError(f"`variables` must have distinct names; got {names}")
    return vs


def _read_tensor(tensor, n: int) -> list:
    """The Poisson tensor as n x n expressions, None where an entry is zero."""
    try:
        rows = [list(r) for r in tensor]
    except TypeError:
        raise TypeError("`tensor` must be an n x n nested sequence of expressions") from None
    if len(rows) != n or any(len(r) != n for r in rows):
        shape = (len(rows), sorted({len(r) for r in rows}))
        raise ValueError(f"`tensor` must be {n} x {n} to match `variables`; got rows x columns {shape}")
    return [
        [None if _is_zero(rows[i][j]) else _as_expr(rows[i][j], f"tensor[{i}][{j}]") for j in range(n)]
        for i in range(n)
    ]


class PoissonSystem:
    """A Hamiltonian system ``dz/dt = {z, H} = P(z) grad H`` with a possibly non-canonical, degenerate bracket.

    Parameters
    ----------
    variables : sequence of str or heyoka variables, length n
        The coordinates z_1..z_n, in state order.
    tensor : n x n nested sequence of heyoka expressions or numbers
        The Poisson tensor ``P_ij = {z_i, z_j}``. Zero entries may be given as ``0``.
    hamiltonian : heyoka expression
        H(z), possibly using runtime parameters ``hy.par[i]``.
    parameters : mapping name -> value, or sequence of values, optional
        Values of ``hy.par[0], hy.par[1], ...``; int, str, Fraction, float or mpf, all kept exact.
    casimirs : mapping name -> expression, optional
        Functions expected to Poisson-commute with every coordinate; see :meth:`casimir_residual`.
    extra_field : sequence of n expressions, optional
        A non-Hamiltonian term added to ``X_H`` (e.g. a dissipative torque): the motion is then
        ``dz/dt = P grad H + extra_field``. The bracket and its checks ignore it.
    name : str
        A label used in messages and reports.
    input_bits : mapping name -> bits, optional
        For models: the precision carried by the data the model was built from (e.g. ``{"inertia": 53}`` for
        moments given as binary floats such as 1.1), reported by :meth:`coarse_data`.
    parameter_sources : mapping parameter name -> argument name, optional
        For models: the argument each runtime parameter is computed from (``{"Iinv1": "inertia"}``), named when
        the parameter does not fit a precision.
    jacobi : bool or None
        Check the Jacobi identity at construction (:meth:`check_jacobi`): None (default) does so for systems of at
        most :data:`JACOBI_AUTO_DIMENSION` variables, whose check is cheap; True always, False never.

    Construction refuses what is not a Poisson system, naming the entry: expressions in variables not among
    ``variables``, expressions depending on time (``heyoka.time``), a tensor that is not antisymmetric
    (checked numerically at a few sample states when the entries are not written as each other's negatives),
    and, as above, one that fails the Jacobi identity. :meth:`invariants` gives H and the Casimirs at a state.
    """

    def __init__(
        self,
        variables: Sequence,
        tensor,
        hamiltonian,
        *,
        parameters: Mapping | Sequence | None = None,
        casimirs: Mapping | None = None,
        extra_field: Sequence | None = None,
        name: str = "system",
        input_bits: Mapping | None = None,
        jacobi: bool | None = None,
        parameter_sources: Mapping | None = None,
    ):
        self._variables = _read_variables(variables)
        self._names = tuple(str(v) for v in self._variables)
        n = len(self._variables)
        self._tensor = _read_tensor(tensor, n)
        self._hamiltonian = _as_expr(hamiltonian, "hamiltonian")
        self._set_parameters(parameters, parameter_sources, input_bits)
        self._constants_checked = False
        self._native_params = {}
        self._check_parameter_count(extra_field)
        self._casimirs = {str(k): _as_expr(c, f"casimirs[{k!r}]") for k, c in (casimirs or {}).items()}
        if "energy" in self._casimirs:
            raise ValueError("`casimirs` must not use the name 'energy': `invariants` gives H under that name")
        self._invariant_program = None
        if extra_field is not None:
            if len(extra_field) != n:
                raise ValueError(f"`extra_field` must have {n} entries, one per variable; got {len(extra_field)}")
            extra_field = [None if _is_zero(e) else _as_expr(e, f"extra_field[{i}]") for i, e in enumerate(extra_field)]
        self._extra = extra_field
        self.name = str(name)
        self._field = None
        self._ode = None
        self._written = None  # (written_program)
        self._key = None
        self._invariants_key = None
        self._check_expressions(extra_field)
        self._check_antisymmetry()
        self._check_structure(jacobi)

    # -- checks at construction ----------------------------------------------------------------------------------
    def _set_parameters(self, parameters, parameter_sources, input_bits):
        """The runtime parameters' names, labels (for messages), exact values and the bits binary inputs carry."""
        if parameters is None:
            parameters = {}
        if isinstance(parameters, Mapping):
            pnames = tuple(str(k) for k in parameters)
            pvals = list(parameters.values())
        else:
            pvals = list(parameters)
            pnames = tuple(f"p{i}" for i in range(len(pvals)))
        self._param_names = pnames
        sources = dict(parameter_sources or {})
        self._param_labels = tuple(
            f"`{sources[k]}` gives the runtime parameter {k!r}, whose value" if k in sources else f"`parameters[{k!r}]` ="
            for k in pnames)
        self._param_values = tuple(to_fraction(v, f"parameters[{k!r}]") for k, v in zip(pnames, pvals))
        self._coarse = {f"parameters[{k!r}]": b for k, b in ((k, carried_bits(v)) for k, v in zip(pnames, pvals))
                        if b is not None}
        for k, b in (input_bits or {}).items():
            if b is not None:
                self._coarse[str(k)] = int(b)

    def _check_parameter_count(self, extra_field):
        """The expressions use no runtime parameter beyond those given."""
        used = hy.get_params(
            [self._hamiltonian]
            + [e for r in self._tensor for e in r if e is not None]
            + [e for e in (extra_field or []) if isinstance(e, hy.expression)]
        )
        npar_used = 1 + max((int(str(p)[1:]) for p in used), default=-1)
        if npar_used > len(self._param_values):
            raise ValueError(
                f"the expressions use {npar_used} runtime parameters (hy.par[0..{npar_used - 1}]) but "
                f"`parameters` gives {len(self._param_values)} values"
            )

    def _check_structure(self, jacobi):
        """The Jacobi identity and the Casimirs, when asked (``jacobi=True``) or by default in small dimensions (a
        function the mpmath compiler lacks then skips them)."""
        if jacobi is not None and not isinstance(jacobi, bool):
            raise TypeError(f"`jacobi` must be True, False or None (automatic); got {jacobi!r}")
        if jacobi or (jacobi is None and len(self._variables) <= JACOBI_AUTO_DIMENSION):
            try:
                self.check_jacobi()
                self.check_casimirs()
            except NotImplementedError:  # a function the mpmath compiler lacks: not checked automatically
                if jacobi is True:
                    raise

    def _check_expressions(self, extra_field):
        """Every expression uses declared variables only, and none depends on time."""
        from .expr import uses_time

        known = set(self._names)
        named = [("hamiltonian", self._hamiltonian)]
        named += [(f"tensor[{i}][{j}]", e) for i, r in enumerate(self._tensor) for j, e in enumerate(r) if e is not None]
        named += [(f"casimirs[{k!r}]", e) for k, e in self._casimirs.items()]
        named += [(f"extra_field[{i}]", e) for i, e in enumerate(extra_field or []) if e is not None]
        exprs = [e for _w, e in named]
        if set(hy.get_variables(exprs)) <= known and not uses_time(exprs):
            return  # all at once (shared subexpressions): the usual case; otherwise find the entry to name
        for where, e in named:
            if uses_time(e):
                raise ValueError(
                    f"`{where}` depends on time (heyoka.time): a PoissonSystem is autonomous (H and the bracket are "
                    "functions of the state; its energy check and invariants assume so). Make time a state "
                    "variable: add `tau` and a conjugate `E` to `variables` with {tau, E} = 1, and use H + E with `tau` "
                    "in place of time (then dtau/dt = 1)."
                )
            unknown = sorted(set(hy.get_variables(e)) - known)
            if unknown:
                shown = ", ".join(f"`{u}`" for u in unknown)
                raise ValueError(
                    f"`{where}` uses {shown}, which {'is' if len(unknown) == 1 else 'are'} not among `variables` "
                    f"{list(self._names)}: add {'it' if len(unknown) == 1 else 'them'} to `variables` (with a row and "
                    "a column of `tensor`), or make a constant a runtime parameter (`hy.par[i]` with its value in "
                    "`parameters`)"
                )

    def _sample_points(self, count: int = 3):
        """A few fixed pseudo-random states with entries in [0.3, 1.3] (exact decimals), for numerical checks, then
        further ones at other signs and scales (entries in each of :data:`WIDER_SAMPLES`, four states each), for
        expressions defined at none of the first (a root or logarithm of x1 - 2)."""
        import random

        rng = random.Random(20240617 + self.dimension + count)
        n = self.dimension
        pts = [[Fraction(rng.randint(300, 1300), 1000) for _ in range(n)] for _ in range(count)]
        for lo, hi in WIDER_SAMPLES:
            pts += [[Fraction(rng.randint(lo, hi), 1000) for _ in range(n)] for _ in range(4)]
        return pts

    def _defined_samples(self, exprs, count, dps, what):
        """Values of ``exprs`` at the first ``count`` sample states where they are defined, at ``dps`` (and
        ``dps + 20`` digits when ``dps`` is a pair); ValueError naming ``what`` when they are defined at none: a
        structure that cannot be checked is not taken as checked."""
        found, tried = [], 0
        for z in self._sample_points(count):
            tried += 1
            vals = [self._values_at(exprs, [z], d) for d in (dps if isinstance(dps, tuple) else (dps,))]
            if all(vals):
                found.append([v[0] for v in vals])
                if len(found) == count:
                    break
        if not found:
            raise ValueError(
                f"{what} cannot be checked: its expressions are undefined (a division by zero, a root or logarithm "
                f"of a negative number) at every one of {tried} sample states with entries from -130 to 130. "
                "Build the system with `jacobi=False` and check it at states in its domain: "
                "`check_jacobi(points=[...])`, `antisymmetry_residual(points)`, `check_casimirs(points=[...])`")
        return found

    def _values_at(self, exprs, points, dps):
        """Values of ``exprs`` at each of ``points`` where they are defined (points where an expression is
        singular or undefined, e.g. a division by zero, are left out)."""
        out = []
        for z in points:
            try:
                vals = self._evaluate(exprs, [z], dps)[0]
            except (ZeroDivisionError, ValueError, ArithmeticError):
                continue
            if all(mp.isfinite(v) for v in vals):
                out.append(vals)
        return out

    def _check_antisymmetry(self):
        """P_ij = -P_ji and P_ii = 0: structurally when the entries are written as negatives of each other,
        otherwise numerically at a few sample states (30 digits, relative to the entries)."""
        n = self.dimension
        pairs = []
        for i in range(n):
            for j in range(i, n):
                a, b = self._tensor[i][j], self._tensor[j][i]
                if a is None and b is None:
                    continue
                if i != j and a is not None and b is not None and (b == -a or -b == a):
                    continue
                zero = hy.expression(0.0)
                pairs.append((i, j, zero if a is None else a, zero if b is None else b))
        if not pairs:
            return
        exprs = [e for _i, _j, a, b in pairs for e in (a, b)]
        try:
            samples = self._defined_samples(exprs, 2, 30, "`tensor`'s antisymmetry")
        except NotImplementedError:  # a function the mpmath compiler lacks: the engines say so when they need it
            return
        for (vals,) in samples:
            for k, (i, j, _a, _b) in enumerate(pairs):
                va, vb = vals[2 * k], vals[2 * k + 1]
                if abs(va + vb) > mp.mpf(10) ** -20 * (abs(va) + abs(vb)) or (i == j and va != 0):
                    if i == j:
                        raise ValueError(
                            f"`tensor[{i}][{i}]` must be 0: a Poisson bracket is antisymmetric, {{z, z}} = 0 (got "
                            f"{mp.nstr(va, 6)} at a sample state)"
                        )
                    raise ValueError(
                        f"`tensor[{i}][{j}]` and `tensor[{j}][{i}]` must be opposite (P_ij = -P_ji: a Poisson bracket "
                        f"is antisymmetric); at a sample state they are {mp.nstr(va, 6)} and {mp.nstr(vb, 6)}. Give "
                        f"the entry above the diagonal and its negative below it (`tensor[{j}][{i}]` = "
                        f"-`tensor[{i}][{j}]`)."
                    )

    def check_jacobi(self, points=None, dps: int = 40) -> None:
        """Check the Jacobi identity {z_i, {z_j, z_k}} + cyclic = 0 numerically (:meth:`jacobi_expressions`).

        At ``points`` (default: three fixed pseudo-random states), the Jacobiator is evaluated with ``dps`` and
        ``dps + 20`` digits: where the identity holds it is rounding noise, which changes with the digits; a value
        that stays the same is a failure of the identity. Runs at construction for systems of at most
        :data:`JACOBI_AUTO_DIMENSION` variables (``jacobi=None``); call it for larger ones (its cost grows like
        n^4).

        Raises
        ------
        ValueError
            Naming the first triple (i, j, k) of variables where the identity fails, with the value.
        """
        dps = check_dps(dps)
        exprs = self.jacobi_expressions()
        samples = (self._defined_samples(exprs, 3, (dps, dps + 20), "The Jacobi identity of `tensor`")
                   if points is None else self._given_samples(exprs, points, dps))
        n = self.dimension
        triples = [(i, j, k) for i in range(n) for j in range(i + 1, n) for k in range(j + 1, n)]
        for lo, hi in samples:
            for (i, j, k), a, b in zip(triples, lo, hi):
                if b != 0 and abs(a - b) <= mp.mpf(10) ** -6 * abs(b):
                    names = self._names
                    raise ValueError(
                        f"`tensor` does not satisfy the Jacobi identity: {{{names[i]}, {{{names[j]}, {names[k]}}}}} + "
                        f"cyclic = {mp.nstr(b, 8)} at a sample state (it must vanish everywhere), so it is not a "
                        "Poisson bracket and the motion need not conserve what a Poisson system conserves. Check "
                        "the entries of `tensor` in the rows and columns of "
                        f"{names[i]}, {names[j]}, {names[k]}" + (
                            "; pass `jacobi=False` to build the system anyway" if n <= JACOBI_AUTO_DIMENSION else "")
                    )

    def _given_samples(self, exprs, points, dps):
        """Values of ``exprs`` at ``dps`` and ``dps + 20`` digits at each of the user's ``points`` where they are
        defined; ValueError when they are defined at none."""
        out = []
        for p in points:
            z = self._state_rows(p, "points")[0][0]
            lo, hi = self._values_at(exprs, [z], dps), self._values_at(exprs, [z], dps + 20)
            if lo and hi:
                out.append((lo[0], hi[0]))
        if not out:
            raise ValueError("`points`: the expressions checked are singular or undefined at every point given; "
                             "choose others")
        return out

    def check_casimirs(self, points=None, dps: int = 40) -> None:
        """Check that every declared Casimir C Poisson-commutes with every coordinate, {C, z_a} = 0, numerically
        as :meth:`check_jacobi` does (a value that stays the same at ``dps`` and ``dps + 20`` digits is not
        rounding noise). Runs at construction with the Jacobi check.

        Raises
        ------
        ValueError
            Naming the Casimir and the coordinate it does not commute with, with the value.
        """
        if not self._casimirs:
            return
        dps = check_dps(dps)
        names = list(self._casimirs)
        exprs = [self.bracket(self._casimirs[c], v) for c in names for v in self._variables]
        samples = (self._defined_samples(exprs, 3, (dps, dps + 20), "The Casimirs' brackets")
                   if points is None else self._given_samples(exprs, points, dps))
        n = self.dimension
        for lo, hi in samples:
            for idx, (a, b) in enumerate(zip(lo, hi)):
                if b != 0 and abs(a - b) <= mp.mpf(10) ** -6 * abs(b):
                    c, v = names[idx // n], self._names[idx % n]
                    raise ValueError(
                        f"`casimirs[{c!r}]` is not a Casimir of this bracket: {{{c}, {v}}} = {mp.nstr(b, 8)} at a "
                        "sample state (a Casimir commutes with every coordinate). Declare it only if it is one "
                        "(an invariant of this Hamiltonian alone is checked by `invariants`, not declared here)")

    # -- structure ---------------------------------------------------------------------------------------------
    @property
    def variables(self) -> list:
        """The heyoka variables, in state order."""
        return list(self._variables)

    @property
    def names(self) -> tuple:
        """Variable names, in state order."""
        return self._names

    @property
    def dimension(self) -> int:
        """Number of variables n."""
        return len(self._variables)

    @property
    def hamiltonian(self) -> hy.expression:
        """The Hamiltonian H(z)."""
        return self._hamiltonian

    @property
    def tensor(self) -> list:
        """The Poisson tensor as an n x n list of heyoka expressions (zeros as ``hy.expression(0.)``)."""
        zero = hy.expression(0.0)
        return [[zero if e is None else e for e in row] for row in self._tensor]

    @property
    def parameter_names(self) -> tuple:
        """Names of the runtime parameters, in ``hy.par`` order."""
        return self._param_names

    @property
    def parameter_values(self) -> tuple:
        """Exact values of the runtime parameters (Fractions), in ``hy.par`` order (a tuple that names, in
        errors, the argument each came from: rounding I^-1 = 1e330 to double names `inertia`)."""
        return NamedValues(self._param_values, self._param_labels)

    @property
    def is_hamiltonian(self) -> bool:
        """False when a non-Hamiltonian ``extra_field`` is part of the motion."""
        return self._extra is None or all(e is None for e in self._extra)

    @property
    def casimirs(self) -> dict:
        """Declared Casimir functions, name -> expression."""
        return dict(self._casimirs)

    @property
    def vector_field(self) -> list:
        """``X_H = P grad H`` (plus ``extra_field``): one heyoka expression per variable (computed once)."""
        if self._field is None:
            grad = [hy.diff(self._hamiltonian, v) for v in self._variables]
            field = []
            for i, row in enumerate(self._tensor):
                terms = [e * g for e, g in zip(row, grad) if e is not None]
                if self._extra is not None and self._extra[i] is not None:
                    terms.append(self._extra[i])
                field.append(hy.sum(terms) if terms else hy.expression(0.0))
            self._field = field
        return list(self._field)

    @property
    def ode_system(self) -> list:
        """The vector field as heyoka's ``[(variable, rhs), ...]``. heyoka counts an ODE's parameters as one more
        than the largest index its expressions use and refuses any other number of values. Integer powers
        ``b**n``, ``|n| >= 3``, are written as products (:func:`lieseries.expr.rewrite.powers_as_products`). When the field does
        not read the last declared parameter (one that enters only an event, an invariant, or nothing), the last
        component gets ``+ (par[k] - par[k])``, exactly 0, so the integrator takes every declared value."""
        if self._ode is not None:
            return list(self._ode)
        pairs = list(zip(self._variables, powers_as_products(self.vector_field)))
        k = len(self._param_values) - 1
        if k >= 0 and pairs and 1 + max((int(str(p)[1:]) for p in hy.get_params([e for _, e in pairs])),
                                         default=-1) <= k:
            v, e = pairs[-1]
            pairs[-1] = (v, e + (hy.par[k] - hy.par[k]))
        self._ode = pairs
        return list(pairs)

    @property
    def key(self) -> str:
        """A structural key: systems with equal keys have the same vector field (the parameters' values apart) and
        compile to the same heyoka integrator. The expressions enter whole (:func:`lieseries.expr.expressions_digest`),
        not as printed: heyoka prints ~1000 characters of an expression at most."""
        if self._key is None:
            from .expr import expressions_digest

            self._key = repr((self._names, len(self._param_values), expressions_digest(self.vector_field)))
        return self._key

    @property
    def invariants_key(self) -> str:
        """:attr:`key` with the Hamiltonian and the Casimirs: systems with equal ones have the same energy check
        (a Hamiltonian that differs by a constant has the same field, not the same energy)."""
        if self._invariants_key is None:
            from .expr import expressions_digest

            names = list(self._casimirs)
            digest = expressions_digest([self._hamiltonian] + [self._casimirs[c] for c in names])
            self._invariants_key = repr((self.key, names, digest))
        return self._invariants_key

    def bracket(self, f, g) -> hy.expression:
        """The Poisson bracket ``{f, g} = sum_ij df/dz_i P_ij dg/dz_j`` as a heyoka expression."""
        f = _as_expr(f, "f")
        g = _as_expr(g, "g")
        df = [hy.diff(f, v) for v in self._variables]
        dg = [hy.diff(g, v) for v in self._variables]
        terms = [
            df[i] * e * dg[j]
            for i, row in enumerate(self._tensor)
            for j, e in enumerate(row)
            if e is not None
        ]
        return hy.sum(terms) if terms else hy.expression(0.0)

    def with_parameters(self, values) -> "PoissonSystem":
        """The same system (same structure, same compiled integrators) with other runtime parameter values."""
        values = tuple(to_fraction(v, f"parameters[{i}]") for i, v in enumerate(values))
        if len(values) != len(self._param_values):
            raise ValueError(f"`values` must give {len(self._param_values)} parameters; got {len(values)}")
        other = copy.copy(self)
        other._param_values = values
        other._param_labels = tuple(f"`parameters[{i}]` =" for i in range(len(values)))
        other._native_params = {}
        return other

    def native_parameters(self, prec):
        """The parameter values rounded once to the :class:`~lieseries.precision.Precision` ``prec`` (kept per
        precision; read-only), or None when the system has no parameters."""
        if not self._param_values:
            return None
        arr = self._native_params.get(prec.name)
        if arr is None:
            arr = prec.array(self.parameter_values, "parameters")
            arr.flags.writeable = False
            self._native_params[prec.name] = arr
        return arr

    def coarse_data(self) -> dict:
        """What in the system carries a finite precision: ``{argument: bits}``.

        Parameters given as long binary floats (1.1 as a double carries 53 bits), the model's inputs (see
        ``input_bits``), and float constants inside the expressions that are not short dyadic numbers (heyoka
        stores ``0.05 * q**2`` with the double nearest 0.05). Empty when every number is exact.
        """
        if not self._constants_checked:
            # the expressions as given (not the derived vector field: 0.1 q**4 in H is "the constant 0.1 in
            # `hamiltonian`", not the 0.4 of its derivative)
            named = [("hamiltonian", self._hamiltonian)]
            named += [(f"tensor[{i}][{j}]", e) for i, r in enumerate(self._tensor) for j, e in enumerate(r)
                      if e is not None]
            named += [(f"extra_field[{i}]", e) for i, e in enumerate(self._extra or []) if e is not None]
            for where, e in named:
                values = binary_constants(e)  # one entry (one warning) per expression, however many it holds
                if len(values) == 1:
                    self._coarse[f"the constant {values[0]!r} in {where}"] = 53
                elif values:
                    shown = ", ".join(map(repr, values[:4])) + (f" and {len(values) - 4} more" if len(values) > 4
                                                                  else "")
                    self._coarse[f"the constants {shown} in {where}"] = 53
            self._constants_checked = True
        return dict(self._coarse)

    @property
    def program(self):
        """The vector field compiled to an mpmath :class:`~lieseries.expr.Program` (once per structure)."""
        prog = _PROGRAMS.get(self.key)
        if prog is None:
            from .expr import compile_expressions

            prog = compile_expressions(self._variables, self.vector_field, len(self._param_values))
            _PROGRAMS[self.key] = prog
        return prog

    @property
    def written_program(self):
        """The vector field as heyoka evaluates it (``ode_system``'s expressions without sympy's simplification:
        :func:`~lieseries.expr.compile_expressions` ``as_written``), for bounds of heyoka's roundings; the
        :attr:`program` where it cannot be compiled so."""
        prog = getattr(self, "_written", None)
        if prog is None:  # once per structure (sympy without evaluation: 0.9 s for a heavy top's Dirac form,
            # which a model built again, or each ls.integrate of a new system object, would pay anew)
            wkey = (self.key, "as written")
            prog = _PROGRAMS.get(wkey)
            if prog is None:
                from .expr import compile_expressions

                try:
                    prog = compile_expressions(self._variables, [e for _, e in self.ode_system],
                                               len(self._param_values), as_written=True)
                except (NotImplementedError, ValueError, TypeError, AttributeError):  # pragma: no cover - defensive
                    prog = self.program
                prog = _PROGRAMS.put(wkey, prog)
            self._written = prog
        return prog

    # -- invariants ----------------------------------------------------------------------------------------------
    def invariants(self, y, dps: int | None = None) -> dict:
        """H and the declared Casimirs at a state, evaluated from its exact value in mpmath: the conserved
        quantities of the system (of its Hamiltonian part: an ``extra_field`` need not conserve them), to check
        a run as the built-in models' ``invariants`` do.

        Parameters
        ----------
        y : state (n numbers) or 2-d array of states (one per row)
            A model state built from exact input is taken at its exact values; an array at its stored values.
        dps : int, optional
            Decimal digits of the result (default: those of the state's precision plus 10; 87 for an exact state).

        Returns
        -------
        dict name -> mpf (``"energy"`` then the Casimirs by name); name -> list of mpf for a 2-d array.
        """
        if dps is None:
            dps = bits_to_dps(state_bits(y)) + 10
        dps = check_dps(dps)
        rows, was_1d = self._state_rows(y, "y")
        if self._invariant_program is None:
            from .expr import compile_expressions

            self._invariant_program = compile_expressions(
                self._variables, [self._hamiltonian] + list(self._casimirs.values()), len(self._param_values))
        names = ["energy"] + list(self._casimirs)
        vals = [self._invariant_program.evaluate(r, list(self._param_values), dps) for r in rows]
        out = {nm: [v[i] for v in vals] for i, nm in enumerate(names)}
        return {k: v[0] for k, v in out.items()} if was_1d else out

    def _state_rows(self, y, argname):
        """(rows of exact values, was_1d) of a state or a 2-d array of states (exact states at their exact
        values, never through the doubles numpy shows of them)."""
        n = self.dimension

        def row(r, name):
            exact = getattr(r, "exact", None)
            vals = list(exact) if exact is not None else list(r)
            if len(vals) != n:
                raise ValueError(f"`{name}` must hold states of length {n}; got length {len(vals)}")
            return [to_fraction(v, f"{name}[{i}]") if not hasattr(v, "_mpf_") else v for i, v in enumerate(vals)]

        if getattr(y, "exact", None) is not None:
            return [row(y, argname)], True
        if isinstance(y, (list, tuple)) and y and all(getattr(r, "exact", None) is not None for r in y):
            return [row(r, f"{argname}[{i}]") for i, r in enumerate(y)], False
        arr = y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object)
        if arr.ndim == 1:
            return [row(arr, argname)], True
        if arr.ndim == 2:
            return [row(r, f"{argname}[{i}]") for i, r in enumerate(arr)], False
        raise ValueError(f"`{argname}` must be a state (1-d) or one state per row (2-d); got {arr.ndim}-d")

    # -- numerical checks of the structure ---------------------------------------------------------------------
    def _evaluate(self, exprs, points, dps):
        from .expr import compile_expressions

        prog = compile_expressions(self._variables, exprs, len(self._param_values))
        out = []
        for i, z in enumerate(points):
            rows, _ = self._state_rows(z, f"points[{i}]")
            out.append(prog.evaluate(rows[0], list(self._param_values), dps))
        return out

    def antisymmetry_residual(self, points, dps: int = 50) -> mp.mpf:
        """Largest ``|P_ij + P_ji|`` over the sample ``points``, evaluated with ``dps`` digits."""
        n = self.dimension
        P = self.tensor  # (a property building the whole n x n list: read once)
        exprs = [P[i][j] + P[j][i] for i in range(n) for j in range(i, n)]
        vals = self._evaluate(exprs, points, dps)
        return max((abs(v) for row in vals for v in row), default=mp.mpf(0))

    def jacobi_expressions(self) -> list:
        """The Jacobiator ``J_ijk = sum_l P_li d_l P_jk + P_lj d_l P_ki + P_lk d_l P_ij`` for i < j < k."""
        n = self.dimension
        dP = {}

        def d(l, a, b):
            key = (l, a, b)
            if key not in dP:
                e = self._tensor[a][b]
                dP[key] = None if e is None else hy.diff(e, self._variables[l])
            return dP[key]

        out = []
        for i in range(n):
            for j in range(i + 1, n):
                for k in range(j + 1, n):
                    terms = []
                    for l in range(n):
                        for (a, b, c) in ((i, j, k), (j, k, i), (k, i, j)):
                            p = self._tensor[l][a]
                            if p is None:
                                continue
                            q = d(l, b, c)
                            if q is not None:
                                terms.append(p * q)
                    out.append(hy.sum(terms) if terms else hy.expression(0.0))
        return out

    def jacobi_residual(self, points, dps: int = 50) -> mp.mpf:
        """Largest ``|J_ijk|`` (the Jacobi identity's cyclic sum) over the sample ``points``."""
        vals = self._evaluate(self.jacobi_expressions(), points, dps)
        return max((abs(v) for row in vals for v in row), default=mp.mpf(0))

    def casimir_residual(self, casimir, points, dps: int = 50) -> mp.mpf:
        """Largest ``|{C, z_a}|`` over all coordinates z_a and sample ``points``.

        ``casimir`` is an expression, or the name of a declared Casimir.
        """
        if isinstance(casimir, str):
            if casimir not in self._casimirs:
                raise ValueError(f"`casimir` {casimir!r} is not declared; known: {sorted(self._casimirs)}")
            casimir = self._casimirs[casimir]
        exprs = [self.bracket(casimir, v) for v in self._variables]
        vals = self._evaluate(exprs, points, dps)
        return max((abs(v) for row in vals for v in row), default=mp.mpf(0))

    def __repr__(self) -> str:
        return f"PoissonSystem({self.name!r}, variables={list(self._names)}, parameters={list(self._param_names)})"


def as_poisson_system(system, argname: str = "system") -> PoissonSystem:
    """The PoissonSystem behind a model (anything with a ``.poisson`` attribute) or the system itself."""
    if isinstance(system, PoissonSystem):
        return system
    ps = getattr(system, "poisson", None)
    if isinstance(ps, PoissonSystem):
        return ps
    raise TypeError(
        f"`{argname}` must be a lieseries model (EulerPoisson, Sphere, ...) or a PoissonSystem; "
        f"got {type(system).__name__}"
    )
