"""A small 2D linear-elasticity oracle (plane stress or plane strain) with 9-node quadrilaterals (Q9).

Independent of pliant (NumPy/SciPy only), written for the Cook's-membrane reference value. The domain is
a quadrilateral given by its four corners; the mesh is the bilinear image of an ``n_s × n_t`` grid of
biquadratic Lagrange elements (isoparametric, 3 × 3 Gauss points, exact for the stiffness of a
parallelogram and converged far beyond the discretisation error on the mildly tapered Cook panel). Edge
``s = 0`` is where Dirichlet values are set, edge ``s = 1`` carries a traction. Textbook formulation:
Zienkiewicz, Taylor & Zhu, *The Finite Element Method: Its Basis and Fundamentals* (7th ed.), ch. 6
(plane elasticity) and ch. 5 (Lagrange elements); Hughes, *The Finite Element Method* (1987), §3.8.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

# Cook's membrane (Cook 1974): the tapered panel, corners in the order s,t = (0,0), (1,0), (1,1), (0,1).
COOK_CORNERS = np.array([[0.0, 0.0], [48.0, 44.0], [48.0, 60.0], [0.0, 44.0]])


def _lagrange3(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values and derivatives [..., 3] of the 1D quadratic Lagrange basis on the nodes −1, 0, 1."""
    x = np.asarray(x, np.float64)
    N = np.stack([0.5 * x * (x - 1.0), 1.0 - x * x, 0.5 * x * (x + 1.0)], -1)
    dN = np.stack([x - 0.5, -2.0 * x, x + 0.5], -1)
    return N, dN


def elasticity_matrix(E: float, nu: float, plane: str) -> np.ndarray:
    """3 × 3 matrix D with (σxx, σyy, σxy) = D (εxx, εyy, γxy); ``plane`` is "stress" or "strain"."""
    if plane == "stress":
        return E / (1.0 - nu * nu) * np.array([[1.0, nu, 0.0], [nu, 1.0, 0.0], [0.0, 0.0, 0.5 * (1.0 - nu)]])
    if plane == "strain":
        c = E / ((1.0 + nu) * (1.0 - 2.0 * nu))
        return c * np.array([[1.0 - nu, nu, 0.0], [nu, 1.0 - nu, 0.0], [0.0, 0.0, 0.5 - nu]])
    raise ValueError(f"plane must be 'stress' or 'strain', got {plane!r}")


def solve_quad_panel(
    corners: np.ndarray,
    n_s: int,
    n_t: int,
    *,
    E: float,
    nu: float,
    plane: str = "stress",
    fixed: Callable[[np.ndarray], np.ndarray] | None = None,
    u_fixed: Callable[[np.ndarray], np.ndarray] | None = None,
    traction: Callable[[np.ndarray], np.ndarray] | None = None,
    thickness: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Static linear-elastic displacement of a quadrilateral panel meshed with Q9 elements.

    corners: [4, 2] the panel's corners at (s, t) = (0,0), (1,0), (1,1), (0,1) (the mesh is their bilinear
    image). n_s, n_t: elements along s and t. E [Pa], nu: Young's modulus and Poisson's ratio; plane:
    "stress" or "strain". fixed(st [k, 2]) -> bool [k]: the nodes with prescribed displacement, chosen by
    their grid coordinates (s, t) ∈ [0, 1]² (default: the edge s = 0); u_fixed(X) -> [k, 2]: their
    values (default 0). traction(X [k, 2]) -> [k, 2]: the traction [Pa] on the edge s = 1 (default
    none), integrated with 5 Gauss points per element edge.
    thickness [m] scales stiffness and loads alike (the displacement does not depend on it).
    Returns (X [N, 2] node positions, u [N, 2] displacements, node ids [2 n_s + 1, 2 n_t + 1] on the grid).
    """
    corners = np.asarray(corners, np.float64)
    ms, mt = 2 * n_s + 1, 2 * n_t + 1
    s, t = (a.ravel() for a in np.meshgrid(np.linspace(0, 1, ms), np.linspace(0, 1, mt), indexing="ij"))
    w4 = np.stack([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t], 1)
    X = w4 @ corners
    ids = np.arange(ms * mt).reshape(ms, mt)
    # Element e = (i, j) takes the 3 × 3 nodes from (2i, 2j); local node (a, b) ↔ (ξ, η) = (a − 1, b − 1).
    ii, jj = np.meshgrid(np.arange(n_s), np.arange(n_t), indexing="ij")
    a, b = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    elems = ids[2 * ii.ravel()[:, None] + a.ravel()[None, :], 2 * jj.ravel()[:, None] + b.ravel()[None, :]]
    xe = X[elems]  # [ne, 9, 2]
    D = elasticity_matrix(E, nu, plane)
    g, w = np.polynomial.legendre.leggauss(3)
    Ke = np.zeros((len(elems), 18, 18))
    for p in range(3):
        for q in range(3):
            Np, dNp = _lagrange3(g[p])
            Nq, dNq = _lagrange3(g[q])
            dN = np.stack([np.outer(dNp, Nq).ravel(), np.outer(Np, dNq).ravel()], 1)  # [9, 2] ∂/∂(ξ, η)
            J = np.einsum("eki,kj->eij", xe, dN)  # [ne, 2, 2] ∂x_i/∂ξ_j
            dNx = dN @ np.linalg.inv(J)  # [ne, 9, 2] ∂N_k/∂x_i
            B = np.zeros((len(elems), 3, 18))
            B[:, 0, 0::2] = dNx[:, :, 0]
            B[:, 1, 1::2] = dNx[:, :, 1]
            B[:, 2, 0::2] = dNx[:, :, 1]
            B[:, 2, 1::2] = dNx[:, :, 0]
            Ke += (thickness * w[p] * w[q] * np.linalg.det(J))[:, None, None] * np.einsum(
                "eia,ij,ejb->eab", B, D, B
            )
    dofs = np.stack([2 * elems, 2 * elems + 1], 2).reshape(len(elems), 18)
    n = 2 * len(X)
    K = sp.coo_matrix(
        (Ke.ravel(), (np.repeat(dofs, 18, 1).ravel(), np.tile(dofs, (1, 18)).ravel())), shape=(n, n)
    ).tocsr()

    f = np.zeros((len(X), 2))
    if traction is not None:
        gl, wl = np.polynomial.legendre.leggauss(5)
        Nl, dNl = _lagrange3(gl)
        for j in range(n_t):
            edge = ids[-1, 2 * j : 2 * j + 3]
            xq = Nl @ X[edge]  # [5, 2] points on the edge
            ds = np.linalg.norm(dNl @ X[edge], axis=1)  # |dx/dξ|
            f[edge] += Nl.T @ (traction(xq) * (thickness * wl * ds)[:, None])

    on = fixed(np.stack([s, t], 1)) if fixed is not None else s == 0.0
    u = np.zeros((len(X), 2))
    if u_fixed is not None:
        u[on] = u_fixed(X[on])
    cdof = np.flatnonzero(np.repeat(on, 2))
    fdof = np.flatnonzero(~np.repeat(on, 2))
    rhs = f.ravel()[fdof] - K[fdof][:, cdof] @ u.ravel()[cdof]
    uf = u.ravel()
    uf[fdof] = spla.spsolve(K[fdof][:, fdof].tocsc(), rhs)
    return X, uf.reshape(-1, 2), ids


def cook_membrane_2d(n: int, *, nu: float = 1.0 / 3.0, plane: str = "stress") -> dict:
    """Cook's membrane on n × n Q9 elements: E = 1, thickness 1, clamped at x = 0, a uniform shear traction
    of total F = 1 on x = 48 (1/16 per unit length). Returns the vertical displacements of the loaded
    edge's midpoint (48, 52), where the published 23.96 is measured, and of its top corner (48, 60)."""
    X, u, ids = solve_quad_panel(
        COOK_CORNERS,
        n,
        n,
        E=1.0,
        nu=nu,
        plane=plane,
        traction=lambda x: np.tile([0.0, 1.0 / 16.0], (len(x), 1)),
    )
    mid, top = ids[-1, n], ids[-1, -1]
    assert np.allclose(X[mid], [48.0, 52.0]) and np.allclose(X[top], [48.0, 60.0])
    return {"mid_edge": float(u[mid, 1]), "top_corner": float(u[top, 1]), "dof": 2 * len(X)}


if __name__ == "__main__":  # the convergence table of docs/tutorials/04_fem.md
    for plane in ("stress", "strain"):
        for n in (4, 8, 16, 32, 64, 128):
            print(plane, n, cook_membrane_2d(n, plane=plane))
