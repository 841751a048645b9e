"""Step bounds and inversion diagnostics of tetrahedra: the first step fraction at which an element keeps only
a fraction η of its volume (the first root of det(D_s + α ΔD_s) = η det(D_s)), the smallest determinant and
a lower bound of the smallest singular value. Material-free; :class:`pliant.energies.TetElasticity` launches
them on its linear tets and on the sub-tets of its quadratic ones."""

from __future__ import annotations

from typing import Any

import warp as wp

from . import _fem_math as fm


@wp.func
def det_polynomial(A: Any, B: Any):
    """det(A + αB) = c0 + c1 α + c2 α² + c3 α³ with c1 = cof(A):B, c2 = cof(B):A; returns (c0, c1, c2, c3)."""
    return wp.determinant(A), wp.ddot(fm.cofactor(A), B), wp.ddot(fm.cofactor(B), A), wp.determinant(B)


@wp.func
def _cubic(a0: Any, a1: Any, a2: Any, a3: Any, t: Any):
    return a0 + t * (a1 + t * (a2 + t * a3))


@wp.func
def _first_root_in(a0: Any, a1: Any, a2: Any, a3: Any, lo: Any, hi: Any):
    """Largest t in [lo, hi] left of the first sign change of the cubic (q(lo) > 0), or hi if none."""
    a = lo
    b = hi
    if _cubic(a0, a1, a2, a3, b) > type(a0)(0.0):
        return b
    for _ in range(48):
        mid = type(a0)(0.5) * (a + b)
        if _cubic(a0, a1, a2, a3, mid) > type(a0)(0.0):
            a = mid
        else:
            b = mid
    return a


@wp.func
def tet_inversion_step(Ds: Any, dDs: Any, eta: Any):
    """Largest α ∈ (0, 1] with det(Ds + t dDs) > η det(Ds) for all t ∈ [0, α]; 1 if det(Ds) ≤ 0.

    The cubic q(t) = det(Ds + t dDs) − η det(Ds), normalised by det(Ds), is monotone between the roots of
    q′; the first interval on which it changes sign is bisected, keeping the admissible end.
    """
    zero = type(eta)(0.0)
    one = type(eta)(1.0)
    c0, c1, c2, c3 = det_polynomial(Ds, dDs)
    alpha = one
    if c0 > zero:
        a0 = one - eta
        a1 = c1 / c0
        a2 = c2 / c0
        a3 = c3 / c0
        # critical points of q: 3 a3 t² + 2 a2 t + a1 = 0, sorted, clipped to (0, 1)
        t1 = one
        t2 = one
        qa = type(eta)(3.0) * a3
        qb = type(eta)(2.0) * a2
        if qa != zero:
            disc = qb * qb - type(eta)(4.0) * qa * a1
            if disc >= zero:
                sq = wp.sqrt(disc)
                r1 = (-qb - sq) / (type(eta)(2.0) * qa)
                r2 = (-qb + sq) / (type(eta)(2.0) * qa)
                t1 = wp.min(r1, r2)
                t2 = wp.max(r1, r2)
        elif qb != zero:
            t1 = -a1 / qb
        if t1 <= zero or t1 >= one:
            t1 = one
        if t2 <= zero or t2 >= one:
            t2 = one
        if t2 < t1:
            tmp = t1
            t1 = t2
            t2 = tmp
        alpha = _first_root_in(a0, a1, a2, a3, zero, t1)
        if alpha >= t1 and t1 < one:
            alpha = _first_root_in(a0, a1, a2, a3, t1, t2)
            if alpha >= t2 and t2 < one:
                alpha = _first_root_in(a0, a1, a2, a3, t2, one)
    return alpha


@wp.kernel(enable_backward=False)
def _tet_max_step(
    tet_indices: wp.array2d(dtype=wp.int32),
    x_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    eta: Any,
    alpha_out: wp.array(dtype=Any),
):
    t = wp.tid()
    i = tet_indices[t, 0]
    j = tet_indices[t, 1]
    k = tet_indices[t, 2]
    l = tet_indices[t, 3]
    x0 = x_in[i]
    d0 = dx_in[i]
    Ds = wp.matrix_from_cols(x_in[j] - x0, x_in[k] - x0, x_in[l] - x0)
    dDs = wp.matrix_from_cols(dx_in[j] - d0, dx_in[k] - d0, dx_in[l] - d0)
    wp.atomic_min(alpha_out, 0, tet_inversion_step(Ds, dDs, eta))


@wp.kernel(enable_backward=False)
def _tet_min_det(
    tet_indices: wp.array2d(dtype=wp.int32),
    tet_rest_inv: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    t = wp.tid()
    F = fm.tet_deformation_gradient(tet_indices, t, x_in, tet_rest_inv[t])
    wp.atomic_min(out, 0, wp.determinant(F))


@wp.kernel(enable_backward=False)
def _tet_sigma_min_bound(
    tet_indices: wp.array2d(dtype=wp.int32),
    x_in: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    # σ_min(D_s) = |det D_s|/(σ₁σ₂) ≥ 2|det D_s|/‖D_s‖_F², since σ₁σ₂ ≤ (σ₁² + σ₂²)/2; 0 for inverted tets.
    # (The exact σ_min from the eigenvalues of D_sᵀD_s is 1.7× larger on Kuhn tets but costs 6× this pass.)
    t = wp.tid()
    x0 = x_in[tet_indices[t, 0]]
    Ds = wp.matrix_from_cols(
        x_in[tet_indices[t, 1]] - x0, x_in[tet_indices[t, 2]] - x0, x_in[tet_indices[t, 3]] - x0
    )
    det = wp.determinant(Ds)
    bound = det * type(det)(0.0)
    if det > bound:
        bound = type(det)(2.0) * det / wp.ddot(Ds, Ds)
    wp.atomic_min(out, 0, bound)


@wp.kernel(enable_backward=False)
def _fill(value: Any, out: wp.array(dtype=Any)):
    out[wp.tid()] = value


# ----------------------------------------------------------------------------------- per-material kernels
