"""Scene errors and their ``file:line: field: what is wrong; what to do`` formatting."""

from __future__ import annotations

import re
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

from ._registry import COLLIDER_KINDS, OBJECT_KINDS
from ._schema import HandleConfig, SceneConfig


class SceneError(ValueError):
    """A scene file is unreadable or invalid; ``problems`` holds ``(line, field path, message)`` each."""

    def __init__(self, file: str, problems: list[tuple[int | None, str, str]]) -> None:
        self.file = file
        self.problems = problems
        lines = []
        for line, path, msg in problems:
            where = f"{file}:{line}" if line else file
            lines.append(f"{where}: {path}: {msg}" if path else f"{where}: {msg}")
        super().__init__("\n".join(lines))


def _unions() -> dict[str, tuple[tuple[str, ...], dict[str, Any]]]:
    """Tagged lists: section -> (allowed kinds, schema of each kind)."""
    return {
        sec: (tuple(reg), {k: v.schema for k, v in reg.items()})
        for sec, reg in (("objects", OBJECT_KINDS), ("colliders", COLLIDER_KINDS))
    }


def fmt_path(loc: tuple) -> str:
    """Dotted field path (``objects[1].material.E``) of a pydantic error location (union tags dropped)."""
    unions = _unions()
    out = ""
    skip_tag = False
    for part in loc:
        if skip_tag:
            skip_tag = False
            if part in unions[str(loc[0])][0]:
                continue
        if isinstance(part, int):
            out += f"[{part}]"
            skip_tag = str(loc[0]) in unions and out.startswith(str(loc[0])) and out.count("[") == 1
        else:
            out += ("." if out else "") + str(part)
    return out


def _allowed_fields(loc: tuple) -> list[str]:
    """Field names allowed next to the unknown one at ``loc`` (for "unknown field" messages)."""
    unions = _unions()
    model: type[BaseModel] = SceneConfig
    parts = list(loc[:-1])
    i = 0
    while i < len(parts):
        p = parts[i]
        if p in unions and i == 0:
            i += 2  # index
            kind = parts[i] if i < len(parts) else None
            kinds, models = unions[p]
            model = models[kinds[0]] if kind is None else models.get(kind, models[kinds[0]])
            i += 1
            continue
        if p == "handles" and i == 0:
            model = HandleConfig
            i += 2
            continue
        f = model.model_fields.get(p) if hasattr(model, "model_fields") else None
        if f is None:
            return []
        ann = f.annotation
        for cand in (ann, *getattr(ann, "__args__", ())):
            if isinstance(cand, type) and issubclass(cand, BaseModel):
                model = cand
                break
        else:
            return []
        i += 1
    excluded = {"source", "base_dir", "text"}
    return [k for k in model.model_fields if k not in excluded]


def _message(err: ErrorDetails) -> tuple[tuple, str]:
    loc, typ, msg = tuple(err["loc"]), err["type"], err["msg"]
    ctx = err.get("ctx") or {}
    got = err.get("input")
    kinds = _unions().get(str(loc[0]) if loc else "", (tuple(OBJECT_KINDS), {}))[0]
    if typ == "union_tag_invalid":
        return loc + ("kind",), f"unknown kind {ctx.get('tag')!r}; allowed: {', '.join(kinds)}"
    if typ == "union_tag_not_found":
        return loc + ("kind",), f"missing required field 'kind'; allowed: {', '.join(kinds)}"
    if typ == "missing":
        if len(loc) >= 3 and str(loc[0]) in _unions() and isinstance(loc[2], str):
            return loc, f"missing required field {loc[-1]!r} (a {loc[2]} in {loc[0]} needs it)"
        return loc, f"missing required field {loc[-1]!r}" if loc else "missing required field"
    if typ == "extra_forbidden":
        allowed = _allowed_fields(loc)
        hint = f"; allowed: {', '.join(allowed)}" if allowed else ""
        return loc[:-1] + (loc[-1],), f"unknown field {loc[-1]!r}{hint}"
    if typ == "literal_error":
        allowed = re.findall(r"'([^']*)'", ctx.get("expected", ""))
        return loc, f"got {_short(got)}; allowed: {', '.join(allowed)}"
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    elif got is not None:
        msg = f"{msg[0].lower()}{msg[1:]}, got {_short(got)}"
    return loc, msg


def _short(v: object) -> str:
    """``repr(v)``, cut to 80 characters (a fuzzed 1 MB string must not flood the terminal)."""
    r = repr(v)
    return r if len(r) <= 80 else r[:77] + "..."


def line_of(text: str, path: str) -> int | None:
    """Best-effort line number of the field at dotted ``path`` in TOML ``text`` (1-based)."""
    parts = re.findall(r"([A-Za-z_][\w-]*)|\[(\d+)\]", path)
    keys: list[str | int] = [int(i) if i else k for k, i in parts]
    if not keys or not text:
        return None
    lines = text.splitlines()
    header = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?")
    section = str(keys[0])
    rest = keys[1:]
    index = None
    if rest and isinstance(rest[0], int):
        index, rest = rest[0], rest[1:]
    # Find the block [section] or the index-th [[section]].
    count, start = -1, None
    for n, ln in enumerate(lines):
        m = header.match(ln)
        if m and m.group(1) == section:
            count += 1
            if index is None or count == index:
                start = n
                break
    if start is None:
        for n, ln in enumerate(lines):  # inline form: section = ... at top level
            if re.match(rf"^\s*{re.escape(section)}\s*=", ln):
                return n + 1
        return None
    end = next((n for n in range(start + 1, len(lines)) if header.match(lines[n])), len(lines))
    best = start
    sub = [k for k in rest if isinstance(k, str)]
    if sub:
        # A sub-table [section.material] after the block, or the key inside the block.
        for n in range(start + 1, len(lines)):
            m = header.match(lines[n])
            if m and m.group(1) == f"{section}.{sub[0]}" and len(sub) > 1:
                stop = next((k for k in range(n + 1, len(lines)) if header.match(lines[k])), len(lines))
                for k in range(n + 1, stop):
                    if re.match(rf"^\s*{re.escape(sub[1])}\s*=", lines[k]):
                        return k + 1
                return n + 1
            if m and not m.group(1).startswith(section + "."):
                break
        for n in range(start + 1, end):
            if re.match(rf"^\s*{re.escape(sub[0])}\s*=", lines[n]):
                return n + 1
    return best + 1


def problems_from(exc: ValidationError, text: str) -> list[tuple[int | None, str, str]]:
    """``(line, path, message)`` of each pydantic error."""
    out = []
    for err in exc.errors():
        loc, msg = _message(err)
        path = fmt_path(loc)
        out.append((line_of(text, path), path, msg))
    return sorted(out, key=lambda p: p[0] or 0)


def scene_error(cfg: SceneConfig, path: str, msg: str) -> SceneError:
    """A one-problem SceneError for the field at ``path`` of the loaded scene ``cfg``."""
    return SceneError(cfg.source, [(line_of(cfg.text, path), path, msg)])
