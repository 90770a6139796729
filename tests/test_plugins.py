"""Models and studies are plug-ins: a model (tests/plugins/harmonic.py) and a study (tests/plugins/energy_table.py),
each one file of the test suite, are registered and run in a scene with a report, touching no library module."""

import importlib.util
import json
import math
from pathlib import Path

import pytest

import lieseries as ls
from lieseries.models.kinds import unregister_initial_family, unregister_model_kind
from lieseries.report import summary_text, write_report
from lieseries.run import run_scene
from lieseries import scenes
from lieseries.scenes import SceneError, parse_scene, scene_reference
from lieseries.studies import unregister_closed_form, unregister_study

HERE = Path(__file__).resolve().parent / "plugins"


def _load(name):
    spec = importlib.util.spec_from_file_location(f"lieseries_test_plugin_{name}", HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def plugins():
    """Both plug-ins registered for one test, and forgotten after it (other tests see the built-in registry)."""
    harmonic = _load("harmonic")
    _load("energy_table")
    yield harmonic
    unregister_study("energy_table")
    unregister_model_kind("harmonic")
    unregister_initial_family("oscillator")
    unregister_closed_form("harmonic")


SCENE = """
name = "oscillator"
title = "A plug-in model and a plug-in study"
[model]
kind = "harmonic"
omega = "1.5"
[initial]
q = 1
p = "0.5"
[run]
t = 3
samples = 7
methods = [{ method = "taylor", precision = "double" }, { method = "lie", dps = 30 }]
[studies.energy_table]
t = 4
[report]
plots = ["energy_table"]
"""


def test_a_plugin_model_and_study_run_in_a_scene_with_a_report(plugins, tmp_path):
    scene = parse_scene(SCENE)
    assert "energy_table" in scenes.STUDIES and "energy_table" in scenes.PLOTS  # read from the registries
    res = run_scene(scene, progress=False)
    rows = {r.method: r for r in res.run["rows"]}
    assert res.run["reference"].startswith("closed form (cos, sin)")  # the plug-in's closed form is the reference
    # independent: the final state in double, from the exact solution computed here in floats
    w, q0, p0, t = 1.5, 1.0, 0.5, 3.0
    exact = [q0 * math.cos(w * t) + p0 / w * math.sin(w * t), p0 * math.cos(w * t) - w * q0 * math.sin(w * t)]
    for r in rows.values():
        assert r.status == "success"
        assert max(abs(a - b) for a, b in zip(r.final_state, exact)) < 1e-13
    assert rows["taylor"].error < 1e-13 and rows["lie"].error < 1e-25  # against the closed form at 30+ digits
    assert set(rows["lie"].drift) == {"energy"} and rows["lie"].drift["energy"] < 1e-25
    assert res.unsuccessful() == []
    (_lab, table), = res.studies["energy_table"]
    assert table.initial["energy"] == pytest.approx((0.5**2 + 1.5**2 * 1.0**2) / 2, rel=1e-15)  # H(0) by hand
    assert abs(table.final["energy"] - table.initial["energy"]) < 1e-13
    write_report(res, tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## Energy table" in md and "![energy table](energy_table.png)" in md
    assert (tmp_path / "rep" / "energy_table.png").is_file() and (tmp_path / "rep" / "energy_table.csv").is_file()
    assert json.loads((tmp_path / "rep" / "data.json").read_text())["studies"]["energy_table"][0]["t"] == 4.0
    assert "energy table (oscillator): 1 invariants to t = 4" in summary_text(res)
    # the scene reference documents the plug-ins' fields
    ref = scene_reference()
    assert '[model] kind = "harmonic"' in ref and "## [studies.energy_table]" in ref


def test_plugin_fields_are_checked_like_the_builtin_ones(plugins):
    with pytest.raises(SceneError, match=r"`model\.omega` must be a positive number"):
        parse_scene(SCENE.replace('omega = "1.5"', "omega = -1"))
    with pytest.raises(SceneError, match=r"unknown field `studies\.energy_table\.tt`"):
        parse_scene(SCENE.replace("t = 4", "tt = 4"))
    with pytest.raises(SceneError, match=r"missing required field `initial\.q`"):
        parse_scene(SCENE.replace("q = 1\n", ""))


def test_the_builtin_registry_is_back_after_the_plugins():
    assert "energy_table" not in scenes.STUDIES and "harmonic" not in scenes.MODEL_KINDS
    with pytest.raises(SceneError, match="unknown model kind 'harmonic'"):
        parse_scene(SCENE)


def test_registrations_refuse_what_they_cannot_use():
    from lieseries import fields as F
    from lieseries.methods import register_method
    from lieseries.models.kinds import ModelKind, register_model_kind
    from lieseries.studies import Study, register_study

    class NoDocs(Study):
        name = "no_docs"
        fields = {"t": (F.positive, 1)}
        docs = {}

    with pytest.raises(ValueError, match="`docs` must describe exactly its fields"):
        register_study(NoDocs())
    with pytest.raises(TypeError, match="`study` must be a Study"):
        register_study(object())
    with pytest.raises(ValueError, match="`docs` must describe exactly its fields"):
        register_model_kind(ModelKind("odd", {"a": (F.positive, 1)}, {}, lambda p, b: None, "state", "odd"))
    with pytest.raises(TypeError, match="`method` must be a Method"):
        register_method({"name": "euler"})
    assert "no_docs" not in scenes.STUDIES and "odd" not in scenes.MODEL_KINDS


def test_a_study_prices_itself_for_the_scene_estimate_or_the_estimate_says_it_is_a_lower_bound(plugins):
    from lieseries.cost import CostPart, SceneTooLong, check_scene_budget, estimate_scene
    from lieseries.studies.plugin import study_plugin

    scene = parse_scene(SCENE)
    est = estimate_scene(scene)
    unpriced = [p for p in est.parts if p.field == "studies.energy_table"]
    assert est.lower_bound and len(unpriced) == 1 and "not estimated" in unpriced[0].what

    study = study_plugin("energy_table")

    def cost(opts, ctx, pricer):  # one heyoka run per model, priced by the model of heyoka's steps
        assert opts["t"] == 4 and [lab for lab, _ in ctx.built] == [lab for lab, _ in scene.build_models()]
        parts = []
        for _lab, model in ctx.built:
            secs, lower, basis = pricer.heyoka_run(model, ctx.initial_state(model), opts["t"], opts["precision"])
            parts.append(CostPart("studies.energy_table.t", "one run", 10**9, "run", secs, basis, lower))
        return parts

    study.cost = cost
    est = estimate_scene(scene)
    assert not est.lower_bound
    assert est.driver().field == "studies.energy_table.t" and est.driver().seconds > 1e3
    with pytest.raises(SceneTooLong, match=r"`studies\.energy_table\.t`"):
        check_scene_budget(est, 60)
