"""Float64 NumPy oracles for the FEM maths of ``pliant.energies._fem_math``.

Written for clarity, one element at a time, with formulas derived independently of the Warp code
(Kronecker-product forms, a Sylvester equation for ∂R/∂F, a full 9×9 eigendecomposition for the PSD
projection). Conventions as in the Warp module: ``vec(F)`` stacks columns (``F.reshape(9, order="F")``),
``dPdF[a, b] = ∂vec(P)_a / ∂vec(F)_b``; for the element, the 12-vector ``x`` stacks x0, x1, x2, x3.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

I3 = np.eye(3)
I9 = np.eye(9)


def vec(M: np.ndarray) -> np.ndarray:
    """Column-major flattening of a 3×3 matrix."""
    return np.asarray(M, dtype=np.float64).reshape(9, order="F")


def unvec(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`vec`."""
    return np.asarray(v, dtype=np.float64).reshape(3, 3, order="F")


def commutation_matrix() -> np.ndarray:
    """K with K vec(X) = vec(Xᵀ)."""
    K = np.zeros((9, 9))
    for i in range(3):
        for j in range(3):
            K[j + 3 * i, i + 3 * j] = 1.0
    return K


K9 = commutation_matrix()


def lame_parameters(E: float, nu: float) -> tuple[float, float]:
    """μ = E / (2(1 + ν)), λ = E ν / ((1 + ν)(1 − 2ν))."""
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


# ---------------------------------------------------------------------------------------------- kinematics


def tet_rest_matrix(X: np.ndarray) -> np.ndarray:
    """Dm = [X1 − X0, X2 − X0, X3 − X0] for X of shape [4, 3]."""
    X = np.asarray(X, dtype=np.float64)
    return np.column_stack([X[1] - X[0], X[2] - X[0], X[3] - X[0]])


def tet_volume(X: np.ndarray) -> float:
    """Signed rest volume det(Dm) / 6."""
    return float(np.linalg.det(tet_rest_matrix(X)) / 6.0)


def deformation_gradient(x: np.ndarray, X: np.ndarray) -> np.ndarray:
    """F = Ds Dm⁻¹."""
    return tet_rest_matrix(x) @ np.linalg.inv(tet_rest_matrix(X))


def green_strain(F: np.ndarray) -> np.ndarray:
    """E = ½(FᵀF − I)."""
    return 0.5 * (F.T @ F - I3)


def small_strain(F: np.ndarray) -> np.ndarray:
    """ε = ½(F + Fᵀ) − I."""
    return 0.5 * (F + F.T) - I3


def polar_rotation(F: np.ndarray) -> np.ndarray:
    """R of F = R S with det R = +1 (SVD with the reflection moved into the last singular value)."""
    U, _, Vt = np.linalg.svd(F)
    if np.linalg.det(U @ Vt) < 0.0:
        U[:, 2] *= -1.0
    return U @ Vt


def cofactor(F: np.ndarray) -> np.ndarray:
    """∂ det F / ∂F = det(F) F⁻ᵀ."""
    return np.linalg.det(F) * np.linalg.inv(F).T


def dcofactor_dF(F: np.ndarray) -> np.ndarray:
    """∂vec(cof F)/∂vec(F) = J (vec(F⁻ᵀ) vec(F⁻ᵀ)ᵀ − (F⁻¹ ⊗ F⁻ᵀ) K)."""
    J = np.linalg.det(F)
    Fit = np.linalg.inv(F).T
    return J * (np.outer(vec(Fit), vec(Fit)) - np.kron(Fit.T, Fit) @ K9)


def drotation_dF(F: np.ndarray) -> np.ndarray:
    """∂vec(R)/∂vec(F) from F = R S: dR = R W, W skew, W S + S W = Rᵀ dF − dFᵀ R (needs det F > 0)."""
    R = polar_rotation(F)
    S = R.T @ F
    S = 0.5 * (S + S.T)
    L = np.kron(S, I3) + np.kron(I3, S)  # vec(W S + S W) = (Sᵀ ⊗ I + I ⊗ S) vec W
    out = np.zeros((9, 9))
    for b in range(9):
        dF = unvec(I9[b])
        W = unvec(np.linalg.solve(L, vec(R.T @ dF - dF.T @ R)))
        out[:, b] = vec(R @ W)
    return out


# ----------------------------------------------------------------------------------------------- materials


def linear_psi(F, mu, lam):
    eps = small_strain(F)
    return mu * np.sum(eps * eps) + 0.5 * lam * np.trace(eps) ** 2


def linear_pk1(F, mu, lam):
    eps = small_strain(F)
    return 2.0 * mu * eps + lam * np.trace(eps) * I3


def linear_dpk1_df(F, mu, lam):
    return mu * (I9 + K9) + lam * np.outer(vec(I3), vec(I3))


def stvk_psi(F, mu, lam):
    E = green_strain(F)
    return mu * np.sum(E * E) + 0.5 * lam * np.trace(E) ** 2


def stvk_pk1(F, mu, lam):
    E = green_strain(F)
    return F @ (2.0 * mu * E + lam * np.trace(E) * I3)


def stvk_dpk1_df(F, mu, lam):
    """dP = dF S + μ F dFᵀ F + μ F Fᵀ dF + λ (F:dF) F."""
    E = green_strain(F)
    S = 2.0 * mu * E + lam * np.trace(E) * I3
    return (
        np.kron(S.T, I3)
        + mu * np.kron(F.T, F) @ K9
        + mu * np.kron(I3, F @ F.T)
        + lam * np.outer(vec(F), vec(F))
    )


def corotated_psi(F, mu, lam):
    D = F - polar_rotation(F)
    return mu * np.sum(D * D) + 0.5 * lam * (np.linalg.det(F) - 1.0) ** 2


def corotated_pk1(F, mu, lam):
    return 2.0 * mu * (F - polar_rotation(F)) + lam * (np.linalg.det(F) - 1.0) * cofactor(F)


def corotated_dpk1_df(F, mu, lam):
    g = vec(cofactor(F))
    J = np.linalg.det(F)
    return 2.0 * mu * (I9 - drotation_dF(F)) + lam * np.outer(g, g) + lam * (J - 1.0) * dcofactor_dF(F)


def neohookean_psi(F, mu, lam):
    """Stable neo-Hookean without the log term, λ̃ = λ + μ."""
    J = np.linalg.det(F)
    return 0.5 * mu * (np.sum(F * F) - 3.0) - mu * (J - 1.0) + 0.5 * (lam + mu) * (J - 1.0) ** 2


def neohookean_pk1(F, mu, lam):
    J = np.linalg.det(F)
    return mu * F + ((lam + mu) * (J - 1.0) - mu) * cofactor(F)


def neohookean_dpk1_df(F, mu, lam):
    J = np.linalg.det(F)
    g = vec(cofactor(F))
    return mu * I9 + (lam + mu) * np.outer(g, g) + ((lam + mu) * (J - 1.0) - mu) * dcofactor_dF(F)


MATERIALS: dict[str, tuple[Callable, Callable, Callable]] = {
    "linear": (linear_psi, linear_pk1, linear_dpk1_df),
    "stvk": (stvk_psi, stvk_pk1, stvk_dpk1_df),
    "corotated": (corotated_psi, corotated_pk1, corotated_dpk1_df),
    "neohookean": (neohookean_psi, neohookean_pk1, neohookean_dpk1_df),
}
"""name -> (psi, pk1, dpk1_df), each taking (F, mu, lam)."""


def project_psd(H: np.ndarray) -> np.ndarray:
    """Clamp the eigenvalues of the symmetric part of H at 0."""
    w, Q = np.linalg.eigh(0.5 * (H + H.T))
    return (Q * np.maximum(w, 0.0)) @ Q.T


# ------------------------------------------------------------------------------------------------- element


def shape_gradients(X: np.ndarray) -> np.ndarray:
    """G [4, 3] with ∂F_ij/∂x_a,l = δ_il G[a, j]."""
    Dm_inv = np.linalg.inv(tet_rest_matrix(X))
    return np.vstack([-Dm_inv.sum(axis=0), Dm_inv])


def dF_dx(X: np.ndarray) -> np.ndarray:
    """B [9, 12] with vec(dF) = B dx, x = (x0, x1, x2, x3)."""
    G = shape_gradients(X)
    B = np.zeros((9, 12))
    for a in range(4):
        for l in range(3):
            dF = np.zeros((3, 3))
            dF[l, :] = G[a]
            B[:, 3 * a + l] = vec(dF)
    return B


def tet_energy(x: np.ndarray, X: np.ndarray, psi: Callable, mu: float, lam: float) -> float:
    """V ψ(F)."""
    return tet_volume(X) * psi(deformation_gradient(x, X), mu, lam)


def tet_forces(x: np.ndarray, X: np.ndarray, pk1: Callable, mu: float, lam: float) -> np.ndarray:
    """f [4, 3] = −∂(V ψ)/∂x = −V Bᵀ vec(P)."""
    P = pk1(deformation_gradient(x, X), mu, lam)
    return (-tet_volume(X) * dF_dx(X).T @ vec(P)).reshape(4, 3)


def tet_hessian(x: np.ndarray, X: np.ndarray, dpk1: Callable, mu: float, lam: float, project=False):
    """H [12, 12] = V Bᵀ (∂P/∂F) B (with ∂P/∂F PSD-projected when ``project``)."""
    A = dpk1(deformation_gradient(x, X), mu, lam)
    if project:
        A = project_psd(A)
    B = dF_dx(X)
    return tet_volume(X) * B.T @ A @ B


# ------------------------------------------------------------------------------------------------- helpers


def central_diff(f: Callable[[np.ndarray], np.ndarray | float], x: np.ndarray, h: float) -> np.ndarray:
    """∂f/∂x by central differences; result shape = shape(f(x)) + shape(x)."""
    x = np.asarray(x, dtype=np.float64)
    f0 = np.asarray(f(x))
    out = np.zeros(f0.shape + x.shape)
    for idx in np.ndindex(x.shape):
        xp = x.copy()
        xm = x.copy()
        xp[idx] += h
        xm[idx] -= h
        out[(Ellipsis, *idx)] = (np.asarray(f(xp)) - np.asarray(f(xm))) / (2.0 * h)
    return out


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly distributed rotation (det = +1)."""
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    Q = Q * np.sign(np.diag(R))
    if np.linalg.det(Q) < 0.0:
        Q[:, 0] *= -1.0
    return Q


def random_deformations(rng, count: int, *, near_rest: bool) -> list[np.ndarray]:
    """Near rest: I + 0.05 N(0, 1). Far: U diag(σ) Vᵀ with σ in [0.6, 2] (det ≥ 0.216)."""
    if near_rest:
        return [I3 + 0.05 * rng.standard_normal((3, 3)) for _ in range(count)]
    return [
        random_rotation(rng) @ np.diag(rng.uniform(0.6, 2.0, 3)) @ random_rotation(rng).T
        for _ in range(count)
    ]
