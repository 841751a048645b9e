"""The size of a scene before anything is built: particles, springs, tets and the memory of the model and of
the implicit solver's matrices, from closed forms of the objects' fields (cells, nx × ny, segments) or a
read of a mesh file's header-sized arrays; compared with the machine's available memory at load time.

The counts are exact for the grid kinds (cloth, rope, soft_box: the builders' own closed forms) and
estimates elsewhere (TetGen fills, point-cloud springs). The bytes count what pliant allocates per item:

- model and simulator states: 36 scalars per particle (position, velocity, mass, inverse mass, radius; the
  states' copies and the integrator's scratch), 3 scalars + 2 indices per spring, 12 scalars + 4 indices per
  tet, 3 indices per triangle, 4 per bending pair;
- implicit solvers (backward Euler's Newton / L-BFGS, fast mass-spring): the 3×3-block Hessian on the pattern
  of the particle pairs the elements couple (9 scalars + 3 indices per block, 16 slot indices per tet), and on
  the CPU its sparse LU factor in float64: about 2·N^(1/3) times the matrix's nonzeros (measured with SciPy's
  SuperLU on tet boxes of 4³…16³ cells: 3.0x … 22x, i.e. 1.0-1.3·N^(1/3)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..io import available_memory

if TYPE_CHECKING:
    from ._schema import ObjectBase, SceneConfig

#: Scalars per particle of the model and the simulator's states (measured on soft_box: 36 × 4 bytes in
#: float32, 36 × 8 in float64).
_PARTICLE_SCALARS = 36
_GB = 1e9
#: Tets per vertex of TetGen's quality fills (the built-in spheres: 2.0-2.5); edges ≈ vertices + tets (Euler).
_TETGEN_TETS = 2.5
#: The largest count (particles, springs, tets, ...) an object may derive: 1e12 particles hold 144 TB of
#: float32 states, beyond any machine, so a larger or non-finite count is a mistake in the file (a denormal
#: max_volume, a huge cell count), refused even with --force rather than overflowing the estimate.
MAX_COUNT = 1e12


@dataclass(frozen=True)
class SceneSize:
    """What a scene will allocate, estimated from its file before building.

    Attributes:
        particles: particles of all objects.
        springs: springs (structural, shear, bend; tet edges of spring volumes; point-cloud neighbours).
        tets: FEM / XPBD-volume tetrahedra.
        triangles: surface triangles (cloth).
        pairs: particle pairs an implicit solver's Hessian couples (off-diagonal blocks / 2).
        implicit: whether the solver assembles and factors a matrix (backward Euler, fast mass-spring).
        model_bytes: model and simulator states [bytes].
        solver_bytes: the implicit solver's matrices (Hessian, sparse LU on the CPU) [bytes]; 0 otherwise.
        exact: whether the counts are the builders' closed forms (else estimates).
    """

    particles: int
    springs: int
    tets: int
    triangles: int
    pairs: int
    implicit: bool
    model_bytes: float
    solver_bytes: float
    exact: bool

    @property
    def total_bytes(self) -> float:
        """Model, states and solver matrices [bytes]."""
        return self.model_bytes + self.solver_bytes

    def describe(self) -> str:
        """One line: the counts and the memory, e.g. ``125 particles, 604 springs; 30 kB (model 30 kB)``."""
        counts = [f"{_count(self.particles)} particles"]
        counts += [f"{_count(v)} {what}" for v, what in ((self.springs, "springs"), (self.tets, "tets")) if v]
        mem = f"model {format_bytes(self.model_bytes)}"
        if self.implicit:
            mem += f" + implicit solver matrices {format_bytes(self.solver_bytes)}"
        approx = "" if self.exact else "about "
        return f"{approx}{', '.join(counts)}; {mem}"


def _count(n: float) -> str:
    return f"{int(n)}" if n < 1e6 else f"{n:.3g}"


def format_bytes(b: float) -> str:
    """``b`` bytes as B, kB, MB or GB (three digits)."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if b >= size:
            return f"{b / size:.3g} {unit}"
    return f"{b:.0f} B"


@dataclass
class _Counts:
    particles: float = 0.0
    springs: float = 0.0
    tets: float = 0.0
    triangles: float = 0.0
    bending: float = 0.0
    pairs: float = 0.0  # particle pairs of the Hessian pattern (springs, tet edges, bending pairs)
    exact: bool = True


def _box_edges(nx: float, ny: float, nz: float) -> float:
    """Unique edges of ``box_tets``'s Kuhn split: axis edges, one diagonal per face, one per cell."""
    axis = nx * (ny + 1) * (nz + 1) + (nx + 1) * ny * (nz + 1) + (nx + 1) * (ny + 1) * nz
    faces = nx * ny * (nz + 1) + nx * (ny + 1) * nz + (nx + 1) * ny * nz
    return axis + faces + nx * ny * nz


def _volume(o: ObjectBase, particles: float, tets: float, edges: float, exact: bool) -> _Counts:
    """Counts of a tet volume: tet-edge springs (spring model), tets (FEM and XPBD volumes)."""
    springs = edges if o.model != "fem" else 0.0
    stored = tets if o.model in ("fem", "pbd") else 0.0
    return _Counts(particles, springs, stored, 0.0, 0.0, edges, exact)


def _object_counts(cfg: SceneConfig, o: Any, i: int) -> _Counts:
    """The counts of object ``o`` (index ``i``), by kind; plugin kinds give their particle estimate only."""
    from ._files import load_mesh_file
    from ._objects import _grid_count, _points_estimate, _sphere_estimate
    from ._registry import OBJECT_KINDS

    if o.kind == "cloth":
        nx, ny = float(o.nx), float(o.ny)
        springs = nx * (ny + 1) + ny * (nx + 1) + 2 * nx * ny  # structural + shear
        if o.material.bend_stiffness:
            springs += (nx - 1) * (ny + 1) + (ny - 1) * (nx + 1)
        bending = 3 * nx * ny - nx - ny  # interior edges: one bending pair each
        return _Counts((nx + 1) * (ny + 1), springs, 0.0, 2 * nx * ny, bending, springs + bending)
    if o.kind == "rope":
        n = float(o.n_segments)
        springs = n + (n - 1 if o.material.bend_stiffness else 0.0)
        return _Counts(n + 1, springs, 0.0, 0.0, 0.0, springs)
    if o.kind == "soft_box":
        nx, ny, nz = (float(c) for c in o.cells)
        return _volume(o, (nx + 1) * (ny + 1) * (nz + 1), 6 * nx * ny * nz, _box_edges(nx, ny, nz), True)
    if o.kind == "mesh":
        from ..geometry import TetMesh
        from ._objects import _mesh_estimate

        mesh = load_mesh_file(cfg, o.path, f"objects[{i}].path")
        if isinstance(mesh, TetMesh):
            p, t = float(len(mesh.points)), float(len(mesh.tets))
            return _volume(o, p, t, p + t, False)  # Euler: a tet mesh has about V + T edges
        p = max(_mesh_estimate(cfg, o), 1.2 * len(mesh.points))  # TetGen adds some interior points
        return _volume(o, p, _TETGEN_TETS * p, (1.0 + _TETGEN_TETS) * p, False)
    if o.kind == "soft_sphere":
        p = _sphere_estimate(cfg, o)
        return _volume(o, p, _TETGEN_TETS * p, (1.0 + _TETGEN_TETS) * p, False)
    if o.kind == "points":
        p = _points_estimate(cfg, o) if o.path is not None else _grid_count(o.size, o.spacing)
        springs = p * o.max_neighbors / 2.0  # at most max_neighbors springs per point, each shared
        return _Counts(p, springs, 0.0, 0.0, 0.0, springs, False)
    est = OBJECT_KINDS[o.kind].particles
    p = float(est(cfg, o)) if est is not None else 0.0
    return _Counts(p, 0.0, 0.0, 0.0, 0.0, 0.0, False)


def _driver(o: Any) -> tuple[str, str]:
    """The field of object ``o`` that sets its counts, and how to lower them."""
    if o.kind == "cloth":
        return ("nx" if o.nx >= o.ny else "ny"), "use fewer cells"
    if o.kind == "rope":
        return "n_segments", "use fewer segments"
    if o.kind == "soft_box":
        return "cells", "use fewer cells"
    if o.kind in ("mesh", "soft_sphere") and getattr(o, "max_volume", None) is not None:
        return "max_volume", "use a larger max_volume [m³]"
    if o.kind == "soft_sphere":
        return "radius", "use a smaller radius"
    if o.kind in ("points", "cluster") and getattr(o, "path", None) is None:
        return "spacing", "use a larger spacing or a smaller size"
    return ("path" if getattr(o, "path", None) is not None else ""), "make the object coarser"


def _bounded_counts(cfg: SceneConfig, o: Any, i: int) -> _Counts:
    """:func:`_object_counts`, every count finite and at most :data:`MAX_COUNT` (an overflowing closed form,
    e.g. a bounding box's volume over a denormal max_volume, counts as infinite)."""
    from ._errors import scene_error

    try:
        c = _object_counts(cfg, o, i)
        counts: tuple[float, ...] = (c.particles, c.springs, c.tets, c.triangles, c.bending, c.pairs)
    except (OverflowError, ZeroDivisionError):  # float ** or / beyond the double range
        counts = (math.inf,)
    worst = max(counts, key=lambda v: v if math.isfinite(v) else math.inf)
    if math.isfinite(worst) and worst <= MAX_COUNT:
        return c
    field, fix = _driver(o)
    at = f"objects[{i}].{field}" if field else f"objects[{i}]"
    value = getattr(o, field, None) if field else None
    shown = f" = {value!r}" if isinstance(value, (int, float)) else ""
    raise scene_error(
        cfg,
        at,
        f"{field or 'this object'}{shown} gives {worst:.3g} particles or elements, beyond any machine "
        f"(at most {MAX_COUNT:.0e}); {fix}",
    )


def _implicit(cfg: SceneConfig) -> bool:
    """Whether the scene's solver assembles and factors a matrix."""
    kind = cfg.solver_kind()
    if kind == "fast_mass_spring":
        return True
    if kind != "force":
        return False
    from .. import integrators
    from ._solvers import find_integrator

    name = find_integrator(cfg.solver.integrator)
    cls = getattr(integrators, name, None) if name else None
    return cls is not None and not getattr(cls, "explicit", True)


def scene_size(cfg: SceneConfig) -> SceneSize:
    """Estimate what the scene ``cfg`` allocates, from its fields alone (and mesh files' arrays).

    Args:
        cfg: a validated scene (:func:`~pliant.scene.parse_scene` with ``force=True``, or any loaded one).

    Returns:
        A :class:`SceneSize`: counts, and bytes of the model and states and of the implicit solver's
        matrices.

    Raises:
        SceneError: a mesh file the estimate needs cannot be read (naming the object's path field), or an
            object derives a non-finite count or one above :data:`MAX_COUNT` (naming the field that sets it,
            e.g. ``objects[0].max_volume``).
    """
    total = _Counts()
    for i, o in enumerate(cfg.objects):
        c = _bounded_counts(cfg, o, i)
        total.particles += c.particles
        total.springs += c.springs
        total.tets += c.tets
        total.triangles += c.triangles
        total.bending += c.bending
        total.pairs += c.pairs
        total.exact = total.exact and c.exact
    s = 8.0 if cfg.scene.dtype == "float64" else 4.0
    model = (
        total.particles * _PARTICLE_SCALARS * s
        + total.springs * (3 * s + 8)
        + total.tets * (12 * s + 16)
        + total.triangles * 12
        + total.bending * 16
    )
    implicit = _implicit(cfg)
    solver = 0.0
    if implicit:
        blocks = total.particles + 2.0 * total.pairs  # diagonal + both triangles of the pattern
        fill = 2.0 * max(total.particles, 1.0) ** (1.0 / 3.0)  # SuperLU's fill-in on 3D meshes (measured)
        solver = blocks * (9 * s + 12) + total.tets * 64 + 9.0 * blocks * fill * 12.0
    return SceneSize(
        particles=int(total.particles),
        springs=int(total.springs),
        tets=int(total.tets),
        triangles=int(total.triangles),
        pairs=int(total.pairs),
        implicit=implicit,
        model_bytes=model,
        solver_bytes=solver,
        exact=total.exact,
    )


def size_problem(cfg: SceneConfig) -> list[tuple[str, str]]:
    """``[("objects", message)]`` when the scene needs more memory than is available, else ``[]``."""
    size = scene_size(cfg)
    have = available_memory()
    if have is None or size.total_bytes <= have:
        return []
    return [
        (
            "objects",
            f"this scene needs {format_bytes(size.total_bytes)} ({size.describe()}); the machine has "
            f"{format_bytes(have)} available; make it coarser, or pass --force to go on",
        )
    ]


__all__ = ["SceneSize", "available_memory", "scene_size", "size_problem"]
