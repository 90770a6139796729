"""docs/scenes.md: the reference of the scene format, generated from the schema and the registries."""

from __future__ import annotations

from ..fields import MAX_MAGNITUDE
from .schema import field_docs, schema_defaults

__all__ = ["scene_reference"]


def scene_reference() -> str:
    """docs/scenes.md: every field of the scene format with its type, default and meaning."""
    heads = {"": "Top level", "run": "[run]", "report": "[report]", "stability": "[stability]"}
    lines = [
        "# Scene format",
        "",
        "A scene is a TOML file that says what to integrate, how, and which studies and plots its report needs;",
        "nothing more is computed. `lieseries run FILE.toml` runs one; `lieseries scenes` lists the built-in ones",
        "(`lieseries/data/scenes/`). Numbers may be strings, read exactly (`\"0.1\"` is 1/10); every number lies",
        f"within 1e-{MAX_MAGNITUDE} .. 1e{MAX_MAGNITUDE} in magnitude. An unknown or invalid field is refused with",
        "its dotted path (`run.methods[1].precision`). A TOML float such as `0.1` is a double (0.1000000000000000055...):",
        "the runs and the reference start from that binary value, and the scene's data list it",
        "(`Scene.binary_inputs()`: `initial.omega[1]`); `1`, `0.5` and other short binary numbers are exact.",
        "",
        "`lieseries run SCENE --quick` runs a scaled-down plan for CI (`effective_plan`: shorter times, fewer",
        "samples and orders, validated runs at most 30 digits); its report lists every setting it changed",
        "(`run.methods[0].dps: 50 -> 30`), since the scene's title and description speak of the full run.",
        "",
        "This page is generated from the schema in `lieseries/scenes/` and the registries of model kinds, methods and",
        "studies (`scene_reference()`), and a test checks that the two agree.",
        "",
    ]
    schema = schema_defaults()
    docs = field_docs()
    for section, fields in schema.items():
        kind = section.split(".", 1)
        if section in heads:
            title = heads[section]
        elif kind[0] == "model":
            title = f"[model] kind = \"{kind[1]}\""
        elif kind[0] == "initial":
            title = f"[initial] for {kind[1].replace('_', ' ')} models"
        elif kind[0] == "method":
            title = f"a method table: method = \"{kind[1]}\" (`label` optional)"
        else:
            title = f"[{section}]"
        lines += [f"## {title}", "", "| field | type | default | meaning |", "|---|---|---|---|"]
        for field, default in fields.items():
            typ, meaning = docs[section][field]
            shown = "required" if default == "required" else ("-" if default is None else f"`{default!r}`")
            lines.append(f"| `{field}` | {typ} | {shown} | {meaning} |")
        lines.append("")
    return "\n".join(lines)
