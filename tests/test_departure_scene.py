"""The departure map as a scene study: validation, a small run checked against facts of the closed form."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from lieseries.report import SECTION_TITLES, summary_text, write_report
from lieseries.run import run_scene
from lieseries.scenes import SceneError, builtin_scenes, effective_plan, load_scene, parse_scene

I = (1, 2, 3)


def _scene(study=None, model=None, models=None):
    data = {"name": "dm", "title": "departure map test", "initial": {"omega": [1, "0.1", "0.5"]},
            "studies": {"departure_map": {"grid": [3, 2], "T": 50, "samples": 10, "precisions": ["double", "quad"],
                                          "threshold": "1e-12", **(study or {})}}}
    if models is not None:
        data["models"] = models
    else:
        data["model"] = model or {"kind": "euler_poisson", "inertia": list(I)}
    return data


def _ratio(theta, phi):
    """2 H I2 / |M|^2 of M0 = (sin th cos ph, sin th sin ph, cos th), from the energy H = sum M_i^2 / (2 I_i)."""
    m = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    return I[1] * sum(m[i] ** 2 / I[i] for i in range(3)) / (m ** 2).sum(axis=0)


def test_builtin_scene_is_listed_and_validates():
    names = dict(builtin_scenes())
    assert names.get("departure-map"), "`lieseries scenes` must list departure-map with its title"
    scene = load_scene("departure-map")
    assert scene.description
    dm = scene.studies["departure_map"]
    assert dm["grid"] == [15, 24] and dm["T"] == 200 and dm["samples"] == 100
    assert dm["precisions"] == ["double", "long double", "quad"] and dm["threshold"] == "1e-6"
    assert scene.plots == ["departure_map"]
    _run, studies = effective_plan(scene, quick=True)
    q = studies["departure_map"]
    assert q["grid"] == [3, 6] and q["T"] == 20 and q["samples"] == 20


@pytest.mark.parametrize("field, value, path", [
    ("grid", [0, 6], "studies.departure_map.grid[0]"),
    ("grid", [3, 129], "studies.departure_map.grid[1]"),
    ("grid", [3], "studies.departure_map.grid"),
    ("T", -1, "studies.departure_map.T"),
    ("samples", 1, "studies.departure_map.samples"),
    ("precisions", ["octuple"], "studies.departure_map.precisions[0]"),
    ("precisions", "double", "studies.departure_map.precisions"),
    ("threshold", 0, "studies.departure_map.threshold"),
    ("dps", 5, "studies.departure_map.dps"),
    ("thresh", 1e-6, "studies.departure_map.thresh"),
])
def test_bad_fields_are_refused_with_their_path(field, value, path):
    with pytest.raises(SceneError, match=f"`{re.escape(path)}`"):
        parse_scene(_scene({field: value}))


@pytest.mark.parametrize("model, path", [
    ({"kind": "sphere"}, "model.kind"),
    ({"kind": "damped_euler_poisson", "inertia": [1, 2, 3], "damping": "0.1"}, "model.kind"),
    ({"kind": "euler_poisson", "inertia": [[1, "0.1", 0], ["0.1", 2, 0], [0, 0, 3]]}, "model.inertia"),
    ({"kind": "euler_poisson", "inertia": [1, 2, 3], "bracket": "intermediate"}, "model.bracket"),
])
def test_models_other_than_the_principal_rigid_body_are_refused(model, path):
    data = _scene(model=model)
    if model["kind"] == "sphere":
        data["initial"] = {"x": [0, 0, 1], "v": [1, 0, 0]}
    with pytest.raises(SceneError, match=rf"studies\.departure_map.*`{re.escape(path)}`"):
        parse_scene(data)


def test_the_path_names_the_model_of_an_array():
    models = [{"kind": "euler_poisson", "inertia": [1, 2, 3], "label": "a"},
              {"kind": "euler_poisson", "inertia": [1, 2, 3], "bracket": "intermediate", "label": "b"}]
    with pytest.raises(SceneError, match=r"`models\[1\]\.bracket`"):
        parse_scene(_scene(models=models))
    # a diagonal tensor is principal inertia
    parse_scene(_scene(model={"kind": "euler_poisson", "inertia": [[1, 0, 0], [0, 2, 0], [0, 0, 3]]}))


def test_small_map_against_the_closed_form_facts(tmp_path):
    """3 x 2 directions to T = 50 (10 output times), threshold 1e-12: the grid's points at theta = 30 and 150 deg,
    phi = 0 and 180 deg lie exactly on the separatrix (M0 = (+-1/2, 0, +-sqrt(3)/2): 2 H I2 = |M|^2), where errors grow like exp(lambda t),
    lambda = sqrt((1/I1 - 1/I2)(1/I2 - 1/I3)) = 0.289: double (eps 1.1e-16) passes 1e-12 after about
    ln(1e4) / lambda = 32, quad (eps 1.9e-34) not before ln(5e21) / lambda = 174 > T = 50."""
    res = run_scene(parse_scene(_scene()), progress=False)
    [(label, m)] = res.studies["departure_map"]
    th, ph = np.meshgrid(m.theta, m.phi, indexing="ij")
    np.testing.assert_allclose(m.theta, [(i + 0.5) * math.pi / 3 for i in range(3)], rtol=1e-15)
    np.testing.assert_allclose(m.phi, [0, math.pi], atol=1e-15)
    ratio = _ratio(th, ph)
    np.testing.assert_allclose(m.energy_ratio, ratio, rtol=1e-13)
    on = np.abs(ratio - 1) < 1e-12
    far = np.abs(ratio - 1) > 0.15
    assert on.sum() == 4 and far.sum() == 2
    for name in ("double", "quad"):
        assert m.statuses[name] == ["success"] * 6
        # stayed <=> no output time farther than the threshold
        np.testing.assert_array_equal(m.stayed[name], m.max_error[name] <= m.threshold)
        assert np.all(m.departure[name][m.stayed[name]] == m.T)
    dd, dq = m.departure["double"], m.departure["quad"]
    assert np.all(dd <= dq)
    assert np.all(~m.stayed["double"][on]) and np.all(m.stayed["double"][far])
    assert dd[on].max() < dd[far].min()
    assert np.all(dd[on] > 20)  # growth by 1e4 from round-off takes about 32 time units
    assert m.stayed["quad"].all()
    # far from the separatrix, errors near each precision's round-off; on it, both grow alike, quad's smaller by
    # about the ratio of the epsilons (5.8e17)
    assert m.max_error["double"][far].max() < 1e-14 and m.max_error["quad"][far].max() < 1e-30
    assert np.all(m.max_error["double"][on] / m.max_error["quad"][on] > 1e16)
    # the report: a section with the table and the plot
    md = write_report(res, tmp_path / "rep").read_text()
    assert f"## {SECTION_TITLES['departure_map']}" in md and "![departure map](departure_map.png)" in md
    assert (tmp_path / "rep" / "departure_map.png").stat().st_size > 0
    assert (tmp_path / "rep" / "departure_map.csv").is_file()
    assert "departure map (rigid body, double): 4 / 6 departed before T = 50" in summary_text(res)
    # the reading says what the data show: lambda from the principal moments, the growth times, the departures
    lam = math.sqrt((1 / I[0] - 1 / I[1]) * (1 / I[1] - 1 / I[2]))
    assert m.saddle_rate == pytest.approx(lam, rel=1e-12)
    assert m.predicted["double"] == pytest.approx(math.log(1e-12 / 2.0**-52) / lam, rel=1e-12)
    assert "4 grid directions lie on the separatrix" in md
    assert f"double: 4 of 6 departed, the earliest at {dd[on].min():.1f}; on the separatrix" in md
    assert "quad: no direction departed by T = 50" in md


@pytest.mark.slow
def test_builtin_scene_quick_run(tmp_path):
    """``lieseries run departure-map --quick``: every member of every precision succeeds and the report is written."""
    res = run_scene("departure-map", quick=True, progress=False)
    [(label, m)] = res.studies["departure_map"]
    assert list(m.departure) == ["double", "long double", "quad"]
    for name in m.departure:
        assert set(m.statuses[name]) == {"success"}
        assert m.max_error[name].max() < 1e-6
    assert np.all(m.max_error["quad"] < m.max_error["double"])
    md = write_report(res, tmp_path / "rep").read_text()
    assert "departure_map.png" in md

