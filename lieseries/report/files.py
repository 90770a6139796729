"""Writing report files: CSV tables and data.json (numbers as floats, anything else as text)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

__all__ = ["write_csv", "write_json", "json_default"]


def write_csv(path: Path, headers, rows) -> None:
    """One table as CSV (None as an empty cell)."""
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(headers)
        for r in rows:
            w.writerow(["" if c is None else c for c in r])


def json_default(o):
    try:
        return float(o)
    except (TypeError, ValueError):
        return str(o)


def write_json(path: Path, data) -> None:
    """``data`` as compact JSON (numbers that are not Python floats as floats, anything else as text)."""
    with open(path, "w", encoding="utf-8") as f:
        json.dump(data, f, separators=(",", ":"), default=json_default)
