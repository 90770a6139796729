"""Finding scenes: the built-in ones (package data), the extreme and stiff cases, files by path."""

from __future__ import annotations

import difflib
import os
import tomllib
from pathlib import Path

from ..fields import SceneError
from .schema import EXTREME_FOLDER, Scene, parse_scene

__all__ = ["scenes_dir", "builtin_scenes", "extreme_scenes", "load_scene"]


def scenes_dir() -> Path:
    """The folder of the built-in scenes (``LIESERIES_SCENES`` overrides it)."""
    env = os.environ.get("LIESERIES_SCENES")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1] / "data" / "scenes"  # package data: the same in every install


def builtin_scenes() -> list:
    """[(name, title)] of the built-in scenes, sorted by name (``default`` first)."""
    out = _titles(scenes_dir())
    out.sort(key=lambda nt: (nt[0] != "default", nt[0]))
    return out


def extreme_scenes() -> list:
    """[(name, title)] of the extreme and stiff cases (``lieseries/data/scenes/extreme/*.toml``), sorted by name."""
    return _titles(scenes_dir() / EXTREME_FOLDER)


def _titles(folder: Path) -> list:
    """[(name, title)] of the scene files in ``folder``, sorted by name."""
    out = []
    if folder.is_dir():
        for p in sorted(folder.glob("*.toml")):
            try:
                data = tomllib.loads(p.read_text(encoding="utf-8"))
                out.append((p.stem, str(data.get("title", ""))))
            except (OSError, tomllib.TOMLDecodeError):
                out.append((p.stem, "(unreadable scene file)"))
    return out


def load_scene(name_or_path) -> Scene:
    """A built-in scene (or an extreme case, see :func:`extreme_scenes`) by name, or a scene file by path.

    Raises
    ------
    SceneError
        Unknown name, unreadable file, invalid scene.
    """
    if isinstance(name_or_path, Scene):
        return name_or_path
    s = str(name_or_path)
    p = Path(s)
    looks_like_path = s.endswith(".toml") or os.sep in s or "/" in s
    if not looks_like_path:
        cand = scenes_dir() / f"{s}.toml"
        extreme = scenes_dir() / EXTREME_FOLDER / f"{s}.toml"
        if cand.is_file():
            p = cand
        elif extreme.is_file():
            p = extreme
        else:
            names = [n for n, _ in builtin_scenes()] + [n for n, _ in extreme_scenes()]
            near = difflib.get_close_matches(s, names, n=1)
            hint = f" (did you mean '{near[0]}'?)" if near else ""
            known = ", ".join(names) or f"none found in {scenes_dir()}"
            raise SceneError(f"unknown scene {s!r}{hint}; built-in scenes: {known}; or give the path of a .toml file")
    if p.is_dir():
        raise SceneError(f"`{s}` is a folder, not a scene file; pass a scene name (`lieseries scenes` lists them) "
                         "or the path of a .toml file")
    if not p.is_file():
        raise SceneError(f"scene file {s!r} not found")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise SceneError(f"cannot read scene file {s!r}: {err}") from None
    return parse_scene(text, source=str(p), path=str(p))
