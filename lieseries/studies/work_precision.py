"""Error against run time for several integrators and settings (a work-precision diagram, as data).

The methods and their settings are those of :mod:`lieseries.methods`.

In :func:`work_precision` any of ``tol``, ``rtol``, ``dps`` (and ``precision``) may be a list: one row per value.

Timing: ``run_time`` is the wall time of the call, best of ``repeat`` (repeats stop once a method has used two
seconds); heyoka's compile time (and the scipy right-hand side's) is kept apart in ``build_time``. Times are
measured in this one run on a shared machine: compare them with each other, not with other runs.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from fractions import Fraction

from ..methods import default_methods, expand_methods, method_label, reference_dps, run_method, setting
from ..poisson import as_poisson_system
from ..precision import check_count, to_fraction
from .reference import reference_solution, state_error

__all__ = ["WorkPrecisionRow", "WorkPrecision", "work_precision"]


@dataclass
class WorkPrecisionRow:
    """One row of a work-precision study (see :class:`MethodRun` for the fields); ``error`` is the max-abs
    error of the final state against the reference at time ``t``."""

    method: str
    label: str
    precision: str
    setting: str
    t: float
    error: float | None
    run_time: float | None
    build_time: float | None
    steps: int | None
    nfev: int | None
    order: int | None
    status: str
    message: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class WorkPrecision:
    """Error against run time: one row per (method, setting).

    Attributes
    ----------
    t : float               final time
    rows : list of WorkPrecisionRow
    reference : str         what the errors are measured against
    notes : list of str     methods left out and why
    system : str
    """

    t: float
    rows: list
    reference: str
    notes: list = field(default_factory=list)
    system: str = ""

    def to_dict(self) -> dict:
        return {"t": self.t, "reference": self.reference, "notes": list(self.notes), "system": self.system,
                "rows": [r.to_dict() for r in self.rows]}


# -- method specifications -------------------------------------------------------------------------------------
def work_precision(system, y0, t, methods=None, reference=None, repeat: int = 3, progress=None) -> WorkPrecision:
    """Error of the final state against run time, for each method and setting.

    Parameters
    ----------
    system : model or PoissonSystem
    y0 : sequence of n numbers
        Initial state (build it at high precision, e.g. ``precision=256``, so that quad and Lie runs start
        from the exact problem; each method rounds it once to its own precision).
    t : number
        Final time.
    methods : list of dict, optional
        Method specifications (module docstring); list-valued settings give one row each. Default:
        :func:`default_methods`.
    reference : sequence of n numbers, optional
        The state at ``t``; default: the closed form where the model has one, else heyoka at 256 bits.
    repeat : int
        Best-of repeats of each timing.
    progress : callable, optional
        Called as ``progress(done, total, label)`` after each run.

    Returns
    -------
    WorkPrecision
    """
    repeat = check_count(repeat, "repeat", low=1, high=1000)
    if methods is None:
        methods = default_methods()
    specs = expand_methods(methods)
    tf = to_fraction(t, "t")
    dps = reference_dps(specs)
    refs = {}

    def ref_at(time_: Fraction):
        if time_ not in refs:
            given = reference if time_ == tf else None
            refs[time_] = reference_solution(system, y0, time_, dps=dps, reference=given)
        return refs[time_]

    rows, notes = [], []
    total = len(specs)
    for i, spec in enumerate(specs):
        label = method_label(spec)
        if progress:
            progress(i, total, f"{label} {setting(spec)}")
        run = run_method(system, y0, tf, spec, repeat=repeat)
        if run.status == "skipped":
            note = f"{label}: {run.message}; its rows are left out."
            if note not in notes:
                notes.append(note)
            continue
        err = None
        if run.ok:
            t_reached = run.t_exact if run.t_exact is not None else to_fraction(run.t)
            err = state_error(system, run.y_final, ref_at(t_reached))
        rows.append(WorkPrecisionRow(
            method=run.method, label=run.label, precision=run.precision, setting=run.setting, t=run.t,
            error=err, run_time=run.run_time, build_time=run.build_time, steps=run.steps, nfev=run.nfev,
            order=run.order, status=run.status, message=run.message,
        ))
    if progress:
        progress(total, total, "done")
    ref = ref_at(tf)
    ps = as_poisson_system(system)
    return WorkPrecision(t=float(tf), rows=rows, reference=f"{ref.label}, {ref.dps} digits", notes=notes,
                         system=ps.name)
