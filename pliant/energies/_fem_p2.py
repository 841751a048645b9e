"""Quadratic (10-node, P2) tetrahedra: E(x) = Σ_e V_e Σ_q w_q ψ(F_e(λ_q)), kernels per material.

Shape functions and node order are those of :mod:`pliant.geometry._p2` (corners, then the mid-edge nodes
of (0,1), (1,2), (0,2), (0,3), (1,3), (2,3)). Elements are straight-sided, so the rest map is affine:
an element stores its corner D_m⁻¹ and volume like a linear tet, and ∇_X N_a at a quadrature point λ_q
follows from the corner gradients g_i = ∇λ_i. The deformation gradient is F = Σ_a x_a ⊗ ∇N_a (linear in
X), so the stiffness of linear elasticity is exact with the 4-point degree-2 rule; the nonlinear laws use
the 14-point degree-5 rule by default (:class:`pliant.energies.TetElasticity`'s ``quadrature``).

One thread per (element, quadrature point): each evaluates ψ, P or ∂P/∂F with the material's functions
of :mod:`pliant.energies._fem_math` — the same code as the linear tets — and adds V w_q ψ, V w_q P ∇N_a
and the 100 blocks V w_q (∇N_a)ᵀ ∂P/∂F (∇N_b) atomically.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from . import _fem_math as fm
from ._materials import get_material_model

if TYPE_CHECKING:
    from ..model import Model


@wp.func
def _edge_first(e: int):
    """First corner of mid-edge e (edges (0,1), (1,2), (0,2), (0,3), (1,3), (2,3))."""
    i = 0
    if e == 1 or e == 4:
        i = 1
    if e == 5:
        i = 2
    return i


@wp.func
def _edge_second(e: int):
    """Second corner of mid-edge e."""
    j = 3
    if e == 0:
        j = 1
    if e == 1 or e == 2:
        j = 2
    return j


@wp.func
def p2_shape_gradient(Dm_inv: Any, lam: Any, a: int):
    """∇_X N_a at barycentric point ``lam``: (4λ_a − 1) g_a at corners, 4 (λ_i g_j + λ_j g_i) at mid-edges."""
    four = type(lam[0])(4.0)
    g = fm.tet_shape_gradient(Dm_inv, 0)
    if a < 4:
        g = (four * lam[a] - type(lam[0])(1.0)) * fm.tet_shape_gradient(Dm_inv, a)
    else:
        i = _edge_first(a - 4)
        j = _edge_second(a - 4)
        g = four * (lam[i] * fm.tet_shape_gradient(Dm_inv, j) + lam[j] * fm.tet_shape_gradient(Dm_inv, i))
    return g


@wp.func
def p2_deformation_gradient(idx: wp.array2d(dtype=wp.int32), t: int, x_in: Any, Dm_inv: Any, lam: Any):
    """F = Σ_a x_a ⊗ ∇N_a = Σ_{a≥1} (x_a − x_0) ⊗ ∇N_a (Σ_a ∇N_a = 0; differences keep float32 accuracy)."""
    x0 = x_in[idx[t, 0]]
    F = wp.outer(x_in[idx[t, 1]] - x0, p2_shape_gradient(Dm_inv, lam, 1))
    for a in range(2, 10):
        F = F + wp.outer(x_in[idx[t, a]] - x0, p2_shape_gradient(Dm_inv, lam, a))
    return F


@wp.func
def p2_point(tid: int, nq: int):
    """(element t, quadrature point q) of thread ``tid``: one thread per pair, ``nq`` points per element."""
    t = tid // nq
    return t, tid - t * nq


@wp.kernel(enable_backward=False)
def _p2_min_det(
    idx: wp.array2d(dtype=wp.int32),
    rest_inv: wp.array(dtype=Any),
    qp_bary: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    t, q = p2_point(wp.tid(), qp_bary.shape[0])
    F = p2_deformation_gradient(idx, t, x_in, rest_inv[t], qp_bary[q])
    wp.atomic_min(out, 0, wp.determinant(F))


_KERNELS: dict[str, tuple[Any, Any, Any, Any]] = {}
_OVERLOADED: set[tuple[str, str]] = set()


def p2_material_kernels(name: str, dtype: str) -> tuple[Any, Any, Any, Any]:
    """(value, gradient [with the value on request], projected Hessian, exact Hessian) P2 kernels of
    material ``name``, built once, with their ``dtype`` overloads declared before the first launch."""
    if name not in _KERNELS:
        _KERNELS[name] = _build(name)
    kernels = _KERNELS[name]
    if (name, dtype) not in _OVERLOADED:
        fm.declare_overloads(
            kernels,
            dtype,
            lambda s, m33: {
                "rest_inv": m33,
                "rest_volume": s,
                "mu": s,
                "lam": s,
                "qp_bary": wp.types.vector(4, s),
                "qp_weight": s,
            },
        )
        _OVERLOADED.add((name, dtype))
    return kernels


def _build(name: str) -> tuple[Any, Any, Any, Any]:
    mat = get_material_model(name)
    psi_fn, pk1_fn = mat.psi, mat.pk1
    module = wp.get_module(f"pliant.energies._fem_p2.{name}")

    @wp.kernel(module=module)
    def p2_value(
        idx: wp.array2d(dtype=wp.int32),
        rest_inv: wp.array(dtype=Any),
        rest_volume: wp.array(dtype=Any),
        mu: wp.array(dtype=Any),
        lam: wp.array(dtype=Any),
        qp_bary: wp.array(dtype=Any),
        qp_weight: wp.array(dtype=Any),
        x_in: wp.array(dtype=Any),
        out: wp.array(dtype=Any),
    ):
        t, q = p2_point(wp.tid(), qp_weight.shape[0])
        F = p2_deformation_gradient(idx, t, x_in, rest_inv[t], qp_bary[q])
        wp.atomic_add(out, 0, rest_volume[t] * qp_weight[q] * psi_fn(F, mu[t], lam[t]))

    @wp.kernel(module=module)
    def p2_gradient(
        idx: wp.array2d(dtype=wp.int32),
        rest_inv: wp.array(dtype=Any),
        rest_volume: wp.array(dtype=Any),
        mu: wp.array(dtype=Any),
        lam: wp.array(dtype=Any),
        qp_bary: wp.array(dtype=Any),
        qp_weight: wp.array(dtype=Any),
        x_in: wp.array(dtype=Any),
        with_value: int,
        out: wp.array(dtype=Any),
        grad_out: wp.array(dtype=Any),
    ):
        # ∂E/∂x_a = V w_q P ∇N_a; E into out[0] when with_value.
        t, q = p2_point(wp.tid(), qp_weight.shape[0])
        Dm_inv = rest_inv[t]
        bary = qp_bary[q]
        F = p2_deformation_gradient(idx, t, x_in, Dm_inv, bary)
        Vw = rest_volume[t] * qp_weight[q]
        if with_value != 0:
            wp.atomic_add(out, 0, Vw * psi_fn(F, mu[t], lam[t]))
        P = Vw * pk1_fn(F, mu[t], lam[t])
        for a in range(10):
            wp.atomic_add(grad_out, idx[t, a], P * p2_shape_gradient(Dm_inv, bary, a))

    def make_hessian(dpdf: Any, mod: Any) -> Any:
        @wp.kernel(module=mod, enable_backward=False)
        def p2_hessian(
            idx: wp.array2d(dtype=wp.int32),
            rest_inv: wp.array(dtype=Any),
            rest_volume: wp.array(dtype=Any),
            mu: wp.array(dtype=Any),
            lam: wp.array(dtype=Any),
            qp_bary: wp.array(dtype=Any),
            qp_weight: wp.array(dtype=Any),
            slots: wp.array(dtype=wp.int32),
            x_in: wp.array(dtype=Any),
            scale: Any,
            slot_offset: int,
            values_out: wp.array(dtype=Any),
        ):
            t, q = p2_point(wp.tid(), qp_weight.shape[0])
            Dm_inv = rest_inv[t]
            bary = qp_bary[q]
            F = p2_deformation_gradient(idx, t, x_in, Dm_inv, bary)
            A = dpdf(F, mu[t], lam[t])
            Vw = scale * rest_volume[t] * qp_weight[q]
            # A runtime bound (idx.shape[1] = 10) keeps Warp from unrolling the 100 blocks: unrolled, each
            # Hessian module took ~45 s to compile; as loops, a few seconds, at the same speed.
            n = idx.shape[1]
            for a in range(n):
                ga = p2_shape_gradient(Dm_inv, bary, a)
                for b in range(n):
                    block = fm.gradient_hessian_block(A, ga, p2_shape_gradient(Dm_inv, bary, b), Vw)
                    wp.atomic_add(values_out, slots[slot_offset + 100 * t + 10 * a + b], block)

        return p2_hessian

    p2_hessian_exact = make_hessian(
        mat.dpk1_df, wp.get_module(f"pliant.energies._fem_p2.{name}_hessian_exact")
    )
    # Linear elasticity's ∂P/∂F is constant and PSD (its projection returns it unchanged): one module, one
    # compile, serves both.
    p2_hessian = (
        p2_hessian_exact
        if name == "linear"
        else make_hessian(mat.dpk1_df_psd, wp.get_module(f"pliant.energies._fem_p2.{name}_hessian"))
    )
    return p2_value, p2_gradient, p2_hessian, p2_hessian_exact


def p2_hessian_pattern(tet10_indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the 100 blocks per 10-node tet, slot 100 t + 10 a + b."""
    idx = np.asarray(tet10_indices, np.int32).reshape(-1, 10)
    return np.repeat(idx, 10, axis=1).ravel(), np.tile(idx, (1, 10)).ravel()


def p2_min_det(model: Model, qp_bary: wp.array, x: wp.array) -> float:
    """min det F over the model's 10-node tets and the quadrature points ``qp_bary`` (one host read)."""
    out = wp.full(1, model.s(np.inf), dtype=model.scalar, device=model.device)
    wp.launch(
        _p2_min_det,
        model.tet10_count * qp_bary.shape[0],
        [model.tet10_indices, model.tet10_rest_inv, qp_bary, x, out],
        device=model.device,
    )
    return float(out.numpy()[0])
