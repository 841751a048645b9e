"""The colliders' signed distances and contact response as Warp functions (no kernels, no Python state).

One collider of kind 0 sphere, 1 box, 2 capsule, 3 mesh (:class:`pliant.collision.Colliders` documents the
parameters) is a signed distance φ(p) [m] (negative inside) with its gradient n = ∇φ and Hessian ∇²φ
[1/m]. The colliders' kernels (:mod:`._colliders`) and the penalty energy both call these, so they sit
below both modules.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._friction import friction_velocity


@wp.func
def _curved_hessian(P: Any, n: Any, rho: Any):
    """(P − nnᵀ)/ρ: the Hessian of the distance to a point (P = I) or a line (P = I − ûûᵀ)."""
    return (P - wp.outer(n, n)) / wp.max(rho, type(rho)(1.0e-12))


@wp.func
def collider_sdf(kind: int, pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ [m], n = ∇φ, ∇²φ [1/m]) of one collider at p; see :class:`Colliders` for the parameters."""
    zero = radius * type(radius)(0.0)
    one = type(radius)(1.0)
    eye = wp.identity(n=3, dtype=type(radius))
    up = type(p)(zero, one, zero)
    phi = zero
    n = up
    H = eye * zero
    if kind == 0:  # sphere: centre pos, radius
        d = p - pos
        l = wp.length(d)
        phi = l - radius
        if l > zero:
            n = d / l
        H = _curved_hessian(eye, n, l)
    elif kind == 1:  # box: centre pos, half extents aux, rotation rot (world from local), rounded by radius
        pl = wp.transpose(rot) * (p - pos)
        q = type(p)(wp.abs(pl[0]) - aux[0], wp.abs(pl[1]) - aux[1], wp.abs(pl[2]) - aux[2])
        qmax = wp.max(q[0], wp.max(q[1], q[2]))
        if qmax > zero:
            qp = type(p)(wp.max(q[0], zero), wp.max(q[1], zero), wp.max(q[2], zero))
            rho = wp.length(qp)
            nl = type(p)(wp.sign(pl[0]) * qp[0], wp.sign(pl[1]) * qp[1], wp.sign(pl[2]) * qp[2]) / rho
            P = eye * zero
            for a in range(3):
                if q[a] > zero:
                    P[a, a] = one
            n = rot * nl
            H = rot * _curved_hessian(P, nl, rho) * wp.transpose(rot)
            phi = rho - radius
        else:
            axis = 0
            if q[1] >= q[0] and q[1] >= q[2]:
                axis = 1
            elif q[2] >= q[0] and q[2] >= q[1]:
                axis = 2
            nl = type(p)(zero, zero, zero)
            nl[axis] = wp.sign(pl[axis])
            n = rot * nl
            phi = qmax - radius
    elif kind == 2:  # capsule: segment pos–aux, radius
        ab = aux - pos
        t = wp.clamp(wp.dot(p - pos, ab) / wp.dot(ab, ab), zero, one)
        d = p - (pos + t * ab)
        l = wp.length(d)
        phi = l - radius
        if l > zero:
            n = d / l
        P = eye
        if t > zero and t < one:
            u = ab / wp.length(ab)
            P = eye - wp.outer(u, u)
        H = _curved_hessian(P, n, l)
    else:  # closed triangle mesh (float32 BVH)
        pf = wp.vec3f(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
        qr = wp.mesh_query_point(mesh, pf, wp.float32(1.0e6))
        if qr.result:
            cpf = wp.mesh_eval_position(mesh, qr.face, qr.u, qr.v)
            cp = type(p)(type(zero)(cpf[0]), type(zero)(cpf[1]), type(zero)(cpf[2]))
            d = p - cp
            l = wp.length(d)
            s = type(zero)(qr.sign)
            phi = s * l - radius
            if l > type(zero)(1.0e-9):
                n = s * d / l
            else:
                nf = wp.mesh_eval_face_normal(mesh, qr.face)
                n = type(p)(type(zero)(nf[0]), type(zero)(nf[1]), type(zero)(nf[2]))
        else:
            phi = type(zero)(1.0e6)
    return phi, n, H


@wp.func
def collider_contact(
    kind: int,
    pos: Any,
    aux: Any,
    rot: Any,
    radius: Any,
    mesh: wp.uint64,
    friction: Any,
    restitution: Any,
    stick_velocity: Any,
    dt: Any,
    particle_radius: Any,
    x: Any,
    v: Any,
):
    """One collider's velocity-level response for one particle: (x, v) → (x', v'), pushed out along n,
    normal velocity reflected with restitution e, tangential velocity through the Coulomb law for the
    normal change Δv_n (:func:`~pliant.collision._friction.friction_scale`: stopped if |v_t| ≤ μ·Δv_n, cut
    by μ·Δv_n otherwise, smoothed below the stick velocity ε_v), and x moved by Δt Δv_t (friction acts
    inside the step, so a sticking particle stays put)."""
    zero = particle_radius * type(particle_radius)(0.0)
    phi, n, H = collider_sdf(kind, pos, aux, rot, radius, mesh, x)
    pen = particle_radius - phi
    x_new = x
    v_new = v
    if pen > zero:
        vn = wp.dot(v, n)
        vn_new = wp.max(vn, zero)
        if vn < zero:
            vn_new = -restitution * vn
        vt = v - vn * n
        vt_new = friction_velocity(vt, friction * (vn_new - vn), stick_velocity)
        x_new = x + pen * n + dt * (vt_new - vt)
        v_new = vt_new + vn_new * n
    return x_new, v_new
