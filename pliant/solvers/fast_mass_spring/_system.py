"""FastMassSpring's implicit step as a linear system: the Baraff–Witkin assembly kernels and the object that
holds the system's buffers and launches its CG.

(M + θhD + θ²h²K) Δv = h(f(xⁿ, vⁿ) − θhK vⁿ) on the model's spring graph (a CSR adjacency: spring ``s``
appears once in the row of each endpoint), K the PSD-projected spring Hessian and D the dashpot Jacobian,
stored as one 3×3 block per adjacency entry; solved by block-Jacobi preconditioned CG (:mod:`._cg`).
:class:`BaraffWitkinSystem` is shared by FastMassSpring's own step and its recorded step
(:class:`~._adjoint.BaraffWitkinStep`), so that neither holds the other.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ...energies import dashpot_force_axis, spring_gradient_axis, spring_hessian
from ...model import Model
from ._cg import _bw_apply, _bw_update


@wp.func
def _spring_blocks(xi: Any, xj: Any, rest: Any, k: Any, gamma: Any, h: Any):
    """(K_s, h²K_s + hD_s) for the spring (i, j): K_s the spring energy's PSD-projected Hessian block
    (:func:`pliant.energies.spring_hessian`, Choi & Ko), D_s = γ n̂n̂ᵀ the dashpot Jacobian."""
    d = xj - xi
    n = d / wp.max(wp.length(d), type(h)(1.0e-30))
    K = spring_hessian(xi, xj, k, rest, 1)
    return K, (h * h) * K + (h * gamma) * wp.outer(n, n)


@wp.kernel
def _bw_assemble(
    # Model:
    adj_offsets: wp.array(dtype=wp.int32),
    adj_neighbor: wp.array(dtype=wp.int32),
    adj_spring: wp.array(dtype=wp.int32),
    spring_rest_length: wp.array(dtype=Any),
    spring_stiffness: wp.array(dtype=Any),
    spring_damping: wp.array(dtype=Any),
    particle_mass: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    h: Any,
    theta: Any,
    # Out (scratch):
    block_out: wp.array(dtype=Any),
    precond_out: wp.array(dtype=Any),
    r_out: wp.array(dtype=Any),
    z_out: wp.array(dtype=Any),
    p_out: wp.array(dtype=Any),
    dv_out: wp.array(dtype=Any),
    rz_out: wp.array(dtype=Any),
):
    i = wp.tid()
    xi = x_in[i]
    vi = v_in[i]
    zero3 = vi * (h * type(h)(0.0))
    dv_out[i] = zero3
    eye = wp.identity(n=3, dtype=type(h))
    if particle_inv_mass[i] == h * type(h)(0.0):
        r_out[i] = zero3
        z_out[i] = zero3
        p_out[i] = zero3
        precond_out[i] = eye * (h * type(h)(0.0))
        return
    m = particle_mass[i]
    f = m * gravity + f_ext[i]
    ht = h * theta  # θ = 1: backward Euler; θ = ½: the implicit midpoint rule (both linearised)
    kv = zero3
    diag = m * eye
    for e in range(adj_offsets[i], adj_offsets[i + 1]):
        j = adj_neighbor[e]
        s = adj_spring[e]
        dvel = v_in[j] - vi
        d = xi - x_in[j]
        l = wp.length(d)
        f += dashpot_force_axis(d, l, vi, v_in[j], spring_damping[s])
        f -= spring_gradient_axis(d, l, spring_stiffness[s], spring_rest_length[s])
        K, H = _spring_blocks(xi, x_in[j], spring_rest_length[s], spring_stiffness[s], spring_damping[s], ht)
        block_out[e] = H
        diag += H
        kv -= K * dvel  # (K v)_i = Σ_s K_s (v_i − v_j)
    r = h * (f - ht * kv)
    P = wp.inverse(diag)
    z = P * r
    precond_out[i] = P
    r_out[i] = r
    z_out[i] = z
    p_out[i] = z
    wp.atomic_add(rz_out, 0, wp.dot(r, z))


@wp.kernel
def _bw_finish(
    particle_inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    dv_in: wp.array(dtype=Any),
    h: Any,
    theta: Any,
    delta: Any,
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    i = wp.tid()
    if particle_inv_mass[i] == h * type(h)(0.0):
        # Infinite mass: no force changes v, and x moves with it (as in ForceSolver's integrators).
        x_out[i] = x_in[i] + h * v_in[i]
        v_out[i] = v_in[i]
        return
    v = delta * (v_in[i] + dv_in[i])
    v_out[i] = v
    if theta == type(h)(1.0):
        x_out[i] = x_in[i] + h * v  # backward Euler: x¹ = x + h v¹
    else:
        x_out[i] = x_in[i] + h * delta * (v_in[i] + theta * dv_in[i])  # x¹ = x + h (v + θΔv)


class BaraffWitkinSystem:
    """The implicit step's system on a model's spring graph: the adjacency, the per-entry blocks, the
    block-Jacobi preconditioner, CG's work arrays and scalars (one slot per iteration, so that a step never
    synchronises with the host), and the CG launches.

    Args:
        model: the Model (springs).
        adj_offsets: CSR row offsets of the spring graph [particle_count + 1] (int32, on the model's device).
        adj_neighbor: the other endpoint of each adjacency entry (int32).
        adj_spring: the spring of each adjacency entry (int32).
        iterations: the most CG iterations per solve (≥ 1).
        tol: relative residual (preconditioned norm) at which CG stops (> 0).
    """

    def __init__(
        self,
        model: Model,
        adj_offsets: wp.array,
        adj_neighbor: wp.array,
        adj_spring: wp.array,
        iterations: int,
        tol: float,
    ) -> None:
        self.model = model
        self.adj_offsets, self.adj_neighbor, self.adj_spring = adj_offsets, adj_neighbor, adj_spring
        self.iterations = int(iterations)
        self.tol = float(tol)
        d = model.device
        n = model.particle_count
        self.block = wp.zeros(max(adj_neighbor.shape[0], 1), dtype=model.mat33, device=d)
        self.precond = wp.zeros(n, dtype=model.mat33, device=d)
        self.r, self.z, self.q, self.dv = (wp.zeros(n, dtype=model.vec3, device=d) for _ in range(4))
        self.p = [wp.zeros(n, dtype=model.vec3, device=d) for _ in range(2)]
        self.scalars = wp.zeros(2 * self.iterations + 2, dtype=model.scalar, device=d)
        self.np_dtype = np.float64 if model.dtype == "float64" else np.float32

    def model_inputs(self) -> list:
        """The model's arrays ``_bw_assemble`` reads, in its argument order (gravity last)."""
        m = self.model
        return [
            self.adj_offsets,
            self.adj_neighbor,
            self.adj_spring,
            m.spring_rest_length,
            m.spring_stiffness,
            m.spring_damping,
            m.particle_mass,
            m.particle_inv_mass,
            m.gravity_vec,
        ]

    def cg(self, record: bool) -> list:
        """The CG iterations on the assembled system (``_bw_apply``, ``_bw_update`` per iteration), as
        recorded commands (``record``) or launched now."""
        m, s, dev = self.model, self.model.s, self.model.device
        n = m.particle_count
        tol2 = s(self.tol**2)
        cmds = []
        for k in range(self.iterations):
            p_old, p_new = self.p[(k + 1) % 2], self.p[k % 2]
            cmds.append(
                wp.launch(
                    _bw_apply,
                    n,
                    [self.adj_offsets, self.adj_neighbor, m.particle_mass, m.particle_inv_mass, self.block]
                    + [self.z, p_old, self.scalars, k, tol2, p_new, self.q],
                    device=dev,
                    record_cmd=record,
                )
            )
            cmds.append(
                wp.launch(
                    _bw_update,
                    n,
                    [self.precond, p_new, self.q, self.scalars, k, tol2, self.dv, self.r, self.z],
                    device=dev,
                    record_cmd=record,
                )
            )
        return cmds

    def run_cg(self) -> None:
        """Run CG now on what ``_bw_assemble`` (or a CG start) left in the work buffers."""
        self.cg(record=False)
