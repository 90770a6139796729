"""The Python examples in the README and the tutorial run as written (docs that match the code)."""

import contextlib
import io
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(path):
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


@pytest.mark.parametrize("doc", ["README.md", "docs/tutorial.md"])
def test_examples_run(doc, tmp_path, monkeypatch):
    blocks = python_blocks(ROOT / doc)
    assert blocks, f"{doc} has no python examples"
    monkeypatch.chdir(tmp_path)
    namespace = {}
    with contextlib.redirect_stdout(io.StringIO()):
        for i, code in enumerate(blocks):
            try:
                exec(compile(code, f"{doc}[block {i}]", "exec"), namespace)
            except Exception as err:  # pragma: no cover - the message says which block
                raise AssertionError(f"{doc}, python block {i} failed: {err!r}\n{code}") from err


def test_tutorial_quoted_numbers_are_what_the_code_gives():
    """The numbers the tutorial quotes in comments are those its code produces (to the digits quoted)."""
    import warnings

    import lieseries as ls

    text = (ROOT / "docs" / "tutorial.md").read_text()
    body = ls.EulerPoisson(inertia=(1, 2, 3))
    y0 = body.initial_state(omega=(1, "0.1", "0.5"))
    # section 1: steps and order of the double run
    m = re.search(r"print\(sol.status, sol.stats.steps, sol.stats.order\)\s+# success (\d+) (\d+)", text)
    sol = ls.integrate(body, y0, t=[5, 10, 20])
    assert (sol.stats.steps, sol.stats.order) == (int(m.group(1)), int(m.group(2)))
    # section 5: the M2 crossings, to the two decimals quoted
    m = re.search(r"times where M2 = 0: about ([0-9., ]+)", text)
    quoted = [float(v) for v in m.group(1).split(",")]
    sol = ls.integrate(body, y0, t=30, events=[ls.Event(body.poisson.variables[10], name="m2")])
    assert [round(float(v), 2) for v in sol.events["m2"]["t"]] == quoted
    # section 6: where the damped body's run stops, to the digits quoted
    m = re.search(r'# "Tiny steps: near t = ([0-9.e+-]+) \(last step size ([0-9.e+-]+)\)', text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        damped = ls.DampedEulerPoisson((1, 2, 3), damping=1e5)
        sol = ls.integrate(damped, damped.initial_state((1, "0.1", "0.5")), t=20)
    got = re.search(r"near t = ([0-9.e+-]+) \(last step size ([0-9.e+-]+)\)", sol.message)
    assert sol.status == "step_collapse"
    assert float(got.group(1)) == pytest.approx(float(m.group(1)), rel=5e-3)
    assert float(got.group(2)) == pytest.approx(float(m.group(2)), rel=5e-3)
