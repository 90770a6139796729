"""Scenes: strict validation naming the field; every built-in scene runs (quick) and its report holds what the
scene asks for and nothing else."""

import json
import re

import pytest

import lieseries as ls
from lieseries.report import SECTION_TITLES, markdown_table
from lieseries.folder import FolderError
from lieseries.report import write_report
from lieseries.run import run_scene
from lieseries.scenes import (
    PLOTS,
    STUDIES,
    SceneError,
    builtin_scenes,
    effective_plan,
    load_scene,
    parse_scene,
)

BUILTINS = [name for name, _ in builtin_scenes()]

RIGID = """
name = "t"
title = "test"
[model]
kind = "euler_poisson"
inertia = [1, 2, 3]
[initial]
omega = [1, "0.1", "0.5"]
[run]
t = 2
samples = 11
methods = [{ method = "taylor", precision = "double" }, { method = "taylor", precision = "quad" }]
"""


def scene_error(text, fragment):
    with pytest.raises(SceneError) as info:
        parse_scene(text)
    msg = str(info.value)
    assert fragment in msg, msg
    return msg


# -- validation ------------------------------------------------------------------------------------------------
def test_minimal_scene_parses_with_defaults():
    sc = parse_scene(RIGID)
    assert sc.name == "t" and sc.models[0].kind == "euler_poisson"
    assert sc.models[0].params["bracket"] == "chetaev"
    assert sc.run["repeat"] == 3 and sc.studies == {} and sc.plots == []


def test_unknown_model_kind():
    msg = scene_error(RIGID.replace('"euler_poisson"', '"pendulum"'), "`model.kind`")
    assert "'pendulum'" in msg and "euler_poisson" in msg


def test_missing_required_field():
    scene_error(RIGID.replace("inertia = [1, 2, 3]\n", ""), "missing required field `model.inertia`")
    scene_error(RIGID.replace('title = "test"\n', ""), "missing required field `title`")
    scene_error(RIGID.replace("t = 2\n", ""), "missing required field `run.t`")


def test_wrong_type():
    msg = scene_error(RIGID.replace("inertia = [1, 2, 3]", 'inertia = "abc"'), "`model.inertia` must be a list of 3 "
                                                                          "numbers or a 3x3 list")
    assert "'abc'" in msg
    scene_error(RIGID.replace('omega = [1, "0.1", "0.5"]', 'omega = [1, "x", 2]'), "`initial.omega[1]`")
    scene_error(RIGID.replace("samples = 11", "samples = 1.5"), "`run.samples` must be an integer")


def test_unknown_field_and_suggestion():
    text = RIGID + "[studies.drift]\nt = 100\nsmaples = 10\n"
    msg = scene_error(text, "unknown field `studies.drift.smaples`")
    assert "did you mean `samples`" in msg and "known:" in msg
    scene_error(RIGID + "[studies.drfit]\nt = 1\n", "unknown field `studies.drfit`")
    scene_error(RIGID.replace("[initial]", "colour = 1\n[initial]"), "unknown field `model.colour`")


def test_method_fields():
    msg = scene_error(RIGID.replace('precision = "quad"', 'precision = "single"'), "`run.methods[1].precision`")
    assert "unknown precision 'single'" in msg
    scene_error(RIGID.replace('method = "taylor", precision = "quad"', 'method = "euler"'), "`run.methods[1].method`")
    scene_error(RIGID.replace('precision = "quad"', 'precision = "quad", rtol = 1e-9'),
                "unknown field `run.methods[1].rtol`")
    scene_error(RIGID.replace('precision = "quad"', 'precision = "quad", tol = 2'), "`run.methods[1].tol`")


def test_physics_errors_name_the_table():
    scene_error(RIGID.replace("inertia = [1, 2, 3]", "inertia = [1, -2, 3]"), "`model`")
    sphere = """
name = "s"
title = "s"
[model]
kind = "sphere"
[initial]
x = [1, 1, 0]
v = [0, 0, 1]
[run]
t = 1
methods = [{ method = "taylor" }]
"""
    msg = scene_error(sphere, "`initial`")
    assert "sphere" in msg


def test_plots_must_have_their_study():
    scene_error(RIGID + '[report]\nplots = ["drift"]\n', "`report.plots[0]` asks for 'drift'")
    scene_error(RIGID + '[report]\nplots = ["histogram"]\n', "`report.plots[0]`: unknown plot")
    sc = parse_scene(RIGID + "[studies.drift]\nt = 100\n")
    assert sc.plots == ["drift"]  # default: one plot per study present


def test_error_vs_order_options():
    scene_error(RIGID + "[studies.error_vs_order]\nmax_order = 10\n", "`studies.error_vs_order`")
    scene_error(RIGID + "[studies.error_vs_order]\nt = 1\nt_fraction = 0.5\n", "got both")
    scene_error(RIGID + "[studies.error_vs_order]\nt_fraction = 1.5\n", "`studies.error_vs_order.t_fraction`")


def test_models_array_and_mixed_families():
    text = RIGID.replace("[model]\nkind = \"euler_poisson\"\ninertia = [1, 2, 3]",
                         '[[models]]\nlabel = "a"\nkind = "euler_poisson"\ninertia = [1, 2, 3]\n'
                         '[[models]]\nlabel = "b"\nkind = "euler_poisson"\ninertia = [1, 2, 3]\n'
                         'bracket = "intermediate"')
    sc = parse_scene(text)
    assert [m.label for m in sc.models] == ["a", "b"]
    bad = text.replace('label = "b"\nkind = "euler_poisson"\ninertia = [1, 2, 3]\nbracket = "intermediate"',
                       'label = "b"\nkind = "sphere"')
    scene_error(bad, "share the initial data")


def test_invalid_toml_and_unknown_scene(tmp_path):
    scene_error("name = ", "not valid TOML")
    with pytest.raises(SceneError, match="unknown scene 'defualt' \\(did you mean 'default'\\?\\)"):
        load_scene("defualt")
    with pytest.raises(SceneError, match="not found"):
        load_scene(str(tmp_path / "missing.toml"))


def test_scene_folder_override(tmp_path, monkeypatch):
    (tmp_path / "mine.toml").write_text(RIGID.replace('name = "t"', 'name = "mine"'))
    monkeypatch.setenv("LIESERIES_SCENES", str(tmp_path))
    assert builtin_scenes() == [("mine", "test")]
    assert load_scene("mine").name == "mine"


def test_builtin_scenes_are_listed_and_valid():
    assert BUILTINS[0] == "default"
    assert {"default", "asymmetric-body", "tennis-racket", "sphere-great-circle", "sphere-forms"} <= set(BUILTINS)
    for name in BUILTINS:
        sc = load_scene(name)
        assert sc.name == name and sc.title and sc.description


def test_quick_plan_scales_studies_down():
    sc = load_scene("asymmetric-body")
    run, studies = effective_plan(sc, quick=True)
    full_run, full = effective_plan(sc, quick=False)
    assert max(studies["error_vs_order"]["orders"]) <= 30 < full["error_vs_order"]["max_order"]
    assert studies["drift"]["t"] == pytest.approx(float(full["drift"]["t"]) / 10)
    assert studies["drift"]["samples"] <= 60 and studies["work_precision"]["repeat"] == 1
    for m in studies["work_precision"]["methods"]:
        for key in ("tol", "rtol"):
            if isinstance(m.get(key), list):
                assert len(m[key]) <= 3
    assert run["samples"] <= 41 and full_run["samples"] == 101
    assert sc.studies["drift"]["samples"] == 200  # the scene itself is untouched


# -- running scenes --------------------------------------------------------------------------------------------
def headings(md: str) -> set:
    return set(re.findall(r"^## (.+)$", md, flags=re.M))


#: Built-in scenes whose quick report runs in the default suite; the others (1-5 s each) run with `make test-all`.
#: sphere-great-circle asks for every section and plot the others do (run, studies, three plots); the default
#: scene's quick run and report stay in the default suite through test_cli.py (the validation script) and the
#: tutorial.
FAST_SCENES = ("sphere-great-circle",)


@pytest.mark.parametrize("name", [pytest.param(n, marks=() if n in FAST_SCENES else pytest.mark.slow)
                                  for n in BUILTINS])
def test_builtin_scene_quick_report_has_what_it_asks_for(name, tmp_path):
    scene = load_scene(name)
    res = run_scene(scene, quick=True, progress=False)
    write_report(res, tmp_path)
    md = (tmp_path / "report.md").read_text()
    heads = headings(md)
    assert SECTION_TITLES["scene"] in heads
    assert (SECTION_TITLES["run"] in heads) == (scene.run is not None)
    for study in STUDIES:
        assert (SECTION_TITLES[study] in heads) == (study in scene.studies), study
        assert (study in res.studies) == (study in scene.studies)
    for plot in PLOTS:
        expected = plot in scene.plots
        assert (tmp_path / f"{plot}.png").is_file() == expected, plot
        assert (f"({plot}.png)" in md) == expected, plot
    data = json.loads((tmp_path / "data.json").read_text())
    assert set(data["studies"]) == set(scene.studies)
    assert data["quick"] is True
    if scene.run is not None:
        rows = res.run["rows"]
        assert rows and all(r.status == "success" for r in rows), [(r.label, r.message) for r in rows]
        assert (tmp_path / "run.csv").is_file()
        # every heyoka run is at the accuracy of its precision against the exact solution
        for r in rows:
            if r.method == "taylor":
                eps = r.precision.eps
                assert r.error < 1e4 * eps, (r.label, r.error)
        # the numbers in the table are the ones computed
        assert f"{rows[0].error:.2e}" in md
    if "error_vs_order" in scene.studies:
        for _, ev in res.studies["error_vs_order"]:
            if ev.radius_theory:
                assert abs(ev.radius_measured / ev.radius_theory - 1) < 0.15


def test_scene_without_drift_never_runs_drift(tmp_path, monkeypatch):
    import sys

    import lieseries.studies

    def boom(*a, **k):  # pragma: no cover - must not be called
        raise AssertionError("drift was run for a scene that does not ask for it")

    # (the package re-exports the function under the module's name: patch both)
    monkeypatch.setattr(sys.modules["lieseries.studies.drift"], "drift", boom)
    monkeypatch.setattr(lieseries.studies, "drift", boom)
    res = run_scene(parse_scene(RIGID), progress=False)
    write_report(res, tmp_path)
    md = (tmp_path / "report.md").read_text()
    assert "drift" not in res.studies
    assert SECTION_TITLES["drift"] not in headings(md)
    assert not list(tmp_path.glob("*.png"))  # no plots asked for


def test_report_drops_its_own_earlier_plots_and_nothing_else(tmp_path):
    # each scene runs once: what is tested is how its reports replace each other in the folder
    with_plot = run_scene(parse_scene(RIGID + '[report]\nplots = ["trajectory"]\n'), progress=False)
    without = run_scene(parse_scene(RIGID), progress=False)
    write_report(with_plot, tmp_path)
    assert (tmp_path / "trajectory.png").is_file()
    # a later report of a scene without plots removes the plot lieseries wrote before...
    write_report(without, tmp_path)
    assert not (tmp_path / "trajectory.png").exists()
    # ...but a folder with the user's own files is refused, and with overwrite they are kept
    (tmp_path / "drift.png").write_bytes(b"mine")
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(FolderError, match="drift.png"):
        write_report(without, tmp_path)
    write_report(with_plot, tmp_path, overwrite=True)
    assert (tmp_path / "drift.png").read_bytes() == b"mine"
    assert (tmp_path / "notes.txt").read_text() == "mine"
    assert (tmp_path / "trajectory.png").is_file()


def test_markdown_table_aligns_numbers():
    md = markdown_table(["method", "error"], [["a", "1.00e-03"], ["longer name", "2.50e-16"]])
    lines = md.splitlines()
    assert lines[1].endswith("-: |")
    assert len({len(line) for line in lines}) == 1
    assert lines[2].index("1.00e-03") == lines[3].index("2.50e-16")


def test_scene_reference_is_generated_from_the_schema():
    """docs/scenes.md is what scene_reference() writes, and every field of the schema has a type and meaning."""
    from pathlib import Path

    from lieseries.scenes import FIELD_DOCS, _schema, scene_reference  # noqa: PLC2701 (same-project test)

    schema = _schema()
    for section, fields in schema.items():
        assert set(fields) == set(FIELD_DOCS[section]), section
    assert set(FIELD_DOCS) == set(schema)
    doc = Path(__file__).resolve().parents[1] / "docs" / "scenes.md"
    assert doc.read_text() == scene_reference() + "\n", "regenerate docs/scenes.md from scene_reference()"


def test_a_scene_can_run_a_model_from_a_python_file(tmp_path):
    """kind = "python": a user's own PoissonSystem (a pendulum) as a scene, measured against heyoka at 256 bits."""
    (tmp_path / "pendulum.py").write_text(
        "import heyoka as hy\nimport lieseries as ls\n\n\ndef make():\n    q, p = hy.make_vars('q', 'p')\n"
        "    return ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p**2 / 2 - hy.par[0] * hy.cos(q),\n"
        "                            parameters={'g': 1}, name='pendulum')\n"
    )
    (tmp_path / "pend.toml").write_text(
        'name = "pendulum"\ntitle = "t"\n[model]\nkind = "python"\nfile = "pendulum.py"\n[initial]\n'
        'y0 = ["0.5", 0]\n[run]\nt = 10\nmethods = [{ method = "taylor" }, { method = "lie", dps = 20 }]\n'
    )
    scene = load_scene(str(tmp_path / "pend.toml"))
    res = run_scene(scene, progress=False)
    rows = {r.method: r for r in res.run["rows"]}
    assert rows["taylor"].status == "success" and rows["taylor"].error < 1e-14
    assert rows["lie"].status == "success" and rows["lie"].error < 1e-19
    assert "numerical" in res.run["reference"] or "heyoka" in res.run["reference"]
    bad = tmp_path / "bad.toml"
    bad.write_text((tmp_path / "pend.toml").read_text().replace('file = "pendulum.py"', 'file = "nope.py"'))
    with pytest.raises(SceneError, match="`model.file`"):
        run_scene(load_scene(str(bad)), progress=False)


def test_scene_says_which_numbers_are_binary_and_against_which_problem():
    """TOML reads omega = [1, 0.1, 0.5] as doubles: the scene's data name initial.omega[1] (not 1 nor 0.5), its
    initial state carries 53 bits, and the note says the errors are measured against the binary problem."""
    text = RIGID.replace('omega = [1, "0.1", "0.5"]', "omega = [1, 0.1, 0.5]").replace(
        "inertia = [1, 2, 3]", "inertia = [1, 2.2, 3]")
    scene = parse_scene(text)
    assert scene.binary_inputs() == {"model.inertia[1]": 53, "initial.omega[1]": 53}
    assert scene.to_dict()["binary_inputs"] == {"model.inertia[1]": 53, "initial.omega[1]": 53}
    note = scene.binary_note()
    assert "`initial.omega[1]`" in note and "binary data" in note and '"0.1"' in note
    model = scene.build_models()[0][1]
    y0 = scene.initial_state(model)
    assert y0.data_bits == 53 and y0.binary_inputs == ("omega[1]",)
    # the exact values the runs start from differ from the decimals as written by the double's rounding
    assert abs(float(y0.exact[10] - 2 * ls.precision.to_fraction("2.2") * ls.precision.to_fraction("0.1"))) > 1e-18
    exact_scene = parse_scene(RIGID)
    assert exact_scene.binary_inputs() == {} and exact_scene.binary_note() == ""
    assert exact_scene.initial_state(exact_scene.build_models()[0][1]).data_bits is None


def test_a_scene_report_with_binary_floats_says_so(tmp_path):
    """The report of a scene whose omega holds the double 0.1 names it in its notes and says against which
    problem its errors are measured; the same scene with "0.1" has no such note."""
    from lieseries.report import write_report
    text = RIGID.replace('omega = [1, "0.1", "0.5"]', "omega = [1, 0.1, 0.5]").replace("t = 2", "t = 0.5")
    with pytest.warns(ls.PrecisionWarning, match=r"omega\[1\]"):
        res = run_scene(parse_scene(text), progress=False)
    md = write_report(res, tmp_path / "binary").read_text()
    assert "`initial.omega[1]`" in md and "binary data" in md
    exact = run_scene(parse_scene(RIGID.replace("t = 2", "t = 0.5")), progress=False)
    assert not any("binary" in n for n in exact.notes)


def test_a_binary_end_time_is_listed_with_the_binary_data():
    """[run] t = 2.1 is the double 2.1 (the runs end at 2.1000000000000001): the scene lists it as binary input;
    t = 2 and t = "2.1" are exact."""
    assert parse_scene(RIGID.replace("t = 2", "t = 2.1")).binary_inputs() == {"run.t": 53}
    assert parse_scene(RIGID.replace("t = 2", 't = "2.1"')).binary_inputs() == {}
    assert parse_scene(RIGID).binary_inputs() == {}


def test_a_toml_number_beyond_a_doubles_range_is_said_to_need_quotes():
    # TOML reads tol = 1e-400 as 0.0 before the scene sees it: the refusal said "got 0.0" and nothing else; as a
    # string it is read exactly, and lie_integrate's refusal names the value asked, not 0
    text = RIGID.replace('methods = [{ method = "taylor", precision = "double" }, { method = "taylor", '
                         'precision = "quad" }]', 'methods = [{ method = "lie", dps = 30, tol = 1e-400 }]')
    scene_error(text, 'got 0.0; a TOML number beyond a double\'s range (1e-400, 1e400) reads as 0.0 or inf: write it '
                      'as a string ("1e-400")')
    scene_error(text.replace("tol = 1e-400", 'tol = "1e-400"'), "`tol` = ~1e-400 is below what 30 digits")
