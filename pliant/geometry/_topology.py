"""Connectivity derived from element lists: edges, boundary faces, bending pairs."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._arrays import as_cells

# Faces of a positively oriented tet (a, b, c, d), each wound so that its normal
# points away from the opposite vertex: for x0 = 0, x1 = e_x, x2 = e_y, x3 = e_z
# the face opposite x0 has normal (1, 1, 1), opposite x1 normal -e_x, and so on.
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.intp)


def _unique_pairs(pairs: NDArray[np.integer]) -> NDArray[np.int32]:
    """Sort each pair (i < j), drop self pairs and duplicates, order rows lexicographically."""
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int32)
    p = np.sort(pairs, axis=1)
    p = p[p[:, 0] != p[:, 1]]
    return np.unique(p, axis=0).astype(np.int32, copy=False)


def edges_from_triangles(tris: ArrayLike) -> NDArray[np.int32]:
    """Unique undirected edges of a triangle mesh.

    Args:
        tris: Triangle vertex indices [T, 3].

    Returns:
        Edges [E, 2] int32 with ``e[:, 0] < e[:, 1]``, rows sorted lexicographically.
    """
    t = as_cells(tris, 3, "triangles")
    return _unique_pairs(t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2))


def edges_from_tets(tets: ArrayLike) -> NDArray[np.int32]:
    """Unique undirected edges of a tetrahedral mesh.

    Args:
        tets: Tetrahedron vertex indices [E, 4].

    Returns:
        Edges [S, 2] int32 with ``e[:, 0] < e[:, 1]``, rows sorted lexicographically.
    """
    t = as_cells(tets, 4, "tets")
    i, j = np.triu_indices(4, k=1)
    return _unique_pairs(np.stack([t[:, i], t[:, j]], axis=-1).reshape(-1, 2))


def surface_from_tets(tets: ArrayLike) -> NDArray[np.int32]:
    """Boundary triangles of a tetrahedral mesh, wound with outward normals.

    A face is on the boundary when exactly one tet uses it. The outward winding
    assumes every tet is positively oriented (see :func:`orient_tets`).

    Args:
        tets: Tetrahedron vertex indices [E, 4].

    Returns:
        Triangles [F, 3] int32, in the order the tets list them.
    """
    t = as_cells(tets, 4, "tets")
    faces = t[:, _TET_FACES].reshape(-1, 3)
    if faces.size == 0:
        return np.zeros((0, 3), dtype=np.int32)
    _, first, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    return faces[np.sort(first[counts == 1])]


def bending_pairs(triangles: ArrayLike) -> NDArray[np.int32]:
    """Pairs of triangles sharing an interior edge, for dihedral-angle bending.

    Each row is ``(e0, e1, o0, o1)``: the shared edge (e0, e1), the vertex o0 of the
    first triangle opposite the edge and the vertex o1 of the second. The first
    triangle traverses the edge as e0 -> e1, so on a consistently wound mesh the
    triangles are (e0, e1, o0) and (e1, e0, o1) up to rotation, which gives the
    dihedral angle a consistent sign. Boundary edges (one triangle) and non-manifold
    edges (three or more) produce no row.

    Args:
        triangles: Triangle vertex indices [T, 3].

    Returns:
        Bending pairs [B, 4] int32, ordered by edge (min vertex, then max vertex).
    """
    t = as_cells(triangles, 3, "triangles")
    if t.size == 0:
        return np.zeros((0, 4), dtype=np.int32)
    # Half-edges (a -> b) with the opposite vertex c, three per triangle.
    a = t.reshape(-1)
    b = t[:, [1, 2, 0]].reshape(-1)
    c = t[:, [2, 0, 1]].reshape(-1)
    n = np.int64(t.max()) + 1
    key = np.minimum(a, b).astype(np.int64) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    _, start, counts = np.unique(key[order], return_index=True, return_counts=True)
    start = start[counts == 2]
    h0, h1 = order[start], order[start + 1]
    return np.stack([a[h0], b[h0], c[h0], c[h1]], axis=1).astype(np.int32)
