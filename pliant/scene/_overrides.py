"""``--set PATH=VALUE``: replace one field of a scene's TOML data before it is validated, so an override
is checked (and reported) exactly like the same value written in the file."""

from __future__ import annotations

import re
import sys
from collections.abc import Sequence
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

_PART = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")


def parse_value(text: str) -> Any:
    """A TOML value (``200``, ``1e5``, ``true``, ``[0, 1, 0]``, ``"RK4"``), else the text as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def split_path(path: str) -> list[str | int]:
    """``objects[0].material.E`` → ``["objects", 0, "material", "E"]``.

    Raises:
        ValueError: a path that is not dotted names with optional ``[index]`` parts.
    """
    out: list[str | int] = []
    for part in path.split("."):
        m = _PART.fullmatch(part)
        if m is None:
            raise ValueError(
                f"cannot read the field path {path!r}; write names joined by '.', with [N] for the N-th "
                "entry of a list, e.g. objects[0].material.stiffness"
            )
        out.append(m.group(1))
        out += [int(i) for i in re.findall(r"\[(\d+)\]", m.group(2))]
    return out


def apply_overrides(data: dict[str, Any], overrides: Sequence[str]) -> list[tuple[str, str]]:
    """Set each ``PATH=VALUE`` of ``overrides`` in the TOML ``data`` (in place); tables on the way are
    created. Returns the problems as (path, message) pairs; an empty list when all applied."""
    problems: list[tuple[str, str]] = []
    for item in overrides:
        path, eq, value = item.partition("=")
        path = path.strip()
        if not eq or not path:
            problems.append(("--set", f"expected PATH=VALUE, got {item!r} (e.g. scene.frames=10)"))
            continue
        try:
            parts = split_path(path)
        except ValueError as exc:
            problems.append(("--set", str(exc)))
            continue
        node: Any = data
        where = ""
        for k, key in enumerate(parts):
            last = k == len(parts) - 1
            if isinstance(key, int):
                if not isinstance(node, list):
                    problems.append((where, "is not a list; drop the [index]"))
                    break
                if key >= len(node):
                    n = len(node)
                    has = f"{n} entr{'y' if n == 1 else 'ies'} (0..{n - 1})" if n else "no entries"
                    problems.append((where, f"index {key} out of range; the scene has {has}"))
                    break
                where += f"[{key}]"
            else:
                if not isinstance(node, dict):
                    problems.append((where, f"is a value, not a table; it has no field {key!r}"))
                    break
                where += ("." if where else "") + key
            if last:
                node[key] = parse_value(value.strip())
            else:
                if isinstance(key, str) and key not in node:
                    node[key] = [] if isinstance(parts[k + 1], int) else {}
                node = node[key]
    return problems
