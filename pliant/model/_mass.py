"""Mass matrices for tetrahedral, triangle and spring meshes (NumPy / SciPy, float64, host side).

The consistent mass matrix of a linear tetrahedron follows from the kinetic energy
T = ½ q̇ᵀ (∫_Ω ρ Nᵀ N dΩ) q̇ with N = [φ0 I, φ1 I, φ2 I, φ3 I]; in barycentric coordinates
dΩ = 6V dφ1 dφ2 dφ3 and 6 ∫ φ_r φ_s = (1 + δ_rs) / 20, so M_rs = ρV/10 (r = s) and ρV/20 (r ≠ s).
Row sums give the lumped mass ρV/4 per vertex.

:func:`distribute_mass` spreads an object's total mass M otherwise (issue 38): evenly per particle (M/N, as
MuJoCo's flexcomp and PhysTwin do), a blend m = (1 − α) m_lumped + α M/N, and a smooth density field
ρ(x) ∝ exp(a · x̂) over the normalised rest coordinates x̂ ∈ [−1, 1]³, renormalised so that Σ m = M.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = [
    "MASS_DISTRIBUTIONS",
    "distribute_mass",
    "distribute_mass_grad",
    "normalised_coordinates",
    "spring_lumped_mass",
    "tet_consistent_mass",
    "tet_lumped_mass",
    "tet_volumes",
    "triangle_lumped_mass",
]


def _check_points(points: np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {points.shape}")
    return points


def _check_cells(cells: np.ndarray, arity: int, name: str, point_count: int) -> np.ndarray:
    cells = np.asarray(cells)
    if cells.ndim != 2 or cells.shape[1] != arity:
        raise ValueError(f"{name} must have shape [M, {arity}], got {cells.shape}")
    if cells.size and not np.issubdtype(cells.dtype, np.integer):
        raise ValueError(f"{name} must hold integer vertex indices, got dtype {cells.dtype}")
    cells = cells.astype(np.int64, copy=False)
    if cells.size and (cells.min() < 0 or cells.max() >= point_count):
        raise ValueError(
            f"{name} index vertices in [{cells.min()}, {cells.max()}], but there are {point_count} points"
        )
    return cells


def _check_density(density: float | np.ndarray, count: int, name: str) -> np.ndarray:
    rho = np.asarray(density, dtype=np.float64)
    if rho.ndim == 0:
        rho = np.full(count, float(rho))
    if rho.shape != (count,):
        raise ValueError(f"{name} must be a scalar or have shape [{count}], got {rho.shape}")
    if not np.all(np.isfinite(rho)) or np.any(rho <= 0.0):
        bad = np.flatnonzero(~(np.isfinite(rho) & (rho > 0.0)))
        raise ValueError(
            f"{name} must be finite and > 0; {bad.size} entries are not (first: {bad[:5].tolist()})"
        )
    return rho


def tet_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes det[X1 − X0, X2 − X0, X3 − X0] / 6.

    Args:
        points: Rest positions [m], shape [N, 3].
        tets: Vertex indices, shape [E, 4].

    Returns:
        Volumes [m³], shape [E]; positive for right-handed tetrahedra.
    """
    points = _check_points(points)
    tets = _check_cells(tets, 4, "tets", len(points))
    X = points[tets]
    d1, d2, d3 = X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]
    return np.einsum("ij,ij->i", d1, np.cross(d2, d3)) / 6.0


def tet_consistent_mass(
    points: np.ndarray, tets: np.ndarray, density: float | np.ndarray, *, per_dof: bool = True
) -> sp.csr_matrix:
    """Consistent mass matrix of linear tetrahedra: M_rs = ρV/10 (r = s), ρV/20 (r ≠ s) per element.

    Args:
        points: Rest positions [m], shape [N, 3].
        tets: Vertex indices, shape [E, 4]. Orientation does not matter (|V| is used).
        density: Mass density ρ [kg/m³], scalar or shape [E].
        per_dof: If True, return the 3N×3N matrix M ⊗ I₃ (degrees of freedom ordered x0, y0, z0, x1, ...);
            otherwise the N×N scalar matrix.

    Returns:
        Symmetric positive semi-definite ``scipy.sparse.csr_matrix`` [kg], shape [3N, 3N] or [N, N].
    """
    points = _check_points(points)
    tets = _check_cells(tets, 4, "tets", len(points))
    rho = _check_density(density, len(tets), "density")
    n = len(points)
    m = rho * np.abs(tet_volumes(points, tets))  # element masses ρV
    local = (np.ones((4, 4)) + np.eye(4)) / 20.0  # 6 ∫ φ_r φ_s dφ = (1 + δ_rs) / 20
    rows = np.repeat(tets, 4, axis=1).ravel()  # r index of (r, s) pairs, row-major over the 4×4 block
    cols = np.tile(tets, (1, 4)).ravel()
    vals = (m[:, None, None] * local[None]).ravel()
    if per_dof:
        rows = (3 * rows[:, None] + np.arange(3)).ravel()
        cols = (3 * cols[:, None] + np.arange(3)).ravel()
        vals = np.repeat(vals, 3)
        n *= 3
    import scipy.sparse as sp  # here, not at import: a cloth or rope model never needs SciPy (27 MB)

    return sp.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()


def tet_lumped_mass(points: np.ndarray, tets: np.ndarray, density: float | np.ndarray) -> np.ndarray:
    """Lumped (row-sum) mass of linear tetrahedra: ρ|V|/4 to each of the 4 vertices.

    Args:
        points: Rest positions [m], shape [N, 3].
        tets: Vertex indices, shape [E, 4].
        density: Mass density ρ [kg/m³], scalar or shape [E].

    Returns:
        Particle masses [kg], shape [N] (0 for points in no tetrahedron).
    """
    points = _check_points(points)
    tets = _check_cells(tets, 4, "tets", len(points))
    rho = _check_density(density, len(tets), "density")
    m = rho * np.abs(tet_volumes(points, tets)) / 4.0
    return np.bincount(tets.ravel(), weights=np.repeat(m, 4), minlength=len(points))


def triangle_lumped_mass(
    points: np.ndarray, tris: np.ndarray, areal_density: float | np.ndarray
) -> np.ndarray:
    """Lumped mass of a triangle mesh (cloth): ρ_A A/3 to each of the 3 vertices.

    Args:
        points: Rest positions [m], shape [N, 3].
        tris: Vertex indices, shape [T, 3].
        areal_density: Mass per area ρ_A [kg/m²], scalar or shape [T].

    Returns:
        Particle masses [kg], shape [N].
    """
    points = _check_points(points)
    tris = _check_cells(tris, 3, "tris", len(points))
    rho = _check_density(areal_density, len(tris), "areal_density")
    X = points[tris]
    area = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)
    return np.bincount(tris.ravel(), weights=np.repeat(rho * area / 3.0, 3), minlength=len(points))


def spring_lumped_mass(
    points: np.ndarray, edges: np.ndarray, linear_density: float | np.ndarray
) -> np.ndarray:
    """Lumped mass of a rod / spring network: ρ_L L/2 to each end of every edge.

    Args:
        points: Rest positions [m], shape [N, 3].
        edges: Vertex indices, shape [S, 2].
        linear_density: Mass per length ρ_L [kg/m], scalar or shape [S].

    Returns:
        Particle masses [kg], shape [N].
    """
    points = _check_points(points)
    edges = _check_cells(edges, 2, "edges", len(points))
    rho = _check_density(linear_density, len(edges), "linear_density")
    length = np.linalg.norm(points[edges[:, 1]] - points[edges[:, 0]], axis=1)
    return np.bincount(edges.ravel(), weights=np.repeat(rho * length / 2.0, 2), minlength=len(points))


#: The names of ``mass_distribution`` in a scene file: ``lumped`` (area / volume / length weighted, the
#: builders' own) and ``uniform`` (M / N per particle).
MASS_DISTRIBUTIONS = ("lumped", "uniform")


def normalised_coordinates(points: np.ndarray) -> np.ndarray:
    """Rest positions mapped to [−1, 1] per axis over their bounding box (0 along an axis they do not span,
    e.g. the normal of a flat cloth).

    Args:
        points: Rest positions [m], shape [N, 3].

    Returns:
        x̂, shape [N, 3], dimensionless.
    """
    points = _check_points(points)
    if points.shape[0] == 0:
        return points.copy()
    lo, hi = points.min(axis=0), points.max(axis=0)
    half = 0.5 * (hi - lo)
    spans = half > 1e-12 * max(float(np.abs(points).max()), 1.0)
    out = np.zeros_like(points)
    out[:, spans] = (points[:, spans] - 0.5 * (hi + lo)[spans]) / half[spans]
    return out


def distribute_mass(
    lumped: np.ndarray,
    points: np.ndarray,
    *,
    uniformity: float = 0.0,
    slope: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """An object's particle masses with its total kept: the blend of the lumped masses and an even split,
    weighted by a smooth density field.

    m_i = M · w_i / Σ_j w_j, with w_i = [(1 − α) m_lumped,i + α M/N] · exp(a · x̂_i), M = Σ m_lumped and x̂
    the normalised rest coordinates (:func:`normalised_coordinates`). α = 0, a = 0 returns ``lumped`` itself
    (the same array values, bit for bit); α = 1, a = 0 gives M/N to every particle. A density
    ρ(x) = ρ̄ exp(a · x̂) lumped to the particles is m_i ∝ ρ(x_i) m_lumped,i; the renormalisation is the
    constraint ∫ρ dV = M.

    Args:
        lumped: The builder's masses [kg], shape [N], all > 0.
        points: Rest positions [m], shape [N, 3].
        uniformity: α ∈ [0, 1]: 0 lumped, 1 uniform per particle.
        slope: a, the density's log-gradient per normalised axis (x, y, z), dimensionless: the density
            at the +x end of the box is exp(2 aₓ) times that at the −x end.

    Returns:
        Masses [kg], shape [N], float64, summing to Σ ``lumped`` (to rounding).

    Raises:
        ValueError: masses not positive and finite, shapes that disagree, α outside [0, 1], a slope not three
            finite numbers.
    """
    m0 = np.asarray(lumped, dtype=np.float64)
    points = _check_points(points)
    if m0.shape != (points.shape[0],):
        raise ValueError(f"lumped masses have shape {m0.shape}; expected [{points.shape[0]}], one per point")
    if not np.all(np.isfinite(m0) & (m0 > 0.0)):
        raise ValueError("lumped masses must be finite and > 0 kg; pin particles that must not move instead")
    if not 0.0 <= float(uniformity) <= 1.0:
        raise ValueError(f"mass uniformity must be in [0, 1] (0 lumped, 1 uniform), got {uniformity}")
    a = np.asarray(slope, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"mass slope must be three finite numbers (x, y, z), got {slope!r}")
    alpha = float(uniformity)
    if alpha == 0.0 and not np.any(a):
        return m0
    total = float(m0.sum())
    w = (1.0 - alpha) * m0 + alpha * (total / m0.size) if alpha < 1.0 else np.full_like(m0, total / m0.size)
    if np.any(a):
        x = normalised_coordinates(points) @ a
        w = w * np.exp(x - x.max())  # shifted: the ratio is what counts, and exp never overflows
    elif alpha == 1.0:
        return w
    return w * (total / float(w.sum()))


def distribute_mass_grad(
    lumped: np.ndarray,
    points: np.ndarray,
    grad_mass: np.ndarray,
    *,
    uniformity: float = 0.0,
    slope: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
) -> tuple[float, np.ndarray]:
    """The chain rule through :func:`distribute_mass`: ∂L/∂α and ∂L/∂a from ∂L/∂m (e.g. a rollout's
    ``grads["particle_mass"]``, which already folds in ∂L/∂(1/m)).

    With S = Σ w and m = M w / S: ∂m_i/∂θ = (M / S) (∂w_i/∂θ − (m_i / M) Σ_j ∂w_j/∂θ), where
    ∂w_i/∂α = (M/N − m_lumped,i) exp(a · x̂_i) and ∂w_i/∂a_k = w_i x̂_ik.

    Args:
        lumped: The builder's masses [kg], shape [N].
        points: Rest positions [m], shape [N, 3].
        grad_mass: ∂L/∂m [L/kg], shape [N].
        uniformity: α ∈ [0, 1].
        slope: a (x, y, z), dimensionless.

    Returns:
        (∂L/∂α [L], ∂L/∂a [L] shape [3]).

    Raises:
        ValueError: as :func:`distribute_mass`, or ``grad_mass`` of another shape or not finite.
    """
    m = distribute_mass(lumped, points, uniformity=uniformity, slope=slope)  # checks the inputs
    g = np.asarray(grad_mass, dtype=np.float64)
    if g.shape != m.shape or not np.all(np.isfinite(g)):
        raise ValueError(f"grad_mass must be finite with shape {m.shape}, got {g.shape}")
    m0 = np.asarray(lumped, dtype=np.float64)
    total, alpha = float(m0.sum()), float(uniformity)
    xh = normalised_coordinates(points)
    x = xh @ np.asarray(slope, dtype=np.float64)
    e = np.exp(x - x.max())
    w = ((1.0 - alpha) * m0 + alpha * (total / m0.size)) * e
    scale = total / float(w.sum())
    gm = float(g @ m) / total

    def project(dw: np.ndarray) -> float:
        return scale * (float(g @ dw) - gm * float(dw.sum()))

    d_alpha = project((total / m0.size - m0) * e)
    d_slope = np.array([project(w * xh[:, k]) for k in range(3)])
    return d_alpha, d_slope
