"""Events: functions of the state whose zero crossings a run records (Poincare sections, crossings) or stops at.

``ls.Event(expression, direction=0, terminal=False, name=None)`` where ``expression`` is a heyoka expression in
the system's variables (``hy.make_vars("M2")``), or a callable that builds one from the model
(``lambda body: body.poisson.variables[10]``). Both engines find the same crossings: heyoka's polynomial root
finding on its Taylor steps (``integrate``), and root isolation on each Lie-series step's polynomial followed by
a bracketed solve in mpmath (``lie_integrate``). ``sol.events[name]`` holds the times and states of the
crossings, in the run's precision; a terminal event ends the run with status ``event`` and its name in the
message.
"""

from __future__ import annotations

import heyoka as hy

from .expr import uses_time
from .expr.rewrite import binary_constants
from .precision import warn_if_coarse

__all__ = ["Event", "resolve_events"]

_DIRECTIONS = {0: 0, 1: 1, -1: -1, "any": 0, "positive": 1, "negative": -1, "up": 1, "down": -1}


class Event:
    """A zero crossing of ``expression`` to record (or to stop at, when ``terminal``).

    Parameters
    ----------
    expression : heyoka expression, or callable model -> expression
        A function of the system's variables (and runtime parameters).
    direction : {0, 1, -1} or {"any", "positive", "negative"}
        Crossings in any direction, only upward (the expression goes from negative to positive), or downward.
    terminal : bool
        Stop the run at the first crossing (status ``event``).
    name : str, optional
        Key of the crossings in ``sol.events`` (default ``"event0"``, ``"event1"``, ... by position).
    """

    def __init__(self, expression, direction=0, terminal: bool = False, name: str | None = None):
        if not (isinstance(expression, hy.expression) or callable(expression)):
            raise TypeError(
                "`expression` must be a heyoka expression in the system's variables, or a callable building one "
                f"from the model; got {type(expression).__name__}"
            )
        key = direction.lower() if isinstance(direction, str) else direction
        if isinstance(key, bool) or key not in _DIRECTIONS:
            raise ValueError(f"`direction` must be 0, 1, -1, 'any', 'positive' or 'negative'; got {direction!r}")
        if not isinstance(terminal, bool):
            raise TypeError(f"`terminal` must be True or False; got {terminal!r}")
        if name is not None and (not isinstance(name, str) or not name):
            raise TypeError(f"`name` must be a non-empty string; got {name!r}")
        self.expression = expression
        self.direction = _DIRECTIONS[key]
        self.terminal = terminal
        self.name = name

    def __repr__(self) -> str:
        return (f"Event({self.expression!r}, direction={self.direction}, terminal={self.terminal}, "
                f"name={self.name!r})")

    def __reduce__(self):
        return (Event, (self.expression, self.direction, self.terminal, self.name))


def resolve_events(events, system, ps, work_bits=None) -> list:
    """``[(name, expression, direction, terminal)]`` for a run of ``system`` (the model or PoissonSystem).

    Raises errors naming ``events[i]``: not an Event, an expression using variables the system does not have,
    depending on time, or constant, a duplicated name. For a run at ``work_bits`` bits, a float constant of an
    expression that carries fewer (0.1 in ``q - 0.1``: the crossing is that of the double 0.1) gives one
    :class:`~lieseries.precision.PrecisionWarning`, as in the system's own expressions.
    """
    if events is None:
        return []
    if isinstance(events, Event) or not hasattr(events, "__iter__"):
        events = [events]
    names = set(ps.names)
    out = []
    for i, ev in enumerate(events):
        if not isinstance(ev, Event):
            raise TypeError(f"`events[{i}]` must be an ls.Event; got {type(ev).__name__}")
        expr = ev.expression
        if not isinstance(expr, hy.expression):
            try:
                expr = expr(system)
            except Exception as err:  # a function of the state (lambda y: y[10]) called with the model
                raise TypeError(
                    f"`events[{i}]`: its callable is called once with the model ({type(system).__name__}) to build "
                    f"a heyoka expression, and raised {type(err).__name__}: {err}. An event is not a Python "
                    "function of the state: give a heyoka expression in the system's variables "
                    f"{list(ps.names)[:12]} (e.g. `body.poisson.variables[i]` or `hy.make_vars(name)`), or a "
                    "callable `lambda model: <that expression>`"
                ) from None
            if not isinstance(expr, hy.expression):
                raise TypeError(
                    f"`events[{i}]`: the callable must return a heyoka expression in the system's variables; got "
                    f"{type(expr).__name__} (an event is not a Python function of the state)")
        variables = set(hy.get_variables(expr))
        unknown = sorted(variables - names)
        if unknown:
            raise ValueError(
                f"`events[{i}]` uses variables {unknown} that the system does not have; its variables are "
                f"{list(ps.names)}"
            )
        label = f"`events[{i}]`" + (f" ({ev.name!r})" if ev.name else "")
        if uses_time(expr):
            raise ValueError(
                f"{label} depends on time (heyoka.time): events are functions of the state (both engines find "
                "them the same way); to stop or record at a given time, make it the final time `t` or an output "
                "time"
            )
        if not variables:
            raise ValueError(
                f"{label} is the constant {expr}, which never crosses zero: give an expression in the system's "
                f"variables {list(ps.names)}"
            )
        name = ev.name or f"event{i}"
        if any(name == o[0] for o in out):
            raise ValueError(f"`events[{i}]`: the name {name!r} is used twice")
        if work_bits is not None and work_bits > 53:
            for value in binary_constants(expr):
                warn_if_coarse(53, work_bits, f"the constant {value!r} in events[{i}]")
        out.append((name, expr, ev.direction, ev.terminal))
    return out


