"""Studies as plug-ins: a :class:`Study` carries its scene fields, quick-mode scaling, run, report section, plot
and summary; :func:`register_study` makes it available to scenes (``[studies.<name>]``), to
:func:`lieseries.run_scene` and to the report, which iterate the registry. A new study is one file defining a
Study subclass plus one registration.

The scene runner calls :meth:`Study.run` with a :class:`StudyContext` (the scene, its built models, progress,
notes); the report calls :meth:`Study.section` (Markdown lines and CSV tables), :meth:`Study.plot` (a PNG path,
when the scene's ``report.plots`` names the study) and :meth:`Study.summary` (lines for the terminal). Results are
``[(model label, result)]``; a result has a ``to_dict()`` (data.json).
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Study", "StudyContext", "ReportContext", "register_study", "unregister_study", "studies_registry",
           "study_plugin"]


@dataclass
class StudyContext:
    """What a study's run sees.

    Attributes
    ----------
    scene : Scene               the scene (``scene.initial_state(model)`` gives a model's initial state)
    built : list                [(label, model)] of the scene's models, built once
    bar : callable              ``bar(done, total, label)`` progress of the study
    notes : list of str         notes for the report (append; do not repeat one)
    failed : list of str        "study (model): what went wrong" for the parts that raised
    quick : bool                quick mode
    """

    scene: object
    built: list
    bar: object = None
    notes: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    quick: bool = False

    def initial_state(self, model):
        return self.scene.initial_state(model)

    def model_progress(self, i: int, label: str):
        """A ``progress(done, total, what)`` for the ``i``-th model that feeds the study's bar."""
        n = len(self.built)
        bar = self.bar

        def prog(done, total, what):
            if bar is not None:
                bar(i * total + done, n * total, f"{label}: {what}")

        return prog

    def note(self, line: str) -> None:
        if line not in self.notes:
            self.notes.append(line)


@dataclass
class ReportContext:
    """What a study's report section sees: ``plotted`` (the study's plot was drawn, as ``<name>.png``),
    ``scene`` and ``quick``."""

    scene: object
    plotted: bool
    quick: bool = False


class Study:
    """Base of the study plug-ins. Subclasses set the class attributes and override :meth:`run`,
    :meth:`section`; the others have defaults.

    Attributes
    ----------
    name : str          the scene table ``[studies.<name>]``, the key of ``SceneResult.studies``, the plot name
    title : str         the report's section heading
    fields : dict       the scene fields ``{key: (checker, default or fields.REQUIRED)}`` (:mod:`lieseries.fields`)
    docs : dict         ``{key: (type, meaning)}`` (docs/scenes.md is generated from it)
    has_plot : bool     the study draws ``<name>.png`` when ``report.plots`` names it (default: it does)
    quick_doc : str     what quick mode does to it (one clause for :func:`lieseries.scenes.effective_plan`)
    """

    name: str = ""
    title: str = ""
    fields: dict = {}
    docs: dict = {}
    has_plot: bool = True
    quick_doc: str = ""

    def check(self, opts: dict, run, models: list, where: str) -> None:
        """Cross-field checks of the study's table ``opts`` (which may be filled in), raising
        :class:`~lieseries.fields.SceneError`. ``run``: the scene's [run] table or None; ``models``: [(path, spec,
        built model, initial state)] (``path``: "model" or "models[i]")."""

    def quick(self, opts: dict) -> None:
        """Scale ``opts`` down for quick mode, in place."""

    def run(self, opts: dict, ctx: StudyContext) -> list:
        """[(model label, result)] for the scene's models."""
        raise NotImplementedError

    def unsuccessful(self, items: list) -> list:
        """One line per run of the study that ended without success (the CLI's exit status)."""
        return []

    def section(self, items: list, ctx: ReportContext):
        """(Markdown lines after the heading, [(csv name, headers, rows)])."""
        raise NotImplementedError

    def plot(self, items: list, path, scene) -> None:
        """Draw the study's figure into ``path`` (PNG)."""

    def summary(self, items: list) -> list:
        """Lines for the terminal summary."""
        return []

    def cost(self, opts: dict, ctx: StudyContext, pricer) -> list | None:
        """The study's work priced for an up-front estimate (:func:`lieseries.cost.estimate_scene`): a list of
        :class:`~lieseries.methods.pricing.CostPart` (units, the price of one from ``pricer``, a
        :class:`~lieseries.methods.pricing.Pricer`, and the scene field ``studies.<name>.<key>`` that drives them);
        add the heyoka integrators it compiles to ``pricer.heyoka_builds``. None (the default): the study does not
        price itself, and an estimate of a scene with it is a lower bound that says so."""
        return None


_STUDIES: dict = {}


def register_study(study: Study) -> Study:
    """Make ``study`` available to scenes, runs and reports (a later registration of the same name replaces the
    earlier one)."""
    if not isinstance(study, Study):
        raise TypeError(f"`study` must be a Study; got {type(study).__name__}")
    if not study.name.isidentifier():
        raise ValueError(f"a study's name must be a Python name; got {study.name!r}")
    if set(study.fields) != set(study.docs):
        raise ValueError(f"study {study.name!r}: `docs` must describe exactly its fields {sorted(study.fields)}")
    _STUDIES[study.name] = study
    return study


def unregister_study(name: str) -> None:
    """Forget the study ``name`` (a plug-in's tests clean up with it)."""
    _STUDIES.pop(name, None)


def studies_registry() -> dict:
    """{name: Study} in registration order (the order of the report's sections)."""
    return dict(_STUDIES)


def study_plugin(name: str) -> Study:
    return _STUDIES[name]
