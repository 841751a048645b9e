"""The ``[[colliders]]`` kinds, one per :data:`pliant.collision.CONTACT_KINDS` entry and built from it (each
kind's file declares its scene keys and its drawing: nothing here names a kind), and the built-in
``[[handles]]`` kinds (box, points)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, create_model

from ..collision.kinds import CONTACT_KINDS, REQUIRED, ContactKind
from ._files import load_surface_file
from ._registry import handle_mode, register_collider_kind, register_handle_kind
from ._schema import ColliderBase, Float, Length, NonNegFloat, Scale3, Size3, Vec3, vector

if TYPE_CHECKING:
    from ..collision import Colliders
    from ._context import BuildContext
    from ._schema import HandleConfig, SceneConfig


#: The scene-file type of each :data:`pliant.collision.kinds.SCENE_TYPES` name (the same validated types the
#: other sections use, so an error names the key and the bound: ``colliders[0].radius: ... >= 1e-06``).
SCENE_TYPES: dict[str, Any] = {
    "vec3": Vec3,
    "length": Length,
    "nonneg": NonNegFloat,
    "size3": Size3,
    "scale3": Scale3,
    "quaternion": (
        Annotated[tuple[Float, Float, Float, Float], BeforeValidator(vector(4, "a quaternion [x, y, z, w]"))]
        | None
    ),
    "surface": str,
}


def collider_schema(kind: ContactKind) -> type[ColliderBase]:
    """The ``[[colliders]]`` schema of a contact kind: :class:`ColliderBase` with ``kind = "<name>"`` and
    the kind's declared :attr:`~pliant.collision.ContactKind.scene` keys (type, default, unit and doc)."""
    fields: dict[str, Any] = {"kind": (Literal.__getitem__(kind.name), ...)}
    for p in kind.scene:
        if p.type not in SCENE_TYPES:
            raise TypeError(
                f"collision/kinds: kind {kind.name!r} key {p.name!r} has type {p.type!r}; "
                f"use one of {sorted(SCENE_TYPES)}"
            )
        default = ... if p.default is REQUIRED else p.default
        fields[p.name] = (SCENE_TYPES[p.type], Field(default, description=f"{p.doc} [{p.unit}]"))
    name = "".join(w.title() for w in kind.name.split("_")) + "Collider"
    schema: type[ColliderBase] = create_model(name, __base__=ColliderBase, __module__=__name__, **fields)
    schema.__doc__ = f"A ``[[colliders]]`` entry of kind {kind.name!r} (``pliant.collision.kinds``)."
    return schema


def collider_adder(kind: ContactKind) -> Callable[..., tuple | None]:
    """``add(colliders, cfg, c, at)`` for a contact kind: reads its ``surface`` keys, adds the collider with
    the kind's keywords and the contact fields every collider has, and returns its drawing (or None)."""
    draw_only = {p.name for p in kind.scene if p.draw_only}

    def add(colliders: Colliders, cfg: SceneConfig, c: ColliderBase, at: str) -> tuple | None:
        values = {p.name: getattr(c, p.name) for p in kind.scene}
        for p in kind.scene:
            if p.type == "surface":
                mesh = load_surface_file(cfg, values[p.name], f"{at}.{p.name}")
                values[p.name] = (mesh.points, np.asarray(mesh.triangles))
        given = {k: v for k, v in values.items() if k not in draw_only}
        args = kind.from_scene(**given) if kind.from_scene is not None else given
        colliders.add(kind.name, **args, **c.contact())
        if not c.render or kind.draw is None:
            return None
        return kind.draw(**args, **{k: values[k] for k in draw_only})

    return add


for _kind in CONTACT_KINDS.values():
    register_collider_kind(_kind.name, collider_schema(_kind), collider_adder(_kind))


# ---------------------------------------------------------------------------------------------- handles
def select_box(ctx: BuildContext, h: HandleConfig, lo: int, hi: int, i: int) -> tuple[np.ndarray, np.ndarray]:
    """The particles of [lo, hi) inside the box at t = 0: (global indices, their positions)."""
    x = ctx.builder.positions()
    inside = np.all(np.abs(x[lo:hi] - np.asarray(h.center)) <= np.asarray(h.half_extents), axis=1)
    idx = np.flatnonzero(inside) + lo
    if idx.size == 0:
        raise ctx.fail(f"handles[{i}].center", "the box holds no particle at t = 0; move or enlarge it")
    return idx, x[idx]


def select_points(ctx: BuildContext, h: HandleConfig, lo: int, hi: int, i: int) -> tuple[None, np.ndarray]:
    """Control points [m] (linked by springs to the particles within ``radius``)."""
    return None, np.asarray(h.points, float)


def check_box(cfg: SceneConfig, h: HandleConfig, at: str) -> list[tuple[str, str]]:
    if h.center is None or h.half_extents is None:
        field_ = "center" if h.center is None else "half_extents"
        return [(f"{at}.{field_}", "a box handle needs center and half_extents [m]")]
    return []


def check_points(cfg: SceneConfig, h: HandleConfig, at: str) -> list[tuple[str, str]]:
    out = []
    if not h.points:
        out.append((f"{at}.points", "a points handle needs points = [[x, y, z], ...] [m]"))
    if h.radius is None:
        out.append((f"{at}.radius", "a points handle needs radius [m] (particles linked to each point)"))
    if handle_mode(h) == "kinematic":
        out.append((f"{at}.mode", 'a points handle acts through springs: use mode = "springs"'))
    return out


register_handle_kind("box", select_box, check=check_box, default_mode="kinematic")
register_handle_kind("points", select_points, check=check_points, default_mode="springs")
