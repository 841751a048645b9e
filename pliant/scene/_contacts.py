"""Built-in ``[[colliders]]`` kinds (sphere, box, capsule, mesh, plane: one per
:data:`pliant.collision.CONTACT_KINDS` entry, ``tests/test_contact_registry.py`` checks) and
``[[handles]]`` kinds (box, points)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator

from ._files import load_surface_file
from ._registry import handle_mode, register_collider_kind, register_handle_kind
from ._schema import ColliderBase, Float, Length, NonNegFloat, Scale3, Size3, Vec3, vector

if TYPE_CHECKING:
    from ..collision import Colliders
    from ._context import BuildContext
    from ._schema import HandleConfig, SceneConfig


class SphereCollider(ColliderBase):
    kind: Literal["sphere"]
    center: Vec3 = (0.0, 0.0, 0.0)  # [m]
    radius: Length  # [m]


class BoxCollider(ColliderBase):
    kind: Literal["box"]
    center: Vec3 = (0.0, 0.0, 0.0)  # [m]
    half_extents: Size3  # [m]
    rotation: (
        Annotated[tuple[Float, Float, Float, Float], BeforeValidator(vector(4, "a quaternion [x, y, z, w]"))]
        | None
    ) = None
    rounding: NonNegFloat = 0.0  # [m]


class CapsuleCollider(ColliderBase):
    kind: Literal["capsule"]
    a: Vec3  # segment end points [m]
    b: Vec3
    radius: Length  # [m]


class PlaneCollider(ColliderBase):
    kind: Literal["plane"]
    point: Vec3 = (0.0, 0.0, 0.0)  # a point of the plane [m]
    normal: Vec3 = (0.0, 1.0, 0.0)  # outward normal (the half space below is solid)
    size: Length = 4.0  # side [m] of the square drawn for it


class MeshCollider(ColliderBase):
    kind: Literal["mesh"]
    path: str  # closed, outward-wound surface (relative to the scene file)
    scale: Scale3 = (1.0, 1.0, 1.0)
    origin: Vec3 = (0.0, 0.0, 0.0)  # translation after scaling [m]


def _fr(c: ColliderBase) -> dict[str, Any]:
    return c.contact()


def add_sphere(colliders: Colliders, cfg: SceneConfig, c: SphereCollider, at: str) -> tuple | None:
    import trimesh

    colliders.add_sphere(c.center, c.radius, **_fr(c))
    if not c.render:
        return None
    m = trimesh.creation.icosphere(subdivisions=3, radius=c.radius)
    return m.vertices + np.asarray(c.center), m.faces


def add_box(colliders: Colliders, cfg: SceneConfig, c: BoxCollider, at: str) -> tuple | None:
    import trimesh

    if c.rotation is not None and not np.linalg.norm(c.rotation) > 1e-12:
        raise ValueError("rotation is a zero quaternion; give [x, y, z, w] with a non-zero norm")
    colliders.add_box(c.center, c.half_extents, rotation=c.rotation, rounding=c.rounding, **_fr(c))
    if not c.render:
        return None
    m = trimesh.creation.box(extents=2.0 * np.asarray(c.half_extents))
    v = m.vertices
    if c.rotation is not None:
        from scipy.spatial.transform import Rotation

        v = Rotation.from_quat(c.rotation).apply(v)
    return v + np.asarray(c.center), m.faces


def add_capsule(colliders: Colliders, cfg: SceneConfig, c: CapsuleCollider, at: str) -> tuple | None:
    import trimesh

    a, b = np.asarray(c.a), np.asarray(c.b)
    d = b - a
    if not np.linalg.norm(d) > 0:
        raise ValueError("a and b coincide; a capsule needs two different end points (or use a sphere)")
    colliders.add_capsule(c.a, c.b, c.radius, **_fr(c))
    if not c.render:
        return None
    m = trimesh.creation.capsule(height=float(np.linalg.norm(d)), radius=c.radius, count=[16, 16])
    rot = trimesh.geometry.align_vectors(np.array([0.0, 0.0, 1.0]), d / np.linalg.norm(d))[:3, :3]
    return m.vertices @ rot.T + 0.5 * (a + b), m.faces  # trimesh's capsule is centred at the origin


def add_mesh(colliders: Colliders, cfg: SceneConfig, c: MeshCollider, at: str) -> tuple | None:
    mesh = load_surface_file(cfg, c.path, f"{at}.path")
    v = mesh.points * np.asarray(c.scale) + np.asarray(c.origin)
    f = np.asarray(mesh.triangles)
    colliders.add_mesh(v, f, **_fr(c))
    return (v, f) if c.render else None


def add_plane(colliders: Colliders, cfg: SceneConfig, c: PlaneCollider, at: str) -> tuple | None:
    colliders.add_plane(c.point, c.normal, **_fr(c))
    if not c.render:
        return None
    n = np.asarray(c.normal) / np.linalg.norm(c.normal)
    u = np.cross(n, (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 0.0, 1.0))
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    h = 0.5 * c.size
    v = np.asarray(c.point) + h * np.array([-u - w, u - w, u + w, -u + w])
    return v, np.array([[0, 2, 1], [0, 3, 2]])


register_collider_kind("sphere", SphereCollider, add_sphere)
register_collider_kind("box", BoxCollider, add_box)
register_collider_kind("capsule", CapsuleCollider, add_capsule)
register_collider_kind("mesh", MeshCollider, add_mesh)
register_collider_kind("plane", PlaneCollider, add_plane)


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
