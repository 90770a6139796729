"""Writing report files: CSV tables and data.json (numbers as floats, anything else as text)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from ..formatting import fmt_sci

__all__ = ["write_csv", "write_json", "json_default"]


def write_csv(path: Path, headers, rows) -> None:
    """One table as CSV (None as an empty cell)."""
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(headers)
        for r in rows:
            w.writerow(["" if c is None else c for c in r])


def json_default(o):
    """Numbers that are not Python floats as floats; one beyond a float's range (an error of 1e-402 from a run
    at 400 digits) as text in scientific notation, not as the 0.0 or inf its float would be; anything else as
    text."""
    try:
        f = float(o)
    except (TypeError, ValueError):
        return str(o)
    except OverflowError:
        f = math.inf
    if (f == 0 and o != 0) or (math.isinf(f) and fmt_sci(o) not in ("inf", "-inf")):
        return fmt_sci(o, 17)
    return f


def write_json(path: Path, data) -> None:
    """``data`` as compact JSON (numbers that are not Python floats as floats, anything else as text)."""
    with open(path, "w", encoding="utf-8") as f:
        json.dump(data, f, separators=(",", ":"), default=json_default)
