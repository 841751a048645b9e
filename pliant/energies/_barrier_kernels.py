"""The barrier contact potential's kernels: broad-phase boxes, the barrier of self-contact pairs
(point–triangle, edge–edge, found by ``wp.Bvh`` box queries) and of obstacles (ground plane, colliders),
and the candidate pairs of the Hessian pattern (:class:`pliant.energies.BarrierContact`); the continuous
collision detection is in :mod:`._barrier_ccd`.

Every pair kernel computes in float64 (:mod:`._barrier_math`) and writes in the model's dtype.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ..collision import collider_sdf
from ._barrier_math import (
    barrier,
    barrier_d1,
    barrier_d2,
    edge_edge_distance,
    mat12d,
    pair_barrier,
    point_triangle_distance,
    to_d,
    vec12d,
)

wp.set_module_options({"max_unroll": 0})


# ------------------------------------------------------------------------------------------------- output
@wp.func
def _vec_out(g: vec12d, k: int, like: Any, s: wp.float64):
    out = like * type(like[0])(0.0)
    for i in range(3):
        out[i] = type(like[0])(s * g[3 * k + i])
    return out


@wp.func
def _block_out(H: mat12d, k: int, l: int, like: Any, s: wp.float64):
    out = wp.outer(like, like) * type(like[0])(0.0)
    for i in range(3):
        for j in range(3):
            out[i, j] = type(like[0])(s * H[3 * k + i, 3 * l + j])
    return out


@wp.func
def _find(keys: wp.array(dtype=wp.int64), key: wp.int64):
    """Index of ``key`` in the sorted ``keys``, or −1."""
    lo = int(0)  # noqa: UP018
    hi = keys.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    if lo < keys.shape[0]:
        if keys[lo] == key:
            return lo
    return -1


@wp.func
def _pair_slot(
    pair_keys: wp.array(dtype=wp.int64), n: int, slots_in: wp.array(dtype=wp.int32), i: int, j: int
):
    """The value slot of block (i, j), i ≠ j, or −1 when the pattern does not have it."""
    p = _find(pair_keys, wp.int64(wp.min(i, j)) * wp.int64(n) + wp.int64(wp.max(i, j)))
    if p < 0:
        return -1
    if i < j:
        return slots_in[n + 2 * p]
    return slots_in[n + 2 * p + 1]


@wp.func
def write_pair(
    idx: wp.vec4i,
    val: wp.float64,
    g: vec12d,
    H: mat12d,
    kappa: wp.float64,
    mode: int,
    scale: wp.float64,
    like: Any,
    pair_keys: wp.array(dtype=wp.int64),
    n: int,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # Hessian: the pattern has one diagonal block per particle, then blocks (i, j), (j, i) for each sorted
    # key i·n + j (i < j) of ``pair_keys``. A pair whose 6 point pairs are all there adds its whole 12×12
    # Hessian; any other only its 3×3 diagonal blocks (a principal submatrix: still PSD when projected).
    if val == wp.float64(0.0):
        return  # farther than d̂: nothing to add
    if mode == 0:
        wp.atomic_add(value_out, 0, type(like[0])(kappa * val))
    elif mode == 1:
        for k in range(4):
            wp.atomic_add(grad_out, idx[k], _vec_out(g, k, like, kappa))
    else:
        s = kappa * scale
        full = int(1)  # noqa: UP018
        for k in range(4):
            for l in range(k + 1, 4):
                if _pair_slot(pair_keys, n, slots_in, idx[k], idx[l]) < 0:
                    full = 0
        for k in range(4):
            wp.atomic_add(hess_out, slots_in[idx[k]], _block_out(H, k, k, like, s))
            if full != 0:
                for l in range(4):
                    if l != k:
                        slot = _pair_slot(pair_keys, n, slots_in, idx[k], idx[l])
                        wp.atomic_add(hess_out, slot, _block_out(H, k, l, like, s))


# ------------------------------------------------------------------------------------------- broad phase
@wp.kernel(enable_backward=False)
def prim_bounds(
    prims: wp.array(dtype=wp.int32),
    arity: int,
    x_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    swept: int,
    pad: float,
    lower_out: wp.array(dtype=wp.vec3f),
    upper_out: wp.array(dtype=wp.vec3f),
):
    # The box of primitive k (an edge or a triangle) at x, or swept from x to x + dx, padded by ``pad``.
    k = wp.tid()
    lo = wp.vec3f(1.0e30, 1.0e30, 1.0e30)
    hi = wp.vec3f(-1.0e30, -1.0e30, -1.0e30)
    for j in range(arity):
        v = prims[arity * k + j]
        p = wp.vec3f(wp.float32(x_in[v][0]), wp.float32(x_in[v][1]), wp.float32(x_in[v][2]))
        lo = wp.min(lo, p)
        hi = wp.max(hi, p)
        if swept != 0:
            q = x_in[v] + dx_in[v]
            pq = wp.vec3f(wp.float32(q[0]), wp.float32(q[1]), wp.float32(q[2]))
            lo = wp.min(lo, pq)
            hi = wp.max(hi, pq)
    lower_out[k] = lo - wp.vec3f(pad, pad, pad)
    upper_out[k] = hi + wp.vec3f(pad, pad, pad)


@wp.func
def all_fixed(inv_mass: wp.array(dtype=Any), idx: wp.vec4i):
    zero = inv_mass[idx[0]] * type(inv_mass[idx[0]])(0.0)
    return (
        inv_mass[idx[0]] == zero
        and inv_mass[idx[1]] == zero
        and inv_mass[idx[2]] == zero
        and inv_mass[idx[3]] == zero
    )


# ------------------------------------------------------------------------------------------------ barrier
@wp.kernel(enable_backward=False)
def point_triangle_barrier(
    points: wp.array(dtype=wp.int32),
    tris: wp.array(dtype=wp.int32),
    tri_bvh: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    pair_keys: wp.array(dtype=wp.int64),
    n: int,
    x_in: wp.array(dtype=Any),
    dhat: wp.float64,
    kappa: wp.float64,
    mode: int,
    project: int,
    scale: wp.float64,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # One thread per point: the triangles whose boxes, padded by d̂, hold it.
    t = wp.tid()
    i = points[t]
    p = x_in[i]
    pf = wp.vec3f(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
    q = wp.bvh_query_aabb(tri_bvh, pf, pf)
    f = int(0)  # noqa: UP018
    while wp.bvh_query_next(q, f):
        idx = wp.vec4i(i, tris[3 * f], tris[3 * f + 1], tris[3 * f + 2])
        if idx[1] == i or idx[2] == i or idx[3] == i:
            continue
        if all_fixed(inv_mass, idx):
            continue
        val, g, H = pair_barrier(
            to_d(p), to_d(x_in[idx[1]]), to_d(x_in[idx[2]]), to_d(x_in[idx[3]]), 0, dhat, mode, project
        )
        write_pair(
            idx, val, g, H, kappa, mode, scale, p, pair_keys, n, slots_in, value_out, grad_out, hess_out
        )


@wp.kernel(enable_backward=False)
def edge_edge_barrier(
    edges: wp.array(dtype=wp.int32),
    edge_bvh: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    pair_keys: wp.array(dtype=wp.int64),
    n: int,
    x_in: wp.array(dtype=Any),
    dhat: wp.float64,
    kappa: wp.float64,
    mode: int,
    project: int,
    scale: wp.float64,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # One thread per edge e; each pair once (partner index above e), edges sharing a point left out.
    e = wp.tid()
    a = x_in[edges[2 * e]]
    b = x_in[edges[2 * e + 1]]
    lo = wp.vec3f(
        wp.float32(wp.min(a[0], b[0])), wp.float32(wp.min(a[1], b[1])), wp.float32(wp.min(a[2], b[2]))
    )
    hi = wp.vec3f(
        wp.float32(wp.max(a[0], b[0])), wp.float32(wp.max(a[1], b[1])), wp.float32(wp.max(a[2], b[2]))
    )
    q = wp.bvh_query_aabb(edge_bvh, lo, hi)
    f = int(0)  # noqa: UP018
    while wp.bvh_query_next(q, f):
        if f <= e:
            continue
        idx = wp.vec4i(edges[2 * e], edges[2 * e + 1], edges[2 * f], edges[2 * f + 1])
        if idx[0] == idx[2] or idx[0] == idx[3] or idx[1] == idx[2] or idx[1] == idx[3]:
            continue
        if all_fixed(inv_mass, idx):
            continue
        val, g, H = pair_barrier(
            to_d(a), to_d(b), to_d(x_in[idx[2]]), to_d(x_in[idx[3]]), 1, dhat, mode, project
        )
        write_pair(
            idx, val, g, H, kappa, mode, scale, a, pair_keys, n, slots_in, value_out, grad_out, hess_out
        )


@wp.func
def _project_psd3(A: wp.mat33d):
    Q, lam = wp.eig3(A)
    out = wp.mat33d()
    for k in range(3):
        if lam[k] > wp.float64(0.0):
            out = out + lam[k] * wp.outer(Q[:, k], Q[:, k])
    return out


@wp.kernel(enable_backward=False)
def obstacle_barrier(
    # Colliders (``n_colliders`` of them; 1-element dummies when none):
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    n_colliders: int,
    ground: int,
    height: wp.float64,
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    dhat: wp.float64,
    kappa: wp.float64,
    mode: int,
    project: int,
    scale: wp.float64,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # κ b(d) per particle and obstacle, d its distance: y − h to the ground, φ_c(x) to collider c.
    # ∇ = κ b′ n, ∇² = κ (b″ n nᵀ + b′ ∇²φ); the curvature term (≤ 0 on convex colliders) is projected.
    i = wp.tid()
    x = x_in[i]
    if inv_mass[i] == x[0] * type(x[0])(0.0):
        return
    val = wp.float64(0.0)
    g = wp.vec3d()
    H = wp.mat33d()
    if ground != 0:
        d = wp.float64(x[1]) - height
        if d < dhat:
            val = val + barrier(d, dhat)
            g[1] = g[1] + barrier_d1(d, dhat)
            H[1, 1] = H[1, 1] + barrier_d2(d, dhat)
    for c in range(n_colliders):
        phi, n, Hphi = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x)
        d = wp.float64(phi)
        if d < dhat:
            nd = to_d(n)
            val = val + barrier(d, dhat)
            db = barrier_d1(d, dhat)
            g = g + db * nd
            if mode == 2:
                Hc = barrier_d2(d, dhat) * wp.outer(nd, nd)
                for r in range(3):
                    for s in range(3):
                        Hc[r, s] = Hc[r, s] + db * wp.float64(Hphi[r, s])
                if project != 0:
                    Hc = _project_psd3(Hc)
                H = H + Hc
    if mode == 0:
        if val != wp.float64(0.0):
            wp.atomic_add(value_out, 0, type(x[0])(kappa * val))
    elif mode == 1:
        out = x * type(x[0])(0.0)
        for r in range(3):
            out[r] = type(x[0])(kappa * g[r])
        wp.atomic_add(grad_out, i, out)
    else:
        hb = wp.outer(x, x) * type(x[0])(0.0)
        for r in range(3):
            for s in range(3):
                hb[r, s] = type(x[0])(kappa * scale * H[r, s])
        wp.atomic_add(hess_out, slots_in[i], hb)


@wp.kernel(enable_backward=False)
def pair_terms(
    x_in: wp.array(dtype=wp.vec3d),
    edge_edge: int,
    dhat: wp.float64,
    project: int,
    value_out: wp.array(dtype=wp.float64),
    grad_out: wp.array(dtype=vec12d),
    hess_out: wp.array(dtype=mat12d),
):
    # Pair k's barrier b(d) of points x[4k..4k+3], its gradient and Hessian (for the derivative tests).
    k = wp.tid()
    v, g, H = pair_barrier(
        x_in[4 * k], x_in[4 * k + 1], x_in[4 * k + 2], x_in[4 * k + 3], edge_edge, dhat, 2, project
    )
    value_out[k] = v
    grad_out[k] = g
    hess_out[k] = H


# ------------------------------------------------------------------------------------------ candidates
@wp.func
def _push(idx: wp.vec4i, count_out: wp.array(dtype=wp.int32), pairs_out: wp.array(dtype=wp.vec4i)):
    k = wp.atomic_add(count_out, 0, 1)
    if k < pairs_out.shape[0]:
        pairs_out[k] = idx


@wp.kernel(enable_backward=False)
def point_triangle_candidates(
    points: wp.array(dtype=wp.int32),
    tris: wp.array(dtype=wp.int32),
    tri_bvh: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    radius: wp.float64,
    count_out: wp.array(dtype=wp.int32),
    pairs_out: wp.array(dtype=wp.vec4i),
):
    # Point–triangle pairs closer than ``radius`` (the triangles' boxes padded by it), for the pattern.
    t = wp.tid()
    i = points[t]
    p = x_in[i]
    pf = wp.vec3f(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
    q = wp.bvh_query_aabb(tri_bvh, pf, pf)
    f = int(0)  # noqa: UP018
    while wp.bvh_query_next(q, f):
        idx = wp.vec4i(i, tris[3 * f], tris[3 * f + 1], tris[3 * f + 2])
        if idx[1] == i or idx[2] == i or idx[3] == i:
            continue
        if all_fixed(inv_mass, idx):
            continue
        d = point_triangle_distance(to_d(p), to_d(x_in[idx[1]]), to_d(x_in[idx[2]]), to_d(x_in[idx[3]]))
        if d < radius:
            _push(idx, count_out, pairs_out)


@wp.kernel(enable_backward=False)
def edge_edge_candidates(
    edges: wp.array(dtype=wp.int32),
    edge_bvh: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    radius: wp.float64,
    count_out: wp.array(dtype=wp.int32),
    pairs_out: wp.array(dtype=wp.vec4i),
):
    # Edge–edge pairs closer than ``radius`` (the edges' boxes padded by it), each once.
    e = wp.tid()
    a = x_in[edges[2 * e]]
    b = x_in[edges[2 * e + 1]]
    lo = wp.vec3f(
        wp.float32(wp.min(a[0], b[0])), wp.float32(wp.min(a[1], b[1])), wp.float32(wp.min(a[2], b[2]))
    )
    hi = wp.vec3f(
        wp.float32(wp.max(a[0], b[0])), wp.float32(wp.max(a[1], b[1])), wp.float32(wp.max(a[2], b[2]))
    )
    q = wp.bvh_query_aabb(edge_bvh, lo, hi)
    f = int(0)  # noqa: UP018
    while wp.bvh_query_next(q, f):
        if f <= e:
            continue
        idx = wp.vec4i(edges[2 * e], edges[2 * e + 1], edges[2 * f], edges[2 * f + 1])
        if idx[0] == idx[2] or idx[0] == idx[3] or idx[1] == idx[2] or idx[1] == idx[3]:
            continue
        if all_fixed(inv_mass, idx):
            continue
        d = edge_edge_distance(to_d(a), to_d(b), to_d(x_in[idx[2]]), to_d(x_in[idx[3]]))
        if d < radius:
            _push(idx, count_out, pairs_out)
