"""The one cache (lieseries.cache): clearing it makes every build a scene's own, its bounds and eviction order,
and the pool of integrator copies shared by single runs and ensembles."""

import math
import threading

import heyoka as hy
import numpy as np
import pytest

import lieseries as ls
from lieseries.ensemble import build_batch_integrator
from lieseries.taylor import build_integrator, clear_cache
from lieseries.poisson import as_poisson_system


def _oscillator():
    """q' = p, p' = -q: q(t) = q0 cos t + p0 sin t, p(t) = p0 cos t - q0 sin t (compiles in milliseconds)."""
    q, p = hy.make_vars("q", "p")
    return ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p * p + q * q) / 2, name="oscillator")


def _exact(y0, t):
    q0, p0 = y0
    return np.array([q0 * math.cos(t) + p0 * math.sin(t), p0 * math.cos(t) - q0 * math.sin(t)])


def test_a_repeated_call_after_clear_cache_reports_its_own_build():
    # who times builds empties the cache first: a call repeated from earlier work (memoised) must build again,
    # not report the earlier build as cached
    osc = _oscillator()
    y0 = np.array([1.0, 0.5])
    first = ls.integrate(osc, y0, 2.0)
    again = ls.integrate(osc, y0, 2.0)
    assert again.stats.cached
    clear_cache()
    after = ls.integrate(osc, y0, 2.0)
    assert not after.stats.cached and after.stats.build_time > 0
    for sol in (first, again, after):
        assert sol.status == "success"
        np.testing.assert_allclose(np.asarray(sol.y[-1], dtype=float), _exact(y0, 2.0), rtol=0, atol=1e-13)


def test_clear_cache_forgets_the_ensemble_integrators_too():
    osc = _oscillator()
    ta, build, _ = build_batch_integrator(osc, batch_size=2)
    assert build_batch_integrator(osc, batch_size=2)[1] == 0.0  # cached
    clear_cache()
    ta2, build2, _ = build_batch_integrator(osc, batch_size=2)
    assert build2 > 0 and ta2 is not ta
    Y0 = np.array([[1.0, 0.0], [0.0, 1.0], [0.3, -0.2]])
    sol = ls.integrate(osc, Y0, 1.5, batch_size=2)
    for i in range(3):
        np.testing.assert_allclose(np.asarray(sol.y_reached[i], dtype=float), _exact(Y0[i], 1.5), rtol=0, atol=1e-13)


def test_run_scene_keeps_what_the_process_built_and_reports_it_as_built_earlier(tmp_path):
    # a scene uses the integrators the process holds (no rebuild); a run whose integrator was built before reports
    # a build time of 0, and the report says what 0 means
    from lieseries import cache, run

    first = run.run_scene("default", quick=True, progress=False)
    held = cache.info()["taylor.integrators"]
    assert held >= 1
    second = run.run_scene("default", quick=True, progress=False)
    assert cache.info()["taylor.integrators"] == held
    heyoka_rows = [r for r in second.run["rows"] if r.build_time is not None and r.method == "taylor"]
    assert heyoka_rows and all(r.build_time == 0 for r in heyoka_rows)
    assert [r.error for r in first.run["rows"]] == [r.error for r in second.run["rows"]]
    from lieseries.report import write_report

    assert "0 when it had been built earlier in the process" in write_report(second, tmp_path / "r").read_text()


def test_a_region_is_bounded_and_evicts_the_least_recently_used():
    from lieseries import cache

    evicted = []
    reg = cache.region("test.lru", 3, on_evict=evicted.append)
    reg.clear()
    evicted.clear()
    for k in "abc":
        assert reg.put(k, k.upper()) == k.upper()
    assert reg.put("a", "other") == "A"  # a key already cached keeps its value
    reg.touch("a")  # a is now the most recently used: b is the oldest
    reg.put("d", "D")
    assert evicted == ["B"] and sorted(reg.data) == ["a", "c", "d"] and reg.get("b") is None
    reg.put("e", "E")
    assert evicted == ["B", "C"] and len(reg) == 3
    reg.clear()
    assert len(reg) == 0 and cache.info()["test.lru"] == 0


def test_the_cache_is_bounded_by_build_cost(monkeypatch):
    from lieseries import cache

    cache.clear()
    monkeypatch.setattr(cache, "MAX_COST", 10.0)
    reg = cache.region("test.cost", 100)
    cheap = cache.region("test.cheap", 100)
    reg.put("x", 1, cost=6.0)
    cheap.put("free", 0)  # no cost: never evicted for cost
    reg.put("y", 2, cost=3.0)
    reg.touch("x")  # x used last: y is the least recently used costly entry
    reg.put("z", 3, cost=4.0)  # 13 s > 10 s: y goes
    assert reg.get("y") is None and reg.get("x") == 1 and reg.get("z") == 3 and cheap.get("free") == 0
    assert cache.info()["cost"] == pytest.approx(10.0)
    cache.clear()
    assert cache.info()["cost"] == 0 and len(reg) == 0 and len(cheap) == 0


def test_the_pool_lends_copies_never_the_template_and_drops_them_with_it():
    from lieseries import cache

    clear_cache()
    osc = _oscillator()
    template = build_integrator(osc, "double")[0]
    ta, free = cache.checkout(template)
    assert ta is not template
    ta.time, ta.state[:] = 0.0, [1.0, 0.0]
    ta.propagate_until(1.0)
    np.testing.assert_allclose(ta.state, _exact((1.0, 0.0), 1.0), rtol=0, atol=1e-13)
    assert template.time == 0.0  # the template never ran
    cache.release(ta, free)
    assert cache.checkout(template)[0] is ta  # the copy comes back
    lent = [cache.checkout(template) for _ in range(cache.MAX_FREE + 3)]  # more runs at once than free copies
    assert len({id(c) for c, _ in lent}) == len(lent) and all(c is not template for c, _ in lent)
    for c, fr in lent:
        cache.release(c, fr)
    assert len(cache.free_copies(template)) == cache.MAX_FREE  # the extra copies are not kept
    clear_cache()
    assert cache.free_copies(template) == [] and cache.info()["pooled"] == 0


def test_threads_share_the_pool_and_get_the_serial_answer():
    clear_cache()
    osc = _oscillator()
    rows = [np.array([math.cos(0.1 * i), math.sin(0.1 * i)]) for i in range(12)]
    serial = [np.asarray(ls.integrate(osc, y, 3.0).y[-1], dtype=float) for y in rows]
    out = [None] * len(rows)

    def work(j):
        for i in range(j, len(rows), 4):
            out[i] = np.asarray(ls.integrate(osc, rows[i], 3.0).y[-1], dtype=float)

    threads = [threading.Thread(target=work, args=(j,)) for j in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    for i, y in enumerate(rows):
        assert np.array_equal(out[i], serial[i])  # bit for bit: the same compiled code, a private copy each
        np.testing.assert_allclose(out[i], _exact(y, 3.0), rtol=0, atol=1e-13)


def _harmonics(c):
    """A pendulum of amplitude ``c`` with 29 small dyadic harmonics written before it: ~210 operations, and a field
    that heyoka prints cut short, so that fields with other ``c`` print the same."""
    q, p = hy.make_vars("q", "p")
    H = p * p / 2 - sum(hy.cos(k * q) / 2 ** (k // 4 + 4) for k in range(2, 31)) - c * hy.cos(q)
    return ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], H, name=f"harmonics ({c})")


def test_fields_that_print_the_same_are_not_taken_for_one_another():
    # heyoka prints ~1000 characters of an expression: a cache keyed by the printed field ran the second system with
    # the first one's integrator (status success, p off by 0.37 at t = 2). Each run against the Lie engine at 30
    # digits.
    a, b = _harmonics(1), _harmonics(2)
    assert [str(e) for e in a.vector_field] == [str(e) for e in b.vector_field]  # what fooled the text key
    assert a.key != b.key
    for system in (a, b, a):
        sol = ls.integrate(system, np.array([0.5, 0.0]), 2.0)
        ref = ls.lie_integrate(system, ["0.5", 0], t=2, dps=30)
        assert sol.status == "success" and ref.status == "success"
        np.testing.assert_allclose(np.asarray(sol.y_final, dtype=float), np.asarray(ref.y_final, dtype=float),
                                   rtol=0, atol=1e-13)


def test_a_field_with_a_large_decomposition_compiles_in_compact_mode_in_double():
    # unrolled, LLVM's time grows as the square of the field's operations (a torus in a local chart, ~1400: 248 s);
    # compact it takes a fraction of a second. The harmonics (~210 operations) are compiled compact for a single run
    # and for an ensemble, the rigid body (57) unrolled.
    from lieseries.heyoka_build import compact_by_default

    many = _harmonics(1)
    assert compact_by_default(many, "double")
    assert build_integrator(many)[0].compact_mode
    assert build_batch_integrator(many, batch_size=2)[0].compact_mode
    body = ls.EulerPoisson((1, 2, 3))
    assert not compact_by_default(body, "double") and not build_integrator(body)[0].compact_mode


def _nested(depth):
    """q' = p, p' = sin(cos(sin(...cos(q)))) with ``depth`` calls, as an extra field: printed whole in ~5 characters
    a call, two operations a call in heyoka's decomposition (each sine brings its cosine)."""
    q, p = hy.make_vars("q", "p")
    e = q
    for i in range(depth):
        e = hy.sin(e) if i % 2 else hy.cos(e)
    return ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2, extra_field=[0, e], name=f"nested {depth}")


def _decomposition_size(system):
    """heyoka's own count of a field's elementary operations (a compact build)."""
    ps = as_poisson_system(system)
    probe = hy.taylor_adaptive(ps.ode_system, [0.0] * ps.dimension, pars=[0.0] * len(ps.parameter_values),
                               compact_mode=True, tol=0.1)
    return len(probe.decomposition) - 2 * ps.dimension


def test_a_field_that_prints_short_but_decomposes_large_is_compiled_compact():
    # 100 nested calls print in ~500 characters (the text's length had let it compile unrolled, LLVM's time growing
    # as the square of its ~200 operations); the printed operators bound the count, whatever the text's length
    from lieseries.heyoka_build import UNROLLED_OPERATIONS, compact_by_default, operations_bound

    deep = _nested(100)
    text = [str(e) for e in deep.vector_field]
    assert sum(map(len, text)) < 1000 and not any("..." in t for t in text)  # the premise: short, printed whole
    assert _decomposition_size(deep) > UNROLLED_OPERATIONS
    assert compact_by_default(deep, "double") and build_integrator(deep)[0].compact_mode
    # the bound is at least heyoka's count, from every kind of call to the models
    q, p = hy.make_vars("q", "p")
    calls = (hy.atan(q) * hy.tan(p) + hy.sinh(q) * hy.exp(-q) + q ** hy.expression(2.5) + hy.log(1 + q * q)
             + hy.sqrt(1 + p ** 4) + hy.cosh(p) / (2 + hy.tanh(q)) - q * p * q * p * q * p * q + hy.cos(3 * q) ** 3)
    fields = [_nested(10), _nested(60), ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + calls),
              ls.EulerPoisson((1, 2, 3)), ls.Sphere(), ls.SphericalPendulum(), ls.PlanarPendulum()]
    q2 = [hy.make_vars(f"x{i}") for i in range(8)]
    signs = ((-q2[0] * -q2[1]) * (-q2[3] * -q2[7]) + (hy.pi * -q2[0]) * q2[3] + (-q2[1] * -q2[7])) ** 3
    fields.append(ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2, extra_field=[0, (q + 1) ** 57 + q ** 41]))
    fields.append(ls.PoissonSystem(q2, [[int(j == i + 4) - int(i == j + 4) for j in range(8)] for i in range(8)],
                                   signs, name="negations and pi"))
    for system in fields:
        ps = as_poisson_system(system)
        text = [str(e) for _, e in ps.ode_system]  # (what heyoka compiles: integer powers as products)
        bound = sum(map(operations_bound, text))
        assert bound >= _decomposition_size(ps) or any("..." in t for t in text), system
    assert not compact_by_default(_nested(60), "double")  # 122 operations: unrolled, as the rigid body


def test_the_command_line_keeps_its_own_bounded_heyoka_cache(tmp_path, monkeypatch):
    # heyoka's default disk cache is one for every program of the user, up to 20 GiB, read whole the first time a
    # process compiles (at 11 GB the default scene's first build took 26 s): the command line uses its own, bounded,
    # unless HEYOKA_CACHE_DIR says where; a library call never moves it
    from lieseries import cli
    from lieseries.heyoka_build import OWN_CACHE_BYTES, use_own_disk_cache

    state = hy.llvm_state
    before = (str(state.get_diskcache_path()), state.get_diskcache_limit())
    try:
        monkeypatch.setenv("HEYOKA_CACHE_DIR", before[0])
        assert use_own_disk_cache() is None and str(state.get_diskcache_path()) == before[0]
        monkeypatch.delenv("HEYOKA_CACHE_DIR")
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
        own = tmp_path / "lieseries" / "heyoka"
        assert use_own_disk_cache() == str(own) and str(state.get_diskcache_path()) == str(own)
        assert state.get_diskcache_limit() == OWN_CACHE_BYTES and own.is_dir()
        state.set_diskcache_path(before[0])
        calls = []
        monkeypatch.setattr("lieseries.heyoka_build.use_own_disk_cache", lambda: calls.append(1))
        assert cli.main(["run", "missing-scene-name", "--no-progress"]) == 2 and calls == [1]
    finally:
        state.set_diskcache_path(before[0])
        state.set_diskcache_limit(before[1])


def test_an_ensemble_takes_equal_fields_written_with_other_sharing():
    # the key is a digest of the field as built: q2 * q2 with q2 = q * q beside (q * q) * (q * q) gets another one,
    # and the ensemble refused the pair as "another structure"; each member against its own single run
    q, p = hy.make_vars("q", "p")
    q2 = q * q
    a = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + hy.par[0] * q2 * q2, parameters=["0.1"])
    b = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + hy.par[0] * (q * q) * (q * q), parameters=["0.2"])
    assert a.key != b.key
    ens = ls.integrate([a, b], [np.array([0.5, 0.0])] * 2, 1.0)
    for i, system in enumerate((a, b)):
        single = ls.integrate(system, np.array([0.5, 0.0]), 1.0)
        assert ens.status[i] == "success" == single.status
        np.testing.assert_allclose(np.asarray(ens.y_reached[i], dtype=float), single.y_final, rtol=0, atol=1e-15)
    other = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], p * p / 2 + hy.par[0] * q2 * q, parameters=["0.1"])
    with pytest.raises(ValueError, match=r"`system\[1\]` has another structure"):
        ls.integrate([a, other], [np.array([0.5, 0.0])] * 2, 1.0)
