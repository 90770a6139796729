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
