"""What every model shares: its PoissonSystem, state validation, and conversion of states to mpmath."""

from __future__ import annotations

import warnings
from fractions import Fraction

import heyoka as hy

from ..precision import thread_mp as mp
import numpy as np

from ..caller import stacklevel
from ..poisson import PoissonSystem, as_poisson_system
from ..solution import ChartRows, Solution, plain_ufunc
from ..precision import (BinaryFraction, CarriedBits, PrecisionWarning, binary_inputs, bits_to_dps, carried_bits,
                         export_mpf, precision_of_dtype, resolve_precision, state_bits, to_fraction)

__all__ = ["Model", "GenericModel", "as_model", "ExactState", "make_state", "state_fractions", "state_bits"]


class ExactState(np.ndarray):
    """A state built from exact input: reads as a float64 array, runs from its exact values.

    numpy sees the values rounded to double (``np.asarray(y0, float)``, printing, plotting); ``y0.exact`` holds
    the exact values (Fractions), which every integrator uses: a run at any precision starts from the exact data
    rounded once to that precision. The array is read-only, and anything derived from it (a slice, arithmetic, a
    copy) is an ordinary float64 array that carries 53 bits only.
    """

    def __new__(cls, values, binary=None):
        """``values``: the state's numbers (exact input stays exact). ``binary``: ``{argument: bits}`` of the binary
        numbers (floats such as 0.1) the values were computed from (:func:`~lieseries.precision.binary_inputs`);
        by default those among ``values`` themselves. A state built from them carries their precision."""
        if binary is None:
            binary = binary_inputs(list(values) if not isinstance(values, np.ndarray) else values, "y0")
        fr = tuple(to_fraction(v, f"y[{i}]") for i, v in enumerate(values))
        found = [b for b in map(carried_bits, fr) if b is not None]  # already marked (a pickled state)
        bits = min(list(binary.values()) + [int(b) for b in found], default=None)
        if bits is not None:
            sources = [k for k, b in binary.items() if b == bits]
            sources += [s for b in found if b == bits for s in b.sources]
            sources = tuple(dict.fromkeys(sources))
            # every entry is marked: engines that read the exact values see the precision they carry
            fr = tuple(f if isinstance(f, BinaryFraction) else BinaryFraction(f, bits, sources) for f in fr)
            data = CarriedBits(bits, sources)
        else:
            data = None
        floats = []
        for f in fr:
            try:
                floats.append(float(f))
            except OverflowError:
                floats.append(float("inf") if f > 0 else float("-inf"))
        arr = np.array(floats, dtype=np.float64).view(cls)
        arr.exact = fr
        arr.data_bits = data
        arr.flags.writeable = False
        return arr

    def __array_finalize__(self, obj):
        self.exact = None
        self.data_bits = None
        self._native = {}

    @property
    def binary_inputs(self) -> tuple:
        """The arguments (``omega[1]``, ...) holding binary numbers (the double 0.1) the state was built from;
        empty when it was built from exact input. The state is exact for their binary values: a run of more
        than ``data_bits`` bits agrees with the decimals they round only to ``data_bits`` bits."""
        return tuple(getattr(self.data_bits, "sources", ()))

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        return plain_ufunc(ExactState, ufunc, method, inputs, kwargs)

    def __getitem__(self, key):
        out = np.ndarray.__getitem__(self, key)
        return np.asarray(out) if isinstance(out, np.ndarray) else out

    def __reduce__(self):
        return (ExactState, (self.exact, {})) if self.exact is not None else np.asarray(self).__reduce__()

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self

    def at(self, precision):
        """The state rounded once to ``precision`` ('double', 'long double', 'quad' or bits), as a new array."""
        return self.native(resolve_precision(precision)).copy()

    def native(self, prec):
        """The state rounded once to the :class:`~lieseries.precision.Precision` ``prec`` (computed once per
        precision and kept: the state is immutable). Read-only."""
        cache = self.__dict__.setdefault("_native", {})
        arr = cache.get(prec.name)
        if arr is None:
            arr = prec.array(list(self.exact), "y0")
            arr.flags.writeable = False
            cache[prec.name] = arr
        return arr

    def __repr__(self) -> str:
        body = np.array2string(np.asarray(self), separator=", ", prefix="ExactState(")
        return f"ExactState({body})"


def make_state(values, precision=None, inputs=None):
    """A model state from exact values: an :class:`ExactState` (``precision=None``) or an array rounded once to
    ``precision``.

    ``inputs``: ``{argument name: value as the user gave it}`` (``{"omega": omega, "R0": R0}``): binary numbers
    among them (the double 0.1) make the ExactState carry their precision (``data_bits``) and name them
    (``binary_inputs``), as an array of doubles would carry 53 bits; default: the ``values`` themselves."""
    binary = {}
    for name, value in (inputs or {}).items():
        binary.update(binary_inputs(value, name))
    if precision is None:
        return ExactState(values) if inputs is None else ExactState(values, binary)
    prec = resolve_precision(precision)
    if binary and min(binary.values()) < prec.bits:
        # the array will look like prec.bits of data (a quad 0.1 from a double has a long significand)
        low = min(binary.values())
        names = ", ".join(f"`{k}`" for k, b in binary.items() if b == low)
        warnings.warn(
            f"the state is rounded to {prec.name} ({prec.bits} bits) from binary numbers ({names}) that carry only "
            f"{low} bits: it is exact for those binary values (the double 0.1 is 0.1000000000000000055511...), "
            f"and agrees with the decimals you may have meant to about {bits_to_dps(low)} digits only; a run of more "
            "bits cannot tell. Pass them as strings ('0.1') or Fractions.",
            PrecisionWarning,
            stacklevel=stacklevel(),
        )
    return prec.array(values, "state")


def state_fractions(y, n: int, argname: str = "y0") -> list:
    """Validate a state (length ``n``, finite numbers) and return its exact values as Fractions.

    Raises
    ------
    ValueError
        Naming ``argname``: wrong shape, NaN or infinity (with the offending index).
    """
    exact = getattr(y, "exact", None)
    if exact is not None:
        if len(exact) != n:
            raise ValueError(f"`{argname}` must be a 1-d sequence of {n} numbers; got {len(exact)}")
        return list(exact)
    if isinstance(y, (str, bytes)) or np.ndim(y) == 0 and not hasattr(y, "__len__"):
        raise ValueError(f"`{argname}` must be a sequence of {n} numbers; got {type(y).__name__}")
    arr = np.asarray(y, dtype=object) if not isinstance(y, np.ndarray) else y
    if arr.ndim != 1 or arr.shape[0] != n:
        raise ValueError(f"`{argname}` must be a 1-d sequence of {n} numbers; got shape {tuple(np.shape(arr))}")
    out = []
    for i, v in enumerate(arr):
        try:
            out.append(to_fraction(v, f"{argname}[{i}]"))
        except ValueError as err:
            raise ValueError(f"{err}: every entry of `{argname}` must be a finite number") from None
    _warn_mixed_reals(arr, argname)
    return out


def _warn_mixed_reals(arr, argname):
    """One PrecisionWarning when a state mixes heyoka.real numbers of different precisions: a run that takes its
    precision from the state uses the first entry's, and rounds the longer entries to it."""
    precs = [(i, int(v.prec)) for i, v in enumerate(arr) if isinstance(v, hy.real)]
    if len({p for _i, p in precs}) < 2:
        return
    first = precs[0]
    longest = max(precs, key=lambda ip: ip[1])
    if longest[1] > first[1]:
        warnings.warn(
            f"`{argname}[{longest[0]}]` is a {longest[1]}-bit heyoka.real but `{argname}[{first[0]}]` has "
            f"{first[1]} bits: a run that takes its precision from `{argname}` works with {first[1]} bits and "
            f"rounds `{argname}[{longest[0]}]` to them. Give every entry the same precision, or pass `precision=`.",
            PrecisionWarning,
            stacklevel=stacklevel(),
        )


class Model:
    """Base of the built-in models: a PoissonSystem plus state helpers, invariants and input checks.

    Subclasses set ``self.poisson`` and implement :meth:`invariants`; they may override :meth:`check_state`
    (extra physical checks) and :meth:`events` (terminal events the integrator must watch).
    """

    poisson: PoissonSystem

    @property
    def dimension(self) -> int:
        """Length of the state vector."""
        return self.poisson.dimension

    @property
    def names(self) -> tuple:
        """Names of the state variables, in order."""
        return self.poisson.names

    def check_parameters(self, values, argname: str = "params") -> None:
        """Refuse runtime parameter values (exact, in the order of ``poisson.parameter_names``) that describe no
        valid model, naming ``argname`` (subclasses know what their parameters mean)."""

    def check_state(self, y, argname: str = "y0") -> list:
        """Validate a state and return it as exact Fractions (subclasses add physical checks)."""
        return state_fractions(y, self.dimension, argname)

    def events(self):
        """Terminal events: a list of ``(expression, status, message)``; the run stops when an expression is 0."""
        return []

    def invariants(self, y) -> dict:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- how studies, runs and reports treat the model (defaults: the state itself) ------------------------------
    #: The name of the closed form that describes the model's motion (:mod:`lieseries.studies.reference` holds
    #: them by name: "free_rigid_body", "great_circle"); None when there is none (a numerical reference is used).
    closed_form = None
    #: True when the model's runs switch charts (their rows are measured through :meth:`atlas_twin`).
    runs_on_atlas = False

    @property
    def compared_names(self) -> tuple:
        """Names of the quantities runs are compared in (:meth:`compared`)."""
        return tuple(self.names)

    def compared(self, fractions, bits: int, chart=None) -> list:
        """The quantities runs are compared in, from a state's exact values (written in ``chart`` for a model with
        charts): exact Fractions, or mpf computed with ``bits`` bits. The state itself (exactly) by default."""
        return list(fractions)

    def plot_quantity(self) -> tuple:
        """(what the trajectory plot shows, the names of its three curves)."""
        return "state", tuple(self.names[:3])

    def plot_values(self, compared_row) -> list:
        """The three plotted floats from one row of :meth:`compared` values."""
        return [float(v) for v in compared_row[:3]]

    def error_groups(self, n: int) -> list:
        """[(indices, "unit" | "norm")] of the compared quantities: errors relative to 1 or to the group's norm."""
        return [(range(n), "norm")]

    def perturbable(self) -> set:
        """Indices of the state that perturbed ensemble members may change (every entry by default)."""
        return set(range(self.dimension))

    # -- helpers -----------------------------------------------------------------------------------------------
    def _with_charts(self, y, chart):
        """(states, chart) for a helper: a Solution gives its rows (and their charts); atlas rows give theirs."""
        if isinstance(y, Solution):
            chart = y.charts if chart is None else chart
            y = y.y
        if isinstance(y, ChartRows):
            if y.charts is None:
                raise ValueError(
                    "`y` was derived from the rows of an atlas run and no longer knows their charts; pass the rows "
                    "themselves (`sol.y`, `sol.y[i]`), the Solution, or `chart=`"
                )
            chart = y.charts if chart is None else chart
            y = np.asarray(y)
        return y, chart

    def _rows(self, y, argname: str = "y"):
        """(rows of exact Fractions, bits, was_1d) for a state or a 2-d array of states."""
        y, _ = self._with_charts(y, None)
        arr = y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object)
        if arr.ndim == 1:
            return [state_fractions(arr, self.dimension, argname)], state_bits(y), True
        if arr.ndim == 2:
            return [state_fractions(r, self.dimension, f"{argname}[{i}]") for i, r in enumerate(arr)], state_bits(
                y
            ), False
        raise ValueError(f"`{argname}` must be a state (1-d) or one state per row (2-d); got {arr.ndim}-d")

    @staticmethod
    def _out_array(values_rows, bits: int, was_1d: bool, like):
        """Round mpf/Fraction rows to the precision of ``like`` and return an array shaped like the input."""
        arr = like if isinstance(like, np.ndarray) else np.asarray(like, dtype=object)
        prec = precision_of_dtype(arr.dtype)
        if prec is None and arr.dtype != object:
            prec = resolve_precision(bits)
        if prec is None and arr.size and hasattr(arr.ravel()[0], "_mpf_"):  # mpf in, mpf out
            with mp.workprec(bits):
                rows = [np.array([+mp.mpf(v) if hasattr(v, "_mpf_") else _to_mpf(v) for v in r], dtype=object)
                        for r in values_rows]
            return export_mpf(rows[0] if was_1d else np.stack(rows))
        if prec is None:  # plain Python sequences: give float64
            prec = resolve_precision("double")
        rows = [prec.array([_exact(v) for v in r]) for r in values_rows]
        return rows[0] if was_1d else np.stack(rows)


class GenericModel(Model):
    """A bare PoissonSystem seen as a model with the defaults (the state compared and plotted, H and the declared
    Casimirs as invariants, no closed form)."""

    def __init__(self, system: PoissonSystem):
        self.poisson = system

    def invariants(self, y, dps: int = 40) -> dict:
        return self.poisson.invariants(y, dps)


def as_model(system) -> Model:
    """``system`` itself when it is a model, else a :class:`GenericModel` around its PoissonSystem."""
    if isinstance(system, Model):
        return system
    return GenericModel(as_poisson_system(system))


def _to_mpf(v):
    f = to_fraction(v)
    return mp.mpf(f.numerator) / f.denominator


def _exact(v):
    if isinstance(v, Fraction):
        return v
    if hasattr(v, "_mpf_"):
        return to_fraction(v)
    return v

