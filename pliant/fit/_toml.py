"""A small TOML writer for scene configs (the standard library reads TOML but cannot write it)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..io import atomic_write_text

if TYPE_CHECKING:
    from ..scene import SceneConfig


def _value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"TOML cannot hold {v}")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(a) for a in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(a)}" for k, a in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def _is_table(v: object) -> bool:
    return isinstance(v, dict)


def _is_table_array(v: object) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(a, dict) for a in v)


def _table(lines: list[str], name: str, data: dict[str, Any], header: str) -> None:
    scalars = {k: v for k, v in data.items() if not _is_table(v) and not _is_table_array(v)}
    if header:
        lines.append("")
        lines.append(header)
    for k, v in scalars.items():
        lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in data.items():
        sub = f"{name}.{_key(k)}" if name else _key(k)
        if _is_table(v):
            _table(lines, sub, v, f"[{sub}]")
        elif _is_table_array(v):
            for item in v:
                _table(lines, sub, item, f"[[{sub}]]")


def dumps(data: dict[str, Any], comment: str = "") -> str:
    """TOML text of nested dicts / lists / scalars (None values must be removed first)."""
    lines = [f"# {c}" for c in comment.splitlines()] if comment else []
    _table(lines, "", data, "")
    return "\n".join(lines).lstrip("\n") + "\n"


def scene_toml(cfg: SceneConfig, path: str | Path, comment: str = "") -> Path:
    """Write a scene config as a TOML file runnable by ``pliant run``.

    Fields left at their defaults are omitted; relative file paths of the scene (meshes, point files, a
    ``[gaussians]`` PLY) are made absolute, since the new file may live in another folder.
    """
    data = cfg.model_dump(mode="json", exclude_unset=True, exclude_none=True)
    base = Path(cfg.base_dir)
    for section in ("objects", "colliders"):
        for item in data.get(section, []):
            for key in ("path",):
                if isinstance(item.get(key), str) and not Path(item[key]).is_absolute():
                    item[key] = str((base / item[key]).resolve())
            rm = item.get("render_mesh")
            if (
                isinstance(rm, dict)
                and isinstance(rm.get("path"), str)
                and not Path(rm["path"]).is_absolute()
            ):
                rm["path"] = str((base / rm["path"]).resolve())
    g = data.get("gaussians")  # a [gaussians] PLY, relative to the scene file
    if isinstance(g, dict) and isinstance(g.get("ply"), str) and not Path(g["ply"]).is_absolute():
        g["ply"] = str((base / g["ply"]).resolve())
    return atomic_write_text(path, dumps(data, comment))  # a kill never leaves half a scene


__all__ = ["dumps", "scene_toml"]
