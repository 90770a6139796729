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

from .precision import bits_to_dps, carried_bits, check_dps, state_bits, to_fraction

__all__ = ["PoissonSystem", "as_poisson_system"]

#: Compiled mpmath programs of vector fields, by structural key (shared by equal structures).
_PROGRAMS: dict = {}


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
    ):
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
        n = len(vs)
        try:
            rows = [list(r) for r in tensor]
        except TypeError:
            raise TypeError("`tensor` must be an n x n nested sequence of expressions") from None
        if len(rows) != n or any(len(r) != n for r in rows):
            shape = (len(rows), sorted({len(r) for r in rows}))
            raise ValueError(f"`tensor` must be {n} x {n} to match `variables`; got rows x columns {shape}")
        self._tensor = [
            [None if _is_zero(rows[i][j]) else _as_expr(rows[i][j], f"tensor[{i}][{j}]") for j in range(n)]
            for i in range(n)
        ]
        self._variables = vs
        self._names = tuple(names)
        self._hamiltonian = _as_expr(hamiltonian, "hamiltonian")

        if parameters is None:
            parameters = {}
        if isinstance(parameters, Mapping):
            pnames = tuple(str(k) for k in parameters)
            pvals = list(parameters.values())
        else:
            pvals = list(parameters)
            pnames = tuple(f"p{i}" for i in range(len(pvals)))
        self._param_names = pnames
        self._param_values = tuple(to_fraction(v, f"parameters[{k!r}]") for k, v in zip(pnames, pvals))
        self._coarse = {f"parameters[{k!r}]": b for k, b in ((k, carried_bits(v)) for k, v in zip(pnames, pvals))
                        if b is not None}
        for k, b in (input_bits or {}).items():
            if b is not None:
                self._coarse[str(k)] = int(b)
        self._constants_checked = False
        self._native_params = {}
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
        self._key = None

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
        """Exact values of the runtime parameters (Fractions), in ``hy.par`` order."""
        return self._param_values

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
        """The vector field as heyoka's ``[(variable, rhs), ...]``."""
        return list(zip(self._variables, self.vector_field))

    @property
    def key(self) -> str:
        """A structural key: systems with equal keys compile to the same heyoka integrator."""
        if self._key is None:
            self._key = repr((self._names, [str(e) for e in self.vector_field], len(self._param_values)))
        return self._key

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
        other._native_params = {}
        return other

    def native_parameters(self, prec):
        """The parameter values rounded once to the :class:`~lieseries.precision.Precision` ``prec`` (kept per
        precision; read-only), or None when the system has no parameters."""
        if not self._param_values:
            return None
        arr = self._native_params.get(prec.name)
        if arr is None:
            arr = prec.array(self._param_values, "parameters")
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
            for _slot, c in self.program.constants:
                if c.kind == "binary" and c.value[1]:
                    if carried_bits(mp.libmp.to_float(c.value)) is not None:
                        key = f"the constant {mp.nstr(mp.make_mpf(c.value), 8)} in the expressions"
                        self._coarse[key] = 53
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
        exprs = [
            self.tensor[i][j] + self.tensor[j][i] for i in range(n) for j in range(i, n)
        ]
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
