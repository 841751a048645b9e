"""The built-in ``[[objects]]`` kinds: schema, builder, load-time checks and particle estimate of each."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field, Strict, field_validator, model_validator

from ._files import load_mesh_file, load_points_npy, npy_shape, scene_path
from ._registry import register_object_kind
from ._schema import (
    Cells3,
    Length,
    ObjectBase,
    Pin,
    PosFloat,
    PosInt,
    Scale3,
    Section,
    Size2,
    Size3,
    Vec3,
)

if TYPE_CHECKING:
    from ._context import BuildContext
    from ._schema import SceneConfig

CLOTH_PINS = (
    "none",
    "top-corners",
    "top-edge",
    "corners",
    "top-left",
    "top-right",
    "bottom-corners",
    "left-corners",
    "right-corners",
    "bottom-edge",
    "left-edge",
    "right-edge",
    "boundary",
)
ROPE_PINS = ("first", "last", "both", "none")
#: Young's modulus given to the tets of a ``model = "pbd"`` volume without ``material.E`` (the builder
#: stores tets with an E; XPBD's volume constraints only use their rest volumes).
PBD_DEFAULT_E = 1.0e5


class ClothObject(ObjectBase):
    """A rectangular cloth of nx × ny cells (structural, shear and bend springs)."""

    kind: Literal["cloth"]
    nx: PosInt = 16
    ny: PosInt = 16
    size: Size2 = (1.0, 1.0)  # [m]
    origin: Vec3 = (-0.5, 1.0, -0.5)  # bottom-left corner [m]
    plane: Literal["xz", "xy", "yz"] = "xz"
    mass: PosFloat = 0.1  # total [kg]
    pin: Pin = "none"


class RopeObject(ObjectBase):
    """A rope (chain of springs) of ``n_segments`` from ``origin`` along ``direction``."""

    kind: Literal["rope"]
    n_segments: PosInt = 20
    length: Length = 1.0  # [m]
    origin: Vec3 = (0.0, 1.0, 0.0)  # first particle [m]
    direction: Vec3 = (1.0, 0.0, 0.0)
    mass: PosFloat = 0.1  # total [kg]
    pin: Pin = "first"


class RenderMesh(Section):
    """A fine surface drawn instead of a volume's own surface, moved by barycentric interpolation."""

    path: str | None = None  # a surface mesh file (relative to the scene file), or:
    icosphere: Annotated[int, Strict(), Field(ge=0, le=6)] | None = None  # subdivision level
    radius: Length | None = None  # icosphere radius [m] (default: the object's radius or half size)
    scale: Scale3 = (1.0, 1.0, 1.0)  # mesh file scale
    center: Vec3 | None = None  # [m] (default: the object's origin)


class TetOrder(Section):
    """``order`` of a volume's tetrahedra: 1 (linear, 4 nodes) or 2 (quadratic, 10 nodes: a particle at
    every edge midpoint; FEM only, ``model = "fem"``; they do not lock in bending)."""

    order: Literal[1, 2] = 1

    @field_validator("order", mode="before")
    @classmethod
    def _order_is_a_whole_number(cls, v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, int) or v not in (1, 2):
            raise ValueError(f"order must be 1 (linear tets) or 2 (quadratic tets), got {v!r}")
        return v

    @model_validator(mode="after")
    def _order_needs_fem(self) -> TetOrder:
        model = getattr(self, "model", "fem")  # a mixin: the object kind that uses it declares `model`
        if self.order == 2 and model != "fem":
            raise ValueError(
                f'order = 2 (quadratic tets) needs model = "fem", got model = "{model}"; '
                "use order = 1 for mass-spring and pbd volumes"
            )
        return self


class SoftBoxObject(ObjectBase, TetOrder):
    """A box of cells × 6 tetrahedra (tet-edge springs, or FEM with ``model = "fem"``)."""

    kind: Literal["soft_box"]
    cells: Cells3 = (4, 4, 4)
    size: Size3 = (0.2, 0.2, 0.2)  # [m]
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]
    render_mesh: RenderMesh | None = None


class Oriented(Section):
    """Orientation of a mesh or point file: ``up`` names the file's up axis, then ``rotation`` turns it.

    The file's points are scaled, turned upright (``up = "z"``: the file's +z becomes pliant's +y),
    rotated by ``rotation`` — Euler angles in degrees about the fixed x, then y, then z axes, through the
    file's coordinate origin (points objects: their centroid) — and finally moved by ``origin``.
    """

    rotation: Vec3 = (0.0, 0.0, 0.0)  # Euler angles [deg], about fixed x, then y, then z
    up: Literal["y", "z"] = "y"  # the file's up axis ("z": a Z-up mesh, e.g. from Blender or CAD)


def rotation_matrix(rotation: Sequence[float], up: str = "y") -> np.ndarray | None:
    """3×3 matrix of :class:`Oriented`'s ``up`` then ``rotation`` (None when both leave points as they
    are, so that unrotated scenes keep their exact positions)."""
    if up == "y" and not any(rotation):
        return None
    ax, ay, az = np.radians(np.asarray(rotation, np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    # z-up to y-up: -90 degrees about x, so (x, y, z) -> (x, z, -y) and the file's +z points up.
    upright = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]) if up == "z" else np.eye(3)
    return rz @ ry @ rx @ upright


def orient(points: np.ndarray, o: ObjectBase) -> np.ndarray:
    """``points`` [N, 3] turned by the object's ``up`` and ``rotation`` (about the coordinate origin)."""
    r = rotation_matrix(getattr(o, "rotation", (0.0, 0.0, 0.0)), getattr(o, "up", "y"))
    return points if r is None else points @ r.T


class MeshObject(ObjectBase, Oriented, TetOrder):
    """A mesh file (relative to the scene file): a tet mesh, or a closed surface filled by TetGen."""

    kind: Literal["mesh"]
    path: str
    scale: Scale3 = (1.0, 1.0, 1.0)
    origin: Vec3 = (0.0, 0.0, 0.0)  # translation after scaling and rotation [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)
    max_volume: PosFloat | None = None  # TetGen bound on tet volume [m³]
    render_mesh: RenderMesh | None = None


class PointsObject(ObjectBase, Oriented):
    """A point cloud with springs to neighbours within ``radius`` (PhysTwin style).

    Points come from ``path`` (.npy [N, 3] or a mesh file's vertices) or fill a ``shape`` on a jittered grid.
    """

    kind: Literal["points"]
    path: str | None = None
    shape: Literal["sphere", "box"] = "sphere"
    size: Size3 = (0.3, 0.3, 0.3)  # diameter / extents [m]
    spacing: Length = 0.04  # grid spacing [m]
    jitter: Annotated[float, Strict(), Field(ge=0, lt=0.5)] = 0.2  # fraction of spacing
    seed: Annotated[int, Strict(), Field(ge=0, le=2**63 - 1)] = 0
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    mass: PosFloat = 0.5  # total [kg]
    radius: Length | None = None  # spring radius [m] (default 1.8 × spacing)
    max_neighbors: Annotated[int, Strict(), Field(ge=1, le=256)] = 12


class SoftSphereObject(ObjectBase, TetOrder):
    """A solid ball: an icosphere filled with tetrahedra by TetGen (springs, XPBD volume or FEM)."""

    kind: Literal["soft_sphere"]
    radius: Length = 0.15  # [m]
    resolution: Annotated[int, Strict(), Field(ge=0, le=4)] = 2  # icosphere subdivision level
    max_volume: PosFloat | None = None  # TetGen bound on tet volume [m³]
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]
    render_mesh: RenderMesh | None = None


class ClusterObject(ObjectBase):
    """Particles on a grid filling a sphere or box, held together by shape matching (XPBD/PBD only)."""

    kind: Literal["cluster"]
    model: Literal["pbd"] = "pbd"
    shape: Literal["sphere", "box"] = "box"
    size: Size3 = (0.1, 0.1, 0.1)  # diameter / extents [m]
    spacing: Length = 0.025  # grid spacing [m]; particle_radius defaults to half of it
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    mass: PosFloat = 0.1  # total [kg]
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]
    rigid: bool = True  # shape-matching stiffness 1
    shape_stiffness: Annotated[float, Strict(), Field(gt=0, le=1)] | None = None  # k_S when not rigid
    oriented: bool = False  # oriented particles (Müller & Chentanez 2011)


# ---------------------------------------------------------------------------------------------- helpers
def _name(o: ObjectBase, i: int) -> str:
    return o.name or f"{getattr(o, 'kind', 'object')}{i}"  # every registered kind declares `kind`


def _stiffness(o: ObjectBase) -> float:
    # pbd objects without a stiffness: the springs only carry topology (the solver gets compliance 0).
    return o.material.stiffness if o.material.stiffness is not None else 1.0


def _radius_kw(o: ObjectBase, key: str = "radius") -> dict[str, Any]:
    return {} if o.particle_radius is None else {key: o.particle_radius}


def _grid_count(size: Sequence[float], spacing: float) -> float:
    return float(np.prod([math.floor(s / spacing) + 1.0 for s in size]))


def grid_points(o: PointsObject | ClusterObject, cfg: SceneConfig, at: str) -> np.ndarray:
    """Points [N, 3] of a points / cluster object: its file's, centred on ``origin``, or a jittered grid."""
    if isinstance(o, PointsObject) and o.path is not None:
        p = scene_path(cfg, o.path, f"{at}.path")
        if p.suffix == ".npy":
            pts = load_points_npy(cfg, p, f"{at}.path")
        else:
            pts = np.asarray(load_mesh_file(cfg, o.path, f"{at}.path").points, np.float64)
        return orient(pts - pts.mean(axis=0), o) + np.asarray(o.origin)
    half = 0.5 * np.asarray(o.size)
    axes = [np.arange(-h, h + 1e-12, o.spacing) for h in half]
    axes = [a - a.mean() for a in axes]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if o.shape == "sphere":
        grid = grid[np.sum((grid / half) ** 2, axis=1) <= 1.0]
    if isinstance(o, PointsObject) and o.jitter:
        rng = np.random.default_rng(o.seed)
        grid = grid + rng.uniform(-o.jitter, o.jitter, grid.shape) * o.spacing
    return orient(grid, o) + np.asarray(o.origin)


def _tet_kw(o: SoftBoxObject | SoftSphereObject | MeshObject, i: int) -> dict[str, Any]:
    mat = o.material
    fem = o.model == "fem"
    # pbd volumes keep their tets (XPBD volume constraints); the builder stores tets with an E.
    E = mat.E if fem else ((mat.E or PBD_DEFAULT_E) if o.model == "pbd" else None)
    return {
        "stiffness": None if fem else _stiffness(o),
        "damping": mat.damping,
        "E": E,
        "nu": mat.nu,
        "velocity": o.velocity,
        "name": _name(o, i),
        "density": o.density,
        "order": o.order,
        **_radius_kw(o),
    }


def _tetgen_particles(volume: float, max_volume: float | None, surface: float) -> float:
    # TetGen puts about one vertex per five tets of the requested volume, plus the surface vertices.
    return surface + (volume / max_volume / 5.0 if max_volume else 0.0)


# ---------------------------------------------------------------------------------------------- builders
def build_cloth(ctx: BuildContext, o: ClothObject, i: int) -> None:
    mat = o.material
    if mat.Et is not None and mat.stiffness is None:
        kw: dict[str, Any] = {"youngs_modulus_thickness": mat.Et, "poisson": mat.nu}
    else:
        kw = {"stiffness": _stiffness(o), "shear_stiffness": mat.shear_stiffness}
    ctx.builder.add_cloth_grid(
        nx=o.nx,
        ny=o.ny,
        size=o.size,
        mass=o.mass,
        bend_stiffness=mat.bend_stiffness,
        damping=mat.damping,
        origin=o.origin,
        plane=o.plane,
        pin=o.pin,
        name=_name(o, i),
        **kw,
        **_radius_kw(o),
    )


def build_rope(ctx: BuildContext, o: RopeObject, i: int) -> None:
    mat = o.material
    ctx.builder.add_rope(
        n_segments=o.n_segments,
        length=o.length,
        mass=o.mass,
        stiffness=_stiffness(o),
        damping=mat.damping,
        start=o.origin,
        direction=o.direction,
        bend_stiffness=mat.bend_stiffness,
        pin=o.pin,
        name=_name(o, i),
        **_radius_kw(o),
    )


def build_soft_box(ctx: BuildContext, o: SoftBoxObject, i: int) -> None:
    ctx.builder.add_soft_box(cells=o.cells, size=o.size, origin=o.origin, **_tet_kw(o, i))


def build_soft_sphere(ctx: BuildContext, o: SoftSphereObject, i: int) -> None:
    from ..geometry import sphere_tets

    tm = sphere_tets(o.radius, o.resolution, o.origin, max_volume=o.max_volume)
    ctx.builder.add_tet_mesh(tm.points, tm.tets, kind="soft_sphere", **_tet_kw(o, i))


def build_mesh(ctx: BuildContext, o: MeshObject, i: int) -> None:
    from ..geometry import TetMesh, tetrahedralize

    mesh = load_mesh_file(ctx.cfg, o.path, f"objects[{i}].path")
    pts = orient(mesh.points * np.asarray(o.scale), o) + np.asarray(o.origin)
    if isinstance(mesh, TetMesh):
        tets = mesh.tets
    else:
        tm = tetrahedralize(pts, mesh.triangles, max_volume=o.max_volume, name=o.path)
        pts, tets = tm.points, tm.tets
    ctx.builder.add_tet_mesh(pts, tets, **_tet_kw(o, i))


def build_points(ctx: BuildContext, o: PointsObject, i: int) -> None:
    pts = grid_points(o, ctx.cfg, f"objects[{i}]")
    ctx.builder.add_point_cloud(
        pts,
        mass=o.mass,
        stiffness=_stiffness(o),
        radius=o.radius or 1.8 * o.spacing,
        max_neighbors=o.max_neighbors,
        damping=o.material.damping,
        name=_name(o, i),
        **_radius_kw(o, "particle_radius"),
    )


def build_cluster(ctx: BuildContext, o: ClusterObject, i: int) -> None:
    pts = grid_points(o, ctx.cfg, f"objects[{i}]")
    name = _name(o, i)
    if pts.shape[0] < 2:
        raise ValueError(f"{name}: {pts.shape[0]} particle(s) fit; make size larger or spacing smaller")
    b = ctx.builder
    start = b.add_particles(
        pts,
        o.mass / pts.shape[0],
        velocities=np.broadcast_to(np.asarray(o.velocity, float), pts.shape),
        radius=o.particle_radius or 0.5 * o.spacing,
        name=name,
    )
    b.register_object(name, "cluster", start)


# ---------------------------------------------------------------------------------------------- checks
def _check_pin(o: ClothObject | RopeObject, at: str, allowed: tuple[str, ...]) -> list[tuple[str, str]]:
    if isinstance(o.pin, str) and o.pin not in allowed:
        return [(f"{at}.pin", f"unknown pin {o.pin!r}; allowed: {', '.join(allowed)} or a list of indices")]
    return []


def check_cloth(cfg: SceneConfig, o: ClothObject, at: str) -> list[tuple[str, str]]:
    return _check_pin(o, at, CLOTH_PINS)


def check_rope(cfg: SceneConfig, o: RopeObject, at: str) -> list[tuple[str, str]]:
    out = _check_pin(o, at, ROPE_PINS)
    if not np.any(o.direction):
        out.append((f"{at}.direction", "must be a non-zero vector"))
    return out


def check_render_mesh(
    cfg: SceneConfig, o: SoftBoxObject | MeshObject | SoftSphereObject, at: str
) -> list[tuple[str, str]]:
    rm = o.render_mesh
    if rm is not None and (rm.path is None) == (rm.icosphere is None):
        return [(f"{at}.render_mesh", "give either path (a surface mesh file) or icosphere (a level)")]
    return []


def check_cluster(cfg: SceneConfig, o: ClusterObject, at: str) -> list[tuple[str, str]]:
    if o.rigid and o.shape_stiffness is not None:
        return [(f"{at}.shape_stiffness", "a rigid cluster has k_S = 1; set rigid = false to use it")]
    return []


def _points_estimate(cfg: SceneConfig, o: PointsObject | ClusterObject) -> float:
    if isinstance(o, PointsObject) and o.path is not None:
        p = scene_path(cfg, o.path, f"objects[{cfg.objects.index(o)}].path")
        if p.suffix == ".npy":
            return float(npy_shape(cfg, p, f"objects[{cfg.objects.index(o)}].path")[0][0])
        return 0.0  # a mesh file's vertex count is checked when it is read
    return _grid_count(o.size, o.spacing)


def _mesh_estimate(cfg: SceneConfig, o: MeshObject) -> float:
    # Only a TetGen bound needs the file now (its vertex count is checked when it is read): the bounding
    # box's volume over max_volume bounds the tets TetGen is asked for.
    if o.max_volume is None:
        return 0.0
    at = f"objects[{cfg.objects.index(o)}].path"
    pts = orient(np.asarray(load_mesh_file(cfg, o.path, at).points, np.float64) * np.asarray(o.scale), o)
    return _tetgen_particles(float(np.prod(np.ptp(pts, axis=0))), o.max_volume, float(len(pts)))


def _sphere_estimate(cfg: SceneConfig, o: SoftSphereObject) -> float:
    return _tetgen_particles(4.0 / 3.0 * math.pi * o.radius**3, o.max_volume, 10.0 * 4**o.resolution + 2)


register_object_kind(
    "cloth", ClothObject, build_cloth, check=check_cloth, particles=lambda cfg, o: (o.nx + 1.0) * (o.ny + 1.0)
)
register_object_kind(
    "rope", RopeObject, build_rope, check=check_rope, particles=lambda cfg, o: o.n_segments + 1.0
)
register_object_kind(
    "soft_box",
    SoftBoxObject,
    build_soft_box,
    check=check_render_mesh,
    volumetric=True,
    particles=lambda cfg, o: float(np.prod([o.order * c + 1.0 for c in o.cells])),
)
register_object_kind(
    "mesh", MeshObject, build_mesh, check=check_render_mesh, volumetric=True, particles=_mesh_estimate
)
register_object_kind("points", PointsObject, build_points, particles=_points_estimate)
register_object_kind(
    "soft_sphere",
    SoftSphereObject,
    build_soft_sphere,
    check=check_render_mesh,
    volumetric=True,
    particles=_sphere_estimate,
)
register_object_kind("cluster", ClusterObject, build_cluster, check=check_cluster, particles=_points_estimate)
