"""Tetrahedral meshes: structured boxes and TetGen volumes from closed surfaces."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from ._arrays import as_cells, as_points, as_vec3, check_in_range
from ._measures import orient_tets
from ._meshes import TetMesh

# Kuhn (Freudenthal) split of the unit cube into 6 tets along the 000-111 diagonal.
# Corner id = dx + 2 dy + 4 dz. Each tet walks 000 -> +e_a -> +e_b -> 111 for a
# permutation (a, b, c) of the axes; odd permutations have their last two vertices
# swapped so that all six are positively oriented. Every cell uses the same split,
# so the diagonals on shared faces agree and the mesh is conforming.
_KUHN = np.array(
    [[0, 1, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 1, 7, 5], [0, 2, 7, 3], [0, 4, 7, 6]], dtype=np.intp
)

_TETGEN_DEBRIS = ("_skipped.face", "_skipped.node")


def _triple(v: float | Sequence[float], what: str) -> np.ndarray:
    arr = np.full(3, float(v)) if np.isscalar(v) else as_vec3(v, what)  # type: ignore[arg-type]
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ValueError(f"{what} must be positive, got {v!r}")
    return arr


def box_tets(
    nx: int,
    ny: int,
    nz: int,
    size: float | Sequence[float] = (1.0, 1.0, 1.0),
    origin: ArrayLike = (0.0, 0.0, 0.0),
) -> TetMesh:
    """Axis-aligned box of ``nx*ny*nz`` cubes, each split into 6 tetrahedra.

    All cells share one Kuhn split so faces match between cells. Vertex ``(i, j, k)``
    has index ``i + (nx+1) * (j + (ny+1) * k)``.

    Args:
        nx: Cells along x (>= 1).
        ny: Cells along y (>= 1).
        nz: Cells along z (>= 1).
        size: Extent along (x, y, z) (m), or one number for a cube.
        origin: Position of the min corner (m).

    Returns:
        :class:`TetMesh` with (nx+1)(ny+1)(nz+1) points and 6 nx ny nz positive tets.
    """
    counts = []
    for name, n in (("nx", nx), ("ny", ny), ("nz", nz)):
        if int(n) != n or n < 1:
            raise ValueError(f"box_tets: {name} must be an integer >= 1 (number of cells), got {n!r}")
        counts.append(int(n))
    nx, ny, nz = counts
    s = _triple(size, "box_tets size")
    axes = [np.linspace(0.0, s[d], counts[d] + 1) for d in range(3)]
    # indexing="ij" over (z, y, x) makes x the fastest index, matching the docstring.
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1) + as_vec3(origin, "box_tets origin")

    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    base = (i + (nx + 1) * (j + (ny + 1) * k)).reshape(-1, 1)
    corner = np.array(
        [dx + (nx + 1) * (dy + (ny + 1) * dz) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]
    )
    cells = base + corner[None, :]  # [C, 8] global index of each local corner id
    tets = cells[:, _KUHN].reshape(-1, 4).astype(np.int32)
    return TetMesh(points=points, tets=tets)


def voxel_tets(centres: ArrayLike, spacing: float, *, dual: bool = False) -> TetMesh:
    """Tetrahedra of a carved voxel set (centres on a grid of pitch ``spacing``), every cube split into 6
    with the one Kuhn split of :func:`box_tets`, so neighbouring cubes share their corners and faces.

    Two meshes of the same voxels:

    - ``dual=False``: each voxel is a cube (its corners are the nodes): the mesh covers the carved volume
      exactly, its nodes reach half a voxel past the centres;
    - ``dual=True``: the nodes are the voxel centres themselves, and a cube joins every 8 neighbouring
      centres: the mesh lies half a voxel inside the carved volume (centres without a complete cube of
      neighbours, parts thinner than two voxels, are left out). A carved hull is the object plus up to half
      a voxel, so the centres sit on the object's surface, the corners outside it.

    Args:
        centres: [M, 3] voxel centres [m] (as :func:`carve` keeps them).
        spacing: Voxel side [m].
        dual: Nodes at the centres (True) or at the voxels' corners (False).

    Returns:
        :class:`TetMesh` over the used nodes, 6 positive tets per cube.

    Raises:
        ValueError: no centres, a non-positive spacing, or (``dual``) no complete cube of 8 centres.
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    if len(c) == 0 or not spacing > 0:
        raise ValueError(f"voxel_tets: expected voxel centres [M >= 1, 3] and spacing > 0, got {c.shape}")
    off = np.array([[dx, dy, dz] for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)])
    if dual:
        lo = c.min(axis=0)
        ijk = np.rint((c - lo) / spacing).astype(np.int64)  # grid index of each centre
        n = ijk.max(axis=0) + 2
        occupied = np.zeros(n, dtype=bool)
        occupied[tuple(ijk.T)] = True
        full = np.all([occupied[tuple((ijk + o).T)] for o in off], axis=0)  # the 8 corners are centres
        if not full.any():
            raise ValueError("voxel_tets: no 8 neighbouring voxel centres form a cube (dual=True)")
        corners = ijk[full][:, None, :] + off[None, :, :]
    else:
        lo = c.min(axis=0) - 0.5 * spacing
        ijk = np.rint((c - lo) / spacing - 0.5).astype(np.int64)  # cell index of each voxel
        n = ijk.max(axis=0) + 2  # corner grid size
        corners = ijk[:, None, :] + off[None, :, :]  # [M, 8, 3], local corner ids as in box_tets
    flat = corners[..., 0] + n[0] * (corners[..., 1] + n[1] * corners[..., 2])
    used, cells = np.unique(flat, return_inverse=True)
    cells = cells.reshape(-1, 8)
    k, rem = np.divmod(used, n[0] * n[1])
    j, i = np.divmod(rem, n[0])
    points = lo + spacing * np.stack([i, j, k], axis=1)
    return TetMesh(points=points, tets=cells[:, _KUHN].reshape(-1, 4).astype(np.int32))


def largest_piece(mesh: TetMesh) -> TetMesh:
    """The largest connected piece of a tetrahedral mesh (tets joined through shared vertices), its unused
    vertices dropped; a carved volume's stray fragments (a few voxels the pictures could not rule out, apart
    from the object) would otherwise fall away freely in a simulation.

    Args:
        mesh: A tet mesh.

    Returns:
        A :class:`TetMesh` with the tets of the piece with the most tets, vertices renumbered in order.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    tets = np.asarray(mesh.tets, dtype=np.int64)
    n = len(mesh.points)
    if len(tets) == 0:
        return mesh
    a = np.repeat(tets[:, :1], 3, axis=1).ravel()
    graph = coo_matrix((np.ones(len(a)), (a, tets[:, 1:].ravel())), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    piece = label[tets[:, 0]]
    keep = piece == np.bincount(piece).argmax()
    used = np.unique(tets[keep])
    index = np.full(n, -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return TetMesh(points=np.asarray(mesh.points)[used], tets=index[tets[keep]].astype(np.int32))


def coarsen_voxels(centres: ArrayLike, spacing: float, factor: int = 2, min_fill: float = 0.5) -> np.ndarray:
    """A coarser voxel set: cells of ``factor`` voxels a side, kept where at least ``min_fill`` of their
    ``factor³`` voxels are (a multigrid restriction of the occupancy).

    Args:
        centres: [M, 3] voxel centres [m] on a grid of pitch ``spacing``.
        spacing: Voxel side [m].
        factor: Voxels per coarse cell along each axis (≥ 2).
        min_fill: Fraction of a coarse cell's voxels that must be present, in (0, 1].

    Returns:
        [K, 3] centres [m] of the kept coarse cells (pitch ``factor · spacing``).
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    if len(c) == 0 or not spacing > 0 or int(factor) < 2 or not 0.0 < min_fill <= 1.0:
        raise ValueError(
            f"coarsen_voxels: expected centres [M >= 1, 3], spacing > 0, factor >= 2, min_fill in (0, 1]; "
            f"got {c.shape}, {spacing}, {factor}, {min_fill}"
        )
    lo = c.min(axis=0) - 0.5 * spacing
    cell = np.floor((c - lo) / (factor * spacing) + 1e-9).astype(np.int64)
    keys, count = np.unique(cell, axis=0, return_counts=True)
    keep = keys[count >= min_fill * factor**3]
    return lo + (keep + 0.5) * factor * spacing


def _surface_problems(vertices: np.ndarray, faces: np.ndarray, name: str) -> str | None:
    """Describe why TetGen would reject this surface, or return None if it looks fine."""
    import trimesh

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    if mesh.is_watertight and mesh.is_winding_consistent:
        return None

    und = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(und, axis=0, return_counts=True)
    n_open, n_nonmanifold = int(np.sum(counts == 1)), int(np.sum(counts > 2))
    if not mesh.is_watertight:
        merged = mesh.copy()
        merged.merge_vertices()
        if merged.is_watertight:
            hint = (
                "Its vertices are duplicated along seams; merging them closes the surface: "
                "`mesh.merge_vertices()` (trimesh) before passing vertices/faces."
            )
        else:
            hint = (
                "Try, in order: `mesh.merge_vertices()` (duplicated seam vertices), "
                "`trimesh.repair.fill_holes(mesh)` (small holes), or PyMeshFix "
                "(`pymeshfix.MeshFix(vertices, faces).repair()`) for larger defects."
            )
        return (
            f"cannot tetrahedralize {name!r}: the surface is not watertight "
            f"({n_open} open boundary edge(s), {n_nonmanifold} non-manifold edge(s) shared by 3+ faces; "
            f"{len(vertices)} vertices, {len(faces)} faces). TetGen needs a closed 2-manifold surface. "
            + hint
        )
    return (
        f"cannot tetrahedralize {name!r}: the faces are not consistently wound (neighbouring faces "
        "traverse a shared edge in the same direction), so inside and outside are ambiguous. "
        "Fix with `trimesh.repair.fix_winding(mesh)` (or `trimesh.repair.fix_normals(mesh)`)."
    )


def tetrahedralize(
    vertices: ArrayLike,
    faces: ArrayLike,
    *,
    max_volume: float | None = None,
    quality: bool = True,
    name: str = "mesh",
) -> TetMesh:
    """Fill a closed triangle surface with tetrahedra using TetGen.

    The surface is checked first (watertight, manifold, consistently wound) so that
    a bad input fails with a message naming the defect and a repair, rather than
    an opaque TetGen error.

    Args:
        vertices: Surface vertex positions [N, 3] (m).
        faces: Surface triangles [F, 3].
        max_volume: Approximate upper bound on tet volume (m^3); None leaves the
            size to TetGen (few interior points).
        quality: Ask TetGen for a radius-edge ratio bound (adds Steiner points,
            avoids slivers).
        name: What to call the mesh in error messages, e.g. its file path.

    Returns:
        :class:`TetMesh` with positively oriented tets. Surface vertices keep their
        positions (TetGen may add points on the surface, but inside its facets, so
        the enclosed volume is preserved).

    Raises:
        ValueError: The surface is open, non-manifold, inconsistently wound, or
            TetGen rejects it (e.g. self-intersections).
    """
    import tetgen

    v = as_points(vertices, f"{name}: vertices")
    f = as_cells(faces, 3, f"{name}: faces")
    if len(v) < 4 or len(f) < 4:
        raise ValueError(
            f"cannot tetrahedralize {name!r}: needs >= 4 vertices and faces, got {len(v)}, {len(f)}"
        )
    if not np.all(np.isfinite(v)):
        bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
        raise ValueError(
            f"cannot tetrahedralize {name!r}: {bad.size} vertices have NaN/inf coordinates "
            f"(first: {bad[:5].tolist()})"
        )
    check_in_range(f, len(v), f"{name}: faces")
    problem = _surface_problems(v, f, name)
    if problem is not None:
        raise ValueError(problem)
    if max_volume is not None and not (np.isfinite(max_volume) and max_volume > 0):
        raise ValueError(
            f"tetrahedralize {name!r}: max_volume must be a positive volume (m^3), got {max_volume!r}"
        )

    kwargs: dict = {"quality": bool(quality)}
    if max_volume is not None:
        # tetgen >= 0.8 ignores maxvolume unless fixedvolume (the "-a" switch) is set.
        kwargs.update(fixedvolume=True, maxvolume=float(max_volume))
    # On failure TetGen dumps debug files into the working directory; remove the ones
    # this call created so a failed run leaves the user's folder as it found it.
    debris = [Path(n) for n in _TETGEN_DEBRIS if not Path(n).exists()]
    try:
        result = tetgen.TetGen(v, f).tetrahedralize(**kwargs)
    except Exception as exc:  # TetGen reports every failure as RuntimeError with a terse text
        for d in debris:
            d.unlink(missing_ok=True)
        raise ValueError(
            f"TetGen failed on {name!r}: {exc}. The surface is closed, so the usual causes are "
            "self-intersecting or touching faces, or near-degenerate triangles. Check with "
            "`trimesh.Trimesh(v, f).is_volume`, repair with PyMeshFix "
            "(`pymeshfix.MeshFix(v, f).repair()`), or retry with quality=False."
        ) from exc
    # tetgen < 0.7 returns (nodes, elems); newer versions append attributes and markers.
    nodes, elems = np.asarray(result[0], dtype=np.float64), np.asarray(result[1])
    if elems.ndim != 2 or elems.shape[0] == 0:
        raise ValueError(f"TetGen produced no tetrahedra for {name!r}; is the surface degenerate (flat)?")
    elems = elems[:, :4]  # drop mid-edge nodes should a caller have asked for order 2
    return TetMesh(points=nodes, tets=orient_tets(nodes, elems))


def sphere_tets(
    radius: float = 1.0,
    resolution: int = 3,
    center: ArrayLike = (0.0, 0.0, 0.0),
    *,
    max_volume: float | None = None,
    quality: bool = True,
) -> TetMesh:
    """Solid ball: a trimesh icosphere filled by TetGen.

    Args:
        radius: Sphere radius (m); surface vertices lie on it, so the volume is
            slightly below 4/3 pi r^3 (0.991x at resolution 3, 0.966x at 2).
        resolution: Icosphere subdivision level (surface has 20 * 4**resolution faces).
        center: Sphere centre (m).
        max_volume: Approximate bound on tet volume (m^3), see :func:`tetrahedralize`.
        quality: TetGen quality refinement.

    Returns:
        :class:`TetMesh` with positively oriented tets.
    """
    import trimesh

    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"sphere_tets: radius must be positive (m), got {radius!r}")
    if int(resolution) != resolution or not 0 <= resolution <= 6:
        raise ValueError(
            f"sphere_tets: resolution must be an integer subdivision level in 0..6, got {resolution!r}"
        )
    surf = trimesh.creation.icosphere(subdivisions=int(resolution), radius=float(radius))
    mesh = tetrahedralize(
        surf.vertices, surf.faces, max_volume=max_volume, quality=quality, name=f"sphere(r={radius})"
    )
    mesh.points += as_vec3(center, "sphere_tets center")
    return mesh


def cylinder_tets(
    radius: float = 0.5,
    height: float = 1.0,
    resolution: int = 32,
    center: ArrayLike = (0.0, 0.0, 0.0),
    *,
    max_volume: float | None = None,
    quality: bool = True,
) -> TetMesh:
    """Solid cylinder along z: a trimesh prism of ``resolution`` sides filled by TetGen.

    Args:
        radius: Cylinder radius (m); rim vertices lie on it, so the volume is
            ``(resolution / 2) sin(2 pi / resolution) r^2 h`` (0.9936 pi r^2 h at 32).
        height: Length along z (m), centred on ``center``.
        resolution: Number of sides of the polygonal cross-section (>= 3).
        center: Centre of the cylinder (m).
        max_volume: Approximate bound on tet volume (m^3), see :func:`tetrahedralize`.
        quality: TetGen quality refinement.

    Returns:
        :class:`TetMesh` with positively oriented tets.
    """
    import trimesh

    if not (np.isfinite(radius) and radius > 0 and np.isfinite(height) and height > 0):
        raise ValueError(f"cylinder_tets: radius and height must be positive (m), got {radius!r}, {height!r}")
    if int(resolution) != resolution or resolution < 3:
        raise ValueError(
            f"cylinder_tets: resolution (number of sides) must be an integer >= 3, got {resolution!r}"
        )
    surf = trimesh.creation.cylinder(radius=float(radius), height=float(height), sections=int(resolution))
    mesh = tetrahedralize(
        surf.vertices,
        surf.faces,
        max_volume=max_volume,
        quality=quality,
        name=f"cylinder(r={radius}, h={height})",
    )
    mesh.points += as_vec3(center, "cylinder_tets center")
    return mesh
