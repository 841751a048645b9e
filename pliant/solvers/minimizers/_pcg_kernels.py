"""The kernels of the device-resident conjugate gradient (:mod:`._pcg`): block-Jacobi preconditioned CG on
the assembled BSR(3×3) Hessian, whose stopping test runs on the device.

One CG iteration is two launches, fused as in FastMassSpring's matrix-free CG (``fast_mass_spring._cg``):

* :func:`cg_apply`: the search direction p = z + β p_old (β = r·z / r·z of the previous iteration) and
  q = H p, row by row on the BSR layout (each row recomputes its neighbours' p from z and p_old, so nobody
  reads a value written in the same launch), accumulating p·q;
* :func:`cg_update`: α = r·z / p·q, x += α p, r −= α q, z = P r (P: the inverted 3×3 diagonal blocks),
  accumulating the next r·z and r·r.

The scalars of a chunk of K iterations live in one array (:data:`slot` gives the layout), each iteration
reading the slots its predecessor filled, so that a chunk is a fixed sequence of launches with the
iteration index a launch argument. An iteration whose residual is already below the tolerance (or whose
p·Hp ≤ 0, or past the iteration cap) is *frozen*: it launches but changes nothing, so a chunk needs no host
read; :func:`cg_chunk_end` rolls the slots over to the next chunk and sets the flag that
``wp.capture_while`` tests. Integer state (``counts``): :data:`DONE` (frozen for good: a breakdown),
:data:`CHECKS` (chunks finished in this solve), :data:`ITERATIONS` (iterations that moved, over the
Newton step) and :data:`TOTAL` (iterations that moved over the solver's life, never cleared).

The dot products reduce in one of two ways (the kernels' ``tiled`` argument, :data:`ATOMIC` or
:data:`TILE`): every thread adds its term to the one scalar (atomics to a single address, serialised on a
GPU), or each block sums its terms with ``wp.tile_sum`` and one thread adds the block's sum. A tiled
launch covers whole blocks (:func:`tiled_dim`); the threads past the last row contribute 0. On the CPU a
block is one thread (Warp's CPU tile semantics), so both ways add the same terms in the same order.
"""

from __future__ import annotations

from typing import Any

import warp as wp

#: ``counts`` slots (int32).
DONE = 0
CHECKS = 1
ITERATIONS = 2
TOTAL = 3
COUNT_SLOTS = 4

#: ``tiled`` argument: per-thread atomic adds, or a block sum (``wp.tile_sum``) and one atomic per block.
ATOMIC = 0
TILE = 1

#: Threads per block of a tiled launch.
BLOCK_DIM = 256


def tiled_dim(n: int) -> int:
    """Launch size of a tiled kernel over n rows: whole blocks of :data:`BLOCK_DIM` threads."""
    return -(-n // BLOCK_DIM) * BLOCK_DIM


def slot(j: int) -> tuple[int, int, int]:
    """Slots of iteration j of a chunk in the scalars array: (r·z at its start, r·r at its start, p·Hp).
    Slot 0 holds r·z of the iteration before the chunk's first (β's denominator; 0 before the first)."""
    return 1 + 3 * j, 2 + 3 * j, 3 + 3 * j


def scalar_slots(chunk: int) -> int:
    """Length of the scalars array of a chunk of ``chunk`` iterations (the slots of iteration ``chunk``'s
    r·z and r·r included: the values the next chunk starts from)."""
    return 3 + 3 * chunk


@wp.func
def _frozen(
    scalars: wp.array(dtype=Any),
    limit: wp.array(dtype=Any),
    counts: wp.array(dtype=wp.int32),
    j: int,
    chunk: int,
    cap: int,
) -> bool:
    # The same answer in every thread of a launch: it reads only values that earlier launches wrote.
    return counts[DONE] != 0 or not (scalars[2 + 3 * j] > limit[0]) or counts[CHECKS] * chunk + j >= cap


@wp.func
def _accumulate(tiled: int, i: int, n: int, total: wp.array(dtype=Any), k: int, value: Any):
    # total[k] += Σ value over the launch's rows i < n. Tiled: every thread of the block must get here
    # (the callers return early only where the whole launch does), rows past n bring 0.
    if tiled == ATOMIC:
        wp.atomic_add(total, k, value)
    else:
        v = value
        if i >= n:
            v = type(value)(0.0)
        s = wp.tile_sum(wp.tile(v))
        if i % wp.block_dim() == 0:
            wp.atomic_add(total, k, s[0])


@wp.kernel(enable_backward=False)
def cg_block_inverse(
    inv_mass: wp.array(dtype=Any),
    diag_slots: wp.array(dtype=wp.int32),
    values: wp.array(dtype=Any),
    blocks_out: wp.array(dtype=Any),
):
    # P_i = (H_ii)⁻¹, the 3×3 block-Jacobi preconditioner; 0 on fixed rows (their mass may be 0, and their
    # residual is 0 anyway).
    i = wp.tid()
    b = values[diag_slots[i]]
    if inv_mass[i] == type(inv_mass[i])(0.0):
        blocks_out[i] = b * type(inv_mass[i])(0.0)
    else:
        blocks_out[i] = wp.inverse(b)


@wp.kernel(enable_backward=False)
def cg_reset(
    limit: wp.array(dtype=Any),
    scalars_out: wp.array(dtype=Any),
    counts_out: wp.array(dtype=wp.int32),
):
    # A solve starts: every slot 0 (r·z and r·r are accumulated by cg_begin), nothing frozen, no chunk done.
    zero = type(limit[0])(0.0)
    for k in range(scalars_out.shape[0]):
        scalars_out[k] = zero
    counts_out[DONE] = 0
    counts_out[CHECKS] = 0


@wp.kernel(enable_backward=False)
def cg_begin(
    tiled: int,
    n: int,
    blocks: wp.array(dtype=Any),
    grad_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    r_out: wp.array(dtype=Any),
    z_out: wp.array(dtype=Any),
    p0_out: wp.array(dtype=Any),
    p1_out: wp.array(dtype=Any),
    scalars_out: wp.array(dtype=Any),
):
    # H x = −∇Φ from x = 0: r = −g, z = P r, both search-direction buffers 0 (β = 0 multiplies them first).
    i = wp.tid()
    rz = type(scalars_out[0])(0.0)
    rr = rz
    if i < n:
        r = -grad_in[i]
        z = blocks[i] * r
        zero = r * type(r[0])(0.0)
        x_out[i] = zero
        r_out[i] = r
        z_out[i] = z
        p0_out[i] = zero
        p1_out[i] = zero
        rz = wp.dot(r, z)
        rr = wp.dot(r, r)
    _accumulate(tiled, i, n, scalars_out, 1, rz)
    _accumulate(tiled, i, n, scalars_out, 2, rr)


@wp.kernel(enable_backward=False)
def cg_start(
    tol2: wp.float64,
    scalars_in: wp.array(dtype=Any),
    limit_out: wp.array(dtype=Any),
    go_out: wp.array(dtype=wp.int32),
):
    # Converged once ‖r‖² ≤ tol²‖b‖² (relative residual, as warp.optim.linear.cg with atol = 0).
    rr = scalars_in[2]
    lim = type(rr)(tol2 * wp.float64(rr))
    limit_out[0] = lim
    go = 0
    if rr > lim:
        go = 1
    go_out[0] = go


@wp.kernel(enable_backward=False)
def cg_apply(
    tiled: int,
    n: int,
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=Any),
    limit: wp.array(dtype=Any),
    counts: wp.array(dtype=wp.int32),
    z_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    j: int,
    prev: int,
    chunk: int,
    cap: int,
    p_out: wp.array(dtype=Any),
    q_out: wp.array(dtype=Any),
    scalars_io: wp.array(dtype=Any),
):
    # p = z + β p_old, q = H p on row i, p·q accumulated into iteration j's slot. ``prev``: the slot of the
    # previous iteration's r·z (β's denominator).
    i = wp.tid()
    if _frozen(scalars_io, limit, counts, j, chunk, cap):
        return  # cg_update freezes this iteration too: p and q are never read
    rz = scalars_io[1 + 3 * j]
    den = scalars_io[prev]
    beta = type(rz)(0.0)
    if den > beta:
        beta = rz / den
    pq = type(rz)(0.0)
    if i < n:
        pi = z_in[i] + beta * p_in[i]
        q = pi * type(rz)(0.0)
        for k in range(offsets[i], offsets[i + 1]):
            c = columns[k]
            q += values[k] * (z_in[c] + beta * p_in[c])
        p_out[i] = pi
        q_out[i] = q
        pq = wp.dot(pi, q)
    _accumulate(tiled, i, n, scalars_io, 3 + 3 * j, pq)


@wp.kernel(enable_backward=False)
def cg_update(
    tiled: int,
    n: int,
    blocks: wp.array(dtype=Any),
    limit: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    q_in: wp.array(dtype=Any),
    j: int,
    chunk: int,
    cap: int,
    x_io: wp.array(dtype=Any),
    r_io: wp.array(dtype=Any),
    z_out: wp.array(dtype=Any),
    scalars_io: wp.array(dtype=Any),
    counts_io: wp.array(dtype=wp.int32),
):
    # α = r·z / p·Hp; a frozen iteration (converged, capped, or p·Hp ≤ 0: H not positive definite along p)
    # carries r·z and r·r to the next slots unchanged, and a breakdown freezes the rest of the solve.
    i = wp.tid()
    rz = scalars_io[1 + 3 * j]
    pq = scalars_io[3 + 3 * j]
    zero = type(rz)(0.0)
    frozen = _frozen(scalars_io, limit, counts_io, j, chunk, cap)
    if frozen or not (pq > zero):
        if i == 0:
            scalars_io[1 + 3 * (j + 1)] = rz
            scalars_io[2 + 3 * (j + 1)] = scalars_io[2 + 3 * j]
            if not frozen:
                counts_io[DONE] = 1
        return
    alpha = rz / pq
    rz_next = zero
    rr_next = zero
    if i < n:
        x_io[i] = x_io[i] + alpha * p_in[i]
        r = r_io[i] - alpha * q_in[i]
        r_io[i] = r
        z = blocks[i] * r
        z_out[i] = z
        rz_next = wp.dot(r, z)
        rr_next = wp.dot(r, r)
    _accumulate(tiled, i, n, scalars_io, 1 + 3 * (j + 1), rz_next)
    _accumulate(tiled, i, n, scalars_io, 2 + 3 * (j + 1), rr_next)
    if i == 0:
        counts_io[ITERATIONS] = counts_io[ITERATIONS] + 1
        counts_io[TOTAL] = counts_io[TOTAL] + 1


@wp.kernel(enable_backward=False)
def cg_chunk_end(
    chunk: int,
    checks: int,
    limit: wp.array(dtype=Any),
    scalars_io: wp.array(dtype=Any),
    counts_io: wp.array(dtype=wp.int32),
    go_out: wp.array(dtype=wp.int32),
):
    # Roll the slots over (the chunk's last r·z becomes β's denominator, its final r·z and r·r the next
    # chunk's start) and go on while the residual is above the limit, nothing broke down and fewer than
    # ``checks`` chunks ran.
    last = scalars_io[1 + 3 * (chunk - 1)]
    rz = scalars_io[1 + 3 * chunk]
    rr = scalars_io[2 + 3 * chunk]
    for k in range(scalars_io.shape[0]):
        scalars_io[k] = type(rz)(0.0)
    scalars_io[0] = last
    scalars_io[1] = rz
    scalars_io[2] = rr
    n = counts_io[CHECKS] + 1
    counts_io[CHECKS] = n
    go = 0
    if counts_io[DONE] == 0 and rr > limit[0] and n < checks:
        go = 1
    go_out[0] = go
