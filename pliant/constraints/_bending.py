"""Bending constraints on the four-particle edge stencil: dihedral bending (the signed angle between two
triangles sharing an edge) and isometric, quadratic bending (Bergou et al. 2006)."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..model import BENDING_STIFFNESS, Model, Parameter, constraint_array, declares
from ._base import Constraint, ProjectionContext, constraint_delta_lambda
from ._factory import _FourPoint, projection_kernels


# ---------------------------------------------------------------------- dihedral bending
@wp.func
def dihedral_angle(x0: Any, x1: Any, x2: Any, x3: Any):
    """θ = atan2((n̂1 × n̂2)·ê, n̂1·n̂2), e = x1 − x0, n1 = e × (x2 − x0), n2 = (x3 − x0) × e  [rad].

    The signed angle between the two triangle normals about the shared edge: 0 when flat, ±π when folded
    shut. It equals the lecture's arccos(n̂1·n̂2) up to sign but, unlike arccos, has a bounded derivative
    at 0 and π.
    """
    e = x1 - x0
    n1 = wp.cross(e, x2 - x0)
    n2 = wp.cross(x3 - x0, e)
    le = wp.length(e)
    zero = type(le)(0.0)
    if le == zero:
        return zero
    # Unnormalised sin/cos: atan2 is scale-invariant, so one division suffices.
    return wp.atan2(wp.dot(wp.cross(n1, n2), e) / le, wp.dot(n1, n2))


@wp.func
def wrap_angle(a: Any):
    """a wrapped into (−π, π]  [rad]."""
    pi = wp.acos(type(a)(-1.0))  # wp.pi is a float32 constant
    two_pi = type(a)(2.0) * pi
    if a > pi:
        a = a - two_pi
    if a <= -pi:
        a = a + two_pi
    return a


@wp.func
def dihedral_c(x0: Any, x1: Any, x2: Any, x3: Any, rest: Any):
    """C = wrap(θ(x) − θ0) ∈ (−π, π]  [rad]; continuous through the folded state θ = ±π."""
    return wrap_angle(dihedral_angle(x0, x1, x2, x3) - rest)


@wp.func
def dihedral_grad(x0: Any, x1: Any, x2: Any, x3: Any):
    """∇θ (Bridson, Marino, Fedkiw 2003): ∇_2 = −|e| n1/|n1|², ∇_3 = −|e| n2/|n2|², edge ends by lever rule.

    With s_k = (x_k − x0)·e/|e|², ∇_0 = −(1 − s2)∇_2 − (1 − s3)∇_3 and ∇_1 = −s2 ∇_2 − s3 ∇_3, so the
    gradients sum to zero and their moments cancel. Zero for a degenerate (zero-area) triangle.
    """
    e = x1 - x0
    n1 = wp.cross(e, x2 - x0)
    n2 = wp.cross(x3 - x0, e)
    ee = wp.dot(e, e)
    a1 = wp.dot(n1, n1)
    a2 = wp.dot(n2, n2)
    zero = type(ee)(0.0)
    g0 = e * zero
    g1 = e * zero
    g2 = e * zero
    g3 = e * zero
    if ee > zero and a1 > zero and a2 > zero:
        le = wp.sqrt(ee)
        g2 = n1 * (-le / a1)
        g3 = n2 * (-le / a2)
        s2 = wp.dot(x2 - x0, e) / ee
        s3 = wp.dot(x3 - x0, e) / ee
        one = type(ee)(1.0)
        g0 = -(one - s2) * g2 - (one - s3) * g3
        g1 = -s2 * g2 - s3 * g3
    return g0, g1, g2, g3


def dihedral_angles_np(q: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Signed dihedral angles [rad] of bending elements [B, 4] (NumPy, same convention as the Warp func)."""
    x0, x1, x2, x3 = (q[idx[:, k]] for k in range(4))
    e = x1 - x0
    n1 = np.cross(e, x2 - x0)
    n2 = np.cross(x3 - x0, e)
    le = np.maximum(np.linalg.norm(e, axis=1), 1e-300)
    return np.arctan2(np.sum(np.cross(n1, n2) * e, axis=1) / le, np.sum(n1 * n2, axis=1))


@declares
class DihedralBending(_FourPoint):
    """Bending: C = wrap(θ(x) − θ0), θ the signed dihedral angle of two triangles sharing edge (0, 1).

    The lecture writes C = arccos(n̂1·n̂2) − φ0; arccos has an unbounded derivative at the flat (0) and
    folded (π) states, so we measure θ with atan2(sin, cos), whose gradient (Bridson et al. 2003) is
    bounded there. Compliance α [1/(N m)] = 1/k_bend.

    By default the set is the model's bending elements with α = 1/k from ``model.bending_stiffness``
    (elements with k = 0 are left out) unless ``compliance`` is given.

    Args:
        indices: [B, 4] (edge 0-1, opposite vertices 2, 3); default the model's bending elements.
        rest_angle: θ0 [rad]; default the current angles.
        compliance: α [1/(N m)], scalar or [B].
        stiffness: PBD stiffness k in [0, 1].
    """

    _name = "DihedralBending"
    kernels = projection_kernels("dihedral", dihedral_c, dihedral_grad, 4)

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """XPBD compliance α per constraint (and the model bending stiffness its default is read from)."""
        return (
            Parameter(
                "compliance_dihedralbending",
                "XPBD compliance of each dihedral bending constraint",
                "1/(N m)",
                "constraint",
                ("constraint.compliance_array",),
                (1e-10, 1e-1),
                get=constraint_array("compliance_dihedralbending"),
            ),
            BENDING_STIFFNESS,
        )

    def __init__(
        self,
        indices: ArrayLike | None = None,
        *,
        rest_angle: ArrayLike | None = None,
        compliance: Any = None,
        stiffness: float = 1.0,
    ) -> None:
        super().__init__(indices, rest_angle, compliance, stiffness)

    def _defaults(self, model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        idx = model.bending_indices.numpy().reshape(-1, 4)
        rest = model.bending_rest_angle.numpy().astype(np.float64)
        if self._compliance_arg is not None:
            return idx, rest, self._compliance_arg
        k = model.bending_stiffness.numpy().astype(np.float64)
        keep = k > 0
        return idx[keep], rest[keep], 1.0 / k[keep]

    def _rest_of(self, q: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return dihedral_angles_np(q, idx)


# ---------------------------------------------------------------------- isometric bending
@wp.func
def isometric_bending_c(x0: Any, x1: Any, x2: Any, x3: Any, K: Any):
    """C = Σ_i K_i x_i (a vector) with K = √(3/(A0 + A1)) [c03 + c04, c01 + c02, −c01 − c03, −c02 − c04].

    The discrete mean-curvature normal of the edge stencil (Bergou, Wardetzky, Harmon, Zorin, Grinspun,
    "A quadratic bending model for inextensible surfaces", SGP 2006): ½ k |C|² is their bending energy
    ½ k xᵀQx, Q = 3/(A0 + A1) K Kᵀ. C vanishes for every planar configuration and is linear in x.
    """
    return K[0] * x0 + K[1] * x1 + K[2] * x2 + K[3] * x3


@wp.func
def isometric_bending_grad(K: Any):
    """∇_i C_d = K_i e_d: the same constant weight for each of the three components of C."""
    return K


@wp.kernel
def _project_isometric(
    indices: wp.array2d(dtype=wp.int32),
    weights: wp.array(dtype=Any),
    compliance: wp.array(dtype=Any),
    split: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=Any),
    inv_dt2: Any,
    pbd_k: Any,
    offset: int,
    jacobi: int,
    omega: Any,
    p_io: wp.array(dtype=Any),
    lam_io: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    s = offset + wp.tid()
    i0 = indices[s, 0]
    i1 = indices[s, 1]
    i2 = indices[s, 2]
    i3 = indices[s, 3]
    K = weights[s]
    w0 = inv_mass[i0]
    w1 = inv_mass[i1]
    w2 = inv_mass[i2]
    w3 = inv_mass[i3]
    if jacobi != 0:
        w0 = w0 * type(w0)(split[i0])
        w1 = w1 * type(w0)(split[i1])
        w2 = w2 * type(w0)(split[i2])
        w3 = w3 * type(w0)(split[i3])
    c = isometric_bending_c(p_io[i0], p_io[i1], p_io[i2], p_io[i3], K)
    g = isometric_bending_grad(K)
    wgs = w0 * g[0] * g[0] + w1 * g[1] * g[1] + w2 * g[2] * g[2] + w3 * g[3] * g[3]
    at = compliance[s] * inv_dt2
    lam = lam_io[s]
    # Three independent scalar constraints with equal gradients: one Δλ per component.
    dl = c * type(at)(0.0)
    for d in range(3):
        dl[d] = constraint_delta_lambda(c[d], wgs, at, lam[d], pbd_k) * omega
    lam_io[s] = lam + dl
    if jacobi != 0:
        wp.atomic_add(delta_out, i0, (w0 * g[0]) * dl)
        wp.atomic_add(delta_out, i1, (w1 * g[1]) * dl)
        wp.atomic_add(delta_out, i2, (w2 * g[2]) * dl)
        wp.atomic_add(delta_out, i3, (w3 * g[3]) * dl)
        wp.atomic_add(count_out, i0, 1)
        wp.atomic_add(count_out, i1, 1)
        wp.atomic_add(count_out, i2, 1)
        wp.atomic_add(count_out, i3, 1)
    else:
        p_io[i0] = p_io[i0] + (w0 * g[0]) * dl
        p_io[i1] = p_io[i1] + (w1 * g[1]) * dl
        p_io[i2] = p_io[i2] + (w2 * g[2]) * dl
        p_io[i3] = p_io[i3] + (w3 * g[3]) * dl


@wp.kernel(enable_backward=False)
def _isometric_values(
    indices: wp.array2d(dtype=wp.int32),
    weights: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    c_out: wp.array(dtype=Any),
    grad_out: wp.array2d(dtype=Any),
):
    # Stencil s holds three scalar constraints, rows 3s + d: C_d and ∇_i C_d = K_i e_d.
    s = wp.tid()
    K = weights[s]
    x0 = p_in[indices[s, 0]]
    c = isometric_bending_c(x0, p_in[indices[s, 1]], p_in[indices[s, 2]], p_in[indices[s, 3]], K)
    g = isometric_bending_grad(K)
    for d in range(3):
        c_out[3 * s + d] = c[d]
        e = x0 * type(c[0])(0.0)
        e[d] = type(c[0])(1.0)
        for j in range(4):
            grad_out[3 * s + d, j] = g[j] * e


def isometric_bending_weights(q: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """K [B, 4] of each stencil (edge 0-1, opposite 2, 3) at rest positions q, scaled by √(3/(A0 + A1))."""
    x0, x1, x2, x3 = (q[idx[:, k]] for k in range(4))

    def cot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.sum(a * b, axis=1) / np.linalg.norm(np.cross(a, b), axis=1)

    e0, e1, e2, e3, e4 = x1 - x0, x2 - x0, x3 - x0, x2 - x1, x3 - x1
    c01, c02, c03, c04 = cot(e0, e1), cot(e0, e2), cot(-e0, e3), cot(-e0, e4)
    area = 0.5 * (np.linalg.norm(np.cross(e0, e1), axis=1) + np.linalg.norm(np.cross(e0, e2), axis=1))
    K = np.stack([c03 + c04, c01 + c02, -c01 - c03, -c02 - c04], axis=1)
    return K * np.sqrt(3.0 / area)[:, None]


class IsometricBending(Constraint):
    """Isometric (quadratic) bending, Bergou et al. 2006: C = Σ_i K_i x_i = 0, compliance α = 1/k [1/(N m)].

    C is the discrete mean-curvature normal of each edge stencil, linear in the positions, so XPBD solves
    it in one sweep when isolated and its energy ½α⁻¹|C|² is Bergou's ½k xᵀQx. Valid for inextensible
    surfaces with a flat rest shape (C = 0 for any planar stencil); for a curved rest shape use
    :class:`DihedralBending`.

    Args:
        indices: [B, 4] stencils (edge 0-1, opposite 2, 3); default the model's bending elements.
        compliance: α [1/(N m)] (scalar or [B]); default 1/k from ``model.bending_stiffness``.
        stiffness: PBD stiffness k in [0, 1].
    """

    relaxes_itself = True

    def __init__(
        self, indices: ArrayLike | None = None, *, compliance: Any = None, stiffness: float = 1.0
    ) -> None:
        super().__init__(
            compliance=None if compliance is None or np.ndim(compliance) else float(compliance),
            stiffness=stiffness,
        )
        self._indices = None if indices is None else np.asarray(indices, np.int64).reshape(-1, 4)
        self._compliance_arg = compliance

    def bind(self, model: Model, coloring: bool) -> None:
        """Rest weights K, colours and multipliers (one vec3 λ per stencil)."""
        self.model = model
        if self._indices is None:
            idx = model.bending_indices.numpy().reshape(-1, 4)
            k = model.bending_stiffness.numpy().astype(np.float64)
            comp = self._compliance_arg if self._compliance_arg is not None else 1.0 / np.maximum(k, 1e-300)
        else:
            idx = self._indices
            if idx.size and (idx.min() < 0 or idx.max() >= model.particle_count):
                raise ValueError(f"IsometricBending: indices out of range [0, {model.particle_count})")
            comp = 0.0 if self._compliance_arg is None else self._compliance_arg
        n = idx.shape[0]
        comp = np.broadcast_to(np.asarray(comp, np.float64), (n,))
        K = isometric_bending_weights(model.particle_q_np, idx)
        order, self.color_offsets = self._colors(idx, coloring)
        d, f = model.device, model.scalar
        vec4 = wp.vec4 if model.dtype == "float32" else wp.vec4d
        self.count = n
        self.indices: wp.array = wp.array(
            idx[order].astype(np.int32).reshape(-1, 4), dtype=wp.int32, device=d
        )
        self.weights: wp.array = wp.array(K[order], dtype=vec4, device=d)
        self.compliance_array: wp.array = wp.array(comp[order], dtype=f, device=d)
        self.lam = wp.zeros(n, dtype=model.vec3, device=d)
        self.split: wp.array = wp.array(self._split_counts(idx), dtype=wp.int32, device=d)
        self.order = order

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [3B], indices [3B, 4] and ∇C [3B, 4, 3]: the three components of each stencil's C, in turn."""
        m = self.model
        c = wp.zeros(3 * self.count, dtype=m.scalar, device=m.device)
        g = wp.zeros((3 * self.count, 4), dtype=m.vec3, device=m.device)
        if self.count:
            wp.launch(_isometric_values, self.count, [self.indices, self.weights, x, c, g], device=m.device)
        return c.numpy(), np.repeat(self.indices.numpy(), 3, axis=0), g.numpy()

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """One sweep: Gauss–Seidel per colour, or Jacobi into ``ctx.delta``."""
        m = self.model
        k = m.s(self.pbd_k(ctx))
        for off, size in self.color_ranges(ctx.coloring):
            ctx.launch(
                _project_isometric,
                size,
                [
                    self.indices,
                    self.weights,
                    self.compliance_array,
                    self.split,
                    m.particle_inv_mass,
                    m.s(1.0 / (dt * dt)),
                    k,
                    off,
                    int(not ctx.coloring),
                    m.s(ctx.relaxation),
                    p,
                    self.lam,
                    ctx.delta,
                    ctx.delta_count,
                ],
            )
