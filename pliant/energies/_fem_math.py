"""Per-element FEM maths for linear tetrahedra, as Warp functions generic over float32 / float64.

Everything here is a ``@wp.func``: the energy classes write the kernels that call them. Every function is
generic (``typing.Any`` annotations); Warp instantiates one overload per scalar type at launch, so the same
code serves ``wp.mat33`` / ``wp.float32`` and ``wp.mat33d`` / ``wp.float64`` models. ``mu`` and ``lam`` must
have the same scalar type as ``F`` (pass ``wp.float64(mu)`` to a float64 kernel).

Conventions
-----------
* ``Dm = [X1 - X0, X2 - X0, X3 - X0]`` (rest edge matrix, columns), ``Ds`` likewise for the deformed
  positions, deformation gradient ``F = Ds Dm⁻¹``, rest volume ``V = det(Dm) / 6``.
* ``vec(F)`` stacks the columns of ``F`` (column-major flattening): ``vec(F)[i + 3 j] = F[i, j]``.
* ``dP/dF`` is a 9×9 matrix (``mat99f`` or ``mat99d``, whichever matches the scalar type) with
  ``dPdF[i + 3 j, k + 3 l] = ∂P_ij / ∂F_kl = ∂²ψ / ∂F_ij ∂F_kl``; it is symmetric. Inside a generic
  function the type is written ``wp.matrix(shape=(9, 9), dtype=type(F).dtype)``; kernels that store it
  use arrays of :data:`mat99f` / :data:`mat99d` (see :func:`mat99_type`).
* Element forces ``f_a = -V P g_a`` and Hessian blocks ``H_ab = V Σ_jq g_a[j] g_b[q] dPdF[3j:3j+3, 3q:3q+3]``,
  where ``g_a = ∂F/∂x_a`` row vectors (:func:`tet_shape_gradient`). The 16 blocks ``H_ab`` (a, b in 0..3)
  are what an implicit solver atomically adds into a BSR(3×3) matrix.

Materials (ψ in J/m³, Lamé parameters ``mu``, ``lam`` in Pa)
--------------------------------------------------------------
* linear:     ψ = μ ε:ε + λ/2 tr(ε)²,  ε = ½(F + Fᵀ) − I. Not rotation invariant.
* stvk:       ψ = μ E:E + λ/2 tr(E)²,  E = ½(FᵀF − I) (St. Venant–Kirchhoff).
* corotated:  ψ = μ ‖F − R‖² + λ/2 (J − 1)²,  F = R S polar decomposition with det R = +1.
* neohookean: stable neo-Hookean (Smith, de Goes, Kim 2018, "Stable Neo-Hookean Flesh Simulation",
  ACM TOG 37(2)), without the log(I_C + 1) term:
  ψ = μ/2 (I_C − 3) − μ (J − 1) + λ̃/2 (J − 1)²,  λ̃ = λ + μ.
  This equals the paper's μ/2 (I_C − 3) + λ̃/2 (J − α)² with α = 1 + μ/λ̃, minus the constant μ²/(2λ̃),
  so that ψ = 0 and P = 0 at rest, and its small-strain limit is linear elasticity with Lamé (μ, λ).
  It stays finite for inverted elements (J ≤ 0).

PSD projection (``*_dpk1_df_psd``) uses the analytic eigensystem of isotropic energies (Smith, de Goes,
Kim 2019, "Analytic Eigensystems for Isotropic Distortion Energies", ACM TOG 38(1)): with the
rotation-variant SVD F = U diag(σ) Vᵀ (det U = det V = +1, σ₃ carries the sign of J), the 9 eigenvectors
are the 3 "twist" modes U (e_i e_jᵀ − e_j e_iᵀ) Vᵀ/√2, the 3 "flip" modes U (e_i e_jᵀ + e_j e_iᵀ) Vᵀ/√2
with eigenvalues (ψ_i + ψ_j)/(σ_i + σ_j) and (ψ_i − ψ_j)/(σ_i − σ_j) (written in closed form per material,
with no division by σ_i − σ_j), and 3 "scaling" modes from the 3×3 Hessian ∂²ψ/∂σ². The projection
subtracts the negative part, dPdF − Σ_{λ<0} λ q qᵀ, so an already-PSD matrix comes back unchanged.
"""

from __future__ import annotations

from typing import Any

import warp as wp

mat99f = wp.types.matrix(shape=(9, 9), dtype=wp.float32)
"""9×9 float32 matrix type for ``dP/dF`` arrays."""
mat99d = wp.types.matrix(shape=(9, 9), dtype=wp.float64)
"""9×9 float64 matrix type for ``dP/dF`` arrays."""


def mat99_type(dtype: type) -> type:
    """The 9×9 matrix type (``mat99f`` or ``mat99d``) for a Warp scalar type.

    Args:
        dtype: ``wp.float32`` or ``wp.float64`` (``"float32"`` / ``"float64"`` accepted too).

    Returns:
        The matching 9×9 Warp matrix type.
    """
    if dtype in (wp.float32, "float32"):
        return mat99f
    if dtype in (wp.float64, "float64"):
        return mat99d
    raise ValueError(f"dtype must be wp.float32 or wp.float64, got {dtype!r}")


def declare_overloads(kernels: tuple, dtype: str, inputs: Any) -> None:
    """Declare the ``dtype`` overloads of (value, gradient, Hessian, exact Hessian) element kernels.

    ``inputs(s, m33)`` maps the kernels' generic per-element inputs to their types given the scalar and
    3×3 matrix types; ``x_in`` (vec3) and the outputs (``out``, ``grad_out``, ``scale``, ``values_out``)
    are added here. Shared by the linear (:mod:`._fem`) and the quadratic (:mod:`._fem_p2`) tets, so it
    lives here, below both.
    """
    s = wp.float32 if dtype == "float32" else wp.float64
    v3 = wp.types.vector(3, s)
    m33 = wp.types.matrix((3, 3), s)
    common: dict[str, wp.array] = {k: wp.array(dtype=t) for k, t in inputs(s, m33).items()}
    common["x_in"] = wp.array(dtype=v3)
    wp.overload(kernels[0], {**common, "out": wp.array(dtype=s)})
    wp.overload(kernels[1], {**common, "out": wp.array(dtype=s), "grad_out": wp.array(dtype=v3)})
    for hessian in kernels[2:]:  # projected, exact
        wp.overload(hessian, {**common, "scale": s, "values_out": wp.array(dtype=m33)})


# ----------------------------------------------------------------------------------------------------------
# Kinematics
# ----------------------------------------------------------------------------------------------------------


@wp.func
def tet_rest_matrix(X0: Any, X1: Any, X2: Any, X3: Any):
    """Dm = [X1 − X0, X2 − X0, X3 − X0] (edge vectors as columns)."""
    return wp.matrix_from_cols(X1 - X0, X2 - X0, X3 - X0)


@wp.func
def tet_signed_volume(Dm: Any):
    """V = det(Dm) / 6 (positive for a right-handed tetrahedron)."""
    return wp.determinant(Dm) / type(Dm[0, 0])(6.0)


@wp.func
def deformation_gradient(x0: Any, x1: Any, x2: Any, x3: Any, Dm_inv: Any):
    """F = Ds Dm⁻¹ with Ds = [x1 − x0, x2 − x0, x3 − x0]."""
    return wp.matrix_from_cols(x1 - x0, x2 - x0, x3 - x0) * Dm_inv


@wp.func
def tet_deformation_gradient(tet_indices: wp.array2d(dtype=wp.int32), t: int, x_in: Any, Dm_inv: Any):
    """F of linear tet ``t`` (vertices ``tet_indices[t]``) at positions ``x_in``: the per-element gather every
    tet kernel starts with."""
    return deformation_gradient(
        x_in[tet_indices[t, 0]],
        x_in[tet_indices[t, 1]],
        x_in[tet_indices[t, 2]],
        x_in[tet_indices[t, 3]],
        Dm_inv,
    )


@wp.func
def green_strain(F: Any):
    """E = ½ (FᵀF − I)."""
    return type(F[0, 0])(0.5) * (wp.transpose(F) * F - wp.identity(n=3, dtype=type(F).dtype))


@wp.func
def small_strain(F: Any):
    """ε = ½ (F + Fᵀ) − I."""
    return type(F[0, 0])(0.5) * (F + wp.transpose(F)) - wp.identity(n=3, dtype=type(F).dtype)


@wp.func
def cofactor(F: Any):
    """cof(F) = ∂ det(F) / ∂F = det(F) F⁻ᵀ (columns: f1 × f2, f2 × f0, f0 × f1)."""
    c0 = wp.vector(F[0, 0], F[1, 0], F[2, 0])
    c1 = wp.vector(F[0, 1], F[1, 1], F[2, 1])
    c2 = wp.vector(F[0, 2], F[1, 2], F[2, 2])
    return wp.matrix_from_cols(wp.cross(c1, c2), wp.cross(c2, c0), wp.cross(c0, c1))


@wp.func
def svd_rv(F: Any):
    """Rotation-variant SVD F = U diag(σ) Vᵀ, det U = det V = +1, |σ| sorted decreasing, sign(σ₂) = sign(J).

    ``wp.svd3`` runs a fixed number of Jacobi sweeps, which leaves float32 residuals near 1e-3 when two
    singular values are close; a second ``svd3`` of the nearly diagonal Uᵀ F V polishes them to ~1e-6.
    """
    U1, s1, V1 = wp.svd3(F)
    U2, s, V2 = wp.svd3(wp.transpose(U1) * F * V1)
    return U1 * U2, s, V1 * V2


@wp.func
def polar_rotation(F: Any):
    """R = U Vᵀ of the rotation-variant SVD: the rotation (det R = +1) of the polar decomposition F = R S."""
    U, s, V = svd_rv(F)
    return U * wp.transpose(V)


@wp.func
def _levi_civita_pair(i: int, k: int):
    """ε_{i k m} for i ≠ k, m = 3 − i − k: +1 when (i, k, m) is cyclic, else −1."""
    s = -1
    if (k - i + 3) % 3 == 1:
        s = 1
    return s


@wp.func
def _det_hessian(F: Any, coeff: Any, H: Any):
    """H + coeff ∂²det(F)/∂F², with ∂²J/∂F_ij ∂F_kl = ε_ikm ε_jln F_mn."""
    for j in range(3):
        for l in range(3):
            if j != l:
                n = 3 - j - l
                s_jl = _levi_civita_pair(j, l)
                for i in range(3):
                    for k in range(3):
                        if i != k:
                            m = 3 - i - k
                            s = s_jl * _levi_civita_pair(i, k)
                            H[i + 3 * j, k + 3 * l] = (
                                H[i + 3 * j, k + 3 * l] + coeff * type(coeff)(s) * F[m, n]
                            )
    return H


@wp.func
def _vec9(M: Any):
    """vec(M): the columns of a 3×3 matrix stacked into a 9-vector."""
    q = wp.vector(length=9, dtype=type(M).dtype)
    for j in range(3):
        for i in range(3):
            q[i + 3 * j] = M[i, j]
    return q


@wp.func
def _pair_mode(U: Any, V: Any, i: int, j: int, sign: Any):
    """vec(U (e_i e_jᵀ + sign e_j e_iᵀ) Vᵀ) / √2: a flip (sign = +1) or twist (sign = −1) eigenvector."""
    q = wp.vector(length=9, dtype=type(U).dtype)
    h = wp.sqrt(type(sign)(0.5))
    for c in range(3):
        for r in range(3):
            q[r + 3 * c] = h * (U[r, i] * V[c, j] + sign * U[r, j] * V[c, i])
    return q


@wp.func
def _scaling_mode(U: Any, V: Any, k: int):
    """vec(u_k v_kᵀ)."""
    q = wp.vector(length=9, dtype=type(U).dtype)
    for c in range(3):
        for r in range(3):
            q[r + 3 * c] = U[r, k] * V[c, k]
    return q


@wp.func
def _project_isotropic(H: Any, U: Any, V: Any, flip: Any, twist: Any, A: Any):
    """H − (negative part of H) from the analytic eigensystem.

    ``flip[k]`` and ``twist[k]`` are the eigenvalues of the pair (i, j) that leaves out k
    (i, j) = ((k + 1) % 3, (k + 2) % 3); ``A`` = ∂²ψ/∂σ² is the 3×3 scaling block.
    """
    zero = type(flip[0])(0.0)
    one = type(flip[0])(1.0)
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        if flip[k] < zero:
            q = _pair_mode(U, V, i, j, one)
            H = H - flip[k] * wp.outer(q, q)
        if twist[k] < zero:
            q = _pair_mode(U, V, i, j, -one)
            H = H - twist[k] * wp.outer(q, q)
    # scaling block: N = Q min(d, 0) Qᵀ, H −= Σ_kl N_kl vec(u_k v_kᵀ) vec(u_l v_lᵀ)ᵀ
    Q, d = wp.eig3(A)
    if wp.min(d) < zero:
        N = wp.matrix(shape=(3, 3), dtype=type(zero))
        for c in range(3):
            if d[c] < zero:
                qc = wp.vector(Q[0, c], Q[1, c], Q[2, c])
                N = N + d[c] * wp.outer(qc, qc)
        D0 = _scaling_mode(U, V, 0)
        D1 = _scaling_mode(U, V, 1)
        D2 = _scaling_mode(U, V, 2)
        D = wp.matrix_from_cols(D0, D1, D2)
        H = H - D * N * wp.transpose(D)
    return H


# ----------------------------------------------------------------------------------------------------------
# Linear elasticity
# ----------------------------------------------------------------------------------------------------------


@wp.func
def linear_psi(F: Any, mu: Any, lam: Any):
    """ψ = μ ε:ε + λ/2 tr(ε)², ε = ½(F + Fᵀ) − I."""
    eps = small_strain(F)
    tr = wp.trace(eps)
    return mu * wp.ddot(eps, eps) + type(mu)(0.5) * lam * tr * tr


@wp.func
def linear_pk1(F: Any, mu: Any, lam: Any):
    """P = 2μ ε + λ tr(ε) I."""
    eps = small_strain(F)
    return type(mu)(2.0) * mu * eps + lam * wp.trace(eps) * wp.identity(n=3, dtype=type(F).dtype)


@wp.func
def linear_dpk1_df(F: Any, mu: Any, lam: Any):
    """∂P/∂F = μ (I₉ + K) + λ vec(I) vec(I)ᵀ (K: commutation matrix); constant."""
    H = wp.matrix(shape=(9, 9), dtype=type(F).dtype)
    for j in range(3):
        for i in range(3):
            H[i + 3 * j, i + 3 * j] = H[i + 3 * j, i + 3 * j] + mu
            H[i + 3 * j, j + 3 * i] = H[i + 3 * j, j + 3 * i] + mu
    for i in range(3):
        for k in range(3):
            H[i + 3 * i, k + 3 * k] = H[i + 3 * i, k + 3 * k] + lam
    return H


@wp.func
def linear_dpk1_df_psd(F: Any, mu: Any, lam: Any):
    """∂P/∂F of linear elasticity, already PSD (eigenvalues 0, 2μ, 2μ + 3λ = 3K > 0) for valid (E, ν)."""
    return linear_dpk1_df(F, mu, lam)


# ----------------------------------------------------------------------------------------------------------
# St. Venant-Kirchhoff
# ----------------------------------------------------------------------------------------------------------


@wp.func
def stvk_psi(F: Any, mu: Any, lam: Any):
    """ψ = μ E:E + λ/2 tr(E)², E = ½(FᵀF − I)."""
    E = green_strain(F)
    tr = wp.trace(E)
    return mu * wp.ddot(E, E) + type(mu)(0.5) * lam * tr * tr


@wp.func
def stvk_pk1(F: Any, mu: Any, lam: Any):
    """P = F (2μ E + λ tr(E) I)."""
    E = green_strain(F)
    return F * (type(mu)(2.0) * mu * E + lam * wp.trace(E) * wp.identity(n=3, dtype=type(F).dtype))


@wp.func
def stvk_dpk1_df(F: Any, mu: Any, lam: Any):
    """∂P_ij/∂F_kl = δ_ik S_lj + μ (F_il F_kj + (FFᵀ)_ik δ_jl) + λ F_ij F_kl, S = 2μE + λ tr(E) I."""
    E = green_strain(F)
    S = type(mu)(2.0) * mu * E + lam * wp.trace(E) * wp.identity(n=3, dtype=type(F).dtype)
    B = F * wp.transpose(F)
    H = wp.matrix(shape=(9, 9), dtype=type(F).dtype)
    for j in range(3):
        for i in range(3):
            for l in range(3):
                for k in range(3):
                    h = mu * F[i, l] * F[k, j] + lam * F[i, j] * F[k, l]
                    if i == k:
                        h = h + S[l, j]
                    if j == l:
                        h = h + mu * B[i, k]
                    H[i + 3 * j, k + 3 * l] = h
    return H


@wp.func
def stvk_dpk1_df_psd(F: Any, mu: Any, lam: Any):
    """∂P/∂F of StVK with negative eigenvalues clamped to 0 (analytic eigensystem)."""
    U, s, V = svd_rv(F)
    one = type(mu)(1.0)
    half = type(mu)(0.5)
    sq = wp.cw_mul(s, s)
    S = sq[0] + sq[1] + sq[2] - type(mu)(3.0)  # Σ (σ_k² − 1) = 2 tr(E)
    flip = wp.vector(length=3, dtype=type(mu))
    twist = wp.vector(length=3, dtype=type(mu))
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        flip[k] = mu * (sq[i] + s[i] * s[j] + sq[j] - one) + half * lam * S
        twist[k] = mu * (sq[i] - s[i] * s[j] + sq[j] - one) + half * lam * S
    A = lam * wp.outer(s, s)
    for k in range(3):
        A[k, k] = A[k, k] + mu * (type(mu)(3.0) * sq[k] - one) + half * lam * S
    return _project_isotropic(stvk_dpk1_df(F, mu, lam), U, V, flip, twist, A)


# ----------------------------------------------------------------------------------------------------------
# Corotated
# ----------------------------------------------------------------------------------------------------------


@wp.func
def _corotated_pair_denominator(a: Any):
    """σ_i + σ_j kept ≥ 1e-6 (∂R/∂F is singular at σ_i + σ_j = 0: flat or inverted elements)."""
    eps = type(a)(1.0e-6)
    return wp.max(a, eps)


@wp.func
def corotated_psi(F: Any, mu: Any, lam: Any):
    """ψ = μ ‖F − R‖² + λ/2 (J − 1)² = μ Σ (σ_i − 1)² + λ/2 (J − 1)²."""
    R = polar_rotation(F)
    D = F - R
    Jm1 = wp.determinant(F) - type(mu)(1.0)
    return mu * wp.ddot(D, D) + type(mu)(0.5) * lam * Jm1 * Jm1


@wp.func
def corotated_pk1(F: Any, mu: Any, lam: Any):
    """P = 2μ (F − R) + λ (J − 1) cof(F)."""
    R = polar_rotation(F)
    return type(mu)(2.0) * mu * (F - R) + lam * (wp.determinant(F) - type(mu)(1.0)) * cofactor(F)


@wp.func
def _corotated_dpk1_df_svd(F: Any, U: Any, s: Any, V: Any, mu: Any, lam: Any):
    """2μ (I₉ − ∂R/∂F) + λ vec(cof F) vec(cof F)ᵀ + λ (J − 1) ∂²J/∂F², ∂R/∂F = Σ 2/(σ_i + σ_j) t tᵀ."""
    two = type(mu)(2.0)
    one = type(mu)(1.0)
    g = _vec9(cofactor(F))
    H = two * mu * wp.identity(n=9, dtype=type(F).dtype) + lam * wp.outer(g, g)
    H = _det_hessian(F, lam * (wp.determinant(F) - one), H)
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        t = _pair_mode(U, V, i, j, -one)
        H = H - (two * mu * two / _corotated_pair_denominator(s[i] + s[j])) * wp.outer(t, t)
    return H


@wp.func
def corotated_dpk1_df(F: Any, mu: Any, lam: Any):
    """∂P/∂F = 2μ (I₉ − ∂R/∂F) + λ vec(cof F) vec(cof F)ᵀ + λ (J − 1) ∂²J/∂F²."""
    U, s, V = svd_rv(F)
    return _corotated_dpk1_df_svd(F, U, s, V, mu, lam)


@wp.func
def corotated_dpk1_df_psd(F: Any, mu: Any, lam: Any):
    """∂P/∂F of the corotated model with negative eigenvalues clamped to 0 (analytic eigensystem)."""
    U, s, V = svd_rv(F)
    two = type(mu)(2.0)
    one = type(mu)(1.0)
    Jm1 = s[0] * s[1] * s[2] - one
    flip = wp.vector(length=3, dtype=type(mu))
    twist = wp.vector(length=3, dtype=type(mu))
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        flip[k] = two * mu - lam * Jm1 * s[k]
        twist[k] = two * mu - two * two * mu / _corotated_pair_denominator(s[i] + s[j]) + lam * Jm1 * s[k]
    # ∂²ψ/∂σ_i² = 2μ + λ (σ_j σ_k)², ∂²ψ/∂σ_i∂σ_j = λ σ_k (2J − 1)
    A = wp.matrix(shape=(3, 3), dtype=type(mu))
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        p = s[i] * s[j]
        A[k, k] = two * mu + lam * p * p
        A[i, j] = lam * s[k] * (two * (Jm1 + one) - one)
        A[j, i] = A[i, j]
    return _project_isotropic(_corotated_dpk1_df_svd(F, U, s, V, mu, lam), U, V, flip, twist, A)


# ----------------------------------------------------------------------------------------------------------
# Stable neo-Hookean
# ----------------------------------------------------------------------------------------------------------


@wp.func
def neohookean_psi(F: Any, mu: Any, lam: Any):
    """ψ = μ/2 (I_C − 3) − μ (J − 1) + (λ + μ)/2 (J − 1)²,  I_C = tr(FᵀF)."""
    Jm1 = wp.determinant(F) - type(mu)(1.0)
    half = type(mu)(0.5)
    return half * mu * (wp.ddot(F, F) - type(mu)(3.0)) - mu * Jm1 + half * (lam + mu) * Jm1 * Jm1


@wp.func
def neohookean_pk1(F: Any, mu: Any, lam: Any):
    """P = μ F + ((λ + μ)(J − 1) − μ) cof(F)."""
    Jm1 = wp.determinant(F) - type(mu)(1.0)
    return mu * F + ((lam + mu) * Jm1 - mu) * cofactor(F)


@wp.func
def neohookean_dpk1_df(F: Any, mu: Any, lam: Any):
    """∂P/∂F = μ I₉ + (λ + μ) vec(cof F) vec(cof F)ᵀ + ((λ + μ)(J − 1) − μ) ∂²J/∂F²."""
    lt = lam + mu
    g = _vec9(cofactor(F))
    H = mu * wp.identity(n=9, dtype=type(F).dtype) + lt * wp.outer(g, g)
    return _det_hessian(F, lt * (wp.determinant(F) - type(mu)(1.0)) - mu, H)


@wp.func
def neohookean_dpk1_df_psd(F: Any, mu: Any, lam: Any):
    """∂P/∂F of stable neo-Hookean with negative eigenvalues clamped to 0 (analytic eigensystem)."""
    U, s, V = svd_rv(F)
    lt = lam + mu
    J = s[0] * s[1] * s[2]
    c = lt * (J - type(mu)(1.0)) - mu  # ψ_i = μ σ_i + c σ_j σ_k
    flip = wp.vector(length=3, dtype=type(mu))
    twist = wp.vector(length=3, dtype=type(mu))
    # ∂²ψ/∂σ_i² = μ + λ̃ (σ_j σ_k)², ∂²ψ/∂σ_i∂σ_j = σ_k (λ̃ J + c)
    A = wp.matrix(shape=(3, 3), dtype=type(mu))
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        flip[k] = mu - c * s[k]
        twist[k] = mu + c * s[k]
        p = s[i] * s[j]
        A[k, k] = mu + lt * p * p
        A[i, j] = s[k] * (lt * J + c)
        A[j, i] = A[i, j]
    return _project_isotropic(neohookean_dpk1_df(F, mu, lam), U, V, flip, twist, A)


# ----------------------------------------------------------------------------------------------------------
# Element level
# ----------------------------------------------------------------------------------------------------------


@wp.func
def tet_shape_gradient(Dm_inv: Any, a: int):
    """g_a with ∂F_ij/∂x_a,l = δ_il g_a[j]: row a−1 of Dm⁻¹ for a ≥ 1, g_0 = −(g_1 + g_2 + g_3)."""
    g = -(Dm_inv[0] + Dm_inv[1] + Dm_inv[2])
    if a > 0:
        g = Dm_inv[a - 1]
    return g


@wp.func
def tet_forces(P: Any, Dm_inv: Any, V: Any):
    """(f0, f1, f2, f3): [f1 f2 f3] = −V P Dm⁻ᵀ, f0 = −(f1 + f2 + f3)."""
    H = -V * P * wp.transpose(Dm_inv)
    f1 = wp.vector(H[0, 0], H[1, 0], H[2, 0])
    f2 = wp.vector(H[0, 1], H[1, 1], H[2, 1])
    f3 = wp.vector(H[0, 2], H[1, 2], H[2, 2])
    return -(f1 + f2 + f3), f1, f2, f3


@wp.func
def gradient_hessian_block(dPdF: Any, ga: Any, gb: Any, V: Any):
    """V Σ_jq ga[j] gb[q] dPdF[3j:3j+3, 3q:3q+3] (3×3): the block of nodes a, b whose shape gradients are
    ``ga``, ``gb`` (∂F_ij/∂x_a,l = δ_il ga[j]); linear and quadratic tets share it."""
    B = wp.matrix(shape=(3, 3), dtype=type(V))
    for j in range(3):
        for q in range(3):
            c = ga[j] * gb[q]
            for l in range(3):
                for m in range(3):
                    B[l, m] = B[l, m] + c * dPdF[l + 3 * j, m + 3 * q]
    return V * B


@wp.func
def tet_hessian_block(dPdF: Any, Dm_inv: Any, V: Any, a: int, b: int):
    """H_ab = V (∂F/∂x_a)ᵀ (∂P/∂F) (∂F/∂x_b) = V Σ_jq g_a[j] g_b[q] dPdF[3j:3j+3, 3q:3q+3]  (3×3)."""
    return gradient_hessian_block(dPdF, tet_shape_gradient(Dm_inv, a), tet_shape_gradient(Dm_inv, b), V)
