r"""Continuous collision detection for barrier contact: the largest fraction of a Newton step Δx that keeps
every contact pair apart (:meth:`pliant.energies.BarrierContact.max_step`).

Point–triangle and edge–edge pairs come from box queries of swept boxes (x to x + Δx) in ``wp.Bvh``\ s; each
pair's bound is additive CCD's (conservative), the ground's is exact, the colliders' a conservative
advancement on their signed distance. All in float64.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ..collision import collider_sdf, rigid_displacement
from ._barrier_kernels import all_fixed
from ._barrier_math import edge_edge_distance, point_triangle_distance, to_d

wp.set_module_options({"max_unroll": 0})

#: The CCD keeps every pair at least this fraction of its distance at the start of the step (the plane's
#: exact bound is then 0.8 × its time of impact, as in IPC).
KEEP_FRACTION = 0.2


@wp.func
def _pair_distance(x0: wp.vec3d, x1: wp.vec3d, x2: wp.vec3d, x3: wp.vec3d, edge_edge: int):
    if edge_edge == 0:
        return point_triangle_distance(x0, x1, x2, x3)
    return edge_edge_distance(x0, x1, x2, x3)


@wp.func
def pair_toi(
    x0: wp.vec3d,
    x1: wp.vec3d,
    x2: wp.vec3d,
    x3: wp.vec3d,
    u0: wp.vec3d,
    u1: wp.vec3d,
    u2: wp.vec3d,
    u3: wp.vec3d,
    edge_edge: int,
    keep: wp.float64,
):
    """Largest t ≤ 1 found such that the pair, moved by t·u, stays at least ``keep`` × its distance apart on
    [0, t]: additive CCD (Li et al., "Codimensional IPC", 2021) — advance by (d − keep·d₀)/l_p, where l_p
    bounds the rate of change of the distance by the displacements relative to their mean."""
    ubar = (u0 + u1 + u2 + u3) * wp.float64(0.25)
    v0 = wp.length(u0 - ubar)
    v1 = wp.length(u1 - ubar)
    v2 = wp.length(u2 - ubar)
    v3 = wp.length(u3 - ubar)
    lp = v0 + wp.max(v1, wp.max(v2, v3))
    if edge_edge != 0:
        lp = wp.max(v0, v1) + wp.max(v2, v3)
    one = wp.float64(1.0)
    if lp <= wp.float64(0.0):
        return one
    d0 = _pair_distance(x0, x1, x2, x3, edge_edge)
    if d0 <= wp.float64(0.0):
        return one  # touching already: nothing this bound can do
    target = keep * d0
    if (d0 - target) >= lp:
        return one  # cannot come closer than keep·d₀ within the whole step
    t = wp.float64(0.0)
    d = d0
    for _ in range(200):
        t = t + (d - target) / lp
        if t >= one:
            return one
        d = _pair_distance(x0 + t * u0, x1 + t * u1, x2 + t * u2, x3 + t * u3, edge_edge)
        if d - target <= wp.float64(1.0e-3) * (d0 - target):
            break
    return t


@wp.kernel(enable_backward=False)
def point_triangle_toi(
    points: wp.array(dtype=wp.int32),
    tris: wp.array(dtype=wp.int32),
    tri_bvh: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    keep: wp.float64,
    alpha_io: wp.array(dtype=Any),
):
    # One thread per point: its swept box against the triangles' swept boxes.
    t = wp.tid()
    i = points[t]
    p = x_in[i]
    p1 = p + dx_in[i]
    lo = wp.vec3f(
        wp.float32(wp.min(p[0], p1[0])), wp.float32(wp.min(p[1], p1[1])), wp.float32(wp.min(p[2], p1[2]))
    )
    hi = wp.vec3f(
        wp.float32(wp.max(p[0], p1[0])), wp.float32(wp.max(p[1], p1[1])), wp.float32(wp.max(p[2], p1[2]))
    )
    q = wp.bvh_query_aabb(tri_bvh, lo, hi)
    f = int(0)  # noqa: UP018
    while wp.bvh_query_next(q, f):
        idx = wp.vec4i(i, tris[3 * f], tris[3 * f + 1], tris[3 * f + 2])
        if idx[1] == i or idx[2] == i or idx[3] == i:
            continue
        if all_fixed(inv_mass, idx):
            continue
        toi = pair_toi(
            to_d(p), to_d(x_in[idx[1]]), to_d(x_in[idx[2]]), to_d(x_in[idx[3]]),
            to_d(dx_in[i]), to_d(dx_in[idx[1]]), to_d(dx_in[idx[2]]), to_d(dx_in[idx[3]]),
            0, keep,
        )  # fmt: skip
        if toi < wp.float64(1.0):
            wp.atomic_min(alpha_io, 0, type(p[0])(toi))


@wp.kernel(enable_backward=False)
def edge_edge_toi(
    edges: wp.array(dtype=wp.int32),
    edge_bvh: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    keep: wp.float64,
    alpha_io: wp.array(dtype=Any),
):
    # One thread per edge: its swept box against the edges' swept boxes, each pair once.
    e = wp.tid()
    ia = edges[2 * e]
    ib = edges[2 * e + 1]
    a0 = x_in[ia]
    b0 = x_in[ib]
    a1 = a0 + dx_in[ia]
    b1 = b0 + dx_in[ib]
    lo = wp.min(wp.min(a0, b0), wp.min(a1, b1))
    hi = wp.max(wp.max(a0, b0), wp.max(a1, b1))
    lof = wp.vec3f(wp.float32(lo[0]), wp.float32(lo[1]), wp.float32(lo[2]))
    hif = wp.vec3f(wp.float32(hi[0]), wp.float32(hi[1]), wp.float32(hi[2]))
    q = wp.bvh_query_aabb(edge_bvh, lof, hif)
    f = int(0)  # noqa: UP018
    while wp.bvh_query_next(q, f):
        if f <= e:
            continue
        idx = wp.vec4i(ia, ib, edges[2 * f], edges[2 * f + 1])
        if idx[0] == idx[2] or idx[0] == idx[3] or idx[1] == idx[2] or idx[1] == idx[3]:
            continue
        if all_fixed(inv_mass, idx):
            continue
        toi = pair_toi(
            to_d(a0), to_d(b0), to_d(x_in[idx[2]]), to_d(x_in[idx[3]]),
            to_d(dx_in[ia]), to_d(dx_in[ib]), to_d(dx_in[idx[2]]), to_d(dx_in[idx[3]]),
            1, keep,
        )  # fmt: skip
        if toi < wp.float64(1.0):
            wp.atomic_min(alpha_io, 0, type(a0[0])(toi))


@wp.kernel(enable_backward=False)
def obstacle_toi(
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
    dx_in: wp.array(dtype=Any),
    keep: wp.float64,
    alpha_io: wp.array(dtype=Any),
):
    # Ground: exact, the plane's distance is linear along the step. Colliders: conservative advancement on
    # φ, which changes by at most |dx| per unit of t (a signed distance is 1-Lipschitz).
    i = wp.tid()
    x = x_in[i]
    if inv_mass[i] == x[0] * type(x[0])(0.0):
        return
    u = dx_in[i]
    one = wp.float64(1.0)
    best = one
    if ground != 0:
        d0 = wp.float64(x[1]) - height
        uy = wp.float64(u[1])
        if d0 > wp.float64(0.0) and uy < wp.float64(0.0):
            best = wp.min(best, (one - keep) * d0 / (-uy))
    lp = wp.length(to_d(u))
    if lp > wp.float64(0.0):
        for c in range(n_colliders):
            phi, n, Hphi = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x)
            d0 = wp.float64(phi)
            if d0 > wp.float64(0.0) and d0 - keep * d0 < lp:
                target = keep * d0
                t = wp.float64(0.0)
                d = d0
                for _ in range(200):
                    t = t + (d - target) / lp
                    if t >= one:
                        t = one
                        break
                    xt = x + type(x[0])(t) * u
                    phi_t, n_t, H_t = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], xt)
                    d = wp.float64(phi_t)
                    if d - target <= wp.float64(1.0e-3) * (d0 - target):
                        break
                best = wp.min(best, t)
    if best < one:
        wp.atomic_min(alpha_io, 0, type(x[0])(best))


@wp.func
def _clear_at_end(
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    n_colliders: int,
    ground: int,
    height: wp.float64,
    x: Any,
):
    """Whether x is strictly outside the ground and every collider (at the pose given)."""
    if ground != 0:
        if wp.float64(x[1]) - height <= wp.float64(0.0):
            return False
    for c in range(n_colliders):
        phi, n, H = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x)
        if phi <= phi * type(phi)(0.0):
            return False
    return True


@wp.kernel(enable_backward=False)
def carry_start(
    # Colliders at the step's start:
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    vel: wp.array(dtype=Any),
    omega: wp.array(dtype=Any),
    centre: wp.array(dtype=Any),
    # ... and at its end (kind, radius and mesh are the same):
    pos1: wp.array(dtype=Any),
    aux1: wp.array(dtype=Any),
    rot1: wp.array(dtype=Any),
    n_colliders: int,
    ground: int,
    height: wp.float64,
    h: Any,
    dhat: Any,
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    blocked_out: wp.array(dtype=wp.int32),
):
    # A free particle within reach of a moving collider over the step (φ < d̂ + |s| + |ω|h φ: no surface
    # point nearer than φ moves farther than that) is carried by its rigid motion (the nearest such
    # collider's), which keeps its distance to that collider exactly. The start must be clear of the ground
    # and of every collider at the end pose: carried, else where it was; neither counts in ``blocked``.
    i = wp.tid()
    x = x_in[i]
    x_out[i] = x
    if inv_mass[i] == x[0] * type(x[0])(0.0):
        return
    best = dhat * type(dhat)(1.0e30)
    moved = x
    for c in range(n_colliders):
        speed = wp.length(vel[c]) + wp.length(omega[c])
        if speed > h * type(h)(0.0):
            phi, n, H = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x)
            s = rigid_displacement(vel[c], omega[c], centre[c], h, x)
            if phi < best and phi < dhat + wp.length(s) + wp.length(omega[c]) * h * phi:
                best = phi
                moved = x + s
    if _clear_at_end(kind, pos1, aux1, rot1, radius, mesh, n_colliders, ground, height, moved):
        x_out[i] = moved
    elif not _clear_at_end(kind, pos1, aux1, rot1, radius, mesh, n_colliders, ground, height, x):
        wp.atomic_add(blocked_out, 0, 1)
