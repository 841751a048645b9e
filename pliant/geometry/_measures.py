"""Per-element measures (areas, volumes, normals) and degeneracy checks."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._arrays import as_cells, as_points, check_in_range


def _tri_cross(points: ArrayLike, tris: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    p = as_points(points)
    t = as_cells(tris, 3, "triangles")
    check_in_range(t, len(p), "triangles")
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    return np.cross(b - a, c - a), np.stack([b - a, c - b, a - c], axis=1)


def triangle_areas(points: ArrayLike, tris: ArrayLike) -> NDArray[np.float64]:
    """Area of each triangle.

    Args:
        points: Vertex positions [N, 3] (m).
        tris: Triangle vertex indices [T, 3].

    Returns:
        Areas [T] (m^2), always >= 0.
    """
    cross, _ = _tri_cross(points, tris)
    return 0.5 * np.linalg.norm(cross, axis=1)


def triangle_normals(points: ArrayLike, tris: ArrayLike, normalize: bool = True) -> NDArray[np.float64]:
    """Normal of each triangle following the right-hand rule on its vertex order.

    Args:
        points: Vertex positions [N, 3] (m).
        tris: Triangle vertex indices [T, 3].
        normalize: If True return unit normals (zero vector for zero-area triangles, so
            no NaN leaks into a simulation); else ``(b - a) x (c - a)``, whose length
            is twice the area (m^2).

    Returns:
        Normals [T, 3].
    """
    cross, _ = _tri_cross(points, tris)
    if not normalize:
        return cross
    norm = np.linalg.norm(cross, axis=1, keepdims=True)
    return np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)


def signed_tet_volumes(points: ArrayLike, tets: ArrayLike) -> NDArray[np.float64]:
    """Signed volume ``det[x1-x0, x2-x0, x3-x0] / 6`` of each tetrahedron.

    Args:
        points: Vertex positions [N, 3] (m).
        tets: Tetrahedron vertex indices [E, 4].

    Returns:
        Volumes [E] (m^3); positive for positively oriented tets.
    """
    p = as_points(points)
    t = as_cells(tets, 4, "tets")
    check_in_range(t, len(p), "tets")
    x0 = p[t[:, 0]]
    d1, d2, d3 = p[t[:, 1]] - x0, p[t[:, 2]] - x0, p[t[:, 3]] - x0
    return np.einsum("ij,ij->i", np.cross(d1, d2), d3) / 6.0


def orient_tets(points: ArrayLike, tets: ArrayLike) -> NDArray[np.int32]:
    """Return a copy of ``tets`` with negatively oriented elements flipped.

    Flipping swaps vertices 2 and 3, which negates the volume while keeping the
    element's vertex set. Zero-volume tets are left unchanged (see
    :func:`degenerate_tets` to find them).

    Args:
        points: Vertex positions [N, 3] (m).
        tets: Tetrahedron vertex indices [E, 4].

    Returns:
        Tets [E, 4] int32 with ``signed_tet_volumes(points, result) >= 0``.
    """
    out = as_cells(tets, 4, "tets").copy()
    neg = signed_tet_volumes(points, out) < 0
    out[neg] = out[neg][:, [0, 1, 3, 2]]
    return out


def degenerate_triangles(points: ArrayLike, tris: ArrayLike, eps: float = 1e-6) -> NDArray[np.int64]:
    """Indices of triangles whose area is tiny relative to their size.

    The test is scale free: ``area / L_max**2 < eps`` with ``L_max`` the longest edge
    (an equilateral triangle scores sqrt(3)/4 ~ 0.43). Triangles with coincident
    vertices always count as degenerate.

    Args:
        points: Vertex positions [N, 3] (m).
        tris: Triangle vertex indices [T, 3].
        eps: Threshold on the dimensionless ratio.

    Returns:
        Sorted indices into ``tris`` [K] int64.
    """
    cross, edges = _tri_cross(points, tris)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    lmax2 = np.max(np.einsum("tei,tei->te", edges, edges), axis=1)
    bad = (lmax2 <= 0) | (area < eps * lmax2)
    return np.flatnonzero(bad)


def degenerate_tets(points: ArrayLike, tets: ArrayLike, eps: float = 1e-6) -> NDArray[np.int64]:
    """Indices of tetrahedra whose volume is tiny relative to their size.

    The test is scale free: ``|volume| / L_max**3 < eps`` with ``L_max`` the longest of
    the six edges (a regular tet scores 1/(6 sqrt 2) ~ 0.118). Orientation is not
    judged here; use :func:`signed_tet_volumes` or :func:`orient_tets` for that.

    Args:
        points: Vertex positions [N, 3] (m).
        tets: Tetrahedron vertex indices [E, 4].
        eps: Threshold on the dimensionless ratio.

    Returns:
        Sorted indices into ``tets`` [K] int64.
    """
    vol = np.abs(signed_tet_volumes(points, tets))
    p = as_points(points)
    t = as_cells(tets, 4, "tets")
    i, j = np.triu_indices(4, k=1)
    d = p[t[:, j]] - p[t[:, i]]
    lmax = np.sqrt(np.max(np.einsum("tei,tei->te", d, d), axis=1))
    bad = (lmax <= 0) | (vol < eps * lmax**3)
    return np.flatnonzero(bad)
