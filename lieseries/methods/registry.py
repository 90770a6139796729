"""The registry of methods: :class:`Method`, the one run record :class:`RunRecord`, and what runs a method from its
specification (:func:`run_method`, :func:`run_atlas_method`)."""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Callable

from .. import fields as F
from ..precision import Precision, to_fraction

__all__ = [
    "LIST_KEYS",
    "METHODS",
    "REPEAT_BUDGET",
    "Method",
    "MethodRun",
    "RunRecord",
    "best_of",
    "default_methods",
    "expand_methods",
    "method_label",
    "method_plugin",
    "methods_registry",
    "normalize_method",
    "precision_name",
    "reference_bits",
    "reference_dps",
    "register_method",
    "run_precision",
    "run_atlas_method",
    "run_method",
    "scene_methods",
    "setting",
    "setting_number",
    "thin",
    "unregister_method",
]

#: Keys that may be lists in :func:`work_precision` (one run per value).
LIST_KEYS = ("precision", "tol", "rtol", "dps")

#: Repeats of a run stop once it has used this many seconds in total.
REPEAT_BUDGET = 2.0


@dataclass
class RunRecord:
    """One run of one method with one setting, and what it is measured to be (the one run record).

    Attributes
    ----------
    method : str                 "taylor", "lie", "scipy", "mpmath", "validated" (a registered method's name)
    label : str                  e.g. "heyoka double", "scipy DOP853"
    precision : Precision        its working precision (:class:`~lieseries.precision.Precision`: name, bits, dps, eps
                                 and guard); None when the specification's precision is itself refused
    setting : str                e.g. "tol=1e-12", "rtol=1e-10", "dps=30"
    t : float                    the time the run reached
    t_requested : float          the final time asked for (mpmath runs are capped)
    t_exact : Fraction           ``t`` exactly
    times : list of float        output times reached
    states : list                the state at each output time, in the run's own number type
    steps, nfev, order : int or None
    build_time : float or None   compile time (heyoka integrator, or the scipy right-hand side)
    run_time : float             wall time of the call without the build, best of the repeats
    core_time : float or None    heyoka's own propagation time (Taylor runs)
    status : str                 "success", a heyoka/Lie status, "failed", "skipped" or "error"
    message : str
    extra : dict                 method-specific figures (validated runs: certified digits, widest radius)

    Measured (filled in by :meth:`measured`, which keeps only the final state):

    model : str                  the model's label in a scene ("" elsewhere)
    error : float or None        max-abs error of the final state against the reference
    max_error : float or None    the largest over the output times (a scene's trajectory)
    scaled_error : float or None the final error relative to the natural scale of each quantity
    drift : dict                 invariant -> max |I(t) - I(0)| over the output times
    final_state : list or None   the final state as floats
    """

    method: str
    label: str
    precision: Precision | None
    setting: str
    t: float
    t_requested: float
    t_exact: Fraction | None = None
    times: list = field(default_factory=list)
    states: list = field(default_factory=list)
    steps: int | None = None
    nfev: int | None = None
    order: int | None = None
    build_time: float | None = None
    run_time: float | None = None
    core_time: float | None = None
    status: str = "success"
    message: str = ""
    extra: dict = field(default_factory=dict)
    model: str = ""
    error: float | None = None
    max_error: float | None = None
    scaled_error: float | None = None
    drift: dict = field(default_factory=dict)
    final_state: list | None = None

    @property
    def y_final(self):
        return self.states[-1] if self.states else None

    @property
    def ok(self) -> bool:
        return bool(self.states)

    @property
    def max_drift(self) -> float | None:
        vals = [v for v in self.drift.values() if v is not None]
        return max(vals) if vals else None

    def measured(self, **figures) -> "RunRecord":
        """A copy with the measured ``figures`` (error, drift, ...) set, the final state as floats, and only the
        final state kept of the run's states."""
        from dataclasses import replace

        final = self.y_final
        out = replace(self, times=self.times[-1:], states=self.states[-1:], **figures)
        if "final_state" not in figures:
            out.final_state = [float(to_fraction(v)) for v in final] if final is not None else None
        return out

    def to_dict(self) -> dict:
        return {
            "model": self.model, "method": self.method, "label": self.label,
            "precision": None if self.precision is None else str(self.precision),
            "setting": self.setting, "t": self.t, "t_requested": self.t_requested, "error": self.error,
            "max_error": self.max_error, "drift": dict(self.drift), "max_drift": self.max_drift, "steps": self.steps,
            "nfev": self.nfev, "order": self.order, "build_time": self.build_time, "run_time": self.run_time,
            "status": self.status, "message": self.message, "scaled_error": self.scaled_error,
            "extra": dict(self.extra),
        }


#: The earlier names of the run record.
MethodRun = RunRecord


def setting_number(v) -> str:
    """A setting's number in a label: "default" for None, ints as they are, others with 3 digits."""
    if v is None:
        return "default"
    if isinstance(v, str):
        return v
    if isinstance(v, int):
        return str(v)
    try:
        return f"{float(v):.3g}"
    except (TypeError, ValueError, OverflowError):  # not a number: the run refuses it, naming the setting
        return repr(v)


def normalize_method(spec, where: str = "method") -> dict:
    """Check a method specification and fill in its defaults.

    Raises
    ------
    ValueError
        Naming ``where`` and the offending key.
    """
    if not isinstance(spec, dict):
        raise ValueError(f"`{where}` must be a table such as {{method = \"taylor\", precision = \"double\"}}; "
                         f"got {spec!r}")
    name = spec.get("method")
    if name not in _METHODS:
        raise ValueError(f"`{where}.method` must be one of {sorted(_METHODS)}; got {name!r}")
    defaults = _METHODS[name].defaults
    known = set(defaults) | {"method", "label"}
    for k in spec:
        if k not in known:
            raise ValueError(f"unknown field `{where}.{k}` for method {name!r}; known: {sorted(known)}")
    out = dict(defaults)
    out.update(spec)
    return out


def expand_methods(methods, where: str = "methods") -> list:
    """Normalised specifications, one per setting (list-valued keys expanded)."""
    if isinstance(methods, dict) or not hasattr(methods, "__iter__"):
        raise ValueError(f"`{where}` must be a list of method tables; got {methods!r}")
    out = []
    for i, spec in enumerate(methods):
        s = normalize_method(spec, f"{where}[{i}]")
        out.extend(_settings(s, _METHODS[s["method"]].list_keys))
    return out


def method_label(spec: dict) -> str:
    """A short label for a method: "heyoka double", "Lie series 30 dps", "scipy DOP853", "mpmath odefun 15 dps"."""
    if spec.get("label"):
        return str(spec["label"])
    return _METHODS[spec["method"]].label(spec)


def default_methods(quick: bool = False) -> list:
    """A default set of methods and settings for :func:`work_precision`."""
    if quick:
        return [
            {"method": "taylor", "precision": "double", "tol": [1e-6, 1e-10, 1e-14]},
            {"method": "taylor", "precision": "quad", "tol": [1e-16, 1e-28]},
            {"method": "scipy", "rtol": [1e-6, 1e-10]},
            {"method": "lie", "dps": 30, "tol": [1e-20]},
        ]
    return [
        {"method": "taylor", "precision": "double", "tol": [1e-6, 1e-8, 1e-10, 1e-12, 1e-14, 2.0**-52]},
        {"method": "taylor", "precision": "long double", "tol": [1e-10, 1e-14, 1e-18]},
        {"method": "taylor", "precision": "quad", "tol": [1e-12, 1e-18, 1e-24, 1e-30, 2.0**-112]},
        {"method": "scipy", "rtol": [1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 1e-13]},
        {"method": "lie", "dps": 30, "tol": [1e-10, 1e-20, 1e-28]},
        {"method": "mpmath", "dps": [15, 25], "t_max": 1.0},
    ]


# -- running one method ----------------------------------------------------------------------------------------
def best_of(call, repeat: int):
    """Run ``call()`` up to ``repeat`` times (stopping once REPEAT_BUDGET seconds are used); the first result
    and the per-call wall times."""
    times, first = [], None
    spent = 0.0
    for i in range(max(1, int(repeat))):
        t0 = _time.perf_counter()
        res = call()
        dt = _time.perf_counter() - t0
        times.append(dt)
        if i == 0:
            first = res
        spent += dt
        if spent > REPEAT_BUDGET:
            break
    return first, times


def _grid(t, times):
    tf = to_fraction(t, "t")
    if times is None:
        return tf, None
    grid = [to_fraction(v, "times") for v in times]
    return tf, grid


def run_method(system, y0, t, spec: dict, *, times=None, repeat: int = 1) -> RunRecord:
    """Run one method (a normalised specification, see :func:`normalize_method`) from ``y0`` to ``t``.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Initial state; its exact value is rounded once to each method's precision.
    t : number
        Final time.
    spec : dict
        One method with scalar settings.
    times : sequence of numbers, optional
        Output times (increasing, ending at ``t``); default: only ``t``.
    repeat : int
        Best-of repeats for the timing.

    Returns
    -------
    RunRecord
        With ``status = "error"`` (and the exception text) when the method raised, ``"skipped"`` when it is not
        available.
    """
    spec = normalize_method(spec)
    m = spec["method"]
    tf, grid = _grid(t, times)
    try:
        label = method_label(spec)
    except (TypeError, ValueError):  # a setting the run refuses below, naming it
        label = m
    try:
        return _METHODS[m].run(system, y0, tf, grid, spec, label, repeat)
    except Exception as err:  # a failing method is a row of the study, not the end of it
        return RunRecord(m, label, run_precision(spec), setting(spec), float(tf), float(tf), status="error",
                         message=f"{type(err).__name__}: {err}")


def run_precision(spec) -> Precision | None:
    """A method's working :class:`~lieseries.precision.Precision` (None when the specification's precision is
    refused: the run says why)."""
    try:
        return _METHODS[spec["method"]].precision(spec)
    except (TypeError, ValueError):
        return None


def precision_name(spec) -> str:
    """The name of a method's working precision ("double", "quad", "30 dps", ...)."""
    p = run_precision(spec)
    return str(p) if p is not None else "?"


def setting(spec) -> str:
    """A method's settings in one line ("tol=1e-12", "dps=30, order=20")."""
    return _METHODS[spec["method"]].setting(spec)


# -- the study ------------------------------------------------------------------------------------------------
def _digits_needed(spec) -> int:
    return _METHODS[spec["method"]].digits(spec)


def reference_dps(specs) -> int:
    """Digits for a reference that resolves the errors of every run in ``specs``."""
    return max([30] + [_digits_needed(s) + 12 for s in specs])


def reference_bits(specs, floor: int = 256) -> int:
    """Bits for references and conversions that stay far above every method of ``specs`` (scalar settings): at
    least ``floor``, and 64 above each method's own."""
    bits = floor
    for s in specs:
        b = method_plugin(s["method"]).bits(s)
        if b is not None:
            bits = max(bits, b + 64)
    return bits




# -- the registry ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Method:
    """An integration method as a plug-in.

    Attributes
    ----------
    name : str                   the ``method`` of a specification
    fields : dict                its scene fields ``{key: (checker, default)}`` (:mod:`lieseries.fields`); the
                                 defaults are the specification's
    docs : dict                  ``{key: (type, meaning)}`` for docs/scenes.md
    label, setting : spec -> str
    precision : spec -> Precision  the run's working precision (:meth:`Precision.of`), guard included
    digits : spec -> int         decimal digits a reference must carry to resolve the method's errors
    run : (system, y0, tf, grid, spec, label, repeat) -> RunRecord
    bits : spec -> int or None   bits the run carries (references and conversions stay 64 bits above)
    state_digits : spec -> int   digits its mpf states are evaluated with (invariants)
    atlas : (model, y0, grid, spec) -> call, or None: a call running it across a model's charts (None: no atlas)
    quick_run, quick_study : spec -> None, optional: scale the specification down in quick mode (in a scene's
                                 [run], in a work-precision study), in place
    list_keys : tuple            keys that may be lists in work-precision studies (one run per value)
    check : spec -> None, optional: the API's checks that tie several fields together (a tolerance against the
                                 precision, ...), on a specification with scalar settings; raises ValueError or
                                 TypeError naming the key in backticks, as the run itself would
    """

    name: str
    fields: dict
    docs: dict
    label: Callable
    precision: Callable
    setting: Callable
    digits: Callable
    run: Callable
    bits: Callable = lambda spec: None
    state_digits: Callable = lambda spec: 40
    atlas: Callable | None = None
    quick_run: Callable | None = None
    quick_study: Callable | None = None
    list_keys: tuple = ()
    check: Callable | None = None

    @property
    def defaults(self) -> dict:
        return {k: d for k, (_check, d) in self.fields.items()}


_METHODS: dict = {}

#: Method name -> accepted keys (besides ``method`` and ``label``) and their defaults (kept in step with the registry).
METHODS: dict = {}


def register_method(method: Method) -> Method:
    """Make ``method`` available to :func:`run_method`, scenes and studies (a later registration of the same name
    replaces the earlier one)."""
    if not isinstance(method, Method):
        raise TypeError(f"`method` must be a Method; got {type(method).__name__}")
    if set(method.fields) != set(method.docs):
        raise ValueError(f"method {method.name!r}: `docs` must describe exactly its fields {sorted(method.fields)}")
    _METHODS[method.name] = method
    METHODS[method.name] = method.defaults
    return method


def unregister_method(name: str) -> None:
    """Forget the method ``name`` (a plug-in's tests clean up with it)."""
    _METHODS.pop(name, None)
    METHODS.pop(name, None)


def method_plugin(name: str) -> Method:
    """The registered :class:`Method` called ``name``."""
    return _METHODS[name]


def methods_registry() -> dict:
    """{name: Method} in registration order."""
    return dict(_METHODS)


def scene_methods(lists: bool):
    """The scene checker of a list of method tables (``lists``: settings may be lists, as in work-precision
    studies): each table's fields are its method's, with their defaults."""

    def one(data, path):
        if not isinstance(data, dict):
            raise F.SceneError(f"`{path}` must be a table such as {{ method = \"taylor\", precision = \"double\" }}; "
                               f"got {F.show(data)}")
        if "method" not in data:
            raise F.SceneError(f"missing required field `{path}.method` (one of {', '.join(_METHODS)})")
        name = data["method"]
        if name not in _METHODS:
            raise F.SceneError(f"`{path}.method`: unknown method {F.show(name)}; known: {', '.join(_METHODS)}")
        plugin = _METHODS[name]
        spec = {"method": (None, F.REQUIRED), "label": (F.string, None)}
        spec.update({k: (F.list_of(c) if lists and k in plugin.list_keys else c, d)
                     for k, (c, d) in plugin.fields.items()})
        out = F.table(data, path, spec)
        if out["label"] is None:
            del out["label"]
        if plugin.check is not None:
            for one_spec in _settings(out, plugin.list_keys):
                try:
                    plugin.check(one_spec)
                except (TypeError, ValueError) as err:
                    where = ", ".join(f"{k} = {F.show(one_spec[k])}" for k in plugin.fields)
                    raise F.SceneError(f"`{path}` ({where}): {err}") from None
        return out

    def check(value, path):
        if not isinstance(value, list) or not value:
            F.fail(path, "a non-empty list of method tables", value)
        return [one(m, f"{path}[{i}]") for i, m in enumerate(value)]

    return check


def _settings(spec: dict, list_keys) -> list:
    """One specification per combination of the list-valued ``list_keys`` of ``spec``."""
    runs = [spec]
    for key in list_keys:
        if isinstance(spec.get(key), (list, tuple)):
            runs = [dict(r, **{key: v}) for r in runs for v in spec[key]]
    return runs


def thin(values, keep: int = 3):
    """At most ``keep`` (3 or 2) values of a list: its ends and (for 3) its middle."""
    if not isinstance(values, list) or len(values) <= keep:
        return values
    idx = sorted({0, len(values) // 2, len(values) - 1}) if keep >= 3 else [0, len(values) - 1]
    return [values[i] for i in idx]


def run_atlas_method(model, y0, t, spec, *, times, repeat: int = 1, bits: int = 256):
    """One method across a model's charts (its ``runs_on_atlas``): (RunRecord, extra) whose states are those of
    ``model.atlas_twin()`` at each output row (the rows of an atlas run are written in different charts,
    converted with ``bits`` bits), with the chart of each row and the number of switches in ``extra``."""
    spec = normalize_method(spec)
    m = spec["method"]
    label = method_label(spec)
    tf, grid = _grid(t, times)
    plugin = _METHODS[m]
    if plugin.atlas is None:
        return RunRecord(m, label, run_precision(spec), setting(spec), float(tf), float(tf), status="skipped",
                         message=f"method {m!r} has no atlas runs (use taylor or lie)"), None
    call = plugin.atlas(model, y0, grid if grid is not None else tf, spec)
    try:
        sol, walls = best_of(call, repeat)
    except Exception as err:  # a failing method is a row, not the end of the run
        return RunRecord(m, label, run_precision(spec), setting(spec), float(tf), float(tf), status="error",
                         message=f"{type(err).__name__}: {err}"), None
    times_ = [to_fraction(v) for v in sol.t]
    rows = list(sol.y)
    charts = [int(c) for c in sol.charts]
    if sol.y_reached is not None and (not times_ or times_[-1] != to_fraction(sol.t_reached)):
        times_.append(to_fraction(sol.t_reached))
        rows.append(sol.y_reached)
        charts.append(int(getattr(sol, "chart_reached", charts[-1] if charts else model.chart)))
    states = [model.atlas_state(r, c, bits) for r, c in zip(rows, charts)]
    st = sol.stats
    build = float(st.build_time or 0.0)
    run = RunRecord(
        m, label, run_precision(spec), setting(spec), float(times_[-1]), float(tf), t_exact=times_[-1],
        times=[float(v) for v in times_], states=states, steps=int(st.steps),
        order=int(st.order) if st.order else None, build_time=build if m == "taylor" else None,
        run_time=float(min([walls[0] - build] + walls[1:])), core_time=float(st.run_time), status=sol.status,
        message=sol.message,
    )
    extra = {"chart_switches": int(st.extra.get("chart_switches", 0)), "charts": charts}
    if "max_step_over_radius" in st.extra:
        extra["max_step_over_radius"] = float(st.extra["max_step_over_radius"])
    return run, extra


