"""Solution: what every integrator returns (output times, states, statistics, status, dense output)."""

from __future__ import annotations

import types

from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

__all__ = ["Solution", "Stats", "STATUSES", "ChartRows", "plain_ufunc"]

#: Every status a run can end with, and what it means.
STATUSES = {
    "success": "reached the final time",
    "chart_edge": "stopped at the edge of a coordinate chart (a terminal event)",
    "event": "stopped by a terminal event",
    "non_finite": "the state became non-finite (NaN or infinity)",
    "step_collapse": "the step size collapsed: finishing would exceed the step budget",
    "step_budget": "the step budget (max_steps) ran out",
    "time_budget": "the wall-time budget (max_time) ran out",
    "divergent": "the Lie series diverges at the requested step (beyond its radius of convergence)",
    "validation_failed": "a validated run could not prove the next enclosure (where and why in the message)",
    "invariant_drift": "reached the final time, but a conserved quantity drifted: the result is wrong",
}


@dataclass(frozen=True, init=False)
class Stats:
    """Run statistics.

    Attributes
    ----------
    method : str            "taylor (heyoka)" or "lie series (mpmath)"
    precision : str         precision name ("double", "quad", "real237", "50 dps", ...)
    tol : float             the tolerance the run was asked for (an mpf below a float's range: 1e-400 is not 0.0)
    steps : int             number of steps taken
    order : int             Taylor/Lie order (the largest used, for a variable-order run)
    build_time : float      seconds spent compiling the integrator (0 when it came from the cache)
    run_time : float        seconds spent integrating
    cached : bool           the integrator came from the cache
    min_step, max_step : float   smallest and largest step size taken
    error_estimates : tuple per-step error estimates (Lie-series runs)
    extra : dict            engine-specific figures (chart switches, certified widths, ...)

    Immutable: an engine builds it once, when the run is over (``dataclasses.replace`` gives a changed copy).
    """

    method: str
    precision: str
    tol: float
    steps: int = 0
    order: int = 0
    build_time: float = 0.0
    run_time: float = 0.0
    cached: bool = False
    min_step: float = float("nan")
    max_step: float = float("nan")
    error_estimates: tuple = ()
    extra: dict = field(default_factory=dict)

    def __init__(self, method, precision, tol, steps=0, order=0, build_time=0.0, run_time=0.0, cached=False,
                 min_step=float("nan"), max_step=float("nan"), error_estimates=(), extra=None):
        # one dict update instead of a frozen __setattr__ per field: a Stats is built on every run
        self.__dict__.update(
            method=method, precision=precision, tol=tol, steps=steps, order=order, build_time=build_time,
            run_time=run_time, cached=cached, min_step=min_step, max_step=max_step,
            error_estimates=tuple(error_estimates), extra={} if extra is None else extra,
        )

    def as_dict(self) -> dict:
        d = asdict(self)
        d.pop("error_estimates")
        return d


class Solution:
    """The result of :func:`lieseries.integrate` or :func:`lieseries.lie_integrate`.

    Attributes
    ----------
    t : ndarray, shape (k,)
        Output times actually reached (a run that stops early has fewer rows than asked for), in the run's format
        as heyoka held them, or for the Lie and validated engines as mpf rounded once to the rows' digits.
    y : ndarray, shape (k, n)
        The state at each output time, in the run's precision (float64, longdouble, real128 or real).
    stats : Stats
    status : str
        One of :data:`STATUSES`; ``success`` is True only for ``"success"``.
    message : str
        What happened and, when the run stopped early, where and what to do.
    t_reached : Fraction
        The time the integration reached (exact).
    y_reached : ndarray, shape (n,)
        The state at ``t_reached``: for a run that stopped early, the last good state.
    charts : ndarray of int or None
        For a run across an atlas (``atlas=True``): the chart each row of ``y`` is written in.
    """

    def __init__(self, t, y, stats: Stats, status: str, message: str, t_reached, dense: Callable | None = None,
                 t_requested=None, y_reached=None, charts=None, chart_reached=None, events=None):
        if status not in STATUSES:  # pragma: no cover - programming error
            raise ValueError(f"unknown status {status!r}")
        self.__dict__.update(
            t=_read_only(t), y=_read_only(y), stats=stats, status=status, message=message, t_reached=t_reached,
            t_requested=tuple(t_requested) if t_requested is not None else None, y_reached=_read_only(y_reached),
            # for an atlas run: the chart each output row is written in (else None), and the chart of y_reached
            charts=_read_only(charts), chart_reached=chart_reached, _dense=dense,
            # ``{name: {"t": times, "y": states}}`` of the events asked for (``events=``), else None
            events=events,
        )

    @classmethod
    def deferred(cls, head: dict, make, data):
        """A Solution with ``head``'s ``status``, ``message``, ``t_reached`` and ``t_requested`` (a dict made once
        by the caller and only read here) whose other fields (``t``, ``y``, ``stats``, ``y_reached``) ``make(*data)``
        computes, as a dict, the first time one of them is read (or the solution is pickled or copied): what a run
        that is called many times in a loop, and whose every field is not read, costs to return. ``make`` must be a
        module-level function (picklable), ``data`` a tuple the run no longer changes."""
        if head["status"] not in STATUSES:  # pragma: no cover - programming error
            raise ValueError(f"unknown status {head['status']!r}")
        self = object.__new__(cls)
        # charts, chart_reached, events and the dense output are None: the class's own values
        d = self.__dict__
        d.update(head)
        d["_make"] = (make, data)
        return self

    # a deferred solution's fields that no run of its kind has (every other solution sets its own)
    charts = chart_reached = events = _dense = None

    def __getattr__(self, name):
        # only reached for a field not yet in __dict__: a deferred solution computes its fields now
        d = self.__dict__
        pending = d.get("_make")
        if pending is None or name.startswith("__"):
            raise AttributeError(f"'Solution' object has no attribute {name!r}")
        self._fill()
        if name in d:
            return d[name]
        raise AttributeError(f"'Solution' object has no attribute {name!r}")

    def _fill(self) -> None:
        d = self.__dict__
        pending = d.get("_make")
        if pending is not None:
            make, data = pending
            fields = make(*data)
            d.update(t=_read_only(fields["t"]), y=_read_only(fields["y"]), stats=fields["stats"],
                     y_reached=_read_only(fields["y_reached"]), _make=None)

    def __getstate__(self):
        self._fill()
        return {k: v for k, v in self.__dict__.items() if k != "_make"}

    def __setstate__(self, state):
        # numpy unpickles its arrays writable: read-only again
        self.__dict__.update({k: _read_only(v) for k, v in state.items()})

    def __setattr__(self, name, value):
        raise AttributeError(f"a Solution is immutable; `{name}` cannot be set")

    def __delattr__(self, name):
        raise AttributeError(f"a Solution is immutable; `{name}` cannot be deleted")

    @property
    def success(self) -> bool:
        return self.status == "success"

    @property
    def y_final(self):
        """The state at ``t_reached`` (the last good state of a run that stopped early)."""
        return self.y_reached

    def __call__(self, t):
        """Dense output: the state at time(s) ``t`` inside the integrated interval."""
        if self._dense is None:
            raise RuntimeError(
                "this solution has no dense output; run the integrator with `dense=True` to get sol(t)"
            )
        return self._dense(t)

    def __repr__(self) -> str:
        return (
            f"Solution(status={self.status!r}, outputs={len(self.t)}, steps={self.stats.steps}, "
            f"order={self.stats.order}, precision={self.stats.precision!r})"
        )


def plain_ufunc(cls, ufunc, method, inputs, kwargs):
    """Run a numpy ufunc on the plain-array views of ``cls`` instances: arithmetic on a state subclass gives a
    plain array, which carries none of the subclass's metadata (exact values, charts)."""
    inputs = tuple(np.asarray(x) if isinstance(x, cls) else x for x in inputs)
    if "out" in kwargs:
        kwargs["out"] = tuple(np.asarray(o) if isinstance(o, cls) else o for o in kwargs["out"])
    return getattr(ufunc, method)(*inputs, **kwargs)


class ChartRows(np.ndarray):
    """States of runs across an atlas of charts: ``charts`` gives the chart of each state (an int for one state,
    an array of shape ``rows.shape[:-1]`` for rows of states, e.g. (k, m) for an ensemble's ``y``).

    States taken from it (``sol.y[-1]``, ``sol.y[2:5]``, ``ens.y[i]``, ``ens.y[i, j]``) keep their charts, so that
    model helpers such as ``Sphere.velocity`` read them in the right chart; anything else derived from it
    (arithmetic, columns, copies) is a plain array with no chart.
    """

    def __new__(cls, rows, charts):
        arr = np.asarray(rows).view(cls)
        arr.charts = np.asarray(charts, dtype=int) if arr.ndim >= 2 else int(charts)
        if arr.ndim >= 2 and arr.charts.shape != arr.shape[:-1]:
            raise ValueError(f"`charts` must have shape {arr.shape[:-1]} (one chart per state); got "
                             f"{arr.charts.shape}")
        return arr

    def __array_finalize__(self, obj):
        self.charts = None

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        return plain_ufunc(ChartRows, ufunc, method, inputs, kwargs)

    def __getitem__(self, key):
        out = np.ndarray.__getitem__(self, key)
        if not isinstance(out, np.ndarray):
            return out
        if self.ndim >= 2 and self.charts is not None:
            keys = key if isinstance(key, tuple) else (key,)
            if len(keys) <= self.ndim and not any(k is Ellipsis or k is None for k in keys):
                lead, last = keys[:self.ndim - 1], keys[self.ndim - 1:]
                if all(isinstance(c, slice) and c == slice(None) for c in last):  # whole states
                    charts = np.asarray(self.charts)[lead]
                    if np.shape(charts) == out.shape[:-1]:
                        return ChartRows(np.asarray(out), charts)
        return np.asarray(out)

    def __copy__(self):
        return ChartRows(np.asarray(self).copy(), self.charts) if self.charts is not None else np.asarray(self).copy()

    def __reduce__(self):
        return (ChartRows, (np.asarray(self), self.charts))


def _read_only(a):
    if isinstance(a, np.ndarray):
        a.setflags(write=False)
    return a


def _read_only_stats(stats):
    """A read-only view of an ensemble's statistics, their arrays (``steps``) read-only too: through the view,
    ``es.stats["steps"][0] = 99`` changed the result."""
    return types.MappingProxyType({k: _read_only(v) for k, v in dict(stats).items()})


class MemberEvents(tuple):
    """An ensemble's events: one ``{name: {"t": times, "y": states}}`` per member (``events[i]``), a tuple (the
    ensemble is immutable: a list let members be appended or replaced). Indexing it by an event's name says how
    to get at that event."""

    def __getitem__(self, key):
        if isinstance(key, str):
            names = sorted({n for member in self if member for n in member})
            raise KeyError(f"an ensemble's `events` holds one record per member: use `events[i][{key!r}]` for "
                           f"member i (events recorded: {names})")
        return tuple.__getitem__(self, key)


class EnsembleSolution:
    """The result of an ensemble run (:func:`lieseries.integrate` with ``Y0`` of shape (k, n)); immutable, as a
    :class:`Solution` is (its arrays read-only).

    Attributes
    ----------
    t : ndarray, shape (m,)
        The output times asked for (the same for every member), in the run's precision.
    y : ndarray, shape (k, m, n)
        ``y[i, j]`` is member i's state at ``t[j]``; NaN in the rows after a member stopped early.
    status : ndarray of str, shape (k,)
        Each member's status (one of :data:`STATUSES`).
    message : tuple of str
        Each member's message: what happened and, for an early stop, where and what to do.
    t_reached : ndarray of Fraction, shape (k,)
        The time each member reached (exact).
    y_reached : ndarray, shape (k, n)
        The state at ``t_reached`` (for a member that stopped early, its last good state).
    rows : ndarray of int, shape (k,)
        How many output rows each member reached.
    stats : mapping (read-only)
        ``steps`` (array, per member), ``order``, ``build_time``, ``run_time``, ``workers``, ``batch_size``,
        ``path`` ("batch" or "single"), ``single_runs`` (members run one by one), ``precision``, ``tol``.
    events : list of dict or None
        With ``events=``: each member's ``{name: {"t": times, "y": states}}``, as a single run's ``sol.events``.
    charts : ndarray of int, shape (k, m), or None
        For runs across an atlas of charts: the chart each state of ``y`` is written in (``chart_reached``, shape
        (k,): the chart of ``y_reached``). ``y`` and ``y_reached`` then carry their charts
        (:class:`ChartRows`), as do ``member(i)`` and the states taken from them.
    """

    def __init__(self, t, y, status, message, t_reached, y_reached, stats: dict, rows=None,
                 method: str = "taylor (heyoka)", events=None, charts=None, chart_reached=None):
        charts = None if charts is None else np.asarray(charts, dtype=int)
        chart_reached = None if chart_reached is None else np.asarray(chart_reached, dtype=int)
        if charts is not None:
            y, y_reached = ChartRows(y, charts), ChartRows(y_reached, chart_reached)
        status = np.asarray(status, dtype=object)
        for s in status:
            if s not in STATUSES:  # pragma: no cover - programming error
                raise ValueError(f"unknown status {s!r}")
        rows = np.full(len(status), len(t), dtype=np.int64) if rows is None else np.asarray(rows)
        # immutable, as a Solution is: read-only arrays, a tuple of messages, a read-only view of the statistics
        self.__dict__.update(
            t=_read_only(t), y=_read_only(y), status=_read_only(status), message=tuple(message),
            t_reached=_read_only(np.asarray(t_reached, dtype=object)), y_reached=_read_only(y_reached),
            stats=_read_only_stats(stats), method=method, rows=_read_only(rows),
            events=None if events is None else MemberEvents(events), charts=_read_only(charts),
            chart_reached=_read_only(chart_reached))

    def __getstate__(self):
        return {**self.__dict__, "stats": dict(self.stats)}

    def __setstate__(self, state):
        # numpy unpickles its arrays writable: read-only again
        state = {k: _read_only(v) for k, v in state.items()}
        self.__dict__.update(state, stats=_read_only_stats(state["stats"]))

    def __setattr__(self, name, value):
        raise AttributeError(f"an EnsembleSolution is immutable; `{name}` cannot be set")

    def __delattr__(self, name):
        raise AttributeError(f"an EnsembleSolution is immutable; `{name}` cannot be deleted")

    def __len__(self) -> int:
        return len(self.status)

    @property
    def success(self) -> bool:
        """True when every member reached the final time."""
        return bool(all(s == "success" for s in self.status))

    @property
    def succeeded(self) -> np.ndarray:
        """Boolean mask of the members that reached the final time."""
        return np.array([s == "success" for s in self.status], dtype=bool)

    def member(self, i: int) -> Solution:
        """Member ``i`` as a :class:`Solution` (its output rows up to where it stopped)."""
        k = len(self.status)
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not -k <= i < k:
            raise IndexError(f"`i` must be an integer member index in [0, {k}); got {i!r}")
        i = int(i) % k
        m = int(self.rows[i])
        steps = self.stats.get("steps")
        st = Stats(method=self.method, precision=str(self.stats.get("precision", "")),
                   tol=float(self.stats.get("tol", float("nan"))),
                   steps=int(steps[i]) if steps is not None else 0, order=int(self.stats.get("order", 0)),
                   extra={"ensemble": True})
        charted = self.charts is not None
        return Solution(self.t[:m], self.y[i, :m], st, str(self.status[i]), self.message[i], self.t_reached[i],
                        y_reached=self.y_reached[i], events=None if self.events is None else self.events[i],
                        charts=self.charts[i, :m].copy() if charted else None,
                        chart_reached=int(self.chart_reached[i]) if charted else None)

    @classmethod
    def concatenate(cls, parts, **stats):
        """One ensemble from consecutive chunks run with the same times and options; ``stats`` set or replace
        entries of its statistics (a cluster's ``run_time``, ``workers``, ...)."""
        parts = list(parts)
        if not parts:
            raise ValueError("`parts` must hold at least one EnsembleSolution")
        first, extra = parts[0], stats
        for i, p in enumerate(parts):
            if not isinstance(p, cls):
                raise TypeError(f"`parts[{i}]` must be an EnsembleSolution; got {type(p).__name__}")
            # chunks of other times or options joined silently: rows labelled with the first part's times
            differs = next((what for what, same in (
                ("output times `t`", p.t.dtype == first.t.dtype and p.t.shape == first.t.shape
                 and bool(np.all(p.t == first.t))),
                ("state size", p.y.shape[1:] == first.y.shape[1:]),
                ("method", p.method == first.method),
                ("precision", p.stats.get("precision") == first.stats.get("precision")),
                ("tolerance", p.stats.get("tol") == first.stats.get("tol")),
                ("events (recorded in one, not in the other)", (p.events is None) == (first.events is None)),
                ("charts (an atlas run and a run in one chart)", (p.charts is None) == (first.charts is None)),
            ) if not same), None)
            if differs is not None:
                raise ValueError(f"`parts[{i}]` differs from `parts[0]` in its {differs}: concatenate joins the "
                                 "chunks of one ensemble run (the same system, times and options)")
        stats = dict(first.stats)
        stats["steps"] = np.concatenate([p.stats["steps"] for p in parts])
        stats["build_time"] = max(p.stats.get("build_time", 0.0) for p in parts)
        stats["run_time"] = sum(p.stats.get("run_time", 0.0) for p in parts)
        stats["single_runs"] = sum(p.stats.get("single_runs", 0) for p in parts)
        stats["order"] = max(p.stats.get("order", 0) for p in parts)
        stats.update(extra)
        return cls(first.t, np.concatenate([p.y for p in parts]),
                   np.concatenate([p.status for p in parts]), [m for p in parts for m in p.message],
                   np.concatenate([p.t_reached for p in parts]), np.concatenate([p.y_reached for p in parts]),
                   stats, rows=np.concatenate([p.rows for p in parts]), method=first.method,
                   events=None if first.events is None else [e for p in parts for e in p.events],
                   charts=None if first.charts is None else np.concatenate([p.charts for p in parts]),
                   chart_reached=None if first.charts is None else np.concatenate([p.chart_reached for p in parts]))

    def __repr__(self) -> str:
        counts = {}
        for s in self.status:
            counts[s] = counts.get(s, 0) + 1
        return (f"EnsembleSolution(members={len(self.status)}, outputs={len(self.t)}, status={counts}, "
                f"precision={self.stats.get('precision')!r})")
