"""Barycentric coordinates in tetrahedra, interpolation, and point location (NumPy / SciPy).

For a tetrahedron X0..X3 the linear shape functions are (φ1, φ2, φ3)ᵀ = [ΔX1 ΔX2 ΔX3]⁻¹ (X − X0),
ΔX_i = X_i − X0, and φ0 = 1 − φ1 − φ2 − φ3; then X = Σ φ_i X_i and any field interpolates as
f(X) = Σ φ_i f(X_i). Used to embed render meshes, observation points or Gaussian splats in a tet mesh.
"""

from __future__ import annotations

import numpy as np

__all__ = ["barycentric_coordinates", "interpolate", "locate_points", "shape_functions"]


def _solve_bary(points: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barycentrics of points [..., 3] in tets X [..., 4, 3], via the adjugate; also det(ΔX) [...]."""
    d1, d2, d3 = X[..., 1, :] - X[..., 0, :], X[..., 2, :] - X[..., 0, :], X[..., 3, :] - X[..., 0, :]
    r = points - X[..., 0, :]
    # rows of ΔX⁻¹ are (d2 × d3, d3 × d1, d1 × d2) / det
    c23, c31, c12 = np.cross(d2, d3), np.cross(d3, d1), np.cross(d1, d2)
    det = np.einsum("...i,...i->...", d1, c23)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi1 = np.einsum("...i,...i->...", c23, r) / det
        phi2 = np.einsum("...i,...i->...", c31, r) / det
        phi3 = np.einsum("...i,...i->...", c12, r) / det
    return np.stack([1.0 - phi1 - phi2 - phi3, phi1, phi2, phi3], axis=-1), det


def barycentric_coordinates(points: np.ndarray, tet_vertices: np.ndarray) -> np.ndarray:
    """Barycentric coordinates φ of each point in its tetrahedron (the lecture's φ = ΔX⁻¹(X − X0)).

    Args:
        points: Query points [m], shape [P, 3].
        tet_vertices: Vertices of the tetrahedron of each point [m], shape [P, 4, 3].

    Returns:
        φ, shape [P, 4], with Σ_i φ_i = 1 and Σ_i φ_i X_i = X; all φ_i ≥ 0 iff the point is inside.

    Raises:
        ValueError: on mismatched shapes, or a degenerate (zero-volume) tetrahedron.
    """
    points = np.asarray(points, dtype=np.float64)
    X = np.asarray(tet_vertices, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape [P, 3], got {points.shape}")
    if X.shape != (len(points), 4, 3):
        raise ValueError(f"tet_vertices must have shape [{len(points)}, 4, 3], got {X.shape}")
    bary, det = _solve_bary(points, X)
    scale = np.max(np.abs(X - X[:, :1]), axis=(1, 2)) ** 3
    bad = np.flatnonzero(~(np.abs(det) > 1e-14 * scale))
    if bad.size:
        raise ValueError(f"{bad.size} tetrahedra are degenerate (zero volume; first: {bad[:5].tolist()})")
    return bary


shape_functions = barycentric_coordinates
"""Alias of :func:`barycentric_coordinates`: the linear FEM shape functions φ_i(X)."""


def interpolate(field: np.ndarray, tets: np.ndarray, tet_ids: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """f(X_p) = Σ_i φ_pi f(X_{tets[tet_ids[p], i]}).

    Args:
        field: Per-vertex values, shape [N, ...] (positions, velocities, colours ...).
        tets: Vertex indices, shape [E, 4].
        tet_ids: Tetrahedron of each point, shape [P].
        bary: Barycentric coordinates, shape [P, 4].

    Returns:
        Interpolated values, shape [P, ...].
    """
    field = np.asarray(field)
    tets = np.asarray(tets)
    tet_ids = np.asarray(tet_ids)
    bary = np.asarray(bary)
    if tet_ids.ndim != 1 or bary.shape != (len(tet_ids), 4):
        raise ValueError(f"tet_ids must have shape [P] and bary [P, 4], got {tet_ids.shape} and {bary.shape}")
    vals = field[tets[tet_ids]]  # [P, 4, ...]
    w = bary.reshape(bary.shape + (1,) * (field.ndim - 1))
    return np.sum(w * vals, axis=1)


def _far_points_error(points: np.ndarray, ids: np.ndarray, dist: np.ndarray, lo, hi, why: str) -> ValueError:
    """The error for points that lie (too) far outside the mesh: which ones, how far, what to do."""
    order = ids[np.argsort(-dist)][:5]
    far = ", ".join(f"#{i} at {points[i].tolist()}" for i in order)
    return ValueError(
        f"{ids.size} point(s) lie outside the tetrahedra {why} (up to {float(np.max(dist)):.3g} m from the "
        f"mesh, whose bounding box is {np.round(lo, 6).tolist()}..{np.round(hi, 6).tolist()} m; farthest: "
        f"{far}); move or scale the points (e.g. a render mesh's center/scale) so they lie inside the mesh"
    )


def locate_points(
    points: np.ndarray,
    mesh_points: np.ndarray,
    tets: np.ndarray,
    *,
    candidates: int = 8,
    tol: float = 1e-9,
    max_distance: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Find the tetrahedron containing each point, and its barycentric coordinates.

    A cKDTree over tet centroids proposes the ``candidates`` nearest tets; points not inside any of them are
    retried against every tet whose centroid lies within the largest centroid-to-vertex distance of the mesh
    (a containing tet always does). Points outside the mesh get the candidate tet whose clamped, renormalised
    barycentric point is nearest, so their ``bary`` is ≥ 0 and sums to 1 (the point is projected into it).

    Args:
        points: Query points [m], shape [P, 3].
        mesh_points: Mesh vertices [m], shape [N, 3].
        tets: Vertex indices, shape [E, 4].
        candidates: Nearest tets tested in the first pass.
        tol: A point is inside when min φ_i ≥ −tol.
        max_distance: If given [m], a point farther than this from its projection into the mesh is an
            error (a render mesh that does not fit its simulation mesh) instead of being projected.

    Returns:
        ``(tet_ids [P] int64, bary [P, 4] float64, inside [P] bool)``.

    Raises:
        ValueError: bad shapes or indices, non-finite coordinates, points beyond ``max_distance``, or
            points so far away that their distance overflows; the message names the points and how far.
    """
    points = np.asarray(points, dtype=np.float64)
    mesh_points = np.asarray(mesh_points, dtype=np.float64)
    tets = np.asarray(tets)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape [P, 3], got {points.shape}")
    if mesh_points.ndim != 2 or mesh_points.shape[1] != 3:
        raise ValueError(f"mesh_points must have shape [N, 3], got {mesh_points.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4 or len(tets) == 0:
        raise ValueError(f"tets must have shape [E, 4] with E > 0, got {tets.shape}")
    if tets.min() < 0 or tets.max() >= len(mesh_points):
        raise ValueError(
            f"tets index vertices in [{tets.min()}, {tets.max()}], but there are {len(mesh_points)}"
        )
    for what, a in (("points", points), ("mesh_points", mesh_points)):
        bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
        if bad.size:
            raise ValueError(f"{what} has NaN/inf coordinates at rows {bad[:5].tolist()} ({bad.size} rows)")
    if max_distance is not None and not max_distance >= 0.0:
        raise ValueError(f"max_distance must be >= 0 m, got {max_distance}")
    tets = tets.astype(np.int64, copy=False)
    P = len(points)
    X = mesh_points[tets]  # [E, 4, 3]
    centroids = X.mean(axis=1)
    lo, hi = mesh_points.min(axis=0), mesh_points.max(axis=0)
    from scipy.spatial import cKDTree  # here, not at import: models without embedding never need SciPy

    tree = cKDTree(centroids)
    k = int(min(max(candidates, 1), len(tets)))

    # first pass: k nearest centroids
    dist_c, cand = tree.query(points, k=k)
    cand = np.asarray(cand).reshape(P, k)
    missing = np.flatnonzero(np.any(cand >= len(tets), axis=1))
    if missing.size:
        # cKDTree reports no neighbour when the distance overflows (points ~1e308 m away); the gap to the
        # bounding box is measured per axis (max norm), which does not overflow.
        p = points[missing]
        gap = np.max(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
        raise _far_points_error(points, missing, gap, lo, hi, "by more than any distance can express")
    bary_c, _ = _solve_bary(points[:, None, :], X[cand])  # [P, k, 4]
    min_c = np.nan_to_num(bary_c.min(axis=2), nan=-np.inf)
    best = np.argmax(min_c, axis=1)  # most-inside candidate (first one on ties, i.e. nearest centroid)
    rows = np.arange(P)
    tet_ids = cand[rows, best]
    bary = bary_c[rows, best]
    inside = min_c[rows, best] >= -tol

    # second pass: every tet that could contain the point
    todo = np.flatnonzero(~inside)
    if todo.size:
        radius = float(np.max(np.linalg.norm(X - centroids[:, None, :], axis=2)))
        lists = tree.query_ball_point(points[todo], r=radius * (1.0 + 1e-9))
        counts = np.fromiter((len(c) for c in lists), dtype=np.int64, count=len(lists))
        if counts.sum():
            flat = np.concatenate([np.asarray(c, dtype=np.int64) for c in lists if len(c)])
            owner = np.repeat(np.arange(todo.size), counts)
            b, _ = _solve_bary(points[todo[owner]], X[flat])
            mins = np.nan_to_num(b.min(axis=1), nan=-np.inf)
            hit_idx = np.flatnonzero(mins >= -tol)
            owners, first = np.unique(owner[hit_idx], return_index=True)  # first hit per point
            sel = hit_idx[first]
            p_ids = todo[owners]
            tet_ids[p_ids] = flat[sel]
            bary[p_ids] = b[sel]
            inside[p_ids] = True

    # outside the mesh: nearest candidate by its clamped barycentric point
    out = np.flatnonzero(~inside)
    if out.size:
        bc = np.clip(np.nan_to_num(bary_c[out], nan=0.0), 0.0, None)  # [O, k, 4]
        s = bc.sum(axis=2, keepdims=True)
        bc = np.where(s > 0.0, bc / np.where(s > 0.0, s, 1.0), 0.25)
        proj = np.einsum("okv,okvi->oki", bc, X[cand[out]])
        dist = np.linalg.norm(proj - points[out, None, :], axis=2)
        j = np.argmin(dist, axis=1)
        tet_ids[out] = cand[out, j]
        bary[out] = bc[np.arange(out.size), j]
        if max_distance is not None:
            gap = dist[np.arange(out.size), j]
            far = gap > max_distance
            if far.any():
                raise _far_points_error(
                    points, out[far], gap[far], lo, hi, f"by more than {max_distance:.3g} m"
                )
    return tet_ids, bary, inside
