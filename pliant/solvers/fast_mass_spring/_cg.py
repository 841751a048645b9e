"""The two kernels of one Baraff–Witkin CG iteration (FastMassSpring's implicit step), matrix-free on the
per-particle spring blocks that ``_bw_assemble`` stores: ``_bw_apply`` (search direction and A·p) and
``_bw_update`` (the step along it, the residual and the block-Jacobi preconditioned residual)."""

from __future__ import annotations

from typing import Any

import warp as wp


@wp.kernel
def _bw_apply(
    # Model:
    adj_offsets: wp.array(dtype=wp.int32),
    adj_neighbor: wp.array(dtype=wp.int32),
    particle_mass: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    block: wp.array(dtype=Any),
    # CG:
    z_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    scalars_io: wp.array(dtype=Any),
    k: int,
    tol2: Any,
    p_out: wp.array(dtype=Any),
    q_out: wp.array(dtype=Any),
):
    # p_new = z + β p_old (β = rz_k / rz_{k−1}; none at k = 0), then q = A p_new, accumulating p·q.
    # Neighbours' p_new are recomputed from z and p_old, so nobody reads a value written in this launch.
    i = wp.tid()
    zero = scalars_io[0] * type(scalars_io[0])(0.0)
    if k > 0 and not scalars_io[2 * k] > tol2 * scalars_io[0]:
        # Converged: _bw_update freezes this iteration (α = 0), so skip the product. This device-side
        # flag is what lets a graph launch every iteration without a host read of the residual.
        return
    beta = zero
    if k > 0:
        den = scalars_io[2 * k - 2]
        if den > zero:
            beta = scalars_io[2 * k] / den
    # Pinned rows have z = 0 (zero preconditioner), hence p = 0: they never move.
    pi = z_in[i]
    if k > 0:
        pi = pi + beta * p_in[i]
    q = particle_mass[i] * pi
    for e in range(adj_offsets[i], adj_offsets[i + 1]):
        j = adj_neighbor[e]
        pj = z_in[j]
        if k > 0:
            pj = pj + beta * p_in[j]
        q += block[e] * (pi - pj)
    if particle_inv_mass[i] == zero:
        q = q * zero
    p_out[i] = pi
    q_out[i] = q
    wp.atomic_add(scalars_io, 2 * k + 1, wp.dot(pi, q))


@wp.kernel
def _bw_update(
    precond: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    q_in: wp.array(dtype=Any),
    scalars_io: wp.array(dtype=Any),
    k: int,
    tol2: Any,
    dv_io: wp.array(dtype=Any),
    r_io: wp.array(dtype=Any),
    z_out: wp.array(dtype=Any),
):
    # α = rz_k / (p·Ap); frozen (α = 0) once rz_k ≤ tol²·rz_0, so a fixed launch count needs no host sync.
    i = wp.tid()
    rz = scalars_io[2 * k]
    pq = scalars_io[2 * k + 1]
    zero = rz * type(rz)(0.0)
    alpha = zero
    if pq > zero and rz > tol2 * scalars_io[0]:
        alpha = rz / pq
    dv_io[i] = dv_io[i] + alpha * p_in[i]
    r = r_io[i] - alpha * q_in[i]
    r_io[i] = r
    z = precond[i] * r
    if alpha == zero:
        z = z * zero
    z_out[i] = z
    wp.atomic_add(scalars_io, 2 * k + 2, wp.dot(r, z))
