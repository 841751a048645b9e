"""Float64 NumPy twins of the PBD/XPBD constraint maths of ``pliant.constraints``.

Written one element at a time for clarity. Where the Warp code uses a closed-form gradient, the twin
derives it differently (the dihedral angle by the lecture's arccos of normal dot products, its gradient
from the rotation of each triangle's normal; the point–triangle gradient by differentiating the unit normal
as a matrix), so agreement is a real check.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def central_diff(f: Callable[[np.ndarray], float], x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """∂f/∂x by central differences, same shape as ``x``."""
    x = np.asarray(x, np.float64)
    g = np.zeros_like(x)
    for k in np.ndindex(x.shape):
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        g[k] = (f(xp) - f(xm)) / (2.0 * h)
    return g


# ---------------------------------------------------------------------- distance
def distance_c(x: np.ndarray, rest: float) -> float:
    """C = |x0 − x1| − rest, x [2, 3]."""
    return float(np.linalg.norm(x[0] - x[1]) - rest)


def distance_grad(x: np.ndarray) -> np.ndarray:
    """[2, 3]: ±(x0 − x1)/|x0 − x1|."""
    n = (x[0] - x[1]) / np.linalg.norm(x[0] - x[1])
    return np.stack([n, -n])


# ---------------------------------------------------------------------- dihedral
def dihedral_angle(x: np.ndarray) -> float:
    """Signed dihedral angle [rad]: |θ| = arccos(n̂1·n̂2) (the lecture), sign from (n̂1 × n̂2)·e."""
    x0, x1, x2, x3 = x
    e = x1 - x0
    n1 = np.cross(e, x2 - x0)
    n2 = np.cross(x3 - x0, e)
    n1 /= np.linalg.norm(n1)
    n2 /= np.linalg.norm(n2)
    a = np.arccos(np.clip(n1 @ n2, -1.0, 1.0))
    return float(a if np.cross(n1, n2) @ e >= 0 else -a)


def dihedral_c(x: np.ndarray, rest: float) -> float:
    """C = θ − θ0 wrapped into (−π, π]."""
    c = dihedral_angle(x) - rest
    return float((c + np.pi) % (2 * np.pi) - np.pi) if abs(c) > np.pi else float(c)


def dihedral_grad(x: np.ndarray) -> np.ndarray:
    """[4, 3] ∇θ from rigid rotations of each wing about the hinge.

    Moving x2 by δ along n̂1 turns wing 1 by δ/h1 about +ê, which lowers θ: ∇_2 = −n̂1/h1 (h1 the distance
    of x2 from the hinge line); likewise ∇_3 = −n̂2/h2. A hinge vertex moving along n̂1 tilts wing 1 about
    the axis through the other hinge vertex and x2, with lever 1 − s (x0) or s (x1), s the hinge coordinate
    of x2's foot point.
    """
    x0, x1, x2, x3 = x
    e = x1 - x0
    L = np.linalg.norm(e)
    eh = e / L
    out = np.zeros((4, 3))
    for opp, (n_raw, k) in enumerate(((np.cross(e, x2 - x0), 2), (np.cross(x3 - x0, e), 3))):
        del opp
        xk = x[k]
        s = (xk - x0) @ eh / L
        foot = x0 + s * e
        h = np.linalg.norm(xk - foot)
        g = -(n_raw / np.linalg.norm(n_raw)) / h
        out[k] += g
        out[0] -= (1.0 - s) * g
        out[1] -= s * g
    return out


# ---------------------------------------------------------------------- volume
def volume_c(x: np.ndarray, rest: float) -> float:
    """C = det[x1 − x0, x2 − x0, x3 − x0]/6 − V0."""
    return float(np.linalg.det(np.stack([x[1] - x[0], x[2] - x[0], x[3] - x[0]], axis=1)) / 6.0 - rest)


def volume_grad(x: np.ndarray) -> np.ndarray:
    """[4, 3] by cofactors: ∂det(D)/∂D = det(D) D⁻ᵀ."""
    D = np.stack([x[1] - x[0], x[2] - x[0], x[3] - x[0]], axis=1)
    G = np.linalg.det(D) * np.linalg.inv(D).T / 6.0  # column k = ∂V/∂x_{k+1}
    g = G.T
    return np.concatenate([-g.sum(axis=0, keepdims=True), g])


# ---------------------------------------------------------------------- ground and contacts
def ground_c(x: np.ndarray, normal: np.ndarray, d: float, r: float) -> float:
    """C = n·x + d − r."""
    return float(normal @ x + d - r)


def point_triangle_c(x: np.ndarray, side: float, h: float) -> float:
    """C = s (q − x1)·n̂ − h, x = [q, x1, x2, x3]."""
    q, x1, x2, x3 = x
    n = np.cross(x2 - x1, x3 - x1)
    return float(side * (q - x1) @ n / np.linalg.norm(n) - h)


def point_triangle_grad(x: np.ndarray, side: float) -> np.ndarray:
    """[4, 3] by the chain rule through N = a × b: ∂n̂/∂N = (I − n̂n̂ᵀ)/|N|, ∂N/∂a = −[b]×, ∂N/∂b = [a]×."""
    q, x1, x2, x3 = x
    a, b = x2 - x1, x3 - x1
    N = np.cross(a, b)
    nn = np.linalg.norm(N)
    nh = N / nn
    r = q - x1
    dn_dN = (np.eye(3) - np.outer(nh, nh)) / nn

    def skew(v):
        return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])

    dC_dN = dn_dN.T @ r
    ga = -skew(b).T @ dC_dN
    gb = skew(a).T @ dC_dN
    gq = nh
    g1 = -nh - ga - gb
    return side * np.stack([gq, g1, ga, gb])


# ---------------------------------------------------------------------- projections
def xpbd_project(x: np.ndarray, w: np.ndarray, c: float, grad: np.ndarray, alpha_tilde: float, lam: float):
    """One XPBD projection: returns (x + wΔλ∇C, λ + Δλ)."""
    dl = -(c + alpha_tilde * lam) / (np.sum(w[:, None] * grad * grad) + alpha_tilde)
    return x + (w * dl)[:, None] * grad, lam + dl


def polar_rotation(A: np.ndarray) -> np.ndarray:
    """Closest rotation to A (SVD with the reflection fixed)."""
    U, _, Vt = np.linalg.svd(A)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def shape_match(p: np.ndarray, rest: np.ndarray, m: np.ndarray, k: float) -> np.ndarray:
    """Δp_i = k [R(p̄_i − c̄) + c − p_i] with A = Σ m_i (p_i − c)(p̄_i − c̄)ᵀ."""
    c = m @ p / m.sum()
    cb = m @ rest / m.sum()
    A = ((p - c) * m[:, None]).T @ (rest - cb)
    R = polar_rotation(A)
    return k * ((rest - cb) @ R.T + c - p)


def ellipsoid_moment(m: float, radii: np.ndarray, R: np.ndarray, n: int = 40) -> np.ndarray:
    """∫ρ (R y) yᵀ dV over a solid ellipsoid of mass m by midpoint quadrature on an n³ grid."""
    t = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    u = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    u = u[np.sum(u * u, axis=1) <= 1.0]
    y = u * radii
    mk = m / len(y)
    return mk * (y @ R.T).T @ y
