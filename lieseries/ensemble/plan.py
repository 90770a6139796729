"""An ensemble's inputs, checked once: the structure and its members, the initial states rounded once to the
working precision, per-member parameters (on each member's own constraint surface), the options; and the plan
the paths run from (:class:`EnsemblePlan`)."""

from __future__ import annotations

import copy
import numbers
import re

import numpy as np

from ..atlas import check_atlas_events
from ..events import resolve_events
from ..expr import expressions_digest
from ..models.base import Model, state_fractions
from ..poisson import PoissonSystem, as_poisson_system
from ..precision import (Precision, check_flag, check_tolerance, data_bits, infer_precision, to_fraction,
                         warn_if_coarse)
from ..timegrid import parse_times, span_loss, warn_span_loss
from .build import check_batch_size

__all__ = ["EnsemblePlan", "plan_ensemble", "check_count", "member_system", "is_constrained"]


def check_count(value, argname):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ValueError(f"`{argname}` must be a positive integer; got {value!r}")
    return int(value)


def split_structure(system):
    """(structure system, list of per-member systems or None) from a model/PoissonSystem or a list of them."""
    if isinstance(system, (list, tuple)):
        if not system:
            raise ValueError("`system` as a list must hold at least one model")
        pss = [as_poisson_system(s, f"system[{i}]") for i, s in enumerate(system)]
        key = pss[0].key
        for i, p in enumerate(pss):
            if p.key != key and not _same_field(p, pss[0]):
                raise ValueError(
                    f"`system[{i}]` has another structure than `system[0]` ({p.name} vs {pss[0].name}): every "
                    "member of an ensemble must be the same model with other parameter values (e.g. inertia)"
                )
            if type(system[i]) is not type(system[0]):
                raise ValueError(f"`system[{i}]` is a {type(system[i]).__name__}, `system[0]` a "
                                 f"{type(system[0]).__name__}: pass models of one kind")
        ev0 = expressions_digest([e[0] for e in system[0].events()]) if isinstance(system[0], Model) else None
        for i, s in enumerate(system):
            evi = expressions_digest([e[0] for e in s.events()]) if isinstance(s, Model) else None
            if evi != ev0:
                raise ValueError(f"`system[{i}]` watches other events than `system[0]`; pass models of one kind")
        return system[0], list(system)
    as_poisson_system(system)
    return system, None


def _same_field(a, b) -> bool:
    """Whether two systems whose keys differ have the same field all the same: the key is a digest of the field as
    built, and an equal field written with other sharing of its subexpressions (``q2 * q2`` with ``q2 = q * q``
    beside ``(q * q) * (q * q)``) gets another one."""
    return (a.dimension == b.dimension and len(a.parameter_values) == len(b.parameter_values)
            and [str(v) for v in a.variables] == [str(v) for v in b.variables]
            and all(x == y for x, y in zip(a.vector_field, b.vector_field)))


def member_states(model, ps, Y0, prec: Precision, foreign=frozenset()):
    """Y0 checked and rounded once to the working precision: a native array (k, n). Rows in ``foreign`` (members
    with parameters of their own) get the plain check here and their constraints in check_member_constraints."""
    n = ps.dimension
    if isinstance(Y0, np.ndarray) and Y0.dtype != object:
        arr = Y0
    else:
        if isinstance(Y0, (list, tuple)) and Y0:
            # ragged rows: name the first whose length differs from the first row's
            lens = [len(r) if hasattr(r, "__len__") and not isinstance(r, (str, bytes)) else None for r in Y0]
            for i, ln in enumerate(lens):
                if ln != lens[0]:
                    what = f"has {ln} numbers" if ln is not None else "is not a row of numbers"
                    raise ValueError(f"`Y0[{i}]` {what}, `Y0[0]` has {lens[0]}: every row of `Y0` must be one initial state of {n} numbers "
                                     f"(shape (k, {n}))")
        if isinstance(Y0, (str, bytes)) or np.ndim(Y0) == 0:
            raise ValueError(f"`Y0` must have shape (k, {n}): one initial state per row; got {type(Y0).__name__}")
        try:
            arr = np.asarray(Y0, dtype=object)
        except ValueError:
            raise ValueError(f"`Y0` must have shape (k, {n}): rows of equal length {n}") from None
    if arr.ndim == 1 and arr.shape[0] == n:
        raise ValueError(f"`Y0` is one state of {n} numbers, but an ensemble (asked for by `params`, `workers`, "
                         "`client` or a list of models) needs one initial state per member, shape (k, n): repeat "
                         "the state, e.g. `[y0] * k`, or drop those arguments for a single run")
    if arr.ndim != 2 or arr.shape[1] != n or arr.shape[0] < 1:
        raise ValueError(f"`Y0` must have shape (k, {n}) with k >= 1: one initial state of {n} numbers per row; "
                         f"got shape {arr.shape}")
    plain_check = model is None or type(model).check_state is Model.check_state or hasattr(model, "check_rows")
    if plain_check and arr.dtype in (np.float64, np.longdouble) and prec.name in ("double", "long double"):
        bad = ~np.isfinite(arr)
        if bad.any():
            i, j = map(int, np.argwhere(bad)[0])
            raise ValueError(f"`Y0[{i}][{j}]` must be finite; got {arr[i, j]}: every entry of `Y0` must be a "
                             "finite number")
        if model is not None and hasattr(model, "check_rows"):
            model.check_rows(arr, "Y0")  # the model's warnings, at numpy speed
        return arr.astype(prec.numpy_dtype)  # exact (widening) or rounded once (long double -> double)
    rows = []
    for i in range(arr.shape[0]):
        if model is not None and i not in foreign:
            rows.append(model.check_state(arr[i], f"Y0[{i}]"))
        else:
            rows.append(state_fractions(arr[i], n, f"Y0[{i}]"))
    return np.stack([prec.array(r) for r in rows])


def exact_rows(Y0):
    """A list of states that carry their exact values (``state.exact``) as rows of those exact values."""
    if isinstance(Y0, (list, tuple)) and Y0 and all(getattr(r, "exact", None) is not None for r in Y0):
        return [list(r.exact) for r in Y0]
    return Y0


def warn_coarse(prec: Precision, inputs, systems) -> None:
    """One :class:`~lieseries.precision.PrecisionWarning` per input (``(name, values)``: Y0, params, t, t0) or
    model parameter that carries fewer bits than the run (binary doubles in a run of more bits), as a single run
    gives."""
    narrow = any(isinstance(v, np.ndarray) and v.dtype in (np.float16, np.float32)
                 for _, v in inputs)  # float32 / float16 data carry fewer bits than even a double run
    if prec.bits <= 53 and not narrow:
        return
    for name, values in inputs:
        if values is not None:
            # a numeric array keeps its dtype (a float32 0.1 carries 24 bits, the double it widens to looks exact)
            arr = values if isinstance(values, np.ndarray) and values.dtype != object else np.asarray(values,
                                                                                                     dtype=object)
            warn_if_coarse(data_bits(arr), prec.bits, name)
    seen = set()
    for s in systems:
        for name, bits in as_poisson_system(s).coarse_data().items():
            if name not in seen and bits is not None and bits < prec.bits:
                seen.add(name)
                warn_if_coarse(bits, prec.bits, name)


def member_parameters(model, ps, params, members, k):
    """Per-member parameter values (exact Fractions, (k, npar)) or None when every member uses the system's own."""
    npar = len(ps.parameter_values)
    if members is not None:
        if len(members) != k:
            raise ValueError(f"`system` as a list must give one model per row of `Y0` ({k}); got {len(members)}")
        if params is not None:
            raise ValueError("pass either `params` or a list of models as `system`, not both")
        return [list(as_poisson_system(m).parameter_values) for m in members]
    if params is None:
        return None
    arr = params if isinstance(params, np.ndarray) else np.asarray(params, dtype=object)
    if arr.ndim != 2 or arr.shape != (k, npar):
        raise ValueError(
            f"`params` must have shape (k, npar) = ({k}, {npar}): one row per member with the values of "
            f"{list(ps.parameter_names)} in that order; got shape {arr.shape}"
        )
    # rows that repeat (a few parameter sets over many members) are converted and checked once: the same values,
    # the same exact Fractions, the same verdict
    done = {}
    rows = []
    for i in range(k):
        key = tuple(arr[i].tolist()) if arr.dtype.kind == "f" else None
        row = done.get(key) if key is not None else None
        if row is None:
            row = [to_fraction(arr[i, j], f"params[{i}][{j}]") for j in range(npar)]
            if model is not None:
                model.check_parameters(row, f"params[{i}]")
            if key is not None:
                done[key] = row
        rows.append(row)
    return rows


def check_member_constraints(ps, Y0, Ynat, pars, prec, from_models):
    """Refuse a row that is off the constraint surface of its own member: a pendulum's state given for one length
    and run with another (``params``, or a list of models) keeps G = |x|^2 - l^2 != 0 as a Casimir, and its run
    would succeed on a motion that is no pendulum's. The constraint Casimirs (``G1..``, ``Phi1..``) are evaluated
    with the member's parameters, relative to 1 + |y|^2, and refused above the square root of the precision."""
    if pars is None or not is_constrained(ps):
        return
    exact = isinstance(Y0, list) and all(isinstance(r, list) for r in Y0)
    tol = 2.0 ** -max(1, (prec.bits - 4) // 2)
    for i, values in enumerate(pars):
        if tuple(values) == tuple(ps.parameter_values):
            continue
        row = Y0[i] if exact else Ynat[i]
        inv = ps.with_parameters(values).invariants(row)
        scale = 1 + sum(float(v) ** 2 for v in (row if exact else np.asarray(row, dtype=float)))
        for name, value in inv.items():
            if _CONSTRAINT_NAME.match(name) and abs(float(value)) > tol * scale:
                source = f"the model `system[{i}]`" if from_models else f"`params[{i}]`"
                raise ValueError(
                    f"`Y0[{i}]` is off the constraint surface of its member: with the parameters of {source} "
                    f"({dict(zip(ps.parameter_names, (float(v) for v in values)))}), {name} = {float(value):.3g} "
                    "at it instead of 0 (the state was made for other parameters). Build each member's state with "
                    "its own parameters (a model with those parameters, then `initial_state`)")


_CONSTRAINT_NAME = re.compile(r"^(G|Phi)\d+$")


def is_constrained(ps) -> bool:
    """Whether the system's Casimirs include constraints G1.., Phi1.. (a model derived from constraints)."""
    return any(_CONSTRAINT_NAME.match(name) for name in ps.casimirs)


def member_system(system, ps, values):
    """The system with the parameter values of one member (the system itself when they are its own)."""
    if values is None or tuple(values) == tuple(ps.parameter_values):
        return system
    # same structure, other runtime parameter values: no recompilation
    ps2 = ps.with_parameters(values)
    if isinstance(system, PoissonSystem):
        return ps2
    model = copy.copy(system)
    model.poisson = ps2
    model.__dict__.pop("_charts", None)
    return model




class EnsemblePlan:
    """What every path of an ensemble runs from: the checked inputs and options (attributes named as the
    arguments of :func:`~lieseries.ensemble.integrate_ensemble`), the structure system ``structure`` (and
    ``run_system``, its chart with the atlas's switching edge when ``atlas``), ``members`` (a list of models, or
    None), ``Ynat`` (k, n) in the working precision ``prec``, ``pars`` (per-member parameters or None), the output
    grid (exact: ``grid``; as heyoka's clock rounds it: ``tgrid``, ``t0n``), ``tolf``, ``B`` (lanes per batch)
    and ``opts`` (the keyword arguments of a member's single run)."""

    def __init__(self, **kw):
        self.__dict__.update(kw)


def plan_ensemble(system, Y0, t, *, tol, precision, t0, params, workers, client, max_steps, max_time, chunk_size,
                  batch_size, progress, min_step, compact_mode, high_accuracy, dense, atlas,
                  events) -> EnsemblePlan:
    """Check every input (errors name the argument) and round the initial states once: the plan of the run."""
    structure, members = split_structure(system)
    ps = as_poisson_system(structure)
    model = structure if isinstance(structure, Model) else None
    Y0 = exact_rows(Y0)
    prec = infer_precision(precision, Y0, "y0")
    # the output: k members x n values per time (hy.real: an object of ~48 bytes plus its limbs)
    members_k = len(Y0) if hasattr(Y0, "__len__") else 1
    grid, direction, t0f = parse_times(t, t0, values_per_time=max(1, members_k) * ps.dimension,
                                       bytes_per_value=48 + prec.bits // 8 if prec.is_real
                                       else np.dtype(prec.numpy_dtype).itemsize,
                                       max_time=max_time)
    tolf = check_tolerance(tol, prec)
    workers = check_count(workers, "workers")
    chunk_size = check_count(chunk_size, "chunk_size")
    check_flag(compact_mode, "compact_mode")
    check_flag(high_accuracy, "high_accuracy", allow_none=False)
    B = check_batch_size(batch_size)
    if max_steps is not None:
        check_count(max_steps, "max_steps")
    if max_time is not None and not (isinstance(max_time, numbers.Real) and max_time > 0):
        raise ValueError(f"`max_time` must be a positive number of seconds; got {max_time!r}")
    if progress is not None and not callable(progress):
        raise TypeError(f"`progress` must be a callable progress(fraction_done); got {type(progress).__name__}")
    if dense:
        raise ValueError("`dense=True` is not available for an ensemble (`Y0` of shape (k, n)); run the members you "
                         "need it for one by one with lieseries.integrate")
    if atlas is None:
        atlas = bool(getattr(structure, "atlas", False))  # as a single run: a model may switch charts by default
    atlas = bool(atlas)
    if atlas and not (hasattr(structure, "for_chart") and hasattr(structure, "ATLAS_SWITCH")):
        raise ValueError(f"`atlas` needs a model with an atlas of charts (Sphere); {type(structure).__name__} has "
                         "one global chart")
    if events is not None:
        resolve_events(events, structure, ps, prec.bits)  # refuse a bad event here, before any member runs
        if atlas:
            check_atlas_events(structure, events)
    if min_step is not None and not (isinstance(min_step, numbers.Real) and min_step > 0):
        raise ValueError(f"`min_step` must be positive; got {min_step!r}")
    # rows of members with parameters of their own are checked against their own constraint surface, not the
    # model's (a pendulum's state for another length is no state of this one)
    foreign = set()
    if (params is not None or members is not None) and hasattr(Y0, "__len__") and len(Y0) and is_constrained(ps):
        own = tuple(ps.parameter_values)
        foreign = {i for i, v in enumerate(member_parameters(model, ps, params, members, len(Y0))) if tuple(v) != own}
    Ynat = member_states(model, ps, Y0, prec, foreign)
    k = Ynat.shape[0]
    pars = member_parameters(model, ps, params, members, k)
    # each member's parameters rounded to the run's format: an overflow names its entry (an array of doubles, finite
    # as read, fits every format)
    if params is not None and not (isinstance(params, np.ndarray) and params.dtype in (np.float64, np.float32)):
        for i, row in enumerate(pars):
            for j, v in enumerate(row):
                prec.to_native(v, f"params[{i}][{j}]")
    check_member_constraints(ps, Y0, Ynat, pars, prec, members is not None)
    warn_coarse(prec, [("Y0", Y0), ("params", params), ("t", t), ("t0", t0)], members or [structure])

    opts = dict(tol=tol, precision=prec, t0=t0, max_steps=max_steps, max_time=max_time, atlas=atlas)
    if events is not None:
        opts["events"] = events
    for name, value in (("min_step", min_step), ("compact_mode", compact_mode)):
        if value is not None:
            opts[name] = value
    if high_accuracy:
        opts["high_accuracy"] = True
    # With an atlas, the batch runs the model with the atlas's switching edge as its terminal event: a member that
    # starts in the model's chart and never reaches that edge is exactly the atlas run's first (and only) segment;
    # the others run as single runs across the atlas.
    run_system = structure.for_chart(structure.chart, edge=structure.ATLAS_SWITCH) if atlas else structure
    tgrid, t0n = [to_fraction(prec.time(g)) for g in grid], to_fraction(prec.time(t0f))
    warn_span_loss(span_loss(grid, t0f, tgrid, t0n), grid, t0f, prec.bits,
                   f"the run's times are {prec.name} numbers")
    return EnsemblePlan(
        structure=structure, members=members, ps=ps, ps_run=as_poisson_system(run_system), run_system=run_system,
        Y0=Y0, Ynat=Ynat, k=k, pars=pars, params=params, prec=prec, t=t, t0=t0, tol=tol, tolf=tolf, grid=grid,
        direction=direction, t0f=t0f,
        # heyoka's clock runs in the working precision: output times as rounded there (as in a single run)
        tgrid=tgrid, t0n=t0n,
        workers=workers, chunk_size=chunk_size, batch_size=batch_size, B=B, max_steps=max_steps,
        max_time=max_time, min_step=min_step, compact_mode=compact_mode, high_accuracy=high_accuracy, atlas=atlas,
        events=events, progress=progress, opts=opts)
