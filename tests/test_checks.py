"""One set of checks: a scene field refuses exactly what the API it feeds refuses.

The test walks every registered scene field (the scene's own [run] and [stability] tables, every method, study,
model kind and initial family, read from the registries) and, for each field that feeds an API argument, feeds
values just inside and just outside the bounds to both the scene schema and the API call (run at t = 0, or stopped
by a later argument that is wrong on purpose), and checks that they accept and refuse the same values. Fields with
no API counterpart are listed in ``NO_API`` with the reason; the lists must cover the registries exactly, so a new
field has to be classified here.
"""

from __future__ import annotations

import warnings

import pytest

import lieseries as ls
from lieseries import fields as F
from lieseries import studies
from lieseries.methods import methods_registry, run_method, scene_methods
from lieseries.methods.builtin import MAX_ODEFUN_DPS
from lieseries.models.kinds import initial_families, model_kinds
from lieseries.precision import MAX_BITS, MAX_DPS, MAX_ORDER, MIN_DPS, PrecisionWarning
from lieseries.scenes.schema import section_fields
from lieseries.studies.convergence import orders_of
from lieseries.studies.plugin import studies_registry

BODY = ls.EulerPoisson((1, 2, 3))
Y0 = BODY.initial_state(("1", "1/10", "1/2"))
BAD = "not a number"  # an argument checked after the probed one, wrong on purpose: the call stops there


def _edges(*bounds):
    return sorted({v for b in bounds for v in (b - 1, b, b + 1)})


# values just inside and just outside every bound the API and the scene have (or had) for integers
INTS = [True, 2.5, "30"] + _edges(0, 2, 5, 6, 10, 15, 64, MAX_ODEFUN_DPS, 100, 128, 1000, 1737, MAX_ORDER, MAX_DPS - 10, MAX_DPS,
                                  100_000)
# ... for numbers: signs, tolerances near double's and quad's epsilon and 10^-(dps + guard), magnitudes
NUMS = [True, "abc", [1], 0, "0", "-1", "1e-4001", "1e-4000", "1e-401", "1e-300", "1e-41", "1e-40", "1e-35", "1e-17",
        "2.3e-16", "1e-10", "1/2", "0.999", 1, "2", "1e300", "1e308", "1e309", "1e4000", "1e4001"]
PRECS = ["double", "long double", "quad", "binary64", "foo", "30 dps", True, 2.5, 0, 1, MAX_BITS + 1]


def refuses(call, name: str) -> bool:
    """True when ``call()`` raises an error naming the argument ``name`` (in backticks); False when it returns or
    stops at another argument."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PrecisionWarning)
            call()
    except (TypeError, ValueError) as err:
        return f"`{name}" in str(err)
    return False


# -- the API each field feeds -----------------------------------------------------------------------------------
def method_api(name, key):
    """The method run (run_method, at t = 0) with ``key = v`` and the other settings at their defaults."""

    def refused(v):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = run_method(BODY, Y0, 0, {"method": name, key: v})
        if rec.status != "error":
            return False
        assert f"`{key}`" in rec.message, rec.message  # loud, and naming the setting
        return True

    return refused


def _error_vs_order_orders(key):
    def refused(v):
        if isinstance(v, bool) or not isinstance(v, int):
            return True  # the orders are range(min_order, max_order + 1, step): integers only
        orders = orders_of({"orders": None, "max_order": None, "min_order": 1, "step": 1, key: v})
        return refuses(lambda: studies.error_vs_order(BODY, Y0, BAD, orders, dps=MIN_DPS), "orders")

    return refused


def _drift(key):
    # drift() checks precision, t, samples, ensemble, seed and perturbation before it reads y0
    return lambda v: refuses(lambda: studies.drift(BODY, BAD, **{"t": 1, key: v}), key)


def _departure(key):
    # departure_map() checks its settings before it builds the body from `inertia`
    return lambda v: refuses(lambda: studies.departure_map((1, 2, BAD), **{key: v}), key.split("[")[0])


API = {
    ("method", "taylor", "precision"): (PRECS, method_api("taylor", "precision")),
    ("method", "taylor", "tol"): (NUMS, method_api("taylor", "tol")),
    ("method", "lie", "dps"): (INTS, method_api("lie", "dps")),
    ("method", "lie", "tol"): (NUMS, method_api("lie", "tol")),
    ("method", "lie", "order"): (INTS, method_api("lie", "order")),
    ("method", "scipy", "rtol"): (NUMS, method_api("scipy", "rtol")),
    ("method", "scipy", "atol"): (NUMS, method_api("scipy", "atol")),
    # odefun works at about 1.5 dps^2 digits: each accepted value costs up to a second, so only the edges
    ("method", "mpmath", "dps"): ([True, "30", MIN_DPS - 1, MIN_DPS, MAX_ODEFUN_DPS, MAX_ODEFUN_DPS + 1, MAX_DPS],
                                  method_api("mpmath", "dps")),
    ("method", "mpmath", "t_max"): (NUMS, method_api("mpmath", "t_max")),
    ("method", "validated", "dps"): (INTS, method_api("validated", "dps")),
    ("method", "validated", "order"): (INTS, method_api("validated", "order")),
    ("study", "error_vs_order", "dps"): (
        INTS, lambda v: refuses(lambda: studies.error_vs_order(BODY, Y0, BAD, [1, 2], dps=v), "dps")),
    ("study", "error_vs_order", "orders"): (
        [[0], [1], [0, 3], [-1, 3], [MAX_ORDER], [MAX_ORDER + 1], [2.5], [], 3],
        lambda v: refuses(lambda: studies.error_vs_order(BODY, Y0, BAD, v, dps=MIN_DPS), "orders")),
    ("study", "error_vs_order", "max_order"): (INTS, _error_vs_order_orders("max_order")),
    ("study", "error_vs_order", "min_order"): (INTS, _error_vs_order_orders("min_order")),
    ("study", "formulations", "radius_dps"): (
        INTS, lambda v: refuses(lambda: studies.error_vs_order(BODY, Y0, BAD, [1, 2], dps=v), "dps")),
    ("study", "formulations", "radius_max_order"): (INTS, _error_vs_order_orders("max_order")),
    ("study", "work_precision", "repeat"): (
        INTS, lambda v: refuses(lambda: studies.work_precision(BODY, Y0, BAD, repeat=v), "repeat")),
    ("study", "drift", "precision"): (PRECS, _drift("precision")),
    ("study", "drift", "t"): (NUMS, _drift("t")),
    ("study", "drift", "samples"): (INTS, _drift("samples")),
    ("study", "drift", "ensemble"): (INTS, _drift("ensemble")),
    ("study", "drift", "seed"): (INTS, _drift("seed")),
    ("study", "drift", "perturbation"): (NUMS, _drift("perturbation")),
    ("study", "departure_map", "samples"): (INTS, _departure("samples")),
    ("study", "departure_map", "dps"): (INTS, _departure("dps")),
    ("study", "departure_map", "T"): (NUMS, _departure("T")),
    ("study", "departure_map", "threshold"): (NUMS, _departure("threshold")),
    ("study", "departure_map", "precisions"): (
        [["double"], ["quad", "foo"], [], "double", [MAX_BITS + 1]], _departure("precisions")),
    ("study", "departure_map", "grid"): (
        [[1, 1], [64, 128], [65, 1], [1, 129], [0, 1], [1], [2.5, 1]], _departure("grid")),
    ("scene", "stability", "dps"): (
        INTS, lambda v: refuses(lambda: studies.error_vs_order(BODY, Y0, BAD, [1, 2], dps=v), "dps")),
}

#: Fields with no API argument of their own, and why.
NO_API = {
    # the scene's own tables
    ("scene", "run", "t"): "the final time: any nonzero number (magnitude as every number: to_fraction)",
    ("scene", "run", "quick_t"): "the final time in quick mode, as `t`",
    ("scene", "run", "methods"): "a list of method tables: each is checked field by field (the method rows)",
    ("scene", "run", "samples"): "the scene's output grid (the API takes the times themselves)",
    ("scene", "run", "repeat"): "best-of repeats of the scene's timings (run_method takes any count)",
    ("scene", "stability", "analysis"): "how lieseries.stability reads the scene (no engine argument)",
    ("scene", "stability", "headline"): "a row label",
    ("scene", "stability", "headline_model"): "a model label",
    ("scene", "stability", "expect"): "a status name",
    ("scene", "stability", "expect_message"): "a text",
    ("scene", "stability", "threshold"): "saddle analysis: a departure threshold compared by stability itself",
    ("scene", "stability", "beyond"): "divergence analysis: a multiple of the radius, used by stability itself",
    ("scene", "stability", "inside"): "divergence analysis: a fraction of the radius, used by stability itself",
    ("scene", "stability", "orders"): "divergence analysis: orders (checked as the error_vs_order study's)",
    ("scene", "stability", "invariants"): "names of invariants",
    ("scene", "stability", "note"): "a text",
    # studies
    ("study", "error_vs_order", "t"): "the time of the comparison: any nonzero number",
    ("study", "error_vs_order", "t_fraction"): "a fraction of the theoretical radius (the study computes t)",
    ("study", "error_vs_order", "step"): "the step between orders of the scene's range (orders are checked above)",
    ("study", "error_vs_order", "fit_min_order"): "which orders enter the rate fit (any order; none left: no fit)",
    ("study", "work_precision", "t"): "the final time: any nonzero number",
    ("study", "work_precision", "methods"): "method tables, checked as the methods' rows",

    ("study", "drift", "tol"): "heyoka's tolerance: checked against `precision` by the study's check "
                               "(check_tolerance, the API's own), see test_drift_tolerance_is_the_apis",
    ("study", "drift", "first"): "the first sample time, in (0, t): checked by the study's check",
    ("study", "formulations", "t"): "the final time",
    ("study", "formulations", "methods"): "method tables, checked as the methods' rows",
    ("study", "formulations", "formulations"): "names of formulations",
    ("study", "formulations", "chart"): "a chart name",
    ("study", "formulations", "dependent"): "names of dependent coordinates",
    ("study", "formulations", "samples"): "the study's output grid",
    ("study", "formulations", "radius_t"): "the time of the radius measurement: any positive number",
}
# Model kinds and initial families: parse_scene builds every model and initial state with the model's own
# constructor while it loads the scene, so their fields are checked by the API itself at load time (and every
# number by to_fraction, whose magnitude bound is the scene's MAX_MAGNITUDE).
BUILT_AT_LOAD = {("kind", k, f) for k, kind in model_kinds().items() for f in kind.fields} | {
    ("initial", k, f) for k, fam in initial_families().items() for f in fam.fields}


def all_fields() -> dict:
    out = {}
    for section, fields in section_fields().items():
        out.update({("scene", section, k): c for k, (c, _d) in fields.items()})
    for name, m in methods_registry().items():
        out.update({("method", name, k): c for k, (c, _d) in m.fields.items()})
    for name, s in studies_registry().items():
        out.update({("study", name, k): c for k, (c, _d) in s.fields.items()})
    for name, kind in model_kinds().items():
        out.update({("kind", name, k): c for k, (c, _d) in kind.fields.items()})
    for name, fam in initial_families().items():
        out.update({("initial", name, k): c for k, (c, _d) in fam.fields.items()})
    return out


def test_every_field_is_classified():
    fields = set(all_fields())
    classified = set(API) | set(NO_API) | BUILT_AT_LOAD
    assert not (set(API) & set(NO_API))
    assert fields - classified == set(), "new scene fields: add them to API (with their API call) or NO_API"
    assert classified - fields == set(), "classified fields that no longer exist"


#: The required fields of a study's table, given in every probe.
STUDY_BASE = {"error_vs_order": {"t": "1/10"}, "drift": {"t": 1}, "work_precision": {"t": 1},
              "formulations": {"t": 1, "formulations": ["dirac"]}}
#: The model a study's cross-field check sees (the formulations study compares a constrained system's forms).
CIRCLE = ls.ConstrainedSystem("(x_dot**2 + y_dot**2)/2", ["x", "y"], ["x**2 + y**2 - 1"]).dirac()
STUDY_MODEL = {"formulations": CIRCLE}


def _scene_refuses(key, value) -> bool:
    kind, owner, name = key
    try:
        if kind == "method":
            opts = scene_methods(lists=False)([{"method": owner, name: value}], "run.methods")[0]
        elif kind == "study":
            study = studies_registry()[owner]
            data = dict(STUDY_BASE.get(owner, {}), **{name: value})
            opts = F.table(data, f"studies.{owner}", study.fields)
            study.check(opts, None, [("model", None, STUDY_MODEL.get(owner, BODY), Y0)], "model")
        else:
            F.table({name: value}, f"{kind}", section_fields()[owner])
    except F.SceneError:
        return True
    return False


@pytest.mark.parametrize("key", sorted(API), ids=lambda k: ".".join(k))
def test_scene_refuses_what_the_api_refuses(key):
    values, api_refuses = API[key]
    disagree = []
    for v in values:
        s, a = _scene_refuses(key, v), api_refuses(v)
        if s != a:
            disagree.append(f"{v!r}: scene {'refuses' if s else 'accepts'}, API {'refuses' if a else 'accepts'}")
    assert not disagree, "; ".join(disagree)


def test_lie_scene_refuses_an_automatic_order_beyond_the_largest():
    """dps = 5000 without `order` asks lie_integrate for an automatic order above MAX_ORDER: the API refuses it,
    so the scene does too; with an order both accept it."""
    spec = {"method": "lie", "dps": 5000}
    assert refuses(lambda: ls.lie_integrate(BODY, Y0, 0, dps=5000), "dps")
    with pytest.raises(F.SceneError, match="automatic series order"):
        scene_methods(lists=False)([spec], "run.methods")
    assert not refuses(lambda: ls.lie_integrate(BODY, Y0, 0, dps=5000, order=20), "dps")
    scene_methods(lists=False)([dict(spec, order=20)], "run.methods")


@pytest.mark.parametrize("precision,tol", [("double", "1e-17"), ("quad", "1e-35"), ("double", "1e-15")])
def test_taylor_tolerance_is_checked_against_the_precision(precision, tol):
    """A tolerance below the precision's epsilon loads as a scene only if the run accepts it (in lists too)."""
    api = run_method(BODY, Y0, 0, {"method": "taylor", "precision": precision, "tol": tol}).status == "error"
    for lists in (False, True):
        spec = {"method": "taylor", "precision": precision, "tol": [tol] if lists else tol}
        try:
            scene_methods(lists=lists)([spec], "studies.work_precision.methods")
            scene = False
        except F.SceneError:
            scene = True
        assert scene == api


@pytest.mark.parametrize("tol", ["1e-17", "1e-15"])
def test_drift_tolerance_is_the_apis(tol):
    study = studies_registry()["drift"]
    api = refuses(lambda: studies.drift(BODY, Y0, "1/100", samples=6, tol=tol), "tol")
    opts = F.table({"t": "1/100", "tol": tol, "samples": 6}, "studies.drift", study.fields)
    try:
        study.check(opts, None, [("model", None, BODY, Y0)], "model")
        scene = False
    except F.SceneError:
        scene = True
    assert scene == api == (tol == "1e-17")


# -- one precision type ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("spec, name, eps, working", [
    ({"method": "lie", "dps": 20}, "20 dps", 1e-20, 1e-30),  # 10 guard digits between steps
    ({"method": "validated", "dps": 20}, "20 dps", 1e-20, 1e-20 * 2.0**-32),  # 32 guard bits
    ({"method": "mpmath", "dps": 20}, "20 dps", 1e-20, 1e-20),
    ({"method": "taylor", "precision": "quad"}, "quad", 2.0**-112, 2.0**-112),
    ({"method": "scipy"}, "double", 2.0**-52, 2.0**-52),
])
def test_a_run_record_carries_its_precision(spec, name, eps, working):
    """The record's precision is a Precision (eps, guard) read by studies and reports, written as the same text."""
    import pickle

    rec = run_method(BODY, Y0, 0, spec)
    assert rec.status == "success", rec.message
    assert isinstance(rec.precision, ls.Precision)
    assert rec.precision.eps == pytest.approx(eps, rel=1e-12)
    assert rec.precision.working_eps == pytest.approx(working, rel=1e-12)
    assert rec.to_dict()["precision"] == name
    assert pickle.loads(pickle.dumps(rec)).precision == rec.precision


def test_precision_of_names_bits_and_digits():
    P = ls.Precision
    assert P.of("double") is ls.resolve_precision("double") and P.of("binary128").bits == 113
    assert P.of(200).name == "real200" and P.of(200).eps == 2.0**-199
    d = P.of(dps=50)
    assert (d.name, d.dps, d.eps, d.is_decimal) == ("50 dps", 50, 1e-50, True)
    assert d.bits >= 50 * 3.3219 and not P.of("quad").is_decimal
    with pytest.raises(ValueError, match="`dps`"):
        P.of(dps=MAX_DPS + 1)
    with pytest.raises(TypeError, match="not both"):
        P.of("double", dps=30)
