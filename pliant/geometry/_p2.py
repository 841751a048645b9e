"""Quadratic (10-node, P2) tetrahedra: promotion of a linear mesh, shape functions, quadrature, mass.

Node order (VTK / TetGen ``-o2``): corners 0–3, then the mid-edge nodes of the edges
:data:`P2_EDGES` = (0,1), (1,2), (0,2), (0,3), (1,3), (2,3) as nodes 4–9. In barycentric coordinates
λ = (λ0, λ1, λ2, λ3) (Σ λ = 1) the Lagrange shape functions are

* corners  N_i = λ_i (2 λ_i − 1),
* edges    N_ij = 4 λ_i λ_j,

and, with g_i = ∇_X λ_i (the linear tet's shape gradients), ∇N_i = (4 λ_i − 1) g_i and
∇N_ij = 4 (λ_i g_j + λ_j g_i). Mid-edge nodes sit at the edge midpoints (straight-sided elements), so the
map from λ to X is affine and g_i is constant over an element.

Everything here is NumPy (float64); the Warp kernels are in :mod:`pliant.energies._fem_p2`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Corner pairs of the mid-edge nodes 4..9.
P2_EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]], dtype=np.int64)

# The 8 linear sub-tets of a 10-node tet (local node numbers): 4 corner tets and the inner octahedron cut
# along its 5–7 diagonal (mid-edges of (1,2) and (0,3)). Orientation is fixed per element at promotion.
_SUBTETS = np.array(
    [
        [0, 4, 6, 7],
        [4, 1, 5, 8],
        [6, 5, 2, 9],
        [7, 8, 9, 3],
        [4, 5, 6, 7],
        [4, 5, 7, 8],
        [6, 5, 9, 7],
        [8, 5, 7, 9],
    ],
    dtype=np.int64,
)


def promote_tets_p2(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Promote a linear tet mesh to 10-node tets: one new node at the midpoint of each distinct edge.

    Edges shared between tets get one node (deduplicated), so the P2 mesh is conforming. The original
    points keep their indices; the mid-edge nodes follow them, in the order of the sorted edge list.

    Args:
        points: [N, 3] vertex positions [m].
        tets: [E, 4] vertex indices (0-based).

    Returns:
        ``(points10, tets10)``: [N + n_edges, 3] positions [m] and [E, 10] node indices (int32).
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    t = np.asarray(tets, np.int64).reshape(-1, 4)
    pairs = np.sort(t[:, P2_EDGES], axis=2).reshape(-1, 2)  # [E * 6, 2]
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    mid = 0.5 * (pts[edges[:, 0]] + pts[edges[:, 1]])
    tets10 = np.concatenate([t, pts.shape[0] + inverse.reshape(-1, 6)], axis=1)
    return np.concatenate([pts, mid]), tets10.astype(np.int32)


def p2_subtets(points10: np.ndarray, tets10: np.ndarray) -> np.ndarray:
    """The 8 positively oriented linear sub-tets of each 10-node tet, [8 E, 4] (int32).

    They tile each element, and the sub-tets of two neighbours meet on the same 4 sub-triangles of their
    shared face, so ``surface_from_tets(p2_subtets(...))`` is the subdivided boundary (4 triangles per
    face) and the sub-tets serve export, embedding and the inversion guards.

    Args:
        points10: [N, 3] node positions [m] (rest shape: fixes the orientation).
        tets10: [E, 10] node indices.
    """
    t = np.asarray(tets10, np.int64).reshape(-1, 10)
    sub = t[:, _SUBTETS].reshape(-1, 4)
    x = np.asarray(points10, np.float64)
    d = x[sub[:, 1:]] - x[sub[:, :1]]
    neg = np.linalg.det(d) < 0
    sub[neg, 2], sub[neg, 3] = sub[neg, 3], sub[neg, 2].copy()
    return sub.astype(np.int32)


def p2_shape_functions(bary: np.ndarray) -> np.ndarray:
    """N_a(λ) for a = 0..9 at barycentric points ``bary`` [Q, 4]; returns [Q, 10] (Σ_a N_a = 1)."""
    lam = np.asarray(bary, np.float64).reshape(-1, 4)
    corner = lam * (2.0 * lam - 1.0)
    edge = 4.0 * lam[:, P2_EDGES[:, 0]] * lam[:, P2_EDGES[:, 1]]
    return np.concatenate([corner, edge], axis=1)


def p2_shape_gradients(bary: np.ndarray, rest_inv: np.ndarray) -> np.ndarray:
    """∇_X N_a [1/m] at barycentric points ``bary`` [Q, 4] of one element with D_m⁻¹ ``rest_inv`` (3×3).

    Returns [Q, 10, 3]; Σ_a ∇N_a = 0 and Σ_a X_a ⊗ ∇N_a = I (both tested).
    """
    lam = np.asarray(bary, np.float64).reshape(-1, 4)
    inv = np.asarray(rest_inv, np.float64)
    g = np.concatenate([-inv.sum(axis=0, keepdims=True), inv], axis=0)  # g_i = ∇λ_i, [4, 3]
    corner = (4.0 * lam - 1.0)[:, :, None] * g[None, :, :]
    i, j = P2_EDGES[:, 0], P2_EDGES[:, 1]
    edge = 4.0 * (lam[:, i, None] * g[None, j, :] + lam[:, j, None] * g[None, i, :])
    return np.concatenate([corner, edge], axis=1)


# Symmetric rules on the tetrahedron, weights normalised to sum 1 (multiply by the volume).
# Degree 2: 4 points (Keast); degree 5: 14 points, all weights positive (Walkington 2000 / Keast #6).
_A2 = 0.1381966011250105  # (5 − √5) / 20


def _orbit31(a: float) -> np.ndarray:
    b = 1.0 - 3.0 * a
    return np.array([[b, a, a, a], [a, b, a, a], [a, a, b, a], [a, a, a, b]])


def _orbit22(a: float) -> np.ndarray:
    b = 0.5 - a
    return np.array([[a, a, b, b], [a, b, a, b], [a, b, b, a], [b, a, a, b], [b, a, b, a], [b, b, a, a]])


def tet_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """A quadrature rule on the tetrahedron exact for polynomials up to ``degree``, all weights > 0.

    Args:
        degree: 1 (1 point, the centroid), 2 (4 points) or 5 (14 points; also used for 3 and 4).

    Returns:
        ``(bary, weights)``: [Q, 4] barycentric points and [Q] weights summing to 1 (∫_T f ≈ V Σ w_q f_q).
    """
    if degree == 1:
        return np.full((1, 4), 0.25), np.ones(1)
    if degree == 2:
        return _orbit31(_A2), np.full(4, 0.25)
    if degree in (3, 4, 5):
        pts = np.concatenate(
            [_orbit31(0.0927352503108912), _orbit31(0.3108859192633006), _orbit22(0.0455037041256496)]
        )
        w = np.concatenate(
            [np.full(4, 0.0734930431163619), np.full(4, 0.1126879257180159), np.full(6, 0.0425460207770815)]
        )
        return pts, w / w.sum()
    raise ValueError(f"tet_quadrature: degree must be 1, 2, 3, 4 or 5, got {degree}")


#: HRZ lumping of the P2 tet mass: the consistent matrix's diagonal (ρV/420 × 6 at corners, × 32 at
#: mid-edges) scaled to the element's mass, so every share is positive (row sums give −ρV/20 at corners).
P2_LUMPED_SHARES = np.array([1.0 / 36.0] * 4 + [4.0 / 27.0] * 6)


def p2_element_mass(volume: float, density: float) -> np.ndarray:
    """Consistent mass matrix ρ ∫ N_a N_b dV [kg] of one 10-node tet (10×10), by the exact 14-point rule."""
    bary, w = tet_quadrature(5)
    n = p2_shape_functions(bary)
    return density * volume * (n.T * w) @ n


def _volumes(points10: np.ndarray, tets10: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tets [E, 10] int64, points [N, 3], element volumes [E] m³) of a 10-node mesh."""
    t = np.asarray(tets10, np.int64).reshape(-1, 10)
    x = np.asarray(points10, np.float64)
    return t, x, np.abs(np.linalg.det(x[t[:, 1:4]] - x[t[:, :1]])) / 6.0


def p2_lumped_masses(points10: np.ndarray, tets10: np.ndarray, density: float) -> np.ndarray:
    """Positive lumped node masses [kg] of a 10-node mesh (HRZ: diagonal of the consistent mass scaled).

    Args:
        points10: [N, 3] node positions [m].
        tets10: [E, 10] node indices.
        density: ρ [kg/m³].
    """
    t, x, vol = _volumes(points10, tets10)
    m = np.zeros(x.shape[0])
    np.add.at(m, t.ravel(), (density * vol[:, None] * P2_LUMPED_SHARES[None, :]).ravel())
    return m


def p2_consistent_mass(points10: np.ndarray, tets10: np.ndarray, density: float):
    """The consistent mass matrix [kg] of a 10-node mesh as a SciPy CSR matrix, one row per node.

    Args:
        points10: [N, 3] node positions [m].
        tets10: [E, 10] node indices.
        density: ρ [kg/m³].
    """
    import scipy.sparse as sp

    t, x, vol = _volumes(points10, tets10)
    me = p2_element_mass(1.0, density)
    vals = vol[:, None, None] * me[None]
    rows = np.repeat(t, 10, axis=1)
    cols = np.tile(t, (1, 10))
    n = x.shape[0]
    return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n))


def locate_points_p2(
    points: np.ndarray, points10: np.ndarray, tets10: np.ndarray, **kw: Any
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Embed points in a 10-node mesh: the element containing each one and its barycentric coordinates.

    The rest elements are straight-sided, so the corner tets locate the points exactly
    (:func:`pliant.geometry.locate_points`); :func:`interpolate_p2` then follows the elements' quadratic
    deformation, where interpolating on the 8 linear sub-tets (what ``model.tet_indices_np`` holds for P2
    bodies) is only piecewise linear.

    Args:
        points: [P, 3] points to embed [m].
        points10: [N, 3] rest node positions [m].
        tets10: [E, 10] node indices.
        **kw: passed to :func:`pliant.geometry.locate_points` (``candidates``, ``tol``, ``max_distance``).

    Returns:
        ``(tet_ids [P], bary [P, 4], inside [P])`` as :func:`pliant.geometry.locate_points` returns them.
    """
    from ._barycentric import locate_points

    t = np.asarray(tets10, np.int64).reshape(-1, 10)
    return locate_points(points, points10, t[:, :4], **kw)


def interpolate_p2(
    field: np.ndarray, tets10: np.ndarray, tet_ids: np.ndarray, bary: np.ndarray
) -> np.ndarray:
    """f(p) = Σ_a N_a(λ_p) f(node a of element tet_ids[p]) with the quadratic shape functions.

    Args:
        field: per-node values, shape [N, ...] (deformed positions [m], velocities, colours ...).
        tets10: [E, 10] node indices.
        tet_ids: element of each point, shape [P] (from :func:`locate_points_p2`).
        bary: barycentric coordinates of each point in its element, shape [P, 4].

    Returns:
        Interpolated values, shape [P, ...].
    """
    f = np.asarray(field)
    nodes = np.asarray(tets10, np.int64).reshape(-1, 10)[np.asarray(tet_ids, np.int64)]  # [P, 10]
    n = p2_shape_functions(bary)  # [P, 10]
    return np.einsum("pa,pa...->p...", n, f[nodes])
